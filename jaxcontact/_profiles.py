r"""Axisymmetric indenter profiles and their MDR transforms.

A profile is the gap $f(r)$ between the indenter and the flat surface, in metres, as a
function of the in-plane radius $r$ (metres), with $f(0) = 0$. The Method of Dimensionality
Reduction replaces it by the plane profile (paper, eq. 1; `docs/physics.md` §1)

$$g(x) = |x| \int_0^{|x|} \frac{f'(r)}{\sqrt{x^2 - r^2}}\,\mathrm{d}r,$$

which is pressed into a one-dimensional foundation of independent springs.

Every profile is an `equinox.Module` (a pytree), so it can be passed through `jit`, `vmap`
and `grad`; its parameters are arrays (a new value never recompiles a program). Each one
provides

- `shape(r)`: the 3D profile $f(r)$ [m];
- `g(x)`: the MDR profile $g(x)$ [m] (even in $x$);
- `dg(x)`: $g'(x)$ for $x \ge 0$ [dimensionless];
- `integral_g(a)`: $\int_0^a g(x)\,\mathrm{d}x$ [m²], needed for the normal force;
- `max_radius`: the largest possible contact radius [m] (`inf` except for bounded shapes);
- `valid_radius`: the largest contact radius the profile describes [m] (`max_radius`; the
  radius `R` of a `Parabola`, which stands for a sphere);
- `domain()`: its parameters as `Constraint`s (checked when built with concrete values; under
  `jit`/`vmap` the methods above raise for invalid parameters, and the entry functions
  report them per lane as `RESULTS.invalid_profile`);

and the operations of the contact models on the MDR front $h(a) = g(a) - c\sqrt a$, closed
forms where they exist (power laws, parabola, cone), a fixed number of Newton steps from a
closed-form start for the power law's front and the exact sphere (`_root.fold_root`,
`_root.convex_root`), a bracketed root otherwise (tables):

- `contact_radius(depth)`: the non-adhesive radius, $g(a) = d$;
- `critical_radius(c, k)`: the root of $a\,g'(a) = k\,c\sqrt a$ ($k = 1/2$: the fold of
  $h$, jump-off under displacement control; $k = 3/2$: the minimum of the force);
- `front_radius(m, c, lo, hi)`: the stable (larger) root of $h(a) = m$;
- `touch_coordinate()`: the coordinate in which the foundation grid of `simulate` is
  uniform (`TouchCoordinate`).

Subclasses implement every abstract method (the equinox abstract/final pattern: no
concrete method is overridden); `AbstractCurvedProfile` and `AbstractPowerLawProfile` hold
the implementations that curved and power-law profiles share.
"""

from __future__ import annotations

import abc
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.scipy.special import gammaln
from jaxtyping import Array, ArrayLike, Float

from ._root import bracketed_root, fold_root
from ._solvers import as_float, float64_scope
from ._validate import Constraint, float_field, guarded, module_repr, unchecked

__all__ = [
    "AbstractProfile",
    "AbstractCurvedProfile",
    "AbstractPowerLawProfile",
    "Parabola",
    "Cone",
    "PowerLaw",
    "FlatPunch",
    "GapCoordinate",
    "PositionCoordinate",
    "TouchCoordinate",
    "fold_front_radius",
    "front_displacement",
    "parabola_stable_radius",
    "power_law_factor",
]


@float64_scope
def power_law_factor(n: ArrayLike) -> Array:
    r"""The MDR stretch factor $\kappa(n) = \sqrt\pi\,\Gamma(n/2+1)/\Gamma(n/2+1/2)$.

    For $f(r) = c r^n$ the MDR profile is $g(x) = \kappa(n)\,c\,|x|^n$. $\kappa(2) = 2$
    (parabola), $\kappa(1) = \pi/2$ (cone).
    """
    n = jnp.asarray(n)
    return jnp.sqrt(jnp.pi) * jnp.exp(gammaln(n / 2 + 1) - gammaln(n / 2 + 0.5))


