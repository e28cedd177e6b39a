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

Note: this model gives $\Delta\gamma_\mathrm{eff} = \Delta\gamma G_g/G_\infty$ already at slow
pulling, unlike classical viscoelastic crack theories (Schapery, Greenwood–Johnson,
Persson–Brener); do not validate it against those.
"""

from __future__ import annotations

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
from jax import lax
from jax.custom_derivatives import SymbolicZero
from jaxtyping import ArrayLike, Float

from ._elastic import (
    _critical_radius,
    _front_displacement,
    _stable_radius,
    profile_radius,
)
from ._profiles import AbstractProfile, Cone, FlatPunch, Parabola
from ._root import bracketed_root
from ._solution import RESULTS, ContactSolution, is_error
from ._solvers import as_float
from ._validate import check_finite, check_positive, check_times, is_concrete

__all__ = ["retract", "ExactUpdate", "DiffraxODE", "AbstractMethod"]


class AbstractMethod(eqx.Module):
    """How the internal viscoelastic variables are integrated in time."""


class ExactUpdate(AbstractMethod):
    r"""Exact solution for piecewise-linear displacement histories (default, fastest).

    For a constant-speed lift the closed form $w_k = -(G_k/G_g)\tau_k v(1 - e^{-t/\tau_k})$ is
    used; for sampled histories the exact exponential update
    $w_k \leftarrow w_k e^{-\Delta/\tau_k} + (G_k/G_g)\,\Delta\delta\,
    (1 - e^{-\Delta/\tau_k})\tau_k/\Delta$ over each interval, combined by a parallel
    associative scan.
    """


class DiffraxODE(AbstractMethod):
    r"""Integrate $\dot w_k = (G_k/G_g)\dot\delta - w_k/\tau_k$ with diffrax.

    **Arguments:**

    - `solver`: a diffrax solver (default `diffrax.Tsit5()`, whose dense output keeps the
      saved values at the step accuracy; for relaxation times far shorter than the sampling
      interval choose an L-stable one such as `diffrax.Kvaerno5()`).
    - `rtol`, `atol`: tolerances of the PID step-size controller (`atol` in metres).
    - `max_steps`: step budget; exceeding it gives `RESULTS.solver_failed`.
    """

    solver: diffrax.AbstractSolver = diffrax.Tsit5()
    rtol: float = 1e-10
    atol: float = 1e-18
    max_steps: int = 16384


def _prony_arrays(rheology):
    prony = rheology.to_prony()
    G_inf = as_float(prony.G_inf)
    G = jnp.atleast_1d(as_float(prony.G))
    tau = jnp.atleast_1d(as_float(prony.tau))
    return G_inf, G, tau


def _phi(x):
    """(1 - exp(-x)) / x, with the limit 1 at x = 0."""
    safe = jnp.where(x > 0, x, 1.0)
    return jnp.where(x > 0, -jnp.expm1(-safe) / safe, 1.0)


def _states_velocity(ts, velocity, arm_ratio, tau):
    # w_k(t) = -(G_k/G_g) tau_k v (1 - exp(-t/tau_k)); shape (n, N). Written without a
    # per-sample division, so that XLA fuses it with the front root into one pass.
    t, arm_ratio, tau = ts[:, None], arm_ratio[None, :], tau[None, :]
    return (arm_ratio * velocity * tau) * jnp.expm1(t * (-1.0 / tau))


def _combine(left, right):
    a1, b1 = left
    a2, b2 = right
    return a1 * a2, a2 * b1 + b2


def _recurrence(alpha, beta):
    """$w_i = \\alpha_i w_{i-1} + \\beta_i$, $w_{-1} = 0$, along axis 0; `beta` may carry
    extra trailing axes (several right-hand sides share the products of the alphas)."""
    extra = beta.ndim - alpha.ndim
    a = alpha.reshape(alpha.shape + (1,) * extra)
    return lax.associative_scan(_combine, (a, beta), axis=0)[1]


def _dphi(x):
    r"""$\phi'(x) = (e^{-x} - \phi(x))/x$ without cancellation (series below $x = 0.01$)."""
    small = x < 0.01
    xs = jnp.where(small, x, 0.0)
    series = -1 / 2 + xs * (1 / 3 + xs * (-1 / 8 + xs * (1 / 30 + xs * (-1 / 144 + xs / 840))))
    xl = jnp.where(small, 1.0, x)
    return jnp.where(small, series, (jnp.exp(-xl) - _phi(xl)) / xl)


def _increments(dt, tau):
    x = dt / tau
    return x, jnp.exp(-x), _phi(x)


@jax.custom_jvp
def _states_increments(dt, ddelta, arm_ratio, tau):
    # w = L(alpha) (arm_ratio ddelta phi(x)), x = dt/tau; shapes (n, 1), (n, 1), (1, N), (1, N)
    _, alpha, phi = _increments(dt, tau)
    return _recurrence(alpha, arm_ratio * ddelta * phi)


