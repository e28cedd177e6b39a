"""AFM instrument files through afmformats, and JPK files it refuses through
:mod:`fitting._io_jpk`: :func:`load_afm`."""

from __future__ import annotations

import dataclasses
import logging
import math
import pathlib
import zipfile
import zlib
from collections.abc import Mapping
from typing import Any

import numpy as np

from ._curve import DEFAULT_LIMITS, DEFAULT_SEGMENT_NAMES, Curve, DataError, Limits
from ._io_bruker import read_bruker, sniff_bruker
from ._io_jpk import JPK_SUFFIXES, JPKCurve, read_jpk, segment_kinds
from ._preprocess import preprocess

__all__ = ["load_afm", "FailedCurve"]


@dataclasses.dataclass(frozen=True)
class FailedCurve:
    """A curve of a multi-curve file (force map, QI series) that could not be made into a
    :class:`Curve`: where it came from (`source`, its position `index` in the file, the
    file's `metadata` of that curve: grid indices and positions of a map) and why
    (`reason`). :func:`load_afm` returns it in place of the curve with
    ``on_error="keep"``; :func:`fitting.fit_each` reports it as a failed point."""

    source: str
    index: int
    reason: str
    metadata: Mapping[str, Any] = dataclasses.field(default_factory=dict)


_MODALITY_SEGMENTS = {
    "force-distance": ("approach", "retract"),
    "creep-compliance": ("approach", "hold", "retract"),
    "stress-relaxation": ("rest", "approach", "hold", "retract"),
}


