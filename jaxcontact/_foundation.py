r"""Adhesive viscoelastic contact under arbitrary loading histories: the MDR foundation.

A rigid axisymmetric indenter with MDR profile $g(x)$ is driven into a viscoelastic
half-space by any sampled history (approach, hold, lift, repeated cycles). Unlike the
relaxed-start model (`retract`), springs enter the contact at different times and carry
different histories, so the state is a field over $x$ (PHYSICS.md §4): the MDR foundation is
discretised.

**Foundation.** Every spring is a linear viscoelastic element in relaxation (Prony) form,
$G(t) = G_\infty + \sum_k G_k e^{-t/\tau_k}$, with glass modulus $G_g = G_\infty + \sum_k G_k$.
Its state is the vector of dashpot displacements $v_k(x, t)$ [m] of the Maxwell arms; with the
spring displacement $u(x, t)$ [m] (positive = compressed) the line load is

$$q = 4\Big[G_\infty u + \sum_k G_k (u - v_k)\Big] = 4\Big[G_g u - \sum_k G_k v_k\Big],\qquad
  \dot v_k = \frac{u - v_k}{\tau_k}.$$

- *Attached* springs ($|x| < a$) follow the indenter, $u = d(t) - g(x)$. For a displacement
  that is linear in time over a step $\Delta$ the update is exact:
  $v_k \leftarrow v_k e^{-\Delta/\tau_k} + u_0(1 - e^{-\Delta/\tau_k})
  + \Delta u\,\psi(\Delta/\tau_k)$, $\psi(s) = 1 - (1 - e^{-s})/s$.
- *Free* springs ($|x| > a$) carry no load, $q = 0$, so $u = \sum_m \rho_m v_m$ with
  $\rho_m = G_m/G_g$ and $\dot v = A v$, $A_{km} = (\rho_m - \delta_{km})/\tau_k$; exact update
  $v \leftarrow e^{A\Delta} v$. A free spring recovers towards $u = 0$ with the retardation
  times of the material.

**Touch and re-attachment (cycles).** The contact is the disc $|x| < a(t)$ (the MDR
describes a single circular contact). Beyond the edge the gap is
$\Phi(x) = d - g(x) - u_\mathrm{free}(x)$. The edge advances while $\Phi > 0$ just outside
it, to the root $\Phi(a) = 0$: a virgin spring ($v = 0$) enters the contact unloaded when
$d \ge g(x)$ (the JKR-limit touch rule; the loading branch of an elastic solid is Hertz), and
a spring that detached earlier re-attaches, carrying its state (continuous $v$, hence
$q = 0$ at the moment of contact), when the indenter reaches its current, partly recovered
free surface: a detached spring is load-free and creeps back towards $u = 0$. Attachment is
by touching only (criteria other than touching are outside the paper). The edge has two
sides: the attached edge spring at $a^-$ and the free spring at $a^+$. They coincide while
the edge moves, but not while it is pinned, so a pinned edge may carry a compressive line
load (e.g. reloading to a smaller depth after the edge crept in tension) until the indenter
reaches the free surface just outside.

**Detachment front.** The edge recedes when its line load reaches the energetic criterion
(paper eq. 10-11, PHYSICS.md §2) $q(a) = -\sqrt{8\pi a\,\Delta\gamma\,G_g}$. The front is the
largest root of $R(x) = q(x) + \sqrt{8\pi x\Delta\gamma G_g}$ below the previous edge, found on
the interpolated load field (below), so it is a continuous and differentiable function of the
parameters (implicit differentiation), not a jump from spring to spring. The contact jumps off
when no root remains (the fold, where $\max_x R = 0$); after that force and radius are exactly
zero.

**Events between samples.** The jump-off time is the root of $\max_x R(x, t) = 0$ with the
exact in-step evolution (the attached update is affine in $s$ with coefficients that do not
depend on $x$), its radius the maximiser of $R$ with the interpolated part replaced by a local
quadratic (second order). The largest tensile force is the minimum over the samples, the
jump-off force and the force along the receding front inside the two steps around the
sample minimum (dense output with a golden-section search); this includes the kink where a
pinned edge starts to recede. All are differentiable. (Under compliant loading the
indentation inside a step is taken linear between the solved samples.)

**Loading system.** `DisplacementControl()` (rigid) or `CompliantLoading(k)`: a spring
between drive and indenter, $k(z - d) = F$, solved for $d$ at every sample by Newton's method
through the full step and differentiated implicitly; the contact jumps off where no
equilibrium connected to the current one remains: inside the step the drive position that
holds a front at $x$ in equilibrium, $z_\mathrm{eq}(x, t)$, is explicit (the criterion is
affine in $d$), and the jump-off is the root of $z(t) = \min_x z_\mathrm{eq}(x, t)$, at
the minimiser ($\mathrm{d}F/\mathrm{d}d = -k$ along the front; the criterion's fold for a
stiff spring, force control's minimum of $F$ for $k \to 0$). Exact for an elastic solid
at any $k$ and any sampling; for a viscoelastic one the jump-off converges at first order
in the sample spacing (the indentation accelerates towards the instability, while a step
takes it linear in time): in the benchmark's approach-hold-lift with $k$ = 2 N/m and 600
samples, 1.2e-3 relaxation times (0.14 of a sample interval) and 6e-4 of the force.

**Discretisation.** Springs sit at nodes $x_j$ uniform in the touch depth: $g(x_j) = j\,
g_\max/n$ (for the parabola $x_j \propto \sqrt j$, densest at the edge): springs of one cell
were reached within the same increment of indentation, so on a loading branch their
histories differ by the same amount in every cell. The dashpot field is interpolated
linearly in $\zeta = g(x)$ (in $x$ for the flat punch) and, on the contact side, as
$s_k = v_k + g(x)$ (the dashpot position in the indenter frame). This makes three limits
exact at any grid: the elastic solid, the glass response ($v = 0$, $s = g$) and the relaxed
state ($v = d - g$, $s = d$); in particular a lift after full relaxation reproduces `retract`
to round-off. The edge is a moving node with its own state, so the pinned phase is integrated
exactly. The force is $F = 2\int_0^a q\,dx = 8\big[G_g a d - G_\infty\int_0^a g
- \sum_k G_k\int_0^a s_k\big]$, integrated exactly over the interpolant (partial last cell
included). The discretisation errors are the interpolation of $s$ between springs of
different histories, second order in the cell size, and the timing of springs that change
state inside a step (located by linear interpolation in time; exact for virgin springs). For
the approach-hold-lift of the standard model in `benchmarks/bench_foundation.py` (5,000
samples, against 1,024 cells) the default 64 cells give a largest force error of 2.5e-5 of
the peak force (2.1e-4 with 32 cells, 4.9e-4 with 16); over approach and hold alone 1.9e-5
(7.6e-5, 3.2e-4), observed order 2.0; the jump-off time to 5e-6 relaxation times (order
2). `estimate_error=True` reports 6e-5 for the force there (it overestimates).

**Time integration.** `ExactUpdate()` (default) uses the closed-form updates above for the
piecewise-linear input: no time-step error. `DiffraxODE(...)` integrates the dashpot ODEs of
all springs over every sample interval with a diffrax solver instead (the same model to the
solver tolerance; the partial steps of springs that change state inside an interval use the
same closed forms in both).

Note: this model gives $\Delta\gamma_\mathrm{eff} = \Delta\gamma G_g/G_\infty$ already at slow
pulling, unlike classical viscoelastic crack theories (Schapery, Greenwood-Johnson,
Persson-Brener); do not validate it against those.
"""

from __future__ import annotations

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, ArrayLike, Float

from ._elastic import _power_law_params, profile_radius
from ._profiles import AbstractProfile, FlatPunch
from ._pulloff import AbstractMethod, DiffraxODE, ExactUpdate
from ._root import bracketed_root
from ._solution import RESULTS, ContactSolution, is_error
from ._validate import check_finite, check_positive, is_concrete

__all__ = [
    "simulate",
    "FoundationGrid",
    "AbstractLoading",
    "DisplacementControl",
    "CompliantLoading",
    "DEFAULT_CELLS",
]

#: Default number of cells of the foundation grid (see `FoundationGrid`).
DEFAULT_CELLS = 64

_ROOT_STEPS = 16


# --------------------------------------------------------------------------------------
# Options
# --------------------------------------------------------------------------------------


class FoundationGrid(eqx.Module):
    r"""The spring grid of the MDR foundation.

    Springs sit at $x_j$ with $g(x_j) = j\,g_\max/n$, $j = 0..n$: uniform in the *touch depth*,
    so every cell spans the same increment of indentation and the springs of one cell touched
    within the same fraction of the approach. For the parabola $x_j = L\sqrt{j/n}$ (densest at
    the contact edge), for the cone the grid is uniform. The flat punch uses a uniform grid
    on $[0, a_0]$ (all its springs share one history, so any grid is exact).

    **Arguments:**

    - `cells`: number of cells $n$ (static). Default `DEFAULT_CELLS` = 64, which keeps the
      discretisation error of the force at about $2.5\times10^{-5}$ of its peak for an
      approach-hold-lift history (measured in `benchmarks/bench_foundation.py`; second
      order, $\propto n^{-2}$, over approach and hold: $1.9\times10^{-5}$ with 64 cells,
      $7.6\times10^{-5}$ with 32; less regular on the lift, where springs are released
      between nodes: $2.1\times10^{-4}$ with 32 cells). The elastic solid and a
      lift from a fully relaxed state are exact on any grid. Use
      `simulate(..., estimate_error=True)` for an estimate for a given history.
    - `depth`: largest indentation $g_\max$ [m] the grid covers. Default, times $(1 + 1/n)$:
      under displacement control the largest input (the contact never extends beyond
      $g(x) = \max_t d(t)$); under compliant loading the indentation at which the relaxed
      force balances the spring at the largest drive position (an upper bound, since the
      viscoelastic force on a loading branch is never below the relaxed one), rounded up to
      1/8 of an octave so that the grid is piecewise constant in the parameters. When fitting
      with compliant loading pass `depth` explicitly: the grid is then fixed and the
      gradients are those of one discretised model.
    """

    cells: int = eqx.field(static=True, default=DEFAULT_CELLS)
    depth: Float[ArrayLike, ""] | None = None

    def __check_init__(self):
        if int(self.cells) < 2:
            raise ValueError(f"`cells` must be >= 2; got {self.cells}.")
        if self.depth is not None:
            check_positive("depth", self.depth, "m")


