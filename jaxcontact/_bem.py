r"""Boundary Element Method (BEM) for adhesive viscoelastic contacts (paper section 4).

The surface of the half-space is cut into $n\times n$ square cells of side $\Delta$ (a
`BEMGrid` of side `extent` $= n\Delta$ centred on the indenter axis). Each cell carries a
uniform pressure $p_{ij}$ (compressive positive, adhesive/tensile negative).

**Elastic kernel.** A uniform unit pressure on the rectangle $|x|\le a$, $|y|\le b$ of a
half-space with $E^* = 1$ displaces the surface by Love's closed form
$$u(x,y) = \frac{1}{\pi}\iint\frac{\mathrm{d}x'\mathrm{d}y'}{|\mathbf r-\mathbf r'|}
 = \frac1\pi\sum_{\pm\pm}\pm F(x\mp a, y\mp b),\quad
 F(X,Y) = \operatorname{sgn}(XY)\Big(|X|\operatorname{asinh}\tfrac{|Y|}{|X|}
 + |Y|\operatorname{asinh}\tfrac{|X|}{|Y|}\Big)$$
(`love_displacement`). The mean of this displacement over the loaded square of side
$\Delta$ is $2\chi\Delta$ with the paper's $\chi$ (`BEM_CHI`, eq. 13): the released energy
$\tfrac12\sigma\bar u\Delta^2 = \chi\sigma^2\Delta^3/E^*$ (eq. 12). The displacement at the
cell centres is a discrete convolution with the values of $u$ at the cell-centre offsets; it
is evaluated by FFT with zero padding to $2n\times2n$ (a non-periodic half-space), with the
kernel transformed once per grid.

**Constrained conjugate gradients.** For a rigid indenter of height map $h_{ij}$ (lowest
point 0) at indentation $d$ the gap is $g = h - d + u \ge 0$. With $u = \mathcal H q$ and
$q = p/E^*$ the contact problem is the bound-constrained quadratic programme
$\min_q \tfrac12 q^\top\mathcal Hq - q^\top(d-h)$ with $q_{ij}\ge 0$ on free cells and no
bound on *attached* cells (bonded, $g = 0$). It is solved by the Polonsky-Keer constrained
conjugate-gradient method in displacement control (fixed-shape masks in a
`lax.while_loop`): conjugate directions on the active set, projection onto the bound, and a
restart of the conjugacy when free cells that penetrate enter the active set.

**Force control and compliant loading.** With a prescribed force $F$ (dead load) or a
spring $k$ between the drive $z$ and the indenter ($F = k(z - d)$) the indentation is an
unknown: at a fixed attached set, $d$ solves $F(d) + kd = $ ($F$ or $kz$) by Newton's method
with the exact slope $\partial F/\partial d = E^*\Delta^2\sum_A\mathcal H_A^{-1}1$ (one
CG on the fixed active set $A$). $F(d)$ is nondecreasing and convex at a fixed attached set
(pressing deeper raises every pressure of $A$ and only adds cells), so the iteration
converges monotonically in a few steps; on a fixed active set $F$ is linear in $d$ and one
step is exact. Each round of the cell rule below solves this at the current set;
under a dead load the cascade that releases every cell is the jump-off (no equilibrium
remains). Displacement control compiles without this loop. The non-adhesive
`bem_contact(force=...)` uses the original Polonsky-Keer force-controlled iteration.

**Adhesion: the paper's cell rule.** A cell becomes *attached* when it touches (its solved
pressure is compressive while it is free). An attached cell is bonded until its stress
reaches $\sigma_c = -\sqrt{E^*_\mathrm{glass}\Delta\gamma/(\chi\Delta)}$
(`bem_critical_stress`, eq. 15, with the glass modulus $E^*_\mathrm{glass} = 4G_0$);
then it is released (stress set to zero; it may touch again later). Releasing one cell
loads its neighbours, so within every load step the solution is iterated to a consistent
set: solve with the current set; release *all* attached cells whose stress is below
$\sigma_c$ and attach *all* free cells that touch, simultaneously; solve again; repeat until
the set does not change. The simultaneous update treats all cells alike, so the result has
the symmetry of the problem (a sphere on a centred grid gives the same answer under the
grid's rotations and reflections); the jump-off of a whole contact is such a cascade within
one step.

**Viscoelasticity (creep form).** With the rheology in creep form (spring $G_0$ in series
with Kelvin elements $(G_k,\eta_k)$, `CreepChain`), the surface displacement is
$u = \tfrac14\big[w/G_0 + \sum_k v_k\big]$, where $w = \mathcal H p$ is the displacement of
a unit-modulus half-space and the Kelvin states obey $\eta_k\dot v_k + G_k v_k = w$ on every
cell. For $w$ linear in time over a step $h$ the update is exact:
$v_k^{1} = e_k v_k^0 + [w^1(1-\varphi_k) + w^0(\varphi_k - e_k)]/G_k$ with
$e_k = e^{-h/\theta_k}$, $\varphi_k = \theta_k(1-e_k)/h$, $\theta_k = \eta_k/G_k$. Hence
$u^1 = \tfrac14[C\,w^1 + b]$ with the step compliance $C = 1/G_0 + \sum_k(1-\varphi_k)/G_k$
and a known field $b$: every step is one elastic-like contact problem with
$E^* = 4/C$ and the indenter shifted by $b/4$. The detachment criterion always uses the glass
modulus (only the instant spring's energy is released). Two starts: a virgin half-space
(the first sample is applied instantly) or a relaxed start (`relaxed_depth`: held at $d_0$
until fully relaxed, the non-adhesive contact with the relaxed modulus $G_\infty$, every
Kelvin state at $v_k = w/G_k$), as in `retract`.

**Jump-off.** The contact jumps off where the whole contact detaches in one cascade of
the cell rule. The sample interval in which this happens is bisected (re-solving from the
state at its start with the linear input), so the jump-off force, time and displacement are
resolved finer than the sampling. The relaxed start, the samples and the bisection steps
are the iterations of one `lax.scan`, so the solver is compiled once.

**Accuracy** (`benchmarks/bench_bem.py`, results in `benchmarks/results/bem.md`). The cell
criterion is a discrete energy balance, so the error is set by the number of cells across
the contact at pull-off. For an elastic sphere the largest tensile force (displacement
control) and the dead-load pull-off (force control) overshoot JKR's
$-\tfrac32\pi\Delta\gamma R$ with an error of first order in $\Delta$; the jump-off force
in displacement control is close to $-\tfrac56\pi\Delta\gamma R$ but not monotonic in
$\Delta$ (it depends on how the last rings of cells fall on the grid). Against the MDR
models (relaxed start, approach-hold-lift) the force curve, the largest tensile force and
the jump-off time converge at first order as well.

**Derivatives.** The solvers are `lax.while_loop`s: forward-mode differentiation
(`jax.jvp`, `jax.jacfwd`) works through them (the derivative of the converged,
piecewise-smooth discrete solution at a fixed attached set); reverse mode (`jax.grad`) is
not supported.

Conventions: SI units; indentation positive into the sample; force positive when compressive
and negative when adhesive; shear moduli of an incompressible half-space ($E^* = 4G$).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from . import _sharding
from ._criteria import cell_critical_stress
from ._profiles import AbstractProfile
from ._rheology import AbstractRheology
from ._solution import RESULTS
from ._solvers import as_float, float64_scope, floats_to_arrays, safe_div
from ._validate import (
    check_finite,
    check_plausible,
    check_positive,
    check_times,
    error_if,
    is_concrete,
)

__all__ = [
    "BEMGrid",
    "BEMSolution",
    "bem_contact",
    "bem_heights",
    "bem_simulate",
    "ellipsoid_heights",
    "love_displacement",
    "pyramid_heights",
    "self_affine_heights",
    "tilted_flat_heights",
]


# --------------------------------------------------------------------------------------
# grid and kernel
# --------------------------------------------------------------------------------------


class BEMGrid(eqx.Module):
    r"""A square grid of $n\times n$ cells covering $[-L/2, L/2]^2$, centred on the axis.

    **Arguments:**

    - `cells`: number of cells $n$ per side (static), >= 2. Even $n$ puts the axis on a cell
      corner, so an axisymmetric problem keeps the grid's full symmetry.
    - `extent`: side $L$ [m] of the simulated square, > 0; the cell side is
      $\Delta = L/n$. The half-space outside the square is unloaded (not periodic).
    """

    cells: int = eqx.field(static=True)
    # an array (never a Python float): compiled programs are shared by all extents
    extent: Float[Array, ""] = eqx.field(converter=lambda x: floats_to_arrays(as_float(x)))

    def __check_init__(self):
        if int(self.cells) < 2:
            raise ValueError(f"`cells` must be an integer >= 2; got {self.cells}.")
        check_positive("extent", self.extent, "m")

    @property
    def cell_size(self) -> Array:
        r"""Cell side $\Delta = L/n$ [m]."""
        return self.extent / self.cells

    def coordinates(self) -> tuple[Array, Array]:
        """Cell-centre coordinates `(x, y)` [m], each of shape `(n, n)` (`x` along axis 0)."""
        c = (jnp.arange(self.cells) + 0.5 - 0.5 * self.cells) * self.cell_size
        return jnp.meshgrid(c, c, indexing="ij")


def _primitive(X, Y):
    ax, ay = jnp.abs(X), jnp.abs(Y)
    safe_x = jnp.where(ax > 0, ax, 1.0)
    safe_y = jnp.where(ay > 0, ay, 1.0)
    val = jnp.where(ax > 0, ax * jnp.arcsinh(ay / safe_x), 0.0) + jnp.where(
        ay > 0, ay * jnp.arcsinh(ax / safe_y), 0.0
    )
    return jnp.sign(X) * jnp.sign(Y) * val


@float64_scope
def love_displacement(
    x: Float[ArrayLike, "..."],
    y: Float[ArrayLike, "..."],
    half_width: Float[ArrayLike, ""],
    half_height: Float[ArrayLike, ""],
) -> Float[Array, "..."]:
    r"""Surface displacement under a uniformly loaded rectangle (Love), per unit $p/E^*$ [m].

    $$u(x, y) = \frac{1}{\pi}\int_{-a}^{a}\int_{-b}^{b}
      \frac{\mathrm{d}x'\,\mathrm{d}y'}{\sqrt{(x-x')^2 + (y-y')^2}},$$
    the displacement (positive into the half-space) of a half-space with $E^* = 1$ under a
    unit pressure on $|x'|\le a$, $|y'|\le b$; multiply by $p/E^*$ for pressure $p$ [Pa].

    **Arguments:**

    - `x`, `y`: surface points [m] (broadcast against each other).
    - `half_width`, `half_height`: $a$, $b$ [m], > 0.
    """
    x, y = as_float(x), as_float(y)
    a, b = as_float(half_width), as_float(half_height)
    total = (
        _primitive(x + a, y + b)
        - _primitive(x - a, y + b)
        - _primitive(x + a, y - b)
        + _primitive(x - a, y - b)
    )
    return total / jnp.pi


def _kernel_hat(n: int, delta) -> Array:
    """rfft2 of the unit-modulus influence of one cell on the zero-padded (2n)^2 grid."""
    k = jnp.arange(2 * n)
    off = jnp.where(k < n, k, k - 2 * n).astype(float) * delta
    ox, oy = jnp.meshgrid(off, off, indexing="ij")
    kern = love_displacement(ox, oy, 0.5 * delta, 0.5 * delta)
    # the offset +-n never pairs two cells of the n x n grid: zero it (not periodic)
    mask = (k == n)
    kern = jnp.where(mask[:, None] | mask[None, :], 0.0, kern)
    return jnp.fft.rfft2(kern)


def _convolve(khat: Array, q: Array) -> Array:
    n = q.shape[0]
    qp = jnp.zeros((2 * n, 2 * n), q.dtype).at[:n, :n].set(q)
    return jnp.fft.irfft2(jnp.fft.rfft2(qp) * khat, s=(2 * n, 2 * n))[:n, :n]


# --------------------------------------------------------------------------------------
# constrained conjugate gradients and the cell rule
# --------------------------------------------------------------------------------------


def _pk_solve(khat, target, bonded, q0, k00, tol, max_iter, frozen=None):
    r"""Polonsky-Keer CG, displacement control: gap $g = \mathcal H q - t$ with `t` the
    `target`; `bonded` cells carry any $q$ ($g = 0$), `frozen` cells (optional) are held at
    $q = 0$, and $q \ge 0$ on the other (free) cells. With every cell bonded or frozen this
    is a plain CG on the bonded set. Returns `(q, Hq, iterations, converged)`."""
    dtype = target.dtype
    free = ~bonded if frozen is None else ~bonded & ~frozen
    q = jnp.where(bonded, q0, jnp.maximum(q0, 0.0))
    if frozen is not None:
        q = jnp.where(frozen, 0.0, q)
    g = _convolve(khat, q) - target
    # seed penetrating free cells so that the active set is never empty when it must not be
    seed = free & (q <= 0) & (g < 0)
    q = jnp.where(seed, -g / k00, q)

    def cond(c):
        return (c[5] < max_iter) & (c[6] > tol)

    def body(c):
        q, hq, t_dir, g_old, delta, it, _ = c
        g = hq - target
        act = bonded | (q > 0)
        gg = jnp.sum(jnp.where(act, g * g, 0.0))
        t_dir = jnp.where(act, g + delta * safe_div(gg, g_old) * t_dir, 0.0)
        r = _convolve(khat, t_dir)
        num = jnp.sum(jnp.where(act, g * t_dir, 0.0))
        den = jnp.sum(jnp.where(act, r * t_dir, 0.0))
        tau = safe_div(num, jnp.where(den > 0, den, 0.0))
        q_lin = q - tau * t_dir
        q_new = jnp.where(bonded, q_lin, jnp.maximum(q_lin, 0.0))
        nol = free & (q_new <= 0) & (g < 0)
        any_nol = jnp.any(nol)
        q_new = jnp.where(nol, q_new - tau * g, q_new)
        # H q is updated linearly (H q - tau r); one more convolution only when the
        # projection or the re-entry of penetrating cells changed q off that line
        fix = q_new - q_lin
        hq = _sharding.cond(jnp.any(fix != 0), lambda: hq - tau * r + _convolve(khat, fix),
                          lambda: hq - tau * r)
        change = jnp.sum(jnp.abs(q_new - q))
        err = safe_div(change, jnp.sum(jnp.abs(q_new)), change)
        err = jnp.where(any_nol, jnp.maximum(err, 2 * tol), err)
        delta = jnp.where(any_nol, 0.0, 1.0).astype(dtype)
        return q_new, hq, t_dir, gg, delta, it + 1, err

    init = (q, _convolve(khat, q), jnp.zeros_like(q), jnp.zeros((), dtype),
            jnp.zeros((), dtype), 0, jnp.asarray(jnp.inf, dtype))
    q, _, _, _, _, it, err = _sharding.while_loop(cond, body, init)
    return q, _convolve(khat, q), it, err <= tol


def _pk_force(khat, h, total, tol, max_iter):
    r"""Polonsky-Keer CG in force control (the original algorithm): $q \ge 0$,
    $\sum q = $ `total`, gap $\mathcal Hq + h - d$ zero on the contact with the rigid
    indentation $d$ found as the mean of $\mathcal Hq + h$ there. Returns `(q, d, converged)`."""
    dtype = h.dtype
    q = jnp.full(h.shape, total / h.size, dtype)

    def mean_on(x, act):
        return safe_div(jnp.sum(jnp.where(act, x, 0.0)), jnp.sum(act))

    def cond(c):
        return (c[5] < max_iter) & (c[6] > tol)

    def body(c):
        q, hq, t_dir, g_old, delta, it, _ = c
        act = q > 0
        g = hq + h
        g = g - mean_on(g, act)
        gg = jnp.sum(jnp.where(act, g * g, 0.0))
        t_dir = jnp.where(act, g + delta * safe_div(gg, g_old) * t_dir, 0.0)
        r_raw = _convolve(khat, t_dir)
        r = r_raw - mean_on(r_raw, act)
        num = jnp.sum(jnp.where(act, g * t_dir, 0.0))
        den = jnp.sum(jnp.where(act, r * t_dir, 0.0))
        tau = safe_div(num, jnp.where(den > 0, den, 0.0))
        q_lin = q - tau * t_dir
        q_new = jnp.maximum(q_lin, 0.0)
        nol = (q_new <= 0) & (g < 0)
        any_nol = jnp.any(nol)
        q_new = jnp.where(nol, q_new - tau * g, q_new)
        fix = q_new - q_lin  # H q follows linearly, plus the projection's correction
        hq = _sharding.cond(jnp.any(fix != 0), lambda: hq - tau * r_raw + _convolve(khat, fix),
                          lambda: hq - tau * r_raw)
        factor = total / jnp.sum(q_new)
        q_new, hq = q_new * factor, hq * factor
        err = jnp.sum(jnp.abs(q_new - q)) / total
        err = jnp.where(any_nol, jnp.maximum(err, 2 * tol), err)
        return (q_new, hq, t_dir, gg, jnp.where(any_nol, 0.0, 1.0).astype(dtype), it + 1,
                err)

    init = (q, _convolve(khat, q), jnp.zeros_like(q), jnp.zeros((), dtype),
            jnp.zeros((), dtype), 0, jnp.asarray(jnp.inf, dtype))
    q, _, _, _, _, _, err = _sharding.while_loop(cond, body, init)
    act = q > 0
    depth = mean_on(_convolve(khat, q) + h, act)
    return q, depth, err <= tol


class _Load(eqx.Module):
    """What fixes the indenter at one load step (dimensionless q-units, see `_equilibrium`).

    `fixed`: displacement control (the indentation is `depth`); otherwise the indentation
    solves $\\sum q + k d = $ `load` (force control: `spring` $k = 0$; compliant loading:
    $k > 0$ and `load` $= k z$)."""

    fixed: Array
    depth: Array
    load: Array
    spring: Array


class _Equilibrium(eqx.Module):
    q: Array
    hq: Array
    depth: Array
    slope: Array  # H_A s = k00 on the active set: dq/dd = s / k00
    cg_iterations: Array
    converged: Array
    exists: Array  # False: a tensile dead load and nothing in contact


def _equilibrium(khat, base, bonded, q0, s0, k00, load: _Load, tol, max_iter, max_newton):
    r"""Equilibrium at a fixed bonded set: $q$ = `_pk_solve` at the target $d - $ `base`.

    In displacement control $d$ is given. Otherwise $d$ solves $F(d) + k d = $ `load` with
    $F = \sum q$: at a fixed bonded set $F(d)$ is nondecreasing and convex (pressing deeper
    raises every pressure of the active set $A$, $\partial q/\partial d = \mathcal H_A^{-1}1
    > 0$, and only adds cells), so Newton's method with the exact slope
    $\sum_A \mathcal H_A^{-1} 1$ (one CG on the fixed set $A$) converges monotonically from
    the right and overshoots at most once from the left; on a fixed active set the force
    is linear in $d$ and the step is exact. Without any active cell and $k = 0$ the
    indenter is moved to first touch (then one cell's compliance `k00`, an overshoot);
    a tensile dead load then has no equilibrium (`exists` False). `max_newton = 0`
    (static) compiles displacement control alone.
    """
    if max_newton == 0:  # displacement control only (static): one solve
        q, hq, it, ok = _pk_solve(khat, load.depth - base, bonded, q0, k00, tol, max_iter)
        return _Equilibrium(q, hq, load.depth, s0, it, ok, jnp.asarray(True))
    d_touch = jnp.min(base)

    def cond(c):
        return ~c[8] & (c[9] < max_newton)

    def body(c):
        d_next, q_start, s, _, _, _, its, ok, _, k = c
        q, hq, it, conv = _pk_solve(khat, d_next - base, bonded, q_start, k00, tol, max_iter)
        force = jnp.sum(q)
        res = load.load - force - load.spring * d_next
        scale = jnp.sum(jnp.abs(q)) + jnp.abs(load.load) + load.spring * jnp.abs(d_next)
        act = bonded | (q > 0)
        empty = ~jnp.any(act)
        no_eq = empty & (load.spring == 0) & (load.load < 0)
        done = load.fixed | (jnp.abs(res) <= 1e2 * tol * scale) | no_eq

        def slope():
            s1, _, it1, ok1 = _pk_solve(khat, jnp.full_like(base, k00), act,
                                        jnp.where(act, s, 0.0), k00, tol, max_iter,
                                        frozen=~act)
            return s1, it1, ok1

        s, it_s, ok_s = _sharding.cond(done, lambda: (s, 0, jnp.asarray(True)), slope)
        stiffness = jnp.sum(s) / k00 + load.spring
        first_touch = jnp.where(load.load > 0, d_touch + load.load * k00, d_touch)
        d_new = jnp.where(stiffness > 0, d_next + safe_div(res, stiffness), first_touch)
        q_new = jnp.where(act, q + (d_new - d_next) * s / k00, q)
        return (jnp.where(done, d_next, d_new), jnp.where(done, q, q_new), s, q, hq, no_eq,
                its + it + it_s, ok & conv & ok_s, done, k + 1)

    init = (load.depth, q0, s0, q0, q0, jnp.asarray(False), 0, jnp.asarray(True),
            jnp.asarray(False), 0)
    d, _, s, q, hq, no_eq, its, ok, done, _ = _sharding.while_loop(cond, body, init)
    return _Equilibrium(q, hq, d, s, its, ok & done, ~no_eq)


class _Step(eqx.Module):
    eq: _Equilibrium
    attached: Array
    rounds: Array
    converged: Array


def _consistent(khat, base, attached, q0, s0, k00, q_crit, adhesive, load, tol, max_iter,
                max_rounds, max_newton):
    """Iterate the cell rule to a consistent attached set at one load step.

    `q_crit` is the critical stress over the step's effective modulus (stress rule
    p < sigma_c  <=>  q < q_crit). Non-adhesive (`adhesive=False`): no cell is ever attached.
    """
    if not adhesive:
        no = jnp.zeros_like(attached)
        eq = _equilibrium(khat, base, no, q0, s0, k00, load, tol, max_iter, max_newton)
        return _Step(eq, no, jnp.asarray(1), eq.converged)

    def cond(c):
        return c[3] & (c[2] < max_rounds)

    def body(c):
        eq, att, rounds, _ = c
        eq = _equilibrium(khat, base, att, eq.q, eq.slope, k00,
                          eqx.tree_at(lambda x: x.depth, load, eq.depth), tol, max_iter,
                          max_newton)
        release = att & (eq.q < q_crit)
        touch = (~att) & (eq.q > 0)
        new = (att & ~release) | touch
        changed = jnp.any(new != att)
        eq = eqx.tree_at(lambda x: (x.q, x.cg_iterations, x.converged), eq,
                         (jnp.where(release, 0.0, eq.q), c[0].cg_iterations + eq.cg_iterations,
                          c[0].converged & eq.converged))
        return eq, new, rounds + 1, changed

    z = jnp.zeros_like(q0)
    init = _Equilibrium(q0, z, load.depth, s0, jnp.asarray(0), jnp.asarray(True),
                        jnp.asarray(True))
    eq, att, rounds, changed = _sharding.while_loop(
        cond, body, (init, attached, jnp.asarray(0), jnp.asarray(True)))
    # the last solve used `att` before the update; if nothing changed it is consistent
    return _Step(eq, att, rounds, eq.converged & ~changed)


# --------------------------------------------------------------------------------------
# indenters
# --------------------------------------------------------------------------------------

_FAR = 1e3  # heights outside a punch: this many grid extents (never touched)


@float64_scope
def bem_heights(profile: AbstractProfile, grid: BEMGrid) -> Float[Array, "n n"]:
    r"""Height map [m] of an axisymmetric profile on the grid: $h_{ij} = f(r_{ij})$.

    Works with every `AbstractProfile` (`Sphere` the exact spherical cap, `Parabola` the
    sphere in the paraboloid approximation, `Cone`, `PowerLaw`, `FlatPunch`, `Tabulated`).
    Heights outside a flat punch or beyond a sphere's equator (infinite) are replaced by a
    large finite value so that the solver never touches them. A pyramid's true (not
    axisymmetric) height map is `pyramid_heights`.
    """
    x, y = grid.coordinates()
    h = profile.shape(jnp.sqrt(x * x + y * y))
    return jnp.where(jnp.isfinite(h), h, _FAR * as_float(grid.extent))


@float64_scope
def pyramid_heights(
    grid: BEMGrid, half_angle: float, sides: int = 4, angle: str = "face"
) -> Float[Array, "n n"]:
    r"""A regular 3- or 4-sided pyramid with its apex at the centre [m], lowest point 0.

    $h(x, y) = \cot\alpha\,\max_k (x\cos\theta_k + y\sin\theta_k)$ over the face normals
    $\theta_k = 2\pi k/n$, with $\alpha$ the half-angle [rad] between the axis and a face
    (`angle="face"`) or an edge (`angle="edge"`: $\tan\alpha_\mathrm{face} =
    \cos(\pi/n)\tan\alpha_\mathrm{edge}$). The axisymmetric models use its equivalent
    cone (`jaxcontact.pyramid`); this is the real shape for the BEM.
    """
    if sides not in (3, 4):
        raise ValueError(f"`sides` must be 3 or 4; got {sides!r}.")
    if angle not in ("face", "edge"):
        raise ValueError(f"`angle` must be 'face' or 'edge'; got {angle!r}.")
    check_positive("half_angle", half_angle, "rad", upper=float(np.pi / 2))
    tan_face = jnp.tan(as_float(half_angle))
    if angle == "edge":
        tan_face = tan_face * float(np.cos(np.pi / sides))
    x, y = grid.coordinates()
    theta = 2 * np.pi * np.arange(sides) / sides
    proj = jnp.stack([x * float(np.cos(t)) + y * float(np.sin(t)) for t in theta])
    return jnp.max(proj, axis=0) / tan_face


@float64_scope
def ellipsoid_heights(
    grid: BEMGrid, radius_x: Float[ArrayLike, ""], radius_y: Float[ArrayLike, ""]
) -> Float[Array, "n n"]:
    r"""Elliptic paraboloid $h = x^2/(2R_x) + y^2/(2R_y)$ [m] (principal radii $R_x, R_y$ [m],
    > 0), the ellipsoid near its apex."""
    check_positive("radius_x", radius_x, "m")
    check_positive("radius_y", radius_y, "m")
    x, y = grid.coordinates()
    return x * x / (2 * as_float(radius_x)) + y * y / (2 * as_float(radius_y))


@float64_scope
def tilted_flat_heights(
    grid: BEMGrid, radius: Float[ArrayLike, ""], angle: Float[ArrayLike, ""]
) -> Float[Array, "n n"]:
    r"""Flat cylindrical punch of radius $a_0$ [m] tilted by `angle` $\alpha$ [rad] in
    $[0, \pi/2)$ about the $y$ axis: $h = (x + a_0)\tan\alpha$ on $r \le a_0$ (lowest at
    $x = -a_0$), never touched outside."""
    check_positive("radius", radius, "m")
    check_positive("angle", angle, "rad", upper=float(np.pi / 2), allow_zero=True)
    x, y = grid.coordinates()
    a0 = as_float(radius)
    inside = x * x + y * y <= a0 * a0
    h = (x + a0) * jnp.tan(as_float(angle))
    h = jnp.where(inside, h, _FAR * as_float(grid.extent))
    return h - jnp.min(h)


@float64_scope
def self_affine_heights(
    grid: BEMGrid,
    *,
    hurst: float,
    rms_height: float,
    seed: int,
    short_wavelength: float | None = None,
    long_wavelength: float | None = None,
) -> Float[Array, "n n"]:
    r"""A random self-affine (fractal) rough surface on the grid [m], lowest point 0.

    Isotropic power spectrum $C(k) \propto k^{-2(1+H)}$ between the roll-off
    $k_l = 2\pi/\lambda_l$ (flat below) and the cut-off $k_s = 2\pi/\lambda_s$ (zero above),
    random phases from `jax.random.PRNGKey(seed)`, scaled to the requested RMS height. The
    surface is periodic over the grid (generated by an inverse FFT).

    **Arguments:**

    - `hurst`: Hurst exponent $H$, in (0, 1).
    - `rms_height`: RMS height [m], > 0.
    - `seed`: integer seed.
    - `short_wavelength`: $\lambda_s$ [m], default $4\Delta$.
    - `long_wavelength`: $\lambda_l$ [m], default the grid extent $L$.
    """
    check_positive("hurst", hurst, "", upper=1.0)
    check_positive("rms_height", rms_height, "m")
    n = grid.cells
    L = as_float(grid.extent)
    ls = 4 * grid.cell_size if short_wavelength is None else as_float(short_wavelength)
    ll = L if long_wavelength is None else as_float(long_wavelength)
    k1 = 2 * jnp.pi * jnp.fft.fftfreq(n, d=grid.cell_size)
    kx, ky = jnp.meshgrid(k1, k1, indexing="ij")
    k = jnp.sqrt(kx * kx + ky * ky)
    kl, ks = 2 * jnp.pi / ll, 2 * jnp.pi / ls
    amp = jnp.where(k > 0, jnp.maximum(k, kl), 1.0) ** (-(1.0 + hurst))
    amp = jnp.where((k > 0) & (k <= ks), amp, 0.0)
    key_r, key_i = jax.random.split(jax.random.PRNGKey(seed))
    noise = jax.random.normal(key_r, (n, n)) + 1j * jax.random.normal(key_i, (n, n))
    h = jnp.real(jnp.fft.ifft2(amp * noise))
    h = h - jnp.mean(h)
    h = h * (as_float(rms_height) / jnp.sqrt(jnp.mean(h * h)))
    return h - jnp.min(h)


def _heights(indenter, grid: BEMGrid) -> Array:
    if isinstance(indenter, AbstractProfile):
        return bem_heights(indenter, grid)
    h = as_float(indenter)
    if h.shape != (grid.cells, grid.cells):
        raise ValueError(
            f"`indenter` must be an AbstractProfile or a height map [m] of shape "
            f"{(grid.cells, grid.cells)} (the grid); got shape {h.shape}."
        )
    check_finite("indenter", h, "m")
    return h - jnp.min(h)


# --------------------------------------------------------------------------------------
# single elastic solve
# --------------------------------------------------------------------------------------


@float64_scope
def bem_contact(
    indenter,
    depth: Float[ArrayLike, ""] | None = None,
    *,
    grid: BEMGrid,
    effective_modulus: Float[ArrayLike, ""],
    force: Float[ArrayLike, ""] | None = None,
    tol: float = 1e-10,
    max_iter: int = 2000,
    throw: bool = True,
) -> tuple[Array, Array, Array]:
    r"""Non-adhesive elastic contact of a rigid indenter, displacement or force control.

    **Arguments:**

    - `indenter`: an `AbstractProfile` (axisymmetric) or a height map [m] of shape
      `(n, n)` on the grid (shifted so that its lowest cell is at 0).
    - `depth`: indentation $d$ [m], positive into the sample (displacement control): of the
      apex $f(0) = 0$ for a profile, of the lowest cell for a height map.
    - `grid`: a `BEMGrid`.
    - `effective_modulus`: $E^*$ [Pa], > 0 ($4G$ for an incompressible half-space).
    - `force`: alternatively the normal force $F$ [N], > 0 (force control: the original
      Polonsky-Keer algorithm with the load constraint). Give exactly one of `depth`, `force`.
    - `tol`: relative change of the pressure at which the CG stops.
    - `max_iter`: CG iteration limit (static).
    - `throw`: raise if the CG did not converge (under `jit` via `equinox.error_if`).

    **Returns:** `(force, depth, pressure)`: the normal force [N] (compressive positive),
    the indentation [m] and the cell pressures [Pa], shape `(n, n)`; the contact area is
    $\Delta^2\cdot\#\{p > 0\}$.
    """
    if (depth is None) == (force is None):
        raise ValueError("Give exactly one of `depth` [m] and `force` [N].")
    check_positive("effective_modulus", effective_modulus, "Pa")
    if depth is not None:
        check_finite("depth", depth, "m")
    else:
        check_positive("force", force, "N")
    h = _heights(indenter, grid)
    out = _bem_contact(*floats_to_arrays((h, None if depth is None else as_float(depth),
                                          None if force is None else as_float(force), grid,
                                          as_float(effective_modulus))), tol, max_iter)
    if throw:
        out = error_if(out, ~out[3], "BEM: the constrained CG did not converge (raise "
                           "`max_iter` or `tol`).")
    return out[:3]


@eqx.filter_jit
def _bem_contact(h, depth, force, grid, modulus, tol, max_iter):
    delta = grid.cell_size
    khat = _kernel_hat(grid.cells, delta)
    if depth is None:
        q, depth, ok = _pk_force(khat, h, force / (modulus * delta * delta), tol, max_iter)
    else:
        k00 = love_displacement(0.0, 0.0, 0.5 * delta, 0.5 * delta)
        att = jnp.zeros(h.shape, bool)
        q, _, _, ok = _pk_solve(khat, depth - h, att, jnp.zeros_like(h), k00, tol, max_iter)
    p = modulus * q
    return jnp.sum(p) * delta * delta, depth, p, ok


# --------------------------------------------------------------------------------------
# time stepping
# --------------------------------------------------------------------------------------


class BEMSolution(eqx.Module):
    """The output of `bem_simulate` (the fields of `ContactSolution`, plus BEM fields).

    Per-sample arrays have the shape of `ts`, `(m,)`. Signs: displacement positive into the
    sample, force compressive positive, adhesive negative.

    **Fields:**

    - `ts`: the sample times [s].
    - `displacement`: the indentation $d$ [m] at `ts` (the input in displacement control;
      solved in force control and with a compliant loading system). `nan` where a
      prescribed tensile force has no equilibrium (force control after the jump-off).
    - `force`: normal force $F = \\Delta^2\\sum p$ [N] carried by the contact (in force
      control the input while in contact, 0 after the jump-off).
    - `contact_area`: $\\Delta^2$ times the number of cells in contact [m²].
    - `contact_radius`: equivalent radius $\\sqrt{A/\\pi}$ [m].
    - `max_tensile_force`: the most negative force [N] of the samples and of the last
      equilibrium before the jump-off.
    - `jumpoff_time`, `jumpoff_displacement`, `jumpoff_force`, `jumpoff_radius`: time [s],
      indentation [m], force [N] and equivalent radius [m] of the last equilibrium still in
      contact before the first jump-off (the whole contact detaching in one cascade of the
      cell rule), located by bisection of the input within the sample interval
      (`refine_steps`); `nan` if the contact did not jump off.
    - `result`: `RESULTS.detached` (a jump-off happened), `RESULTS.in_contact` or
      `RESULTS.solver_failed`.
    - `pressure`: cell pressures [Pa], shape `(m, n, n)`, if `save_fields=True`, else None.
    - `attached`: cells in contact (bonded cells with adhesion), boolean `(m, n, n)`, if
      `save_fields`, else None.
    - `stats`: `cg_iterations` and `rounds` (cell-rule iterations) per sample;
      `touches_edge`: whether the contact reached the outermost cells of the grid (the
      grid is then too small; an error with `throw=True`); `drive`: the input history.
    """

    ts: Float[Array, " m"]
    displacement: Float[Array, " m"]
    force: Float[Array, " m"]
    contact_area: Float[Array, " m"]
    contact_radius: Float[Array, " m"]
    max_tensile_force: Float[Array, ""]
    jumpoff_time: Float[Array, ""]
    jumpoff_force: Float[Array, ""]
    jumpoff_radius: Float[Array, ""]
    jumpoff_displacement: Float[Array, ""]
    result: RESULTS
    pressure: Float[Array, "m n n"] | None
    attached: Bool[Array, "m n n"] | None
    stats: dict = eqx.field(default_factory=dict)

    @property
    def detached(self) -> Array:
        """Boolean: whether the contact jumped off within `ts`."""
        return self.result == RESULTS.detached


@float64_scope
def bem_simulate(
    rheology: AbstractRheology,
    indenter,
    work_of_adhesion: Float[ArrayLike, ""],
    ts: Float[ArrayLike, " m"],
    displacement: Float[ArrayLike, " m"] | None = None,
    *,
    grid: BEMGrid,
    force: Float[ArrayLike, " m"] | None = None,
    stiffness: Float[ArrayLike, ""] | None = None,
    relaxed_depth: Float[ArrayLike, ""] | None = None,
    save_fields: bool = False,
    tol: float = 1e-9,
    max_iter: int = 1000,
    max_rounds: int | None = None,
    max_newton: int = 50,
    refine_steps: int = 12,
    throw: bool = True,
) -> BEMSolution:
    r"""Adhesive contact of a rigid indenter and a viscoelastic half-space by BEM.

    The input is given at `ts` and is linear in between; every sample is one load step
    (exact creep update; the cell rule iterated to a consistent attached set, one
    constrained-CG solve per round; see the module docstring). Three loading systems:

    - displacement control (`displacement` alone): the indentation $d(t)$ is prescribed;
    - force control (`force` instead of `displacement`): a dead load $F(t)$; the contact
      jumps off where no equilibrium connected to the current one carries the load (for
      an elastic sphere at $-\tfrac32\pi\Delta\gamma R$);
    - compliant loading (`displacement` with `stiffness` $k$): a spring between the drive
      and the indenter (an AFM cantilever); `displacement` is then the drive position
      $z(t)$ (zero where the undeflected indenter touches) and $k(z - d) = F$.

    **Arguments:**

    - `rheology`: any rheology (`StandardModel`, `CreepChain`, `PronySeries`, `Elastic`),
      shear moduli [Pa] of an incompressible half-space, $E^* = 4G$. Converted to the creep
      form; the criterion uses the glass modulus.
    - `indenter`: an `AbstractProfile` (axisymmetric, e.g. `Parabola(R)`) or a height map
      [m] of shape `(n, n)` (see `ellipsoid_heights`, `tilted_flat_heights`,
      `self_affine_heights`).
    - `work_of_adhesion`: $\Delta\gamma$ [J/m²], >= 0 (0: non-adhesive).
    - `ts`: sample times [s], shape `(m,)`, non-decreasing.
    - `displacement`: the indentation $d(t_i)$ [m] at `ts` (of the apex $f(0) = 0$ for a
      profile, as in `simulate`; of the lowest cell for a height map), or the drive
      position $z(t_i)$ [m] with `stiffness`.
    - `grid`: a `BEMGrid`; it must hold the whole contact.
    - `force`: instead of `displacement`, the applied force $F(t_i)$ [N] (compressive
      positive) at `ts`, shape `(m,)`: force control.
    - `stiffness`: $k$ [N/m], > 0, of a compliant loading system (with `displacement`).
    - `relaxed_depth`: if given, the half-space starts fully relaxed under the indenter held
      at this depth $d_0$ [m] (> 0) without adhesion (as `retract`), and the history
      continues from $d_0$ at `ts[0]`; if None (default) it starts virgin and the first
      input is applied instantly at `ts[0]`.
    - `save_fields`: also return the pressure and contact fields per sample.
    - `tol`, `max_iter`: CG tolerance (relative change of the pressure) and iteration limit.
    - `max_rounds`: limit of cell-rule rounds per step (default $n^2$).
    - `max_newton`: limit of the Newton steps on the indentation per round (force control
      and compliant loading; each a constrained solve, a few per round).
    - `refine_steps`: bisection steps (static) that locate the jump-off within the sample
      interval in which the contact vanished (re-solving from the state at the previous
      sample with the linear input); the jump-off quantities are then resolved to
      $2^{-k}$ of that interval.
    - `throw`: raise if a solve did not converge (`.result`) or if the contact reached the
      edge of the grid (`.stats["touches_edge"]`); with False inspect these instead.

    Concrete inputs far outside the plausible range of their unit (a displacement above
    1 m: nanometres given as metres; see `PLAUSIBLE`) raise a `ValueError` before the solve
    (switched off by `plausibility_checks(False)`).

    **Returns:** a `BEMSolution`.
    """
    if not isinstance(grid, BEMGrid):
        raise TypeError(f"`grid` must be a BEMGrid; got {type(grid).__name__}.")
    if not isinstance(rheology, AbstractRheology):
        raise TypeError(f"`rheology` must be an AbstractRheology; got {type(rheology).__name__}.")
    check_positive("work_of_adhesion", work_of_adhesion, "J/m^2", allow_zero=True)
    check_times(ts)
    ts = as_float(ts)
    if (displacement is None) == (force is None):
        raise ValueError("Give exactly one of `displacement` [m] and `force` [N] (the input "
                         "history at `ts`).")
    if force is not None and stiffness is not None:
        raise ValueError("`stiffness` [N/m] goes with `displacement` (the drive position of "
                         "a compliant loading system), not with `force`.")
    name, unit = ("displacement", "m") if force is None else ("force", "N")
    inputs = as_float(displacement if force is None else force)
    if inputs.shape != ts.shape:
        raise ValueError(f"`{name}` [{unit}] must have the shape of `ts` {ts.shape}; got "
                         f"{inputs.shape}.")
    check_finite(name, inputs, unit)
    if stiffness is not None:
        check_positive("stiffness", stiffness, "N/m")
    if relaxed_depth is not None:
        check_positive("relaxed_depth", relaxed_depth, "m")
    # a displacement of 4000 m is nanometres given as metres: say so, rather than let the
    # contact outgrow the grid ("enlarge grid.extent")
    if force is None:
        check_plausible(name, inputs, "length", magnitude=True)
    check_plausible("relaxed_depth", relaxed_depth, "length")
    check_plausible("work_of_adhesion", work_of_adhesion, "work_of_adhesion")
    check_plausible("stiffness", stiffness, "stiffness")
    h = _heights(indenter, grid)
    adhesive = True
    if is_concrete(work_of_adhesion):
        adhesive = bool(np.asarray(work_of_adhesion) > 0)
    chain = rheology.to_creep_chain()
    rounds = grid.cells * grid.cells if max_rounds is None else int(max_rounds)
    dtype = ts.dtype
    # the start and the spring are traced values (one compiled program serves a relaxed and a
    # virgin start); displacement control compiles without the Newton loop on the depth
    dynamic = _sharding.on_mesh(floats_to_arrays((
        chain, h, as_float(work_of_adhesion).astype(dtype), ts, inputs, grid,
        jnp.asarray(relaxed_depth is not None),
        as_float(0.0 if relaxed_depth is None else relaxed_depth).astype(dtype),
        jnp.asarray(force is None and stiffness is None),
        as_float(0.0 if stiffness is None else stiffness).astype(dtype),
    )))
    sol = _sharding.compiled(_bem_simulate, _bem_simulate_plain)(
        *dynamic, save_fields, tol, int(max_iter), rounds,
        0 if force is None and stiffness is None else max(int(max_newton), 1), adhesive,
        int(refine_steps))
    if throw:
        sol = error_if(
            sol,
            sol.result == RESULTS.solver_failed,
            "BEM: a constrained-CG solve or the cell rule did not converge (raise `max_iter`, "
            "`max_rounds`, `max_newton` or `tol`).",
        )
        sol = error_if(
            sol,
            sol.stats["touches_edge"],
            "BEM: the contact reached the edge of the grid; enlarge `grid.extent` (or, if "
            "the indentation is not small against `grid.extent`, check the units: all "
            "lengths are in metres).",
        )
    return sol


class _State(eqx.Module):
    p: Array  # cell pressures [Pa]
    attached: Array  # bonded cells
    v: Array  # Kelvin states, (nk, n, n)
    w: Array  # displacement of a unit-modulus half-space, H p
    slope: Array  # warm start of the slope solve
    t: Array
    d: Array  # indentation [m]
    x: Array  # the input at t
    touching: Array


class _Carry(eqx.Module):
    state: _State
    pre: _State  # the state at the start of the step in which the contact first vanished
    t_end: Array  # ... and the end of that step's input
    x_end: Array
    found: Array
    lo: Array  # bisection: fractions of that step with and without contact
    hi: Array
    jump: Array  # (t, d, F, A) of the last equilibrium in contact
    ok: Array


def _tree_where(c, a, b):
    return jax.tree_util.tree_map(lambda x, y: jnp.where(c, x, y), a, b)


def _bem_simulate_plain(chain, h, dgamma, ts, inputs, grid, relaxed, d0, displacement_control,
                        spring,
                        save_fields, tol, max_iter, max_rounds, max_newton, adhesive,
                        refine_steps):
    r"""One `lax.scan` over the prelude (the relaxed start, or nothing), the samples and the
    bisection steps of the jump-off: the solver appears once in the compiled program."""
    n, m = grid.cells, ts.shape[0]
    delta = grid.cell_size
    khat = _kernel_hat(n, delta)
    k00 = love_displacement(0.0, 0.0, 0.5 * delta, 0.5 * delta)
    G0, Gk, eta = chain.G0, chain.G, chain.eta
    theta = eta / Gk
    sigma_c = cell_critical_stress(delta, dgamma, 4 * G0)  # the glass E* = 4 G0
    dtype = h.dtype
    zeros = jnp.zeros((n, n), dtype)
    scalar = jnp.zeros((), dtype)
    state0 = _State(zeros, jnp.zeros((n, n), bool), jnp.zeros((Gk.shape[0], n, n), dtype),
                    zeros, zeros, ts[0], scalar, scalar, jnp.asarray(False))

    def advance(st: _State, t1, dt, x1, fixed):
        e = jnp.exp(-dt / theta)
        phi = safe_div(theta * (-jnp.expm1(-dt / theta)), dt, 1.0)
        compliance = 1.0 / G0 + jnp.sum((1.0 - phi) / Gk)
        b = jnp.sum(e[:, None, None] * st.v
                    + ((phi - e) / Gk)[:, None, None] * st.w[None, :, :], axis=0)
        modulus = 4.0 / compliance
        unit = modulus * delta * delta  # F = unit * sum(q)
        load = _Load(fixed=fixed, depth=jnp.where(fixed, x1, st.d),
                     load=jnp.where(spring > 0, spring * x1, x1) / unit, spring=spring / unit)
        # warm start: the previous pressure at this step's modulus
        step = _consistent(khat, h + 0.25 * b, st.attached, st.p / modulus, st.slope, k00,
                           sigma_c / modulus, adhesive, load, tol, max_iter, max_rounds,
                           max_newton)
        eq = step.eq
        p = modulus * eq.q
        w1 = modulus * eq.hq
        v1 = (e[:, None, None] * st.v
              + ((1.0 - phi) / Gk)[:, None, None] * w1[None, :, :]
              + ((phi - e) / Gk)[:, None, None] * st.w[None, :, :])
        contact = step.attached | (eq.q > 0)
        area = jnp.sum(contact) * delta * delta
        edge = (jnp.any(contact[0]) | jnp.any(contact[-1]) | jnp.any(contact[:, 0])
                | jnp.any(contact[:, -1]))
        new = _State(p, step.attached, v1, w1, eq.slope, t1, eq.depth, x1, area > 0)
        out = dict(force=jnp.sum(p) * delta * delta, area=area, edge=edge,
                   d=jax.lax.select(eq.exists, eq.depth, jnp.full_like(eq.depth, jnp.nan)),
                   its=eq.cg_iterations,
                   rounds=step.rounds, ok=step.converged, contact=contact)
        return new, out

    def skip(st: _State, t1, dt, x1, fixed):
        return st, dict(force=scalar, area=scalar, edge=jnp.asarray(False), d=scalar,
                        its=jnp.asarray(0), rounds=jnp.asarray(0), ok=jnp.asarray(True),
                        contact=jnp.zeros((n, n), bool))

    def body(c: _Carry, j):
        prelude = j == 0
        refining = j > m
        i = jnp.clip(j - 1, 0, m - 1)
        start = _tree_where(refining, c.pre, c.state)
        mid = 0.5 * (c.lo + c.hi)
        t_ref = c.pre.t + mid * (c.t_end - c.pre.t)
        x_ref = c.pre.x + mid * (c.x_end - c.pre.x)
        # prelude: relax at the depth d0 (an infinite step), or nothing (a depth below touch)
        t1 = jnp.where(prelude, ts[0], jnp.where(refining, t_ref, _sharding.pick(ts, i)))
        x1 = jnp.where(prelude, jnp.where(relaxed, d0, -grid.extent),
                       jnp.where(refining, x_ref, _sharding.pick(inputs, i)))
        dt = jnp.where(prelude, jnp.where(relaxed, jnp.inf, 0.0), t1 - start.t)
        fixed = prelude | displacement_control
        idle = refining & ~c.found
        new, out = _sharding.cond(idle, skip, advance, start, t1, dt, x1, fixed)
        sample = ~prelude & ~refining
        lost = sample & c.state.touching & ~new.touching & ~c.found
        st = c.state
        here = jnp.stack([st.t, st.d, jnp.sum(st.p) * delta * delta,
                          jnp.sum(st.attached | (st.p > 0)) * delta * delta])
        keep = refining & new.touching
        jump = jnp.where(lost, here, jnp.where(keep, jnp.stack(
            [t1, new.d, out["force"], out["area"]]), c.jump))
        carry = _Carry(
            state=_tree_where(refining, c.state, new),
            pre=_tree_where(lost, c.state, c.pre),
            t_end=jnp.where(lost, t1, c.t_end),
            x_end=jnp.where(lost, x1, c.x_end),
            found=c.found | lost,
            lo=jnp.where(keep, mid, c.lo),
            hi=jnp.where(refining & ~new.touching, mid, c.hi),
            jump=jump,
            ok=c.ok & out["ok"],
        )
        ys = dict(force=out["force"], area=out["area"], d=out["d"], its=out["its"],
                  rounds=out["rounds"], edge=out["edge"] & ~refining)
        if save_fields:
            ys["p"] = new.p
            ys["contact"] = out["contact"]
        return carry, ys

    nan = jnp.full((), jnp.nan, dtype)
    init = _Carry(state0, state0, scalar, scalar, jnp.asarray(False), scalar,
                  jnp.ones((), dtype), jnp.full((4,), jnp.nan, dtype), jnp.asarray(True))
    final, out = _sharding.scan(body, init, jnp.arange(1 + m + refine_steps),
                                tie=(chain, h, dgamma, ts, inputs, grid, d0, spring))
    touches_edge = jnp.any(out["edge"])  # the prelude included
    out = jax.tree_util.tree_map(lambda y: y[1:1 + m], out)
    force, area = out["force"], out["area"]
    jt, jd, jf, ja = (jnp.where(final.found, final.jump[k], nan) for k in range(4))
    result = RESULTS.where(final.found, RESULTS.detached, RESULTS.in_contact)
    result = RESULTS.where(final.ok, result, RESULTS.solver_failed)
    return BEMSolution(
        ts=ts,
        displacement=jnp.where(displacement_control, inputs, out["d"]),
        force=force,
        contact_area=area,
        contact_radius=jnp.sqrt(area / jnp.pi),
        max_tensile_force=jnp.where(final.found, jnp.minimum(jnp.min(force), jf),
                                    jnp.min(force)),
        jumpoff_time=jt,
        jumpoff_force=jf,
        jumpoff_radius=jnp.sqrt(ja / jnp.pi),
        jumpoff_displacement=jd,
        result=result,
        pressure=out.get("p"),
        attached=out.get("contact"),
        stats=dict(cg_iterations=out["its"], rounds=out["rounds"],
                   touches_edge=touches_edge, drive=inputs),
    )


_bem_simulate = eqx.filter_jit(_bem_simulate_plain)
