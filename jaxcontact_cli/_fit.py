"""``jaxcontact fit FILE [FILE ...] (--radius M | --profile SHAPE) --out DIR``.

Several files are one fit with shared parameters (``--joint``, the default); a file with
several curves (a force map, a QI series) or ``--each`` fits every curve on its own
(:func:`fitting.fit_each`, batched compiled calls, failures isolated per curve) and writes
``map.nc`` (xarray/netCDF, one row per curve with its grid position), ``map.csv``,
``parameters.json`` (settings and counts) and ``map.png`` (a map image per parameter).

``--posterior`` (one fit, not ``--each``) samples the posterior of the fit's free
parameters afterwards (:func:`fitting.sample`, NUTS; ``--draws``, ``--chains``) and adds
``posterior.nc`` (the ArviZ groups), ``posterior.json``, ``posterior.csv``, ``corner.png``
and the posterior band on ``fit.png``; the summary is printed after the fit's.

Instrument files are read through afmformats, and JPK files it refuses (segment layouts
its recogniser does not know) or without it by the project's own JPK reader
(:func:`fitting.load_curve` decides by the file's content and suffix); tables (CSV/TSV)
take ``--units``. ``--spring-constant`` given with an instrument file overrides the file's
value and selects the compliant loading model.

Order of work: every argument and input file is checked, the output folder is checked
(it must be new, empty, or an earlier jaxcontact output holding only the files its
manifest lists: it is replaced, never mixed, and a file jaxcontact did not write is never
deleted; one run at a time per folder, see :class:`._common.OutputFolder`), the fit
runs, and the report (``parameters.json``, ``parameters.csv``, ``fit.csv``, ``fit.png``)
is written into a temporary folder beside ``DIR`` and renamed into place: a failed or
interrupted run leaves no file and no stale file. A fit that did not converge is written
(its best point, marked ``"converged": false`` with the reason and what to try) and exits
with status :data:`EXIT_NOT_CONVERGED` (3); so does a map in which some curve did not
converge or failed (the others are written; see ``map.csv``, columns ``status``,
``convergence`` and ``error``). Fits whose residuals are far above the noise are written
and flagged (``"status": "flagged"``, ``flags``), exit 0. JAX's persistent compilation
cache (``~/.cache/jaxcontact/jax``, or ``$JAXCONTACT_CACHE``; none when
``$JAXCONTACT_NO_CACHE`` is set) spares a second run the
compile, and its ``programs`` folder the trace of the search's program
(:mod:`fitting._programs`: the same program, keyed by the code and the shapes).

Several processes (``--coordinator HOST:PORT --num-processes N --process-id I`` in each, or
``--distributed`` from a cluster's environment: ``jax.distributed``) share the curves of a
force map or of ``--each``: each fits every N-th curve on its own devices
(:func:`fitting.fit_each`), all get every result, and process 0 checks and writes the
output folder; the others write nothing.
"""

from __future__ import annotations

import math
import os
import pathlib
import sys
import warnings

from ._common import (
    OutputFolder,
    UsageError,
    add_process_arguments,
    check_number,
    check_process_arguments,
    parse_assignments,
    parse_profile,
    profile_help,
    several_processes,
    start_processes,
)

__all__ = ["add_parser", "add_fit_arguments", "load_inputs", "run", "EXIT_NOT_CONVERGED"]

#: Exit status of a fit that was written but did not converge (or a map with such curves
#: or failed curves).
EXIT_NOT_CONVERGED = 3

EXIT_STATUS = """exit status:
  0  the fit converged and was written (a fit flagged as not describing the data, e.g.
     residuals far above the noise, is written with "status": "flagged" and exits 0)
  2  bad arguments or input data, or no curve could be fitted: nothing written
  3  written, but the fit did not converge (its best point, "converged": false, the
     reason and what to try in parameters.json), or in a map some curves did not
     converge or failed (map.csv: status, convergence, error)
  1  an unexpected error
"""

