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
(the area between the tensile part of the lift curve and $F = 0$). Computed by the
trapezoidal rule over the samples in contact; the last interval, from the last sample in
contact to the jump-off, by the rule that is exact for the square-root shape
$F = F_j + C\sqrt{d - d_j}$ of a front approaching its fold,
$(d_k - d_j)\,(F_j + 2F_k)/3$. The error is $O(h^{3/2})$ in the sample spacing $h$ (the
square-root shape of the front near the fold).
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from .._elastic import _critical_radius, _front_displacement, profile_radius
from .._foundation import FoundationGrid, simulate
from .._pulloff import _prony_arrays, retract
from .._root import bracketed_root

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
    time: jnp.ndarray | None = None
    displacement: jnp.ndarray | None = None
    force: jnp.ndarray | None = None
    contact_radius: jnp.ndarray | None = None


def _front_constants(rheology, profile, work_of_adhesion):
    G_inf, G, tau = _prony_arrays(rheology)
    G_g = G_inf + jnp.sum(G)
    c = jnp.sqrt(0.5 * jnp.pi * work_of_adhesion * G_g) / G_inf
    one = jnp.ones_like(G_inf)
    a0 = profile_radius(profile, one)
    a_fold = _critical_radius(profile, c, 0.5)
    h_crit = _front_displacement(profile, jnp.minimum(a_fold, a0), c)
    return G / G_inf, tau, h_crit


def _lift_bound(ratio, tau, h_crit, hold):
    """$T_b$ with $D(T_b) = h_c$ (module docstring); `hold` = inf for the relaxed start."""
    decay = jnp.exp(-hold / tau)

    def D(T):
        return 1.0 - T + jnp.sum(ratio * (decay * jnp.exp(-T / tau) + tau * jnp.expm1(-T / tau)))

    hi = 1.0 - h_crit + jnp.sum(ratio * decay)
    zero = jnp.zeros_like(hi)
    return bracketed_root(lambda T: D(T) - h_crit, zero, hi, steps=64)


def _separation_work(d, force, attached, lift, detached, d_j, f_j):
    """$\\int_{d_j}^{d_0}\\max(-F, 0)\\,dd$ over the lift (module docstring)."""
    tension = jnp.maximum(-force, 0.0)
    both = attached[:-1] & attached[1:] & lift[:-1] & lift[1:]
    segments = 0.5 * (tension[:-1] + tension[1:]) * (d[:-1] - d[1:])
    work = jnp.sum(jnp.where(both, segments, 0.0))
    # last interval: from the last lift sample in contact to the jump-off
    in_lift = attached & lift
    k = jnp.max(jnp.where(in_lift, jnp.arange(d.shape[0]), -1))
    has_k = detached & (k >= 0)
    k = jnp.maximum(k, 0)
    last = (d[k] - d_j) * jnp.maximum(-(f_j + 2.0 * force[k]) / 3.0, 0.0)
    return work + jnp.where(has_k, jnp.where(jnp.isfinite(last), last, 0.0), 0.0)


class AbstractSweepModel(eqx.Module):
    """A protocol a sweep runs at every point (`RelaxedStart` or `ApproachHoldLift`).

    **Fields** (static: one compiled program per value):

    - `samples`: samples per curve.
    - `duration_factor`: the lift lasts `duration_factor` times the bound $T_b$ of the
      jump-off time (module docstring of `jaxcontact._sweep._models`), > 1.
    """

    samples: int = eqx.field(static=True, default=2000)
    duration_factor: float = eqx.field(static=True, default=1.5)

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

    def solve(self, rheology, profile, p, *, curves: bool = False) -> PointResult:
        """One point in scaled units; `p` maps parameter names to scalars; with `curves`
        the result also holds the sampled curve."""
        raise NotImplementedError

    def floats_per_curve(self, arms: int) -> int:
        """Live floats per sample of one curve, an upper estimate for sizing chunks."""
        raise NotImplementedError


def _result(sol, d, lift, lift_start, lift_duration, time, curves):
    attached = sol.contact_radius > 0
    detached = jnp.isfinite(sol.jumpoff_time)
    work = _separation_work(d, sol.force, attached, lift, detached, sol.jumpoff_displacement,
                            sol.jumpoff_force)
    out = dict(
        max_tensile_force=sol.max_tensile_force,
        jumpoff_force=sol.jumpoff_force,
        jumpoff_displacement=sol.jumpoff_displacement,
        jumpoff_time=sol.jumpoff_time - lift_start,
        jumpoff_radius=sol.jumpoff_radius,
        separation_work=work,
        lift_duration=lift_duration,
        status=sol.result._value.astype(jnp.int32),
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

    **Fields:** `samples` (default 2000), `duration_factor` (default 1.5).
    """

    name: ClassVar[str] = "relaxed"

    def solve(self, rheology, profile, p, *, curves=False):
        dgamma = p["work_of_adhesion"]
        ratio, tau, h_crit = _front_constants(rheology, profile, dgamma)
        T_b = _lift_bound(ratio, tau, h_crit, jnp.inf)
        duration = self.duration_factor * T_b
        ts = jnp.linspace(0.0, 1.0, self.samples, dtype=T_b.dtype) * duration
        one = jnp.ones_like(T_b)
        sol = retract(rheology, profile, work_of_adhesion=dgamma, depth=one, velocity=one,
                      ts=ts, throw=False)
        lift = jnp.ones(ts.shape, dtype=bool)
        return _result(sol, sol.displacement, lift, 0.0, duration, ts, curves)

    def floats_per_curve(self, arms: int) -> int:
        return 24 + 4 * arms


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
        ratio, tau, h_crit = _front_constants(rheology, profile, dgamma)
        T_b = _lift_bound(ratio, tau, h_crit, hold)
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
        return _result(sol, sol.displacement, lift, t_h, duration, ts - t_h, curves)

    def floats_per_curve(self, arms: int) -> int:
        n = max(arms, 1)
        return 64 + 8 * n * n + 4 * n