def _states_increments_jvp(primals, tangents):
    r"""Tangents of the arm states through two fixed sensitivities.

    With $u = L(\alpha)(\Delta\delta\,\phi(x))$ the states are $w = (G_k/G_g)\,u$, and
    $v = \partial w/\partial\tau = L(\alpha)\,q$ with
    $q = x\,[\alpha\,w_{i-1} - (G_k/G_g)\Delta\delta\,\phi'(x)]/\tau$. Both come
    from one scan that shares the products of the $\alpha$s, so any number of tangent
    directions (the Jacobian's columns) costs two element-wise products,
    $\dot w = u\,\dot r + v\,\dot\tau$, and under `jax.linearize` no scan is left in the
    linear map. Tangents of the sampling (`dt`, `ddelta`: a differentiated displacement
    history) need their own scan and only run when present.
    """
    dt, ddelta, arm_ratio, tau = primals
    t_dt, t_ddelta, t_ratio, t_tau = tangents
    x, alpha, phi = _increments(dt, tau)
    u = _recurrence(alpha, ddelta * phi)
    w = arm_ratio * u
    w_prev = jnp.concatenate([jnp.zeros_like(w[:1]), w[:-1]])
    dphi = _dphi(x)
    q = x * (alpha * w_prev - arm_ratio * ddelta * dphi) / tau
    v = _recurrence(alpha, q)
    zero = lambda t: isinstance(t, SymbolicZero)  # noqa: E731
    dw = jnp.zeros_like(w)
    if not zero(t_ratio):
        dw = dw + u * t_ratio
    if not zero(t_tau):
        dw = dw + v * t_tau
    if not (zero(t_dt) and zero(t_ddelta)):
        # dw = L(alpha) (dbeta + dalpha w_prev) for the sampling's own tangents
        forcing = jnp.zeros_like(w)
        if not zero(t_ddelta):
            forcing = forcing + arm_ratio * t_ddelta * phi
        if not zero(t_dt):
            forcing = forcing + (arm_ratio * ddelta * dphi - alpha * w_prev) * (t_dt / tau)
        dw = dw + _recurrence(alpha, forcing)
    return w, dw


_states_increments.defjvp(_states_increments_jvp, symbolic_zeros=True)


def _states_samples(ts, delta, arm_ratio, tau):
    # exact update over each interval, the first sample responding as a step from rest
    dt = jnp.diff(ts, prepend=ts[:1])[:, None]
    ddelta = jnp.diff(delta, prepend=0.0)[:, None]
    # all four of rank 2: (n, 1), (n, 1), (1, N), (1, N)
    return _states_increments(dt, ddelta, arm_ratio[None, :], tau[None, :])


def _states_diffrax(method, ts, velocity, delta, arm_ratio, tau):
    if delta is None:
        t0 = jnp.zeros_like(ts[0])
        y0 = jnp.zeros_like(tau)

        def rate(t):
            return -velocity

        jump_ts = None
    else:
        t0 = ts[0]
        y0 = arm_ratio * delta[0]
        path = diffrax.LinearInterpolation(ts=ts, ys=delta)

        def rate(t):
            return path.derivative(t)

        jump_ts = ts

    def vector_field(t, w, args):
        return arm_ratio * rate(t) - w / tau

    controller = diffrax.PIDController(rtol=method.rtol, atol=method.atol)
    if jump_ts is not None:
        controller = diffrax.ClipStepSizeController(controller, jump_ts=jump_ts)
    span = ts[-1] - t0
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(vector_field),
        method.solver,
        t0=t0,
        t1=ts[-1],
        dt0=jnp.maximum(span, 1e-300) * 1e-4,
        y0=y0,
        saveat=diffrax.SaveAt(ts=ts),
        stepsize_controller=controller,
        max_steps=method.max_steps,
        throw=False,
    )
    ok = sol.result == diffrax.RESULTS.successful
    return sol.ys, ok, sol.stats


def _segment_deff(u, depth, delta_a, w_a, slope, arm_ratio, tau, glass_ratio):
    """d_eff at time t_a + u inside a segment where d(t) is linear with `slope`."""
    e = jnp.exp(-u / tau)
    w = w_a * e + arm_ratio * slope * u * _phi(u / tau)
    return depth + delta_a + slope * u + glass_ratio * jnp.sum(w)


