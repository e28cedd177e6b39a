"""`simulate`: the history loop over the samples and the assembly of its solution."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import ArrayLike, Float

from .. import _sharding
from .._checks import (
    Requirement,
    check_eagerly,
    constraint,
    domain,
    domain_plausibility,
    fold_checks,
    plausibility,
    traced_checks,
)
from .._method import AbstractMethod, ExactUpdate
from .._probes import check_depth_limit, depth_limit
from .._profiles import AbstractProfile, compiled_contact_radius
from .._rheology import AbstractRheology
from .._sharding import pick
from .._solution import (
    RESULTS,
    ContactSolution,
    ErrorEstimate,
    FoundationDetails,
    raise_if_error,
)
from .._solvers import as_float, cast_floats, float64_scope, float_dtype, safe_div, smallest
from .._validate import (
    Constraint,
    check_contact_radius,
    check_finite,
    check_times,
    contact_radius_plausible,
    contact_radius_valid,
    is_concrete,
    plausibility_enabled,
    times_ok,
    unchecked,
)
from ._events import front_minimum, refine_jumpoff
from ._loading import AbstractLoading, DisplacementControl
from ._model import _Model
from ._options import FoundationGrid
from ._state import FoundationState, StepStart, _Carry, _MinimumPair


@float64_scope
def simulate(
    rheology: AbstractRheology,
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
    - `profile`: any profile (`Sphere`, `Parabola`, `Cone`, `PowerLaw`, `FlatPunch`,
      `Tabulated`); with `Sphere` and displacement control the displacement may not exceed
      its `depth_limit` (1.74 R).
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
      contact, and of the jump-off time [s] and force [N], in
      `details.error_estimate` (an `ErrorEstimate`).
    - `throw`: raise on an error result (invalid or implausible input; `solver_failed`: the
      diffrax solver failed or the contact outgrew the grid; `non_finite_result`),
      whichever field is read. With `False` the status is returned in `.result` per lane
      (use under `vmap`), and the fields of a lane with invalid input are NaN.

    Precision: float32 when every floating input is float32, float64 otherwise (Python
    floats take the precision of the arrays they meet).

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
      history may re-attach after a jump-off; `jumpoffs` counts them), or an error.
    - `details`: a `FoundationDetails` (the grid, the input, the final state, the compliant
      loading's Newton failures, the error estimate).

    Everything is differentiable with respect to the rheology, the profile, $\Delta\gamma$
    and the input, and works under `jit` and `vmap`.
    """
    if not isinstance(rheology, AbstractRheology):
        raise TypeError(f"`rheology` must be an AbstractRheology; got {type(rheology).__name__}.")
    if not isinstance(profile, AbstractProfile):
        raise TypeError(f"`profile` must be an AbstractProfile; got {type(profile).__name__}.")
    if not isinstance(loading, AbstractLoading):
        raise TypeError(
            "`loading` must be an AbstractLoading (DisplacementControl() or "
            f"CompliantLoading(k)); got {loading!r}."
        )
    if not isinstance(method, AbstractMethod):
        raise TypeError(f"`method` must be ExactUpdate() or DiffraxODE(...); got {method!r}.")
    if grid is None:
        grid = FoundationGrid()
    elif isinstance(grid, int | np.integer):
        grid = FoundationGrid(cells=int(grid))
    elif not isinstance(grid, FoundationGrid):
        raise TypeError(f"`grid` must be a FoundationGrid or an int; got {grid!r}.")
    ts = as_float(ts)
    u = as_float(displacement)
    check_plausibility = plausibility_enabled()
    check_eagerly(_requirements(rheology, profile, work_of_adhesion, ts, u, loading, grid,
                                check_plausibility))
    if isinstance(loading, DisplacementControl) and is_concrete((profile, u)) and u.size:
        # the largest non-adhesive radius of the history (the adhesive one, reported by the
        # solution's status, is a little larger); skipped inside a caller's trace
        deepest = max(float(np.max(np.asarray(u))), 0.0)
        check_contact_radius(profile, compiled_contact_radius(profile, deepest),
                             f"`displacement` up to {deepest:g} m")

    # one compiled program serves every call with the same configuration (types, static
    # options, shapes), whatever the parameter values
    dtype = float_dtype(rheology, profile, work_of_adhesion, ts, u, loading, grid)
    rheology, profile, work_of_adhesion, ts, u, loading, grid = _sharding.on_mesh(cast_floats(
        (rheology, profile, as_float(work_of_adhesion), ts, u, loading, grid), dtype
    ))
    run = _sharding.compiled(_simulate_jit, _simulate)
    sol = run(rheology, profile, work_of_adhesion, ts, u, loading, grid, method,
                        check_plausibility)
    if estimate_error:
        coarse = FoundationGrid(cells=max(grid.cells // 2, 2), depth=grid.depth)
        sol_c = run(rheology, profile, work_of_adhesion, ts, u, loading, coarse,
                              method, check_plausibility)
        # samples where one grid has jumped off and the other not are left out: near the
        # fold the front moves as sqrt(t* - t) and any shift of t* is a large force jump
        both = (sol.contact_radius > 0) == (sol_c.contact_radius > 0)
        err = jnp.max(jnp.where(both, jnp.abs(sol.force - sol_c.force), 0.0)) / 3.0
        scale = jnp.max(jnp.abs(sol.force))
        estimate = ErrorEstimate(
            force=err,
            relative_force=safe_div(err, scale, jnp.nan),
            jumpoff_time=jnp.abs(sol.jumpoff_time - sol_c.jumpoff_time) / 3.0,
            jumpoff_force=jnp.abs(sol.jumpoff_force - sol_c.jumpoff_force) / 3.0,
        )
        sol = eqx.tree_at(lambda s: s.details.error_estimate, sol, estimate,
                          is_leaf=lambda x: x is None)
    if throw:
        sol = raise_if_error(sol, sol.result)
    return sol


def _requirements(rheology, profile, work_of_adhesion, ts, u, loading, grid,
                  check_plausibility):
    """The `Requirement` of every input, in the order of the arguments (the eager checks
    and, inside the compiled program, the `.result` of a lane)."""
    dgamma = Constraint("work_of_adhesion", work_of_adhesion, "J/m^2", kind="work_of_adhesion")

    def same_shape():
        if u.shape != ts.shape:
            raise ValueError(
                f"`displacement` [m] must have the shape of `ts` {ts.shape}; got {u.shape}."
            )

    out = [
        domain(rheology, RESULTS.invalid_rheology),
        domain(profile, RESULTS.invalid_profile),
        constraint(dgamma, RESULTS.invalid_work_of_adhesion),
        Requirement(lambda: times_ok(ts), RESULTS.invalid_times, lambda: check_times(ts)),
        Requirement(None, RESULTS.invalid_displacement, same_shape),
        Requirement(lambda: jnp.all(jnp.isfinite(u)), RESULTS.invalid_displacement,
                    lambda: check_finite("displacement", u, "m")),
    ]
    if isinstance(loading, DisplacementControl):  # the exact sphere's limit
        out.append(Requirement(lambda: jnp.max(u) <= depth_limit(profile),
                               RESULTS.invalid_displacement,
                               lambda: check_depth_limit("displacement", profile, u)))
    out += [domain(loading, RESULTS.invalid_loading),
            domain(grid, RESULTS.invalid_depth)]
    if check_plausibility:
        out += [domain_plausibility(obj, RESULTS.implausible_input)
                for obj in (rheology, profile, loading, grid)]
        out += [plausibility("work_of_adhesion", work_of_adhesion, "work_of_adhesion",
                             RESULTS.implausible_input),
                plausibility("ts", ts, "time", RESULTS.implausible_input, magnitude=True),
                plausibility("displacement", u, "length", RESULTS.implausible_input,
                             magnitude=True)]
    return out


def _simulate(rheology, profile, work_of_adhesion, ts, u, loading, grid, method,
              check_plausibility):
    with unchecked():
        checks = traced_checks(_requirements(rheology, profile, work_of_adhesion, ts, u,
                                             loading, grid, check_plausibility))
        sol = _history(rheology, profile, work_of_adhesion, ts, u, loading, grid, method)
        # the contact radii reached: plausible lengths, within what the profile describes
        if check_plausibility:
            checks.append((contact_radius_plausible(sol.contact_radius),
                           RESULTS.implausible_input))
        checks.append((contact_radius_valid(profile, sol.contact_radius),
                       RESULTS.beyond_profile))
    return fold_checks(sol, checks)


def _history(rheology, profile, work_of_adhesion, ts, u, loading, grid, method):
    geo = profile.touch_coordinate()
    cells = int(grid.cells)
    dtype = ts.dtype
    if grid.depth is None:
        depth = jnp.maximum(jnp.max(u), 0.0)
        depth = loading.grid_depth(rheology, profile, depth)
        depth = depth * (1.0 + 1.0 / cells)
    else:
        depth = grid.depth
    depth = lax.stop_gradient(jnp.maximum(depth, jnp.finfo(dtype).tiny))
    x_nodes = lax.stop_gradient(geo.nodes(cells, depth))
    model = _Model(rheology, profile, work_of_adhesion, x_nodes, method)
    N = model.Gk.shape[0]

    # one free-relaxation propagator per sample interval (the first one is a zero step)
    dts = jnp.diff(ts, prepend=ts[:1])
    P_all = model.free_propagator(dts)
    t_prev = jnp.concatenate([ts[:1], ts[:-1]])
    u_prev = jnp.concatenate([jnp.minimum(u[:1], 0.0), u[:-1]])

    V0 = jnp.zeros((model.n_nodes, N), dtype=dtype)
    vf0 = jnp.zeros((N,), dtype=dtype)
    E0 = jnp.zeros((2, N), dtype=dtype)
    a0 = jnp.zeros((), dtype=dtype)
    inf = jnp.asarray(jnp.inf, dtype=dtype)
    # the contact's state (springs, front, the lowest force and its pair) starts as
    # constants and depends on every input after the first contact: seeded, so that JAX
    # rewrites the loop's body once per transformation (`_sharding.seeded`); the
    # indentation, the times and the stiffness keep their own dependencies (the input's,
    # the samples')
    V0, vf0, E0, a0, inf, found0 = _sharding.seeded(
        (V0, vf0, E0, a0, inf, jnp.asarray(False)),
        (rheology, profile, work_of_adhesion, ts, u, loading))
    d_start = jnp.minimum(u[0], 0.0)
    state0 = FoundationState(nodes=V0, edge=E0, radius=a0, depth=d_start)
    pre0 = StepStart(nodes=V0, edge_spring=vf0, radius=a0, t0=ts[0], t1=ts[0], d0=d_start,
                     d1=d_start)

    def body(carry, inp):
        state, pre, found = carry.state, carry.jumpoff_step, carry.found
        t0, t1, z0, z1, P = inp
        new_state, out, S = loading.step(model, state, t0, t1, z0, z1, P, carry.stiffness, depth)
        first = out.jumped & jnp.logical_not(found)
        cand = StepStart(nodes=state.nodes, edge_spring=state.edge[0], radius=state.radius,
                         t0=t0, t1=t1, d0=state.depth, d1=new_state.depth)
        pre = jax.tree_util.tree_map(lambda c, p: jnp.where(first, c, p), cand, pre)
        found = found | out.jumped
        # keep the states before and at the lowest force in contact (dense output after)
        lower = (new_state.radius > 0) & (out.force < carry.min_force)
        pair = _MinimumPair(
            nodes_before=state.nodes, edge_before=state.edge[0], radius_before=state.radius,
            nodes_at=new_state.nodes, edge_at=new_state.edge[0], radius_at=new_state.radius,
        )
        min_pair = jax.tree_util.tree_map(
            lambda c, p: jnp.where(lower, c, p), pair, carry.min_pair
        )
        min_force = jnp.where(lower, out.force, carry.min_force)
        carry = _Carry(state=new_state, jumpoff_step=pre, found=found, stiffness=S,
                       min_pair=min_pair, min_force=min_force)
        return carry, out

    zero = jnp.zeros((), dtype=dtype)
    pair0 = _MinimumPair(nodes_before=V0, edge_before=vf0, radius_before=a0, nodes_at=V0,
                         edge_at=vf0, radius_at=a0)
    carry0 = _Carry(state=state0, jumpoff_step=pre0, found=found0, stiffness=zero,
                    min_pair=pair0, min_force=inf)
    carry_end, out = _sharding.scan(body, carry0, (t_prev, ts, u_prev, u, P_all))
    pre, found, min_pair = carry_end.jumpoff_step, carry_end.found, carry_end.min_pair
    d, force, radius, jumped = out.depth, out.force, out.radius, out.jumped

    # ---- jump-off ---------------------------------------------------------------------------
    nan = jnp.asarray(jnp.nan, dtype=dtype)
    i_j = jnp.argmax(jumped)
    # on lanes without a jump-off refine a harmless stand-in (a pinned toy state)
    safe = found & (pre.radius > 0)
    pre_safe = StepStart(
        nodes=jnp.where(safe, pre.nodes, 0.0),
        edge_spring=jnp.where(safe, pre.edge_spring, 0.0),
        radius=jnp.where(safe, pre.radius, x_nodes[-1] * 0.5),
        t0=jnp.where(safe, pre.t0, 0.0),
        t1=jnp.where(safe, pre.t1, 1.0),
        d0=jnp.where(safe, pre.d0, model.geo.g(x_nodes[-1] * 0.5)),
        d1=jnp.where(safe, pre.d1, -depth),
    )
    jump = loading.refine_jumpoff(
        model, refine_jumpoff(model, pre_safe), pre_safe, safe, i_j, ts, u, d, radius, force
    )
    jumpoff_time = jnp.where(found, jump.time, nan)
    jumpoff_disp = jnp.where(found, jump.displacement, nan)
    jumpoff_radius = jnp.where(found, jump.radius, nan)
    jumpoff_force = jnp.where(found, jump.force, nan)

    # ---- largest tensile force ------------------------------------------------------------
    # Candidates: the jump-off force; the minimum along the receding front inside the steps
    # before and after the sample minimum (dense output, `front_minimum`, which includes
    # the kink where a pinned edge starts to recede; up to the jump-off radius when the
    # contact jumps off in the step after); the sample minimum. Ties take the derivative of
    # the first (the refined values before the sampled one).
    in_c = radius > 0
    f_masked = jnp.where(in_c, force, jnp.inf)
    i_m = jnp.argmin(f_masked)
    n_s = ts.shape[0]
    any_contact = jnp.any(in_c)
    f_sample = jnp.where(any_contact, pick(f_masked, i_m), 0.0)
    im1, ip1 = jnp.maximum(i_m - 1, 0), jnp.minimum(i_m + 1, n_s - 1)
    before = (i_m > 0) & any_contact
    after = (i_m < n_s - 1) & any_contact
    a_after = jnp.where(found & (i_j == i_m + 1), jumpoff_radius, pick(radius, ip1))
    # the two steps as a batch of two (one copy of the dense output in the program)
    steps_pre = StepStart(
        nodes=jnp.stack([min_pair.nodes_before, min_pair.nodes_at]),
        edge_spring=jnp.stack([min_pair.edge_before, min_pair.edge_at]),
        radius=jnp.stack([jnp.where(before, min_pair.radius_before, 0.0),
                          jnp.where(after, min_pair.radius_at, 0.0)]),
        t0=jnp.stack([pick(ts, im1), pick(ts, i_m)]),
        t1=jnp.stack([pick(ts, i_m), pick(ts, ip1)]),
        d0=jnp.stack([jnp.where(i_m > 0, pick(d, im1), 0.0), pick(d, i_m)]),
        d1=jnp.stack([pick(d, i_m), pick(d, ip1)]),
    )
    ends = jnp.stack([jnp.where(before, min_pair.radius_at, 0.0),
                      jnp.where(after, a_after, 0.0)])
    f_steps = jax.vmap(lambda pre, end: front_minimum(model, pre, end))(steps_pre, ends)
    f_jump = jnp.where(found, jumpoff_force, jnp.inf)
    max_tensile = smallest(jnp.stack([f_jump, f_steps[0], f_steps[1], f_sample]))

    # ---- status ---------------------------------------------------------------------------
    result = RESULTS.where(radius[-1] > 0, RESULTS.in_contact, RESULTS.detached)
    failed = jnp.logical_not(jnp.all(out.ok)) | jnp.any(out.overflow)
    result = RESULTS.where(failed, RESULTS.solver_failed, result)
    finite = jnp.all(jnp.isfinite(force)) & jnp.all(jnp.isfinite(radius))
    finite = finite & jnp.isfinite(max_tensile)
    result = RESULTS.where(finite, result, RESULTS.non_finite_result)

    details = FoundationDetails(
        cells=cells,
        nodes=x_nodes,
        grid_radius=x_nodes[-1],
        grid_overflow=jnp.any(out.overflow),
        drive=u,
        final_state=carry_end.state,
        newton_failures=jnp.sum(out.newton_failed),
    )
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
        jumpoffs=jnp.sum(jumped),
        result=result,
        details=details,
    )


# compiled once per configuration and cached: an eager call of `simulate` compiles the whole
# history loop (scan, refinements) as one program instead of dispatching its parts one by one
_simulate_jit = eqx.filter_jit(_simulate)
