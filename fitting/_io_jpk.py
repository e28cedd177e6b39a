"""JPK Instruments files read without afmformats: :func:`read_jpk`.

afmformats (0.18.7) reads a JPK file only when its curves have one of three segment
layouts: extend–retract, extend–constant-force pause–retract, and
pause–extend–constant-height pause–retract. Every other layout (an extend–pause–retract
curve with a constant-height pause, as newer JPK software writes for force maps with a
dwell; a single segment; five or more segments) makes its recogniser say no, and
``afmformats.load_data`` raises "Could not determine file format recipe". This module
reads the files' documented structure directly; :func:`fitting.load_afm` uses it when
afmformats refuses a JPK file or is not installed.

The structure (a zip archive of Java property files and big-endian binary channels):

* ``header.properties``: the file (``jpk-data-file``, ``type`` = ``force-scan-series``
  for one curve, ``force-scan-map``/``quantitative-imaging-map`` for maps; the grid in
  ``<type>.position-pattern.grid.*``: ``ilength``, ``jlength`` [points], ``ulength``,
  ``vlength`` [m], ``xcenter``, ``ycenter`` [m]).
* ``shared-data/header.properties`` (not in older single-curve files): numbered blocks
  ``lcd-info.K.*`` (a channel's encoding and conversions) and
  ``force-segment-header-info.K.*`` (a segment's settings) that the segment headers
  reference: a key ``A.B.*=K`` in a segment header stands for every shared key
  ``B.K.rest`` as ``A.rest``.
* One curve: ``segments/M/``; a map: ``index/N/header.properties`` (the point's position
  ``<series>.header.position.x``/``.y`` [m]) and ``index/N/segments/M/``.
* ``segment-header.properties`` of a segment: ``force-segment-header.num-points``,
  ``.duration`` [s], ``.settings.style`` (``extend``, ``retract``, ``pause``) and
  ``.settings.segment-settings.type`` (``constant-height-pause``,
  ``constant-force-pause``, ...); per channel ``channel.C.data.file.name`` (relative to the
  segment folder), the data type (``short``/``integer``/``long`` with an integer encoder
  ``channel.C[.data].encoder.type`` and its linear ``scaling.multiplier``/``.offset``
  to the base unit, or ``float``/``double`` stored in the base unit) and the conversion
  set ``channel.C.conversion-set``: ``conversions.base`` (the encoder's slot) and for
  each slot ``conversion.S.base-calibration-slot`` with a linear
  ``scaling.multiplier``/``.offset`` from that slot. A value in slot S is reached by
  applying the chain from the base slot up to S.

Columns, as afmformats names them: ``force`` [N] (``vDeflection``, slot ``force``: volts →
``distance`` by the sensitivity [m/V], → ``force`` by the spring constant [N/m]),
``height (measured)`` [m] (``strainGaugeHeight``, ``capacitiveSensorHeight`` or
``measuredHeight``, slot ``nominal``), ``height (piezo)`` [m] (``height`` or
``head-height``, slot ``calibrated``), ``segment`` (the file's segment number) and
``time`` [s] (uniform within a segment, from its ``duration``, segments one after the
other from 0). Heights decrease toward the sample.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
import re
import zipfile
import zlib
from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = ["JPK_SUFFIXES", "JPKCurve", "read_jpk", "parse_properties", "segment_kinds"]

JPK_SUFFIXES = (".jpk-force", ".jpk-force-map", ".jpk-qi-data", ".jpk-qi-series")
"""File suffixes of JPK force curves and maps (zip archives) that :func:`read_jpk` reads."""

_COLUMNS = {  # column: (JPK channels in order of preference, slot, unit)
    "force": (("vDeflection",), "force", "N"),
    "height (measured)": (("strainGaugeHeight", "capacitiveSensorHeight", "measuredHeight"),
                          "nominal", "m"),
    "height (piezo)": (("height", "head-height"), "calibrated", "m"),
}
_ENCODERS = {"signedshort": ">i2", "unsignedshort": ">u2", "signedinteger": ">i4",
             "unsignedinteger": ">u4", "signedlong": ">i8"}
_FLOATS = {"float": ">f4", "float-data": ">f4", "double": ">f8", "double-data": ">f8"}
_SERIES = ("force-scan-map", "force-scan-series", "quantitative-imaging-map",
           "quantitative-imaging-series")
_KIND_OF_STYLE = {"extend": "approach", "retract": "retract"}


@dataclasses.dataclass(frozen=True)
class JPKCurve:
    """One curve of a JPK file, shaped like an afmformats dataset for
    :func:`fitting.load_afm`: ``curve[column]`` gives a column (see the module docstring),
    ``columns`` their names, ``metadata`` a dict (afmformats' keys: ``spring constant``
    [N/m], ``sensitivity`` [m/V], ``imaging mode``, ``grid index x``/``y``, ``grid shape
    x``/``y``, ``grid size x``/``y`` [m], ``grid center x``/``y`` [m], ``position
    x``/``y`` [m], ``rate approach``/``retract`` [Hz], ``duration`` [s], ``point count``,
    ...), ``segment_names`` one of :data:`fitting.SEGMENT_KINDS` per file segment
    (:func:`segment_kinds`) and ``styles`` the file's segment styles."""

    data: Mapping[str, np.ndarray]
    metadata: dict[str, Any]
    segment_names: tuple[str, ...]
    styles: tuple[str, ...]

    @property
    def columns(self) -> list[str]:
        return list(self.data)

    @property
    def modality(self) -> str:
        return self.metadata["imaging mode"]

    def __getitem__(self, column: str) -> np.ndarray:
        return self.data[column]


