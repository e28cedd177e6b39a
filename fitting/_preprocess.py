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
The steps are registered by name (:data:`STEPS`, :func:`preprocessing_steps`); the
pipeline is the sequence of their names, :data:`PIPELINE`, each step reading and writing
one :class:`Preprocessing`:

1. ``free_region``: the ``rest`` segment if one precedes the approach (and has at least
   10 samples); otherwise the first ``baseline_fraction`` of the approach, later
   replaced by the approach samples before 90 % of the detected contact index (step 3).
2. ``baseline``: the baseline model, in time ``t`` [s]: ``"constant"`` (mean of the free
   force) or ``"linear"`` (least-squares line ``F_0 + s t`` through the free force:
   corrects a deflection drift, which is a function of time, not of position). The
   noise ``sigma`` is the standard deviation of the free approach (or rest) force about
   it.
3. ``contact_index``, the detection: the first approach sample from which the baselined
   force stays above ``threshold * sigma`` for ``min_run`` samples; from there back to
   the last sample with force ``<= 0``. If the force dips below ``-2 * threshold *
   sigma`` just before that (a jump to contact), the contact is the last sample before
   the dip (the first sample below half the dip depth is the first in contact). If the
   force is positive from the very first approach sample, the contact is the first
   approach sample. With the free region on the approach, the baseline is refitted
   before 90 % of the index and the detection repeated until the index settles (at
   most 5 times).
4. ``retract_baseline``: with ``"linear"``, the free tail of the retract (its last
   ``baseline_fraction``, at least 10 samples) joins the line when it is free and
   consistent: its scatter about its own line is below ``2 sigma``, no sample lies more
   than ``threshold * sigma`` off that line (no detachment step), the line does not
   move by more than ``threshold * sigma`` over the tail, and the joint line leaves the
   free approach scatter within 1.25 ``sigma`` (a retract offset by viscous drag in
   liquid, opposite to that of the approach, or a drift that is not linear in time,
   fails this). This anchors the drift at both ends of the curve; the detection is then
   repeated with the new baseline. ``retract_baseline=True`` always joins the tail (also
   for ``"constant"``), ``False`` never, ``"separate"`` gives the retract its own offset.
5. ``baseline_trend``: the straight line in time through the final free force, whatever
   the baseline: its rise from the free samples' mean time to the end of the approach
   (``ContactPoint.trend``: what a ``"constant"`` baseline leaves in the data at the
   deepest point), that rise's standard error (``trend_error``) and the scatter about the
   line (``trend_noise``). Measured to the end of the approach, not over the free force
   alone: a rising trend read as a constant moves the detected contact early, which
   shortens the free force, so that its own rise stays near the threshold whatever the
   tilt. Under a ``"constant"`` baseline a large, significant rise is a tilt of the
   approach (virtual deflection) or a drift; a fit flags it (:mod:`fitting._quality`,
   ``baseline_trend``).
6. ``tip_position``: the baselined force and the tip position (see above).
7. ``contact_point``: the tip position at the detected index, or with
   ``contact_point="fit"`` refined by least squares of the Hertz-like power law
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
from collections.abc import Callable

import numpy as np

from jaxcontact._solvers import golden_section_host

from ._curve import ContactPoint, Curve, DataError

__all__ = ["preprocess", "preprocessing_steps", "PIPELINE", "STEPS", "Step",
           "Preprocessing"]


