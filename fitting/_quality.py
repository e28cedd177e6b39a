r"""How good a fit is, said honestly: quality per segment, model inadequacy, a contact point
outside the data, convergence, and curves without a contact signal.

Every function here works on plain arrays of the prepared data (:class:`CurveBatch`
fields, shape `(curves, samples)`) and the model at the optimum, so that the finish of a
fit can later run batched; :func:`assess` applies them to a :class:`FitResult`.

Quality measures (σ: each sample's noise, :attr:`CurveBatch.noise`; $w$: the number of
measured samples a kept sample stands for, :attr:`CurveBatch.weight`; $r = (F^\mathrm{eff}
- F)/\sigma$ the fitted residual):

- $R^2$ of the model force, *weighted* (each kept sample counted $w$ times: the headline
  $R^2$, an estimate of $R^2$ over all measured samples) and *unweighted* (over the kept
  samples, each once: subsampling keeps more samples where the force changes fast, so this
  one weighs the contact, the hold's start and the jump-off more).
- per segment (approach, hold, retract): both $R^2$, the reduced $\chi^2$ of the segment
  $\sum w r^2 / \sum w$ (the mean squared normalised residual per measured sample; the
  fit's $k$ parameters are not shared out among the segments) and the largest $|r|$.

Flags (:data:`FLAGS`; each with a message naming the numbers):

- ``model_inadequate``: the reduced $\chi^2$ exceeds :data:`INADEQUATE_CHI2` (RMS residual
  above 5σ): the residuals are systematic, the model does not describe the data. The
  standard errors are then those of the Gauss–Newton covariance scaled by $\chi^2_\mathrm{red}$
  (lmfit's ``scale_covar``, :mod:`fitting._uncertainty`): how tightly the misfit holds
  the parameters, not the precision of a measurement, and not a confidence interval.
- ``segment_not_described``: a fitted segment with $R^2 <$ :data:`POOR_R2` while its
  residuals are above the noise (segment $\chi^2_\mathrm{red} > 2$: a flat, noise-dominated
  segment has $R^2$ near 0 however good the fit), or with a segment $\chi^2_\mathrm{red}$
  above :data:`INADEQUATE_CHI2`.
- ``contact_outside_data``: a fitted contact point (indentation offset $\delta$, model
  indentation $d + \delta$) before the first fitted approach sample, with the model in
  contact there while the data are not (the model starts at a force the data do not show),
  or beyond the deepest sample (the model never touches). Such an offset is not a fit
  result but a failure of the model to describe the start of contact. It is flagged, not
  bounded: a bound would only move the failure into the other parameters and report the
  offset "at a bound", while the flag names the misfit where it happens.
- ``force_after_detachment``: after the model's last jump-off on the retract, where the
  model is free, the measured force stays off it by more than 3σ on average, at 1 % or more
  of the curve's χ² (:func:`force_after_detachment`): membrane tethers on a cell, a
  detachment slower or later than the model's, or a retract baseline unlike the
  approach's. The model cannot describe these samples, and every sample counts in the
  objective (:mod:`fitting._objective`), so they pull on the parameters; the message names
  the offset, its duration, its share of χ² and what to try.
- ``baseline_trend``: a curve preprocessed with a constant baseline whose free force
  (the rest segment, or the approach before the contact) follows a straight line in time
  that rises or falls, by the end of the approach, by at least :data:`TREND_SIGMA` times
  both the free force's scatter about the line and the rise's standard error
  (``ContactPoint.trend``, ``trend_noise``, ``trend_error``; :func:`baseline_trend`): a
  tilt of the approach (virtual deflection), a drift or an interference wave, which the
  constant baseline leaves in the data. It inflates the noise estimate (by
  $\sqrt{1 + (A/\sigma)^2/12}$ for a rise $A$ over the free force itself and scatter
  $\sigma$: the reduced $\chi^2$ follows it), can put the detected contact point on a
  bump of the baseline, and continues into the contact as a force the model does not
  have; the message gives the trend and the remedies (a fitted drift,
  ``force_drift=True``, or a linear baseline, for a line). Not raised for a fit with a
  fitted drift.
- ``drift_not_baseline``: a fit with a fitted force drift (``force_drift=True``) whose
  drift differs from the free force's own slope before contact (``ContactPoint.trend_slope``,
  less the slope the baseline removed) by at least :data:`TREND_SIGMA` standard errors of
  the difference and by at least one noise σ over the fitted duration
  (:func:`drift_not_baseline`): the line then takes up a misfit of the model in contact (a
  relaxation or an adhesion the model does not have), not a baseline; its lower χ² does
  not make the values right, and they depend on it.
- ``not_converged``: the best start did not meet the tolerance; :func:`convergence`
  gives the reason (the step limit, or a stop without progress) and what to try.
- ``outside_jkr_limit``: Tabor's parameter of the fitted contact (:func:`tabor_entry`),
  determined (status "ok"), is below :data:`TABOR_JKR_MIN`: the surface forces' range is
  not small against the elastic
  neck at the contact edge, and the model's JKR-limit criterion (adhesion of vanishing
  range) overestimates the neck and the pull-off.

**Validity (Tabor).** Every fit with adhesion reports Tabor's parameter
$\mu = (R\,\Delta\gamma^2/(E^{*2} z_0^3))^{1/3}$ (:func:`jaxcontact.tabor_parameter`) among
its derived quantities (``tabor_mu_1``: the summary, ``parameters.json``, ``parameters.csv``
and the map columns), with the glass modulus $E^* = 4G_g$ (the criterion's modulus; the
conservative, smaller $\mu$), $z_0$ = :data:`jaxcontact._probes.TABOR_SEPARATION` (0.3 nm)
and $R$ the radius of the fitted sphere or paraboloid. For other profiles (cone, pyramid,
flat punch, power law, tabulated) no radius of curvature is fitted and $\mu$ is reported as
not defined (NaN). The standard error follows from the covariance by the delta method.

A curve whose data show no contact (:func:`check_contact_signal`: on the approach and hold
the baselined force never stays above ``5 σ`` for 5 samples — the loader's contact
detection, :func:`fitting.preprocess` — or, on a retract-only curve, $|F|$ never does) is not
fitted: a `ValueError` with the reason (a failed curve in :func:`fitting.fit_each`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
from collections.abc import Sequence

import numpy as np

import jaxcontact as jc

from ._caller import warn_at_caller
from ._curve import DataError
from ._prepare import SEGMENTS, noise_level
from ._preprocess import _detect_index
from ._spec import rheology_kind
from ._uncertainty import delta_method, derived_quantities

__all__ = ["INADEQUATE_CHI2", "POOR_R2", "FLAGS", "SegmentQuality", "r_squared",
           "r_squared_rows", "segment_quality", "segment_quality_rows", "contact_outside",
           "force_after_detachment", "AFTER_DETACHMENT_SAMPLES", "AFTER_DETACHMENT_SIGMA",
           "AFTER_DETACHMENT_SHARE", "baseline_trend", "TREND_SIGMA", "drift_not_baseline",
           "convergence", "check_contact_signal",
           "assess", "warning_kinds", "warn_summary", "tabor_entry", "TABOR_JKR_MIN"]

#: Reduced χ² above which the residuals are far above the noise (RMS residual > 5 σ).
INADEQUATE_CHI2 = 25.0

#: R² below which a segment with residuals above the noise is not described.
POOR_R2 = 0.5

#: Contact-signal detection: the loader's defaults (:func:`fitting.preprocess`).
SIGNAL_THRESHOLD = 5.0
SIGNAL_RUN = 5

#: The flags of a fit (see the module docstring).
FLAGS = ("model_inadequate", "segment_not_described", "contact_outside_data",
         "force_after_detachment", "baseline_trend", "drift_not_baseline", "not_converged",
         "outside_jkr_limit")

#: Tabor's parameter below which a fit is flagged ``outside_jkr_limit``. Johnson and
#: Greenwood's adhesion map (J. Colloid Interface Sci. 192, 326 (1997)) puts the JKR zone at
#: Maugis' $\lambda > 5$ ($\lambda \approx 1.16\mu$ for a Lennard-Jones law, i.e.
#: $\mu \gtrsim 4.3$), where JKR's pull-off is within a few per cent of the
#: Maugis–Dugdale one; DMT holds below $\lambda \approx 0.1$. 5 is that bound rounded up
#: (and `docs/physics.md`'s "≳ 3–5" at its safe end).
TABOR_JKR_MIN = 5.0

#: :func:`force_after_detachment`: the least measured samples after the model's jump-off,
#: the mean normalised residual over them and their least share of the curve's χ² for a
#: curve to be named.
AFTER_DETACHMENT_SAMPLES = 10
AFTER_DETACHMENT_SIGMA = 3.0
AFTER_DETACHMENT_SHARE = 0.01


#: :func:`baseline_trend`: the least rise of the free force's straight line to the end of
#: the approach, in units of the free force's scatter about the line and of the rise's
#: standard error, for a constant baseline to be flagged: the preprocessing's contact
#: threshold (5 σ, :func:`fitting.preprocess`), so that what the constant baseline leaves
#: at the deepest point reaches what the detection counts as contact, and the rise is not
#: noise.
TREND_SIGMA = 5.0


def _curve_label(n: int, curve) -> str:
    """How a message names curve `n` of a fit: ``curve n (source)``."""
    return f"curve {n}" + (f" ({curve.source})" if curve.source else "")


def baseline_trend(curves, *, drift: bool = True) -> list[str]:
    """One message per curve of `curves` (preprocessed :class:`fitting.Curve`) with a
    constant baseline whose free force's straight line in time rises or falls, by the
    end of the approach, by at least :data:`TREND_SIGMA` times both the free force's
    scatter about the line and the rise's standard error (``ContactPoint.trend``,
    ``trend_noise``, ``trend_error``): what it is, what it does to the fit, and what to
    try (with `drift`, a fitted force drift among the remedies: the history model's; the
    relaxed model refuses it)."""
    remedy = ("refit with force_drift=True (command line: --force-drift), where the data "
              "decide the line inside the fit (flagged drift_not_baseline where it is not "
              "the free force's own slope), or with baseline='linear' (command line: "
              "--baseline linear); compare either" if drift else
              "refit with baseline='linear' (command line: --baseline linear) and compare")
    msgs = []
    for n, c in enumerate(curves):
        cp = c.contact
        if cp is None or cp.baseline != "constant" or not math.isfinite(cp.trend_noise) \
                or abs(cp.trend) < TREND_SIGMA * max(cp.trend_noise, cp.trend_error):
            continue
        label = _curve_label(n, c)
        msgs.append(
            f"{label}: the free force before contact ({cp.baseline_region}) has a trend "
            f"in time that {'rises' if cp.trend > 0 else 'falls'} by {abs(cp.trend):.3g} N "
            f"by the end of the approach, {abs(cp.trend) / cp.trend_noise:.1f} times its "
            f"scatter about the line ({cp.trend_noise:.3g} N): a tilt of the approach "
            "(virtual deflection), a drift or an interference wave, which the constant "
            f"baseline leaves in the data; its noise estimate ({cp.noise:.3g} N, "
            f"{cp.noise / cp.trend_noise:.2g} times the scatter about the line) and the "
            "reduced chi2 follow it, the detected contact point may lie on a bump of the "
            "baseline, and the trend continues into the contact as a force the model does "
            "not have, so the fitted values can depend on it (the work of adhesion most): "
            f"{remedy} with this fit in one noise (each reduced chi2 as printed is against "
            "its own noise estimate: multiply it by (that noise / "
            f"{cp.trend_noise:.3g} N)^2); a wave no baseline here removes")
    return msgs


def drift_not_baseline(result) -> list[str]:
    r"""One message per curve of a fit with a fitted force drift (``force_drift``) whose
    drift $s$ differs from the free force's own slope before contact, $s_f$
    (``ContactPoint.trend_slope`` less the baseline's ``force_slope``: the slope left in the
    fitted data), by at least :data:`TREND_SIGMA` times the standard error of the
    difference, $\sqrt{\sigma_s^2 + \sigma_{s_f}^2}$, and by at least the curve's noise
    over the fitted duration $T$, $|s - s_f|\,T \ge \sigma$."""
    if not result.spec.force_drift or "force_drift" not in result.names:
        return []
    j = result.names.index("force_drift")
    s, se = float(result.values[j]), float(result.stderr[j])
    data = result.data
    ts, valid = np.asarray(data.ts), np.asarray(data.valid) > 0
    msgs = []
    for n, c in enumerate(result.curves):
        cp = c.contact
        if cp is None or not (math.isfinite(cp.trend_slope)
                              and math.isfinite(cp.trend_slope_error)):
            continue
        free = cp.trend_slope - cp.force_slope
        gap = s - free
        error = math.sqrt((se if math.isfinite(se) else 0.0) ** 2 + cp.trend_slope_error ** 2)
        span = float(np.ptp(ts[n][valid[n]])) if valid[n].any() else 0.0
        sigma = float(np.asarray(data.sigma)[n])
        if abs(gap) < TREND_SIGMA * error or abs(gap) * span < sigma:
            continue
        label = _curve_label(n, c)
        msgs.append(
            f"{label}: the fitted force drift {s:.3g} +/- {se:.2g} N/s is not the free force's "
            f"own slope before contact ({free:.3g} +/- {cp.trend_slope_error:.2g} N/s): "
            f"{abs(gap) / error:.1f} standard errors apart, {abs(gap) * span / sigma:.3g} "
            f"noise sigma over the fitted {span:.3g} s; the line takes up a misfit of the "
            "model in contact (a relaxation or an adhesion the model does not have), not a "
            "baseline drift, and the fitted values depend on it: its lower chi2 does not "
            "make them right; compare with the fit without the drift, and where the trend "
            "before contact is a baseline, baseline='linear' (--baseline linear) removes "
            "that line itself")
    return msgs


def r_squared(model, force, weight, mask) -> float:
    """$R^2 = 1 - \\sum w (F_m - F)^2 / \\sum w (F - \\bar F_w)^2$ over the masked samples
    (`weight` `None`: every sample once); nan with fewer than 2 samples or no variance."""
    row = lambda x: None if x is None else np.reshape(np.asarray(x), (1, -1))  # noqa: E731
    return float(r_squared_rows(row(model), row(force), row(weight), row(mask))[0])


def r_squared_rows(model, force, weight, mask) -> np.ndarray:
    """:func:`r_squared` of every row of `(rows, samples)` arrays at once (`weight` `None`:
    every sample once): shape `(rows,)`."""
    mask = np.asarray(mask, dtype=bool)
    f = np.where(mask, np.asarray(force, dtype=float), 0.0)
    w = np.where(mask, 1.0 if weight is None else np.asarray(weight, dtype=float), 0.0)
    sw = np.sum(w, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.sum(w * f, axis=1) / sw
        ss_tot = np.sum(w * (f - mean[:, None]) ** 2, axis=1)
        e = np.where(mask, np.asarray(model, dtype=float), 0.0) - f
        ss_res = np.sum(w * e * e, axis=1)
        r2 = 1.0 - ss_res / ss_tot
    ok = (np.sum(mask, axis=1) >= 2) & (sw > 0) & (ss_tot > 0)
    return np.where(ok, r2, np.nan)


@dataclasses.dataclass
class SegmentQuality:
    """Fit quality of one segment (all curves together): `segment` name, `n_kept`,
    `n_measured` samples, `r_squared` (weighted), `r_squared_unweighted`, `reduced_chi2`
    ($\\sum w r^2/\\sum w$), `max_residual` (largest $|r|$ [σ]), `described`."""

    segment: str
    n_kept: int
    n_measured: int
    r_squared: float
    r_squared_unweighted: float
    reduced_chi2: float
    max_residual: float
    described: bool

    def as_dict(self) -> dict:
        return {k: (_num(v) if isinstance(v, float) else v)
                for k, v in dataclasses.asdict(self).items()}


def _num(x):
    x = float(x)
    return x if math.isfinite(x) else None


def segment_quality(force, fitted_force, model_force, noise, weight, valid,
                    segment) -> list[SegmentQuality]:
    """:class:`SegmentQuality` of every segment present (arrays `(curves, samples)`;
    `fitted_force` for the residuals, `model_force` for $R^2$, as the headline values)."""
    return segment_quality_rows(*(np.asarray(x)[None] for x in (
        force, fitted_force, model_force, noise, weight, valid, segment)))[0]


def segment_quality_rows(force, fitted_force, model_force, noise, weight, valid,
                         segment) -> list[list[SegmentQuality]]:
    """:func:`segment_quality` of several fits at once (arrays `(fits, curves, samples)`):
    one list per fit."""
    rows = np.shape(force)[0]
    flat = lambda x: np.reshape(np.asarray(x), (rows, -1))  # noqa: E731
    force, fitted, model, noise, w = (flat(x) for x in (force, fitted_force, model_force,
                                                          noise, weight))
    valid = flat(valid) > 0
    seg = flat(segment)
    w = w.astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = (fitted - force) / noise
    out: list[list[SegmentQuality]] = [[] for _ in range(rows)]
    for j, name in enumerate(SEGMENTS):
        m = valid & (seg == j)
        present = np.any(m, axis=1)
        if not present.any():
            continue
        wm = np.where(m, w, 0.0)
        sw = np.sum(wm, axis=1)
        r2m = np.where(m, r, 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            chi = np.where(sw > 0, np.sum(wm * r2m * r2m, axis=1) / sw, np.nan)
        r2 = r_squared_rows(model, force, w, m)
        r2u = r_squared_rows(model, force, None, m)
        largest = np.max(np.abs(r2m), axis=1)
        kept = np.sum(m, axis=1)
        for i in np.flatnonzero(present):
            c, q = float(chi[i]), float(r2[i])
            described = not (c > INADEQUATE_CHI2 or (q < POOR_R2 and c > 2.0))
            out[i].append(SegmentQuality(
                segment=name, n_kept=int(kept[i]), n_measured=int(round(float(sw[i]))),
                r_squared=q, r_squared_unweighted=float(r2u[i]), reduced_chi2=c,
                max_residual=float(largest[i]), described=described))
    return out


def contact_outside(indentation, force, model_force, noise, valid, segment, contact_radius,
                    delta: float) -> list[str]:
    """Messages for curves whose fitted contact point (model indentation $d + \\delta$, `delta`
    [m]) lies outside the fitted data: before the first approach sample with the model in
    contact there (contact radius > 0) and its force more than 5σ from the data's, or
    beyond the deepest sample."""
    out = []
    d = np.asarray(indentation)
    valid = np.asarray(valid) > 0
    seg = np.asarray(segment)
    for c in range(d.shape[0]):
        idx = np.flatnonzero(valid[c])
        if idx.size == 0:
            continue
        i0 = int(idx[0])
        where = f"curve {c}: " if d.shape[0] > 1 else ""
        sig = float(np.asarray(noise)[c, i0])
        fm, fd = float(np.asarray(model_force)[c, i0]), float(np.asarray(force)[c, i0])
        ahead = float(d[c, i0]) + delta
        if (seg[c, i0] == SEGMENTS.index("approach") and ahead > 0
                and float(np.asarray(contact_radius)[c, i0]) > 0 and abs(fm - fd) > 5 * sig):
            out.append(f"{where}the fitted contact point lies {ahead:.3g} m before the first "
                       f"fitted sample (contact_offset {delta:.3g} m): the model starts in "
                       f"contact at {fm:.3g} N where the data show {fd:.3g} N "
                       f"({abs(fm - fd) / sig:.0f} sigma); the model does not describe the "
                       "start of contact, and the offset is not a measured contact point")
        deepest = float(np.max(d[c, idx])) + delta
        if deepest <= 0:
            out.append(f"{where}the fitted contact point lies beyond the deepest sample "
                       f"(contact_offset {delta:.3g} m, deepest model indentation "
                       f"{deepest:.3g} m): the model never touches the sample")
    return out


def force_after_detachment(ts, force, model_force, noise, weight, valid, segment,
                           contact_radius) -> list[str]:
    r"""Messages for curves whose measured force stays off the model's after the model's
    last jump-off on the retract (arrays `(curves, samples)`; `contact_radius`: the model's
    at the samples [m]).

    The samples counted: the fitted retract samples after the last one where the model is
    in contact (the model's force there is its free force, the force offset when fitted;
    a curve whose model is still in contact at its last retract sample, or never on the
    retract, has none; at least 3 kept samples are needed). With
    $r_i = (F_i - F^\mathrm{model}_i)/\sigma_i$ and $w_i$ the measured samples a kept sample
    stands for, a curve is named when those samples stand for at least
    :data:`AFTER_DETACHMENT_SAMPLES` measured samples and their mean
    $\bar r = \sum w r / \sum w$ exceeds :data:`AFTER_DETACHMENT_SIGMA` in magnitude (a
    systematic offset: the noise alone gives $|\bar r| \approx 1/\sqrt{\sum w}$, which the
    model, free there, cannot describe) and their $\sum w r^2$ is at least
    :data:`AFTER_DETACHMENT_SHARE` of the curve's (an offset that matters to the fit, not
    one lost beside a misfit elsewhere a thousand times larger). On a cell it is mostly
    membrane tethers (a tensile plateau that falls in steps as they break); else a
    detachment slower or later than the model's, or a retract baseline unlike the
    approach's (viscous drag, drift).
    """
    out = []
    ts, f, fm, sig, w = (np.asarray(x, dtype=float) for x in (ts, force, model_force,
                                                             noise, weight))
    valid = np.asarray(valid) > 0
    a = np.nan_to_num(np.asarray(contact_radius, dtype=float))
    retract = valid & (np.asarray(segment) == SEGMENTS.index("retract")) & (w > 0)
    for c in range(f.shape[0]):
        idx = np.flatnonzero(retract[c])
        touching = idx[a[c, idx] > 0]
        if idx.size == 0 or touching.size == 0 or touching[-1] == idx[-1]:
            continue
        after = idx[idx > touching[-1]]
        n = float(np.sum(w[c, after]))
        if after.size < 3 or n < AFTER_DETACHMENT_SAMPLES:
            continue
        off = f[c, after] - fm[c, after]
        r = off / sig[c, after]
        mean_r = float(np.sum(w[c, after] * r) / n)
        if not abs(mean_r) > AFTER_DETACHMENT_SIGMA:
            continue
        with np.errstate(invalid="ignore", divide="ignore"):
            r_all = np.where(valid[c], (f[c] - fm[c]) / sig[c], 0.0)
        share = float(np.sum(w[c, after] * r * r) / np.sum(w[c] * r_all * r_all))
        if not share >= AFTER_DETACHMENT_SHARE:
            continue
        mean_f = float(np.sum(w[c, after] * off) / n)
        where = f"curve {c}: " if f.shape[0] > 1 else ""
        if mean_f < 0:
            side = "below the model's free force (tensile)"
            why = ("the tip is still pulled (membrane tethers, or a slower or later "
                   "detachment than the model's) or the retract's baseline differs from the "
                   "approach's (viscous drag, drift)")
        else:
            side = "above the model's free force (compressive)"
            why = "the retract's baseline differs from the approach's (viscous drag, drift)"
        out.append(
            f"{where}after the model's jump-off (t = {float(ts[c, touching[-1]]):.4g} s) the "
            f"measured force stays on average {abs(mean_f):.3g} N {side} ({mean_r:+.1f} sigma"
            f" over the last {float(ts[c, after[-1]] - ts[c, touching[-1]]):.3g} s of the "
            f"retract, {n:.0f} measured samples, {100 * share:.2g} % of the curve's chi2): "
            f"{why}; the model cannot describe it, and these samples pull on every "
            "parameter. A constant retract offset is removed by retract_baseline="
            "'separate' (command line --retract-baseline separate), a drift in time by a "
            "linear baseline through the approach and the retract's tail (baseline='linear', "
            "retract_baseline=True; --baseline linear --retract-baseline include); tethers "
            "are not in the model")
    return out


def convergence(converged: bool, steps: int, max_steps: int | None, *,
                simpler: Sequence[str] = ()) -> dict:
    """``{"converged", "reason", "advice", "steps", "max_steps"}`` of the best start:
    the reason a search stopped without converging (the step limit, or no progress) and
    what to try (empty advice when converged); `simpler`: the simpler rheologies nested in
    the fitted one (:attr:`fitting._spec.RheologyKind.nested`), offered as advice."""
    steps = int(steps)
    out = {"converged": bool(converged), "steps": steps,
           "max_steps": None if max_steps is None else int(max_steps)}
    if converged:
        out.update(reason="converged", advice=[])
        return out
    if max_steps is not None and steps >= int(max_steps):
        reason = (f"the best start stopped at the step limit (max_steps {max_steps}) while "
                  "chi2 was still decreasing")
        advice = [f"more iterations (max_steps={2 * int(max_steps)}; command line "
                  f"--max-steps {2 * int(max_steps)})"]
    else:
        reason = (f"the best start stopped after {steps} steps without meeting the "
                  "tolerance (no step lowered chi2: a flat or non-smooth valley, or "
                  "non-finite residuals)")
        advice = ["more starts (n_starts; command line --starts)"]
    if simpler:
        advice.append("a simpler rheology, with fewer arms (rheology="
                      + " or ".join(repr(r) for r in reversed(simpler)) + ")")
    advice.append("fix a parameter the data do not determine (fixed={...}; command line "
                  "--fix NAME=VALUE) or narrow its bounds")
    out.update(reason=reason, advice=advice)
    return out


def check_contact_signal(curves, spec) -> None:
    """`ValueError` naming the curve when its data show no contact (see the module
    docstring): the force of the measured approach and hold never stays above 5σ for 5
    samples (any model), or $|F|$ on a retract-only curve."""
    for n, c in enumerate(curves):
        names = c.segment_names
        f = np.asarray(c.force, dtype=float)
        # each segment one block of samples (segment indices never decrease, `Curve`):
        # segment j is f[edges[j]:edges[j + 1]]
        edges = np.searchsorted(c.segment, np.arange(len(names) + 1)).tolist()
        # a measured approach or hold (a loader's inferred one-sample approach at the top of
        # a pure lift is none) shows whether the tip pressed on the sample, whichever model
        # is fitted: a relaxed fit of a curve that never pressed has no contact either
        pressed = sorted(j for j in (names.index(s) for s in ("approach", "hold") if s in names)
                         if edges[j + 1] - edges[j] > 1)
        if pressed:
            blocks = [f[edges[j]:edges[j + 1]] for j in pressed]
            part = blocks[0] if len(blocks) == 1 else np.concatenate(blocks)
            what = "approach and hold"
        else:
            j = names.index("retract") if "retract" in names else None
            part, what = np.abs(f if j is None else f[edges[j]:edges[j + 1]]), "retract (|F|)"
            if spec.model == "history":
                what = "curve (|F|)"
        if part.size == 0:
            continue
        noise = c.contact.noise if c.contact is not None else None
        sigma = noise_level(part if noise is None else f, noise)
        try:
            _detect_index(part, SIGNAL_THRESHOLD * sigma, SIGNAL_RUN)
        except DataError:
            label = f"curve {n} ({c.source or 'no source'})"
            raise ValueError(
                f"{label}: no contact in the data: on the {what} the force never stays "
                f"above {SIGNAL_THRESHOLD:g} sigma = {SIGNAL_THRESHOLD * sigma:.3g} N for "
                f"{SIGNAL_RUN} samples (largest {float(np.max(part)):.3g} N); the tip does "
                "not indent the sample, or the contact lies outside the selected "
                "segments") from None


def assess(result, *, max_steps: int | None = None, evaluated=None,
           quality=None) -> list[str]:
    """Fill the quality fields of a :class:`FitResult` (`r_squared_unweighted`,
    `segments`, `flags`, `convergence`, `stderr_scale`, `derived`) and return the new warning
    messages (also appended to `result.warnings`). `evaluated`: ``(derived, tabor)``, the
    values and gradients of :func:`fitting._uncertainty.derived_fn` and :func:`tabor_fn` at
    ``result.values`` when already computed (a chunk of curves in one call), else `None`;
    `quality`: ``{"r_squared_unweighted", "segments"}`` when already computed (for a chunk
    at once, :func:`r_squared_rows`, :func:`segment_quality_rows`), else `None`."""
    derived_at, tabor_at = (None, None) if evaluated is None else evaluated
    data = result.data
    if quality is None:
        valid = np.asarray(data.valid) > 0
        quality = {"r_squared_unweighted": r_squared(result.model_force, data.force, None,
                                                     valid),
                   "segments": segment_quality(data.force, result.fitted_force,
                                               result.model_force, data.noise, data.weight,
                                               data.valid, data.segment)}
    result.r_squared_unweighted = quality["r_squared_unweighted"]
    result.segments = quality["segments"]
    red = float(result.reduced_chi2)
    result.stderr_scale = math.sqrt(red) if math.isfinite(red) and red > 0 else math.nan
    flags: dict[str, str] = {}
    if math.isfinite(red) and red > INADEQUATE_CHI2:
        flags["model_inadequate"] = (
            f"the model does not describe the data: reduced chi2 = {red:.3g} (> "
            f"{INADEQUATE_CHI2:g}; residuals about {math.sqrt(red):.3g} sigma RMS, "
            "systematic, not noise); the standard errors are scaled by sqrt(reduced chi2) "
            "and say how tightly the misfit holds the parameters, not the measurement "
            "precision")
    bad = [s for s in result.segments if not s.described]
    if bad:
        flags["segment_not_described"] = "; ".join(
            f"the {s.segment} segment is not described by the model: R^2 = "
            f"{s.r_squared:.3g} (unweighted {s.r_squared_unweighted:.3g}), reduced chi2 "
            f"{s.reduced_chi2:.3g}, largest residual {s.max_residual:.3g} sigma" for s in bad)
    if result.spec.contact_offset and "contact_offset" in result.names:
        msgs = contact_outside(data.indentation, data.force, result.model_force, data.noise,
                               data.valid, data.segment,
                               np.asarray(result.model_contact_radius),
                               float(result["contact_offset"]))
        if msgs:
            flags["contact_outside_data"] = "; ".join(msgs)
    # a fit with its own drift has answered the trend (`FitOptions.force_drift`)
    msgs = [] if result.spec.force_drift else baseline_trend(
        result.curves, drift=result.spec.model == "history")
    if msgs:
        flags["baseline_trend"] = "; ".join(msgs)
    msgs = drift_not_baseline(result)
    if msgs:
        flags["drift_not_baseline"] = "; ".join(msgs)
    if result.model_contact_radius is not None:
        msgs = force_after_detachment(data.ts, data.force, result.model_force, data.noise,
                                      data.weight, data.valid, data.segment,
                                      result.model_contact_radius)
        if msgs:
            flags["force_after_detachment"] = "; ".join(msgs)
    # the steps of the start the result is (the polished one where the search ran coarser)
    losses, steps = ((result.start_losses, result.start_steps) if result.polish_losses is None
                     else (result.polish_losses, result.polish_steps))
    best = int(np.argmin(np.where(np.isfinite(losses), losses, np.inf))) \
        if np.size(losses) else 0
    result.convergence = convergence(
        result.converged, int(np.asarray(steps)[best]) if steps is not None else 0,
        max_steps, simpler=rheology_kind(result.spec).nested(result.spec.arms))
    if not result.converged:
        flags["not_converged"] = ("the fit did not converge: " + result.convergence["reason"]
                                  + "; the values are the best point found; try: "
                                  + "; ".join(result.convergence["advice"]))
    result.flags = flags
    result.derived = derived_quantities(result.spec, result.values, result.covariance,
                                        result.status, evaluated=derived_at)
    tabor = tabor_entry(result.spec, result.values, result.covariance, result.status,
                        result.radius, result.names, evaluated=tabor_at)
    if tabor is not None:
        result.derived.append(tabor)
        # only a determined mu: with the work of adhesion not determined (e.g. bounded only
        # from below, no curve detaches) mu is not known to be small
        if tabor["status"] == "ok" and tabor["value"] < TABOR_JKR_MIN:
            flags["outside_jkr_limit"] = (
                f"Tabor's parameter mu = {tabor['value']:.3g} (< {TABOR_JKR_MIN:g}; R = "
                f"{result.radius:.3g} m, z0 = {jc.TABOR_SEPARATION:.3g} m, E* = 4 G_glass): "
                "the contact is outside the JKR limit the model assumes (short-range "
                "adhesion); the criterion overestimates the adhesive neck and the pull-off "
                "(Maugis-Dugdale regime), so the work of adhesion is biased")
    new = list(flags.values())
    result.warnings = list(result.warnings) + new
    return new


def tabor_entry(spec, p, covariance, status, radius, names, *, evaluated=None
                ) -> dict | None:
    r"""Tabor's parameter of a fit as a derived quantity (module docstring, "Validity"):
    a dict like those of :func:`fitting._uncertainty.derived_quantities` (``name``
    "tabor_mu", ``unit`` "1", ``value``, ``stderr``, ``status``, ``definition``), or None for
    a fit without adhesion (work of adhesion fixed at 0).

    $\mu$ uses the glass modulus $E^* = 4G_g$ and `radius` (the fitted sphere's or
    paraboloid's $R$ [m]); with `radius` None (other profiles) the value is NaN and the
    status "not defined". The standard error is the delta method's over the free
    parameters (NaN, status "not determined", when one of them is not determined or at a
    bound). `evaluated`: the value and gradient of :func:`tabor_fn` at `p` and `radius`
    when already computed, else `None`.
    """
    k = list(names).index("work_of_adhesion")
    p = np.asarray(p, dtype=float)
    if not p[k] > 0:
        return None
    definition = ("Tabor's parameter (R dgamma^2 / (E*^2 z0^3))^(1/3), E* = 4 G_glass, z0 = "
                  f"{jc.TABOR_SEPARATION:g} m; JKR limit (the model's) for mu >= "
                  f"{TABOR_JKR_MIN:g}")
    if radius is None or not math.isfinite(float(radius)):
        return {"name": "tabor_mu", "unit": "1", "value": math.nan, "stderr": math.nan,
                "status": "not defined",
                "definition": definition + "; not defined: the profile has no fitted radius "
                "of curvature (sphere or paraboloid only)"}
    value, grad = tabor_fn(spec, k)(np.asarray(p, float), float(radius)) \
        if evaluated is None else evaluated
    value, radius = float(value), float(radius)
    stderr, ok = delta_method(grad, covariance, status)
    se, ok = float(stderr[0]), bool(ok[0])
    return {"name": "tabor_mu", "unit": "1", "value": value, "stderr": se,
            "status": "ok" if ok and math.isfinite(se) else "not determined",
            "definition": definition + f", R = {radius:g} m"}


_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


def warning_kinds(results) -> list[tuple[str, int, str]]:
    """The warnings of many fits grouped by kind (the message with its numbers replaced by
    ``#``): `(kind, number of fits, an example message)`, most frequent first."""
    kinds: dict[str, list] = {}
    for r in results:
        if r is None:
            continue
        for kind in dict.fromkeys(_NUMBER.sub("#", m) for m in r.warnings):
            kinds.setdefault(kind, [0, None])[0] += 1
        for m in r.warnings:
            entry = kinds[_NUMBER.sub("#", m)]
            entry[1] = entry[1] or m
    return sorted(((k, n, ex) for k, (n, ex) in kinds.items()), key=lambda x: -x[1])


def warn_summary(results) -> None:
    """One warning per kind for many fits (:func:`warning_kinds`): the count and an example;
    :class:`IdentifiabilityWarning` for parameters not determined or at a bound, else
    :class:`ModelValidityWarning`."""
    from ._uncertainty import IdentifiabilityWarning, ModelValidityWarning

    total = sum(r is not None for r in results)
    for kind, n, example in warning_kinds(results):
        ident = ("not determined" in kind or "bound (" in kind or "too few samples" in kind)
        warn_at_caller(f"{n} of {total} fitted curves: {example}",
                       IdentifiabilityWarning if ident else ModelValidityWarning)


@functools.lru_cache(maxsize=16)
def tabor_fn(spec, k: int):
    """Tabor's parameter and its gradient w.r.t. the parameter vector, compiled once per
    model (not an eager `jax.jacfwd` traced again for every curve of a map)."""
    import jax

    from jaxcontact._validate import without_guards

    from ._spec import build_rheology

    @without_guards  # the fit's values: no host callback in the finish's program
    def fn(q, radius):
        e_star = 4 * build_rheology(spec, q[:k]).glass_modulus
        return jc.tabor_parameter(radius, q[k], e_star)

    return jax.jit(lambda q, radius: (fn(q, radius), jax.jacfwd(fn)(q, radius)))