def retract(
    rheology,
    profile: AbstractProfile,
    *,
    work_of_adhesion: Float[ArrayLike, ""],
    depth: Float[ArrayLike, ""] | None = None,
    ts: Float[ArrayLike, " n"],
    velocity: Float[ArrayLike, ""] | None = None,
    displacement: Float[ArrayLike, " n"] | None = None,
    contact_radius: Float[ArrayLike, ""] | None = None,
    method: AbstractMethod = ExactUpdate(),
    throw: bool = True,
) -> ContactSolution:
    r"""Lift an indenter from a fully relaxed adhesive contact.

    **Arguments:**

    - `rheology`: any rheology (`StandardModel`, `CreepChain`, `PronySeries`, `Elastic`);
      shear moduli of an incompressible half-space, foundation stiffness $4G$ per length.
    - `profile`: any profile (`Parabola`, `Cone`, `PowerLaw`, `FlatPunch`, `Tabulated`).
    - `work_of_adhesion`: $\Delta\gamma$ [J/m²], > 0.
    - `depth`: relaxed indentation $d_0$ [m], > 0 (positive into the sample). With
      `displacement` it defaults to `displacement[0]`.
    - `ts`: sample times [s], shape `(n,)`, non-decreasing; $t = 0$ is the start of the lift.
    - `velocity`: lift speed $v$ [m/s], > 0: $d(t) = d_0 - v t$.
    - `displacement`: alternatively, the indentation $d(t_i)$ [m] at `ts` (a measured
      history); piecewise linear between samples, and a step from $d_0$ at `ts[0]` if
      `displacement[0] != depth`. Give exactly one of `velocity` and `displacement`.
    - `contact_radius`: contact radius $a_0$ [m] of the relaxed state (default: $g(a_0) = d_0$,
      the non-adhesive radius; a larger, adhesive radius is allowed).
    - `method`: `ExactUpdate()` (default) or `DiffraxODE(...)`.
    - `throw`: raise on an error result (`advancing_contact`, `solver_failed`,
      `invalid_input`); with `False` the status is returned in `.result` (use under `vmap`).

    **Returns:** a `ContactSolution`. `max_tensile_force` and the jump-off quantities are exact
    on the receding front (which is a fixed JKR curve) and the jump-off time is refined
    between samples with the exact in-segment solution.
    """
    if (velocity is None) == (displacement is None):
        raise ValueError("Give exactly one of `velocity` [m/s] and `displacement` [m].")
    check_positive("work_of_adhesion", work_of_adhesion, "J/m^2")
    check_times(ts, require_nonnegative=velocity is not None)
    ts = as_float(ts)
    if displacement is not None:
        displacement = as_float(displacement)
        if displacement.shape != ts.shape:
            raise ValueError(
                f"`displacement` [m] must have the shape of `ts` {ts.shape}; "
                f"got {displacement.shape}."
            )
        check_finite("displacement", displacement, "m")
        if depth is None:
            depth = displacement[0]
    if depth is None:
        raise ValueError("`depth` [m] (the relaxed indentation) is required with `velocity`.")
    check_positive("depth", depth, "m")
    if velocity is not None:
        check_positive("velocity", velocity, "m/s")
    if contact_radius is not None:
        check_positive("contact_radius", contact_radius, "m")

    if contact_radius is not None and is_concrete(contact_radius) and is_concrete(profile):
        amax = profile.max_radius
        if bool(jnp.asarray(contact_radius) > amax):
            raise ValueError(
                f"`contact_radius` = {float(contact_radius):g} m exceeds the profile's size "
                f"{float(amax):g} m."
            )
    if not isinstance(method, ExactUpdate | DiffraxODE):
        raise TypeError(f"`method` must be ExactUpdate() or DiffraxODE(...); got {method!r}.")
    return _retract(
        rheology,
        profile,
        as_float(work_of_adhesion),
        as_float(depth),
        ts,
        None if velocity is None else as_float(velocity),
        displacement,
        None if contact_radius is None else as_float(contact_radius),
        method,
        throw,
    )


