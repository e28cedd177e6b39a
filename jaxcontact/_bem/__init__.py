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

**Force control and compliant loading.** With a prescribed force $F$ (dead load,
`loading=ForceControl()`) or a spring $k$ between the drive $z$ and the indenter
($F = k(z - d)$, `loading=CompliantLoading(k)`) the indentation is an unknown: at a fixed
attached set, $d$ solves the loading's `SpringEquation` $F(d) + kd = $ ($F$ or $kz$) by
Newton's method (`_root.newton_iterate`, the loop that `simulate` uses as well)
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

**Modules.** `_kernel` (the grid, Love's kernel and its FFT convolution), `_surfaces` (the
indenter height maps), `_solver` (constrained CG, the equilibrium at a fixed attached set,
the cell rule, `bem_contact`) and `_history` (`bem_simulate`: the load steps, the creep
update, the jump-off).

Conventions: SI units; indentation positive into the sample; force positive when compressive
and negative when adhesive; shear moduli of an incompressible half-space ($E^* = 4G$).
"""

from .._solution import BEMSolution as BEMSolution
from ._history import bem_simulate as bem_simulate
from ._kernel import BEMGrid as BEMGrid
from ._kernel import love_displacement as love_displacement
from ._solver import bem_contact as bem_contact
from ._surfaces import bem_heights as bem_heights
from ._surfaces import ellipsoid_heights as ellipsoid_heights
from ._surfaces import pyramid_heights as pyramid_heights
from ._surfaces import self_affine_heights as self_affine_heights
from ._surfaces import tilted_flat_heights as tilted_flat_heights

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
