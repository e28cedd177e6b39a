r"""The forward models a sweep runs, one point at a time (vmapped and sharded by `_run.py`).

Every point is computed in its own units (`_parameters.py`): depth $d_0 = 1$, lift speed
$v = 1$, relaxed modulus $G_\infty = 1$. The quantities below are in those units.

**Duration of the lift (how it reaches the jump-off).** During a lift at speed $v$ every
attached spring carries the line load $q(x) = 4[G_\infty u + \sum_k G_k e_k]$ with
$u = d(t) - g(x)$ and $e_k = u - v_k$ the stretch of arm $k$'s spring (relaxation form). On
approach $0 \le e_k \le u \le d_0 - g(x)$; a hold of length $t_h$ multiplies $e_k$ by
$e^{-t_h/\tau_k}$; a lift of duration $T$ maps $e_k \mapsto e_k e^{-T/\tau_k} -
v\tau_k(1 - e^{-T/\tau_k})$. Hence $q(x) \le 4G_\infty\,(D(T) - g(x))$ with

$$D(T) = d_0 - vT + \sum_k \frac{G_k}{G_\infty}\Big[d_0\,e^{-(t_h + T)/\tau_k}
  - v\tau_k\big(1 - e^{-T/\tau_k}\big)\Big],$$

decreasing in $T$. The contact radius never exceeds the touch radius $a_0$ ($g(a_0) = d_0$),
and an edge at $a$ survives only while $q(a) \ge -\sqrt{8\pi a\Delta\gamma G_g}
= -4G_\infty c\sqrt a$ (the energetic criterion, `docs/physics.md` §2). Once
$D(T) < h_c = \min_{a \le a_0}\big(g(a) - c\sqrt a\big) = h(\min(a_\mathrm{fold}, a_0))$
no radius satisfies it: the contact has detached. The sweep solves $D(T_b) = h_c$
(bracketed Newton, `_root.bracketed_root`, on $[0, d_0 - h_c + d_0\sum_k (G_k/G_\infty)
e^{-t_h/\tau_k}]$) and lifts for `duration_factor` $\times\,T_b$. For the relaxed start
($t_h \to \infty$) $D$ is exactly the effective displacement $d_\mathrm{eff}$ of `retract`, so
$T_b$ *is* the jump-off time; after a finite hold it is an upper bound. With
`duration_factor` > 1 every point therefore detaches within its lift; a point that does not
(round-off at a factor too close to 1) keeps `status = in_contact`.

**Separation work.** $W = \int_\mathrm{lift}\max(-F, 0)\,(-\dot d)\,\mathrm{d}t
= \int_{d_j}^{d_0}\max(-F(d), 0)\,\mathrm{d}d \ge 0$ [J]: the work the pulling machine does
against the adhesive (tensile) force from the start of the lift to the jump-off at $d_j$
(the area between the tensile part of the lift curve and $F = 0$).

*Relaxed start: exact, without samples.* With $v = d_0 = 1$ the lift is $d = 1 - t$ and
$d_\mathrm{eff}(t) = D(t) = 1 - t + \sum_k r_k\tau_k\,\mathrm{expm1}(-t/\tau_k)$,
$r_k = G_k/G_\infty$, convex and decreasing. The force is
$F = 8G_\infty(a_0 D - I(a_0))$ while the edge is pinned ($D \ge h(a_0)$, up to $t_p$) and
$F = F_f(a) = 8G_\infty(a\,h(a) - I(a))$ on the front, $a(t)$ the stable root of
$h(a) = D(t)$, $I(a) = \int_0^a g$. It is compressive at the start and changes sign once,
at $t_z$: in the pinned phase where $D = I(a_0)/a_0$, else on the front at the radius $a_z$
with $F_f(a_z) = 0$; it stays tensile to the jump-off $T_b$ ($F_j < 0$: $a_\mathrm{fold} <
a_z$). $t_p$, $t_z$, $T_b$ are roots (`_root.bracketed_root`), $a_z$ too or a closed form
(`zero_force_radius` of the profile). Then

$$W = 8G_\infty a_0\Big[\frac{\Delta^2}{2} + \sum_k r_k\tau_k\Delta\,e^{-t_z/\tau_k}
  \,\psi(\Delta/\tau_k)\Big] - \int_{\max(t_p, t_z)}^{T_b} F_f(a(t))\,\mathrm{d}t,
  \qquad \Delta = \max(t_p - t_z, 0),\ \psi(s) = 1 - \frac{1 - e^{-s}}{s},$$

the first term the pinned tension in closed form, the second with $t = T_b - u^2$ (the
front's square-root shape at the fold becomes smooth in $u$) by 32-point Gauss–Legendre
quadrature in $u$. It agrees with the elastic JKR closed form to round-off and with a
dense graded sampling of `retract` to about 1e-10 (`tests/test_sweep.py` asserts 1e-12 and
1e-8); the summaries of the relaxed start do not depend on `samples`, which sets only the
curves of `curves=True`.

*Full history: from the samples.* Computed by the trapezoidal rule over the samples in
contact up to the last but one, $k - 1$; from there to the jump-off through
$F = F_j + b\,s + c\,s^2$, $s = \sqrt{d - d_j}$, fitted to the jump-off force and samples
$k$ and $k - 1$ (or $k - 1$ and $k - 2$ when sample $k$ lies within a quarter interval of
the jump-off, where $F_k - F_j$ is round-off) and integrated exactly: exact for a pinned
edge ($F$ linear in $d$) and for the square-root shape of a front at its fold. The
remaining error is $O(h^{3/2})$ in the sample spacing $h$ (the square-root shape of the
front near the fold in the trapezoids before), larger where the tension occupies few
samples; the tests measure it against the relaxed start's exact value after a long hold.

*Its sampling error is estimated* from the same rule on every other sample:
$|W_h - W_{2h}|/(2^{3/2} - 1)$ (the rule converges as $h^{3/2}$ or faster, so this bounds
the error of $W_h$ asymptotically), infinite with fewer than 8 lift samples under tension
(too few for the asymptotics). `sweep` returns it (`separation_work_error_J`) and withholds
the work (NaN, `separation_work_status = undersampled`) where it exceeds the model's
`work_rtol` (default 1 %) of the work: more `samples` fix it.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp

from .._arms import psi_relative
from .._elastic import profile_radius
from .._foundation import FoundationGrid, simulate
from .._profiles import front_displacement
from .._pulloff import RelaxedFront, prony_arrays, relaxed_front, retract
from .._root import bracketed_root
from .._solution import RESULTS, is_error
from .._solvers import gauss_legendre_unit
from .._validate import domain_ok

__all__ = ["AbstractSweepModel", "RelaxedStart", "ApproachHoldLift", "PointResult"]


class PointResult(eqx.Module):
    """What one point of a sweep returns, in the point's own units (see the module docstring).

    Times are measured from the start of the lift.
    """

    max_tensile_force: jnp.ndarray
    jumpoff_force: jnp.ndarray
    jumpoff_displacement: jnp.ndarray
    jumpoff_time: jnp.ndarray
    jumpoff_radius: jnp.ndarray
    separation_work: jnp.ndarray
    lift_duration: jnp.ndarray
    status: jnp.ndarray
    separation_work_error: jnp.ndarray  # estimated absolute error of `separation_work`
    time: jnp.ndarray | None = None
    displacement: jnp.ndarray | None = None
    force: jnp.ndarray | None = None
    contact_radius: jnp.ndarray | None = None


class _Front(eqx.Module):
    """The constants of a lift's detachment front in scaled units (module docstring); the
    front itself is `retract`'s (`_pulloff.relaxed_front`)."""

    G_inf: jnp.ndarray
    ratio: jnp.ndarray  # G_k / G_inf, per arm
    tau: jnp.ndarray
    a0: jnp.ndarray  # the touch radius, g(a0) = 1
    relaxed: RelaxedFront  # c, a_fold, a_crit, h_crit (no edge holds once D < h_crit), ...

    @property
    def h_crit(self):
        return self.relaxed.h_crit