def front_displacement(profile, a, c):
    r"""The indentation on the detachment front, $h(a) = g(a) - c\sqrt a$ [m], with $c$ from
    the criterion (`_criteria.hess_coefficient` or `_criteria.relaxed_front_coefficient`)."""
    return profile.g(a) - c * jnp.sqrt(a)


# --------------------------------------------------------------------------------------
# The touch coordinate of the foundation grid
# --------------------------------------------------------------------------------------


class TouchCoordinate(eqx.Module):
    r"""The coordinate $\zeta(x)$ in which `simulate` places and interpolates its springs.

    For a curved profile $\zeta = g(x)$, the indentation at which the indenter reaches the
    spring at $x$: springs of one cell touched within the same increment of indentation
    (`GapCoordinate`). A flat punch touches every spring at once ($g = 0$ on the punch), so
    there $\zeta = x$ (`PositionCoordinate`).
    """

    @property
    @abc.abstractmethod
    def covers_contact(self) -> bool:
        """The grid spans every possible contact (it does not depend on the depth, and the
        contact cannot outgrow it)."""

    @property
    @abc.abstractmethod
    def g_weight(self) -> float:
        r"""$\mathrm{d}g/\mathrm{d}\zeta$: 1 for a curved profile, 0 for the flat punch."""

    @abc.abstractmethod
    def g(self, x):
        """$g(x)$ on the grid [m]."""

    @abc.abstractmethod
    def integral_g(self, x):
        r"""$\int_0^x g$ [m²]."""

    @abc.abstractmethod
    def zeta(self, x):
        r"""$\zeta(x)$ [m]."""

    @abc.abstractmethod
    def zeta_integral(self, x):
        r"""$\int_0^x \zeta$ [m²]."""

    @abc.abstractmethod
    def zeta_inverse(self, y, lo, hi):
        r"""$x$ in `[lo, hi]` with $\zeta(x) = y$ ($\zeta$ increasing)."""

    @abc.abstractmethod
    def stationary_radius(self, q, lo, hi):
        r"""The solution of $\sqrt{x}\,\zeta'(x) = q$ in `[lo, hi]`."""

    @abc.abstractmethod
    def nodes(self, cells: int, depth) -> Array:
        r"""Node positions $x_j$, shape `(cells + 1,)`, uniform in $\zeta$ (up to `depth`)."""

    def stationary(self, q, lo, hi):
        r"""Solution of $\sqrt{x}\,\zeta'(x) = q$ (the maximiser of $-\beta\zeta + c\sqrt x$
        for $q = c/(2\beta)$), clipped to `[lo, hi]`; not differentiated."""
        q = lax.stop_gradient(q)
        lo = lax.stop_gradient(lo)
        hi = lax.stop_gradient(hi)
        x = self.stationary_radius(q, lo, hi)
        x = jnp.where(jnp.isfinite(x), x, hi)
        return jnp.clip(x, lo, hi)


class GapCoordinate(TouchCoordinate):
    r"""$\zeta = g(x)$: the touch depth of a curved profile."""

    profile: AbstractProfile

    @property
    def covers_contact(self):
        return False

    @property
    def g_weight(self):
        return 1.0

    def g(self, x):
        return self.profile.g(x)

    def integral_g(self, x):
        return self.profile.integral_g(x)

    def zeta(self, x):
        return self.profile.g(x)

    def zeta_integral(self, x):
        return self.profile.integral_g(x)

    def zeta_inverse(self, y, lo, hi):
        return self.profile.contact_radius(y, lo=lo, hi=hi)

    def stationary_radius(self, q, lo, hi):
        return self.profile.stationary_radius(q, lo, hi)

    def nodes(self, cells, depth):
        frac = jnp.linspace(0.0, 1.0, cells + 1, dtype=jnp.result_type(depth))
        return self.profile.contact_radius(frac * depth)


