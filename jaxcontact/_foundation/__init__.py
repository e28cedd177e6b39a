r"""Adhesive viscoelastic contact under arbitrary loading histories: the MDR foundation.

A rigid axisymmetric indenter with MDR profile $g(x)$ is driven into a viscoelastic
half-space by any sampled history (approach, hold, lift, repeated cycles). Unlike the
relaxed-start model (`retract`), springs enter the contact at different times and carry
different histories, so the state is a field over $x$ (`docs/physics.md` §5): the MDR foundation is
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
- *Free* springs ($|x| > a$) carry no load, $q = 0$, so $u = \sum_m r_m v_m$ with the arm
  ratios $r_m = G_m/G_g$ (`arm_ratio`) and $\dot v = A v$,
  $A_{km} = (r_m - \delta_{km})/\tau_k$; exact update $v \leftarrow e^{A\Delta} v$. A free
  spring recovers towards $u = 0$ with the retardation
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
(paper eq. 10-11, `docs/physics.md` §3) $q(a) = -\sqrt{8\pi a\,\Delta\gamma\,G_g}$. The front is the
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
takes it linear in time; measured by `benchmarks/bench_foundation.py`, results in
`benchmarks/results/forward.md`).

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
state inside a step (located by linear interpolation in time; exact for virgin springs).
The error against the number of cells, and the estimate of `estimate_error=True` (which
overestimates it), are measured by `benchmarks/bench_foundation.py` (results in
`benchmarks/results/forward.md`).

**Time integration.** `ExactUpdate()` (default) uses the closed-form updates above for the
piecewise-linear input: no time-step error. `DiffraxODE(...)` integrates the dashpot ODEs of
all springs over every sample interval with a diffrax solver instead (the same model to the
solver tolerance; the partial steps of springs that change state inside an interval use the
same closed forms in both).

Note: this model gives $\Delta\gamma_\mathrm{eff} = \Delta\gamma G_g/G_\infty$ already at slow
pulling, unlike classical viscoelastic crack theories (Schapery, Greenwood-Johnson,
Persson-Brener); do not validate it against those.
"""

from ._loading import AbstractLoading as AbstractLoading
from ._loading import CompliantLoading as CompliantLoading
from ._loading import DisplacementControl as DisplacementControl
from ._loading import ForceControl as ForceControl
from ._loading import SpringEquation as SpringEquation
from ._options import DEFAULT_CELLS as DEFAULT_CELLS
from ._options import FoundationGrid as FoundationGrid
from ._simulate import simulate as simulate
from ._state import FoundationState as FoundationState