def _front_constants(rheology, profile, work_of_adhesion) -> _Front:
    G_inf, G, tau = prony_arrays(rheology)
    G_g = G_inf + jnp.sum(G)
    one = jnp.ones_like(G_inf)
    # the touch radius g(a0) = d0 = 1, rounded up by a few ulp so that g(a0) >= d0 also after
    # round-off (retract flags a lift whose start lies beyond g(a0) as an advancing contact,
    # with a tolerance below float32's resolution), and no larger than a bounded shape (a flat
    # punch touches with its whole face: rounded beyond its edge it was an invalid radius)
    a0 = profile_radius(profile, one, throw=False) * (1 + 4 * jnp.finfo(one.dtype).eps)
    a0 = jnp.minimum(a0, profile.max_radius)
    return _Front(G_inf=G_inf, ratio=G / G_inf, tau=tau, a0=a0,
                  relaxed=relaxed_front(profile, work_of_adhesion, G_inf, G_g, a0))


def _lift_D(ratio, tau, decay):
    r"""$D(T)$ of the module docstring (`decay` = $e^{-t_h/\tau_k}$: 0 for the relaxed start,
    where $D$ is the effective displacement $d_\mathrm{eff}$ of `retract`)."""

    def D(T):
        return 1.0 - T + jnp.sum(ratio * (decay * jnp.exp(-T / tau) + tau * jnp.expm1(-T / tau)))

    return D


