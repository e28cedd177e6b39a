"""Reader dispatch: :func:`load_curve`."""

from __future__ import annotations

import pathlib

from ._curve import Curve, DataError
from ._io_afm import FailedCurve, load_afm
from ._io_bruker import BRUKER_SUFFIXES, is_bruker_suffix, sniff_bruker
from ._io_csv import load_csv
from ._io_jpk import JPK_SUFFIXES

__all__ = ["load_curve", "TABLE_SUFFIXES", "supported_formats"]


TABLE_SUFFIXES = (".csv", ".tsv", ".txt", ".dat")
"""Suffixes read as tables by :func:`load_csv` unless an afmformats recogniser claims
the file (e.g. an Optics11 Chiaro or NT-MDT ``.txt`` export)."""


def _afm_recipes(suffix: str) -> list:
    try:
        import afmformats.formats as afm_formats
    except ImportError:  # pragma: no cover - depends on the environment
        return []
    return list(afm_formats.formats_by_suffix.get(suffix, []))


def supported_formats() -> str:
    """A one-line description of the readable file types (extensions and formats)."""
    parts = [f"tables {' '.join(TABLE_SUFFIXES)} (header row; see load_csv)",
             f"{' '.join(JPK_SUFFIXES)} (JPK Instruments force curves and maps, any layout "
             "of extend, retract and pause segments; through afmformats when it reads "
             "them, else the built-in JPK reader)",
             f"{' '.join(BRUKER_SUFFIXES[:1])} .000 .001 ... (Bruker NanoScope force curves "
             "and force volumes, built-in reader; not PeakForce capture .pfc)"]
    try:
        import afmformats.formats as afm_formats
    except ImportError:  # pragma: no cover - depends on the environment
        return "; ".join(parts) + "; other instrument files need afmformats"
    for r in afm_formats.formats_available:
        if r.suffix not in JPK_SUFFIXES:
            parts.append(f"{r.suffix} ({r.maker}, {r.descr})")
    return "; ".join(parts)


def _claimed_by_afmformats(path: pathlib.Path) -> bool:
    """Whether an afmformats recogniser with a content check accepts ``path``."""
    for rec in _afm_recipes(path.suffix):
        if "detect" not in rec.recipe:
            continue
        try:
            if rec.detect(path):
                return True
        except (KeyboardInterrupt, SystemExit, GeneratorExit):
            raise
        except BaseException:  # noqa: BLE001, S112 - a recogniser that fails says "no"
            continue
    return False


_TABLE_ONLY = ("columns", "units", "delimiter", "segment_names")
_AFM_ONLY = ("sensitivity", "sample_rate")


def _afm_options(path: pathlib.Path, kw: dict) -> dict:
    """``kw`` without table-only options left at ``None``; others are an error."""
    bad = [k for k in _TABLE_ONLY if kw.get(k) is not None]
    if bad:
        raise ValueError(
            f"{path}: is an instrument file read through afmformats; the table options "
            f"{bad} do not apply"
        )
    return {k: v for k, v in kw.items() if k not in _TABLE_ONLY}


