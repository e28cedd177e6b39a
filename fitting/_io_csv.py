"""CSV / TSV / whitespace tables with a header row: :func:`load_csv`."""

from __future__ import annotations

import csv
import io
import math
import pathlib
import re
from collections.abc import Mapping, Sequence

import numpy as np

from jaxcontact._validate import plain

from ._curve import (
    DEFAULT_LIMITS,
    SEGMENT_ALIASES,
    Curve,
    DataError,
    Limits,
    runs_to_segments,
)
from ._preprocess import preprocess
from ._units import BASE_UNITS, ROLE_DIMENSION, parse_units, unit_factor

__all__ = ["load_csv"]

_ROLES = ("time", "displacement", "height", "force", "segment")
_ROLE_ALIASES: dict[str, tuple[str, ...]] = {
    "time": ("time", "t"),
    "displacement": ("displacement", "indentation", "delta", "depth", "disp", "d", "z"),
    "height": ("height",),
    "force": ("force", "f", "load"),
    "segment": ("segment", "seg", "segment_name", "phase"),
}


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
            if unit in BASE_UNITS or (sep != "/" and _is_quotient_unit(unit)):
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
        raise DataError(f"{path}: file is empty (no header and no data rows)")
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
        try:
            rows = [(no, [c.strip() for c in fields])
                    for (no, _), fields in zip(lines, reader, strict=True)]
        except (csv.Error, ValueError) as exc:
            raise DataError(f"{path}: not a readable table ({exc})") from None
    header = rows[0][1]
    if not any(re.search(r"[A-Za-z]", h) for h in header):
        raise DataError(
            f"{path}: line {rows[0][0]} has no column names; the first row must be a header "
            "such as 'time_s,displacement_m,force_N'"
        )
    data = rows[1:]
    if not data:
        raise DataError(f"{path}: no data rows after the header {header}")
    for no, fields in data:
        if len(fields) != len(header):
            raise DataError(
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
                raise DataError(
                    f"{path}: no column {name!r} (asked for {role}); the header has {header}"
                )
            chosen[role] = hits[0]
    for role in _ROLES:
        if role in chosen:
            continue
        hits = [i for i, (b, _) in enumerate(parsed) if b in _ROLE_ALIASES[role]]
        if len(hits) > 1:
            raise DataError(
                f"{path}: several columns could be the {role}: "
                f"{[header[i] for i in hits]}; choose with columns={{'{role}': ...}}"
            )
        if hits:
            chosen[role] = hits[0]
    if "displacement" in chosen and "height" in chosen and not (columns and "height" in columns):
        del chosen["height"]
    for role in ("time", "force"):
        if role not in chosen:
            raise DataError(
                f"{path}: no {role} column found; the header has {header}; name it e.g. "
                f"'{role}_{'s' if role == 'time' else 'N'}' or pass columns={{'{role}': ...}}"
            )
    if "displacement" not in chosen and "height" not in chosen:
        raise DataError(
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
            raise DataError(
                f"{path}: column {header_name!r}, data row {r + 1} (line {no}): cannot read "
                f"{s!r} as a number"
            ) from None
        if not math.isfinite(out[r]):
            raise DataError(
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
    **preprocess_kw,
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
        spring_constant: cantilever spring constant [N/m], stored on the curve (the
            compliant loading model of a fit uses it). Without preprocessing the
            displacement column is the tip indentation, as written; with ``baseline`` or
            ``contact_point`` it is read as the base (piezo) displacement and the tip
            correction ``− F/k`` is applied (see :func:`preprocess`).
        baseline: ``None``/``"none"`` (default: the force is taken as already
            baselined), ``"constant"`` or ``"linear"`` (line in time; see :func:`preprocess`).
        contact_point: ``None``/``"none"`` (default: the displacement is already the
            indentation), ``"detect"`` or ``"fit"`` (see :func:`preprocess`; a ``None``
            baseline then means ``"constant"``).
        limits: plausibility limits (see :class:`Limits`).
        **preprocess_kw: further options of :func:`preprocess` (``threshold``,
            ``min_run``, ``retract_baseline``, ...); only with ``baseline`` or
            ``contact_point`` (a table read as it is is not preprocessed).

    Raises:
        DataError: empty file, missing column, unparsable or NaN value (naming the
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
                raise DataError(f"{path}: column {hname!r}: {exc}") from None
            if hdim != ROLE_DIMENSION[role]:
                raise DataError(
                    f"{path}: column {hname!r} is the {role} but its unit {header_unit!r} "
                    f"is a {hdim}"
                )
            if unit is not None and unit_factor(unit)[1] != unit_factor(header_unit)[1]:
                raise DataError(
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
        raise DataError(
            f"{path}: column {header[chosen['time']]!r} is not strictly increasing at data "
            f"row {r + 1} (line {data[r][0]}): {plain(t[r])} s after {plain(t[r - 1])} s"
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

    try:
        curve = Curve(
            time=t, displacement=disp, force=values["force"], segment=seg,
            segment_names=names, spring_constant=spring_constant, source=str(path),
            limits=limits, metadata={"columns": {r: header[i] for r, i in chosen.items()}},
        )
    except DataError:
        raise
    except ValueError as exc:
        raise DataError(f"{path}: {exc}") from None
    baseline = None if baseline == "none" else baseline
    contact_point = None if contact_point == "none" else contact_point
    given = sorted(k for k, v in preprocess_kw.items() if v is not None)
    if baseline is not None or contact_point is not None:
        curve = preprocess(
            curve, baseline=baseline or ("constant" if contact_point else None),
            contact_point=contact_point, **preprocess_kw,
        )
    elif given:
        raise ValueError(f"{', '.join(given)}: apply when the table is preprocessed (give "
                         "baseline= or contact_point=); without them it is read as "
                         "indentation and force as they are")
    return curve


def _parse_segment_column(path, hname, raw, data, segment_names):
    ints = []
    for r, s in enumerate(raw):
        try:
            ints.append(int(float(s)))
        except ValueError:
            break
        if not s or float(s) % 1:
            raise DataError(
                f"{path}: column {hname!r}, data row {r + 1} (line {data[r][0]}): "
                f"segment {s!r} is not an integer"
            )
    else:
        seg = np.asarray(ints)
        if np.any(np.diff(seg) < 0):
            r = int(np.flatnonzero(np.diff(seg) < 0)[0]) + 1
            raise DataError(
                f"{path}: column {hname!r} decreases at data row {r + 1} (line "
                f"{data[r][0]}); segments must be numbered in order"
            )
        present = np.unique(seg)
        seg = np.searchsorted(present, seg)  # compact numbering (empty segments dropped)
        if segment_names is not None:
            segment_names = tuple(segment_names)
            if len(segment_names) != len(present):
                raise DataError(
                    f"{path}: {len(present)} segments in column {hname!r} but "
                    f"{len(segment_names)} segment_names"
                )
        return seg, segment_names
    labels = []
    for r, s in enumerate(raw):
        key = _norm(s)
        if key not in SEGMENT_ALIASES:
            raise DataError(
                f"{path}: column {hname!r}, data row {r + 1} (line {data[r][0]}): unknown "
                f"segment name {s!r}; use approach, hold, retract or rest"
            )
        labels.append(SEGMENT_ALIASES[key])
    return runs_to_segments(labels)