def _lift_bound(ratio, tau, h_crit, hold):
    """$T_b$ with $D(T_b) = h_c$ (module docstring); `hold` = inf for the relaxed start."""
    decay = jnp.exp(-hold / tau)
    D = _lift_D(ratio, tau, decay)
    hi = 1.0 - h_crit + jnp.sum(ratio * decay)
    zero = jnp.zeros_like(hi)
    return bracketed_root(lambda T: D(T) - h_crit, zero, hi, steps=64)


# Gauss-Legendre nodes and weights on [0, 1] (the front's part of the relaxed start's
# separation work, module docstring)
_GL_U, _GL_W = gauss_legendre_unit(32)


class _RelaxedEvents(eqx.Module):
    """The summaries of a relaxed-start lift, exact (module docstring), in scaled units."""

    jumpoff_time: jnp.ndarray
    jumpoff_radius: jnp.ndarray
    jumpoff_force: jnp.ndarray
    max_tensile_force: jnp.ndarray
    separation_work: jnp.ndarray


def _relaxed_events(front: _Front, profile) -> _RelaxedEvents:
    """Jump-off, largest tensile force and separation work of a constant-speed lift ($v =
    d_0 = 1$) from the relaxed contact at the touch radius, without sampling the curve."""
    G_inf, ratio, tau, a0 = front.G_inf, front.ratio, front.tau, front.a0
    rf = front.relaxed
    c, a_fold, a_crit, h_crit, can_recede = rf.c, rf.a_fold, rf.a_crit, rf.h_crit, rf.can_recede
    # the edge stays pinned down to D = h(a0), or to the jump-off where the front cannot
    # recede (a0 <= a_fold, e.g. a flat punch)
    h_pin = jnp.where(can_recede, rf.h_pin, h_crit)
    y0 = profile.integral_g(a0) / a0  # the pinned force vanishes at D = y0
    D = _lift_D(ratio, tau, jnp.zeros_like(tau))

    def front_force(a):
        return 8.0 * G_inf * (a * front_displacement(profile, a, c) - profile.integral_g(a))

    # the force changes sign in the pinned phase (y0 > h(a0)) or on the front at a_z (not
    # needed in the first case: the bracket [a0, a0])
    pinned_zero = h_pin < y0
    a_z = profile.zero_force_radius(c, jnp.where(pinned_zero, a0, a_crit), a0)
    y_zero = jnp.where(pinned_zero, y0, front_displacement(profile, a_z, c))
    # D(t) = y for the jump-off (T_b), the end of pinning (t_p) and the zero of the force
    # (t_z), one loop for the three: D(0) = 1 >= y and D(1 - y) <= y (D(t) <= 1 - t; equal
    # for an elastic solid, whose root is that end)
    targets = jnp.stack([h_crit, h_pin, y_zero])
    T_b, t_p, t_z = jax.vmap(
        lambda y: bracketed_root(lambda t: D(t) - y, jnp.zeros_like(y), 1.0 - y))(targets)
    t_p = jnp.minimum(jnp.where(can_recede, t_p, T_b), T_b)
    t_z = jnp.minimum(t_z, T_b)
    # pinned tension, closed form: 8 G a0 int_{t_z}^{t_p} (D(t_z) - D(t)) dt
    span = jnp.where(pinned_zero, jnp.maximum(t_p - t_z, 0.0), 0.0)
    arms = jnp.sum(ratio * tau * span * jnp.exp(-t_z / tau) * psi_relative(span / tau))
    w_pin = 8.0 * G_inf * a0 * (0.5 * span * span + arms)
    # the front from max(t_p, t_z) to T_b, t = T_b - u^2
    U = jnp.sqrt(jnp.where(can_recede, jnp.maximum(T_b - jnp.maximum(t_p, t_z), 0.0), 0.0))
    u = U * jnp.asarray(_GL_U, T_b.dtype)
    d_eff = jax.vmap(D)(T_b - u * u)
    # lanes without a front: a harmless stand-in (retract's choice)
    m_safe = front_displacement(profile, jnp.maximum(a0, 2 * a_fold), c)
    m = jnp.where(can_recede, jnp.maximum(d_eff, h_crit), m_safe)
    a = profile.front_radius(m, c, a_fold, jnp.maximum(a0, 2 * a_fold))
    w_front = U * jnp.sum(jnp.asarray(_GL_W, T_b.dtype) * -front_force(a) * 2.0 * u)
    # the largest tensile force: the minimum of F_f over the radii the front visits
    a_fc = rf.a_fc
    return _RelaxedEvents(
        jumpoff_time=T_b,
        jumpoff_radius=a_crit,
        jumpoff_force=front_force(a_crit),
        max_tensile_force=front_force(jnp.clip(a_fc, a_crit, a0)),
        separation_work=w_pin + jnp.where(can_recede, w_front, 0.0),
    )