class PositionCoordinate(TouchCoordinate):
    r"""$\zeta = x$ on a flat punch of radius `radius` ($g = 0$ there)."""

    radius: Float[Array, ""]

    @property
    def covers_contact(self):
        return True

    @property
    def g_weight(self):
        return 0.0

    def g(self, x):
        return jnp.zeros_like(x)

    def integral_g(self, x):
        return jnp.zeros_like(x)

    def zeta(self, x):
        return x

    def zeta_integral(self, x):
        return 0.5 * x**2

    def zeta_inverse(self, y, lo, hi):
        return y

    def stationary_radius(self, q, lo, hi):
        return q**2

    def nodes(self, cells, depth):
        return self.radius * jnp.linspace(0.0, 1.0, cells + 1, dtype=self.radius.dtype)


# --------------------------------------------------------------------------------------
# Numerical operations on the front, for profiles without closed forms
# --------------------------------------------------------------------------------------


def upper_radius(profile) -> Array:
    """A finite upper end for radius brackets (the profile's own, or 1 m)."""
    amax = as_float(profile.max_radius)
    return jnp.where(jnp.isfinite(amax), amax, 1.0)


@eqx.filter_jit
def compiled_contact_radius(profile, depth) -> Array:
    """`profile.contact_radius(depth)` [m] as one compiled program per profile class, shape
    and dtype (the parameters are its arguments: a new value never recompiles), for eager
    callers with inputs already checked (`profile_radius`, the entry points' checks of a
    relaxed or deepest indentation). Run eagerly op by op, a bracketed root (the exact
    sphere, tables) took 0.15–0.4 s a call, every call. Without the guards of `guarded`
    (`unchecked`: the entry points report the inputs themselves)."""
    with unchecked():
        return profile.contact_radius(depth)


def _elementwise(fn, x):
    """`fn` (a scalar function) over every entry of `x` by `vmap`."""
    x = jnp.asarray(x)
    return jax.vmap(fn)(jnp.ravel(x)).reshape(x.shape)


def fold_front_radius(profile, m, c, lo, hi, start, *, steps: int):
    r"""The stable root of $h(a) = g(a) - c\sqrt a = m$ right of the fold `lo` [m], per
    entry of `m` (any shape), by `fold_root` from `start(m)`: the `front_radius` of profiles
    with a closed-form start at or right of the root (`start` takes one entry of `m`, not
    differentiated; `steps` the profile's measured worst case)."""

    def one(mm):
        return fold_root(lambda a: front_displacement(profile, a, c) - mm,
                         start(lax.stop_gradient(mm)), lo, hi, steps=steps)

    return _elementwise(one, as_float(m))


def numerical_contact_radius(profile, depth, lo=None, hi=None):
    """$a$ with $g(a) = d$ by a bracketed root on `[lo, hi]` (default `[0, max radius]`)."""
    top = upper_radius(profile)
    lo = 0.0 * top if lo is None else lo
    hi = top if hi is None else hi
    if jnp.ndim(lo) == 0 and jnp.ndim(hi) == 0 and jnp.ndim(depth) > 0:
        return _elementwise(
            lambda d: bracketed_root(lambda a: profile.g(a) - d, lo, hi, steps=80), depth
        )
    return bracketed_root(lambda a: profile.g(a) - depth, lo, hi, steps=80)


def numerical_critical_radius(profile, c, k):
    r"""Root of $a g'(a) = k c \sqrt a$ in log-radius on $[10^{-12}, 1]$ of the profile's
    size (the edge of the shape when the minimum lies beyond it)."""
    hi = upper_radius(profile)
    lo = hi * 1e-12

    def resid(log_a):
        a = jnp.exp(log_a)
        return a * profile.dg(a) - k * c * jnp.sqrt(a)

    log_a = bracketed_root(resid, jnp.log(lo), jnp.log(hi), steps=80)
    # no sign change at the top: the minimum sits at the edge of the shape
    return jnp.where(resid(jnp.log(hi)) < 0, hi, jnp.exp(log_a))