class AbstractLoading(eqx.Module):
    """How the input history drives the indenter."""


class DisplacementControl(AbstractLoading):
    r"""Rigid loading (default): the input is the indentation $d(t)$ [m] itself."""


class CompliantLoading(AbstractLoading):
    r"""A spring of stiffness $k$ between the drive and the indenter (AFM cantilever).

    The input is the drive position $z(t)$ [m] (positive towards the sample, zero where the
    undeflected indenter touches the surface); the indentation follows from
    $k\,(z - d) = F$ (compressive $F$ positive), i.e. $d = z - F/k$. At every sample this
    scalar equation is solved by Newton's method on the full step (differentiated
    implicitly). The contact jumps off where its stiffness $\mathrm{d}F/\mathrm{d}d$ meets
    $-k$ (no equilibrium connected to the current one remains); the indenter then jumps to
    the free branch $d = z$. For $k \to \infty$ this is displacement control, for $k \to 0$
    force control (pull-off at the minimum of $F$; for an elastic parabola the jump-off
    force tends to $-\tfrac32\pi\Delta\gamma R$). A dead load $F(t)$ itself is not an
    input: drive a soft spring ($k$ well below the contact stiffness $8 G a$) with
    $z = F/k$; the applied force is then $F - k\,d$.

    **Arguments:**

    - `stiffness`: $k$ [N/m], > 0.
    - `newton_steps`: Newton iterations per sample (static, default 12).
    """

    stiffness: Float[ArrayLike, ""]
    newton_steps: int = eqx.field(static=True, default=12)

    def __check_init__(self):
        check_positive("stiffness", self.stiffness, "N/m")


# --------------------------------------------------------------------------------------
# Small numerical helpers
# --------------------------------------------------------------------------------------


def _psi(s):
    r"""$\psi(s) = 1 - (1 - e^{-s})/s$ for $s \ge 0$, $\psi(0) = 0$.

    Evaluated directly: its absolute error is of the order of the machine epsilon for every
    $s$ (the relative error grows like $\epsilon/s$ for small $s$, but $\psi$ only enters
    as the increment $\Delta u\,\psi$ added to a dashpot displacement, so the absolute error
    is what matters).
    """
    pos = s > 0
    ss = jnp.where(pos, s, 1.0)
    return jnp.where(pos, 1.0 + jnp.expm1(-ss) / ss, 0.0)


def _attached_update(v, u0, du, dt, tau):
    r"""Exact update of attached dashpots over `dt` with $u$ linear from `u0` by `du`.

    `v`: (..., N); `u0`, `du`, `dt`: (...) or scalars; returns (..., N).
    """
    s = jnp.asarray(dt)[..., None] / tau
    e = jnp.exp(-s)
    return v * e - jnp.asarray(u0)[..., None] * jnp.expm1(-s) + jnp.asarray(du)[..., None] * _psi(s)


def _concave_root(fn, lo, hi, steps):
    r"""Root of `fn` in [lo, hi] with fn(lo) >= 0 > fn(hi), fn concave there.

    Newton's method started at `hi` converges monotonically from the right for a concave
    function (each tangent lies above the graph); a bisection guard keeps the iterate inside
    the shrinking bracket. Differentiated implicitly (`lax.custom_root`).
    """
    lo = lax.stop_gradient(lo)
    hi = lax.stop_gradient(hi)

    def solve(f, _guess):
        def body(_, carry):
            a, b, x = carry
            fx, dfx = jax.jvp(f, (x,), (jnp.ones_like(x),))
            a = jnp.where(fx >= 0, x, a)
            b = jnp.where(fx >= 0, b, x)
            newton = x - fx / jnp.where(dfx == 0, 1.0, dfx)
            good = (dfx != 0) & jnp.isfinite(newton) & (newton >= a) & (newton <= b)
            x_new = jnp.where(good, newton, 0.5 * (a + b))
            return a, b, jnp.where(fx == 0, x, x_new)

        return lax.fori_loop(0, steps, body, (lo, hi, hi))[2]

    def tangent_solve(g, y):
        slope = g(jnp.ones_like(y))
        return y / jnp.where(slope == 0, 1.0, slope)

    return lax.custom_root(fn, hi, solve, tangent_solve)


def _safe_div(num, den, fallback=0.0):
    ok = den != 0
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), fallback)


class _Geometry:
    """Profile operations in the interpolation coordinate zeta (g, or x for the flat punch)."""

    def __init__(self, profile: AbstractProfile):
        self.profile = profile
        self.flat = isinstance(profile, FlatPunch)
        self.power = None if self.flat else _power_law_params(profile)

    def g(self, x):
        if self.flat:
            return jnp.zeros_like(x)
        return self.profile.g(x)

    def integral_g(self, x):
        if self.flat:
            return jnp.zeros_like(x)
        return self.profile.integral_g(x)

    def zeta(self, x):
        return x if self.flat else self.profile.g(x)

    def zeta_integral(self, x):
        return 0.5 * x**2 if self.flat else self.profile.integral_g(x)

    def zeta_inverse(self, y, lo, hi):
        """x in [lo, hi] with zeta(x) = y (zeta increasing)."""
        if self.flat:
            return y
        if self.power is not None:
            K, n = self.power
            return (jnp.maximum(y, 0.0) / K) ** (1.0 / n)
        return bracketed_root(lambda x: self.profile.g(x) - y, lo, hi, steps=48)

    def stationary(self, q, lo, hi):
        r"""Solution of $\sqrt{x}\,\zeta'(x) = q$ (maximiser of $-\beta\zeta + c\sqrt x$,
        $q = c/(2\beta)$), clipped to [lo, hi]; not differentiated."""
        q = lax.stop_gradient(q)
        lo = lax.stop_gradient(lo)
        hi = lax.stop_gradient(hi)
        if self.flat:
            x = q**2
        elif self.power is not None:
            K, n = lax.stop_gradient(self.power)
            x = (q / (n * K)) ** (1.0 / (n - 0.5))
        else:
            def h(x):
                return jnp.sqrt(x) * self.profile.dg(x) - q

            root = bracketed_root(h, lo, hi, steps=48)
            x = jnp.where(h(hi) <= 0, hi, jnp.where(h(lo) >= 0, lo, root))
        x = jnp.where(jnp.isfinite(x), x, hi)
        return jnp.clip(x, lo, hi)


# --------------------------------------------------------------------------------------
# The model: constants, cells, one step
# --------------------------------------------------------------------------------------


