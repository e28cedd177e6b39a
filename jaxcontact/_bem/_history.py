"""The BEM's time history: `bem_simulate`, one `lax.scan` over the load steps with the
exact creep update and the bisection of the jump-off (`jaxcontact._bem`)."""

from __future__ import annotations

import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .. import _sharding
from .._criteria import cell_critical_stress
from .._foundation._loading import (
    AbstractLoading,
    CompliantLoading,
    DisplacementControl,
    ForceControl,
    SpringEquation,
)
from .._rheology import AbstractRheology
from .._solution import RESULTS, BEMDetails, BEMSolution
from .._solvers import as_float, cast_floats, float64_scope, float_dtype, floats_to_arrays, safe_div
from .._validate import (
    check_domain_plausible,
    check_finite,
    check_plausible,
    check_positive,
    check_times,
    error_if,
    is_concrete,
)
from ._kernel import BEMGrid, _kernel_hat, love_displacement
from ._solver import _consistent, _Load
from ._surfaces import _heights

__all__ = ["bem_simulate"]

@float64_scope
def bem_simulate(
    rheology: AbstractRheology,
    indenter,
    work_of_adhesion: Float[ArrayLike, ""],
    ts: Float[ArrayLike, " m"],
    displacement: Float[ArrayLike, " m"] | None = None,
    *,
    grid: BEMGrid,
    loading: AbstractLoading | None = None,
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
    constrained-CG solve per round; see the module docstring). The loading systems are
    those of `simulate` (`loading=`), plus the dead load:

    - `DisplacementControl()` (default): the input is the indentation $d(t)$;
    - `CompliantLoading(k)`: a spring of stiffness $k$ between the drive and the indenter
      (an AFM cantilever); the input is the drive position $z(t)$ (zero where the
      undeflected indenter touches) and $k(z - d) = F$;
    - `ForceControl()`: a dead load, the input is the force $F(t)$ [N]; the contact jumps
      off where no equilibrium connected to the current one carries the load (for an
      elastic sphere at $-\tfrac32\pi\Delta\gamma R$).

    **Arguments:**

    - `rheology`: any rheology (`StandardModel`, `CreepChain`, `PronySeries`, `Elastic`),
      shear moduli [Pa] of an incompressible half-space, $E^* = 4G$. Converted to the creep
      form; the criterion uses the glass modulus.
    - `indenter`: an `AbstractProfile` (axisymmetric, e.g. `Parabola(R)`) or a height map
      [m] of shape `(n, n)` (see `ellipsoid_heights`, `tilted_flat_heights`,
      `self_affine_heights`).
    - `work_of_adhesion`: $\Delta\gamma$ [J/m²], >= 0 (0: non-adhesive).
    - `ts`: sample times [s], shape `(m,)`, non-decreasing.
    - `displacement`: the input at `ts`, shape `(m,)`: the indentation $d(t_i)$ [m] (of the
      apex $f(0) = 0$ for a profile, as in `simulate`; of the lowest cell for a height
      map), the drive position $z(t_i)$ [m] under `CompliantLoading`, or the applied force
      $F(t_i)$ [N] (compressive positive) under `ForceControl`.
    - `grid`: a `BEMGrid`; it must hold the whole contact.
    - `loading`: `DisplacementControl()` (default), `CompliantLoading(k)` or
      `ForceControl()`.
    - `force`: deprecated, `loading=ForceControl()` with the force as the input.
    - `stiffness`: deprecated, `loading=CompliantLoading(stiffness)`.
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
      edge of the grid (`.details.touches_edge`); with False inspect these instead.

    Concrete inputs far outside the plausible range of their unit (a displacement above
    1 m: nanometres given as metres; see `PLAUSIBLE`) raise a `ValueError` before the solve
    (switched off by `plausibility_checks(False)`).

    **Returns:** a `BEMSolution` (a `ContactSolution` with the BEM's fields).
    """
    if not isinstance(grid, BEMGrid):
        raise TypeError(f"`grid` must be a BEMGrid; got {type(grid).__name__}.")
    if not isinstance(rheology, AbstractRheology):
        raise TypeError(f"`rheology` must be an AbstractRheology; got {type(rheology).__name__}.")
    loading, displacement = _loading(loading, displacement, force, stiffness)
    check_positive("work_of_adhesion", work_of_adhesion, "J/m^2", allow_zero=True)
    check_times(ts)
    ts = as_float(ts)
    name, unit = loading.input_name, loading.input_unit
    inputs = as_float(displacement)
    if inputs.shape != ts.shape:
        raise ValueError(f"`{name}` [{unit}] must have the shape of `ts` {ts.shape}; got "
                         f"{inputs.shape}.")
    check_finite(name, inputs, unit)
    if relaxed_depth is not None:
        check_positive("relaxed_depth", relaxed_depth, "m")
    # a displacement of 4000 m is nanometres given as metres: say so, rather than let the
    # contact outgrow the grid ("enlarge grid.extent")
    if loading.input_kind is not None:
        check_plausible(name, inputs, loading.input_kind, magnitude=True)
    check_plausible("relaxed_depth", relaxed_depth, "length")
    check_plausible("work_of_adhesion", work_of_adhesion, "work_of_adhesion")
    check_domain_plausible(loading)
    h = _heights(indenter, grid)
    adhesive = True
    if is_concrete(work_of_adhesion):
        adhesive = bool(np.asarray(work_of_adhesion) > 0)
    chain = rheology.to_creep_chain()
    rounds = grid.cells * grid.cells if max_rounds is None else int(max_rounds)
    # the precision of the history and the material (float32 when every one of them is
    # float32); the grid and the heights follow it, as the other forward models do
    dtype = float_dtype(ts, inputs, chain)
    chain, h, ts, inputs, grid = cast_floats((chain, h, ts, inputs, grid), dtype)
    # the start and the loading's spring equation are traced values (one compiled program
    # serves a relaxed and a virgin start, force control and every spring); displacement
    # control compiles without the Newton loop on the depth
    equation = loading.spring_equation()
    fixed = equation is None
    if fixed:
        equation = SpringEquation(0.0, 1.0)  # not used: the indentation is the input
    dynamic = _sharding.on_mesh(floats_to_arrays((
        chain, h, as_float(work_of_adhesion).astype(dtype), ts, inputs, grid,
        jnp.asarray(relaxed_depth is not None),
        as_float(0.0 if relaxed_depth is None else relaxed_depth).astype(dtype),
        jnp.asarray(fixed),
        SpringEquation(as_float(equation.spring).astype(dtype),
                       as_float(equation.gain).astype(dtype)),
    )))
    sol = _sharding.compiled(_bem_simulate, _bem_simulate_plain)(
        *dynamic, save_fields, tol, int(max_iter), rounds,
        0 if fixed else max(int(max_newton), 1), adhesive, int(refine_steps))
    if throw:
        sol = error_if(
            sol,
            sol.result == RESULTS.solver_failed,
            "BEM: a constrained-CG solve or the cell rule did not converge (raise `max_iter`, "
            "`max_rounds`, `max_newton` or `tol`).",
        )
        sol = error_if(
            sol,
            sol.details.touches_edge,
            "BEM: the contact reached the edge of the grid; enlarge `grid.extent` (or, if "
            "the indentation is not small against `grid.extent`, check the units: all "
            "lengths are in metres).",
        )
    return sol


def _loading(loading, displacement, force, stiffness):
    """The loading system and the input history of `bem_simulate`'s arguments; the
    deprecated `force=` and `stiffness=` become `ForceControl()` and `CompliantLoading`."""
    if force is None and stiffness is None:
        if loading is None:
            loading = DisplacementControl()
        if not isinstance(loading, AbstractLoading):
            raise TypeError("`loading` must be an AbstractLoading (DisplacementControl(), "
                            f"CompliantLoading(k) or ForceControl()); got {loading!r}.")
        if displacement is None:
            raise ValueError("Give exactly one of `displacement` (the input history at `ts`: "
                             "the indentation or drive position [m], or the force [N] under "
                             "`loading=ForceControl()`) and the deprecated `force`; got "
                             "neither.")
        return loading, displacement
    if loading is not None:
        raise ValueError("Give `loading=` or the deprecated `force=`/`stiffness=`, not both "
                         "(`loading=jc.ForceControl()` with the force as the input, or "
                         "`loading=jc.CompliantLoading(stiffness)`).")
    if force is not None and stiffness is not None:
        raise ValueError("`stiffness` [N/m] goes with `displacement` (the drive position of "
                         "a compliant loading system), not with `force`.")
    if force is not None:
        if displacement is not None:
            raise ValueError("Give exactly one of `displacement` [m] and `force` [N] (the "
                             "input history at `ts`).")
        warnings.warn("`bem_simulate(..., force=F)` is deprecated: use "
                      "`bem_simulate(..., ts, F, loading=jaxcontact.ForceControl())` (the "
                      "force history as the input).", DeprecationWarning, stacklevel=4)
        return ForceControl(), force
    warnings.warn("`bem_simulate(..., stiffness=k)` is deprecated: use "
                  "`loading=jaxcontact.CompliantLoading(k)`.", DeprecationWarning,
                  stacklevel=4)
    check_positive("stiffness", stiffness, "N/m")
    check_plausible("stiffness", stiffness, "stiffness")
    if displacement is None:
        raise ValueError("Give `displacement` (the drive position [m]) with `stiffness`.")
    return CompliantLoading(stiffness), displacement


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
                        equation,
                        save_fields, tol, max_iter, max_rounds, max_newton, adhesive,
                        refine_steps):
    r"""One `lax.scan` over the prelude (the relaxed start, or nothing), the samples and the
    bisection steps of the jump-off: the solver appears once in the compiled program."""
    n, m = grid.cells, ts.shape[0]
    delta = grid.cell_size
    # the kernel in the history's precision (its construction promotes to float64 under the
    # float64 scope even from a float32 grid), so that every loop carry keeps that precision
    khat = _kernel_hat(n, delta)
    khat = khat.astype(jnp.result_type(ts.dtype, jnp.complex64))
    k00 = love_displacement(0.0, 0.0, 0.5 * delta, 0.5 * delta).astype(ts.dtype)
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
                     equation=equation.scaled(unit), x=x1)
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
                                tie=(chain, h, dgamma, ts, inputs, grid, d0, equation))
    touches_edge = jnp.any(out["edge"])  # the prelude included
    touching = out["area"][:1 + m] > 0  # the prelude and the samples
    jumpoffs = jnp.sum(touching[:-1] & ~touching[1:])
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
        jumpoffs=jumpoffs,
        result=result,
        details=BEMDetails(cg_iterations=out["its"], rounds=out["rounds"],
                           touches_edge=touches_edge, drive=inputs),
        pressure=out.get("p"),
        attached=out.get("contact"),
    )


_bem_simulate = eqx.filter_jit(_bem_simulate_plain)
