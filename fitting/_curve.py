"""The measured curve: :class:`Curve`, :class:`ContactPoint`, plausibility limits and
segment operations.

Everything here is numpy (no JAX) and SI inside: time [s], displacement [m], force [N].

Conventions of a :class:`Curve`
-------------------------------
* ``displacement`` is the indentation depth, positive into the sample and 0 at the
  contact point (once a contact point has been found; see :func:`preprocess`).
* ``force`` is positive when compressive (pushing into the sample) and negative when
  adhesive, with the free (non-contact) force baseline subtracted.
* ``segment`` holds, per sample, an index into ``segment_names``; each name is one of
  :data:`SEGMENT_KINDS` = ``("rest", "approach", "hold", "retract")``. Segment indices
  never decrease along the curve and every listed segment has at least one sample, so a
  segment is one contiguous block. Examples: a JPK stress-relaxation file gives
  ``("rest", "approach", "hold", "retract")``; a force–distance curve gives
  ``("approach", "retract")``.

Plausibility limits
-------------------
:class:`Limits` (default :data:`DEFAULT_LIMITS`: |displacement| <= 1 mm, |force| <= 1 N,
duration <= 1e6 s, and non-zero spans >= 1 pm and >= 1 fN) catch unit mistakes such as
nanometres declared as metres. Pass ``limits=Limits(...)`` to a loader or to
:class:`Curve` to change them, or ``limits=None`` to switch the check off.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from jaxcontact._validate import plain

__all__ = ["DataError", "SEGMENT_KINDS", "Limits", "DEFAULT_LIMITS", "ContactPoint", "Curve",
           "infer_segments", "select_segments", "resample"]

class DataError(ValueError):
    """A data file that cannot be read or holds unusable data.

    Raised by the loaders for unsupported, empty, truncated or corrupt files and for
    malformed tables; the message names the file and the reason. A subclass of
    `ValueError`, so ``except ValueError`` also catches it.
    """


SEGMENT_KINDS: tuple[str, ...] = ("rest", "approach", "hold", "retract")
"""Allowed segment names: ``rest`` (no motion, out of contact), ``approach`` (loading),
``hold`` (dwell at constant height or force), ``retract`` (unloading)."""

DEFAULT_SEGMENT_NAMES: dict[int, tuple[str, ...]] = {
    1: ("approach",),
    2: ("approach", "retract"),
    3: ("approach", "hold", "retract"),
    4: ("rest", "approach", "hold", "retract"),
}

SEGMENT_ALIASES: dict[str, str] = {
    "rest": "rest", "pre": "rest", "preapproach": "rest", "baseline": "rest",
    "approach": "approach", "extend": "approach", "load": "approach",
    "loading": "approach", "trace": "approach",
    "hold": "hold", "dwell": "hold", "pause": "hold", "intermediate": "hold",
    "relaxation": "hold", "creep": "hold",
    "retract": "retract", "unload": "retract", "unloading": "retract",
    "withdraw": "retract", "retrace": "retract",
}


# --- plausibility limits -----------------------------------------------------------------


@dataclass(frozen=True)
class Limits:
    """Plausibility limits checked by :class:`Curve` (all SI).

    Attributes:
        max_displacement: largest allowed |displacement| [m] (default 1e-3: 1 mm).
        max_force: largest allowed |force| [N] (default 1.0).
        max_duration: largest allowed time span [s] (default 1e6).
        min_displacement_span: smallest allowed non-zero peak-to-peak displacement [m]
            (default 1e-12); smaller suggests metres declared as nanometres.
        min_force_span: smallest allowed non-zero peak-to-peak force [N] (default 1e-15).
    """

    max_displacement: float = 1e-3
    max_force: float = 1.0
    max_duration: float = 1e6
    min_displacement_span: float = 1e-12
    min_force_span: float = 1e-15


DEFAULT_LIMITS = Limits()


def _check_limits(time, displacement, force, limits: Limits) -> None:
    how = (
        "pass units={{'{col}': '<unit>'}} to the loader (or fix the unit in the column "
        "name), or relax the check with limits=Limits({par}=...) (limits=None switches it "
        "off)"
    )
    dmax = float(np.max(np.abs(displacement)))
    if dmax > limits.max_displacement:
        raise ValueError(
            f"displacement reaches {dmax:.3g} m, above the plausibility limit "
            f"{limits.max_displacement:g} m; did you give nm or µm as m? "
            + how.format(col="displacement", par="max_displacement")
        )
    fmax = float(np.max(np.abs(force)))
    if fmax > limits.max_force:
        raise ValueError(
            f"force reaches {fmax:.3g} N, above the plausibility limit {limits.max_force:g} N; "
            "did you give nN or µN as N? " + how.format(col="force", par="max_force")
        )
    duration = float(time[-1] - time[0])
    if duration > limits.max_duration:
        raise ValueError(
            f"time spans {duration:.3g} s, above the plausibility limit "
            f"{limits.max_duration:g} s; did you give ms as s? "
            + how.format(col="time", par="max_duration")
        )
    dspan = float(np.ptp(displacement))
    if 0.0 < dspan < limits.min_displacement_span:
        raise ValueError(
            f"displacement spans only {dspan:.3g} m, below the plausibility limit "
            f"{limits.min_displacement_span:g} m; did you give m as nm? "
            + how.format(col="displacement", par="min_displacement_span")
        )
    fspan = float(np.ptp(force))
    if 0.0 < fspan < limits.min_force_span:
        raise ValueError(
            f"force spans only {fspan:.3g} N, below the plausibility limit "
            f"{limits.min_force_span:g} N; did you give N as nN? "
            + how.format(col="force", par="min_force_span")
        )


# --- the curve ---------------------------------------------------------------------------


@dataclass(frozen=True)
class ContactPoint:
    """Where and how the baseline and contact point were found (see :func:`preprocess`).

    Enough to redraw the preprocessing on the raw curve: the baseline is
    ``force_offset + force_slope * t``, plus ``retract_offset`` from ``retract_time`` on
    (:meth:`baseline_force`); the contact is at ``(time, height)`` of the raw curve.

    **Attributes:**

    - `index`: sample index of the contact in the curve as preprocessed (before any
      :func:`select_segments` or :func:`resample`); 0 when ``method`` is ``"none"``.
    - `time`: time of that sample [s].
    - `tip_position`: tip position toward the sample at contact [m], relative to the base
      position of the first sample; subtracted from the tip position to give the
      indentation.
    - `height`: base (piezo) displacement toward the sample at contact [m], relative to
      the first sample (the raw curve's ``displacement`` at ``index``).
    - `force_offset`: baseline force at ``t = 0`` [N] (0 for ``baseline="none"``).
    - `force_slope`: baseline slope in time [N/s] (0 unless ``baseline="linear"``).
    - `noise`: standard deviation of the free force about the baseline [N] (the rest
      segment or the free part of the approach).
    - `method`: ``"detect"``, ``"fit"`` or ``"none"`` (no contact point sought: the
      displacement is the tip position relative to the first sample's base position).
    - `baseline`: ``"constant"``, ``"linear"`` or ``"none"`` (the force was left as given).
    - `baseline_region`: the free samples the baseline was fitted to: ``"rest"`` or
      ``"approach"``, with ``"+retract"`` when the free tail of the retract was used too;
      ``"none"`` when no baseline was estimated.
    - `retract_offset`: extra baseline force [N] from ``retract_time`` on (only with
      ``retract_baseline="separate"``; else 0).
    - `retract_time`: time [s] of the first retract sample when ``retract_offset``
      applies, else ``inf``.
    - `trend`: the rise [N] of a straight line in time through the free force, from the
      free samples' mean time to the end of the approach (signed; measured whatever the
      baseline: a tilt of the approach or a drift, which a ``"constant"`` baseline leaves
      in the data), `trend_error` [N] its standard error and `trend_noise` [N] the free
      force's scatter about the line (both nan when no free force was found); see the
      ``baseline_trend`` step of :func:`preprocess`.
    - `trend_slope` [N/s]: that line's slope in time, and `trend_slope_error` [N/s] its
      standard error (nan when no free force was found): what a fitted force drift
      (``force_drift`` of :func:`fitting.fit`) should find where the trend is a baseline.
    """

    index: int
    time: float
    tip_position: float
    force_offset: float
    force_slope: float
    noise: float
    method: str
    baseline_region: str
    height: float = 0.0
    baseline: str = "constant"
    retract_offset: float = 0.0
    retract_time: float = math.inf
    trend: float = 0.0
    trend_error: float = math.nan
    trend_noise: float = math.nan
    trend_slope: float = math.nan
    trend_slope_error: float = math.nan

    def baseline_force(self, time) -> np.ndarray:
        """The subtracted baseline [N] at the given times [s] (array like ``time``)."""
        t = np.asarray(time, dtype=np.float64)
        step = np.where(t >= self.retract_time, self.retract_offset, 0.0)
        return self.force_offset + self.force_slope * t + step


def _as_1d_float(name: str, value) -> np.ndarray:
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric: {exc}") from None
    if arr.ndim != 1:
        raise ValueError(f"{name} must be 1-D, got shape {arr.shape}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class Curve:
    """One measured force–displacement–time curve (SI units; see the module docstring).

    Attributes:
        time: sample times [s], strictly increasing.
        displacement: indentation depth [m], positive into the sample, 0 at the contact
            point (when ``contact.method`` is "detect" or "fit"; a raw cantilever curve before
            :func:`preprocess` holds the base displacement toward the sample instead).
        force: normal force [N], compressive positive, adhesive negative.
        segment: per-sample index into ``segment_names`` (non-decreasing, every segment
            non-empty). ``None``: inferred from the displacement by :func:`infer_segments`.
        segment_names: one name from :data:`SEGMENT_KINDS` per segment. ``None``: from the
            number of segments (1: approach; 2: approach, retract; 3: approach, hold,
            retract; 4: rest, approach, hold, retract).
        spring_constant: cantilever spring constant [N/m], ``None`` if not a cantilever
            curve (or unknown).
        contact: how the baseline, tip correction and contact point were done by
            :func:`preprocess`; ``None`` if the curve was not preprocessed.
        source: where the curve came from (a path).
        metadata: free-form metadata (e.g. the instrument file's).
        limits: plausibility limits checked on construction (``None``: no check).

    Raises:
        ValueError: unequal lengths, no samples, NaN/inf, time not strictly increasing,
            bad or empty segments, a non-positive spring constant, or values outside
            ``limits``; the message names the array and the sample.
    """

    time: np.ndarray
    displacement: np.ndarray
    force: np.ndarray
    segment: np.ndarray | None = None
    segment_names: tuple[str, ...] | None = None
    spring_constant: float | None = None
    contact: ContactPoint | None = None
    source: str = ""
    metadata: Mapping[str, Any] = field(default_factory=dict)
    limits: Limits | None = DEFAULT_LIMITS

    def __post_init__(self) -> None:
        t = _as_1d_float("time", self.time)
        d = _as_1d_float("displacement", self.displacement)
        f = _as_1d_float("force", self.force)
        if not (len(t) == len(d) == len(f)):
            raise ValueError(
                f"curve arrays have different lengths: time {len(t)}, "
                f"displacement {len(d)}, force {len(f)}"
            )
        if len(t) == 0:
            raise ValueError("curve is empty: time, displacement and force have no samples")
        for name, arr in (("time", t), ("displacement", d), ("force", f)):
            bad = np.flatnonzero(~np.isfinite(arr))
            if bad.size:
                i = int(bad[0])
                raise ValueError(
                    f"{name} has a non-finite value ({arr[i]}) at sample {i} "
                    f"({bad.size} non-finite in all)"
                )
        dt = np.diff(t)
        bad = np.flatnonzero(dt <= 0)
        if bad.size:
            i = int(bad[0]) + 1
            raise ValueError(
                f"time is not strictly increasing at sample {i}: t[{i}] = {plain(t[i])} s "
                f"after t[{i - 1}] = {plain(t[i - 1])} s"
            )
        object.__setattr__(self, "time", t)
        object.__setattr__(self, "displacement", d)
        object.__setattr__(self, "force", f)

        seg, names = self.segment, self.segment_names
        if seg is None:
            if names is not None:
                raise ValueError("segment_names given without segment")
            seg, names = infer_segments(t, d)
        seg = np.asarray(seg)
        if seg.ndim != 1 or len(seg) != len(t):
            raise ValueError(
                f"segment must be 1-D with one entry per sample ({len(t)}), got shape "
                f"{seg.shape}"
            )
        if seg.dtype.kind not in "iu":
            if seg.dtype.kind != "f" or not np.all(np.isfinite(seg)) or np.any(seg % 1):
                raise ValueError("segment must hold integer segment indices")
        seg = seg.astype(np.int64)
        if np.any(seg < 0):
            raise ValueError(f"segment has a negative index at sample {int(np.argmax(seg < 0))}")
        if np.any(np.diff(seg) < 0):
            i = int(np.flatnonzero(np.diff(seg) < 0)[0]) + 1
            raise ValueError(
                f"segment indices must not decrease along the curve; segment[{i}] = "
                f"{seg[i]} after segment[{i - 1}] = {seg[i - 1]}"
            )
        if names is None:
            count = int(seg.max()) + 1
            if count not in DEFAULT_SEGMENT_NAMES:
                raise ValueError(
                    f"{count} segments and no segment_names; pass segment_names (one of "
                    f"{SEGMENT_KINDS} per segment)"
                )
            names = DEFAULT_SEGMENT_NAMES[count]
        names = tuple(str(n) for n in names)
        for n in names:
            if n not in SEGMENT_KINDS:
                raise ValueError(f"segment name {n!r} is not one of {SEGMENT_KINDS}")
        if int(seg.max()) >= len(names):
            raise ValueError(
                f"segment index {int(seg.max())} but only {len(names)} segment_names {names}"
            )
        counts = np.bincount(seg, minlength=len(names))
        for j, c in enumerate(counts):
            if c == 0:
                raise ValueError(f"segment {j} ({names[j]!r}) has no samples")
        seg.setflags(write=False)
        object.__setattr__(self, "segment", seg)
        object.__setattr__(self, "segment_names", names)

        k = self.spring_constant
        if k is not None:
            k = float(k)
            if not (math.isfinite(k) and k > 0):
                raise ValueError(f"spring_constant must be finite and > 0 [N/m], got {k}")
            object.__setattr__(self, "spring_constant", k)
        if self.limits is not None:
            _check_limits(t, d, f, self.limits)

    def __len__(self) -> int:
        return len(self.time)

    @property
    def n_segments(self) -> int:
        """Number of segments."""
        return len(self.segment_names)

    def mask(self, *which: str | int) -> np.ndarray:
        """Boolean mask of the samples in the given segments (names or indices).

        A name selects every segment of that kind. Raises `ValueError` for a segment the
        curve does not have.
        """
        idx = _segment_indices(self, which)
        return np.isin(self.segment, idx)

    def surface_height(self, contact_offset: float = 0.0) -> float:
        r"""The height of the sample's surface where this curve touched it [m], in the
        instrument's frame of heights (the file's: decreasing toward the sample, so a
        taller sample has a larger surface height; a map of it is the sample's
        topography):

        $$z_s = h_0 - (p_c - \delta),$$

        $h_0$ the first sample's height (``metadata["height at start"]``, set by
        :func:`fitting.load_afm` for files whose heights are the instrument's frame),
        $p_c$ the contact's tip position (``contact.tip_position``, relative to the first
        sample's base position) and $\delta$ the fitted `contact_offset` [m] (the model's
        indentation is the data's plus $\delta$, so the contact lies $\delta$ before
        $p_c$; 0 for a detected contact point used as it is). NaN when the curve has no
        contact point (not preprocessed, or ``method="none"``) or no ``height at start``
        (heights relative to each curve's start: Bruker force volumes, Optics11 exports,
        CSV files)."""
        h0 = self.metadata.get("height at start")
        c = self.contact
        if h0 is None or c is None or c.method == "none":
            return math.nan
        return float(h0) - (float(c.tip_position) - float(contact_offset))

    def replace(self, **changes) -> Curve:
        """A copy with some fields replaced (validated again)."""
        return dataclasses.replace(self, **changes)


def _segment_indices(curve: Curve, which: Iterable[str | int]) -> list[int]:
    out: list[int] = []
    for w in which:
        if isinstance(w, str):
            hits = [j for j, n in enumerate(curve.segment_names) if n == w]
            if not hits:
                raise ValueError(
                    f"curve has no {w!r} segment; its segments are {curve.segment_names}"
                )
            out.extend(hits)
        else:
            j = int(w)
            if not 0 <= j < curve.n_segments:
                raise ValueError(
                    f"segment index {j} out of range; the curve has {curve.n_segments} "
                    f"segments {curve.segment_names}"
                )
            out.append(j)
    return sorted(set(out))


def select_segments(curve: Curve, *which: str | int) -> Curve:
    """The curve restricted to some segments (names or indices), renumbered from 0.

    Example: ``select_segments(c, "approach", "hold", "retract")`` drops a ``rest``
    segment. Raises `ValueError` if a requested segment is absent.
    """
    if not which:
        raise ValueError("select_segments needs at least one segment name or index")
    idx = _segment_indices(curve, which)
    keep = np.isin(curve.segment, idx)
    renumber = np.full(curve.n_segments, -1)
    renumber[idx] = np.arange(len(idx))
    return dataclasses.replace(
        curve,
        time=curve.time[keep],
        displacement=curve.displacement[keep],
        force=curve.force[keep],
        segment=renumber[curve.segment[keep]],
        segment_names=tuple(curve.segment_names[j] for j in idx),
    )


def resample(curve: Curve, n: int | Mapping[str, int]) -> Curve:
    """Linear interpolation onto ``n`` samples per segment, uniform in time.

    Each segment keeps its first and last time, so peaks at segment boundaries survive.
    ``n`` may be a mapping from segment name to sample count (missing names keep their
    samples). A segment with a single sample keeps it.
    """
    ts, ds, fs, ss = [], [], [], []
    for j, name in enumerate(curve.segment_names):
        m = curve.segment == j
        t, d, f = curve.time[m], curve.displacement[m], curve.force[m]
        count = int(n.get(name, len(t)) if isinstance(n, Mapping) else n)
        if count < 1:
            raise ValueError(f"resample: n must be >= 1, got {count} for segment {name!r}")
        tn = t[:1] if (len(t) == 1 or count == 1) else np.linspace(t[0], t[-1], count)
        ts.append(tn)
        ds.append(np.interp(tn, t, d))
        fs.append(np.interp(tn, t, f))
        ss.append(np.full(len(tn), j))
    return dataclasses.replace(
        curve,
        time=np.concatenate(ts),
        displacement=np.concatenate(ds),
        force=np.concatenate(fs),
        segment=np.concatenate(ss),
    )


def infer_segments(
    time, displacement, *, hold_tolerance: float = 0.02
) -> tuple[np.ndarray, tuple[str, ...]]:
    """Approach / hold / retract labels from the displacement history.

    The samples within ``hold_tolerance`` × (displacement span) of the maximum form a
    ``hold`` if they last more than 3× the time a ramp at the measured approach and
    retract speeds would spend there; before them is the ``approach``, after them the
    ``retract``. Otherwise the curve is split at the displacement maximum (approach up to
    and including it). Empty parts are left out. Returns ``(segment, segment_names)``.
    """
    t = np.asarray(time, dtype=np.float64)
    d = np.asarray(displacement, dtype=np.float64)
    n = len(d)
    span = float(np.ptp(d)) if n else 0.0
    if n < 3 or span == 0.0:
        return np.zeros(n, dtype=np.int64), ("approach",)
    tol = hold_tolerance * span
    near = np.flatnonzero(d >= d.max() - tol)
    i0, i1 = int(near[0]), int(near[-1])

    def _speed(a: int, b: int) -> float:
        dt = t[b] - t[a]
        return abs(d[b] - d[a]) / dt if dt > 0 else math.inf

    v_app = _speed(0, i0)
    v_ret = _speed(i1, n - 1)
    expected = sum(tol / v for v in (v_app, v_ret) if v > 0 and math.isfinite(v))
    labels = np.empty(n, dtype=object)
    if i1 - i0 >= 2 and (t[i1] - t[i0]) > 3.0 * expected:
        labels[:i0] = "approach"
        labels[i0 : i1 + 1] = "hold"
        labels[i1 + 1 :] = "retract"
    else:
        imax = int(np.argmax(d))
        labels[: imax + 1] = "approach"
        labels[imax + 1 :] = "retract"
    return runs_to_segments(list(labels))


def runs_to_segments(labels: Sequence[str]) -> tuple[np.ndarray, tuple[str, ...]]:
    seg = np.empty(len(labels), dtype=np.int64)
    names: list[str] = []
    prev = None
    for i, lab in enumerate(labels):
        if lab != prev:
            names.append(lab)
            prev = lab
        seg[i] = len(names) - 1
    return seg, tuple(names)
