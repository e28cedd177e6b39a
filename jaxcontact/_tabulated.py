r"""A measured axisymmetric profile given as a table $(r_i, f_i)$.

The table is interpolated by a not-a-knot cubic spline $f(r)$ (the same spline as
`scipy.interpolate.CubicSpline` with its default end conditions). Its slope $f'(r)$ is then a
continuous piecewise quadratic $A_j + B_j r + C_j r^2$ on $[r_j, r_{j+1}]$, and the MDR
transform (paper, eq. 1) is integrated in closed form on every interval. With $r = x s$,

$$g(x) = x \int_0^1 \frac{f'(xs)}{\sqrt{1-s^2}}\,\mathrm{d}s
       = x \sum_j \left[A_j J_0 + B_j x J_1 + C_j x^2 J_2\right]_{s=r_j/x}^{\min(r_{j+1},x)/x},$$

with the antiderivatives $J_0 = \arcsin s$, $J_1 = -\sqrt{1-s^2}$,
$J_2 = (\arcsin s - s\sqrt{1-s^2})/2$ of $s^k/\sqrt{1-s^2}$. The inverse-square-root end point
$r = x$ is thus handled exactly; the only error is that of the spline. Likewise

- $g'(x) = \int_0^x f'(r)/\sqrt{x^2-r^2}\,dr + \int_0^x r f''(r)/\sqrt{x^2-r^2}\,dr$,
- $g''(x) = \int_0^1 [2 s f''(xs) + x s^2 f'''(xs)]/\sqrt{1-s^2}\,ds$ (the spline is $C^2$),
- $\int_0^a g(x)\,dx = \int_0^a f'(r)\sqrt{a^2-r^2}\,dr$ (order of integration swapped),

all in closed form. Derivatives with respect to `x` use these formulas through
`jax.custom_jvp` (differentiating the arcsine term by term would give `inf - inf` at the end
point); derivatives with respect to the table values `f` (and `r`) go through the spline
construction by ordinary autodiff. `g` and `integral_g` can be differentiated twice in `x`,
`dg` once; the `x`-derivative of `d2g` is plain autodiff and not reliable.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.lax.linalg import tridiagonal_solve
from jaxtyping import Array

from . import _sharding
from ._profiles import (
    AbstractCurvedProfile,
    numerical_contact_radius,
    numerical_critical_radius,
    numerical_front_radius,
    numerical_stationary_radius,
)
from ._solvers import as_float
from ._validate import (
    Condition,
    Constraint,
    check_finite,
    float_field,
    guarded,
    is_concrete,
)

__all__ = ["Tabulated"]


# ---------------------------------------------------------------------------------------
# Spline construction (differentiable in r and f).
# ---------------------------------------------------------------------------------------


def _spline_slopes(r: Array, f: Array) -> Array:
    """Node slopes $f'(r_i)$ of the not-a-knot cubic spline (scipy's banded system)."""
    dx = jnp.diff(r)
    m = jnp.diff(f) / dx
    d0 = r[2] - r[0]
    dn = r[-1] - r[-3]
    b = jnp.concatenate(
        [
            (((dx[0] + 2 * d0) * dx[1] * m[0] + dx[0] ** 2 * m[1]) / d0)[None],
            3 * (dx[1:] * m[:-1] + dx[:-1] * m[1:]),
            ((dx[-1] ** 2 * m[-2] + (2 * dn + dx[-1]) * dx[-2] * m[-1]) / dn)[None],
        ]
    )
    diag = jnp.concatenate([dx[1:2], 2 * (dx[:-1] + dx[1:]), dx[-2:-1]])
    upper = jnp.concatenate([d0[None], dx[:-1], jnp.zeros((1,), dx.dtype)])
    lower = jnp.concatenate([jnp.zeros((1,), dx.dtype), dx[1:], dn[None]])
    return tridiagonal_solve(lower, diag, upper, b[:, None])[:, 0]


def _spline_pieces(r: Array, f: Array):
    """Local cubic coefficients: on interval j, $f = f_j + s_j t + c_2 t^2 + c_3 t^3$."""
    s = _spline_slopes(r, f)
    h = jnp.diff(r)
    m = jnp.diff(f) / h
    c2 = (3 * m - 2 * s[:-1] - s[1:]) / h
    c3 = (s[:-1] + s[1:] - 2 * m) / h**2
    return s, c2, c3


def _slope_coefficients(r: Array, f: Array):
    """Global coefficients of $f'(r) = A_j + B_j r + C_j r^2$ on every interval."""
    s, c2, c3 = _spline_pieces(r, f)
    rj = r[:-1]
    C = 3 * c3
    B = 2 * c2 - 6 * c3 * rj
    A = s[:-1] - 2 * c2 * rj + 3 * c3 * rj**2
    return A, B, C