def numerical_front_radius(profile, m, c, lo, hi=None):
    r"""Stable root of $g(a) - c\sqrt a = m$ on `[lo, hi]` (`lo` the fold radius); with
    `hi=None` the upper bracket is the first of $\mathrm{lo}\cdot 2^k$ (capped at the
    profile's size) with $h \ge m$."""
    top = upper_radius(profile)

    def front(a):
        return front_displacement(profile, a, c)

    def one(mm):
        if hi is None:
            cand = jnp.minimum(lo * 2.0 ** jnp.arange(1, 64, dtype=jnp.result_type(lo)), top)
            ok = front(cand) >= mm
            upper = jnp.where(jnp.any(ok), cand[jnp.argmax(ok)], top)
        else:
            upper = hi
        return bracketed_root(lambda a: front(a) - mm, lo, upper, steps=64)

    return _elementwise(one, m)


def numerical_stationary_radius(profile, q, lo, hi):
    r"""Solution of $\sqrt x\,g'(x) = q$ in `[lo, hi]` (an end where there is no sign
    change)."""

    def h(x):
        return jnp.sqrt(x) * profile.dg(x) - q

    root = bracketed_root(h, lo, hi, steps=48)
    return jnp.where(h(hi) <= 0, hi, jnp.where(h(lo) >= 0, lo, root))


# --------------------------------------------------------------------------------------
# Base classes
# --------------------------------------------------------------------------------------


class AbstractProfile(eqx.Module):
    """Base class of all axisymmetric profiles. See the module docstring for the interface."""

    @float64_scope  # (a table's checks compute with its float64 arrays, whatever x64 is)
    def __check_init__(self):
        for constraint in self.domain():
            constraint.check()

    def __repr__(self) -> str:
        """``Parabola(R=1e-05)``: the values (see `module_repr`)."""
        return module_repr(self)

    @abc.abstractmethod
    def domain(self) -> tuple[Constraint, ...]:
        """The profile's parameters and their allowed ranges."""

    @abc.abstractmethod
    def shape(self, r: Float[ArrayLike, "..."]) -> Float[Array, "..."]:
        """The 3D gap $f(r)$ [m] at radius `r` [m]."""

    @abc.abstractmethod
    def g(self, x: Float[ArrayLike, "..."]) -> Float[Array, "..."]:
        """The MDR plane profile $g(x)$ [m] at `x` [m]; even in `x`."""

    @abc.abstractmethod
    def dg(self, x: Float[ArrayLike, "..."]) -> Float[Array, "..."]:
        """The slope $g'(x)$ [1] for $x \\ge 0$."""

    @abc.abstractmethod
    def integral_g(self, a: Float[ArrayLike, "..."]) -> Float[Array, "..."]:
        r"""$\int_0^a g(x)\,\mathrm{d}x$ [m²] for contact radius `a` [m]."""

    @property
    @abc.abstractmethod
    def max_radius(self) -> Array:
        """Largest contact radius [m] the profile admits (`inf` unless bounded)."""

    @property
    def valid_radius(self) -> Array:
        """Largest contact radius [m] the profile describes: `max_radius`, and for a profile
        standing for a sphere its radius (`Parabola`: `R`; no sphere contact reaches beyond
        it). The entry functions refuse (eagerly) or flag (`RESULTS.beyond_profile`) a
        contact radius beyond it."""
        return self.max_radius

    @abc.abstractmethod
    def contact_radius(self, depth, *, lo=None, hi=None) -> Array:
        r"""The non-adhesive MDR contact radius $a$ with $g(a) = d$ [m] for `depth` $d$ [m]
        (any shape). `lo`, `hi`: a bracket for profiles without a closed form."""

    @abc.abstractmethod
    def critical_radius(self, c, k) -> Array:
        r"""The root of $a\,g'(a) = k\,c\sqrt a$ [m] ($c$ [m^(1/2)], $k$ = 1/2 or 3/2); the
        edge of a bounded shape when the root lies beyond it."""

    @abc.abstractmethod
    def front_radius(self, m, c, lo, hi=None) -> Array:
        r"""The stable root $a \ge$ `lo` of $g(a) - c\sqrt a = m$ [m] (`m` any shape; `lo`
        the fold radius, `hi` an upper bracket or None)."""

    @abc.abstractmethod
    def stationary_radius(self, q, lo, hi) -> Array:
        r"""The solution of $\sqrt x\,g'(x) = q$ in `[lo, hi]` [m] (not differentiated)."""

    @abc.abstractmethod
    def touch_coordinate(self) -> TouchCoordinate:
        """The coordinate of the foundation grid of `simulate` (see `TouchCoordinate`)."""

    def zero_force_radius(self, c, lo, hi) -> Array:
        r"""The radius $a_z$ [m] in `[lo, hi]` where the force on the detachment front
        vanishes: $a\,h(a) = I(a)$ with $h(a) = g(a) - c\sqrt a$, i.e.
        $\int_0^a x\,g'(x)\,\mathrm{d}x = c\,a^{3/2}$ ($c$ [m^(1/2)]). A bracketed root
        (`lo` or `hi` without a sign change on the bracket); closed forms override it."""

        def force(a):
            return a * front_displacement(self, a, c) - self.integral_g(a)

        return bracketed_root(force, lo, hi)