@dataclasses.dataclass(frozen=True)
class _FailedJPKCurve:
    """A curve whose reading failed: any use of it raises the reason (a `ValueError`), so
    that :func:`fitting.load_afm` reports it as that curve's failure."""

    reason: str
    metadata_: dict[str, Any]

    @property
    def metadata(self):
        return self.metadata_

    def __getattr__(self, name):
        raise ValueError(self.reason)

    def __getitem__(self, column):
        raise ValueError(self.reason)


# --- Java property files ------------------------------------------------------------------

_ESCAPES = {"t": "\t", "n": "\n", "r": "\r", "f": "\f"}
_ESCAPE_RE = re.compile(r"\\(u[0-9a-fA-F]{4}|.)", re.S)


def _unescape(s: str) -> str:
    def sub(m):
        e = m.group(1)
        if len(e) == 5 and e[0] == "u":
            return chr(int(e[1:], 16))
        return _ESCAPES.get(e, e)

    return _ESCAPE_RE.sub(sub, s)


def parse_properties(text: str) -> dict[str, str]:
    """A Java ``.properties`` text as a dict (``key=value``, ``key: value`` or ``key
    value``; ``#``/``!`` comments; a line ending in an odd number of backslashes continues
    on the next; ``\\:``, ``\\=``, ``\\uXXXX``, ``\\t`` ... escapes)."""
    out: dict[str, str] = {}
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i].lstrip()
        i += 1
        if not line or line[0] in "#!":
            continue
        while (len(line) - len(line.rstrip("\\"))) % 2 == 1 and i < len(lines):
            line = line[:-1] + lines[i].lstrip()
            i += 1
        j, n = 0, len(line)
        while j < n and line[j] not in "=: \t\f":
            j += 2 if line[j] == "\\" else 1
        key = line[:j]
        rest = line[j:].lstrip(" \t\f")
        if rest[:1] in ("=", ":"):
            rest = rest[1:].lstrip(" \t\f")
        out[_unescape(key)] = _unescape(rest)
    return out


# --- segments ---------------------------------------------------------------------------------