@eqx.filter_jit
def _retract(rheology, profile, dgamma, depth, ts, velocity, displacement, contact_radius, method,
             throw):
    G_inf, G, tau = _prony_arrays(rheology)
    G_g = G_inf + jnp.sum(G)
    arm_ratio = G / G_g
    glass_ratio = G_g / G_inf
    a0 = profile_radius(profile, depth) if contact_radius is None else contact_radius

    # ---- internal variables w_k(t_i), shape (n, N) -------------------------------------
    if velocity is not None:
        delta = -velocity * ts
    else:
        delta = displacement - depth
    ode_ok = jnp.asarray(True)
    stats = {}
    if isinstance(method, ExactUpdate):
        if velocity is not None:
            w = _states_velocity(ts, velocity, arm_ratio, tau)
        else:
            w = _states_samples(ts, delta, arm_ratio, tau)
    elif isinstance(method, DiffraxODE):
        w, ode_ok, stats = _states_diffrax(
            method, ts, velocity, None if velocity is not None else delta, arm_ratio, tau
        )
    d = depth + delta
    d_eff = d + glass_ratio * jnp.sum(w, axis=-1)

    # ---- the front -----------------------------------------------------------------------
    c = jnp.sqrt(0.5 * jnp.pi * dgamma * G_g) / G_inf
    a_fold = _critical_radius(profile, c, 0.5)
    a_fc = _critical_radius(profile, c, 1.5)
    h_pin = _front_displacement(profile, a0, c)
    a_crit = jnp.minimum(a_fold, a0)
    h_crit = _front_displacement(profile, a_crit, c)
    can_recede = a0 > a_fold

    if velocity is not None:
        # constant-speed lift from rest: d_eff' = -v G(t)/G_inf < 0, so d_eff is its own
        # running minimum (and the cumulative minimum, slow on CPU, is not needed)
        m = d_eff
    else:
        m = lax.cummin(d_eff, axis=0)
    attached = m >= h_crit
    receding = attached & (m < h_pin) & can_recede
    # safe input for lanes not on the receding front: the root at max(a0, 2 a_fold)
    a_safe = jnp.maximum(a0, 2 * a_fold)
    m_safe = jnp.where(receding, m, _front_displacement(profile, a_safe, c))
    if isinstance(profile, Parabola | Cone):
        a_root = _stable_radius(profile, m_safe, c, None, None)
    else:
        hi = jnp.maximum(a0, a_safe)
        a_root = jax.vmap(lambda mm: _stable_radius(profile, mm, c, a_fold, hi))(m_safe)
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
    # the radii visited, [a_end, a0], is at clip(a_fc, a_end, a0)
    a_end = jnp.where(detached, a_crit, radius[-1])
    visited = detached | receding[-1]
    a_min = jnp.clip(a_fc, a_end, a0)
    f_front = force_at(a_min, _front_displacement(profile, a_min, c))
    max_tensile = jnp.minimum(jnp.min(force), jnp.where(visited, f_front, jnp.inf))

    # jump-off time inside the segment (t_prev, t_j]
    has_prev = i_j > 0
    i_prev = jnp.maximum(i_j - 1, 0)
    if velocity is not None:
        t_a = jnp.where(has_prev, ts[i_prev], 0.0)
        delta_a = -velocity * t_a
        w_a = jnp.where(has_prev, w[i_prev], jnp.zeros_like(tau))
        slope = -velocity
    else:
        t_a = jnp.where(has_prev, ts[i_prev], ts[0])
        delta_a = jnp.where(has_prev, delta[i_prev], delta[0])
        w_a = jnp.where(has_prev, w[i_prev], w[0])
        span_ = ts[i_j] - t_a
        slope = jnp.where(span_ > 0, (delta[i_j] - delta_a) / jnp.where(span_ > 0, span_, 1.0), 0)
    span = ts[i_j] - t_a
    seg_ok = detached & (span > 0)
    # on lanes without a bracketing segment, solve a harmless stand-in problem
    seg_args = (depth, delta_a, w_a, slope, arm_ratio, tau, glass_ratio)
    h_mid = 0.5 * (_segment_deff(0.0, *seg_args) + _segment_deff(1.0, *seg_args))
    h_target = jnp.where(seg_ok, h_crit, h_mid)
    span_safe = jnp.where(seg_ok, span, 1.0)

    def resid(u):
        return _segment_deff(u, *seg_args) - h_target

    u_j = bracketed_root(resid, 0.0, span_safe, steps=64)
    t_j = jnp.where(seg_ok, t_a + u_j, ts[i_j])
    nan = jnp.asarray(jnp.nan)
    jumpoff_time = jnp.where(detached, t_j, nan)
    jumpoff_disp = jnp.where(detached, depth + delta_a + slope * (t_j - t_a), nan)
    jumpoff_force = jnp.where(detached, jumpoff_force_value, nan)
    jumpoff_radius = jnp.where(detached, a_crit, nan)

    # ---- status ---------------------------------------------------------------------------
    result = RESULTS.where(detached, RESULTS.detached, RESULTS.in_contact)
    if not isinstance(profile, FlatPunch):
        g_touch = profile.g(a0)
        advancing = jnp.any(d > g_touch + 1e-9 * depth + 1e-15)
        result = RESULTS.where(advancing, RESULTS.advancing_contact, result)
    result = RESULTS.where(ode_ok, result, RESULTS.solver_failed)
    finite = jnp.all(jnp.isfinite(force)) & jnp.all(jnp.isfinite(radius))
    result = RESULTS.where(finite, result, RESULTS.invalid_input)
    if throw:
        force = result.error_if(force, is_error(result))

    stats = dict(stats)
    stats.update(
        fold_radius=a_fold,
        force_control_radius=a_fc,
        initial_radius=a0,
        effective_displacement=d_eff,
        effective_work_of_adhesion=dgamma * glass_ratio,
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
        result=result,
        stats=stats,
    )