class AbstractCurvedProfile(AbstractProfile):
    """A profile with $g$ increasing from $g(0) = 0$ (every shape but the flat punch)."""

    def touch_coordinate(self) -> TouchCoordinate:
        return GapCoordinate(self)


class AbstractPowerLawProfile(AbstractCurvedProfile):
    r"""A profile with $g(x) = K|x|^n$, $n > 1/2$: closed forms for the radii."""

    @abc.abstractmethod
    def power_law(self) -> tuple[Array, Array]:
        """`(K, n)` with $g(x) = K|x|^n$."""

    @property
    def max_radius(self):
        return jnp.full((), jnp.inf, dtype=jnp.result_type(*self.power_law()))

    def contact_radius(self, depth, *, lo=None, hi=None):
        K, n = self.power_law()
        return (jnp.maximum(as_float(depth), 0.0) / K) ** (1.0 / n)

    def critical_radius(self, c, k):
        K, n = self.power_law()
        return (k * c / (n * K)) ** (1.0 / (n - 0.5))

    def stationary_radius(self, q, lo, hi):
        K, n = lax.stop_gradient(self.power_law())
        return (q / (n * K)) ** (1.0 / (n - 0.5))

    def zero_force_radius(self, c, lo, hi):
        # int_0^a x g' dx = K n a^(n+1) / (n+1) = c a^(3/2): a^(n-1/2) = (n+1) c / (n K)
        _, n = self.power_law()
        return jnp.clip(self.critical_radius(c, n + 1.0), lo, hi)


# --------------------------------------------------------------------------------------
# Closed-form fronts of the parabola (Ferrari) and the cone (quadratic)
# --------------------------------------------------------------------------------------


def _rcbrt_positive(y):
    r"""$y^{-1/3}$ for positive, normal `y` (float32 or float64), to a few ulp.

    XLA's `cbrt` on the CPU is a scalar library call (about ten times the cost of `exp`)
    and dominated `retract`; and divisions or square roots whose results are used more than
    once stop XLA from fusing the element-wise chain, which then makes one pass over memory
    per intermediate. This uses multiplications only: the exponent divided by three on the
    bit pattern (shifts; initial relative error below 3.5 %), then four Newton steps
    $r \leftarrow r\,(4 - y r^3)/3$ (error $\to 2e^2$: 3e-2, 2e-3, 1e-5, 2e-10, round-off).
    Only for arguments whose cube stays in range (here $y \ge 1/16$).
    """
    y = jnp.asarray(y)
    if y.dtype == jnp.float64:
        itype, magic = jnp.int64, 0x553EF00000000000
    elif y.dtype == jnp.float32:
        itype, magic = jnp.int32, 0x54A23400
    else:
        return 1.0 / jnp.cbrt(y)
    bits = jax.lax.bitcast_convert_type(y, itype)
    # bits // 3 by shifts (bits >= 0): 1/3 = 0.010101..., exact to far below the guess error
    third = (bits >> 2) + (bits >> 4)
    for shift in (4, 8, 16, 32)[: 4 if itype == jnp.int64 else 3]:
        third = third + (third >> shift)
    r = jax.lax.bitcast_convert_type(jnp.asarray(magic, itype) - third, y.dtype)
    for _ in range(4):
        r = r * (4.0 - y * (r * r * r)) * (1.0 / 3.0)
    return r