def segment_kinds(styles) -> tuple[str, ...]:
    """:data:`fitting.SEGMENT_KINDS` names for a curve's JPK segment styles.

    ``extend`` → ``approach``; ``retract`` → ``retract``; ``pause`` → ``rest`` before the
    first extend and after the last retract (no contact), ``hold`` in between (a dwell in
    contact at constant height or force). Any other style is a `ValueError` naming it.
    """
    styles = [str(s) for s in styles]
    for j, s in enumerate(styles):
        if s not in ("extend", "retract", "pause"):
            raise ValueError(f"segment {j} has the style {s!r}; JPK curves are read with "
                             "extend, retract and pause segments")
    first_extend = styles.index("extend") if "extend" in styles else len(styles)
    last_retract = (len(styles) - 1 - styles[::-1].index("retract") if "retract" in styles
                    else -1)
    names = []
    for j, s in enumerate(styles):
        if s != "pause":
            names.append(_KIND_OF_STYLE[s])
        elif j < first_extend or (last_retract >= 0 and j > last_retract):
            names.append("rest")
        else:
            names.append("hold")
    return tuple(names)


def _imaging_mode(names, pause_types) -> str:
    """afmformats' modality names: a hold at constant force → ``creep-compliance``, at
    constant height → ``stress-relaxation``, none → ``force-distance``."""
    for nm, pt in zip(names, pause_types, strict=True):
        if nm == "hold":
            if pt == "constant-force-pause":
                return "creep-compliance"
            if pt == "constant-height-pause":
                return "stress-relaxation"
    return "force-distance"


# --- the archive ------------------------------------------------------------------------------


def _float(props, key, what):
    try:
        v = float(props[key])
    except KeyError:
        raise ValueError(f"{what}: the file has no {key!r}") from None
    except ValueError:
        raise ValueError(f"{what}: {key!r} = {props[key]!r} is not a number") from None
    return v


def _first(props, keys):
    for k in keys:
        if k in props:
            return props[k]
    return None


class _Archive:
    """An open JPK zip archive with its general and shared properties."""

    def __init__(self, z: zipfile.ZipFile):
        self.z = z
        self.names = set(z.namelist())
        if "header.properties" not in self.names:
            raise ValueError("no header.properties in the archive (not a JPK data file)")
        self.general = self.properties("header.properties")
        shared = (self.properties("shared-data/header.properties")
                  if "shared-data/header.properties" in self.names else {})
        self.shared: dict[tuple[str, str], dict[str, str]] = {}
        for key, val in shared.items():
            parts = key.split(".", 2)
            if len(parts) == 3:
                self.shared.setdefault((parts[0], parts[1]), {})[parts[2]] = val

    def properties(self, name: str) -> dict[str, str]:
        return parse_properties(self.z.read(name).decode("latin-1"))

    def resolve(self, props: dict[str, str]) -> dict[str, str]:
        """``props`` with the shared blocks its ``A.B.*=K`` keys reference substituted."""
        out = dict(props)
        for key, val in props.items():
            if not key.endswith(".*"):
                continue
            head, mediator = key[:-2].rsplit(".", 1) if "." in key[:-2] else ("", key[:-2])
            block = self.shared.get((mediator, val.strip()))
            if block is None:
                raise ValueError(f"{key}={val} refers to the shared block {mediator}.{val}, "
                                 "which shared-data/header.properties does not have")
            for rest, v in block.items():
                out[f"{head}.{rest}" if head else rest] = v
        return out

    def curve_dirs(self) -> list[tuple[int, str]]:
        """(index number, folder) of every curve, in index order."""
        if any(n.startswith("segments/") for n in self.names):
            return [(0, "")]
        idx = sorted({int(m.group(1)) for n in self.names
                      if (m := re.match(r"index/(\d+)/", n))})
        if not idx:
            raise ValueError("neither segments/ nor index/N/ folders (not a JPK force file)")
        return [(i, f"index/{i}/") for i in idx]