def _separation_work(d, force, attached, lift, detached, d_j, f_j):
    r"""$\int_{d_j}^{d_0}\max(-F, 0)\,dd$ over the lift (module docstring)."""
    n = d.shape[0]
    tension = jnp.maximum(-force, 0.0)
    in_lift = attached & lift
    idx = jnp.arange(n)
    k = jnp.max(jnp.where(in_lift, idx, -1))  # the last lift sample in contact
    has_k = detached & (k >= 0)

    def at(i):
        i = jnp.clip(i, 0, n - 1)
        return jnp.maximum(d[i] - d_j, 0.0), force[i] - f_j

    # the fit runs through samples p and q = p - 1: p = k, or k - 1 where sample k lies so
    # close to the jump-off (within a quarter of a sample interval) that F_k - F_j is
    # round-off
    xk, _ = at(k)
    xk1, _ = at(k - 1)
    p = jnp.where(xk > 0.25 * (xk1 - xk), k, k - 1)
    q = p - 1
    has_fit = has_k & (q >= 0) & in_lift[jnp.maximum(q, 0)]
    # the trapezoidal rule up to sample q (up to k without a jump-off or a fit)
    end = jnp.where(has_fit, q, jnp.where(has_k, k, n))
    both = in_lift[:-1] & in_lift[1:] & (idx[1:] <= end)
    segments = 0.5 * (tension[:-1] + tension[1:]) * (d[:-1] - d[1:])
    work = jnp.sum(jnp.where(both, segments, 0.0))
    # from sample q to the jump-off: F = F_j + b s + c s^2 with s = sqrt(d - d_j) through
    # samples p and q (exact for a pinned edge, F linear in d, and for the square-root shape
    # of a front at its fold), integrated exactly
    x1, g1 = at(p)
    x2, g2 = at(q)
    r1, r2 = jnp.sqrt(x1), jnp.sqrt(x2)
    det = r1 * x2 - x1 * r2
    ok = has_fit & (det > 0) & jnp.isfinite(det)
    det = jnp.where(ok, det, 1.0)
    b = (g1 * x2 - g2 * x1) / det
    c = (r1 * g2 - r2 * g1) / det
    fit = -(f_j * x2 + (2.0 / 3.0) * b * x2 * r2 + 0.5 * c * x2 * x2)
    # with one lift sample in contact: from it to the jump-off by the square-root rule
    sqrt_rule = xk * jnp.maximum(-(f_j + 2.0 * force[jnp.maximum(k, 0)]) / 3.0, 0.0)
    last = jnp.where(ok, jnp.maximum(fit, 0.0), jnp.where(has_k, sqrt_rule, 0.0))
    return work + jnp.where(jnp.isfinite(last), last, 0.0)


