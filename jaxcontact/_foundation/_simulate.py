"""`simulate`: the history loop over the samples and the assembly of its solution."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import ArrayLike, Float

from .._profiles import AbstractProfile
from .._pulloff import AbstractMethod, DiffraxODE, ExactUpdate
from .._solution import RESULTS, ContactSolution, is_error
from .._solvers import (
    floats_to_arrays,
    safe_div,
)
from .._validate import check_finite, check_positive, check_times
from ._events import _Model
from ._geometry import _Geometry, _grid_nodes
from ._loading import AbstractLoading, DisplacementControl
from ._options import FoundationGrid
from ._state import FoundationState, StepStart, _Carry, _MinimumPair


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
    check_times(ts)
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
    if not isinstance(loading, AbstractLoading):
        raise TypeError(
            "`loading` must be an AbstractLoading (DisplacementControl() or "
            f"CompliantLoading(k)); got {loading!r}."
        )
    if not isinstance(method, ExactUpdate | DiffraxODE):
        raise TypeError(f"`method` must be ExactUpdate() or DiffraxODE(...); got {method!r}.")

    # one compiled program serves every call with the same configuration (types, static
    # options, shapes), whatever the parameter values
    rheology, profile, work_of_adhesion, loading, grid = floats_to_arrays(
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
            relative_discretisation_error=safe_div(err, scale, jnp.nan),
            jumpoff_time_error=jnp.abs(sol.jumpoff_time - sol_c.jumpoff_time) / 3.0,
            jumpoff_force_error=jnp.abs(sol.jumpoff_force - sol_c.jumpoff_force) / 3.0,
        )
        sol = eqx.tree_at(lambda s: s.stats, sol, stats)
    if throw:
        force = sol.result.error_if(sol.force, is_error(sol.result))
        sol = eqx.tree_at(lambda s: s.force, sol, force)
    return sol


def _simulate(rheology, profile, work_of_adhesion, ts, u, loading, grid, method):
    geo = _Geometry(profile)
    cells = int(grid.cells)
    if grid.depth is None:
        depth = jnp.maximum(jnp.max(u), 0.0)
        depth = loading.grid_depth(rheology, profile, depth, geo.flat)
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
    state0 = FoundationState(nodes=V0, edge=E0, radius=a0, depth=d_start)
    pre0 = StepStart(V0, vf0, a0, ts[0], ts[0], d_start, d_start)
    inf = jnp.asarray(jnp.inf, dtype=dtype)

    def body(carry, inp):
        state, pre, found = carry.state, carry.jumpoff_step, carry.found
        t0, t1, z0, z1, P = inp
        new_state, out, S = loading.step(model, state, t0, t1, z0, z1, P, carry.stiffness, depth)
        first = out.jumped & jnp.logical_not(found)
        V, E, a, d0 = state.nodes, state.edge, state.radius, state.depth
        cand = StepStart(V, E[0], a, t0, t1, d0, new_state.depth)
        pre = jax.tree_util.tree_map(lambda c, p: jnp.where(first, c, p), cand, pre)
        found = found | out.jumped
        # keep the states before and at the lowest force in contact (dense output after)
        lower = (new_state.radius > 0) & (out.force < carry.min_force)
        pair = _MinimumPair(V, E[0], a, new_state.nodes, new_state.edge[0], new_state.radius)
        min_pair = jax.tree_util.tree_map(
            lambda c, p: jnp.where(lower, c, p), pair, carry.min_pair
        )
        min_force = jnp.where(lower, out.force, carry.min_force)
        ys = (new_state.depth, out, S)
        carry = _Carry(new_state, pre, found, S, min_pair, min_force)
        return carry, ys

    zero = jnp.zeros((), dtype=dtype)
    pair0 = _MinimumPair(V0, vf0, a0, V0, vf0, a0)
    carry0 = _Carry(state0, pre0, jnp.asarray(False), zero, pair0, inf)
    carry_end, ys = lax.scan(body, carry0, (t_prev, ts, u_prev, u, P_all))
    state_end, pre, found, min_pair = (
        carry_end.state, carry_end.jumpoff_step, carry_end.found, carry_end.min_pair
    )
    d, out, _ = ys
    force, radius, jumped = out.force, out.radius, out.jumped
    ok, overflow, newton_failed = out.ok, out.overflow, out.newton_failed

    # ---- jump-off ---------------------------------------------------------------------------
    nan = jnp.asarray(jnp.nan, dtype=dtype)
    i_j = jnp.argmax(jumped)
    # on lanes without a jump-off refine a harmless stand-in (a pinned toy state)
    V, vf, a, t0, t1, d0, d1 = pre.unpack()
    safe = found & (a > 0)
    pre_safe = StepStart(
        jnp.where(safe, V, 0.0),
        jnp.where(safe, vf, 0.0),
        jnp.where(safe, a, x_nodes[-1] * 0.5),
        jnp.where(safe, t0, 0.0),
        jnp.where(safe, t1, 1.0),
        jnp.where(safe, d0, model.geo.g(x_nodes[-1] * 0.5)),
        jnp.where(safe, d1, -depth),
    )
    j_time, j_disp, j_rad, j_force = loading.refine_jumpoff(
        model, model.refine_jumpoff(pre_safe), pre_safe, safe, i_j, ts, u, d, radius, force
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
    Vb, vfb, ab = min_pair.nodes_before, min_pair.edge_before, min_pair.radius_before
    Vm, vfm, am = min_pair.nodes_at, min_pair.edge_at, min_pair.radius_at
    im1, ip1 = jnp.maximum(i_m - 1, 0), jnp.minimum(i_m + 1, n_s - 1)
    before = (i_m > 0) & any_contact
    after = (i_m < n_s - 1) & any_contact
    a_after = jnp.where(found & (i_j == i_m + 1), jumpoff_radius, radius[ip1])
    # the two steps as a batch of two (one copy of the dense output in the program)
    steps_pre = StepStart(
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
    stats.update(loading.stats(newton_failed))
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