DEVICES = """devices:
  the fit runs on JAX's default backend (a GPU where jax has CUDA). One curve, or a few,
  fits faster on the host's CPU: its search is a sequence of small steps and a GPU
  compiles slower (the README's main job took 57 s on an NVIDIA H100 against 25 s on a
  2-core CPU, 2026-11-27): JAX_PLATFORMS=cpu jaxcontact fit ... runs it there. Force maps
  fill a GPU (a relaxed-model map of 16,384 curves: 269 curves/s on the H100, 108 on the
  2-core CPU).
"""


def add_parser(sub, common) -> None:
    import argparse

    p = sub.add_parser("fit", parents=[common],
                       help="identify the rheology and the work of adhesion from force curves",
                       epilog=EXIT_STATUS + "\n" + DEVICES,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    add_fit_arguments(p)
    p.set_defaults(func=run)


def add_fit_arguments(parser):
    """Add the ``fit`` options to `parser` (an argparse parser)."""
    parser.add_argument("files", nargs="+", metavar="FILE",
                        help="curves: CSV/TSV (time_s,displacement_m,force_N; units in the "
                             "header or --units) or AFM instrument files (afmformats; JPK "
                             "also without it; Bruker NanoScope force curves and volumes "
                             ".spm, .000, .001, ... built in)")
    parser.add_argument("--radius", type=float, default=None, metavar="M",
                        help="radius of curvature of a spherical indenter [m] in the "
                             "paraboloid (small-indentation) approximation: the same as "
                             "--profile paraboloid:M (kept so that earlier results reproduce); "
                             "for the exact sphere give --profile sphere:M")
    parser.add_argument("--profile", default=None, metavar="SHAPE",
                        help=profile_help())
    parser.add_argument("--model", choices=("relaxed", "history"), default="relaxed",
                        help="relaxed (default, as fitting.fit): the retract after a hold "
                             "long enough to relax (the report warns when the curves have no "
                             "such hold); history: the whole approach-hold-lift")
    parser.add_argument("--rheology", default="standard",
                        metavar="standard|prony:N|elastic|auto",
                        help="standard model (G0 [Pa], G1 [Pa], eta1 [Pa s]), Prony series "
                             "with N arms (G_inf, G_k [Pa], tau_k [s]), elastic (one modulus "
                             "G [Pa], E = 3G: Hertz/MDR on the approach, JKR on the retract), "
                             "or auto: standard and prony:1..3, chosen by BIC")
    parser.add_argument("--fix", action="append", default=[], metavar="NAME=VALUE",
                        help="hold a parameter at a value (SI units; repeatable), e.g. "
                             "--fix work_of_adhesion=0.01")
    parser.add_argument("--bounds", action="append", default=[], metavar="NAME=LO:HI",
                        help="bounds of a parameter (SI units; repeatable), e.g. "
                             "--bounds eta1=1:1e4")
    parser.add_argument("--initial", action="append", default=[], metavar="NAME=VALUE",
                        help="initial value of a parameter (SI units; repeatable)")
    parser.add_argument("--contact-point", choices=("fit", "detect", "none", "fixed"),
                        default=None,
                        help="as fitting.fit's contact_point: fit: detect, then fit an "
                             "indentation offset [m] (default for instrument files); detect: "
                             "use the detected contact point as it is; none: the data are "
                             "indentation already (0 at contact; default for tables); fixed: "
                             "older spelling of detect")
    parser.add_argument("--threshold", type=float, default=None, metavar="X",
                        help="contact detection: the force must exceed X times the baseline "
                             "noise (default 5; fitting.preprocess threshold)")
    parser.add_argument("--min-run", type=int, default=None, metavar="N",
                        help="contact detection: for N consecutive samples (default 5; "
                             "fitting.preprocess min_run)")
    parser.add_argument("--retract-baseline", default=None,
                        choices=("auto", "include", "exclude", "separate"),
                        help="the retract's free tail in the force baseline: auto (default: "
                             "for --baseline linear when it is free and consistent), include, "
                             "exclude, or separate (its own constant offset: a retract offset "
                             "by viscous drag; recommended for force maps)")
    parser.add_argument("--indentation-range", default=None, metavar="LO:HI",
                        help="fit only the samples with indentation in [LO, HI] [m] (like "
                             "nanite's range_x), e.g. 0:2e-6; the model still runs through "
                             "the whole curve")
    parser.add_argument("--force-offset", action="store_true",
                        help="also fit a force offset [N] (a baseline error)")
    parser.add_argument("--force-drift", action="store_true",
                        help="also fit a force drift [N/s]: the line F0 + s t added to the "
                             "model (t from the first fitted sample; implies --force-offset), "
                             "so the data decide how much of a trend is baseline (the answer "
                             "to the baseline_trend flag)"),
    parser.add_argument("--baseline", choices=("constant", "linear", "none"), default=None,
                        help="force baseline removed before the fit: constant (the loader's "
                             "default), linear (drift in time), none")
    parser.add_argument("--segments", default=None,
                        metavar="approach|retract|approach,retract|...|all",
                        help="segments to fit (comma-separated names from approach, hold, "
                             "retract; default all: every segment the model uses). The "
                             "history model needs the approach (approach alone: the moduli, "
                             "work_of_adhesion held and said so), the relaxed model the "
                             "retract (the retract-only fit of any rheology)")
    parser.add_argument("--spring-constant", type=float, default=None, metavar="N_M",
                        help="cantilever stiffness [N/m]: compliant loading (history model); "
                             "overrides the spring constant of an instrument file")
    parser.add_argument("--sensitivity", type=float, default=None, metavar="M_V",
                        help="deflection sensitivity [m/V] for instrument files that store "
                             "the deflection in volts without it (AFM Workshop .csv); needs "
                             "--spring-constant")
    parser.add_argument("--sample-rate", type=float, default=None, metavar="HZ",
                        help="sampling rate [Hz] for instrument files without a time base "
                             "(AFM Workshop .csv)")
    parser.add_argument("--cells", type=int, default=32, metavar="N",
                        help="foundation grid cells of the history model (default 32)")
    parser.add_argument("--search-cells", type=int, default=None, metavar="N",
                        help="foundation grid cells of the history model's search, at most "
                             "--cells (default: --cells); below it, the search's best end "
                             "points are continued on --cells (a second compilation: for "
                             "maps of many curves, e.g. 16)")
    parser.add_argument("--units", default=None, metavar="ROLE=UNIT,...",
                        help="units of CSV columns without units, e.g. "
                             "'displacement=nm,force=nN'")
    parser.add_argument("--starts", type=int, default=None, metavar="N",
                        help="number of starts of the global search (default: the library's, "
                             "see fitting.fit)")
    parser.add_argument("--screen", type=int, default=None, metavar="N",
                        help="evaluate chi2 at N points of the search's Latin hypercube and "
                             "start from the lowest (N >= --starts; default 0: not screened); "
                             "with fewer --starts a cheaper search, see fitting.FitOptions")
    parser.add_argument("--explore-steps", type=int, default=None, metavar="N",
                        help="iterations of an exploring start (all but the continued best; "
                             "default: --max-steps); a best start stopped there is continued")
    parser.add_argument("--abandon", type=float, default=None, metavar="F",
                        help="stop a local round's start (not the continued best) whose chi2 "
                             "is still above F times the best known after 5 steps (F > 1; "
                             "default: the library's, 100; 'inf': never)")
    parser.add_argument("--max-steps", type=int, default=None, metavar="N",
                        help="iterations per start of the search (default: the library's, "
                             "200); a fit that stops at this limit is written with "
                             "\"converged\": false and exit status 3")
    parser.add_argument("--max-samples", type=int, default=None, metavar="N",
                        help="subsample each curve (all its segments together) to at most N "
                             "samples, N >= 4, each weighted by the measured samples it stands "
                             "for (default 1000 for --model relaxed, 600 for history)")
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--each", action="store_true",
                       help="fit every curve on its own, in batched compiled calls (default "
                            "when a file holds several curves: a force map or QI series); "
                            "writes map.nc, map.csv, map.png and parameters.json")
    group.add_argument("--joint", action="store_true",
                       help="one fit to all curves with shared parameters (default for "
                            "several single-curve files: e.g. different speeds)")
    parser.add_argument("--chunk", type=int, default=None, metavar="N",
                        help="with --each: curves per compiled call (default 64 on a CPU, "
                             "fewer where a small map would leave a --streams idle; 4096 on a "
                             "GPU)")
    parser.add_argument("--streams", type=int, default=None, metavar="N",
                        help="with --each: chunks searched at once, each from its own "
                             "thread (default: one per usable CPU core on a CPU, 1 on a "
                             "GPU; the results do not depend on it)")
    add_process_arguments(parser)  # with --each: the curves shared by several processes
    parser.add_argument("--posterior", action="store_true",
                        help="after the fit, sample the posterior of its free parameters by "
                             "NUTS (fitting.sample; needs numpyro): posterior.nc (ArviZ "
                             "groups), posterior.json, posterior.csv, corner.png and the "
                             "posterior band on fit.png; not with --each")
    parser.add_argument("--draws", type=int, default=1000, metavar="N",
                        help="with --posterior: draws per chain after as many warm-up draws "
                             "(default 1000)")
    parser.add_argument("--chains", type=int, default=4, metavar="K",
                        help="with --posterior: chains, vectorised (default 4)")
    parser.add_argument("--max-draws", type=int, default=None, metavar="N",
                        help="with --posterior: while some parameter has R-hat > 1.01 or "
                             "bulk ESS < 400, continue the chains in blocks of --draws up "
                             "to N draws each (default: --draws, no continuation)")
    parser.add_argument("--no-figure", action="store_true",
                        help="skip fit.png / map.png (and corner.png)")
    parser.add_argument("--quiet", action="store_true", help="no progress display")
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
    return parser


