"""Force baseline, tip position and contact point of a raw curve (:func:`preprocess`).

Everything here is numpy (no JAX) and SI: time [s], displacement [m], force [N].

Cantilever curves (AFM)
-----------------------
An AFM records the height of the cantilever base (``height (measured)`` from the closed
loop sensor, or ``height (piezo)``) and the force ``F = k d`` from the deflection ``d``.
Heights *decrease* as the base moves toward the sample (checked on both bundled files).
With the base displacement toward the sample ``u = h[0] − h`` the tip position toward the
sample is ``p = u − F/k`` (the deflection lifts the tip by ``F/k`` while pushing), i.e.
"height − F/k" in a coordinate pointing into the sample. The indentation is
``p − p_c`` with ``p_c`` the tip position at the contact point.

Contact point and baseline (:func:`preprocess`)
-----------------------------------------------
1. Free region: the ``rest`` segment if one precedes the approach (and has at least 10
   samples); otherwise the first ``baseline_fraction`` of the approach, later replaced
   by the approach samples before 90 % of the detected contact index (repeated until the
   contact index settles, at most 5 times).
2. Baseline model, in time ``t`` [s]: ``"constant"`` (mean of the free force) or
   ``"linear"`` (least-squares line ``F_0 + s t`` through the free force: corrects a
   deflection drift, which is a function of time, not of position). The noise
   ``sigma`` is the standard deviation of the free approach (or rest) force about it.
3. With ``"linear"``, the free tail of the retract (its last ``baseline_fraction``, at
   least 10 samples) joins the line when it is free and consistent: its scatter about
   its own line is below ``2 sigma``, no sample lies more than ``threshold * sigma`` off
   that line (no detachment step), the line does not move by more than
   ``threshold * sigma`` over the tail, and the joint line leaves the free approach
   scatter within 1.25 ``sigma`` (a retract offset by viscous drag in liquid, opposite
   to that of the approach, or a drift that is not linear in time, fails this). This
   anchors the drift at both ends of the curve; the detection is then repeated with the
   new baseline. ``retract_baseline=True`` always joins the tail (also for
   ``"constant"``), ``False`` never, ``"separate"`` gives the retract its own offset.
4. Detection: the first approach sample from which the baselined force stays above
   ``threshold * sigma`` for ``min_run`` samples; from there back to the last sample
   with force ``<= 0``. If the force dips below ``-2 * threshold * sigma`` just before
   that (a jump to contact), the contact is the last sample before the dip (the first
   sample below half the dip depth is the first in contact). If the force is positive
   from the very first approach sample, the contact is the first approach sample.
5. ``contact_point="fit"`` refines it by least squares of the Hertz-like power law
   ``F = a (p − p_c)_+^n`` (``n = contact_exponent``, 3/2 for a sphere) over the approach
   samples up to where the force first reaches ``fit_fraction`` of its approach maximum;
   ``a`` is profiled out and ``p_c`` found by a grid plus golden-section search within
   the tip positions of that window (no extrapolation before the first approach sample).

All steps are deterministic (no random starts), so the same curve and options give the
same :class:`ContactPoint`; a fit may start its contact offset from it.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from jaxcontact._solvers import golden_section_host

from ._curve import ContactPoint, Curve, DataError

__all__ = ["preprocess"]


def _baseline_fit(t, f, kind):
    """``(offset, slope, noise)`` of ``f ≈ offset + slope t`` (slope 0 for "constant")."""
    if kind == "linear" and len(t) >= 3 and np.ptp(t) > 0:
        slope, offset = np.polyfit(t, f, 1)
    else:
        slope, offset = 0.0, float(np.mean(f))
    resid = f - (offset + slope * t)
    return float(offset), float(slope), float(np.std(resid))


def _detect_index(fb, thr, min_run):
    """Contact index on the baselined approach force ``fb`` (see module docstring)."""
    above = (fb > thr).astype(np.int64)
    m = min(min_run, len(fb))
    runs = np.convolve(above, np.ones(m, dtype=np.int64), mode="valid")
    hits = np.flatnonzero(runs == m)
    if hits.size == 0:
        raise DataError(
            f"no contact found on the approach: the baselined force never stays above "
            f"{thr:.3g} N (threshold × noise) for {m} samples; is the approach segment "
            "right, or is the threshold too high?"
        )
    j = int(hits[0])
    below = np.flatnonzero(fb[: j + 1] <= 0)
    if below.size == 0:
        return 0
    i = int(below[-1])
    nonneg = np.flatnonzero(fb[:i] >= 0)
    s = int(nonneg[-1]) + 1 if nonneg.size else 0  # start of the negative run ending at i
    k_min = s + int(np.argmin(fb[s : i + 1]))
    depth = -float(fb[k_min])
    if depth > 2.0 * thr:
        q = k_min
        while q > s and fb[q - 1] < -0.5 * depth:
            q -= 1
        return max(q - 1, 0)
    return i


def _fit_power_law_contact(p, fb, n_exp, lo, hi):
    """Least-squares ``p_c`` of ``fb ≈ a (p − p_c)_+^n``, ``a`` profiled out."""

    def sse(pc):
        g = np.clip(p - pc, 0.0, None) ** n_exp
        gg = float(g @ g)
        a = max(float(g @ fb) / gg, 0.0) if gg > 0 else 0.0
        r = fb - a * g
        return float(r @ r)

    grid = np.linspace(lo, hi, 401)
    vals = np.array([sse(x) for x in grid])
    b = int(np.argmin(vals))
    lo_, hi_ = golden_section_host(sse, grid[max(b - 1, 0)], grid[min(b + 1, len(grid) - 1)],
                                   steps=60)
    return 0.5 * (lo_ + hi_)


def preprocess(
    curve: Curve,
    *,
    spring_constant: float | None = None,
    baseline: str | None = "constant",
    contact_point: str | None = "detect",
    threshold: float = 5.0,
    min_run: int = 5,
    baseline_fraction: float = 0.2,
    fit_fraction: float = 0.5,
    contact_exponent: float = 1.5,
    retract_baseline: bool | None = None,
) -> Curve:
    """Force baseline, tip position and contact point of a raw curve.

    ``curve.displacement`` is read as the base (piezo) displacement toward the sample
    and ``curve.force`` as the raw force. Returns a curve whose displacement is the
    indentation ``p − p_c`` with tip position ``p = u − F/k`` (``p = u`` without a spring
    constant) and whose force has the baseline removed; ``contact`` records what was done.
    The algorithm is in the module docstring.

    **Arguments:**

    - `curve`: the raw curve (must have an ``approach`` segment for a baseline or a
      contact point).
    - `spring_constant`: cantilever k [N/m]; default ``curve.spring_constant``; ``None``
      for both means no tip correction.
    - `baseline`: ``"constant"`` (mean of the free force), ``"linear"`` (a straight line
      in time through the free parts: corrects drift) or ``"none"``/``None`` (no
      subtraction; the free force is still estimated for the detection).
    - `contact_point`: ``"detect"`` (threshold), ``"fit"`` (power-law onset) or
      ``"none"``/``None`` (no zeroing: the displacement is then the tip position
      relative to the first sample's base position; for data that are already
      indentation with 0 at contact, pass ``baseline="none"`` too).
    - `threshold`: detection threshold in units of the baseline noise.
    - `min_run`: samples the force must stay above the threshold.
    - `baseline_fraction`: initial fraction of the approach used as baseline when there
      is no rest segment; also the fraction of the retract tested as its free tail.
    - `fit_fraction`: the power-law fit uses the approach up to this fraction of its
      maximum force.
    - `contact_exponent`: exponent of the power law (1.5: Hertz sphere).
    - `retract_baseline`: use the tail of the retract in the baseline: ``None``
      (default) for ``"linear"`` when it is free and consistent (see the module
      docstring), ``True`` always, ``False`` never; ``"separate"``: keep the approach
      baseline and give the retract (from its first sample on) its own constant offset,
      the mean of its tail about the approach baseline (for a retract offset by viscous
      drag or by a step at the turnaround; assumes the retract ends free).

    **Returns:**

    The preprocessed :class:`Curve`, with ``contact`` set (:class:`ContactPoint`).

    **Raises:**

    - `ValueError`: already preprocessed, unknown option (naming it and the allowed
      values), or no approach segment.
    - `DataError`: no contact found on the approach.
    """
    if curve.contact is not None:
        raise ValueError("curve was already preprocessed (curve.contact is set)")
    if baseline == "none":
        baseline = None
    if contact_point == "none":
        contact_point = None
    if baseline not in (None, "constant", "linear"):
        raise ValueError(
            f"baseline must be 'constant', 'linear' or 'none', got {baseline!r}"
        )
    if contact_point not in (None, "detect", "fit"):
        raise ValueError(
            f"contact_point must be 'detect', 'fit' or 'none', got {contact_point!r}"
        )
    if not threshold > 0:
        raise ValueError(f"threshold must be > 0, got {threshold}")
    if not 0 < fit_fraction <= 1:
        raise ValueError(f"fit_fraction must lie in (0, 1], got {fit_fraction}")
    if not 0 < baseline_fraction < 1:
        raise ValueError(f"baseline_fraction must lie in (0, 1), got {baseline_fraction}")
    if retract_baseline not in (None, True, False, "separate"):
        raise ValueError(
            "retract_baseline must be None, True, False or 'separate', got "
            f"{retract_baseline!r}"
        )
    k = spring_constant if spring_constant is not None else curve.spring_constant
    if k is not None and not (math.isfinite(k) and k > 0):
        raise ValueError(f"spring_constant must be finite and > 0 [N/m], got {k}")
    t, u, f = curve.time, curve.displacement, curve.force
    offset = slope = noise = retract_offset = 0.0
    retract_time = math.inf
    region = "none"
    c = None
    method = contact_point or "none"
    kind = baseline or "constant"

    if contact_point is not None or baseline is not None:
        if "approach" not in curve.segment_names:
            raise ValueError(
                f"curve has no 'approach' segment (segments {curve.segment_names}); the "
                "baseline and contact point are found on the approach"
            )
        j_app = curve.segment_names.index("approach")
        app = np.flatnonzero(curve.segment == j_app)
        ta, fa = t[app], f[app]
        rest_js = [j for j, nm in enumerate(curve.segment_names[:j_app]) if nm == "rest"]
        rest = np.flatnonzero(curve.segment == rest_js[-1]) if rest_js else np.array([], int)
        if rest.size >= 10:
            region = "rest"
            free = rest
        else:
            region = "approach"
            free = app[: min(len(app), max(10, int(baseline_fraction * len(app))))]
        offset, slope, noise = _baseline_fit(t[free], f[free], kind)
        scale = float(np.max(np.abs(fa - offset - slope * ta))) or 1.0
        sig = max(noise, 1e-12 * scale)
        if contact_point is not None:
            c = _detect_index(fa - offset - slope * ta, threshold * sig, min_run)
            if region == "approach":
                for _ in range(5):
                    n0 = int(0.9 * c)
                    if n0 < 10:
                        break
                    free = app[:n0]
                    offset, slope, noise = _baseline_fit(t[free], f[free], kind)
                    sig = max(noise, 1e-12 * scale)
                    c_new = _detect_index(fa - offset - slope * ta, threshold * sig, min_run)
                    if c_new == c:
                        break
                    c = c_new
        tail = None
        if retract_baseline == "separate":
            tail = _retract_tail(curve, baseline_fraction)
            if tail is None:
                raise ValueError(
                    "retract_baseline='separate' but the curve has no retract of at least "
                    "20 samples"
                )
            r0 = int(np.flatnonzero(curve.segment == curve.segment[tail[0]])[0])
            retract_offset = float(np.mean(f[tail] - offset - slope * t[tail]))
            retract_time = float(t[r0])
            tail = None
        elif retract_baseline is True:
            tail = _retract_tail(curve, baseline_fraction)
            if tail is None:
                raise ValueError(
                    "retract_baseline=True but the curve has no retract of at least 20 "
                    "samples"
                )
        elif retract_baseline is None and kind == "linear":
            tail = _free_retract_tail(curve, f, baseline_fraction, sig, threshold)
        if tail is not None:
            both = np.concatenate([free, tail])
            off2, sl2, _ = _baseline_fit(t[both], f[both], kind)
            noise2 = float(np.std(f[free] - off2 - sl2 * t[free]))
            if retract_baseline is True or noise2 <= 1.25 * noise:
                offset, slope, noise = off2, sl2, noise2
                sig = max(noise, 1e-12 * scale)
                region += "+retract"
                if contact_point is not None:
                    c = _detect_index(fa - offset - slope * ta, threshold * sig, min_run)

    fdet = f - offset - slope * t - np.where(t >= retract_time, retract_offset, 0.0)
    fb = f.copy() if baseline is None else fdet
    p = u - fdet / k if k is not None else u.copy()  # deflection from the free baseline
    if contact_point is None:
        p_c = float(u[0])
        ci = 0
    else:
        app_p = p[app]
        fba = fdet[app]
        if contact_point == "detect":
            idx = c
            p_c = float(app_p[c])
        else:
            fmax = float(np.max(fba))
            reach = np.flatnonzero(fba >= fit_fraction * fmax)
            w = int(reach[0]) if reach.size else len(fba) - 1
            w = max(w, min(c + 3, len(fba) - 1))
            pw, fw = app_p[: w + 1], fba[: w + 1]
            lo, hi = float(np.min(pw)), float(pw[-1])
            p_c = float(_fit_power_law_contact(pw, fw, contact_exponent, lo, hi))
            idx = int(np.searchsorted(np.maximum.accumulate(app_p), p_c))
            idx = min(idx, len(app_p) - 1)
        ci = int(app[idx])
    cp = ContactPoint(
        index=ci, time=float(t[ci]), tip_position=p_c, height=float(u[ci]),
        force_offset=offset if baseline is not None else 0.0,
        force_slope=slope if baseline is not None else 0.0,
        noise=noise, method=method, baseline=baseline or "none", baseline_region=region,
        retract_offset=retract_offset if baseline is not None else 0.0,
        retract_time=retract_time,
    )
    return dataclasses.replace(
        curve, displacement=p - p_c, force=fb, spring_constant=k, contact=cp,
    )


def _retract_tail(curve: Curve, fraction: float):
    """Indices of the last ``fraction`` (at least 10 samples) of the last retract."""
    js = [j for j, nm in enumerate(curve.segment_names) if nm == "retract"]
    if not js:
        return None
    ret = np.flatnonzero(curve.segment == js[-1])
    n = max(10, int(fraction * len(ret)))
    return ret[-n:] if len(ret) >= 2 * n else None


def _free_retract_tail(curve: Curve, f, fraction: float, sig: float, threshold: float):
    """The retract tail if it is free: flat within the noise, no step, no slope."""
    tail = _retract_tail(curve, fraction)
    if tail is None:
        return None
    tt, ft = curve.time[tail], f[tail]
    off, sl, s = _baseline_fit(tt, ft, "linear")
    resid = ft - off - sl * tt
    if s > 2.0 * sig or np.max(np.abs(resid)) > threshold * sig:
        return None  # noisier than the free approach, or a step (a tether letting go)
    if abs(sl) * np.ptp(tt) > threshold * sig:
        return None  # still moving (e.g. relaxing adhesion or a tether stretching)
    return tail
