r"""Viscoelastic pull-off after full relaxation (paper section 5, generalised).

**Model.** The indenter was pressed to the depth $d_0$ and held until every relaxation
process finished; the contact radius is then $a_0$ (default: the non-adhesive MDR radius,
$g(a_0) = d_0$). From $t = 0$ on it is driven by a displacement history
$d(t) = d_0 + \delta(t)$ (a constant-speed lift $\delta = -v t$, or samples).

Every spring of the MDR foundation is a linear viscoelastic element; in relaxation (Prony)
form $G(t) = G_\infty + \sum_k G_k e^{-t/\tau_k}$. Because the relaxed state has no memory and
the input $\delta(t)$ is the same for every spring in contact, the line load in the contact is

$$q(x,t) = 4G_\infty\big(d_\mathrm{eff}(t) - g(x)\big),\qquad
  d_\mathrm{eff}(t) = d_0 + \delta(t) + \frac{G_g}{G_\infty}\sum_k w_k(t),$$

with one internal variable per Maxwell arm (in displacement units, $G_g = G_\infty + \sum G_k$
the glass modulus),

$$\dot w_k = \frac{G_k}{G_g}\,\dot\delta - \frac{w_k}{\tau_k},\qquad w_k(0) = 0.$$

For the standard model this is the paper's eq. (24) corrected (the printed one drops a
constant and misses the relaxed state at $t = 0$; `docs/physics.md` §4):
$u_{G_0} = [G_1(d_0 - v_0t - x^2/R) - G_0\tau v_0(1-e^{-t/\tau})]/(G_0+G_1)$.

**Detachment.** The energetic criterion (eq. 10–11) says the edge element detaches when its
line load reaches $q(a) = -\sqrt{8\pi a\Delta\gamma G_g}$. With the load above this is

$$g(a) - c\sqrt{a} = d_\mathrm{eff}(t),\qquad c = \frac{\sqrt{\pi\Delta\gamma G_g/2}}{G_\infty},$$

the corrected eq. (25): the JKR front relation with $E^* = 4G_\infty$ and
$\Delta\gamma_\mathrm{eff} = \Delta\gamma\,G_g/G_\infty$. The front stays pinned at $a_0$
until the criterion is met, then follows the larger (stable) root of that equation,
found by a bracketed Newton solve (closed form for the parabola and the cone) and
differentiated implicitly. The front never re-advances (detached springs do not
re-attach in this model); it jumps off at the fold of $g(a) - c\sqrt a$ (or directly from the
pinned state when $a_0$ is smaller than the fold radius). Afterwards force and radius are
exactly zero.

**Force.** $F = 2\int_0^a q\,\mathrm{d}x = 8G_\infty\big(a\,d_\mathrm{eff} - \int_0^a g\big)$.

Everything is one compiled program per configuration (types, shapes, method); inputs are
checked eagerly (`ValueError`) and, under `jit`/`vmap`, per lane in `.result`
(`docs/physics.md` §4; the reliability checks in `docs/reliability-forward.md`).

Note: this model gives $\Delta\gamma_\mathrm{eff} = \Delta\gamma G_g/G_\infty$ already at slow
pulling, unlike classical viscoelastic crack theories (Schapery, Greenwood–Johnson,
Persson–Brener); do not validate it against those.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, ArrayLike, Float

from ._arms import phi
from ._checks import (
    Requirement,
    check_eagerly,
    constraint,
    domain,
    domain_plausibility,
    fold_checks,
    plausibility,
    traced_checks,
)
from ._criteria import relaxed_front_coefficient
from ._method import AbstractMethod, DiffraxODE, ExactUpdate
from ._probes import check_depth_limit, depth_limit
from ._profiles import AbstractProfile, compiled_contact_radius, front_displacement
from ._rheology import AbstractRheology
from ._root import bracketed_root
from ._sharding import pick
from ._solution import (
    RESULTS,
    ContactSolution,
    RetractDetails,
)
from ._solvers import as_float, cast_floats, float64_scope, float_dtype, smallest
from ._validate import (
    Constraint,
    check_contact_radius,
    check_finite,
    check_times,
    concrete_float,
    contact_radius_plausible,
    contact_radius_valid,
    is_concrete,
    plausibility_enabled,
    times_ok,
    unchecked,
)

__all__ = ["retract", "ExactUpdate", "DiffraxODE", "AbstractMethod"]


def prony_arrays(rheology):
    """`(G_inf, G, tau)` of the relaxation form, the arms as 1-D arrays."""
    prony = rheology.to_prony()
    return prony.G_inf, jnp.atleast_1d(prony.G), jnp.atleast_1d(prony.tau)


class RelaxedFront(NamedTuple):
    r"""The detachment front of a lift from a relaxed contact of touch radius $a_0$ (the
    module docstring; also the sweep's, `_sweep/_models.py`), any consistent units.

    On the front the indentation is $h(a) = g(a) - c\sqrt a$ (`front_displacement`) with $c$
    the energetic criterion carried by the relaxed springs (`relaxed_front_coefficient`).
    """

    c: Array  # the criterion's coefficient [m^(1/2)]
    a_fold: Array  # the fold of h(a) (displacement control: the smallest stable radius)
    a_fc: Array  # the minimum of the front's force (force control)
    a_crit: Array  # the jump-off radius, min(a_fold, a0)
    h_crit: Array  # h(a_crit): no edge holds once the effective displacement is below it
    h_pin: Array  # h(a0): the pinned edge starts to recede below it
    can_recede: Array  # a0 > a_fold (false e.g. for the flat punch)


def relaxed_front(profile, work_of_adhesion, relaxed_modulus, glass_modulus, a0) -> RelaxedFront:
    """The constants of the relaxed detachment front (`RelaxedFront`), computed once for
    `retract` and the sweep."""
    c = relaxed_front_coefficient(work_of_adhesion, glass_modulus, relaxed_modulus)
    a_fold = profile.critical_radius(c, 0.5)
    a_crit = jnp.minimum(a_fold, a0)
    return RelaxedFront(
        c=c,
        a_fold=a_fold,
        a_fc=profile.critical_radius(c, 1.5),
        a_crit=a_crit,
        h_crit=front_displacement(profile, a_crit, c),
        h_pin=front_displacement(profile, a0, c),
        can_recede=a0 > a_fold,
    )


def _segment_deff(u, depth, delta_a, w_a, slope, arm_ratio, tau, glass_ratio):
    """d_eff at time t_a + u inside a segment where d(t) is linear with `slope`."""
    e = jnp.exp(-u / tau)
    w = w_a * e + arm_ratio * slope * u * phi(u / tau)
    return depth + delta_a + slope * u + glass_ratio * jnp.sum(w)


@float64_scope
def retract(
    rheology: AbstractRheology,
    profile: AbstractProfile,
    work_of_adhesion: Float[ArrayLike, ""],
    ts: Float[ArrayLike, " n"],
    displacement: Float[ArrayLike, " n"] | None = None,
    *,
    depth: Float[ArrayLike, ""] | None = None,
    velocity: Float[ArrayLike, ""] | None = None,
    contact_radius: Float[ArrayLike, ""] | None = None,
    method: AbstractMethod = ExactUpdate(),
    throw: bool = True,
) -> ContactSolution:
    r"""Lift an indenter from a fully relaxed adhesive contact.

    The positional arguments are those of `simulate`: `retract(rheology, profile,
    work_of_adhesion, ts, displacement)` lifts along a sampled history; every argument may
    also be given by keyword.

    **Arguments:**

    - `rheology`: any rheology (`StandardModel`, `CreepChain`, `PronySeries`, `Elastic`);
      shear moduli of an incompressible half-space, foundation stiffness $4G$ per length.
    - `profile`: any profile (`Sphere`, `Parabola`, `Cone`, `PowerLaw`, `FlatPunch`,
      `Tabulated`).
    - `work_of_adhesion`: $\Delta\gamma$ [J/m²], > 0.
    - `ts`: sample times [s], shape `(n,)`, non-decreasing; $t = 0$ is the start of the lift
      (>= 0 with `velocity`).
    - `displacement`: the indentation $d(t_i)$ [m] at `ts` (a measured history); piecewise
      linear between samples, and a step from $d_0$ at `ts[0]` if
      `displacement[0] != depth`. Give exactly one of `displacement` and `velocity`.
    - `depth`: relaxed indentation $d_0$ [m], > 0 (positive into the sample). With
      `displacement` it defaults to `displacement[0]`. At most `depth_limit(profile)` (the
      exact `Sphere`: 1.74 R; no limit for the other profiles).
    - `velocity`: lift speed $v$ [m/s], > 0: $d(t) = d_0 - v t$.
    - `contact_radius`: contact radius $a_0$ [m] of the relaxed state (default: $g(a_0) = d_0$,
      the non-adhesive radius; a larger, adhesive radius is allowed, up to the profile's
      `max_radius`).
    - `method`: `ExactUpdate()` (default) or `DiffraxODE(...)`.
    - `throw`: raise on an error result (invalid or implausible input,
      `advancing_contact`, `solver_failed`, `non_finite_result`), whichever field is read;
      with `False` the status is returned in `.result` per lane (use under `vmap`), and the
      fields of a lane with invalid input are NaN.

    Precision: float32 when every floating input is float32, float64 otherwise (Python
    floats take the precision of the arrays they meet).

    **Returns:** a `ContactSolution` (`details`: a `RetractDetails`). `max_tensile_force`
    and the jump-off quantities are exact on the receding front (which is a fixed JKR curve)
    and the jump-off time is refined between samples with the exact in-segment solution.
    """
    if (velocity is None) == (displacement is None):
        raise ValueError("Give exactly one of `velocity` [m/s] and `displacement` [m].")
    if not isinstance(rheology, AbstractRheology):
        raise TypeError(f"`rheology` must be an AbstractRheology; got {type(rheology).__name__}.")
    if not isinstance(profile, AbstractProfile):
        raise TypeError(f"`profile` must be an AbstractProfile; got {type(profile).__name__}.")
    if not isinstance(method, AbstractMethod):
        raise TypeError(f"`method` must be ExactUpdate() or DiffraxODE(...); got {method!r}.")
    ts = as_float(ts)
    if displacement is not None:
        displacement = as_float(displacement)
        if depth is None and displacement.shape == ts.shape and ts.size:
            depth = displacement[0]  # else the times' or the displacement's check raises
    elif depth is None:
        raise ValueError("`depth` [m] (the relaxed indentation) is required with `velocity`.")
    check_plausibility = plausibility_enabled()
    check_eagerly(_requirements(rheology, profile, work_of_adhesion, depth, ts, velocity,
                                displacement, contact_radius, check_plausibility))
    dtype = float_dtype(rheology, profile, work_of_adhesion, depth, ts, velocity, displacement,
                        contact_radius)
    args = cast_floats(
        (rheology, profile, as_float(work_of_adhesion), as_float(depth), ts,
         None if velocity is None else as_float(velocity), displacement,
         None if contact_radius is None else as_float(contact_radius)),
        dtype,
    )
    return _retract(*args, method, throw, check_plausibility)


def _number(value) -> str:
    return f"{float(np.asarray(value)):g}" if is_concrete(value) else "(traced)"


def _requirements(rheology, profile, dgamma, depth, ts, velocity, displacement,
                  contact_radius, check_plausibility):
    """The `Requirement` of every input, in the order of the arguments (the eager checks
    and, inside the compiled program, the `.result` of a lane)."""
    scalars = [
        (Constraint("work_of_adhesion", dgamma, "J/m^2", kind="work_of_adhesion"),
         RESULTS.invalid_work_of_adhesion),
        (Constraint("depth", depth, "m", kind="length"), RESULTS.invalid_depth)]
    if velocity is not None:
        scalars.append((Constraint("velocity", velocity, "m/s", kind="velocity"),
                        RESULTS.invalid_velocity))
    if contact_radius is not None:
        scalars.append((Constraint("contact_radius", contact_radius, "m", kind="length"),
                        RESULTS.invalid_contact_radius))
    nonnegative = velocity is not None

    def same_shape():
        if displacement.shape != ts.shape:
            raise ValueError(
                f"`displacement` [m] must have the shape of `ts` {ts.shape}; "
                f"got {displacement.shape}."
            )

    def within_profile():
        if is_concrete(contact_radius) and is_concrete(profile):
            amax = concrete_float(lambda: profile.max_radius)
            if float(np.asarray(contact_radius)) > amax:
                raise ValueError(
                    f"`contact_radius` = {float(np.asarray(contact_radius)):g} m exceeds the "
                    f"profile's size {amax:g} m."
                )

    @functools.cache
    def relaxed_radius():  # traced: the relaxed contact radius (computed once)
        return profile.contact_radius(depth) if contact_radius is None else contact_radius

    def relaxed_radius_check():
        if contact_radius is not None:
            check_contact_radius(profile, contact_radius,
                                 f"`contact_radius` = {_number(contact_radius)} m")
        elif is_concrete((profile, depth)):
            check_contact_radius(profile, compiled_contact_radius(profile, as_float(depth)),
                                 f"`depth` = {_number(depth)} m")

    out = [domain(rheology, RESULTS.invalid_rheology),
           domain(profile, RESULTS.invalid_profile)]
    out += [constraint(c, item) for c, item in scalars]
    out += [Requirement(lambda: depth <= depth_limit(profile), RESULTS.invalid_depth,
                        None if depth is None else
                        lambda: check_depth_limit("depth", profile, depth)),
            Requirement(lambda: times_ok(ts, require_nonnegative=nonnegative),
                        RESULTS.invalid_times,
                        lambda: check_times(ts, require_nonnegative=nonnegative),
                        eager_first=True)]
    if displacement is not None:  # (`depth` defaults to its first sample)
        out += [Requirement(None, RESULTS.invalid_displacement, same_shape, eager_first=True),
                Requirement(lambda: jnp.all(jnp.isfinite(displacement)),
                            RESULTS.invalid_displacement,
                            lambda: check_finite("displacement", displacement, "m"),
                            eager_first=True)]
    if contact_radius is not None:
        out.append(Requirement(lambda: contact_radius <= profile.max_radius,
                               RESULTS.invalid_contact_radius, within_profile))
    if check_plausibility:
        implausible = RESULTS.implausible_input
        out += [domain_plausibility(obj, implausible) for obj in (rheology, profile)]
        out += [plausibility(c.name, c.value, c.kind, implausible) for c, _ in scalars]
        out.append(plausibility("ts", ts, "time", implausible, magnitude=True))
        if displacement is not None:
            out.append(plausibility("displacement", displacement, "length", implausible,
                                    magnitude=True))
        out.append(Requirement(lambda: contact_radius_plausible(relaxed_radius()),
                               implausible))
    # the relaxed contact radius: a plausible length, within what the profile describes
    out.append(Requirement(lambda: contact_radius_valid(profile, relaxed_radius()),
                           RESULTS.beyond_profile, relaxed_radius_check))
    return out


@eqx.filter_jit
def _retract(rheology, profile, dgamma, depth, ts, velocity, displacement, contact_radius, method,
             throw, check_plausibility):
    with unchecked():
        checks = traced_checks(_requirements(rheology, profile, dgamma, depth, ts, velocity,
                                             displacement, contact_radius, check_plausibility))
        sol = _solve(rheology, profile, dgamma, depth, ts, velocity, displacement,
                     contact_radius, method)
    return fold_checks(sol, checks, throw=throw)


def _solve(rheology, profile, dgamma, depth, ts, velocity, displacement, contact_radius, method):
    G_inf, G, tau = prony_arrays(rheology)
    G_g = G_inf + jnp.sum(G)
    arm_ratio = G / G_g
    glass_ratio = G_g / G_inf
    a0 = profile.contact_radius(depth) if contact_radius is None else contact_radius

    # ---- internal variables w_k(t_i), shape (n, N) -------------------------------------
    if velocity is not None:
        delta = -velocity * ts
    else:
        delta = displacement - depth
    w, ode_ok, solver_steps = method.arm_states(ts, velocity, delta, arm_ratio, tau)
    d = depth + delta
    d_eff = d + glass_ratio * jnp.sum(w, axis=-1)

    # ---- the front -----------------------------------------------------------------------
    front = relaxed_front(profile, dgamma, G_inf, G_g, a0)
    c, a_fold, a_fc, h_pin = front.c, front.a_fold, front.a_fc, front.h_pin
    a_crit, h_crit, can_recede = front.a_crit, front.h_crit, front.can_recede

    if velocity is not None:
        # constant-speed lift from rest: d_eff' = -v G(t)/G_inf < 0, so d_eff is its own
        # running minimum (and the cumulative minimum, slow on CPU, is not needed)
        m = d_eff
    else:
        m = lax.cummin(d_eff, axis=0)
    attached = m >= h_crit
    receding = attached & (m < h_pin) & can_recede
    # safe input for lanes not on the receding front: the root at max(a0, 2 a_fold), within
    # the radii the profile admits (beyond them h is infinite: the stand-in's bracket held
    # inf - inf, and its root bisected for 50 iterations on every sample of the lane)
    a_safe = jnp.minimum(jnp.maximum(a0, 2 * a_fold), profile.max_radius)
    m_safe = jnp.where(receding, m, front_displacement(profile, a_safe, c))
    a_root = profile.front_radius(m_safe, c, a_fold, jnp.maximum(a0, a_safe))
    radius = jnp.where(receding, a_root, jnp.where(attached, a0, 0.0))
    radius_safe = jnp.where(attached, radius, a0)

    def force_at(a, deff):
        return 8 * G_inf * (a * deff - profile.integral_g(a))

    force = jnp.where(attached, force_at(radius_safe, d_eff), 0.0)

    # ---- events ---------------------------------------------------------------------------
    detached = jnp.logical_not(attached[-1])
    i_j = jnp.argmax(jnp.logical_not(attached))
    jumpoff_force_value = force_at(a_crit, h_crit)
    # the receding front is the fixed JKR curve F(a) = 8 G_inf (a h(a) - I(a)): its minimum over
    # the radii visited, [a_end, a0], is at clip(a_fc, a_end, a0). Where the front was
    # visited this is the largest tensile force (no sample is below it: a pinned sample has
    # F(a0, d_eff) >= F(a0, h(a0))); elsewhere the smallest sample.
    a_end = jnp.where(detached, a_crit, radius[-1])
    visited = detached | receding[-1]
    a_min = jnp.clip(a_fc, a_end, a0)
    f_front = force_at(a_min, front_displacement(profile, a_min, c))
    max_tensile = jnp.where(visited, f_front, smallest(force))

    # jump-off time inside the segment (t_prev, t_j]
    has_prev = i_j > 0
    i_prev = jnp.maximum(i_j - 1, 0)
    if velocity is not None:
        t_a = jnp.where(has_prev, pick(ts, i_prev), 0.0)
        delta_a = -velocity * t_a
        w_a = jnp.where(has_prev, pick(w, i_prev), jnp.zeros_like(tau))
        slope = -velocity
    else:
        t_a = jnp.where(has_prev, pick(ts, i_prev), ts[0])
        delta_a = jnp.where(has_prev, pick(delta, i_prev), delta[0])
        w_a = jnp.where(has_prev, pick(w, i_prev), w[0])
        span_ = pick(ts, i_j) - t_a
        rise = pick(delta, i_j) - delta_a
        slope = jnp.where(span_ > 0, rise / jnp.where(span_ > 0, span_, 1.0), 0)
    span = pick(ts, i_j) - t_a
    seg_ok = detached & (span > 0)
    # on lanes without a bracketing segment, solve a harmless stand-in problem
    seg_args = (depth, delta_a, w_a, slope, arm_ratio, tau, glass_ratio)
    h_mid = 0.5 * (_segment_deff(0.0, *seg_args) + _segment_deff(1.0, *seg_args))
    h_target = jnp.where(seg_ok, h_crit, h_mid)
    span_safe = jnp.where(seg_ok, span, 1.0)

    def resid(u):
        return _segment_deff(u, *seg_args) - h_target

    u_j = bracketed_root(resid, jnp.zeros_like(span_safe), span_safe, steps=64)
    t_j = jnp.where(seg_ok, t_a + u_j, pick(ts, i_j))
    nan = jnp.asarray(jnp.nan, ts.dtype)
    jumpoff_time = jnp.where(detached, t_j, nan)
    jumpoff_disp = jnp.where(detached, depth + delta_a + slope * (t_j - t_a), nan)
    jumpoff_force = jnp.where(detached, jumpoff_force_value, nan)
    jumpoff_radius = jnp.where(detached, a_crit, nan)

    # ---- status ---------------------------------------------------------------------------
    result = RESULTS.where(detached, RESULTS.detached, RESULTS.in_contact)
    # the indenter must not go beyond the gap just outside the initial contact (infinite at
    # the edge of a bounded shape: a flat punch cannot advance); with the non-adhesive
    # initial radius that gap is the depth itself (no round-off from g(a0))
    g_out = lax.stop_gradient(profile.g(jnp.nextafter(lax.stop_gradient(a0), jnp.inf)))
    touch = g_out if contact_radius is not None else jnp.maximum(depth, g_out)
    rel = max(1e-9, 64 * float(jnp.finfo(ts.dtype).eps))
    advancing = jnp.any(d > touch + rel * depth + 1e-15)
    result = RESULTS.where(advancing, RESULTS.advancing_contact, result)
    result = RESULTS.where(ode_ok, result, RESULTS.solver_failed)
    finite = jnp.all(jnp.isfinite(force)) & jnp.all(jnp.isfinite(radius))
    finite = finite & jnp.isfinite(max_tensile)
    result = RESULTS.where(finite, result, RESULTS.non_finite_result)

    details = RetractDetails(
        initial_radius=a0,
        fold_radius=a_fold,
        force_control_radius=a_fc,
        effective_displacement=d_eff,
        effective_work_of_adhesion=dgamma * glass_ratio,
        solver_steps=jnp.asarray(solver_steps),
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
        jumpoffs=detached.astype(jnp.int32),
        result=result,
        details=details,
    )