def load_afm(
    path,
    *,
    spring_constant: float | None = None,
    sensitivity: float | None = None,
    sample_rate: float | None = None,
    height_column: str | None = None,
    baseline: str | None = "constant",
    contact_point: str | None = "detect",
    modality: str | None = None,
    limits: Limits | None = DEFAULT_LIMITS,
    on_error: str = "raise",
    **preprocess_kw,
) -> list[Curve | FailedCurve]:
    """Load the curves of an AFM file through ``afmformats.load_data``.

    Reads whatever afmformats reads (JPK ``.jpk-force``, ``.jpk-force-map``,
    ``.jpk-qi-data``; Asylum ``.ibw``; afmformats' HDF5/tab/txt exports, ...); see
    ``afmformats.supported_extensions``. A JPK file (``.jpk-force``, ``.jpk-force-map``,
    ``.jpk-qi-data``, ``.jpk-qi-series``) that afmformats refuses (its recogniser knows
    three segment layouts only: extend–retract, extend–constant-force pause–retract,
    pause–extend–constant-height pause–retract; newer JPK software also writes e.g.
    extend–pause–retract maps) or that is read without afmformats installed goes to
    :func:`fitting._io_jpk.read_jpk`, which reads any layout of extend, retract and pause
    segments into the same columns and metadata (``metadata["reader"]``: ``"afmformats"``
    or ``"jaxcontact-jpk"``). A Bruker NanoScope force curve or force volume (a file that
    starts with ``\\*Force file list``; afmformats reads none) goes to
    :func:`fitting._io_bruker.read_bruker` (``metadata["reader"]``:
    ``"jaxcontact-bruker"``).

    * Height: ``height (measured)`` (closed-loop sensor) when present, else
      ``height (piezo)``; choose with ``height_column``. Base displacement toward the
      sample ``u = h[0] − h`` (AFM heights decrease toward the sample). Where the file's
      heights are the instrument's own frame, one for every curve of a map (JPK and
      Asylum files: :data:`ABSOLUTE_HEIGHT_FORMATS`), ``metadata["height at start"]`` is
      ``h[0]`` [m], so that :meth:`fitting.Curve.surface_height` gives the sample's
      surface at the curve's contact point (a map's topography); other files (Bruker
      force volumes, whose ramps each start at 0; Optics11 exports) have none.
    * Time: the file's ``time`` column, else ``sample index / rate approach`` (Asylum
      ``.ibw`` files carry no time column; their sample interval is 1/``NumPtsPerSec``),
      else ``sample index / sample_rate`` with the ``sample_rate`` [Hz] given (AFM
      Workshop ``.csv`` files store neither time nor rate: the viscoelastic models need
      it, so such a file without ``sample_rate`` is a `DataError` that says so). A
      ``sample_rate`` given for a file with its own time base is an error.
    * Segments by modality: stress-relaxation → rest, approach, hold, retract;
      creep-compliance → approach, hold, retract; force-distance → approach, retract,
      and a single-segment force-distance curve is split after the force maximum. An
      Asylum ``.ibw`` stores all segments in one wave; its note's ``Indexes`` (segment
      boundaries, sample indices) and ``Direction`` (``1`` toward the sample, ``0``
      dwell, ``-1`` away, ``NaN`` before the first) give approach / hold / retract (and
      rest for a zero-motion segment before the approach); without them the curve is
      split after the force maximum. A JPK ``.jpk-force`` file names its segments in
      each ``segment-header.properties`` (``segment-settings.style``: ``extend`` →
      approach, ``retract`` → retract, ``pause`` → rest before the first extend, hold
      after it); these names are used when present. A missing (empty) segment is an
      error.
    * Spring constant: the file's ``spring constant``. A ``spring_constant`` argument
      overrides it and rescales the force by ``k_arg / k_file`` (the instrument measured
      the deflection, ``F = k d``); it is only *required* when the file has none.
    * Sensitivity: ``sensitivity`` [m/V], the deflection per photodetector volt, for
      files that store the deflection in volts without it (AFM Workshop ``.csv`` with the
      default light-lever gain); it is given to afmformats as metadata together with
      ``spring_constant`` (both are needed: ``F = k s V``). A file that needs them and
      lacks them is a `DataError` that says so.
    * Then :func:`preprocess` (``baseline``, ``contact_point`` and ``preprocess_kw``).
    * ``on_error``: ``"raise"`` (a curve that cannot be loaded or preprocessed is a
      `DataError` for the file) or ``"keep"`` (it is returned as a :class:`FailedCurve`
      with the reason, and the other curves load: a force map with a few bad points).

    Raises:
        ImportError: afmformats is not installed and the file is not a JPK file
            (``pip install jaxcontact[afm]``).
        DataError: a file neither afmformats nor the JPK reader can read (unsupported,
            empty, truncated, corrupt; the message gives each reader's reason), unreadable
            data, an empty segment, NaN values, or a failed contact detection (the
            message names the file).
    """
    if on_error not in ("raise", "keep"):
        raise ValueError(f"on_error must be 'raise' or 'keep'; got {on_error!r}")
    path = pathlib.Path(path)
    jpk = path.suffix.lower() in JPK_SUFFIXES
    bruker = path.is_file() and sniff_bruker(path) == "force"
    try:
        import afmformats
    except ImportError as exc:  # pragma: no cover - depends on the environment
        if not (jpk or bruker):
            raise ImportError(
                "reading AFM files needs afmformats: pip install 'jaxcontact[afm]'"
            ) from exc
        afmformats = None
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    meta_override = {}
    if sensitivity is not None:
        s = float(sensitivity)
        if not (math.isfinite(s) and s > 0):
            raise ValueError(f"sensitivity must be finite and > 0 [m/V], got {sensitivity}")
        meta_override["sensitivity"] = s
        if spring_constant is not None:
            meta_override["spring constant"] = float(spring_constant)
    datasets = None
    refused = "afmformats is not installed"
    reader = "afmformats"
    if bruker:  # afmformats reads no Bruker files
        try:
            datasets = read_bruker(path, sensitivity=sensitivity)
        except ValueError as exc:
            raise DataError(f"{path}: Bruker NanoScope force file: {exc}") from None
        reader = "jaxcontact-bruker"
    elif afmformats is not None:
        afm_log = logging.getLogger("afmformats")
        level = afm_log.level
        afm_log.setLevel(logging.CRITICAL)  # its failed-recogniser tracebacks are not errors
        try:
            datasets = afmformats.load_data(path, modality=modality,
                                            meta_override=meta_override or None)
        except (KeyboardInterrupt, SystemExit, GeneratorExit):
            raise
        except BaseException as exc:  # afmformats' errors derive from BaseException
            hint = ""
            if type(exc).__name__ == "MissingMetaDataError":
                hint = ("; the file stores the deflection in volts: give spring_constant "
                        "[N/m] and sensitivity [m/V] (command line: --spring-constant, "
                        "--sensitivity)")
            refused = (f"afmformats cannot read it "
                       f"({type(exc).__name__}: {str(exc).replace(str(path), 'the file')})"
                       f"{hint}")
            if not jpk or hint:
                raise DataError(f"{path}: {refused}") from None
        finally:
            afm_log.setLevel(level)
        if datasets is not None and not datasets:
            raise DataError(f"{path}: afmformats found no curves in the file")
    if datasets is None:  # a JPK file afmformats refuses or cannot be asked about
        try:
            datasets = read_jpk(path, sensitivity=sensitivity,
                                spring_constant=spring_constant if sensitivity else None)
        except ValueError as exc:
            raise DataError(f"{path}: {refused}; the JPK reader cannot read it "
                            f"either ({exc})") from None
        reader = "jaxcontact-jpk"
    if reader != "afmformats" and modality is not None:
        # as afmformats: only the curves of that modality
        modes = {ds.modality for ds in datasets if isinstance(ds, JPKCurve)}
        datasets = [ds for ds in datasets
                    if not isinstance(ds, JPKCurve) or ds.modality == modality]
        if not any(isinstance(ds, JPKCurve) for ds in datasets):
            raise DataError(f"{path}: no {modality} curves in the file (its curves: "
                            f"{', '.join(sorted(modes)) or 'none readable'})")
    curves = []
    for n, ds in enumerate(datasets):
        try:
            curves.append(
                _afm_curve(ds, path, spring_constant, height_column, baseline,
                           contact_point, limits, preprocess_kw, sample_rate, reader)
            )
        except BaseException as exc:  # noqa: BLE001 - filtered by _curve_failure
            msg = _curve_failure(exc)
            if msg is None:
                raise
            if on_error == "keep":
                curves.append(FailedCurve(str(path), n, " ".join(msg.split()),
                                          _plain_metadata(ds)))
                continue
            where = f"{path}" if len(datasets) == 1 else f"{path} (curve {n})"
            raise DataError(f"{where}: {msg}") from None
    return curves