def load_curve(path, *, format: str | None = None, on_error: str = "raise", **kw
               ) -> list[Curve | FailedCurve]:
    """Load the curves of one file, choosing the reader from the suffix and content.

    **Arguments:**

    - `path`: the file.
    - `format`: ``None`` (choose), ``"csv"`` (:func:`load_csv`) or ``"afm"``
      (:func:`load_afm`, through afmformats; JPK files it refuses through the built-in
      JPK reader).
    - `on_error`: for an instrument file with several curves (force map, QI series):
      ``"raise"`` (one bad curve is an error for the file) or ``"keep"`` (it is returned
      as a :class:`FailedCurve` with its reason; see :func:`load_afm`). A table holds
      one curve; its errors are raised.
    - `**kw`: passed to the chosen reader (e.g. ``baseline``, ``contact_point``,
      ``units``, ``spring_constant``; ``sensitivity`` and ``sample_rate`` for instrument
      files that lack them, see :func:`load_afm`).

    The choice for ``format=None``: a table suffix (``.csv``, ``.tsv``, ``.txt``,
    ``.dat``) goes to afmformats when one of its recognisers that inspects the content
    accepts the file (Optics11 Chiaro and NT-MDT ``.txt`` exports, afmformats' own
    exports), else to :func:`load_csv`; if the table reader fails and afmformats has a
    reader for that suffix without a content check (AFM Workshop ``.csv``), that reader
    is tried before the table error is raised. Any other suffix afmformats knows
    (``.jpk-force``, ``.jpk-force-map``, ``.jpk-qi-data``, ``.ibw``, ``.h5``, ...) and the
    JPK suffixes (also without afmformats) go to :func:`load_afm`.

    **Returns:**

    A list of :class:`Curve` (one per curve in the file; a table holds one), with
    :class:`FailedCurve` records in place of bad curves for ``on_error="keep"``.

    **Raises:**

    - `FileNotFoundError`: no such file.
    - `DataError`: a file nothing reads (the message lists the supported extensions and
      formats), or an empty, truncated or corrupt file (naming the file and the reason).
    """
    path = pathlib.Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    if format not in (None, "csv", "afm"):
        raise ValueError(f"format must be 'csv', 'afm' or None, got {format!r}")
    if on_error not in ("raise", "keep"):
        raise ValueError(f"on_error must be 'raise' or 'keep'; got {on_error!r}")
    if format == "csv":
        return [load_csv(path, **kw)]
    if format == "afm":
        return load_afm(path, on_error=on_error, **kw)
    if path.stat().st_size == 0:
        raise DataError(f"{path}: the file is empty")
    suffix = path.suffix.lower()
    if suffix in TABLE_SUFFIXES:
        if _claimed_by_afmformats(path):
            return load_afm(path, on_error=on_error, **_afm_options(path, kw))
        table_kw = {k: v for k, v in kw.items() if k not in _AFM_ONLY}
        try:
            table = load_csv(path, **table_kw)
            given = [k for k in _AFM_ONLY if kw.get(k) is not None]
            if given:
                raise ValueError(f"{path}: is read as a table (time, displacement and "
                                 f"force columns); {', '.join(given)} apply to instrument "
                                 "files only")
            return [table]
        except DataError as table_error:
            # table options given: the caller reads a table, and its error is the answer
            # (not "an instrument file read through afmformats")
            tabled = any(kw.get(k) is not None for k in _TABLE_ONLY)
            if not tabled and any("detect" not in r.recipe
                                  for r in _afm_recipes(path.suffix)):
                try:
                    return load_afm(path, on_error=on_error, **_afm_options(path, kw))
                except DataError as afm_error:
                    # both readers failed: say why each did
                    t = str(table_error).removeprefix(f"{path}: ")
                    a = str(afm_error).removeprefix(f"{path}: ")
                    raise DataError(f"{path}: not a table ({t}); as an instrument file "
                                    f"read by afmformats: {a}") from None
            raise table_error from None
    if is_bruker_suffix(path):
        kind = sniff_bruker(path)
        if kind == "force":
            return load_afm(path, on_error=on_error, **_afm_options(path, kw))
        what = ("a NanoScope file but not a force file (no \\*Force file list: an image?)"
                if kind == "other" else "not a Bruker NanoScope force file (it does not "
                "start with \\*Force file list)")
        raise DataError(f"{path}: {what}; the {path.suffix!r} suffix is read as Bruker "
                        f"force curves and volumes only; supported: {supported_formats()}")
    if _afm_recipes(path.suffix) or suffix in JPK_SUFFIXES:
        return load_afm(path, on_error=on_error, **kw)
    raise DataError(
        f"{path}: unsupported file type {path.suffix or '(no suffix)'!r}; supported: "
        f"{supported_formats()}"
    )
