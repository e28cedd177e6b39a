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

**Jump-off.** In displacement control the contact jumps off where the whole contact
detaches in one cascade of the cell rule. The sample interval in which this happens is
bisected (re-solving from the state at its start with the linear input), so the jump-off
force, time and displacement are resolved finer than the sampling.

**Accuracy** (elastic sphere, displacement control, `tests/test_bem.py` and
`benchmarks/bench_bem.py`): the largest tensile force approaches JKR's
$-\tfrac32\pi\Delta\gamma R$ from above with an error of about first order in $\Delta$
(+13.6 %, +8.0 %, +3.6 % at $R/\Delta$ = 158, 317, 634, contact radius at pull-off of
9, 18, 36 cells); the jump-off force approaches $-\tfrac56\pi\Delta\gamma R$ faster
(+2.1 %, +0.4 %, +0.3 %). The cell criterion is a discrete energy balance, so the error is
set by the number of cells across the contact at pull-off.

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

from ._criteria import BEM_CHI
from ._profiles import AbstractProfile
from ._rheology import AbstractRheology
from ._solution import RESULTS
from ._solvers import as_float
from ._validate import check_finite, check_positive, check_times, is_concrete

__all__ = [
    "BEMGrid",
    "BEMSolution",
    "bem_contact",
    "bem_heights",
    "bem_simulate",
    "ellipsoid_heights",
    "love_displacement",
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
    extent: Float[ArrayLike, ""]

    def __check_init__(self):
        if int(self.cells) < 2:
            raise ValueError(f"`cells` must be an integer >= 2; got {self.cells}.")
        check_positive("extent", self.extent, "m")

    @property
    def cell_size(self) -> Array:
        r"""Cell side $\Delta = L/n$ [m]."""
        return as_float(self.extent) / self.cells

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


def _pk_solve(khat, target, attached, q0, k00, tol, max_iter):
    r"""Polonsky-Keer CG, displacement control: $g = \mathcal H q - t$; bonded on `attached`
    (no bound), $q \ge 0$ elsewhere. Returns `(q, Hq, iterations, converged)`."""
    dtype = target.dtype
    q = jnp.where(attached, q0, jnp.maximum(q0, 0.0))
    g = _convolve(khat, q) - target
    # seed penetrating free cells so that the active set is never empty when it must not be
    seed = (~attached) & (q <= 0) & (g < 0)
    q = jnp.where(seed, -g / k00, q)

    def cond(c):
        return (c[5] < max_iter) & (c[6] > tol)

    def body(c):
        q, hq, t_dir, g_old, delta, it, _ = c
        g = hq - target
        act = attached | (q > 0)
        gg = jnp.sum(jnp.where(act, g * g, 0.0))
        ratio = jnp.where(g_old > 0, gg / jnp.where(g_old > 0, g_old, 1.0), 0.0)
        t_dir = jnp.where(act, g + delta * ratio * t_dir, 0.0)
        r = _convolve(khat, t_dir)
        num = jnp.sum(jnp.where(act, g * t_dir, 0.0))
        den = jnp.sum(jnp.where(act, r * t_dir, 0.0))
        tau = jnp.where(den > 0, num / jnp.where(den > 0, den, 1.0), 0.0)
        q_lin = q - tau * t_dir
        q_new = jnp.where(attached, q_lin, jnp.maximum(q_lin, 0.0))
        nol = (~attached) & (q_new <= 0) & (g < 0)
        any_nol = jnp.any(nol)
        q_new = jnp.where(nol, q_new - tau * g, q_new)
        # H q is updated linearly (H q - tau r); one more convolution only when the
        # projection or the re-entry of penetrating cells changed q off that line
        fix = q_new - q_lin
        hq = jax.lax.cond(jnp.any(fix != 0), lambda: hq - tau * r + _convolve(khat, fix),
                          lambda: hq - tau * r)
        scale = jnp.sum(jnp.abs(q_new))
        err = jnp.sum(jnp.abs(q_new - q)) / jnp.where(scale > 0, scale, 1.0)
        err = jnp.where(any_nol, jnp.maximum(err, 2 * tol), err)
        delta = jnp.where(any_nol, 0.0, 1.0).astype(dtype)
        return q_new, hq, t_dir, gg, delta, it + 1, err

    init = (q, _convolve(khat, q), jnp.zeros_like(q), jnp.zeros((), dtype),
            jnp.zeros((), dtype), 0, jnp.asarray(jnp.inf, dtype))
    q, _, _, _, _, it, err = jax.lax.while_loop(cond, body, init)
    return q, _convolve(khat, q), it, err <= tol


def _pk_force(khat, h, total, tol, max_iter):
    r"""Polonsky-Keer CG in force control (the original algorithm): $q \ge 0$,
    $\sum q = $ `total`, gap $\mathcal Hq + h - d$ zero on the contact with the rigid
    indentation $d$ found as the mean of $\mathcal Hq + h$ there. Returns `(q, d, converged)`."""
    dtype = h.dtype
    q = jnp.full(h.shape, total / h.size, dtype)

    def mean_on(x, act):
        cnt = jnp.sum(act)
        return jnp.sum(jnp.where(act, x, 0.0)) / jnp.where(cnt > 0, cnt, 1)

    def cond(c):
        return (c[5] < max_iter) & (c[6] > tol)

    def body(c):
        q, hq, t_dir, g_old, delta, it, _ = c
        act = q > 0
        g = hq + h
        g = g - mean_on(g, act)
        gg = jnp.sum(jnp.where(act, g * g, 0.0))
        ratio = jnp.where(g_old > 0, gg / jnp.where(g_old > 0, g_old, 1.0), 0.0)
        t_dir = jnp.where(act, g + delta * ratio * t_dir, 0.0)
        r_raw = _convolve(khat, t_dir)
        r = r_raw - mean_on(r_raw, act)
        num = jnp.sum(jnp.where(act, g * t_dir, 0.0))
        den = jnp.sum(jnp.where(act, r * t_dir, 0.0))
        tau = jnp.where(den > 0, num / jnp.where(den > 0, den, 1.0), 0.0)
        q_lin = q - tau * t_dir
        q_new = jnp.maximum(q_lin, 0.0)
        nol = (q_new <= 0) & (g < 0)
        any_nol = jnp.any(nol)
        q_new = jnp.where(nol, q_new - tau * g, q_new)
        fix = q_new - q_lin  # H q follows linearly, plus the projection's correction
        hq = jax.lax.cond(jnp.any(fix != 0), lambda: hq - tau * r_raw + _convolve(khat, fix),
                          lambda: hq - tau * r_raw)
        factor = total / jnp.sum(q_new)
        q_new, hq = q_new * factor, hq * factor
        err = jnp.sum(jnp.abs(q_new - q)) / total
        err = jnp.where(any_nol, jnp.maximum(err, 2 * tol), err)
        return (q_new, hq, t_dir, gg, jnp.where(any_nol, 0.0, 1.0).astype(dtype), it + 1,
                err)

    init = (q, _convolve(khat, q), jnp.zeros_like(q), jnp.zeros((), dtype),
            jnp.zeros((), dtype), 0, jnp.asarray(jnp.inf, dtype))
    q, _, _, _, _, _, err = jax.lax.while_loop(cond, body, init)
    act = q > 0
    depth = mean_on(_convolve(khat, q) + h, act)
    return q, depth, err <= tol


class _Step(eqx.Module):
    q: Array
    hq: Array
    attached: Array
    cg_iterations: Array
    rounds: Array
    converged: Array


def _consistent(khat, target, attached, q0, k00, q_crit, adhesive, tol, max_iter, max_rounds):
    """Iterate the cell rule to a consistent attached set at one load step.

    `q_crit` is the critical stress over the step's effective modulus (stress rule
    p < sigma_c  <=>  q < q_crit). Non-adhesive (`adhesive=False`): no cell is ever attached.
    """
    if not adhesive:
        q, hq, it, ok = _pk_solve(khat, target, attached, q0, k00, tol, max_iter)
        return _Step(q, hq, jnp.zeros_like(attached), it, jnp.asarray(1), ok)

    def cond(c):
        _, _, _, _, rounds, _, changed = c
        return changed & (rounds < max_rounds)

    def body(c):
        q, _, att, its, rounds, ok, _ = c
        q, hq, it, conv = _pk_solve(khat, target, att, q, k00, tol, max_iter)
        release = att & (q < q_crit)
        touch = (~att) & (q > 0)
        new = (att & ~release) | touch
        q = jnp.where(release, 0.0, q)
        changed = jnp.any(new != att)
        return q, hq, new, its + it, rounds + 1, ok & conv, changed

    z = jnp.zeros_like(q0)
    init = (q0, z, attached, 0, 0, jnp.asarray(True), jnp.asarray(True))
    q, hq, att, its, rounds, ok, changed = jax.lax.while_loop(cond, body, init)
    # the last solve used `att` before the update; if nothing changed it is consistent
    return _Step(q, hq, att, its, rounds, ok & ~changed)


# --------------------------------------------------------------------------------------
# indenters
# --------------------------------------------------------------------------------------

_FAR = 1e3  # heights outside a punch: this many grid extents (never touched)


def bem_heights(profile: AbstractProfile, grid: BEMGrid) -> Float[Array, "n n"]:
    r"""Height map [m] of an axisymmetric profile on the grid: $h_{ij} = f(r_{ij})$.

    Works with every `AbstractProfile` (`Parabola` gives the sphere in the paraboloid
    approximation, `Cone`, `PowerLaw`, `FlatPunch`, `Tabulated`). Heights outside a flat
    punch (infinite) are replaced by a large finite value so that the solver never touches
    them.
    """
    x, y = grid.coordinates()
    h = profile.shape(jnp.sqrt(x * x + y * y))
    return jnp.where(jnp.isfinite(h), h, _FAR * as_float(grid.extent))


def ellipsoid_heights(
    grid: BEMGrid, radius_x: Float[ArrayLike, ""], radius_y: Float[ArrayLike, ""]
) -> Float[Array, "n n"]:
    r"""Elliptic paraboloid $h = x^2/(2R_x) + y^2/(2R_y)$ [m] (principal radii $R_x, R_y$ [m],
    > 0), the ellipsoid near its apex."""
    check_positive("radius_x", radius_x, "m")
    check_positive("radius_y", radius_y, "m")
    x, y = grid.coordinates()
    return x * x / (2 * as_float(radius_x)) + y * y / (2 * as_float(radius_y))


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
    out = _bem_contact(h, None if depth is None else as_float(depth),
                       None if force is None else as_float(force), grid,
                       as_float(effective_modulus), tol, max_iter)
    if throw:
        out = eqx.error_if(out, ~out[3], "BEM: the constrained CG did not converge (raise "
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

    - `ts`, `displacement`: the input [s], [m].
    - `force`: normal force $F = \\Delta^2\\sum p$ [N].
    - `contact_area`: $\\Delta^2$ times the number of cells in contact [m²].
    - `contact_radius`: equivalent radius $\\sqrt{A/\\pi}$ [m].
    - `max_tensile_force`: the most negative sampled force [N].
    - `jumpoff_time`, `jumpoff_displacement`: time [s] and indentation [m] at which the
      contact vanished (a detachment cascade through the whole contact), located by
      bisection within the sample interval (`refine_steps`); `nan` if it did not.
    - `jumpoff_force`, `jumpoff_radius`: force [N] and equivalent radius [m] of the last
      equilibrium still in contact found by the bisection; `nan` if no jump-off.
    - `result`: `RESULTS.detached`, `RESULTS.in_contact` or `RESULTS.solver_failed`.
    - `pressure`: cell pressures [Pa], shape `(m, n, n)`, if `save_fields=True`, else None.
    - `attached`: attached (bonded) cells, boolean `(m, n, n)`, if `save_fields`, else None.
    - `stats`: `cg_iterations` and `rounds` (cell-rule iterations) per sample;
      `touches_edge`: whether the contact reached the outermost cells of the grid (the
      grid is then too small; an error with `throw=True`).
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
        """Boolean: whether the contact detached within `ts`."""
        return self.result == RESULTS.detached


def bem_simulate(
    rheology: AbstractRheology,
    indenter,
    work_of_adhesion: Float[ArrayLike, ""],
    ts: Float[ArrayLike, " m"],
    displacement: Float[ArrayLike, " m"],
    *,
    grid: BEMGrid,
    relaxed_depth: Float[ArrayLike, ""] | None = None,
    save_fields: bool = False,
    tol: float = 1e-9,
    max_iter: int = 1000,
    max_rounds: int | None = None,
    refine_steps: int = 12,
    throw: bool = True,
) -> BEMSolution:
    r"""Adhesive contact of a rigid indenter and a viscoelastic half-space by BEM.

    Displacement control: the indentation $d(t)$ is given at `ts` and is linear in between;
    every sample is one load step (exact creep update, one constrained-CG solve per round of
    the cell rule; see the module docstring).

    **Arguments:**

    - `rheology`: any rheology (`StandardModel`, `CreepChain`, `PronySeries`, `Elastic`),
      shear moduli [Pa] of an incompressible half-space, $E^* = 4G$. Converted to the creep
      form; the criterion uses the glass modulus.
    - `indenter`: an `AbstractProfile` (axisymmetric, e.g. `Parabola(R)`) or a height map
      [m] of shape `(n, n)` (see `ellipsoid_heights`, `tilted_flat_heights`,
      `self_affine_heights`).
    - `work_of_adhesion`: $\Delta\gamma$ [J/m²], >= 0 (0: non-adhesive).
    - `ts`: sample times [s], shape `(m,)`, non-decreasing.
    - `displacement`: indentation $d(t_i)$ [m] at `ts`: of the apex $f(0) = 0$ for a
      profile (as in `simulate`), of the lowest cell for a height map.
    - `grid`: a `BEMGrid`; it must hold the whole contact.
    - `relaxed_depth`: if given, the half-space starts fully relaxed under the indenter held
      at this depth $d_0$ [m] (> 0) without adhesion (as `retract`), and the history
      continues from $d_0$ at `ts[0]`; if None (default) it starts virgin and
      `displacement[0]` is applied instantly at `ts[0]`.
    - `save_fields`: also return the pressure and attached-cell fields per sample.
    - `tol`, `max_iter`: CG tolerance (relative change of the pressure) and iteration limit.
    - `max_rounds`: limit of cell-rule rounds per step (default $n^2$).
    - `refine_steps`: bisection steps (static) that locate the jump-off within the sample
      interval in which the contact vanished (re-solving from the state at the previous
      sample with the linear input); the jump-off quantities are then resolved to
      $2^{-k}$ of that interval.
    - `throw`: raise if a solve did not converge (`.result`) or if the contact reached the
      edge of the grid (`.stats["touches_edge"]`); with False inspect these instead.

    **Returns:** a `BEMSolution`.
    """
    if not isinstance(grid, BEMGrid):
        raise TypeError(f"`grid` must be a BEMGrid; got {type(grid).__name__}.")
    check_positive("work_of_adhesion", work_of_adhesion, "J/m^2", allow_zero=True)
    check_times(ts)
    ts = as_float(ts)
    disp = as_float(displacement)
    if disp.shape != ts.shape:
        raise ValueError(
            f"`displacement` [m] must have the shape of `ts` {ts.shape}; got {disp.shape}."
        )
    check_finite("displacement", disp, "m")
    if relaxed_depth is not None:
        check_positive("relaxed_depth", relaxed_depth, "m")
        relaxed_depth = as_float(relaxed_depth)
    h = _heights(indenter, grid)
    adhesive = True
    if is_concrete(work_of_adhesion):
        adhesive = bool(np.asarray(work_of_adhesion) > 0)
    if not isinstance(rheology, AbstractRheology):
        raise TypeError(f"`rheology` must be an AbstractRheology; got {type(rheology).__name__}.")
    chain = rheology.to_creep_chain()
    rounds = grid.cells * grid.cells if max_rounds is None else int(max_rounds)
    sol = _bem_simulate(chain, h, as_float(work_of_adhesion), ts, disp, grid, relaxed_depth,
                        save_fields, tol, max_iter, rounds, adhesive, int(refine_steps))
    if throw:
        sol = eqx.error_if(
            sol,
            sol.result == RESULTS.solver_failed,
            "BEM: a constrained-CG solve or the cell rule did not converge (raise `max_iter`, "
            "`max_rounds` or `tol`).",
        )
        sol = eqx.error_if(
            sol,
            sol.stats["touches_edge"],
            "BEM: the contact reached the edge of the grid; enlarge `grid.extent`.",
        )
    return sol


class _Carry(eqx.Module):
    p: Array
    attached: Array
    v: Array
    w: Array
    t: Array
    d: Array
    ok: Array
    touching: Array


@eqx.filter_jit
def _bem_simulate(chain, h, dgamma, ts, disp, grid, relaxed_depth, save_fields, tol, max_iter,
                  max_rounds, adhesive, refine_steps):
    n = grid.cells
    delta = grid.cell_size
    khat = _kernel_hat(n, delta)
    k00 = love_displacement(0.0, 0.0, 0.5 * delta, 0.5 * delta)
    G0, Gk, eta = chain.G0, chain.G, chain.eta
    theta = eta / Gk
    sigma_c = -jnp.sqrt(4 * G0 * dgamma / (BEM_CHI * delta))
    nk = Gk.shape[0]
    zeros = jnp.zeros((n, n), h.dtype)

    if relaxed_depth is None:
        carry = _Carry(zeros, jnp.zeros((n, n), bool), jnp.zeros((nk, n, n), h.dtype), zeros,
                       ts[0], jnp.zeros((), h.dtype), jnp.asarray(True), jnp.asarray(False))
    else:
        c_inf = 1.0 / G0 + jnp.sum(1.0 / Gk)
        q, hq, _, ok = _pk_solve(khat, relaxed_depth - h, jnp.zeros((n, n), bool), zeros, k00,
                                 tol, max_iter)
        w = (4.0 / c_inf) * hq  # unit-modulus displacement H p of the relaxed pressure
        v = w[None, :, :] / Gk[:, None, None]
        carry = _Carry(q * (4.0 / c_inf), q > 0, v, w, ts[0], relaxed_depth, ok,
                       jnp.any(q > 0))

    def advance(c: _Carry, t1, d1):
        dt = t1 - c.t
        e = jnp.exp(-dt / theta)
        phi = jnp.where(dt > 0, theta * (-jnp.expm1(-dt / theta)) / jnp.where(dt > 0, dt, 1.0),
                        1.0)
        compliance = 1.0 / G0 + jnp.sum((1.0 - phi) / Gk)
        b = jnp.sum(e[:, None, None] * c.v
                    + ((phi - e) / Gk)[:, None, None] * c.w[None, :, :], axis=0)
        modulus = 4.0 / compliance
        target = d1 - h - 0.25 * b
        # warm start: the previous pressure at this step's modulus
        step = _consistent(khat, target, c.attached, c.p / modulus, k00,
                           sigma_c / modulus, adhesive, tol, max_iter, max_rounds)
        p = modulus * step.q
        w1 = modulus * step.hq
        v1 = (e[:, None, None] * c.v
              + ((1.0 - phi) / Gk)[:, None, None] * w1[None, :, :]
              + ((phi - e) / Gk)[:, None, None] * c.w[None, :, :])
        contact = step.attached | (step.q > 0)
        area = jnp.sum(contact) * delta * delta
        edge = (jnp.any(contact[0]) | jnp.any(contact[-1]) | jnp.any(contact[:, 0])
                | jnp.any(contact[:, -1]))
        new = _Carry(p, step.attached, v1, w1, t1, d1, c.ok & step.converged, area > 0)
        return new, step, contact, jnp.sum(p) * delta * delta, area, edge

    def refine(c: _Carry, t1, d1):
        # the contact vanished within (c.t, t1]: bisect the (linear) input from the state
        # at c.t; keep the last equilibrium still in contact
        def bisect(k, lohi):
            lo, hi, f, a = lohi
            mid = 0.5 * (lo + hi)
            _, _, _, fm, am, _ = advance(c, c.t + mid * (t1 - c.t), c.d + mid * (d1 - c.d))
            keep = am > 0
            return (jnp.where(keep, mid, lo), jnp.where(keep, hi, mid),
                    jnp.where(keep, fm, f), jnp.where(keep, am, a))

        f0 = c.p.sum() * delta * delta
        a0 = jnp.sum(c.attached | (c.p > 0)) * delta * delta
        lo, hi, f, a = jax.lax.fori_loop(0, refine_steps, bisect,
                                         (jnp.zeros_like(t1), jnp.ones_like(t1), f0, a0))
        return c.t + hi * (t1 - c.t), c.d + hi * (d1 - c.d), f, jnp.sqrt(a / jnp.pi)

    def body(c: _Carry, inp):
        t1, d1 = inp
        new, step, contact, force, area, edge = advance(c, t1, d1)
        lost = c.touching & ~new.touching
        nan = jnp.full((), jnp.nan, force.dtype)
        jump = jax.lax.cond(lost, refine, lambda *_: (nan, nan, nan, nan), c, t1, d1)
        out = dict(force=force, area=area, its=step.cg_iterations, rounds=step.rounds,
                   ok=step.converged, lost=lost, jump=jump, edge=edge)
        if save_fields:
            out["p"] = new.p
            out["att"] = contact if not adhesive else step.attached
        return new, out

    final, out = jax.lax.scan(body, carry, (ts, disp))
    force, area = out["force"], out["area"]
    radius = jnp.sqrt(area / jnp.pi)
    lost = out["lost"]
    has = jnp.any(lost)
    i = jnp.argmax(lost)
    nan = jnp.asarray(jnp.nan, force.dtype)
    jt, jd, jf, ja = (jnp.where(has, x[i], nan) for x in out["jump"])
    result = RESULTS.where(has, RESULTS.detached, RESULTS.in_contact)
    result = RESULTS.where(jnp.all(out["ok"]) & final.ok, result, RESULTS.solver_failed)
    return BEMSolution(
        ts=ts,
        displacement=disp,
        force=force,
        contact_area=area,
        contact_radius=radius,
        max_tensile_force=jnp.min(force),
        jumpoff_time=jt,
        jumpoff_force=jf,
        jumpoff_radius=ja,
        jumpoff_displacement=jd,
        result=result,
        pressure=out.get("p"),
        attached=out.get("att"),
        stats=dict(cg_iterations=out["its"], rounds=out["rounds"],
                   touches_edge=jnp.any(out["edge"])),
    )
