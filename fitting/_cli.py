"""Command line: ``jaxcontact fit FILE [FILE ...] --radius M --out DIR``.

`add_fit_arguments(parser)` adds the options to an argparse (sub)parser; `run_fit(args)`
runs the fit and returns the exit code; `load_inputs(args)` is its input stage.

Instrument files (anything but ``.csv``, ``.tsv``, ``.txt``, ``.dat``) are read with
:func:`fitting.load_afm`, which takes the segments, the units and the spring constant from
the file (the tip position is ``height − F/k``). ``--spring-constant`` given with an
instrument file overrides the file's value (the force is rescaled by ``k/k_file``, since
the instrument measured the deflection) and selects the compliant loading model.

All input is validated and the fit done before anything is written; the report goes to a
temporary folder beside ``DIR`` and is moved into place at the end, so a failed run writes
no files. JAX's persistent compilation cache
(``~/.cache/jaxcontact/jax``, or ``$JAXCONTACT_CACHE``) spares a second run the compile.
"""

from __future__ import annotations

import argparse
import math
import os
import pathlib
import shutil
import sys
import tempfile

__all__ = ["add_fit_arguments", "load_inputs", "run_fit"]


def add_fit_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the ``fit`` options to `parser`."""
    parser.add_argument("files", nargs="+", metavar="FILE",
                        help="curves: CSV (time_s,displacement_m,force_N; extra columns "
                             "ignored) or AFM instrument files (read with afmformats)")
    parser.add_argument("--radius", type=float, required=True, metavar="M",
                        help="indenter radius of curvature [m] (parabolic profile)")
    parser.add_argument("--model", choices=("relaxed", "history"), default="relaxed",
                        help="relaxed-start retract model or full approach-hold-lift history")
    parser.add_argument("--rheology", default="standard", metavar="standard|prony:N",
                        help="standard model (G0, G1, eta1) or Prony series with N arms")
    parser.add_argument("--spring-constant", type=float, default=None, metavar="N_M",
                        help="cantilever stiffness [N/m]: compliant loading (history model); "
                             "overrides the spring constant of an instrument file")
    parser.add_argument("--cells", type=int, default=32, metavar="N",
                        help="foundation grid cells of the history model (default 32)")
    parser.add_argument("--units", default=None, metavar="ROLE=UNIT,...",
                        help="units of CSV columns without units, e.g. "
                             "'displacement=nm,force=nN'")
    parser.add_argument("--starts", type=int, default=4, help="number of starts (vmapped)")
    parser.add_argument("--max-samples", type=int, default=None,
                        help="resample each segment to at most this many samples")
    parser.add_argument("--no-figure", action="store_true", help="skip fit.png")
    parser.add_argument("--quiet", action="store_true", help="no progress display")
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
    return parser


def _error(msg: str) -> int:
    print(f"jaxcontact fit: error: {msg}", file=sys.stderr)
    return 2


def _enable_cache():
    import jax

    cache = os.environ.get("JAXCONTACT_CACHE") or str(
        pathlib.Path.home() / ".cache" / "jaxcontact" / "jax")
    try:
        pathlib.Path(cache).mkdir(parents=True, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", cache)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    except Exception:  # pragma: no cover - cache is an optimisation only
        pass


def load_inputs(args: argparse.Namespace) -> list:
    """The curves of ``args.files`` (CSV with ``--units``; instrument files with the
    spring constant of the file, or ``--spring-constant`` when given).

    Raises `ValueError` naming the option or the file.
    """
    from ._data import _TABLE_SUFFIXES, load_curve, parse_units

    if args.units is not None:
        try:
            parse_units(args.units)
        except ValueError as exc:
            raise ValueError(f"--units: {exc}") from None
    curves = []
    for f in args.files:
        p = pathlib.Path(f)
        if not p.is_file():
            raise ValueError(f"FILE {f}: no such file")
        try:
            if p.suffix.lower() in _TABLE_SUFFIXES:
                curves += load_curve(p, units=args.units)
            else:
                curves += load_curve(p, spring_constant=args.spring_constant)
        except (ValueError, ImportError, OSError) as exc:
            msg = str(exc)
            for prefix in (f"{p}: ", f"{f}: "):  # the loaders name the file already
                msg = msg.removeprefix(prefix)
            raise ValueError(f"FILE {f}: {msg}") from None
    return curves


def run_fit(args: argparse.Namespace) -> int:
    """Run a fit from parsed arguments; returns the exit code (0 on success)."""
    if not (math.isfinite(args.radius) and args.radius > 0):
        return _error(f"--radius must be finite and > 0 [m]; got {args.radius}")
    if args.spring_constant is not None and not (
            math.isfinite(args.spring_constant) and args.spring_constant > 0):
        return _error(f"--spring-constant must be finite and > 0 [N/m]; got "
                      f"{args.spring_constant}")
    if args.spring_constant is not None and args.model != "history":
        return _error("--spring-constant needs --model history")
    if args.starts < 1:
        return _error(f"--starts must be >= 1; got {args.starts}")
    cells = getattr(args, "cells", 32)
    if cells < 2:
        return _error(f"--cells must be >= 2; got {cells}")
    if args.max_samples is not None and args.max_samples < 2:
        return _error(f"--max-samples must be >= 2; got {args.max_samples}")
    from ._objective import make_spec

    try:
        make_spec(args.model, args.rheology)
    except ValueError as exc:
        return _error(f"--rheology: {exc}")
    out = pathlib.Path(args.out)
    if out.exists() and not out.is_dir():
        return _error(f"--out {out} exists and is not a folder")

    try:
        curves = load_inputs(args)
    except ValueError as exc:
        return _error(str(exc))

    _enable_cache()
    from ._optimise import fit
    from ._report import write_report

    try:
        result = fit(curves, radius=args.radius, model=args.model, rheology=args.rheology,
                     spring_constant=args.spring_constant, n_starts=args.starts,
                     max_samples=args.max_samples, cells=cells,
                     progress=not args.quiet)
    except ValueError as exc:
        return _error(str(exc))
    parent = out.resolve().parent
    parent.mkdir(parents=True, exist_ok=True)
    tmp = pathlib.Path(tempfile.mkdtemp(prefix=".fit-", dir=parent))
    try:
        write_report(result, tmp, figure=not args.no_figure)
        out.mkdir(parents=True, exist_ok=True)
        for item in tmp.iterdir():
            shutil.move(str(item), str(out / item.name))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    if not args.quiet:
        for col, v, s in zip(result.columns, result.values, result.stderr, strict=True):
            print(f"{col:>24} = {v:.6g} ± {s:.3g}")
        print(f"{'r_squared':>24} = {result.r_squared:.6f}")
        print(f"{'reduced_chi2':>24} = {result.reduced_chi2:.4g}")
        print(f"written to {out}")
    return 0


def main(argv=None) -> int:  # pragma: no cover - convenience entry
    parser = add_fit_arguments(argparse.ArgumentParser(prog="jaxcontact fit"))
    return run_fit(parser.parse_args(argv))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