class AbstractSweepModel(eqx.Module):
    """A protocol a sweep runs at every point (`RelaxedStart` or `ApproachHoldLift`).

    **Fields** (static: one compiled program per value):

    - `samples`: samples per curve.
    - `duration_factor`: the lift lasts `duration_factor` times the bound $T_b$ of the
      jump-off time (module docstring of `jaxcontact._sweep._models`), > 1.
    - `work_rtol`: the relative sampling error the separation work must be within (estimated
      from the samples, module docstring); beyond it the work is withheld (NaN) and
      `separation_work_status` is `undersampled`. Default 1e-2.
    """

    samples: int = eqx.field(static=True, default=2000)
    duration_factor: float = eqx.field(static=True, default=1.5)
    work_rtol: float = eqx.field(static=True, default=1e-2)

    name: ClassVar[str] = ""
    required: ClassVar[tuple] = ("work_of_adhesion", "depth", "velocity")
    # name -> default: None (absent unless given), a number, or the name of another parameter
    optional: ClassVar[dict] = {}
    min_samples: ClassVar[int] = 2

    def __check_init__(self):
        if int(self.samples) < self.min_samples:
            raise ValueError(f"`samples` must be an integer >= {self.min_samples}; got "
                             f"{self.samples}.")
        factor = float(self.duration_factor)
        if not factor > 1.0 or not factor < float("inf"):
            raise ValueError(f"`duration_factor` must be a finite number > 1 (the lift lasts "
                             f"that many times the bound of the jump-off time); got {factor}.")
        rtol = float(self.work_rtol)
        if not 0.0 < rtol < float("inf"):
            raise ValueError(f"`work_rtol` must be a finite number > 0; got {rtol}.")

    @abc.abstractmethod
    def solve(self, rheology, profile, p, *, curves: bool = False) -> PointResult:
        """One point in scaled units; `p` maps parameter names to scalars; with `curves`
        the result also holds the sampled curve."""

    def cpu_chunk_budget(self, curves: bool) -> int:
        """Default bytes of one chunk per CPU device (`sweep`'s `memory_limit` where the
        backend reports no memory limit): the fastest of the sizes measured for the model
        (`benchmarks/results/sweep.md`); 512 MiB unless a model says otherwise."""
        return 512 * 2**20

    @abc.abstractmethod
    def floats_per_curve(self, arms: int, curves: bool) -> int:
        """Live floats of one point (with `curves`: including the sampled curves), an upper
        estimate for sizing chunks."""


def _valid(front: _Front, T_b, p):
    """A point the model can run: finite inputs, positive relaxation times (no underflow in
    the scaling) and a finite positive bound of the jump-off time."""
    tau = front.tau
    ok = jnp.all(jnp.isfinite(front.ratio)) & jnp.all(tau > 0) & jnp.all(jnp.isfinite(tau))
    ok = ok & jnp.isfinite(front.h_crit) & jnp.isfinite(T_b) & (T_b > 0)
    for value in p.values():
        ok = ok & jnp.isfinite(value)
    return ok


# the lift samples under tension below which the history's separation work is `undersampled`
_MIN_TENSION_SAMPLES = 8


def _beyond_profile(profile, dtype):
    """A point whose touch radius (g(a0) = d0 = 1 in scaled units) lies beyond what the
    profile describes (`valid_radius`: a Parabola's R); scale-free, so checked in the
    model's units."""
    return profile.contact_radius(jnp.ones((), dtype)) > profile.valid_radius