# ---------------------------------------------------------------------------------------
# Closed-form interval sums (x >= 0; r[0] == 0; the last piece is extrapolated).
# ---------------------------------------------------------------------------------------


def _per_piece(v: Array, ax: Array) -> Array:
    """A per-node or per-piece vector `v` (shape `(m,)`) as shape `(1, ..., 1, m)`, of the
    rank of `ax[..., None]` (explicit broadcasting)."""
    return jnp.reshape(v, (1,) * jnp.ndim(ax) + jnp.shape(v))


def _node_functions(ax: Array, r: Array):
    r"""$u_j = \min(r_j, x)/x$, $c_j = \sqrt{1-u_j^2}$, $\theta_j = \arcsin u_j$ per node.

    Node 0 is the axis ($u = 0$); the last node counts as $+\infty$ (the last spline piece is
    extrapolated beyond the table), so $u = 1$ there. Shapes: `ax.shape + (n,)`.
    """
    xe = ax[..., None]
    rin = _per_piece(r[1:-1], ax)
    cut = rin >= xe
    xs = jnp.where(xe > 0, xe, 1.0)
    # Safe in both branches (no sqrt of 0 or of a negative number under autodiff).
    q = jnp.sqrt(jnp.where(cut, 1.0, (xe - rin) * (xe + rin)))
    u = jnp.where(cut, 1.0, rin / xs)
    c = jnp.where(cut, 0.0, q / xs)
    th = jnp.where(cut, 0.5 * jnp.pi, jnp.arctan2(rin, q))
    shape = u.shape[:-1] + (1,)
    zeros = jnp.zeros(shape, u.dtype)
    ones = jnp.ones(shape, u.dtype)
    u = jnp.concatenate([zeros, u, ones], axis=-1)
    c = jnp.concatenate([ones, c, zeros], axis=-1)
    th = jnp.concatenate([zeros, th, 0.5 * jnp.pi * ones], axis=-1)
    return u, c, th


def _inv_sqrt_moments(ax, r):
    r"""Interval integrals of $s^k/\sqrt{1-s^2}$, k = 0, 1, 2."""
    u, c, th = _node_functions(ax, r)
    dJ0 = jnp.diff(th, axis=-1)
    dJ1 = -jnp.diff(c, axis=-1)
    dJ2 = 0.5 * jnp.diff(th - u * c, axis=-1)
    return dJ0, dJ1, dJ2


def _sqrt_moments(ax, r):
    r"""Interval integrals of $s^k\sqrt{1-s^2}$, k = 0, 1, 2."""
    u, c, th = _node_functions(ax, r)
    dP0 = 0.5 * jnp.diff(u * c + th, axis=-1)
    dP1 = -jnp.diff(c**3, axis=-1) / 3
    dP2 = jnp.diff(th - u * c * (1 - 2 * u**2), axis=-1) / 8
    return dP0, dP1, dP2


def _g_raw(ax, r, A, B, C):
    dJ0, dJ1, dJ2 = _inv_sqrt_moments(ax, r)
    x = ax[..., None]
    A, B, C = (_per_piece(v, ax) for v in (A, B, C))
    return ax * jnp.sum(A * dJ0 + x * B * dJ1 + x**2 * C * dJ2, axis=-1)


def _dg_raw(ax, r, A, B, C):
    dJ0, dJ1, dJ2 = _inv_sqrt_moments(ax, r)
    x = ax[..., None]
    A, B, C = (_per_piece(v, ax) for v in (A, B, C))
    return jnp.sum(A * dJ0 + 2 * x * B * dJ1 + 3 * x**2 * C * dJ2, axis=-1)


def _d2g_raw(ax, r, A, B, C):
    _, dJ1, dJ2 = _inv_sqrt_moments(ax, r)
    x = ax[..., None]
    A, B, C = (_per_piece(v, ax) for v in (A, B, C))
    return jnp.sum(2 * B * dJ1 + 6 * x * C * dJ2, axis=-1)


