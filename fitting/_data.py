"""Data in: measured force–displacement curves from CSV/TSV and AFM instrument files.

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
1. Baseline region: the ``rest`` segment if one precedes the approach (and has at least
   10 samples); otherwise the first ``baseline_fraction`` of the approach, later replaced
   by the approach samples before 90 % of the detected contact index (repeated until the
   contact index settles, at most 5 times).
2. Baseline model: ``"constant"`` (mean of the region) or ``"linear"`` (straight line in
   the base displacement, extrapolated into contact; useful against virtual deflection).
   The noise ``sigma`` is the standard deviation of the region about the baseline.
3. Detection: the first approach sample from which the baselined force stays above
   ``threshold * sigma`` for ``min_run`` samples; from there back to the last sample
   with force ``<= 0``. If the force dips below ``-2 * threshold * sigma`` just before
   that (a jump to contact), the contact is the last sample before the dip (the first
   sample below half the dip depth is the first in contact). If the force is positive
   from the very first approach sample, the contact is the first approach sample.
4. ``contact_point="fit"`` refines it by least squares of the Hertz-like power law
   ``F = a (p − p_c)_+^n`` (``n = contact_exponent``, 3/2 for a sphere) over the approach
   samples up to where the force first reaches ``fit_fraction`` of its approach maximum;
   ``a`` is profiled out and ``p_c`` found by a grid plus golden-section search within
   the tip positions of that window (no extrapolation before the first approach sample).

Plausibility limits
-------------------
:class:`Limits` (default :data:`DEFAULT_LIMITS`: |displacement| <= 1 mm, |force| <= 1 N,
duration <= 1e6 s, and non-zero spans >= 1 pm and >= 1 fN) catch unit mistakes such as
nanometres declared as metres. Pass ``limits=Limits(...)`` to a loader or to
:class:`Curve` to change them, or ``limits=None`` to switch the check off.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
import pathlib
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "SEGMENT_KINDS",
    "Limits",
    "DEFAULT_LIMITS",
    "ContactPoint",
    "Curve",
    "unit_factor",
    "parse_units",
    "infer_segments",
    "select_segments",
    "resample",
    "preprocess",
    "load_csv",
    "load_afm",
    "load_curve",
]

SEGMENT_KINDS: tuple[str, ...] = ("rest", "approach", "hold", "retract")
"""Allowed segment names: ``rest`` (no motion, out of contact), ``approach`` (loading),
``hold`` (dwell at constant height or force), ``retract`` (unloading)."""

_DEFAULT_SEGMENT_NAMES: dict[int, tuple[str, ...]] = {
    1: ("approach",),
    2: ("approach", "retract"),
    3: ("approach", "hold", "retract"),
    4: ("rest", "approach", "hold", "retract"),
}

_SEGMENT_ALIASES: dict[str, str] = {
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
    """Where and how the contact point was found (see :func:`preprocess`).

    Attributes:
        index: sample index of the contact in the curve as preprocessed (before any
            :func:`select_segments` or :func:`resample`).
        time: time of that sample [s].
        tip_position: tip position toward the sample at contact [m], relative to the base
            position of the first sample; subtracted from the tip position to give the
            indentation.
        force_offset: baseline force subtracted [N] (its value at zero base displacement for
            a linear baseline).
        force_slope: slope of a linear baseline in the base displacement [N/m] (0 for a
            constant baseline).
        noise: standard deviation of the force about the baseline in the baseline region
            [N].
        method: ``"detect"`` or ``"fit"``; ``"none"`` when no contact point was sought
            (``index`` is then 0 and the displacement is the tip position relative to the
            first sample's base position).
        baseline_region: ``"rest"``, ``"approach"``, or ``"none"`` (no baseline).
    """

    index: int
    time: float
    tip_position: float
    force_offset: float
    force_slope: float
    noise: float
    method: str
    baseline_region: str


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
                f"time is not strictly increasing at sample {i}: t[{i}] = {t[i]!r} s "
                f"after t[{i - 1}] = {t[i - 1]!r} s"
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
            if count not in _DEFAULT_SEGMENT_NAMES:
                raise ValueError(
                    f"{count} segments and no segment_names; pass segment_names (one of "
                    f"{SEGMENT_KINDS} per segment)"
                )
            names = _DEFAULT_SEGMENT_NAMES[count]
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
    return _runs_to_segments(list(labels))


def _runs_to_segments(labels: Sequence[str]) -> tuple[np.ndarray, tuple[str, ...]]:
    seg = np.empty(len(labels), dtype=np.int64)
    names: list[str] = []
    prev = None
    for i, lab in enumerate(labels):
        if lab != prev:
            names.append(lab)
            prev = lab
        seg[i] = len(names) - 1
    return seg, tuple(names)


# --- units -------------------------------------------------------------------------------

_BASE_UNITS: dict[str, tuple[str, float]] = {
    # time
    "s": ("time", 1.0), "ms": ("time", 1e-3), "us": ("time", 1e-6),
    "\u00b5s": ("time", 1e-6), "\u03bcs": ("time", 1e-6), "ns": ("time", 1e-9),
    "min": ("time", 60.0),
    # length
    "m": ("length", 1.0), "mm": ("length", 1e-3), "um": ("length", 1e-6),
    "\u00b5m": ("length", 1e-6), "\u03bcm": ("length", 1e-6), "nm": ("length", 1e-9),
    "pm": ("length", 1e-12),
    # force
    "N": ("force", 1.0), "mN": ("force", 1e-3), "uN": ("force", 1e-6),
    "\u00b5N": ("force", 1e-6), "\u03bcN": ("force", 1e-6), "nN": ("force", 1e-9),
    "pN": ("force", 1e-12),
}


def unit_factor(unit: str) -> tuple[str, float]:
    """``(dimension, factor to SI)`` of a unit string.

    Known: s, ms, us/µs, ns, min; m, mm, um/µm, nm, pm; N, mN, uN/µN, nN, pN; and
    quotients of them such as ``µm/s`` (dimension ``"length/time"``) or ``N/m``.
    Units are case-sensitive. Raises `ValueError` for an unknown unit.
    """
    u = unit.strip()
    if u in _BASE_UNITS:
        return _BASE_UNITS[u]
    if u.count("/") == 1:
        num, den = (p.strip() for p in u.split("/"))
        if num in _BASE_UNITS and den in _BASE_UNITS:
            dn, fn = _BASE_UNITS[num]
            dd, fd = _BASE_UNITS[den]
            return f"{dn}/{dd}", fn / fd
    raise ValueError(
        f"unknown unit {unit!r}; known units: {', '.join(_BASE_UNITS)} and quotients "
        "such as 'um/s'"
    )


_ROLE_DIMENSION = {"time": "time", "displacement": "length", "height": "length",
                   "force": "force"}
_ROLES = ("time", "displacement", "height", "force", "segment")
_ROLE_ALIASES: dict[str, tuple[str, ...]] = {
    "time": ("time", "t"),
    "displacement": ("displacement", "indentation", "delta", "depth", "disp", "d", "z"),
    "height": ("height",),
    "force": ("force", "f", "load"),
    "segment": ("segment", "seg", "segment_name", "phase"),
}


def parse_units(spec: str | Mapping[str, str] | None) -> dict[str, str]:
    """Unit choices per column role, e.g. ``"displacement=nm,force=nN"`` → dict.

    Roles: time, displacement, height, force. Accepts a mapping (returned as a checked
    dict) or ``None`` (empty dict). Raises `ValueError` for an unknown role, an unknown
    unit, or a unit of the wrong dimension.
    """
    if spec is None:
        return {}
    if isinstance(spec, str):
        out: dict[str, str] = {}
        for part in spec.split(","):
            part = part.strip()
            if not part:
                continue
            if "=" not in part:
                raise ValueError(
                    f"units: cannot read {part!r}; write role=unit pairs such as "
                    "'displacement=nm,force=nN'"
                )
            role, unit = (p.strip() for p in part.split("=", 1))
            out[role] = unit
        spec = out
    checked: dict[str, str] = {}
    for role, unit in spec.items():
        if role not in _ROLE_DIMENSION:
            raise ValueError(
                f"units: unknown column role {role!r}; use one of {tuple(_ROLE_DIMENSION)}"
            )
        dim, _ = unit_factor(unit)
        if dim != _ROLE_DIMENSION[role]:
            raise ValueError(
                f"units: {role} needs a {_ROLE_DIMENSION[role]} unit, got {unit!r} ({dim})"
            )
        checked[role] = unit
    return checked


_HEADER_BRACKET = re.compile(r"^(.*?)\s*[\[(]\s*([^\])]+?)\s*[\])]\s*$")


def _split_header(name: str) -> tuple[str, str | None]:
    """``"force [nN]"`` → ``("force", "nN")``; ``"time_s"`` → ``("time", "s")``."""
    name = name.strip().strip('"').strip("'").strip()
    m = _HEADER_BRACKET.match(name)
    if m:
        return _norm(m.group(1)), m.group(2)
    for sep in ("_", "/", " "):
        if sep in name:
            base, unit = name.rsplit(sep, 1)
            if unit in _BASE_UNITS or (sep != "/" and _is_quotient_unit(unit)):
                return _norm(base), unit
    return _norm(name), None


def _is_quotient_unit(unit: str) -> bool:
    try:
        unit_factor(unit)
    except ValueError:
        return False
    return "/" in unit


def _norm(base: str) -> str:
    return re.sub(r"[\s\-]+", "_", base.strip().lower())


# --- CSV / TSV ---------------------------------------------------------------------------


def _read_table(path: pathlib.Path, delimiter: str | None):
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        text = path.read_text(encoding="latin-1")
    lines = [
        (no, line)
        for no, line in enumerate(text.splitlines(), start=1)
        if line.strip() and not line.lstrip().startswith("#")
    ]
    if not lines:
        raise ValueError(f"{path}: file is empty (no header and no data rows)")
    header_line = lines[0][1]
    if delimiter is None:
        if path.suffix.lower() == ".tsv" or "\t" in header_line:
            delimiter = "\t"
        elif "," in header_line:
            delimiter = ","
        elif ";" in header_line:
            delimiter = ";"
        else:
            delimiter = " "  # runs of whitespace
    if delimiter == " ":
        rows = [(no, line.split()) for no, line in lines]
    else:
        reader = csv.reader(io.StringIO("\n".join(line for _, line in lines)),
                            delimiter=delimiter)
        rows = [(no, [c.strip() for c in fields]) for (no, _), fields in zip(lines, reader,
                                                                            strict=True)]
    header = rows[0][1]
    if not any(re.search(r"[A-Za-z]", h) for h in header):
        raise ValueError(
            f"{path}: line {rows[0][0]} has no column names; the first row must be a header "
            "such as 'time_s,displacement_m,force_N'"
        )
    data = rows[1:]
    if not data:
        raise ValueError(f"{path}: no data rows after the header {header}")
    for no, fields in data:
        if len(fields) != len(header):
            raise ValueError(
                f"{path}: line {no} has {len(fields)} fields, the header has {len(header)} "
                f"(delimiter {delimiter!r})"
            )
    return header, data


def _resolve_columns(path, header, columns: Mapping[str, str] | None):
    parsed = [_split_header(h) for h in header]
    chosen: dict[str, int] = {}
    if columns:
        for role, name in columns.items():
            if role not in _ROLES:
                raise ValueError(f"columns: unknown role {role!r}; use one of {_ROLES}")
            hits = [i for i, h in enumerate(header) if h.strip() == name]
            if not hits:
                hits = [i for i, (b, _) in enumerate(parsed) if b == _norm(name)]
            if not hits:
                raise ValueError(
                    f"{path}: no column {name!r} (asked for {role}); the header has {header}"
                )
            chosen[role] = hits[0]
    for role in _ROLES:
        if role in chosen:
            continue
        hits = [i for i, (b, _) in enumerate(parsed) if b in _ROLE_ALIASES[role]]
        if len(hits) > 1:
            raise ValueError(
                f"{path}: several columns could be the {role}: "
                f"{[header[i] for i in hits]}; choose with columns={{'{role}': ...}}"
            )
        if hits:
            chosen[role] = hits[0]
    if "displacement" in chosen and "height" in chosen and not (columns and "height" in columns):
        del chosen["height"]
    for role in ("time", "force"):
        if role not in chosen:
            raise ValueError(
                f"{path}: no {role} column found; the header has {header}; name it e.g. "
                f"'{role}_{'s' if role == 'time' else 'N'}' or pass columns={{'{role}': ...}}"
            )
    if "displacement" not in chosen and "height" not in chosen:
        raise ValueError(
            f"{path}: no displacement column found; the header has {header}; name it e.g. "
            "'displacement_m' or pass columns={'displacement': ...}"
        )
    return chosen, parsed


def _parse_numeric(path, header_name, data, col) -> np.ndarray:
    out = np.empty(len(data))
    for r, (no, fields) in enumerate(data):
        s = fields[col]
        try:
            out[r] = float(s)
        except ValueError:
            raise ValueError(
                f"{path}: column {header_name!r}, data row {r + 1} (line {no}): cannot read "
                f"{s!r} as a number"
            ) from None
        if not math.isfinite(out[r]):
            raise ValueError(
                f"{path}: column {header_name!r} has a non-finite value ({s!r}) at data row "
                f"{r + 1} (line {no})"
            )
    return out


def load_csv(
    path,
    *,
    columns: Mapping[str, str] | None = None,
    units: str | Mapping[str, str] | None = None,
    delimiter: str | None = None,
    segment_names: Sequence[str] | None = None,
    spring_constant: float | None = None,
    baseline: str | None = None,
    contact_point: str | None = None,
    limits: Limits | None = DEFAULT_LIMITS,
) -> Curve:
    """Load one curve from a CSV/TSV/whitespace table with a header row.

    Columns are found by name (case-insensitive), with an optional unit in the name:
    ``force_N``, ``force [nN]``, ``force (nN)``, ``force/nN``. Roles and accepted names:
    time (``time``, ``t``), displacement (``displacement``, ``indentation``, ``delta``,
    ``depth``, ``disp``, ``d``, ``z``; positive into the sample), height (``height``;
    decreasing toward the sample, used as ``height[0] − height`` when there is no
    displacement column), force (``force``, ``f``, ``load``; compressive positive) and an
    optional segment column (``segment``, ``seg``, ``phase``) holding names (approach /
    extend, hold / dwell / pause, retract, rest) or non-decreasing integers. Other
    columns are ignored. Lines starting with ``#`` are skipped.

    Args:
        path: file path.
        columns: role → column name, overriding the automatic choice.
        units: role → unit (e.g. ``{"displacement": "nm", "force": "nN"}`` or the string
            ``"displacement=nm,force=nN"``); columns without a unit anywhere are SI. A
            unit given here that contradicts the one in the column name is an error.
        delimiter: field separator; ``None`` auto-detects (tab for ``.tsv`` or a tab in
            the header, else comma, semicolon, whitespace).
        segment_names: names for integer segment columns (default by count, see
            :class:`Curve`); without a segment column the segments are inferred by
            :func:`infer_segments`.
        spring_constant: cantilever spring constant [N/m]; when given, the displacement
            column is the base (piezo) displacement and the tip correction ``− F/k`` is
            applied (see :func:`preprocess`).
        baseline: ``None`` (default: the force is taken as already baselined),
            ``"constant"`` or ``"linear"``.
        contact_point: ``None`` (default: the displacement is already the indentation),
            ``"detect"`` or ``"fit"`` (see :func:`preprocess`; a ``None`` baseline then
            means ``"constant"``).
        limits: plausibility limits (see :class:`Limits`).

    Raises:
        ValueError: empty file, missing column, unparsable or NaN value (naming the
            column and the row), bad unit, time not strictly increasing (naming the row),
            or implausible magnitudes.
    """
    path = pathlib.Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    header, data = _read_table(path, delimiter)
    chosen, parsed = _resolve_columns(path, header, columns)
    user_units = parse_units(units)

    values: dict[str, np.ndarray] = {}
    for role in ("time", "displacement", "height", "force"):
        if role not in chosen:
            continue
        col = chosen[role]
        hname = header[col]
        header_unit = parsed[col][1]
        unit = user_units.get(role)
        if header_unit is not None:
            try:
                hdim, _ = unit_factor(header_unit)
            except ValueError as exc:
                raise ValueError(f"{path}: column {hname!r}: {exc}") from None
            if hdim != _ROLE_DIMENSION[role]:
                raise ValueError(
                    f"{path}: column {hname!r} is the {role} but its unit {header_unit!r} "
                    f"is a {hdim}"
                )
            if unit is not None and unit_factor(unit)[1] != unit_factor(header_unit)[1]:
                raise ValueError(
                    f"{path}: column {hname!r} declares unit {header_unit!r} but "
                    f"units['{role}'] = {unit!r}"
                )
            unit = header_unit
        factor = unit_factor(unit)[1] if unit is not None else 1.0
        values[role] = _parse_numeric(path, hname, data, col) * factor

    t = values["time"]
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        r = int(bad[0]) + 1
        raise ValueError(
            f"{path}: column {header[chosen['time']]!r} is not strictly increasing at data "
            f"row {r + 1} (line {data[r][0]}): {t[r]!r} s after {t[r - 1]!r} s"
        )
    if "displacement" in values:
        disp = values["displacement"]
    else:
        disp = values["height"][0] - values["height"]

    seg = names = None
    if "segment" in chosen:
        col = chosen["segment"]
        raw = [fields[col] for _, fields in data]
        seg, names = _parse_segment_column(path, header[col], raw, data, segment_names)
    elif segment_names is not None:
        raise ValueError("segment_names given but the file has no segment column")

    curve = Curve(
        time=t, displacement=disp, force=values["force"], segment=seg, segment_names=names,
        spring_constant=spring_constant, source=str(path), limits=limits,
        metadata={"columns": {r: header[i] for r, i in chosen.items()}},
    )
    if spring_constant is not None or baseline is not None or contact_point is not None:
        curve = preprocess(
            curve, baseline=baseline or ("constant" if contact_point else None),
            contact_point=contact_point,
        )
    return curve


def _parse_segment_column(path, hname, raw, data, segment_names):
    ints = []
    for r, s in enumerate(raw):
        try:
            ints.append(int(float(s)))
        except ValueError:
            break
        if not s or float(s) % 1:
            raise ValueError(
                f"{path}: column {hname!r}, data row {r + 1} (line {data[r][0]}): "
                f"segment {s!r} is not an integer"
            )
    else:
        seg = np.asarray(ints)
        if np.any(np.diff(seg) < 0):
            r = int(np.flatnonzero(np.diff(seg) < 0)[0]) + 1
            raise ValueError(
                f"{path}: column {hname!r} decreases at data row {r + 1} (line "
                f"{data[r][0]}); segments must be numbered in order"
            )
        present = np.unique(seg)
        seg = np.searchsorted(present, seg)  # compact numbering (empty segments dropped)
        if segment_names is not None:
            segment_names = tuple(segment_names)
            if len(segment_names) != len(present):
                raise ValueError(
                    f"{path}: {len(present)} segments in column {hname!r} but "
                    f"{len(segment_names)} segment_names"
                )
        return seg, segment_names
    labels = []
    for r, s in enumerate(raw):
        key = _norm(s)
        if key not in _SEGMENT_ALIASES:
            raise ValueError(
                f"{path}: column {hname!r}, data row {r + 1} (line {data[r][0]}): unknown "
                f"segment name {s!r}; use approach, hold, retract or rest"
            )
        labels.append(_SEGMENT_ALIASES[key])
    return _runs_to_segments(labels)


# --- baseline, tip position and contact point -------------------------------------------


def _baseline_fit(u, f, kind):
    if kind == "linear" and len(u) >= 3 and np.ptp(u) > 0:
        slope, offset = np.polyfit(u, f, 1)
    else:
        slope, offset = 0.0, float(np.mean(f))
    resid = f - (offset + slope * u)
    return float(offset), float(slope), float(np.std(resid))


def _detect_index(fb, thr, min_run):
    """Contact index on the baselined approach force ``fb`` (see module docstring)."""
    above = (fb > thr).astype(np.int64)
    m = min(min_run, len(fb))
    runs = np.convolve(above, np.ones(m, dtype=np.int64), mode="valid")
    hits = np.flatnonzero(runs == m)
    if hits.size == 0:
        raise ValueError(
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
    a_, c_ = grid[max(b - 1, 0)], grid[min(b + 1, len(grid) - 1)]
    gr = (math.sqrt(5.0) - 1.0) / 2.0
    x1, x2 = c_ - gr * (c_ - a_), a_ + gr * (c_ - a_)
    f1, f2 = sse(x1), sse(x2)
    for _ in range(60):
        if f1 < f2:
            c_, x2, f2 = x2, x1, f1
            x1 = c_ - gr * (c_ - a_)
            f1 = sse(x1)
        else:
            a_, x1, f1 = x1, x2, f2
            x2 = a_ + gr * (c_ - a_)
            f2 = sse(x2)
    return 0.5 * (a_ + c_)


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
) -> Curve:
    """Force baseline, tip position and contact point of a raw curve.

    ``curve.displacement`` is read as the base (piezo) displacement toward the sample
    and ``curve.force`` as the raw force. Returns a curve whose displacement is the
    indentation ``p − p_c`` with tip position ``p = u − F/k`` (``p = u`` without a spring
    constant) and whose force has the baseline removed; ``contact`` records what was done.
    The algorithm is in the module docstring.

    Args:
        curve: the raw curve (must have an ``approach`` segment when detecting).
        spring_constant: cantilever k [N/m]; default ``curve.spring_constant``; ``None``
            for both means no tip correction.
        baseline: ``"constant"``, ``"linear"`` or ``None`` (no subtraction).
        contact_point: ``"detect"``, ``"fit"`` or ``None`` (no zeroing: the displacement
            is then the tip position relative to the first sample's base position).
        threshold: detection threshold in units of the baseline noise.
        min_run: samples the force must stay above the threshold.
        baseline_fraction: initial fraction of the approach used as baseline when there
            is no rest segment.
        fit_fraction: the power-law fit uses the approach up to this fraction of its
            maximum force.
        contact_exponent: exponent of the power law (1.5: Hertz sphere).

    Raises:
        ValueError: already preprocessed, unknown option, no approach segment, or no
            contact found.
    """
    if curve.contact is not None:
        raise ValueError("curve was already preprocessed (curve.contact is set)")
    if baseline not in (None, "constant", "linear"):
        raise ValueError(f"baseline must be 'constant', 'linear' or None, got {baseline!r}")
    if contact_point not in (None, "detect", "fit"):
        raise ValueError(f"contact_point must be 'detect', 'fit' or None, got {contact_point!r}")
    if not threshold > 0:
        raise ValueError(f"threshold must be > 0, got {threshold}")
    if not 0 < fit_fraction <= 1:
        raise ValueError(f"fit_fraction must lie in (0, 1], got {fit_fraction}")
    k = spring_constant if spring_constant is not None else curve.spring_constant
    if k is not None and not (math.isfinite(k) and k > 0):
        raise ValueError(f"spring_constant must be finite and > 0 [N/m], got {k}")
    u, f = curve.displacement, curve.force
    offset = slope = noise = 0.0
    region = "none"
    c_global = None
    method = contact_point or "none"

    if contact_point is not None or baseline is not None:
        kind = baseline or "constant"
        if "approach" not in curve.segment_names:
            raise ValueError(
                f"curve has no 'approach' segment (segments {curve.segment_names}); the "
                "baseline and contact point are found on the approach"
            )
        j_app = curve.segment_names.index("approach")
        app = np.flatnonzero(curve.segment == j_app)
        ua, fa = u[app], f[app]
        rest_js = [j for j, nm in enumerate(curve.segment_names[:j_app]) if nm == "rest"]
        rest = np.flatnonzero(curve.segment == rest_js[-1]) if rest_js else np.array([], int)
        if rest.size >= 10:
            region = "rest"
            ref_u, ref_f = u[rest], f[rest]
            if kind == "linear" and np.ptp(ref_u) == 0:
                kind_eff = "constant"
            else:
                kind_eff = kind
            offset, slope, noise = _baseline_fit(ref_u, ref_f, kind_eff)
        else:
            region = "approach"
            n0 = min(len(app), max(10, int(baseline_fraction * len(app))))
            offset, slope, noise = _baseline_fit(ua[:n0], fa[:n0], kind)
        scale = float(np.max(np.abs(fa - offset - slope * ua))) or 1.0
        sig = max(noise, 1e-12 * scale)
        c = None
        if contact_point is not None:
            c = _detect_index(fa - offset - slope * ua, threshold * sig, min_run)
            if region == "approach":
                for _ in range(5):
                    n0 = int(0.9 * c)
                    if n0 < 10:
                        break
                    offset, slope, noise = _baseline_fit(ua[:n0], fa[:n0], kind)
                    sig = max(noise, 1e-12 * scale)
                    c_new = _detect_index(fa - offset - slope * ua, threshold * sig, min_run)
                    if c_new == c:
                        break
                    c = c_new
        if baseline is None:  # detection only: keep the force as given
            fb = f.copy()
            offset_used, slope_used = 0.0, 0.0
        else:
            fb = f - offset - slope * u
            offset_used, slope_used = offset, slope
    else:
        fb = f.copy()
        offset_used = slope_used = 0.0
        c = None

    fdet = f - offset - slope * u  # baselined force (= f when no baseline was computed)
    p = u - fdet / k if k is not None else u.copy()  # deflection from the free baseline
    if contact_point is None:
        p_c = float(u[0])
        idx = 0
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
        c_global = int(app[idx])
    ci = c_global if c_global is not None else 0
    cp = ContactPoint(
        index=ci, time=float(curve.time[ci]), tip_position=p_c,
        force_offset=offset_used, force_slope=slope_used, noise=noise,
        method=method, baseline_region=region,
    )
    return dataclasses.replace(
        curve, displacement=p - p_c, force=fb, spring_constant=k, contact=cp,
    )


# --- AFM instrument files (afmformats) ----------------------------------------------------

_MODALITY_SEGMENTS = {
    "force-distance": ("approach", "retract"),
    "creep-compliance": ("approach", "hold", "retract"),
    "stress-relaxation": ("rest", "approach", "hold", "retract"),
}


def load_afm(
    path,
    *,
    spring_constant: float | None = None,
    height_column: str | None = None,
    baseline: str | None = "constant",
    contact_point: str | None = "detect",
    modality: str | None = None,
    limits: Limits | None = DEFAULT_LIMITS,
    **preprocess_kw,
) -> list[Curve]:
    """Load the curves of an AFM file through ``afmformats.load_data``.

    Reads whatever afmformats reads (JPK ``.jpk-force``, ``.jpk-force-map``,
    ``.jpk-qi-data``; Asylum ``.ibw``; afmformats' HDF5/tab/txt exports, ...); see
    ``afmformats.supported_extensions``.

    * Height: ``height (measured)`` (closed-loop sensor) when present, else
      ``height (piezo)``; choose with ``height_column``. Base displacement toward the
      sample ``u = h[0] − h`` (AFM heights decrease toward the sample).
    * Time: the file's ``time`` column, else ``sample index / rate approach`` (Asylum
      ``.ibw`` files carry no time column; their sample interval is 1/``NumPtsPerSec``).
    * Segments by modality: stress-relaxation → rest, approach, hold, retract;
      creep-compliance → approach, hold, retract; force-distance → approach, retract,
      and a single-segment force-distance curve (e.g. ``.ibw``) is split after the force
      maximum. A missing (empty) segment is an error.
    * Spring constant: the file's ``spring constant``. A ``spring_constant`` argument
      overrides it and rescales the force by ``k_arg / k_file`` (the instrument measured
      the deflection, ``F = k d``); it is only *required* when the file has none.
    * Then :func:`preprocess` (``baseline``, ``contact_point`` and ``preprocess_kw``).

    Raises:
        ImportError: afmformats is not installed (``pip install jaxcontact[afm]``).
        ValueError: unreadable data, an empty segment, NaN values, or a failed contact
            detection (the message names the file).
    """
    try:
        import afmformats
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(
            "reading AFM files needs afmformats: pip install 'jaxcontact[afm]'"
        ) from exc
    path = pathlib.Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    datasets = afmformats.load_data(path, modality=modality)
    if not datasets:
        raise ValueError(f"{path}: afmformats found no curves in the file")
    curves = []
    for n, ds in enumerate(datasets):
        try:
            curves.append(
                _afm_curve(ds, path, spring_constant, height_column, baseline,
                           contact_point, limits, preprocess_kw)
            )
        except ValueError as exc:
            where = f"{path}" if len(datasets) == 1 else f"{path} (curve {n})"
            raise ValueError(f"{where}: {exc}") from None
    return curves


def _afm_curve(ds, path, k_arg, height_column, baseline, contact_point, limits, pkw):
    meta = dict(ds.metadata)
    cols = list(ds.columns)
    if height_column is None:
        height_column = next(
            (c for c in ("height (measured)", "height (piezo)") if c in cols), None
        )
        if height_column is None:
            raise ValueError(f"no height column; the file has columns {cols}")
    elif height_column not in cols:
        raise ValueError(f"no column {height_column!r}; the file has columns {cols}")
    if "force" not in cols:
        raise ValueError(f"no force column; the file has columns {cols}")
    h = np.asarray(ds[height_column], dtype=np.float64)
    force = np.asarray(ds["force"], dtype=np.float64)
    seg_raw = (np.asarray(ds["segment"], dtype=np.int64) if "segment" in cols
               else np.zeros(len(h), dtype=np.int64))
    if "time" in cols:
        time = np.asarray(ds["time"], dtype=np.float64)
    else:
        rate = meta.get("rate approach")
        if not rate or not math.isfinite(float(rate)) or float(rate) <= 0:
            raise ValueError("the file has no time column and no sampling rate")
        time = np.arange(len(h), dtype=np.float64) / float(rate)

    k_file = meta.get("spring constant")
    k_file = float(k_file) if k_file is not None and math.isfinite(float(k_file)) else None
    if k_arg is not None:
        k = float(k_arg)
        if not (math.isfinite(k) and k > 0):
            raise ValueError(f"spring_constant must be finite and > 0 [N/m], got {k}")
        if k_file is not None:
            force = force * (k / k_file)
    else:
        k = k_file

    mod = meta.get("imaging mode") or ds.modality
    expected = _MODALITY_SEGMENTS.get(mod)
    present = np.unique(seg_raw)
    if mod == "force-distance" and len(present) == 1:
        imax = int(np.argmax(force))
        seg = (np.arange(len(force)) > imax).astype(np.int64)
        names = ("approach", "retract") if imax < len(force) - 1 else ("approach",)
        seg = np.minimum(seg, len(names) - 1)
    elif expected is not None:
        for j, nm in enumerate(expected):
            if j not in present:
                raise ValueError(f"segment {j} ({nm!r}) has no samples")
        if present.max() >= len(expected):
            raise ValueError(
                f"{mod} data with {len(present)} segments; expected {expected}"
            )
        seg, names = seg_raw, expected
    else:
        seg = np.searchsorted(present, seg_raw)
        if len(present) not in _DEFAULT_SEGMENT_NAMES:
            raise ValueError(f"cannot name {len(present)} segments of modality {mod!r}")
        names = _DEFAULT_SEGMENT_NAMES[len(present)]

    meta["height column"] = height_column
    meta["spring constant (file)"] = k_file
    raw = Curve(
        time=time, displacement=h[0] - h, force=force, segment=seg, segment_names=names,
        spring_constant=k, source=str(path), metadata=meta, limits=limits,
    )
    if baseline is None and contact_point is None and k is None:
        return raw
    return preprocess(raw, baseline=baseline, contact_point=contact_point, **pkw)


# --- dispatch ----------------------------------------------------------------------------

_TABLE_SUFFIXES = (".csv", ".tsv", ".txt", ".dat")


def load_curve(path, *, format: str | None = None, **kw) -> list[Curve]:
    """Load curves from ``path``, choosing the reader by extension.

    ``.csv``, ``.tsv``, ``.txt``, ``.dat`` → :func:`load_csv` (one curve); anything else
    → :func:`load_afm`. ``format="csv"`` or ``format="afm"`` forces a reader (e.g.
    ``format="afm"`` for an afmformats ``.csv``/``.txt`` export). Keyword arguments go to
    the chosen reader. Always returns a list.
    """
    path = pathlib.Path(path)
    if format is None:
        format = "csv" if path.suffix.lower() in _TABLE_SUFFIXES else "afm"
    if format == "csv":
        return [load_csv(path, **kw)]
    if format == "afm":
        return load_afm(path, **kw)
    raise ValueError(f"format must be 'csv', 'afm' or None, got {format!r}")