class _Model:
    """Constants of one simulation (closed over inside the traced function)."""

    def __init__(self, rheology, profile, work_of_adhesion, x_nodes, method):
        prony = rheology.to_prony()
        Gi = jnp.asarray(prony.G_inf, dtype=float)
        Gk = jnp.atleast_1d(jnp.asarray(prony.G, dtype=float))
        tau = jnp.atleast_1d(jnp.asarray(prony.tau, dtype=float))
        if Gk.shape[0] == 0:  # elastic: one inert arm keeps the shapes non-empty
            Gk = jnp.zeros((1,), dtype=Gi.dtype)
            tau = jnp.ones((1,), dtype=Gi.dtype)
        self.Gi, self.Gk, self.tau = Gi, Gk, tau
        self.Gg = Gi + jnp.sum(Gk)
        self.rho = Gk / self.Gg
        self.A = (self.rho[None, :] - jnp.eye(Gk.shape[0], dtype=Gi.dtype)) / tau[:, None]
        self.c = jnp.sqrt(8.0 * jnp.pi * jnp.asarray(work_of_adhesion, dtype=float) * self.Gg)
        self.geo = _Geometry(profile)
        # the elastic part of beta: 4 G_inf g(x) (absent for the flat punch, where g = 0)
        self.Gi_g = jnp.zeros_like(Gi) if self.geo.flat else Gi
        self.x = x_nodes
        self.n_nodes = x_nodes.shape[0]
        self.L = x_nodes[-1]
        self.gx = self.geo.g(x_nodes)
        self.zx = self.geo.zeta(x_nodes)
        self.Zx = self.geo.zeta_integral(x_nodes)
        self.sqrt_x = jnp.sqrt(x_nodes)
        inf = jnp.full((1,), jnp.inf, dtype=x_nodes.dtype)
        self.x_next = jnp.concatenate([x_nodes[1:], inf])
        self.z_next = jnp.concatenate([self.zx[1:], self.zx[-1:]])
        self.Z_next = jnp.concatenate([self.Zx[1:], self.Zx[-1:]])
        self.method = method

    def free_propagator(self, h):
        r"""$e^{A h}$ for the load-free springs, shape (len(h), N, N).

        $A = \mathrm{diag}(1/\tau)(\mathbf 1\rho^\top - I)$ is similar to the symmetric
        $B = y y^\top - \mathrm{diag}(1/\tau)$, $y_k = \sqrt{\rho_k/\tau_k}$, through
        $S = \mathrm{diag}(\sqrt{\rho_k\tau_k})$, so $e^{Ah} = S^{-1} Q e^{\Lambda h} Q^\top S$
        with one symmetric eigenproblem (its eigenvalues are minus the retardation rates).
        """
        if self.Gk.shape[0] == 1:
            return jnp.exp(self.A[None] * h[:, None, None])
        y = jnp.sqrt(self.rho / self.tau)
        lam, Q = jnp.linalg.eigh(y[:, None] * y[None, :] - jnp.diag(1.0 / self.tau))
        sig = jnp.sqrt(self.rho * self.tau)
        P = jnp.einsum("km,im,jm->ikj", Q, jnp.exp(lam[None, :] * h[:, None]), Q)
        return P * (sig[None, None, :] / sig[None, :, None])

    # ---- line load and criterion ----------------------------------------------------------

    def sqrt(self, x):
        return jnp.sqrt(jnp.maximum(x, 0.0))

    # ---- attached side: cells [x_j, min(x_{j+1}, a)] ----------------------------------------

    def attached_cells(self, V, vf, a, d):
        r"""Linear-in-zeta representation of $s = v + g$ on the contact side.

        Cell $j$ is $[x_j, \min(x_{j+1}, a)]$ (valid where $x_j < a$); inside it
        $R(x) = \alpha_j - \beta_j\zeta(x) + c\sqrt{x}$. Returns a dict of per-cell arrays
        (n_nodes,) or (n_nodes, N): valid, up_node, x_lo, x_hi, z_lo, z_hi, dz, s_lo, s_hi,
        slope, alpha, beta, R_nodes ($R$ at $x_j$).
        """
        x = self.x
        s_nodes = V + self.gx[:, None]
        s_next = jnp.concatenate([s_nodes[1:], s_nodes[-1:]], axis=0)
        s_front = vf + self.geo.g(a)
        valid = x < a
        up_node = self.x_next < a
        x_hi = jnp.where(up_node, self.x_next, a)
        z_hi = jnp.where(up_node, self.z_next, self.geo.zeta(a))
        s_hi = jnp.where(up_node[:, None], s_next, s_front[None, :])
        dz = z_hi - self.zx
        slope = _safe_div(s_hi - s_nodes, dz[:, None])
        Gs = s_nodes @ self.Gk
        Gm = slope @ self.Gk
        alpha = 4.0 * (self.Gg * d - Gs + Gm * self.zx)
        beta = 4.0 * (self.Gi_g + Gm)
        R_nodes = 4.0 * (self.Gg * d - self.Gi_g * self.zx - Gs) + self.c * self.sqrt_x
        return dict(
            valid=valid, up_node=up_node, x_lo=x, x_hi=x_hi, z_lo=self.zx, z_hi=z_hi, dz=dz,
            s_lo=s_nodes, s_hi=s_hi, slope=slope, alpha=alpha, beta=beta, R_nodes=R_nodes,
        )

    def cell_R(self, x, alpha, beta):
        return alpha - beta * self.geo.zeta(x) + self.c * self.sqrt(x)

    def force(self, V, vf, a, d):
        r"""$F = 8[G_g a d - G_\infty\int_0^a g - \sum_k G_k\int_0^a s_k]$ [N]."""
        x = self.x
        Gs = (V + self.gx[:, None]) @ self.Gk
        Gs_next = jnp.concatenate([Gs[1:], Gs[-1:]])
        Gs_front = jnp.sum(self.Gk * (vf + self.geo.g(a)))
        valid = x < a
        up_node = self.x_next < a
        h = jnp.where(valid, jnp.where(up_node, self.x_next, a) - x, 0.0)
        dz = jnp.where(valid, jnp.where(up_node, self.z_next, self.geo.zeta(a)) - self.zx, 0.0)
        Z_hi = jnp.where(up_node, self.Z_next, self.geo.zeta_integral(a))
        num = jnp.where(valid, Z_hi - self.Zx - self.zx * h, 0.0)
        w = jnp.where(dz > 0, num / jnp.where(dz > 0, dz, 1.0), 0.5 * h)
        Gs_hi = jnp.where(up_node, Gs_next, Gs_front)
        int_Gs = jnp.sum(jnp.where(valid, Gs * h + (Gs_hi - Gs) * w, 0.0))
        return 8.0 * (self.Gg * a * d - self.Gi * self.geo.integral_g(a) - int_Gs)

    def max_criterion(self, cells, a):
        """Largest value of R on [0, a] (concave R per cell assumed) and where it is.

        Returns (R_max, x_max, cell index of x_max); R_max carries gradients (envelope
        theorem), x_max does not.
        """
        valid = cells["valid"]
        R_nodes = jnp.where(valid, cells["R_nodes"], -jnp.inf)
        m = jnp.maximum(jnp.sum(valid) - 1, 0)  # last contact node; its cell ends at the front
        R_front = self.cell_R(a, cells["alpha"][m], cells["beta"][m])
        j_star = jnp.argmax(R_nodes)
        at_front = R_front >= R_nodes[j_star]
        c1 = jnp.where(at_front, m, jnp.maximum(j_star - 1, 0))
        c2 = jnp.where(at_front, m, j_star)

        def cell_max(j):
            lo, hi = cells["x_lo"][j], cells["x_hi"][j]
            al, be = cells["alpha"][j], cells["beta"][j]
            q = _safe_div(self.c, 2.0 * be, jnp.inf)
            xs = jnp.where(be > 0, self.geo.stationary(jnp.where(be > 0, q, 1.0), lo, hi), hi)
            cand = lax.stop_gradient(jnp.stack([lo, hi, xs]))
            vals = self.cell_R(cand, al, be)
            i = jnp.argmax(vals)
            return vals[i], cand[i]

        r1, x1 = cell_max(c1)
        r2, x2 = cell_max(c2)
        take2 = r2 >= r1
        return jnp.where(take2, r2, r1), jnp.where(take2, x2, x1), jnp.where(take2, c2, c1)

    # ---- propagation over one step ------------------------------------------------------------

    def propagate(self, Vp, gp, t0, t1, d0, d1, P):
        """Attached and free evolution of all points over the full step.

        `Vp`: (p, N) states, `gp`: (p,) g at the points. Returns (V_att, V_free, ok).
        """
        dt = t1 - t0
        if isinstance(self.method, DiffraxODE):
            return self._propagate_diffrax(Vp, gp, t0, t1, d0, d1)
        V_att = _attached_update(Vp, d0 - gp, d1 - d0, dt, self.tau)
        V_free = Vp @ P.T
        return V_att, V_free, jnp.asarray(True)

    def _propagate_diffrax(self, Vp, gp, t0, t1, d0, d1):
        method = self.method
        dt = t1 - t0
        rate = _safe_div(d1 - d0, dt)
        tau, A = self.tau, self.A
        has_span = dt > 0

        def field(t, y, args):
            va, vf = y
            d = d0 + rate * (t - t0)
            return ((d - gp)[:, None] - va) / tau, vf @ A.T

        # a zero-length step (instantaneous jump of d) leaves the dashpots unchanged
        t1_safe = jnp.where(has_span, t1, t0 + 1.0)
        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(field),
            method.solver,
            t0=t0,
            t1=t1_safe,
            dt0=None,
            y0=(Vp, Vp),
            saveat=diffrax.SaveAt(t1=True),
            stepsize_controller=diffrax.PIDController(rtol=method.rtol, atol=method.atol),
            max_steps=method.max_steps,
            throw=False,
        )
        va, vf = sol.ys
        va = jnp.where(has_span, va[0], Vp)
        vf = jnp.where(has_span, vf[0], Vp)
        ok = (sol.result == diffrax.RESULTS.successful) | jnp.logical_not(has_span)
        return va, vf, ok

    # ---- one step -------------------------------------------------------------------------------

    def step(self, state, t0, t1, d1, P, force_detach=False):
        r"""Advance the foundation from `state` (at t0) to t1 with $d$ linear to `d1`.

        `state` = (V (n_nodes, N), E (2, N), a, d0): node dashpots, the two sides of the
        edge (E[0] the attached edge spring at $a^-$, E[1] the free spring at $a^+$; they
        differ while the edge is pinned), contact radius, indentation. Returns
        (new_state, out) with
        out = dict(force, radius, jumped, theta_jump, ok, overflow).
        """
        V, E, a, d0 = state
        vf = E[0]
        x, gx, rho = self.x, self.gx, self.rho
        dt = t1 - t0
        dd = d1 - d0
        ga = self.geo.g(a)
        Vp = jnp.concatenate([V, E], axis=0)
        gp = jnp.concatenate([gx, ga[None], ga[None]])
        Vp_att, Vp_free, ok = self.propagate(Vp, gp, t0, t1, d0, d1, P)
        V_att, vf_att = Vp_att[:-2], Vp_att[-2]
        V_free, vf_free = Vp_free[:-2], Vp_free[-1]
        # when out of contact the edge sits at x = 0 and carries node 0's state
        vf_free = jnp.where(a > 0, vf_free, V_free[0])

        in_contact = a > 0
        q_edge = 4.0 * (self.Gg * (d1 - ga) - jnp.sum(self.Gk * vf_att))
        R_edge = q_edge + self.c * self.sqrt(a)
        phi_edge = d1 - ga - jnp.sum(rho * vf_free)
        recede = in_contact & ((R_edge < 0) | force_detach)
        advance = jnp.logical_not(recede) & (phi_edge > 0) & (a < self.L)
        branch = jnp.where(recede, 2, jnp.where(advance, 1, 0))

        def pinned(_):
            V_new = jnp.where((x < a)[:, None], V_att, V_free)
            E_new = jnp.stack([jnp.where(in_contact, vf_att, V_free[0]), vf_free])
            nan = jnp.asarray(jnp.nan, dtype=a.dtype)
            return V_new, E_new, a, jnp.asarray(False), nan, jnp.asarray(False)

        def advancing(_):
            # free side: cells [max(x_j, a), x_{j+1}] for x_{j+1} > a, v linear in zeta
            x_lo_n, x_hi_n = x[:-1], x[1:]
            beyond = x_lo_n > a
            x_lo = jnp.where(beyond, x_lo_n, a)
            z_lo = jnp.where(beyond, self.zx[:-1], self.geo.zeta(a))
            z_hi = self.zx[1:]
            v_lo = jnp.where(beyond[:, None], V_free[:-1], vf_free[None, :])
            v_hi = V_free[1:]
            phi_nodes = d1 - gx - V_free @ rho
            phi_lo = jnp.where(beyond, phi_nodes[:-1], phi_edge)
            phi_hi = phi_nodes[1:]
            stop = (x_hi_n > a) & (phi_hi < 0)
            exists = jnp.any(stop)
            j = jnp.argmax(stop)
            frac = _safe_div(phi_lo[j], phi_lo[j] - phi_hi[j])
            frac = jnp.clip(jnp.where(exists, frac, 1.0), 0.0, 1.0)
            z_star = z_lo[j] + frac * (z_hi[j] - z_lo[j])
            a_root = self.geo.zeta_inverse(z_star, x_lo[j], x_hi_n[j])
            a_new = jnp.where(exists, a_root, self.L)
            # springs touched during the step: free until theta, attached afterwards
            phi0 = d0 - gx - V @ rho
            theta = jnp.where(phi0 >= 0, 0.0, jnp.clip(_safe_div(phi0, phi0 - phi_nodes), 0, 1))
            v_theta = V + theta[:, None] * (V_free - V)
            V_touch = _attached_update(
                v_theta, d0 + theta * dd - gx, (1 - theta) * dd, (1 - theta) * dt, self.tau
            )
            V_new = jnp.where(
                (x < a)[:, None], V_att, jnp.where((x < a_new)[:, None], V_touch, V_free)
            )
            # the contact covers the whole grid (the flat punch): the edge is the last node
            vf_new = jnp.where(exists, v_lo[j] + frac * (v_hi[j] - v_lo[j]), V_touch[-1])
            nan = jnp.asarray(jnp.nan, dtype=a.dtype)
            E_new = jnp.stack([vf_new, vf_new])
            return V_new, E_new, a_new, jnp.asarray(False), nan, jnp.logical_not(exists)

        def receding(_):
            cells = self.attached_cells(V_att, vf_att, a, d1)
            R_max, x_max, c_max = self.max_criterion(cells, a)
            valid = cells["valid"]
            ok_nodes = valid & (cells["R_nodes"] >= 0)
            idx = jnp.arange(self.n_nodes)
            m_R = jnp.max(jnp.where(ok_nodes, idx, -1))
            x_mR = jnp.where(m_R >= 0, x[jnp.maximum(m_R, 0)], -jnp.inf)
            use_xmax = (R_max >= 0) & (x_max > x_mR)
            cell = jnp.where(use_xmax, c_max, jnp.maximum(m_R, 0))
            lo = jnp.where(use_xmax, x_max, x_mR)
            hi = cells["x_hi"][cell]
            jump = (R_max < 0) | force_detach
            lo = jnp.where(jump, 0.25 * a, lo)
            hi = jnp.where(jump, 0.75 * a, hi)
            al, be = cells["alpha"][cell], cells["beta"][cell]
            mid = 0.5 * (lo + hi)

            def resid(xx):
                # a harmless stand-in on lanes that jump off (finite derivative for the
                # implicit-function tangent)
                return jnp.where(jump, xx - mid, self.cell_R(xx, al, be))

            root = _concave_root(resid, lo, hi, steps=_ROOT_STEPS)
            a_new = jnp.where(jump, 0.0, root)
            s_edge = cells["s_lo"][cell] + cells["slope"][cell] * (
                self.geo.zeta(root) - cells["z_lo"][cell]
            )
            # springs released during the step: attached until theta, free afterwards.
            # Jump-off: theta from the edge criterion at t0 and max R at t1 (linear in time).
            R0 = 4.0 * (self.Gg * (d0 - ga) - jnp.sum(self.Gk * vf)) + self.c * self.sqrt(a)
            theta_jump = jnp.clip(_safe_div(R0, R0 - R_max, 1.0), 0.0, 1.0)
            theta_jump = jnp.where(jump, theta_jump, jnp.nan)
            theta_front = jnp.clip(_safe_div(a - x, a - a_new, 1.0), 0.0, 1.0)
            theta = jnp.where(jump, theta_jump, theta_front)
            theta = jnp.where(jnp.isfinite(theta), theta, 1.0)
            v_theta = _attached_update(V, d0 - gx, theta * dd, theta * dt, self.tau)
            V_rel = v_theta + (1 - theta)[:, None] * (v_theta @ P.T - v_theta)
            V_new = jnp.where(
                (x < a_new)[:, None], V_att, jnp.where((x < a)[:, None], V_rel, V_free)
            )
            vf_new = jnp.where(jump, V_new[0], s_edge - self.geo.g(root))
            E_new = jnp.stack([vf_new, vf_new])
            return V_new, E_new, a_new, jump, theta_jump, jnp.asarray(False)

        V_new, E_new, a_new, jumped, theta_jump, overflow = lax.switch(
            branch, (pinned, advancing, receding), None
        )
        F = jnp.where(a_new > 0, self.force(V_new, E_new[0], a_new, d1), 0.0)
        out = dict(
            force=F, radius=a_new, jumped=jumped, theta_jump=theta_jump,
            ok=ok, overflow=overflow & jnp.logical_not(jnp.asarray(self.geo.flat)),
        )
        return (V_new, E_new, a_new, d1), out

    # ---- jump-off refinement ---------------------------------------------------------------

    def refine_jumpoff(self, pre):
        r"""Solve $\max_x R(x, t) = 0$ inside the jump-off step (exact in-step evolution).

        `pre` = (V, vf, a, t0, t1, d0, d1) at the start of the step that jumped off (vf: the
        attached edge spring). The attached update is affine in $s$ with coefficients that
        do not depend on $x$, so inside the cell that holds the maximum the criterion is an
        explicit function of the step fraction $\theta$:
        $s_k(x, \theta) = e_k(\theta)\,s_k(x, 0) + b_k(\theta)$. The maximum of
        $R(\cdot, \theta)$ over that cell is then solved for $\theta$ by a scalar root.
        Returns (time, displacement, radius, force, valid); `valid` is False when the step
        does not bracket the fold.
        """
        V, vf, a, t0, t1, d0, d1 = pre
        dt, dd = t1 - t0, d1 - d0
        ga = self.geo.g(a)
        # the cell of the maximum at the end of the step (no derivative needed for the choice)
        V1 = _attached_update(V, d0 - self.gx, dd, dt, self.tau)
        vf1 = _attached_update(vf, d0 - ga, dd, dt, self.tau)
        cells1 = self.attached_cells(V1, vf1, a, d1)
        cell = lax.stop_gradient(self.max_criterion(cells1, a)[2])
        cells0 = self.attached_cells(V, vf, a, d0)
        s_lo0, slope0 = cells0["s_lo"][cell], cells0["slope"][cell]
        z_lo = cells0["z_lo"][cell]
        lo, hi = cells0["x_lo"][cell], cells0["x_hi"][cell]

        def coefficients(theta):
            s = jnp.asarray(theta * dt) / self.tau
            e = jnp.exp(-s)
            b = -d0 * jnp.expm1(-s) + theta * dd * _psi(s)
            Gs = jnp.sum(self.Gk * (s_lo0 * e + b))
            Gm = jnp.sum(self.Gk * slope0 * e)
            alpha = 4.0 * (self.Gg * (d0 + theta * dd) - Gs + Gm * z_lo)
            beta = 4.0 * (self.Gi_g + Gm)
            return alpha, beta, e, b

        def argmax(alpha, beta):
            q = _safe_div(self.c, 2.0 * beta, jnp.inf)
            xs = jnp.where(beta > 0, self.geo.stationary(jnp.where(beta > 0, q, 1.0), lo, hi), hi)
            cand = lax.stop_gradient(jnp.stack([lo, hi, xs]))
            vals = self.cell_R(cand, alpha, beta)
            return cand[jnp.argmax(vals)]

        def rmax(theta):
            alpha, beta, _, _ = coefficients(theta)
            return self.cell_R(argmax(alpha, beta), alpha, beta)

        valid = (rmax(0.0) >= 0) & (rmax(1.0) < 0)
        theta = bracketed_root(rmax, 0.0, 1.0, steps=48)
        alpha, beta, e, b = coefficients(theta)
        x_max = argmax(alpha, beta)
        # one Newton step on R'(x) = 0 at the converged maximiser: same value, and the exact
        # implicit derivative dx/dp = -R'_p / R'' when the maximum is interior to the cell
        dR = jax.grad(lambda xx: self.cell_R(xx, alpha, beta))
        d2R = jax.grad(dR)
        curv = d2R(x_max)
        good = (x_max > lo) & (x_max < hi) & (curv < 0)
        x_cell = jnp.where(good, x_max - dR(x_max) / jnp.where(good, curv, -1.0), x_max)
        d = d0 + theta * dd
        Va = _attached_update(V, d0 - self.gx, theta * dd, theta * dt, self.tau)
        vfa = _attached_update(vf, d0 - ga, theta * dd, theta * dt, self.tau)
        cells = self.attached_cells(Va, vfa, a, d)
        x_fold = self._fold_radius(cells, a, d, x_cell)
        n_last = jnp.maximum(jnp.sum(cells["valid"]) - 1, 0)
        c = jnp.clip(jnp.searchsorted(self.x, x_fold, side="right") - 1, 0, n_last)
        s_edge = cells["s_lo"][c] + cells["slope"][c] * (self.geo.zeta(x_fold) - cells["z_lo"][c])
        F = self.force(Va, s_edge - self.geo.g(x_fold), x_fold, d)
        return t0 + theta * dt, d, x_fold, F, valid

    def _fold_radius(self, cells, a, d, fallback):
        r"""Second-order maximiser of the criterion near the fold.

        The maximiser of the piecewise-linear interpolant is only first-order accurate (its
        slope is). Here the interpolated part $S = \sum_k G_k s_k$ is replaced by the
        quadratic in $\zeta$ through the spring of largest $R$ and its two neighbours, and
        $R = 4(G_g d - G_\infty g - S) + c\sqrt{x}$ is maximised by Newton's method (exact
        for the elastic, glass and relaxed limits, where $S$ is at most linear in $\zeta$).
        Falls back to `fallback` where those springs are not available.
        """
        valid = cells["valid"]
        R_nodes = jnp.where(valid, cells["R_nodes"], -jnp.inf)
        Gs = cells["s_lo"] @ self.Gk
        j = jnp.argmax(R_nodes)
        m = jnp.maximum(jnp.sum(valid) - 1, 0)
        Gs_front = jnp.sum(self.Gk * cells["s_hi"][m])
        jl = jnp.maximum(j - 1, 0)
        jr = jnp.minimum(j + 1, self.n_nodes - 1)
        right_is_node = valid[jr] & (jr > j)
        x0 = self.x[jl]
        x2 = jnp.where(right_is_node, self.x[jr], a)
        z0, z1 = self.zx[jl], self.zx[j]
        z2 = jnp.where(right_is_node, self.zx[jr], self.geo.zeta(a))
        S0, S1 = Gs[jl], Gs[j]
        S2 = jnp.where(right_is_node, Gs[jr], Gs_front)
        ok = (j >= 1) & (z2 > z1) & (z1 > z0)
        b1, c2 = _quadratic_through(z0, z1, z2, S0, S1, S2, ok)

        def R(x):
            z = self.geo.zeta(x)
            S = S0 + b1 * (z - z0) + c2 * (z - z0) * (z - z1)
            return 4.0 * (self.Gg * d - self.Gi_g * z - S) + self.c * self.sqrt(x)

        dR = jax.grad(R)
        d2R = jax.grad(dR)
        lo, hi = lax.stop_gradient(x0), lax.stop_gradient(x2)

        def newton(_, x):
            step = dR(x) / d2R(x)
            x_new = x - jnp.where(jnp.isfinite(step), step, 0.0)
            return jnp.clip(x_new, lo, hi)

        x_start = lax.stop_gradient(jnp.clip(fallback, x0, x2))
        xs = lax.fori_loop(0, 12, newton, x_start)
        curv = d2R(xs)
        ok = ok & (curv < 0) & (xs > lo) & (xs < hi) & jnp.isfinite(curv)
        # one Newton step with derivatives: the implicit derivative of the maximiser
        x_fold = xs - dR(xs) / jnp.where(ok, curv, -1.0)
        return jnp.where(ok, x_fold, fallback)

    def front_field(self, V, vf, a0, d0):
        r"""The attached field of a contact of radius `a0` as a function of the position.

        Returns `(field, cells)`: `field(x) -> (s(x), J(x))` for $0 \le x \le a_0$, the
        interpolated $s_k = v_k + g$ at $x$ and its integral $J_k(x) = \int_0^x s_k\,dx'$,
        exact over the interpolant (both of shape (N,)); `cells` from `attached_cells`.
        """
        cells = self.attached_cells(V, vf, a0, d0)
        valid = cells["valid"]
        h = jnp.where(valid, cells["x_hi"] - cells["x_lo"], 0.0)
        dz = jnp.where(valid, cells["dz"], 0.0)
        Z_hi = self.geo.zeta_integral(jnp.where(valid, cells["x_hi"], cells["x_lo"]))
        num = jnp.where(valid, Z_hi - self.Zx - self.zx * h, 0.0)
        w = jnp.where(dz > 0, num / jnp.where(dz > 0, dz, 1.0), 0.5 * h)
        full = cells["s_lo"] * h[:, None] + (cells["s_hi"] - cells["s_lo"]) * w[:, None]
        full = jnp.where(valid[:, None], full, 0.0)
        cum = jnp.cumsum(full, axis=0) - full  # integral over the cells below cell j
        n_last = jnp.maximum(jnp.sum(valid) - 1, 0)

        def field(x):
            c = jnp.clip(jnp.searchsorted(self.x, x, side="right") - 1, 0, n_last)
            hc = x - self.x[c]
            s_x = cells["s_lo"][c] + cells["slope"][c] * (self.geo.zeta(x) - self.zx[c])
            part = self.geo.zeta_integral(x) - self.Zx[c] - self.zx[c] * hc
            J = cum[c] + cells["s_lo"][c] * hc + cells["slope"][c] * part
            return s_x, J

        return field, cells

    def refine_instability(self, pre, z0, z1, k):
        r"""Jump-off inside a step under a compliant loading system of stiffness `k`.

        Inside the step the drive is $z(\theta) = z_0 + \theta(z_1 - z_0)$ and the
        indentation is taken linear in time from $d_0$ to its value $d$ at $\theta$, so
        the attached field is $s_k(x, \theta) = e_k s_k(x, 0) - d_0(e_k - 1)
        + (d - d_0)\psi_k$ ($e_k = e^{-\theta\Delta t/\tau_k}$, $\psi_k =
        \psi(\theta\Delta t/\tau_k)$): affine in $d$. For a front at $x$ the criterion
        $R(x, \theta, d) = 0$ then gives $d_R(x, \theta)$ explicitly, and the drive position
        that holds that front in equilibrium is $z_\mathrm{eq}(x, \theta) = d_R + F/k$.
        Equilibria exist while $z(\theta) \ge \min_x z_\mathrm{eq}(x, \theta)$; the
        contact jumps off at the root $\theta^*$ of
        $H(\theta) = z(\theta) - \min_x z_\mathrm{eq}(x, \theta)$, at the minimiser
        $x^*$ (where $\mathrm{d}F/\mathrm{d}d = -k$ along the front, or the criterion's fold
        for a stiff spring, or the edge itself when a pinned edge is already unstable as
        it starts to recede). Exact for an elastic solid (no time dependence);
        otherwise as accurate as the linear-in-time indentation inside a step.
        The minimum over $x$ is a golden-section search (one minimum on $[0, a]$ assumed),
        differentiated by the envelope theorem; $x^*$ by one Newton step on
        $\partial_x z_\mathrm{eq} = 0$.

        `pre` = (V, vf, a, t0, t1, d0, d1) at the start of the step that jumped off.
        Returns (time, displacement, radius, force, valid); `valid` is False when the step
        does not bracket the instability.
        """
        V, vf, a, t0, t1, d0, _ = pre
        dt = t1 - t0
        field, cells = self.front_field(V, vf, a, d0)

        def equilibrium(x, theta):
            sc = jnp.asarray(theta * dt) / self.tau
            e, m1, ps = jnp.exp(-sc), jnp.expm1(-sc), _psi(sc)
            s_x, J = field(x)
            P = jnp.sum(self.Gk * ps)
            # R = 4 (G_g d - G_inf g - sum G_k s_k) + c sqrt(x) = 0, solved for d
            rest = self.Gi_g * self.geo.zeta(x) + jnp.sum(self.Gk * (e * s_x - d0 * m1))
            d = (rest - d0 * P - 0.25 * self.c * self.sqrt(x)) / (self.Gg - P)
            b = -d0 * m1 + (d - d0) * ps
            F = self.Gg * x * d - self.Gi * self.geo.integral_g(x)
            F = 8.0 * (F - jnp.sum(self.Gk * (e * J + b * x)))
            return d, F

        def z_eq(x, theta):
            d, F = equilibrium(x, theta)
            return d + F / k

        ratio = 0.5 * (np.sqrt(5.0) - 1.0)
        a_sg = lax.stop_gradient(a)

        def argmin(theta):
            theta = lax.stop_gradient(theta)

            def golden(_, carry):
                lo, hi = carry
                x1 = hi - ratio * (hi - lo)
                x2 = lo + ratio * (hi - lo)
                f1 = z_eq(x1, theta)
                f2 = z_eq(x2, theta)
                left = f1 <= f2
                return jnp.where(left, lo, x1), jnp.where(left, x2, hi)

            zero = jnp.zeros_like(a_sg)
            lo, hi = lax.fori_loop(0, 60, golden, (zero, a_sg))
            mid = 0.5 * (lo + hi)
            # golden section resolves a smooth minimum to ~sqrt(eps) only: polish by Newton
            # steps, kept where they are as small as that (not across a kink of the
            # interpolant, where the minimum is the kink itself)
            dz = jax.grad(z_eq)
            d2z = jax.grad(dz)

            def polish(_, x):
                step = dz(x, theta) / d2z(x, theta)
                small = jnp.isfinite(step) & (jnp.abs(step) < 1e-6 * a_sg)
                return jnp.clip(jnp.where(small, x - step, x), 0.0, a_sg)

            mid = lax.fori_loop(0, 3, polish, mid)
            # the minimum at the edge itself (a pinned edge unstable as it starts to recede)
            return jnp.where(a_sg - mid < 1e-9 * a_sg, a_sg, mid)

        def at_min(theta):
            xs = argmin(theta)
            # envelope theorem: the value at the fixed interior minimiser; at the edge the
            # edge moves with the parameters
            x = jnp.where(xs == a_sg, a, lax.stop_gradient(xs))
            return x

        def H(theta):
            return z0 + theta * (z1 - z0) - z_eq(at_min(theta), theta)

        valid = (H(0.0) >= 0) & (H(1.0) < 0)
        theta = bracketed_root(H, 0.0, 1.0, steps=48)
        x = at_min(theta)
        interior = lax.stop_gradient(x) < a_sg
        dz = jax.grad(z_eq)
        d2z = jax.grad(dz)
        curv = d2z(x, theta)
        good = interior & (curv > 0) & jnp.isfinite(curv)
        # the implicit derivative of the minimiser, dx/dp = -(d z'/dp) / z'' (a Newton step
        # on z' = 0 that only enters the derivative: the value stays the converged one)
        slope = dz(x, theta)
        x = jnp.where(good, x - (slope - lax.stop_gradient(slope)) / jnp.where(good, curv, 1.0), x)
        x = jnp.where(interior, self._instability_radius(cells, a, d0, dt, theta, k, x), x)
        d, F = equilibrium(x, theta)
        return t0 + theta * dt, d, x, F, valid

    def _instability_radius(self, cells, a, d0, dt, theta, k, fallback):
        r"""Second-order location of an interior minimum of $z_\mathrm{eq}(x, \theta)$.

        The slope of the piecewise-linear interpolant is only first-order accurate, so is
        the minimiser found on it. Here the interpolated part
        $S_e(x) = \sum_k G_k e_k s_k(x, 0)$ is replaced by the quadratic in $\zeta$ through
        three springs around the minimum (exact for the elastic, glass and relaxed limits,
        as in `_fold_radius`) and $\partial_x z_\mathrm{eq} = 0$ is solved by Newton's
        method, with one final step carrying the implicit derivative. Falls back to
        `fallback` where those springs are not available.
        """
        sc = jnp.asarray(theta * dt) / self.tau
        e, m1, ps = jnp.exp(-sc), jnp.expm1(-sc), _psi(sc)
        P = jnp.sum(self.Gk * ps)
        B0 = -d0 * jnp.sum(self.Gk * m1)
        den = self.Gg - P
        S_nodes = (cells["s_lo"] * e[None, :]) @ self.Gk
        m = jnp.maximum(jnp.sum(cells["valid"]) - 1, 0)  # last node in contact
        S_front = jnp.sum(self.Gk * e * cells["s_hi"][m])
        xs = lax.stop_gradient(fallback)
        c = jnp.clip(jnp.searchsorted(self.x, xs, side="right") - 1, 0, m)
        n1 = self.n_nodes - 1
        up_node = cells["up_node"][c]
        z_up = jnp.where(up_node, self.zx[jnp.minimum(c + 1, n1)], self.geo.zeta(a))
        S_up = jnp.where(up_node, S_nodes[jnp.minimum(c + 1, n1)], S_front)
        x_up = jnp.where(up_node, self.x[jnp.minimum(c + 1, n1)], a)
        # springs c-1, c and the upper end of cell c; c-2, c-1, c if that end is very close
        # to spring c (the front just past it)
        short = (z_up - self.zx[c]) < 0.1 * (self.zx[c] - self.zx[jnp.maximum(c - 1, 0)])
        i0 = jnp.where(short, c - 2, c - 1)
        j0, j1 = jnp.maximum(i0, 0), jnp.maximum(i0 + 1, 0)
        z0, z1 = self.zx[j0], self.zx[j1]
        z2 = jnp.where(short, self.zx[c], z_up)
        S0, S1 = S_nodes[j0], S_nodes[j1]
        S2 = jnp.where(short, S_nodes[c], S_up)
        ok = (i0 >= 0) & (z2 > z1) & (z1 > z0)
        b1, c2 = _quadratic_through(z0, z1, z2, S0, S1, S2, ok)
        dzeta = jax.grad(self.geo.zeta)

        def slope(x):
            # d z_eq / dx with z_eq = d_R + F / k and the quadratic S_e
            zz, zd = self.geo.zeta(x), dzeta(x)
            S = S0 + b1 * (zz - z0) + c2 * (zz - z0) * (zz - z1)
            Sp = (b1 + c2 * (2.0 * zz - z0 - z1)) * zd
            dR = (self.Gi_g * zz + S + B0 - d0 * P - 0.25 * self.c * self.sqrt(x)) / den
            dRp = (self.Gi_g * zd + Sp - 0.125 * self.c / self.sqrt(x)) / den
            Fp = self.Gg * (dR + x * dRp) - self.Gi * self.geo.g(x) - S - B0
            Fp = 8.0 * (Fp - (dR - d0) * P - x * P * dRp)
            return dRp + Fp / k

        curvature = jax.grad(slope)
        lo = lax.stop_gradient(self.x[j0])
        hi = lax.stop_gradient(jnp.where(short, self.x[c], x_up))

        def newton(_, x):
            step = slope(x) / curvature(x)
            return jnp.clip(x - jnp.where(jnp.isfinite(step), step, 0.0), lo, hi)

        xq = lax.stop_gradient(lax.fori_loop(0, 8, newton, jnp.clip(xs, lo, hi)))
        curv = curvature(xq)
        ok = ok & (curv > 0) & jnp.isfinite(curv) & (xq > lo) & (xq < hi)
        # one Newton step with derivatives: the implicit derivative of the minimiser
        x = xq - slope(xq) / jnp.where(ok, curv, 1.0)
        return jnp.where(ok, x, fallback)

    def front_minimum(self, pre, a_end):
        r"""Smallest force along a receding front inside one step (dense output).

        The attached field is affine in time with $x$-independent coefficients,
        $s_k(x, \theta) = e_k(\theta)s_k(x, 0) + b_k(\theta)$, so for a front position
        $a$ in $[a_\mathrm{end}, a_\mathrm{start}]$ the time $\theta(a)$ at which the front
        passes solves the scalar criterion $R(a, \theta) = 0$, and the force there is
        $F = 8[G_g a d - G_\infty\int_0^a g - \sum_k G_k(e_k J_k(a) + b_k a)]$ with
        $J_k(a) = \int_0^a s_k(x, 0)\,dx$, minimised over $a$ by a golden-section search.
        `pre` = (V, vf, a_start, t0, t1, d0, d1). Returns `inf` if the front does not
        recede.
        """
        V, vf, a0, t0, t1, d0, d1 = pre
        dt, dd = t1 - t0, d1 - d0
        recedes = (a_end < a0) & (a_end > 0)
        a_end = jnp.where(recedes, a_end, 0.5 * a0)
        field, _ = self.front_field(V, vf, a0, d0)

        def e_b(theta):
            sc = jnp.asarray(theta * dt) / self.tau
            return jnp.exp(-sc), -d0 * jnp.expm1(-sc) + theta * dd * _psi(sc)

        e1, b1 = e_b(1.0)

        def at(a):
            s_a, J = field(a)
            za = self.geo.zeta(a)

            def R(theta):
                e, b = e_b(theta)
                q = self.Gg * (d0 + theta * dd) - self.Gi_g * za - jnp.sum(self.Gk * (e * s_a + b))
                return 4.0 * q + self.c * self.sqrt(a)

            theta = bracketed_root(R, 0.0, 1.0, steps=40)
            # the ends: the front is already there at t0 (receding), or only at t1
            edge = self.c * self.sqrt(a) - 4.0 * self.Gi_g * za
            R0 = 4.0 * (self.Gg * d0 - jnp.sum(self.Gk * s_a)) + edge
            R1 = 4.0 * (self.Gg * d1 - jnp.sum(self.Gk * (e1 * s_a + b1))) + edge
            theta = jnp.where(R0 <= 0, 0.0, jnp.where(R1 >= 0, 1.0, theta))
            e, b = e_b(theta)
            d = d0 + theta * dd
            F = self.Gg * a * d - self.Gi * self.geo.integral_g(a)
            F = F - jnp.sum(self.Gk * (e * J + b * a))
            return 8.0 * F

        # golden-section search over the front path (F is continuous in a; one minimum per
        # step assumed)
        lo = lax.stop_gradient(a_end)
        hi = lax.stop_gradient(a0)
        ratio = 0.5 * (np.sqrt(5.0) - 1.0)

        def golden(_, carry):
            lo, hi = carry
            x1 = hi - ratio * (hi - lo)
            x2 = lo + ratio * (hi - lo)
            f1, f2 = lax.stop_gradient(jax.vmap(at)(jnp.stack([x1, x2])))
            left = f1 <= f2
            return jnp.where(left, lo, x1), jnp.where(left, x2, hi)

        lo, hi = lax.fori_loop(0, 48, golden, (lo, hi))
        # derivatives: at an interior minimum (smooth, or at the kink of a spring) only the
        # partial derivative at the fixed minimiser counts (envelope theorem); at an end of
        # the path the end moves with the parameters
        mid = 0.5 * (lo + hi)
        tol = 1e-8 * (a0 - a_end)
        x_best = jnp.where(
            mid - a_end < tol, a_end, jnp.where(a0 - mid < tol, a0, lax.stop_gradient(mid))
        )
        best = at(x_best)
        return jnp.where(recedes, best, jnp.inf)