#: afmformats' format names (their beginnings) whose heights are the instrument's own
#: frame, one for every curve of a map: JPK's closed-loop height sensor or piezo, Asylum's
#: Z sensor (checked on the files of `tests/data`, `benchmarks/data`: the first sample's
#: height differs between a map's points, tens of micrometres on JPK maps). JPK files read
#: by :func:`fitting._io_jpk.read_jpk` count too.
ABSOLUTE_HEIGHT_FORMATS = ("JPK Instruments", "Asylum Research")

_READ_ERRORS = (KeyError, IndexError, OSError, EOFError, NotImplementedError,
                zipfile.BadZipFile, zlib.error)


def _curve_failure(exc: BaseException) -> str | None:
    """The reason a curve failed, for errors of the data and of reading them: `ValueError`
    (ours), the archive and lookup errors afmformats' lazy loaders raise when a curve's
    data are read, and afmformats' own errors (which derive from `BaseException`, not
    `Exception`); ``None`` for anything else (interrupts, programming errors such as a
    `TypeError`), which is raised as it is."""
    if isinstance(exc, ValueError):
        return str(exc)
    if isinstance(exc, _READ_ERRORS) or not isinstance(
            exc, (Exception, KeyboardInterrupt, SystemExit, GeneratorExit)):
        return f"{type(exc).__name__}: {exc}"
    return None


def _plain_metadata(ds) -> dict:
    """The curve's metadata as plain values: afmformats keeps some as lazy values
    (functions of the data, e.g. "z range"), evaluated here on access, so that a curve and
    its results can be pickled (sent between processes); a value that cannot be evaluated
    is left out."""
    try:
        meta = ds.metadata
        keys = list(meta.keys())
    except Exception:  # noqa: BLE001 - metadata of a broken curve are optional
        return {}
    out = {}
    for key in keys:
        try:
            out[key] = meta[key]
        except Exception:  # noqa: BLE001 - an optional value that cannot be computed
            continue
    return out


def _sample_time(meta, n: int, sample_rate) -> np.ndarray:
    """Time [s] of the samples of a file without a time column."""
    rate = meta.get("rate approach")
    has_rate = rate is not None and math.isfinite(float(rate)) and float(rate) > 0
    if sample_rate is not None:
        if has_rate:
            raise ValueError(f"sample_rate was given, but the file has its own sampling "
                             f"rate ({float(rate):g} Hz)")
        rate = float(sample_rate)
        if not (math.isfinite(rate) and rate > 0):
            raise ValueError(f"sample_rate must be finite and > 0 [Hz], got {sample_rate}")
    elif not has_rate:
        raise ValueError("the file has no time column and no sampling rate: give "
                         "sample_rate [Hz] (command line: --sample-rate)")
    return np.arange(n, dtype=np.float64) / float(rate)