@jax.custom_jvp
def parabola_stable_radius(m, c, R):
    r"""The stable root $a$ [m] of the paraboloid's front $a^2/R - c\sqrt a = m$ in closed
    form (Ferrari; `Parabola.front_radius`, and the start of the exact sphere's), any
    broadcast shapes; an `m` below the front's minimum gives the fold radius."""
    # Nondimensionalise a = lam^2 s^2 with lam^3 = c R: s^4 - s = mu = R m / lam^4.
    lam = jnp.cbrt(c * R)
    mu = R * m / lam**4
    mu_fold = -0.75 * 4.0 ** (-1.0 / 3.0)
    mu = jnp.maximum(mu, mu_fold)
    # resolvent cubic y^3 + mu y - 1/8 = 0 has one real (positive) root for mu >= mu_fold.
    # Cardano: y = u + v, u = z^(1/3), v = -mu / (3 u), z = 1/16 + sqrt(disc); u + v cancels
    # for large mu, so use y = (u^3 + v^3) / (u^2 - u v + v^2) = 1 / (8 D) with
    # D = u^2 + mu/3 + v^2 > 0. With rs = D^(-1/2): sqrt(2 y) = rs / 2, 2 / sqrt(2 y) = 4 D rs.
    # Multiplications, one cube-root reciprocal and square roots only, so that XLA fuses the
    # whole chain into one pass.
    # sqrt(disc) = sqrt(1/256 + mu^3/27); for mu > 1 as q sqrt(1 + 27/(256 mu^3)) with
    # q = mu^(3/2)/sqrt(27) and t = mu^(-1/2), so that mu^3 cannot overflow (float32: mu is
    # up to (a/a_fold)^2, 1e12 and more for weak adhesion)
    t = jax.lax.rsqrt(jnp.maximum(mu, 1.0))
    q = mu * (mu * t) * float(1.0 / np.sqrt(27.0))
    t3 = t * t * t
    sqrt_disc = jnp.where(
        mu > 1.0,
        q * jnp.sqrt(1.0 + (27.0 / 256.0) * (t3 * t3)),
        jnp.sqrt(jnp.maximum(1.0 / 256.0 + jnp.minimum(mu, 1.0) ** 3 / 27.0, 0.0)),
    )
    z = 1.0 / 16.0 + sqrt_disc
    r = _rcbrt_positive(z)
    u = z * r * r
    v = mu * r * (-1.0 / 3.0)
    D = u * u + mu * (1.0 / 3.0) + v * v
    rs = jax.lax.rsqrt(D)
    s = 0.5 * (0.5 * rs + jnp.sqrt(jnp.maximum(4.0 * D * rs - 0.25 * rs * rs, 0.0)))
    # one Newton polish away from the double root at the fold
    slope = 4.0 * s**3 - 1.0
    s = jnp.where(slope > 1e-3, s - (s**4 - s - mu) / jnp.where(slope > 1e-3, slope, 1.0), s)
    return (lam * s) ** 2