def _enable_cache():
    import jax

    if os.environ.get("JAXCONTACT_NO_CACHE"):
        return
    cache = os.environ.get("JAXCONTACT_CACHE") or str(
        pathlib.Path.home() / ".cache" / "jaxcontact" / "jax")
    try:
        pathlib.Path(cache).mkdir(parents=True, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", cache)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
        from fitting import _programs

        _programs.enable(pathlib.Path(cache) / "programs")
    except Exception:  # noqa: BLE001 - the cache is an optimisation only
        pass


def load_inputs(args) -> tuple[list, bool]:
    """The curves of ``args.files`` and whether a file held several (a force map); raises
    `UsageError` naming the option or the file. A bad curve of a multi-curve file is a
    :class:`fitting.FailedCurve` in the list."""
    import fitting

    if args.units is not None:
        try:
            fitting.parse_units(args.units)
        except ValueError as exc:
            raise UsageError(f"argument --units: {exc}") from None
    options = {}
    if args.baseline is not None:
        options["baseline"] = args.baseline
    if args.contact_point == "none":
        options["contact_point"] = "none"
    elif args.contact_point is not None:  # detect, fit, fixed: the loader detects it
        options["contact_point"] = "detect"
    if args.threshold is not None:
        options["threshold"] = args.threshold
    if args.min_run is not None:
        options["min_run"] = args.min_run
    if args.retract_baseline is not None:
        options["retract_baseline"] = _RETRACT_BASELINE[args.retract_baseline]
    for name in ("sensitivity", "sample_rate"):
        if getattr(args, name) is not None:
            options[name] = getattr(args, name)
    curves, multi = [], False
    for f in args.files:
        p = pathlib.Path(f)
        if not p.is_file():
            raise UsageError(f"FILE {f}: no such file")
        if args.units is not None:
            options["units"] = args.units
        try:
            loaded = fitting.load_curve(p, spring_constant=args.spring_constant,
                                        on_error="keep", **options)
        except TypeError:
            raise UsageError(f"argument --units: {f} is not a table (CSV/TSV); its units "
                             "come from the file") from None
        except (ValueError, ImportError, OSError) as exc:
            raise UsageError(f"FILE {f}: {_cli_names(_without_path(exc, p, f))}") from None
        if len(loaded) == 1 and isinstance(loaded[0], fitting.FailedCurve):
            raise UsageError(f"FILE {f}: {_without_path(loaded[0].reason, p, f)}")
        multi = multi or len(loaded) > 1
        curves += loaded
    return curves, multi


#: ``--retract-baseline`` to `fitting.preprocess`'s `retract_baseline`
_RETRACT_BASELINE = {"auto": None, "include": True, "exclude": False, "separate": "separate"}


def _cli_names(msg: str) -> str:
    """A loader message with its option names as the command line spells them."""
    msg = msg.replace("(give baseline= or contact_point=)",
                      "(give --baseline or --contact-point detect/fit)")
    for name in ("threshold", "min_run", "retract_baseline"):
        msg = msg.replace(name, "--" + name.replace("_", "-"))
    return msg


def _without_path(exc, p, f) -> str:
    msg = " ".join(str(exc).split())
    for prefix in (f"{p}: ", f"{f}: "):  # the loaders name the file already
        msg = msg.removeprefix(prefix)
    return msg


def _check(args):
    profile, radius = parse_profile(args.profile, args.radius)
    check_number("--spring-constant", args.spring_constant, "N/m")
    check_number("--sensitivity", args.sensitivity, "m/V")
    check_number("--sample-rate", args.sample_rate, "Hz")
    if args.sensitivity is not None and args.spring_constant is None:
        raise UsageError("argument --sensitivity: needs --spring-constant (F = k s V)")
    if args.spring_constant is not None and args.model != "history":
        raise UsageError("argument --spring-constant: needs --model history")
    if args.starts is not None and args.starts < 1:
        raise UsageError(f"argument --starts: must be an integer >= 1; got {args.starts}")
    if args.chunk is not None and args.chunk < 1:
        raise UsageError(f"argument --chunk: must be an integer >= 1; got {args.chunk}")
    if args.streams is not None and args.streams < 1:
        raise UsageError(f"argument --streams: must be an integer >= 1; got {args.streams}")
    if args.cells < 2:
        raise UsageError(f"argument --cells: must be an integer >= 2; got {args.cells}")
    if args.search_cells is not None and not 2 <= args.search_cells <= args.cells:
        raise UsageError(f"argument --search-cells: must be an integer in [2, --cells = "
                         f"{args.cells}]; got {args.search_cells}")
    if args.screen is not None and args.screen < 0:
        raise UsageError(f"argument --screen: must be an integer >= 0; got {args.screen}")
    if args.screen and args.starts is not None and args.screen < args.starts:
        raise UsageError(f"argument --screen: must be 0 or an integer >= --starts "
                         f"({args.starts}); got {args.screen}")
    if args.explore_steps is not None and args.explore_steps < 1:
        raise UsageError(f"argument --explore-steps: must be an integer >= 1; got "
                         f"{args.explore_steps}")
    if args.abandon is not None and not args.abandon > 1:
        raise UsageError(f"argument --abandon: must be a number > 1 or 'inf'; got "
                         f"{args.abandon}")
    if args.max_steps is not None and args.max_steps < 1:
        raise UsageError(f"argument --max-steps: must be an integer >= 1; got {args.max_steps}")
    if args.max_samples is not None and args.max_samples < 4:
        raise UsageError(f"argument --max-samples: must be an integer >= 4; got "
                         f"{args.max_samples}")
    if getattr(args, "posterior", False):
        if args.draws < 10:
            raise UsageError(f"argument --draws: must be an integer >= 10; got {args.draws}")
        if args.chains < 1:
            raise UsageError(f"argument --chains: must be an integer >= 1; got {args.chains}")
        if args.max_draws is not None and args.max_draws < args.draws:
            raise UsageError(f"argument --max-draws: must be an integer >= --draws "
                             f"({args.draws}); got {args.max_draws}")
        if args.each:
            raise UsageError("argument --posterior: not with --each (one posterior per fit; "
                             "sample the curves one by one)")
        try:
            import numpyro  # noqa: F401
        except ImportError:
            raise UsageError("argument --posterior: needs numpyro (pip install "
                             "'jaxcontact[posterior]')") from None
    check_number("--threshold", args.threshold, "noise sigma")
    if args.min_run is not None and args.min_run < 1:
        raise UsageError(f"argument --min-run: must be an integer >= 1; got {args.min_run}")
    if args.contact_point == "none" and (args.threshold is not None
                                         or args.min_run is not None):
        raise UsageError("argument --threshold/--min-run: contact detection options; not "
                         "with --contact-point none")
    indentation_range = None
    if args.indentation_range is not None:
        indentation_range = parse_assignments(
            "--indentation-range", [f"range={args.indentation_range}"],
            ranges=True)["range"]
    import fitting

    if args.rheology != "auto":
        try:
            fitting.make_spec(args.model, args.rheology)
        except ValueError as exc:
            raise UsageError(f"argument --rheology: {exc}") from None
    try:
        args.segments = fitting.check_segments(args.segments, args.model)
    except ValueError as exc:
        msg = str(exc)
        for word in ("model='relaxed'", "model='history'", "rheology='elastic'"):
            name, value = word.split("=")
            msg = msg.replace(word, f"--{name} {value.strip(chr(39))}")
        raise UsageError(f"argument --segments: {msg}") from None
    fixed = parse_assignments("--fix", args.fix)
    bounds = parse_assignments("--bounds", args.bounds, ranges=True)
    initial = parse_assignments("--initial", args.initial)
    return profile, radius, fixed, bounds, initial, indentation_range


def run(args) -> int:
    """Run a fit from parsed arguments; returns the exit status (0: converged fit)."""
    # several processes share a map's curves (started before anything starts JAX, such
    # as the probe's check); process 0 checks and writes the output
    check_process_arguments(args)
    rank = start_processes(args) if several_processes(args) else 0
    profile, radius, fixed, bounds, initial, indentation_range = _check(args)
    folder = OutputFolder("--out", args.out, command="fit") if rank == 0 else None
    curves, multi = load_inputs(args)
    each = args.each or (multi and not args.joint)
    if several_processes(args) and not each:
        raise UsageError("argument --coordinator/--distributed: several processes share the "
                         "curves of a force map or of --each; one fit runs in one process")
    _enable_cache()
    import fitting

    if not each:
        # a failed curve of a force map fitted jointly: an error naming it
        for c in curves:
            if isinstance(c, fitting.FailedCurve):
                raise UsageError(f"FILE {c.source} (curve {c.index}): {c.reason}")

    options = dict(model=args.model, rheology=args.rheology, fixed=fixed or None,
                   bounds=bounds or None, initial=initial or None,
                   spring_constant=args.spring_constant, max_samples=args.max_samples,
                   cells=args.cells, progress=not args.quiet, force_offset=args.force_offset,
                   force_drift=args.force_drift, indentation_range=indentation_range,
                   segments=args.segments)
    if args.starts is not None:
        options["n_starts"] = args.starts
    if args.max_steps is not None:
        options["max_steps"] = args.max_steps
    if args.search_cells is not None:
        options["search_cells"] = args.search_cells
    if args.screen is not None:
        options["screen"] = args.screen
    if args.explore_steps is not None:
        options["explore_steps"] = args.explore_steps
    if args.abandon is not None:
        options["abandon"] = None if math.isinf(args.abandon) else args.abandon
    if args.contact_point is not None:
        options["contact_point"] = args.contact_point  # fitting.fit's vocabulary
    if radius is not None:
        options["radius"] = radius
    else:
        options["profile"] = profile
    if each:
        if getattr(args, "posterior", False):
            raise UsageError("argument --posterior: not with a force map or --each (one "
                             "posterior per fit; fit the curves one by one)")
        return _run_each(args, folder, curves, options)
    if getattr(args, "posterior", False):
        return _run_posterior(args, folder, curves, options)
    result, out = _fit_and_write(
        args, folder, lambda: fitting.fit(curves, **options), write=fitting.write_report,
        figure=("fit.png", "plot_fit"))
    if not result.converged:
        conv = result.convergence
        print(f"jaxcontact fit: error: the fit did not converge: {conv.get('reason')}; its "
              f"best point is written to {out}, marked \"converged\": false; try: "
              + "; ".join(conv.get("advice", [])), file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return 0


def _run_posterior(args, folder, curves, options) -> int:
    """``--posterior``: the fit, then :func:`fitting.sample` from its optimum; the fit's
    report plus ``posterior.nc``, ``posterior.json``, ``posterior.csv``, ``corner.png`` and
    ``fit.png`` with the posterior band. The sampler's warnings (divergences, R-hat, ESS)
    are in the summary and ``posterior.json``."""
    import fitting

    def fit_and_sample():
        result = fitting.fit(curves, **options)
        if not args.quiet:
            print(f"[posterior] NUTS: {args.chains} chain(s) x {args.draws} draws after "
                  f"{args.draws} warm-up (compiles first)", file=sys.stderr, flush=True)
        # the posterior band is drawn on fit.png only
        return fitting.sample(result, draws=args.draws, chains=args.chains, warn=False,
                              max_draws=args.max_draws, predictive=not args.no_figure)

    def write(post, staging):
        fitting.write_report(post.fit, staging)
        post.to_netcdf(staging / "posterior.nc")
        post.to_json(staging / "posterior.json")
        post.to_csv(staging / "posterior.csv")
        if not args.no_figure:
            from . import _plots

            _plots.plot_corner(post, staging / "corner.png")

    post, out = _fit_and_write(args, folder, fit_and_sample, write=write,
                               figure=("fit.png", "plot_fit_posterior"))
    if not post.fit.converged:
        conv = post.fit.convergence
        print(f"jaxcontact fit: error: the fit did not converge: {conv.get('reason')}; its "
              f"best point and the posterior around it are written to {out}; try: "
              + "; ".join(conv.get("advice", [])), file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return 0


def _fit_and_write(args, folder, fit, *, write, figure, check=None):
    """Run `fit()` (its warnings go into the result, not to stderr; a `ValueError` is a
    one-line usage error), `check(result)` (may raise `UsageError`), write the report
    (`write(result, folder)`) and the figure (`figure`: file name and the name of the
    plotting function in `_plots`) into a staging folder renamed into place, and print
    the summary. Returns the result and the output folder."""
    import fitting

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", fitting.IdentifiabilityWarning)
            warnings.simplefilter("ignore", fitting.ModelValidityWarning)
            result = fit()
    except ValueError as exc:
        raise UsageError(" ".join(str(exc).split())) from None
    if check is not None:
        check(result)
    if folder is None:  # a process other than 0 of several: process 0 writes
        return result, None
    staging = folder.stage()
    try:
        write(result, staging)
        if not args.no_figure:
            from . import _plots

            getattr(_plots, figure[1])(result, staging / figure[0])
        out = folder.commit()
    finally:
        folder.discard()
    if not args.quiet:
        if isinstance(result, fitting.PosteriorResult):
            print(result.fit.summary())
        print(result.summary())
        print(f"written to {out}")
    return result, out


def _run_each(args, folder, curves, options) -> int:
    """``--each``: one fit per curve (:func:`fitting.fit_each`); map.nc, map.csv,
    parameters.json and map.png. Exit status :data:`EXIT_NOT_CONVERGED` when a curve failed
    or did not converge (the report names them; a curve that did not converge keeps its
    best point, flagged), 2 when none could be fitted (nothing written)."""
    import fitting

    if args.rheology == "auto":
        raise UsageError("argument --rheology: 'auto' is not offered with --each (a map "
                         "needs one model for all points); choose standard or prony:N")

    def check(result):
        if result.n_failed == len(curves):
            raise UsageError("no curve could be fitted: " + "; ".join(
                f"curve {i}: {e}" for i, e in enumerate(result.errors)))

    result, out = _fit_and_write(
        args, folder,
        lambda: fitting.fit_each(curves, chunk=args.chunk, streams=args.streams, **options),
        write=fitting.write_each_report, figure=("map.png", "plot_map"), check=check)
    bad = len(curves) - result.n_converged
    if bad:
        if out is not None:  # process 0 (of one or several) says it
            print(f"jaxcontact fit: error: {result.n_failed} curve(s) failed and "
                  f"{bad - result.n_failed} did not converge (kept with their best point, "
                  f"flagged; see {out / 'map.csv'}, columns status, convergence and error)",
                  file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return 0