def _afm_curve(ds, path, k_arg, height_column, baseline, contact_point, limits, pkw,
               sample_rate=None, reader="afmformats"):
    meta = _plain_metadata(ds)
    meta["reader"] = reader
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
        if sample_rate is not None:
            raise ValueError("sample_rate was given, but the file has a time column")
        time = np.asarray(ds["time"], dtype=np.float64)
    else:
        time = _sample_time(meta, len(h), sample_rate)

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
    native = isinstance(ds, JPKCurve)  # the JPK reader names every file segment
    ibw = _ibw_segments(path, len(force)) if len(present) == 1 and not native else None
    jpk = _jpk_segment_names(path, present) if len(present) > 1 and not native else None
    if native:
        seg, names = seg_raw, ds.segment_names
    elif ibw is not None:
        seg, names = ibw
    elif jpk is not None:
        seg, names = np.searchsorted(present, seg_raw), jpk
    elif mod == "force-distance" and len(present) == 1:
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
        if len(present) not in DEFAULT_SEGMENT_NAMES:
            raise ValueError(f"cannot name {len(present)} segments of modality {mod!r}")
        names = DEFAULT_SEGMENT_NAMES[len(present)]

    meta["height column"] = height_column
    if reader == "jaxcontact-jpk" or str(meta.get("format", "")).startswith(
            ABSOLUTE_HEIGHT_FORMATS):
        # the first sample's height [m] in the instrument's frame (decreasing toward the
        # sample), where the displacement starts (`Curve.surface_height`)
        meta["height at start"] = float(h[0])
    meta["spring constant (file)"] = k_file
    raw = Curve(
        time=time, displacement=h[0] - h, force=force, segment=seg, segment_names=names,
        spring_constant=k, source=str(path), metadata=meta, limits=limits,
    )
    if baseline in (None, "none") and contact_point in (None, "none") and k is None:
        return raw
    return preprocess(raw, baseline=baseline, contact_point=contact_point, **pkw)


_IBW_DIRECTION = {1.0: "approach", 0.0: "hold", -1.0: "retract"}


def _ibw_segments(path: pathlib.Path, n: int):
    """Segments of an Asylum ``.ibw`` force curve from its wave note, or ``None``.

    The note holds ``Indexes: 0,i1,...,n-1`` (segment ends, inclusive sample indices)
    and ``Direction: NaN,d1,...`` (one entry per boundary; ``d_j`` is the motion of the
    segment that ends at ``Indexes[j]``: 1 toward the sample, 0 dwell, -1 away).
    """
    if path.suffix != ".ibw":
        return None
    try:
        from igor2 import binarywave
    except ImportError:  # pragma: no cover - afmformats depends on igor2
        return None
    try:
        note = binarywave.load(path)["wave"]["note"]
    except Exception:  # noqa: BLE001 - unreadable note: fall back to the force maximum
        return None
    note = note.decode("latin-1") if isinstance(note, bytes) else str(note)
    fields = {}
    for line in note.replace("\\r", "\r").split("\r"):
        if ":" in line:
            key, val = line.split(":", 1)
            fields[key.strip()] = val.strip()
    try:
        ends = [int(float(x)) for x in fields["Indexes"].strip(",").split(",")]
        dirs = [float(x) for x in fields["Direction"].strip(",").split(",")]
    except (KeyError, ValueError):
        return None
    if len(ends) < 2 or len(dirs) != len(ends) or ends[0] != 0 or ends[-1] != n - 1:
        return None
    if any(b <= a for a, b in zip(ends[:-1], ends[1:], strict=True)):
        return None
    labels: list[str] = []
    for d in dirs[1:]:
        if d not in _IBW_DIRECTION:
            return None
        labels.append(_IBW_DIRECTION[d])
    if labels and labels[0] == "hold":
        labels[0] = "rest"
    seg = np.zeros(n, dtype=np.int64)
    names: list[str] = []
    start = 0
    for end, lab in zip(ends[1:], labels, strict=True):
        if not names or names[-1] != lab:
            names.append(lab)
        seg[start : end + 1] = len(names) - 1
        start = end + 1
    return seg, tuple(names)


def _jpk_segment_names(path: pathlib.Path, present) -> tuple[str, ...] | None:
    """Segment names of a single-curve ``.jpk-force`` file read by afmformats, from the
    styles in its segment headers (:func:`fitting._io_jpk.segment_kinds`)."""
    if path.suffix != ".jpk-force":
        return None

    key = "force-segment-header.settings.segment-settings.style="
    styles: list[str | None] = []
    try:
        with zipfile.ZipFile(path) as z:
            for j in present:
                text = z.read(f"segments/{int(j)}/segment-header.properties")
                styles.append(next(
                    (ln.split("=", 1)[1].strip()
                     for ln in text.decode("latin-1").splitlines() if ln.startswith(key)),
                    None,
                ))
        return segment_kinds(styles)
    except (OSError, KeyError, ValueError, zipfile.BadZipFile):
        return None