def _segments(arc: _Archive, folder: str) -> list[str]:
    found = {int(m.group(1)) for n in arc.names
             if (m := re.match(re.escape(folder) + r"segments/(\d+)/segment-header\.properties$",
                               n))}
    if not found:
        raise ValueError(f"no segments in {folder or 'the file'}")
    count = max(found) + 1
    missing = sorted(set(range(count)) - found)
    if missing:
        raise ValueError(f"segment {missing[0]} of {folder or 'the file'} has no "
                         "segment-header.properties")
    return [f"{folder}segments/{m}/" for m in range(count)]


def _channel(arc: _Archive, props, seg_dir: str, name: str, slot: str, unit: str,
             override: Mapping[str, tuple[float, float]] | None = None) -> np.ndarray:
    """One channel of one segment in ``slot`` [``unit``]; ``override``: slot →
    (multiplier, offset) replacing the file's conversion to that slot."""
    c = f"channel.{name}."
    what = f"{seg_dir}channel {name}"
    fname = props.get(c + "data.file.name")
    if fname is None:
        raise ValueError(f"{what}: no data file named (channel.{name}.data.file.name)")
    path = seg_dir + fname
    if path not in arc.names:
        raise ValueError(f"{what}: the data file {path} is missing")
    raw = arc.z.read(path)
    dtype = _first(props, (c + "data.type", c + "type"))
    encoder = _first(props, (c + "data.encoder.type", c + "encoder.type"))
    if encoder is not None:
        if encoder not in _ENCODERS:
            raise ValueError(f"{what}: unknown encoder {encoder!r} (read: {sorted(_ENCODERS)})")
        fmt = np.dtype(_ENCODERS[encoder])
        pre = c + ("data.encoder.scaling." if c + "data.encoder.type" in props
                   else "encoder.scaling.")
        mult = _float(props, pre + "multiplier", what)
        off = _float(props, pre + "offset", what)
    elif dtype in _FLOATS:
        fmt, mult, off = np.dtype(_FLOATS[dtype]), 1.0, 0.0
    else:
        raise ValueError(f"{what}: data type {dtype!r} without an integer encoder is not "
                         f"read (read: integer types with an encoder, {sorted(_FLOATS)})")
    if len(raw) % fmt.itemsize:
        raise ValueError(f"{what}: {len(raw)} bytes is not a whole number of "
                         f"{fmt.itemsize}-byte values (truncated?)")
    values = np.frombuffer(raw, dtype=fmt).astype(np.float64) * mult + off
    n_decl = props.get(c + "data.num-points")
    if n_decl is not None and int(float(n_decl)) != len(values):
        raise ValueError(f"{what}: {len(values)} values, the header declares {n_decl}")

    cs = c + "conversion-set."
    base = props.get(cs + "conversions.base")
    if base is None:
        raise ValueError(f"{what}: no conversion set (channel.{name}.conversion-set)")
    chain = []
    cur = slot
    while cur != base:
        if override and cur in override:
            mult, off = override[cur]
        else:
            pre = f"{cs}conversion.{cur}."
            if props.get(pre + "defined", "true") == "false" or pre + "scaling.multiplier" \
                    not in props:
                hint = ("; the file stores the deflection in volts: give spring_constant "
                        "[N/m] and sensitivity [m/V] (command line: --spring-constant, "
                        "--sensitivity)") if name == "vDeflection" else ""
                raise ValueError(f"{what}: no {cur!r} calibration in the file{hint}")
            style = props.get(pre + "scaling.style", "offsetmultiplier")
            kind = props.get(pre + "scaling.type", "linear")
            if (style, kind) != ("offsetmultiplier", "linear"):
                raise ValueError(f"{what}: conversion {cur!r} is {kind}/{style}; only "
                                 "linear offset-multiplier conversions are read")
            mult = _float(props, pre + "scaling.multiplier", what)
            off = _float(props, pre + "scaling.offset", what)
        chain.append((mult, off))
        nxt = props.get(f"{cs}conversion.{cur}.base-calibration-slot")
        if nxt is None or len(chain) > 16:
            raise ValueError(f"{what}: the conversion chain from {slot!r} does not reach the "
                             f"base slot {base!r}")
        cur = nxt
    for mult, off in reversed(chain):
        values = values * mult + off
    got = (_first(props, (f"{cs}conversion.{slot}.scaling.unit.unit",
                          f"{cs}conversion.{slot}.scaling.unit"))
           if slot != base else
           _first(props, (c + "data.encoder.scaling.unit.unit", c + "encoder.scaling.unit.unit",
                          c + "unit.unit")))
    if override and slot in override:
        got = unit
    if got != unit:
        raise ValueError(f"{what}: slot {slot!r} is in {got!r}, expected {unit!r}")
    return values