def _result(sol, d, lift, lift_start, lift_duration, time, curves, valid, beyond):
    """The summaries of a point; a point that is not `valid` gets `invalid_input`, one
    `beyond` its profile `beyond_profile`."""
    result = RESULTS.where(valid, sol.result, RESULTS.invalid_input)
    result = RESULTS.where(beyond, RESULTS.beyond_profile, result)
    attached = sol.contact_radius > 0
    detached = jnp.isfinite(sol.jumpoff_time)
    work = _separation_work(d, sol.force, attached, lift, detached, sol.jumpoff_displacement,
                            sol.jumpoff_force)
    # its sampling error: the same rule on every other sample; the rule converges as h^(3/2)
    # or faster, so |W_h - W_2h| / (2^(3/2) - 1) bounds the error of W_h (asymptotically)
    coarse = _separation_work(d[::2], sol.force[::2], attached[::2], lift[::2], detached,
                              sol.jumpoff_displacement, sol.jumpoff_force)
    error = jnp.abs(work - coarse) / (2.0**1.5 - 1.0)
    # fewer than `_MIN_TENSION_SAMPLES` lift samples under tension: no estimate to trust
    tension = jnp.sum(attached & lift & (sol.force < 0))
    error = jnp.where(tension >= _MIN_TENSION_SAMPLES, error, jnp.inf)
    out = dict(
        max_tensile_force=sol.max_tensile_force,
        jumpoff_force=sol.jumpoff_force,
        jumpoff_displacement=sol.jumpoff_displacement,
        jumpoff_time=sol.jumpoff_time - lift_start,
        jumpoff_radius=sol.jumpoff_radius,
        separation_work=work,
        lift_duration=lift_duration,
        status=result._value.astype(jnp.int32),
        separation_work_error=jnp.where(detached, error, jnp.nan),
    )
    if curves:
        out.update(time=time, displacement=d, force=sol.force, contact_radius=sol.contact_radius)
    return PointResult(**out)


class RelaxedStart(AbstractSweepModel):
    r"""Lift from a fully relaxed contact at constant speed: `retract` (paper section 5).

    Parameters: the material, the indenter, `work_of_adhesion`, `depth`, `velocity`. Times
    start at the start of the lift; the lift lasts `duration_factor` times the exact jump-off
    time (found before the run from the effective displacement, see the module docstring), so
    a fraction `1/duration_factor` of the samples lies before the jump-off.

    The summaries (jump-off, largest tensile force, separation work) are computed exactly,
    without sampling the curve (module docstring): they do not depend on `samples` or
    `duration_factor`, which shape only the curves of `sweep(..., curves=True)`
    (`retract` at `samples` uniform times).

    **Fields:** `samples` (default 2000), `duration_factor` (default 1.5).
    """

    name: ClassVar[str] = "relaxed"

    def cpu_chunk_budget(self, curves: bool) -> int:
        # chunks near the CPU's caches: 32 MiB with the curves, 8 MiB for the summaries alone
        # (the measurements: benchmarks/results/sweep.md, "Chunk size")
        return (32 if curves else 8) * 2**20

    def solve(self, rheology, profile, p, *, curves=False):
        dgamma = p["work_of_adhesion"]
        front = _front_constants(rheology, profile, dgamma)
        ev = _relaxed_events(front, profile)
        T_b = ev.jumpoff_time
        duration = self.duration_factor * T_b
        valid = _valid(front, T_b, p)
        valid = valid & domain_ok(rheology) & domain_ok(profile) & (dgamma > 0)
        summaries = dict(
            max_tensile_force=ev.max_tensile_force,
            jumpoff_force=ev.jumpoff_force,
            jumpoff_displacement=1.0 - T_b,
            jumpoff_time=T_b,
            jumpoff_radius=ev.jumpoff_radius,
            separation_work=ev.separation_work,
        )
        finite = jnp.asarray(True)
        for value in summaries.values():
            finite = finite & jnp.isfinite(value)
        result = RESULTS.where(finite, RESULTS.detached, RESULTS.non_finite_result)
        out = {}
        if curves:
            ts = jnp.linspace(0.0, 1.0, self.samples, dtype=T_b.dtype) * duration
            one = jnp.ones_like(T_b)
            sol = retract(rheology, profile, work_of_adhesion=dgamma, depth=one, velocity=one,
                          ts=ts, contact_radius=front.a0, throw=False)
            # the curve's own failure: non-finite samples (retract's other results, e.g. an
            # advancing contact, cannot occur on this lift; not reading `sol.result` lets XLA
            # drop its events, which the exact summaries replace; benchmarks/bench_sweep.py)
            finite = jnp.all(jnp.isfinite(sol.force)) & jnp.all(jnp.isfinite(sol.contact_radius))
            result = RESULTS.where(finite, result, RESULTS.non_finite_result)
            out = dict(time=ts, displacement=sol.displacement, force=sol.force,
                       contact_radius=sol.contact_radius)
        result = RESULTS.where(valid, result, RESULTS.invalid_input)
        result = RESULTS.where(_beyond_profile(profile, T_b.dtype), RESULTS.beyond_profile,
                               result)
        bad = is_error(result)
        nan = jnp.asarray(jnp.nan, T_b.dtype)
        summaries = {k: jnp.where(bad, nan, v) for k, v in summaries.items()}
        # the separation work is exact (quadrature error ~1e-10 relative, module docstring)
        return PointResult(**summaries, lift_duration=jnp.where(bad, nan, duration),
                           status=result._value.astype(jnp.int32),
                           separation_work_error=jnp.where(bad, nan, 0.0), **out)

    def floats_per_curve(self, arms: int, curves: bool) -> int:
        # the summaries: the quadrature's nodes and the roots (XLA's compiled memory: 98
        # floats with one arm and 32 nodes); with the curves, `retract`'s samples (floats per
        # sample: benchmarks/results/sweep.md, XLA's compiled memory), with a margin, and
        # the curves' outputs
        summaries = 4 * len(_GL_U) + 16 * arms + 16
        return summaries + (int(self.samples) * (12 + 2 * arms) if curves else 0)