def _baseline_fit(t, f, kind):
    """``(offset, slope, noise)`` of ``f ≈ offset + slope t`` (slope 0 for "constant"): the
    least-squares line, in closed form about the mean time; `noise` the standard deviation
    of the residuals."""
    tm, fm = float(np.mean(t)), float(np.mean(f))
    dt = t - tm
    ss = float(dt @ dt)
    slope = float(dt @ f) / ss if kind == "linear" and len(t) >= 3 and ss > 0 else 0.0
    return fm - slope * tm, slope, float(np.std(f - fm - slope * dt))


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
    The algorithm is in the module docstring: the steps of :data:`PIPELINE`, in turn.

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
    st = Preprocessing(
        curve=curve, baseline=baseline, contact_point=contact_point, threshold=threshold,
        min_run=min_run, baseline_fraction=baseline_fraction, fit_fraction=fit_fraction,
        contact_exponent=contact_exponent, retract_baseline=retract_baseline,
        spring_constant=k,
    )
    for name in PIPELINE:
        STEPS[name].function(st)
    t, u = curve.time, curve.displacement
    cp = ContactPoint(
        index=st.contact_index, time=float(t[st.contact_index]), tip_position=st.p_c,
        height=float(u[st.contact_index]),
        force_offset=st.offset if baseline is not None else 0.0,
        force_slope=st.slope if baseline is not None else 0.0,
        noise=st.noise, method=contact_point or "none", baseline=baseline or "none",
        baseline_region=st.region,
        retract_offset=st.retract_offset if baseline is not None else 0.0,
        retract_time=st.retract_time, trend=st.trend, trend_error=st.trend_error,
        trend_noise=st.trend_noise, trend_slope=st.trend_slope,
        trend_slope_error=st.trend_slope_error,
    )
    return dataclasses.replace(
        curve, displacement=st.tip - st.p_c, force=st.force, spring_constant=k, contact=cp,
    )


@dataclasses.dataclass
class Preprocessing:
    """What the steps of :func:`preprocess` read and write (SI; one curve): the options
    (checked), then each step's results, in the order of :data:`PIPELINE`.

    **Fields:** `curve` (raw) and the options of :func:`preprocess` (`spring_constant`:
    the one used, or `None`); `approach` (sample indices of the approach; `None` when
    neither a baseline nor a contact point is asked for: the steps up to
    ``retract_baseline`` do nothing); `free` (sample indices of the free force),
    `region` (``"rest"``, ``"approach"``, ``"none"``, with ``"+retract"`` when the
    retract's tail joined); `offset` [N], `slope` [N/s], `noise` [N] of the baseline,
    `scale` [N] (largest baselined approach force), `sig` [N] (the noise, at least
    1e-12 of the scale); `index` (contact index on the approach); `trend`, `trend_error`,
    `trend_noise` [N] (the free force's straight line: its rise to the end of the approach,
    that rise's standard error, the scatter about the line), `trend_slope`,
    `trend_slope_error` [N/s] (its slope and that slope's error); `retract_offset` [N]
    from `retract_time` [s] on; `baselined` [N] (force less the baseline, for the tip
    position and the detection), `force` [N] (the output force), `tip` [m] (tip position
    toward the sample); `p_c` [m] and `contact_index` (sample index) of the contact.
    """

    curve: Curve
    baseline: str | None
    contact_point: str | None
    threshold: float
    min_run: int
    baseline_fraction: float
    fit_fraction: float
    contact_exponent: float
    retract_baseline: bool | str | None
    spring_constant: float | None
    approach: np.ndarray | None = None
    free: np.ndarray | None = None
    region: str = "none"
    offset: float = 0.0
    slope: float = 0.0
    noise: float = 0.0
    scale: float = 1.0
    sig: float = 0.0
    index: int | None = None
    retract_offset: float = 0.0
    retract_time: float = math.inf
    trend: float = 0.0
    trend_noise: float = math.nan
    trend_error: float = math.nan
    trend_slope: float = math.nan
    trend_slope_error: float = math.nan
    baselined: np.ndarray | None = None
    force: np.ndarray | None = None
    tip: np.ndarray | None = None
    p_c: float = 0.0
    contact_index: int = 0

    def baselined_approach(self) -> np.ndarray:
        """The approach force less the current baseline [N]."""
        t, f = self.curve.time[self.approach], self.curve.force[self.approach]
        return f - self.offset - self.slope * t

    def fit_baseline(self, samples) -> tuple[float, float, float]:
        """``(offset, slope, noise)`` of the baseline through the force of `samples`."""
        return _baseline_fit(self.curve.time[samples], self.curve.force[samples],
                             self.baseline or "constant")

    def detect(self) -> int:
        """The contact index on the approach for the current baseline."""
        return _detect_index(self.baselined_approach(), self.threshold * self.sig,
                             self.min_run)