def _quadratic_through(z0, z1, z2, S0, S1, S2, ok):
    r"""Newton form $S(z) = S_0 + b_1 (z - z_0) + c_2 (z - z_0)(z - z_1)$ of the quadratic
    through three points; returns $(b_1, c_2)$. `ok` marks lanes with $z_0 < z_1 < z_2$
    (elsewhere the spacings are replaced by 1, so that nothing divides by zero)."""
    h0 = jnp.where(ok, z1 - z0, 1.0)
    h1 = jnp.where(ok, z2 - z1, 1.0)
    b1 = (S1 - S0) / h0
    return b1, ((S2 - S1) / h1 - b1) / (h0 + h1)


# --------------------------------------------------------------------------------------
# Grid
# --------------------------------------------------------------------------------------


def _grid_nodes(geo: _Geometry, cells: int, depth) -> Array:
    """Node positions x_j (cells + 1,), uniform in zeta = g (in x for the flat punch)."""
    frac = jnp.linspace(0.0, 1.0, cells + 1)
    if geo.flat:
        return jnp.asarray(geo.profile.radius, dtype=float) * frac
    depth = jnp.asarray(depth, dtype=float)
    if geo.power is not None:
        K, n = geo.power
        return (frac * depth / K) ** (1.0 / n)
    amax = jnp.asarray(geo.profile.max_radius, dtype=float)
    top = jnp.where(jnp.isfinite(amax), amax, 1.0)

    def one(y):
        return bracketed_root(lambda xx: geo.profile.g(xx) - y, 0.0 * top, top, steps=80)

    return jax.vmap(one)(frac * depth)