class ApproachHoldLift(AbstractSweepModel):
    r"""Approach from first touch, hold, lift: the full-history model `simulate`.

    The indenter touches at $t = -t_a - t_h$ (times are measured from the start of the
    lift), approaches at `approach_velocity` (default `velocity`) to `depth`, holds for
    `hold` [s] (0 allowed), and is lifted at `velocity` for `duration_factor` times the bound
    $T_b$ of the jump-off time (module docstring). The samples: $\max(2, n/4)$ uniform over
    the approach, $\max(2, n/8)$ over the hold, the rest over the lift (every corner of the
    history is a sample, as `simulate` needs).

    **Fields:** `samples` (default 2000, at least 8), `duration_factor` (default 1.5),
    `cells` (foundation cells, default 64: `FoundationGrid`).
    """

    cells: int = eqx.field(static=True, default=64)

    name: ClassVar[str] = "history"
    required: ClassVar[tuple] = ("work_of_adhesion", "depth", "velocity", "hold")
    optional: ClassVar[dict] = {"approach_velocity": "velocity"}
    min_samples: ClassVar[int] = 8

    def _counts(self):
        n = int(self.samples)
        n_a = max(2, n // 4)
        n_h = max(2, n // 8)
        return n_a, n_h, n - n_a - n_h

    def solve(self, rheology, profile, p, *, curves=False):
        dgamma = p["work_of_adhesion"]
        hold = p["hold"]
        v_in = p["approach_velocity"]
        front = _front_constants(rheology, profile, dgamma)
        T_b = _lift_bound(front.ratio, front.tau, front.h_crit, hold)
        duration = self.duration_factor * T_b
        dtype = T_b.dtype
        n_a, n_h, n_l = self._counts()
        t_a = 1.0 / v_in
        t_h = t_a + hold
        s_a = jnp.linspace(0.0, 1.0, n_a, endpoint=False, dtype=dtype)
        s_h = jnp.linspace(0.0, 1.0, n_h, endpoint=False, dtype=dtype)
        s_l = jnp.linspace(0.0, 1.0, n_l, dtype=dtype)
        ts = jnp.concatenate([s_a * t_a, t_a + s_h * hold, t_h + s_l * duration])
        d = jnp.concatenate([s_a, jnp.ones_like(s_h), 1.0 - s_l * duration])
        sol = simulate(rheology, profile, dgamma, ts, d, grid=FoundationGrid(cells=self.cells),
                       throw=False)
        lift = jnp.arange(ts.shape[0]) >= n_a + n_h
        valid = _valid(front, T_b, p)
        return _result(sol, sol.displacement, lift, t_h, duration, ts - t_h, curves, valid,
                       _beyond_profile(profile, dtype))

    def floats_per_curve(self, arms: int, curves: bool) -> int:
        # XLA's compiled memory measures 9.7 (2000 samples) to 11.7 (500) floats per sample
        # with one arm: per-sample outputs and the free propagators (N x N per sample)
        per_sample = 8 + 4 * arms * arms + 4 * arms + (4 if curves else 0)
        return int(self.samples) * per_sample