@dataclasses.dataclass(frozen=True)
class Step:
    """A registered preprocessing step: its `name`, the `function` that does it (reads and
    writes a :class:`Preprocessing`) and its `description` (the docstring's first line)."""

    name: str
    function: Callable[[Preprocessing], None]
    description: str


#: The preprocessing steps by name (:func:`step` registers one).
STEPS: dict[str, Step] = {}


def step(name: str):
    """Register the decorated function as the preprocessing step `name`."""

    def register(fn):
        if name in STEPS:
            raise ValueError(f"preprocessing step {name!r} is registered twice")
        STEPS[name] = Step(name, fn, (fn.__doc__ or "").strip().splitlines()[0])
        return fn

    return register


@step("free_region")
def _free_region(st: Preprocessing) -> None:
    """The free force: the rest segment before the approach (at least 10 samples), else
    the first `baseline_fraction` of the approach."""
    curve = st.curve
    if st.contact_point is None and st.baseline is None:
        return
    if "approach" not in curve.segment_names:
        raise ValueError(
            f"curve has no 'approach' segment (segments {curve.segment_names}); the "
            "baseline and contact point are found on the approach"
        )
    j_app = curve.segment_names.index("approach")
    st.approach = app = np.flatnonzero(curve.segment == j_app)
    rest_js = [j for j, nm in enumerate(curve.segment_names[:j_app]) if nm == "rest"]
    rest = np.flatnonzero(curve.segment == rest_js[-1]) if rest_js else np.array([], int)
    if rest.size >= 10:
        st.region, st.free = "rest", rest
    else:
        st.region = "approach"
        st.free = app[: min(len(app), max(10, int(st.baseline_fraction * len(app))))]


@step("baseline")
def _baseline(st: Preprocessing) -> None:
    """The baseline (constant, or a line in time) through the free force, and its noise."""
    if st.approach is None:
        return
    st.offset, st.slope, st.noise = st.fit_baseline(st.free)
    st.scale = float(np.max(np.abs(st.baselined_approach()))) or 1.0
    st.sig = max(st.noise, 1e-12 * st.scale)


@step("contact_index")
def _contact_index(st: Preprocessing) -> None:
    """The contact index by the threshold; with the free force on the approach, the
    baseline refitted before 90 % of it until the index settles (at most 5 times)."""
    if st.approach is None or st.contact_point is None:
        return
    st.index = st.detect()
    if st.region != "approach":
        return
    for _ in range(5):
        n0 = int(0.9 * st.index)
        if n0 < 10:
            break
        st.free = st.approach[:n0]
        st.offset, st.slope, st.noise = st.fit_baseline(st.free)
        st.sig = max(st.noise, 1e-12 * st.scale)
        c_new = st.detect()
        if c_new == st.index:
            break
        st.index = c_new