@parabola_stable_radius.defjvp
def _parabola_stable_radius_jvp(primals, tangents):
    m, c, R = primals
    dm, dc, dR = tangents
    a = parabola_stable_radius(m, c, R)
    sa = jnp.sqrt(a)
    dh_da = 2 * a / R - 0.5 * c / sa
    # h(a; c, R) = a^2/R - c sqrt(a) = m  =>  h_a da = dm + sqrt(a) dc + a^2/R^2 dR
    da = (dm + sa * dc + a**2 / R**2 * dR) / dh_da
    return a, da


# --------------------------------------------------------------------------------------
# Profiles
# --------------------------------------------------------------------------------------


#: Newton steps of a power law's detachment front (`fold_root`): over n in [0.55, 6], c over
#: nine decades and roots from 1e-12 of the fold to 1e6 times it, 10 steps agree with Brent's
#: method to the root's conditioning (`tests/test_profiles.py`); 8 miss it 1e9-fold at
#: n = 0.55
_POWER_LAW_FRONT_STEPS = 10


class PowerLaw(AbstractPowerLawProfile):
    r"""Power-law profile $f(r) = c\,r^n$.

    **Arguments:**

    - `c`: prefactor [m^(1-n)], > 0.
    - `n`: exponent [1], > 1/2 (n = 2: paraboloid, n = 1: cone). For $n \le 1/2$ the
      adhesive front $g(a) - c\sqrt a$ has no fold (the contact never jumps off).

    MDR profile: $g(x) = \kappa(n)\,c\,|x|^n$ with `power_law_factor`.
    """

    c: Float[Array, ""] = eqx.field(converter=float_field("c", "m^(1-n)"))
    n: Float[Array, ""] = eqx.field(converter=float_field("n", "1"))

    def domain(self):
        return (Constraint("c", self.c, "m^(1-n)"), Constraint("n", self.n, "1", lo=0.5))

    def power_law(self):
        return power_law_factor(self.n) * self.c, self.n

    @guarded
    def shape(self, r):
        return self.c * jnp.abs(jnp.asarray(r)) ** self.n

    @guarded
    def g(self, x):
        K, n = self.power_law()
        return K * jnp.abs(jnp.asarray(x)) ** n

    @guarded
    def dg(self, x):
        K, n = self.power_law()
        return n * K * jnp.abs(jnp.asarray(x)) ** (n - 1)

    @guarded
    def integral_g(self, a):
        K, n = self.power_law()
        return K * jnp.asarray(a) ** (n + 1) / (n + 1)

    def front_radius(self, m, c, lo, hi=None):
        # `fold_root` from a radius at or right of the root: where K a^n >= 2 max(m, 0) and
        # K a^n >= 2 c sqrt(a), h(a) = K a^n - c sqrt(a) >= K a^n / 2 >= m
        K, n = lax.stop_gradient(self.power_law())
        cs = lax.stop_gradient(as_float(c))

        def start(mm):
            return jnp.maximum((2.0 * jnp.maximum(mm, 0.0) / K) ** (1.0 / n),
                               (2.0 * cs / K) ** (1.0 / (n - 0.5)))

        return fold_front_radius(self, m, c, lo, jnp.inf if hi is None else hi, start,
                                 steps=_POWER_LAW_FRONT_STEPS)


class Parabola(AbstractPowerLawProfile):
    r"""Paraboloid $f(r) = r^2/(2R)$ (sphere of radius $R$ in the small-slope limit).

    **Arguments:**

    - `R`: radius of curvature [m], > 0.

    MDR profile: $g(x) = x^2/R$, $\int_0^a g = a^3/(3R)$. The front is solved in closed
    form (Ferrari, with a cancellation-free Cardano step).
    """

    R: Float[Array, ""] = eqx.field(converter=float_field("R", "m"))

    def domain(self):
        return (Constraint("R", self.R, "m", kind="length"),)

    def power_law(self):
        return 1.0 / self.R, 2.0

    @guarded
    def shape(self, r):
        return jnp.asarray(r) ** 2 / (2 * self.R)

    @guarded
    def g(self, x):
        return jnp.asarray(x) ** 2 / self.R

    @guarded
    def dg(self, x):
        return 2 * jnp.abs(jnp.asarray(x)) / self.R

    @guarded
    def integral_g(self, a):
        return jnp.asarray(a) ** 3 / (3 * self.R)

    @property
    def valid_radius(self):
        # the paraboloid stands for a sphere of radius R (its error grows as (a/R)^2)
        return self.R

    def front_radius(self, m, c, lo, hi=None):
        return parabola_stable_radius(m, c, self.R)