def _ig_raw(ax, r, A, B, C):
    dP0, dP1, dP2 = _sqrt_moments(ax, r)
    x = ax[..., None]
    A, B, C = (_per_piece(v, ax) for v in (A, B, C))
    return ax**2 * jnp.sum(A * dP0 + x * B * dP1 + x**2 * C * dP2, axis=-1)


# Tangents with respect to the node positions r are zero by construction: f' and f'' of the
# spline are continuous, so moving a node between two pieces does not change the integrals
# (the dependence of A, B, C on r is differentiated outside, through the spline solve).


def _d2g(x, r, A, B, C):
    # Plain autodiff in x: g''' of the spline, which has integrable singularities at the
    # nodes (f''' jumps there), so it is not a reliable quantity.
    return _d2g_raw(jnp.abs(x), r, A, B, C)


@jax.custom_jvp
def _dg(x, r, A, B, C):
    return _dg_raw(jnp.abs(x), r, A, B, C)


@_dg.defjvp
def _dg_jvp(primals, tangents):
    x, r, A, B, C = primals
    xd, _, Ad, Bd, Cd = tangents
    out = _dg(x, r, A, B, C)
    tan = jnp.sign(x) * _d2g(x, r, A, B, C) * xd + _dg(x, r, Ad, Bd, Cd)
    return out, tan


@jax.custom_jvp
def _g(x, r, A, B, C):
    return _g_raw(jnp.abs(x), r, A, B, C)


@_g.defjvp
def _g_jvp(primals, tangents):
    x, r, A, B, C = primals
    xd, _, Ad, Bd, Cd = tangents
    out = _g(x, r, A, B, C)
    tan = jnp.sign(x) * _dg(x, r, A, B, C) * xd + _g(x, r, Ad, Bd, Cd)
    return out, tan


@jax.custom_jvp
def _ig(x, r, A, B, C):
    return jnp.sign(x) * _ig_raw(jnp.abs(x), r, A, B, C)


@_ig.defjvp
def _ig_jvp(primals, tangents):
    x, r, A, B, C = primals
    xd, _, Ad, Bd, Cd = tangents
    out = _ig(x, r, A, B, C)
    tan = _g(x, r, A, B, C) * xd + _ig(x, r, Ad, Bd, Cd)
    return out, tan


_KERNELS = {"g": _g, "dg": _dg, "d2g": _d2g, "integral_g": _ig}


@functools.partial(jax.jit, static_argnums=0)
def _evaluate(kind: str, x, r: Array, f: Array) -> Array:
    """Evaluate one method of `Tabulated` (jitted: eager calls compile once per shape)."""
    x = jnp.asarray(x)
    dtype = jnp.result_type(x.dtype, r.dtype, f.dtype)
    x, r, f = x.astype(dtype), r.astype(dtype), f.astype(dtype)
    if kind == "shape":
        rr = jnp.abs(x)
        s, c2, c3 = _spline_pieces(r, f)
        j = jnp.clip(_sharding.searchsorted(r, rr, side="right") - 1, 0, r.shape[0] - 2)
        t = rr - r[j]
        return (f[j] - f[0]) + t * (s[j] + t * (c2[j] + t * c3[j]))
    A, B, C = _slope_coefficients(r, f)
    return _KERNELS[kind](x, r, A, B, C)


# ---------------------------------------------------------------------------------------
# The profile.
# ---------------------------------------------------------------------------------------