def _grid_index(pos, size, center, shape):
    """The grid cell (0 … shape-1) whose centre is nearest to ``pos`` [m] on a grid of
    ``shape`` cells spanning ``size`` [m] around ``center`` [m]."""
    if not all(map(math.isfinite, (pos, size, center))) or shape < 1:
        return None
    step = size / shape
    if step == 0:
        return 0
    k = math.floor((pos - (center - size / 2)) / step)
    return int(min(max(k, 0), shape - 1))


def _read_curve(arc: _Archive, enum: int, folder: str,
                override: Mapping[str, tuple[float, float]]) -> JPKCurve:
    index_props = arc.properties(folder + "header.properties") if folder else {}
    seg_dirs = _segments(arc, folder)
    cols: dict[str, list[np.ndarray]] = {c: [] for c in _COLUMNS}
    times, segs, styles, pause_types, props_of = [], [], [], [], []
    t0 = 0.0
    for m, sd in enumerate(seg_dirs):
        props = {**index_props, **arc.resolve(arc.properties(sd + "segment-header.properties")),
                 **arc.general}
        props_of.append(props)
        what = f"{sd}segment-header.properties"
        n = int(_float(props, "force-segment-header.num-points", what))
        duration = _float(props, "force-segment-header.duration", what)
        styles.append(props.get("force-segment-header.settings.style",
                                props.get("force-segment-header.settings.segment-settings.style",
                                          "?")))
        pause_types.append(props.get("force-segment-header.settings.segment-settings.type"))
        channels = props.get("channels.list", "").split()
        for col, (names, slot, unit) in _COLUMNS.items():
            name = next((c for c in names if c in channels
                         or f"channel.{c}.data.file.name" in props), None)
            if name is None:
                if col == "height (measured)":
                    continue  # optional: not every instrument has a height sensor
                raise ValueError(f"{sd}: no {' or '.join(names)} channel for {col!r}; the "
                                 f"segment has {channels}")
            v = _channel(arc, props, sd, name, slot, unit,
                         override if col == "force" else None)
            if len(v) != n:
                raise ValueError(f"{sd}channel {name}: {len(v)} values, the segment has {n}")
            cols[col].append(v)
        times.append(t0 + np.arange(n) * (duration / n if n else 0.0))
        t0 += duration
        segs.append(np.full(n, m, dtype=np.int64))
    names = segment_kinds(styles)
    data = {col: np.concatenate(v) for col, v in cols.items()
            if v and len(v) == len(seg_dirs)}
    data["segment"] = np.concatenate(segs)
    data["time"] = np.concatenate(times)
    meta = _metadata(props_of, names, pause_types, enum, override)
    meta["imaging mode"] = _imaging_mode(names, pause_types)
    return JPKCurve(data=data, metadata=meta, segment_names=names, styles=tuple(styles))