def _compliant_depth(rheology, profile, stiffness, z_max):
    r"""Largest indentation reachable through a spring $k$ driven to `z_max` [m].

    On a touch-rule loading branch the viscoelastic force is at least the relaxed one,
    $F \ge F_\infty(d) = 8G_\infty(a d - \int_0^a g)$ with $g(a) = d$, so the indentation
    never exceeds the root of $d + F_\infty(d)/k = z_\max$.
    """
    G_inf = jnp.asarray(rheology.to_prony().G_inf, dtype=float)
    k = jnp.asarray(stiffness, dtype=float)

    def resid(d):
        a = profile_radius(profile, d)
        return d + 8.0 * G_inf * (a * d - profile.integral_g(a)) / k - z_max

    root = bracketed_root(resid, 0.0 * z_max, z_max, steps=80)
    return jnp.where(z_max > 0, root, z_max)


# --------------------------------------------------------------------------------------
# Public entry point
# --------------------------------------------------------------------------------------


def simulate(
    rheology,
    profile: AbstractProfile,
    work_of_adhesion: Float[ArrayLike, ""],
    ts: Float[ArrayLike, " n"],
    displacement: Float[ArrayLike, " n"],
    *,
    loading: AbstractLoading = DisplacementControl(),
    grid: FoundationGrid | int | None = None,
    method: AbstractMethod = ExactUpdate(),
    estimate_error: bool = False,
    throw: bool = True,
) -> ContactSolution:
    r"""Simulate an adhesive viscoelastic contact under any loading history.

    The sample is virgin (unstressed, no memory) before `ts[0]`; the input is piecewise
    linear between samples. If `displacement[0] > 0` the indentation up to it is applied
    instantaneously at `ts[0]` (glass response).

    **Arguments:**

    - `rheology`: any rheology (`StandardModel`, `CreepChain`, `PronySeries`, `Elastic`);
      shear moduli [Pa] of an incompressible half-space (foundation stiffness $4G$ per
      length).
    - `profile`: any profile (`Parabola`, `Cone`, `PowerLaw`, `FlatPunch`, `Tabulated`).
    - `work_of_adhesion`: $\Delta\gamma$ [J/m²], > 0.
    - `ts`: sample times [s], shape `(n,)`, non-decreasing (equal times give a jump).
    - `displacement`: the input at `ts` [m], shape `(n,)`: the indentation $d(t)$ (positive
      into the sample) under `DisplacementControl()`, the drive position $z(t)$ under
      `CompliantLoading(k)`. Any shape of history: approach, hold, lift, cycles.
    - `loading`: `DisplacementControl()` (default) or `CompliantLoading(stiffness)`.
    - `grid`: a `FoundationGrid`, or an int (number of cells); default
      `FoundationGrid()` (`DEFAULT_CELLS` cells uniform in touch depth, covering the
      largest input).
    - `method`: `ExactUpdate()` (default: exact exponential updates for piecewise-linear
      input) or `DiffraxODE(...)` (the dashpot ODEs of all springs integrated by diffrax over
      every sample interval; the same model, to the solver tolerance).
    - `estimate_error`: also solve on a grid with half the cells and report the Richardson
      estimate of the discretisation error of the force,
      $\max_t|F_n - F_{n/2}|/3$ [N] over the samples where both grids agree on being in
      contact, in `stats["discretisation_error"]` (relative to $\max_t|F_n|$ in
      `stats["relative_discretisation_error"]`), and of the jump-off time [s] and force [N]
      (`stats["jumpoff_time_error"]`, `stats["jumpoff_force_error"]`).
    - `throw`: raise on an error result (`solver_failed`: the diffrax solver failed or the
      contact outgrew the grid; `invalid_input`: non-finite values). With `False` the status
      is returned in `.result` (use under `vmap`).

    **Returns:** a `ContactSolution` with `displacement` the indentation $d(t)$ [m],
    `force` $F(t)$ [N] (compressive positive) and `contact_radius` $a(t)$ [m] at `ts`.

    - The jump-off fields refer to the first jump-off in the history (`nan` if none). Under
      displacement control the time is the root of $\max_x R(x, t) = 0$ inside the step,
      exact for the piecewise-linear input; under compliant loading it is the root of
      $z(t) = \min_x z_\mathrm{eq}(x, t)$ inside the step (see the module docstring: exact
      for an elastic solid, first order in the sample spacing for a viscoelastic one).
    - `max_tensile_force`: the most negative force, refined between samples (see the module
      docstring); 0 if the history never touches.
    - `result`: `detached` if the history ends out of contact, `in_contact` otherwise (a
      history may re-attach after a jump-off; `stats["jumpoffs"]` counts them), or an error.
    - `stats`: `cells`, `grid_radius` [m] and `nodes` [m] of the grid, `jumpoffs`,
      `grid_overflow`, `drive` (the input), `final_state` (the foundation state at `ts[-1]`:
      node dashpots, edge springs, radius, indentation), for compliant loading
      `newton_failures` (samples where Newton's method did not converge without losing the
      contact), and with `estimate_error` the error estimates above.

    Everything is differentiable with respect to the rheology, the profile, $\Delta\gamma$
    and the input, and works under `jit` and `vmap`.
    """
    check_positive("work_of_adhesion", work_of_adhesion, "J/m^2")
    ts = jnp.asarray(ts, dtype=float)
    if ts.ndim != 1 or ts.shape[0] < 1:
        raise ValueError(f"`ts` [s] must be a 1-D array with at least one time; got {ts.shape}.")
    check_finite("ts", ts, "s")
    if is_concrete(ts) and np.any(np.diff(np.asarray(ts)) < 0):
        i = int(np.argmax(np.diff(np.asarray(ts)) < 0))
        raise ValueError(f"`ts` [s] must be non-decreasing; ts[{i + 1}] < ts[{i}].")
    u = jnp.asarray(displacement, dtype=float)
    if u.shape != ts.shape:
        raise ValueError(
            f"`displacement` [m] must have the shape of `ts` {ts.shape}; got {u.shape}."
        )
    check_finite("displacement", u, "m")
    if grid is None:
        grid = FoundationGrid()
    elif isinstance(grid, int | np.integer):
        grid = FoundationGrid(cells=int(grid))
    if not isinstance(loading, DisplacementControl | CompliantLoading):
        raise TypeError(
            f"`loading` must be DisplacementControl() or CompliantLoading(k); got {loading!r}."
        )
    if not isinstance(method, ExactUpdate | DiffraxODE):
        raise TypeError(f"`method` must be ExactUpdate() or DiffraxODE(...); got {method!r}.")

    # one compiled program serves every call with the same configuration (types, static
    # options, shapes), whatever the parameter values
    rheology, profile, work_of_adhesion, loading, grid = _floats_to_arrays(
        (rheology, profile, work_of_adhesion, loading, grid)
    )
    sol = _simulate_jit(rheology, profile, work_of_adhesion, ts, u, loading, grid, method)
    if estimate_error:
        coarse = FoundationGrid(cells=max(grid.cells // 2, 2), depth=grid.depth)
        sol_c = _simulate_jit(rheology, profile, work_of_adhesion, ts, u, loading, coarse, method)
        # samples where one grid has jumped off and the other not are left out: near the
        # fold the front moves as sqrt(t* - t) and any shift of t* is a large force jump
        both = (sol.contact_radius > 0) == (sol_c.contact_radius > 0)
        err = jnp.max(jnp.where(both, jnp.abs(sol.force - sol_c.force), 0.0)) / 3.0
        scale = jnp.max(jnp.abs(sol.force))
        stats = dict(sol.stats)
        stats.update(
            discretisation_error=err,
            relative_discretisation_error=_safe_div(err, scale, jnp.nan),
            jumpoff_time_error=jnp.abs(sol.jumpoff_time - sol_c.jumpoff_time) / 3.0,
            jumpoff_force_error=jnp.abs(sol.jumpoff_force - sol_c.jumpoff_force) / 3.0,
        )
        sol = eqx.tree_at(lambda s: s.stats, sol, stats)
    if throw:
        force = sol.result.error_if(sol.force, is_error(sol.result))
        sol = eqx.tree_at(lambda s: s.force, sol, force)
    return sol


def _floats_to_arrays(tree):
    """Python and NumPy floats become arrays, weakly typed arrays strongly typed (the
    cache key of a compiled program holds the types, not the values)."""

    def convert(leaf):
        if isinstance(leaf, float | np.floating):
            return jnp.asarray(leaf, dtype=float)
        if isinstance(leaf, jax.Array) and getattr(leaf, "weak_type", False):
            return lax.convert_element_type(leaf, leaf.dtype)
        return leaf

    return jax.tree_util.tree_map(convert, tree)


def _simulate(rheology, profile, work_of_adhesion, ts, u, loading, grid, method):
    geo = _Geometry(profile)
    cells = int(grid.cells)
    if grid.depth is None:
        depth = jnp.maximum(jnp.max(u), 0.0)
        if isinstance(loading, CompliantLoading) and not geo.flat:
            # rounded up to 1/8 of an octave, so that the grid does not move with small
            # changes of the parameters (pass `depth` to fix it for a fit)
            bound = _compliant_depth(rheology, profile, loading.stiffness, depth)
            bound = jnp.exp2(jnp.ceil(8.0 * jnp.log2(jnp.maximum(bound, 1e-300))) / 8.0)
            depth = jnp.where(depth > 0, jnp.minimum(bound, depth), depth)
        depth = depth * (1.0 + 1.0 / cells)
    else:
        depth = jnp.asarray(grid.depth, dtype=float)
    depth = lax.stop_gradient(jnp.maximum(depth, jnp.finfo(float).tiny))
    x_nodes = lax.stop_gradient(_grid_nodes(geo, cells, depth))
    model = _Model(rheology, profile, work_of_adhesion, x_nodes, method)
    N = model.Gk.shape[0]
    dtype = model.Gi.dtype

    # one free-relaxation propagator per sample interval (the first one is a zero step)
    dts = jnp.diff(ts, prepend=ts[:1])
    P_all = model.free_propagator(dts)
    t_prev = jnp.concatenate([ts[:1], ts[:-1]])
    u_prev = jnp.concatenate([jnp.minimum(u[:1], 0.0), u[:-1]])

    V0 = jnp.zeros((model.n_nodes, N), dtype=dtype)
    vf0 = jnp.zeros((N,), dtype=dtype)
    E0 = jnp.zeros((2, N), dtype=dtype)
    a0 = jnp.zeros((), dtype=dtype)
    d_start = jnp.minimum(u[0], 0.0)
    state0 = (V0, E0, a0, d_start)
    pre0 = (V0, vf0, a0, ts[0], ts[0], d_start, d_start)
    inf = jnp.asarray(jnp.inf, dtype=dtype)
    compliant = isinstance(loading, CompliantLoading)

    def solve_compliant(state, t0, t1, z0, z1, P, S_prev):
        k = jnp.asarray(loading.stiffness, dtype=dtype)
        d0 = state[3]

        def f(d1):
            return k * (d1 - z1) + model.step(state, t0, t1, d1, P)[1]["force"]

        def newton(fn, guess):
            def body(_, x):
                fx, dfx = jax.jvp(fn, (x,), (jnp.ones_like(x),))
                dfx = jnp.where(dfx > 0.05 * k, dfx, k)
                return x - fx / dfx

            return lax.fori_loop(0, loading.newton_steps, body, lax.stop_gradient(guess))

        def tangent_solve(g, y):
            slope = g(jnp.ones_like(y))
            return y / jnp.where(jnp.abs(slope) > 1e-3 * k, slope, k)

        guess = d0 + (z1 - z0) * k / (k + jnp.maximum(S_prev, 0.0))
        d1 = lax.custom_root(f, guess, newton, tangent_solve)
        f1, df1 = jax.jvp(f, (d1,), (jnp.ones_like(d1),))
        scale = k * (jnp.abs(z1) + depth) + jnp.abs(f1 - k * (d1 - z1))
        converged = (jnp.abs(f1) <= 1e-8 * scale) & (df1 > 0)
        lost = jnp.logical_not(converged) & (state[2] > 0)
        d1 = jnp.where(lost, z1, d1)
        new_state, out = model.step(state, t0, t1, d1, P, force_detach=lost)
        out["newton_failed"] = jnp.logical_not(converged) & jnp.logical_not(lost)
        S = jnp.where(converged, df1 - k, 0.0)
        return new_state, out, S

    def body(carry, inp):
        state, pre, found, S_prev, min_pair, min_best = carry
        t0, t1, z0, z1, P = inp
        if compliant:
            new_state, out, S = solve_compliant(state, t0, t1, z0, z1, P, S_prev)
        else:
            new_state, out = model.step(state, t0, t1, z1, P)
            out["newton_failed"] = jnp.asarray(False)
            S = S_prev
        first = out["jumped"] & jnp.logical_not(found)
        V, E, a, d0 = state
        cand = (V, E[0], a, t0, t1, d0, new_state[3])
        pre = jax.tree_util.tree_map(lambda c, p: jnp.where(first, c, p), cand, pre)
        found = found | out["jumped"]
        # keep the states before and at the lowest force in contact (dense output after)
        lower = (new_state[2] > 0) & (out["force"] < min_best)
        pair = (V, E[0], a, new_state[0], new_state[1][0], new_state[2])
        min_pair = jax.tree_util.tree_map(lambda c, p: jnp.where(lower, c, p), pair, min_pair)
        min_best = jnp.where(lower, out["force"], min_best)
        ys = (new_state[3], out["force"], out["radius"], out["jumped"], out["ok"],
              out["overflow"], out["newton_failed"], S)
        carry = (new_state, pre, found, S, min_pair, min_best)
        return carry, ys

    zero = jnp.zeros((), dtype=dtype)
    pair0 = (V0, vf0, a0, V0, vf0, a0)
    carry0 = (state0, pre0, jnp.asarray(False), zero, pair0, inf)
    carry_end, ys = lax.scan(body, carry0, (t_prev, ts, u_prev, u, P_all))
    state_end, pre, found, _, min_pair, _ = carry_end
    d, force, radius, jumped, ok, overflow, newton_failed, stiff = ys

    # ---- jump-off ---------------------------------------------------------------------------
    nan = jnp.asarray(jnp.nan, dtype=dtype)
    i_j = jnp.argmax(jumped)
    # on lanes without a jump-off refine a harmless stand-in (a pinned toy state)
    V, vf, a, t0, t1, d0, d1 = pre
    safe = found & (a > 0)
    pre_safe = (
        jnp.where(safe, V, 0.0),
        jnp.where(safe, vf, 0.0),
        jnp.where(safe, a, x_nodes[-1] * 0.5),
        jnp.where(safe, t0, 0.0),
        jnp.where(safe, t1, 1.0),
        jnp.where(safe, d0, model.geo.g(x_nodes[-1] * 0.5)),
        jnp.where(safe, d1, -depth),
    )
    j_time, j_disp, j_rad, j_force, refined = model.refine_jumpoff(pre_safe)
    if compliant:
        # The instability is the fold of the drive position along the receding front: z(a)
        # has a minimum at the critical radius (dF/dd = -k there), solved inside the step
        # (`refine_instability`). Where the step does not bracket it (the contact was lost
        # by a failure of Newton's method elsewhere), fit parabolas z(a), F(a) through the
        # last three samples in contact and take the vertex.
        k = jnp.asarray(loading.stiffness, dtype=dtype)
        i_prev = jnp.maximum(i_j - 1, 0)
        inst = model.refine_instability(pre_safe, u[i_prev], u[i_j], k)
        idx = jnp.maximum(i_j - jnp.arange(3, 0, -1), 0)  # i_j-3, i_j-2, i_j-1
        a3, z3, f3 = radius[idx], u[idx], force[idx]
        usable = (i_j >= 3) & jnp.all(a3 > 0) & (a3[0] > a3[1]) & (a3[1] > a3[2])

        def parabola(y):
            # y(a) = y2 + b (a - a2) + c (a - a2)(a - a1), Newton form
            h1 = jnp.where(usable, a3[1] - a3[2], 1.0)
            h0 = jnp.where(usable, a3[0] - a3[2], 2.0)
            b = (y[1] - y[2]) / h1
            c = ((y[0] - y[2]) / h0 - b) / jnp.where(usable, a3[0] - a3[1], 1.0)
            return b, c

        bz, cz = parabola(z3)
        ok_c = usable & (cz > 0)
        # vertex of z(a): dz/da = b + c (2a - a2 - a1) = 0
        a_v = 0.5 * (a3[2] + a3[1]) - bz / (2 * jnp.where(ok_c, cz, 1.0))
        ok_c = ok_c & (a_v <= a3[2]) & (a_v >= a3[2] - 3 * (a3[0] - a3[2]))
        a_v = jnp.where(ok_c, a_v, a3[2])

        def at_vertex(y):
            b, c = parabola(y)
            return y[2] + b * (a_v - a3[2]) + c * (a_v - a3[2]) * (a_v - a3[1])

        z_v, f_v = at_vertex(z3), at_vertex(f3)
        dz = u[i_j] - z3[2]
        frac = jnp.clip(_safe_div(z_v - z3[2], dz), 0.0, 1.0)
        # an instability (no equilibrium left, the vertex) or the criterion itself (stiff
        # spring: the refined root as under displacement control), whichever the receding
        # front reaches first
        use_v = ok_c & (jnp.logical_not(refined) | (a_v > j_rad))
        j_time = jnp.where(
            use_v, jnp.where(ok_c, ts[idx[2]] + frac * (ts[i_j] - ts[idx[2]]), ts[i_j]), j_time
        )
        j_rad = jnp.where(use_v, a_v, j_rad)
        j_force = jnp.where(use_v, jnp.where(ok_c, f_v, force[idx[2]]), j_force)
        j_disp = jnp.where(use_v, jnp.where(ok_c, z_v - f_v / k, d[idx[2]]), j_disp)
        use_i = inst[4] & safe & (i_j >= 1)
        j_time, j_disp, j_rad, j_force = (
            jnp.where(use_i, new, old)
            for new, old in zip(inst[:4], (j_time, j_disp, j_rad, j_force), strict=True)
        )

    jumpoff_time = jnp.where(found, j_time, nan)
    jumpoff_disp = jnp.where(found, j_disp, nan)
    jumpoff_radius = jnp.where(found, j_rad, nan)
    jumpoff_force = jnp.where(found, j_force, nan)

    # ---- largest tensile force ------------------------------------------------------------
    # Candidates: the sample minimum; the minimum along the receding front inside the steps
    # before and after it (dense output, `front_minimum`, which includes the kink where a
    # pinned edge starts to recede; up to the jump-off radius when the contact jumps off in
    # the step after); the jump-off force.
    in_c = radius > 0
    f_masked = jnp.where(in_c, force, jnp.inf)
    i_m = jnp.argmin(f_masked)
    n_s = ts.shape[0]
    any_contact = jnp.any(in_c)
    f_min = jnp.where(any_contact, f_masked[i_m], 0.0)
    Vb, vfb, ab, Vm, vfm, am = min_pair
    im1, ip1 = jnp.maximum(i_m - 1, 0), jnp.minimum(i_m + 1, n_s - 1)
    before = (i_m > 0) & any_contact
    after = (i_m < n_s - 1) & any_contact
    a_after = jnp.where(found & (i_j == i_m + 1), jumpoff_radius, radius[ip1])
    # the two steps as a batch of two (one copy of the dense output in the program)
    steps_pre = (
        jnp.stack([Vb, Vm]),
        jnp.stack([vfb, vfm]),
        jnp.stack([jnp.where(before, ab, 0.0), jnp.where(after, am, 0.0)]),
        jnp.stack([ts[im1], ts[i_m]]),
        jnp.stack([ts[i_m], ts[ip1]]),
        jnp.stack([jnp.where(i_m > 0, d[im1], 0.0), d[i_m]]),
        jnp.stack([d[i_m], d[ip1]]),
    )
    ends = jnp.stack([jnp.where(before, am, 0.0), jnp.where(after, a_after, 0.0)])
    f_steps = jax.vmap(model.front_minimum)(steps_pre, ends)
    f_before, f_after = f_steps[0], f_steps[1]
    f_min = jnp.minimum(f_min, jnp.minimum(f_before, f_after))
    max_tensile = jnp.minimum(f_min, jnp.where(found, jumpoff_force, jnp.inf))

    # ---- status ---------------------------------------------------------------------------
    result = RESULTS.where(radius[-1] > 0, RESULTS.in_contact, RESULTS.detached)
    failed = jnp.logical_not(jnp.all(ok)) | jnp.any(overflow)
    result = RESULTS.where(failed, RESULTS.solver_failed, result)
    finite = jnp.all(jnp.isfinite(force)) & jnp.all(jnp.isfinite(radius))
    finite = finite & jnp.all(jnp.isfinite(u)) & jnp.all(jnp.isfinite(ts))
    finite = finite & jnp.isfinite(model.c) & jnp.isfinite(model.Gg)
    finite = finite & jnp.all(jnp.isfinite(model.tau)) & jnp.isfinite(model.Gi)
    result = RESULTS.where(finite, result, RESULTS.invalid_input)

    stats = dict(
        cells=jnp.asarray(cells),
        grid_radius=x_nodes[-1],
        nodes=x_nodes,
        jumpoffs=jnp.sum(jumped),
        grid_overflow=jnp.any(overflow),
        drive=u,
        final_state=state_end,
    )
    if compliant:
        stats["newton_failures"] = jnp.sum(newton_failed)
    return ContactSolution(
        ts=ts,
        displacement=d,
        force=force,
        contact_radius=radius,
        max_tensile_force=max_tensile,
        jumpoff_time=jumpoff_time,
        jumpoff_force=jumpoff_force,
        jumpoff_radius=jumpoff_radius,
        jumpoff_displacement=jumpoff_disp,
        result=result,
        stats=stats,
    )


# compiled once per configuration and cached: an eager call of `simulate` compiles the whole
# history loop (scan, refinements) as one program instead of dispatching its parts one by one
_simulate_jit = eqx.filter_jit(_simulate)