@step("retract_baseline")
def _retract_baseline(st: Preprocessing) -> None:
    """The retract's free tail: its own offset (``"separate"``), or joined to the baseline
    (always, or for a linear baseline when free and consistent), then the contact index
    again."""
    if st.approach is None:
        return
    curve, f, t = st.curve, st.curve.force, st.curve.time
    tail = None
    if st.retract_baseline == "separate":
        tail = _retract_tail(curve, st.baseline_fraction)
        if tail is None:
            raise ValueError(
                "retract_baseline='separate' but the curve has no retract of at least "
                "20 samples"
            )
        r0 = int(np.flatnonzero(curve.segment == curve.segment[tail[0]])[0])
        st.retract_offset = float(np.mean(f[tail] - st.offset - st.slope * t[tail]))
        st.retract_time = float(t[r0])
        return
    if st.retract_baseline is True:
        tail = _retract_tail(curve, st.baseline_fraction)
        if tail is None:
            raise ValueError(
                "retract_baseline=True but the curve has no retract of at least 20 "
                "samples"
            )
    elif st.retract_baseline is None and (st.baseline or "constant") == "linear":
        tail = _free_retract_tail(curve, f, st.baseline_fraction, st.sig, st.threshold)
    if tail is None:
        return
    free = st.free
    both = np.concatenate([free, tail])
    off2, sl2, _ = st.fit_baseline(both)
    noise2 = float(np.std(f[free] - off2 - sl2 * t[free]))
    if st.retract_baseline is True or noise2 <= 1.25 * st.noise:
        st.offset, st.slope, st.noise = off2, sl2, noise2
        st.sig = max(st.noise, 1e-12 * st.scale)
        st.region += "+retract"
        if st.contact_point is not None:
            st.index = st.detect()


@step("baseline_trend")
def _baseline_trend(st: Preprocessing) -> None:
    """The straight-line trend of the free force in time, whatever the baseline: its rise
    from the free samples' mean time to the end of the approach, its standard error and
    the scatter about the line (what a constant baseline leaves in the data)."""
    if st.free is None or st.free.size < 3:
        return
    t = st.curve.time[st.free]
    _, slope, scatter = _baseline_fit(t, st.curve.force[st.free], "linear")
    st.trend_noise = max(scatter, 1e-12 * st.scale)
    tm = float(np.mean(t))
    reach = float(st.curve.time[st.approach[-1]]) - tm
    st.trend = slope * reach
    st.trend_slope = slope
    st.trend_slope_error = st.trend_noise / math.sqrt(float(np.sum((t - tm) ** 2)))
    st.trend_error = st.trend_slope_error * reach


@step("tip_position")
def _tip_position(st: Preprocessing) -> None:
    """The baselined force and the tip position ``p = u - F/k`` (``u`` without a spring
    constant)."""
    t, u, f = st.curve.time, st.curve.displacement, st.curve.force
    st.baselined = (f - st.offset - st.slope * t
                    - np.where(t >= st.retract_time, st.retract_offset, 0.0))
    st.force = f.copy() if st.baseline is None else st.baselined
    k = st.spring_constant
    st.tip = u - st.baselined / k if k is not None else u.copy()


@step("contact_point")
def _contact_point(st: Preprocessing) -> None:
    """The contact's tip position: at the contact index (``"detect"``), by the power-law
    fit of the onset (``"fit"``), or the first sample's base position (``"none"``)."""
    if st.contact_point is None:
        st.p_c, st.contact_index = float(st.curve.displacement[0]), 0
        return
    app_p = st.tip[st.approach]
    if st.contact_point == "detect":
        idx = st.index
        st.p_c = float(app_p[idx])
    else:
        fba = st.baselined[st.approach]
        fmax = float(np.max(fba))
        reach = np.flatnonzero(fba >= st.fit_fraction * fmax)
        w = int(reach[0]) if reach.size else len(fba) - 1
        w = max(w, min(st.index + 3, len(fba) - 1))
        pw, fw = app_p[: w + 1], fba[: w + 1]
        lo, hi = float(np.min(pw)), float(pw[-1])
        st.p_c = float(_fit_power_law_contact(pw, fw, st.contact_exponent, lo, hi))
        idx = int(np.searchsorted(np.maximum.accumulate(app_p), st.p_c))
        idx = min(idx, len(app_p) - 1)
    st.contact_index = int(st.approach[idx])


#: The pipeline of :func:`preprocess`: the registered steps (:data:`STEPS`) in this order.
PIPELINE = ("free_region", "baseline", "contact_index", "retract_baseline", "baseline_trend",
            "tip_position", "contact_point")


def preprocessing_steps() -> dict[str, str]:
    """The steps of :func:`preprocess` in the order they run: ``{name: description}``."""
    return {name: STEPS[name].description for name in PIPELINE}


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