def _metadata(props_of, names, pause_types, enum, override) -> dict[str, Any]:
    first = props_of[0]
    vd = "channel.vDeflection.conversion-set.conversion."
    meta: dict[str, Any] = {"software": "JPK", "enum": int(enum)}
    for key, slot in (("sensitivity", "distance"), ("spring constant", "force")):
        if slot in override:
            meta[key] = override[slot][0]
        elif vd + slot + ".scaling.multiplier" in first:
            meta[key] = float(first[vd + slot + ".scaling.multiplier"])
    meta["duration"] = sum(float(p["force-segment-header.duration"]) for p in props_of)
    meta["point count"] = sum(int(float(p["force-segment-header.num-points"]))
                              for p in props_of)
    for p, nm in zip(props_of, names, strict=True):
        if nm in ("approach", "retract") and f"rate {nm}" not in meta:
            d = float(p["force-segment-header.duration"])
            n = int(float(p["force-segment-header.num-points"]))
            if d > 0:
                meta[f"rate {nm}"] = n / d
        if nm == "approach" and "time stamp" not in meta:
            stamp = p.get("force-segment-header.time-stamp")
            if stamp:
                meta["time stamp"] = stamp
    for s in _SERIES:
        g = f"{s}.position-pattern.grid."
        for ax, (shape, size, center) in {"x": ("ilength", "ulength", "xcenter"),
                                          "y": ("jlength", "vlength", "ycenter")}.items():
            if g + shape in first:
                meta[f"grid shape {ax}"] = int(float(first[g + shape]))
            if g + size in first:
                meta[f"grid size {ax}"] = float(first[g + size])
            if g + center in first:
                meta[f"grid center {ax}"] = float(first[g + center])
        for ax in ("x", "y"):
            if f"{s}.header.position.{ax}" in first and f"position {ax}" not in meta:
                meta[f"position {ax}"] = float(first[f"{s}.header.position.{ax}"])
        for key, field in (("instrument", "instrument"),
                           ("software version", "source-software")):
            if f"{s}.description.{field}" in first and key not in meta:
                meta[key] = first[f"{s}.description.{field}"]
    for ax in ("x", "y"):
        try:
            k = _grid_index(meta[f"position {ax}"], meta[f"grid size {ax}"],
                            meta[f"grid center {ax}"], meta[f"grid shape {ax}"])
        except KeyError:
            continue
        if k is not None:
            meta[f"grid index {ax}"] = k
    meta["segment pause types"] = tuple(pause_types)
    return meta


def read_jpk(path, *, sensitivity: float | None = None, spring_constant: float | None = None
             ) -> list[JPKCurve | _FailedJPKCurve]:
    """Read every curve of a JPK force file or map (``.jpk-force``, ``.jpk-force-map``,
    ``.jpk-qi-data``, ``.jpk-qi-series``) from its zip archive.

    **Arguments:**

    - `path`: the file.
    - `sensitivity` [m/V]: replaces the file's deflection sensitivity (the ``distance``
      conversion of ``vDeflection``); with it, `spring_constant` [N/m] replaces the
      file's ``force`` conversion (as afmformats' ``meta_override`` does).

    **Returns:** one :class:`JPKCurve` per curve (index order); a curve that cannot be read
    is an object that raises its reason (`ValueError`) when used, so that one bad point
    of a map does not stop the others.

    **Raises:** `ValueError` for a file that is not a readable JPK archive (not a zip,
    truncated, no ``header.properties``, no curves); the message says why.
    """
    override: dict[str, tuple[float, float]] = {}
    if sensitivity is not None:
        override["distance"] = (float(sensitivity), 0.0)
        if spring_constant is not None:
            override["force"] = (float(spring_constant), 0.0)
    path = pathlib.Path(path)
    try:
        z = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError) as exc:
        raise ValueError(f"not a JPK zip archive ({type(exc).__name__}: {exc})") from None
    with z:
        try:
            arc = _Archive(z)
            dirs = arc.curve_dirs()
        except (zipfile.BadZipFile, OSError, EOFError, KeyError) as exc:
            raise ValueError(f"unreadable archive ({type(exc).__name__}: {exc})") from None
        curves: list[JPKCurve | _FailedJPKCurve] = []
        for enum, folder in dirs:
            try:
                curves.append(_read_curve(arc, enum, folder, override))
            except (ValueError, KeyError, zipfile.BadZipFile, OSError, EOFError,
                    zlib.error) as exc:
                reason = str(exc) if isinstance(exc, ValueError) else \
                    f"{type(exc).__name__}: {exc}"
                curves.append(_FailedJPKCurve(reason, {"enum": enum}))
    return curves