class Cone(AbstractPowerLawProfile):
    r"""Cone with half-opening angle $\alpha$ (between the axis and the flank).

    $f(r) = r\cot\alpha$, so the flank inclination is $\theta = \pi/2 - \alpha$ and
    $g(x) = \frac{\pi}{2}\,|x|\cot\alpha$.

    **Arguments:**

    - `half_angle`: $\alpha$ [rad], in (0, π/2).
    """

    half_angle: Float[Array, ""] = eqx.field(converter=float_field("half_angle", "rad"))

    def domain(self):
        return (Constraint("half_angle", self.half_angle, "rad", hi=math.pi / 2),)

    def _slope(self):
        return 1.0 / jnp.tan(self.half_angle)

    def power_law(self):
        return 0.5 * jnp.pi * self._slope(), 1.0

    @guarded
    def shape(self, r):
        return jnp.abs(jnp.asarray(r)) * self._slope()

    @guarded
    def g(self, x):
        return 0.5 * jnp.pi * jnp.abs(jnp.asarray(x)) * self._slope()

    @guarded
    def dg(self, x):
        return jnp.zeros_like(as_float(x)) + 0.5 * jnp.pi * self._slope()

    @guarded
    def integral_g(self, a):
        return 0.25 * jnp.pi * self._slope() * jnp.asarray(a) ** 2

    def front_radius(self, m, c, lo, hi=None):
        s = 0.5 * jnp.pi * self._slope()
        # s sigma^2 - c sigma - m = 0, sigma = sqrt(a)
        sigma = (c + jnp.sqrt(jnp.maximum(c**2 + 4 * s * m, 0.0))) / (2 * s)
        return sigma**2


class FlatPunch(AbstractProfile):
    r"""Flat-ended cylindrical punch of radius $a_0$.

    $g(x) = 0$ for $|x| \le a_0$; the contact radius cannot exceed $a_0$
    (`max_radius`). Outside the punch $g$ is $+\infty$.

    **Arguments:**

    - `radius`: punch radius $a_0$ [m], > 0.
    """

    radius: Float[Array, ""] = eqx.field(converter=float_field("radius", "m"))

    def domain(self):
        return (Constraint("radius", self.radius, "m", kind="length"),)

    @guarded
    def shape(self, r):
        r = jnp.abs(as_float(r))
        return jnp.where(r <= self.radius, 0.0, jnp.inf)

    @guarded
    def g(self, x):
        return self.shape(x)

    @guarded
    def dg(self, x):
        return jnp.zeros_like(as_float(x))

    @guarded
    def integral_g(self, a):
        return jnp.zeros_like(as_float(a))

    @property
    @guarded
    def max_radius(self):
        return self.radius

    def contact_radius(self, depth, *, lo=None, hi=None):
        return self.radius + jnp.zeros_like(as_float(depth))

    def critical_radius(self, c, k):
        return self.radius + 0.0 * c

    def front_radius(self, m, c, lo, hi=None):
        # the front cannot recede from the edge of the punch: attached means a = a0
        return self.radius + jnp.zeros_like(as_float(m))

    def stationary_radius(self, q, lo, hi):
        # g' = 0 on the punch: sqrt(x) g'(x) < q everywhere, the end of the bracket
        return hi + jnp.zeros_like(q)

    def touch_coordinate(self) -> TouchCoordinate:
        return PositionCoordinate(self.radius)