class Tabulated(AbstractCurvedProfile):
    r"""Axisymmetric profile $f(r)$ from a table, e.g. a measured AFM tip shape.

    **Arguments:**

    - `r`: radii [m], a 1-D array of at least 4 strictly increasing values starting at
      exactly `r[0] = 0` (the apex on the axis of symmetry; the MDR transform needs $f'$ on
      the whole of $[0, x]$, so a table that starts off-axis is rejected rather than
      silently extrapolated: prepend the apex point).
    - `f`: the gap $f(r_i)$ [m] at those radii, same shape. The profile is taken relative to
      the apex, $f(r) - f(0)$, so the table may carry any constant offset.

    The table is assumed smooth (resampled or fitted data, not raw noisy measurements): it is
    interpolated by a not-a-knot cubic spline, and every MDR quantity (`g`, `dg`, `d2g`,
    `integral_g`) is the exact transform of that spline, integrated in closed form (see the
    module docstring). The only error is that of the spline, which reproduces cubic
    polynomials exactly (parabola, cone, $c r^3$: rounding only) and shrinks quickly with the
    spacing $h$ for smooth shapes (`tests/test_tabulated.py` measures it against the closed
    forms of power laws). Relative accuracy degrades towards the axis (about
    $(h/x)^{2\ldots4}$: the profile there is flat and carried by few points); cluster the
    table points towards $r = 0$ if small contacts matter. `d2g` is one order less accurate
    than `dg`.

    `max_radius` is `r[-1]`; beyond it the last cubic piece is extrapolated, so values there
    are finite and smooth but not backed by data. Every method is elementwise over `x` of any
    shape (memory `x.size * len(r)`), and differentiable with respect to `x` and to the table
    values. Use float64 (the package default): the closed-form sums lose up to about
    `eps * (r_max / h)^2` in relative accuracy (in float32 a few per cent with thousands of
    points). The radii of the contact models (`contact_radius`, `critical_radius`,
    `front_radius`) are bracketed roots.
    """

    r: Array = eqx.field(converter=float_field("r", "m"))
    f: Array = eqx.field(converter=float_field("f", "m"))

    def __check_init__(self):
        if self.r.ndim != 1:
            raise ValueError(f"`r` [m] must be a 1-D array; got shape {self.r.shape}.")
        if self.f.shape != self.r.shape:
            raise ValueError(
                f"`f` [m] must have the same shape as `r`; got {self.f.shape} and "
                f"{self.r.shape}."
            )
        if self.r.shape[0] < 4:
            raise ValueError(
                f"`r` [m] needs at least 4 points for the cubic spline; got {self.r.shape[0]}."
            )
        check_finite("r", self.r, "m")
        check_finite("f", self.f, "m")
        if is_concrete(self.r):
            r = np.asarray(self.r)
            if r[0] != 0:
                raise ValueError(
                    f"`r` [m] must start at the axis, r[0] = 0; got r[0] = {r[0]}. "
                    "Prepend the apex point (0, f(0))."
                )
            steps = np.diff(r)
            if not np.all(steps > 0):
                i = int(np.argmin(steps > 0))
                raise ValueError(
                    f"`r` [m] must be strictly increasing; r[{i}] = {r[i]} >= "
                    f"r[{i + 1}] = {r[i + 1]}."
                )

    def domain(self):
        steps = self.r[1:] - self.r[:-1]
        return (
            Constraint("r", self.r, "m", lo=0.0, lo_open=False, kind="length"),
            Constraint("f", self.f, "m", lo=-np.inf),
            Condition("`r` [m] must start at 0 and increase strictly",
                      (self.r[0] == 0) & jnp.all(steps > 0)),
        )

    @guarded
    def shape(self, r):
        """The interpolated gap $f(r) - f(0)$ [m] (even in `r`)."""
        return _evaluate("shape", r, self.r, self.f)

    @guarded
    def g(self, x):
        return _evaluate("g", x, self.r, self.f)

    @guarded
    def dg(self, x):
        return _evaluate("dg", x, self.r, self.f)

    @guarded
    def d2g(self, x):
        """The curvature $g''(x)$ [1/m] for $x \\ge 0$ (even in `x`); see the module docstring."""
        return _evaluate("d2g", x, self.r, self.f)

    @guarded
    def integral_g(self, a):
        r"""$\int_0^a g(x)\,\mathrm{d}x$ [m²]; odd in `a`, derivative $g(a)$."""
        return _evaluate("integral_g", a, self.r, self.f)

    @property
    @guarded
    def max_radius(self):
        return self.r[-1]

    def contact_radius(self, depth, *, lo=None, hi=None):
        return numerical_contact_radius(self, as_float(depth), lo, hi)

    def critical_radius(self, c, k):
        return numerical_critical_radius(self, c, k)

    def front_radius(self, m, c, lo, hi=None):
        return numerical_front_radius(self, m, c, lo, hi)

    def stationary_radius(self, q, lo, hi):
        return numerical_stationary_radius(self, q, lo, hi)
