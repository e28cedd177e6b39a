"""``jaxcontact sweep``: the forward model over a grid of parameters, written as netCDF.

Every model option of ``simulate`` takes a value or a range: ``LO:HI:N`` (N values, linear)
or ``LO:HI:N:log`` (logarithmic). Each range is one dimension of the result. The output is
an ``xarray`` dataset in netCDF-4 (h5netcdf) with a coordinate per parameter and the
per-point summaries of :func:`jaxcontact.sweep`, and a plot of one summary against one swept
parameter beside it. Several processes (``--coordinator`` ... or ``--distributed``) share
the work through ``jax.distributed``; process 0 writes the files.
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

from ._common import (
    COMMIT_GUARD,
    UsageError,
    add_material_arguments,
    add_process_arguments,
    check_number,
    check_output_file,
    check_process_arguments,
    note_written,
    start_processes,
    temp_beside,
)

__all__ = ["add_parser", "run", "parse_range"]

# command-line option -> sweep parameter (its unit and range: the registry of parameters,
# `jaxcontact._vocabulary`, read when the options are parsed: importing jaxcontact starts JAX)
_OPTIONS = {
    "G0": "G0",
    "G1": "G1",
    "eta1": "eta1",
    "work_of_adhesion": "work_of_adhesion",
    "radius": "R",
    "depth": "depth",
    "velocity": "velocity",
    "hold": "hold",
    "approach_velocity": "approach_velocity",
}
_SUMMARY_NAMES = (
    "max_tensile_force_N", "jumpoff_force_N", "jumpoff_displacement_m", "jumpoff_time_s",
    "jumpoff_contact_radius_m", "separation_work_J", "lift_duration_s",
)


def add_parser(sub, common) -> None:
    p = sub.add_parser(
        "sweep", parents=[common],
        help="sweep the pull-off model over a grid of parameters (netCDF + plot)",
        description=(
            "Run the pull-off model of a parabolic indenter on a viscoelastic (standard-model) "
            "half-space over a grid of parameters. Every model option takes a value or a range "
            "LO:HI:N (linear) or LO:HI:N:log; each range is one dimension of the result. "
            "--model relaxed: lift from a fully relaxed contact at --depth; --model history: "
            "approach, --hold, lift (the full-history model). Each lift lasts --duration-factor "
            "times a bound of its jump-off time, so every point detaches. Writes a netCDF file "
            "(per point: max_tensile_force_N, jumpoff_force_N, jumpoff_displacement_m, "
            "jumpoff_time_s, separation_work_J, status, ...) and a plot beside it."
        ),
        epilog=(
            "example: jaxcontact sweep --G0 1e6 --G1 1e5:1e6:4:log --eta1 1e4 "
            "--work-of-adhesion 0.05 --radius 1e-2 --depth 1e-4 --velocity 1e-5:1e-1:32:log "
            "--duration-factor 3 --samples 2000 --out s.nc"
        ),
    )
    add_material_arguments(p)
    # the same options as `simulate`, read as text: a value or a range (parsed in `run`)
    for action in p._actions:
        if action.dest in _OPTIONS:
            action.type = str
            action.metavar = "VALUE|LO:HI:N[:log]"
    p.add_argument("--model", choices=("relaxed", "history"), default="relaxed",
                   help="relaxed start (default) or the full approach-hold-lift history "
                        "(needs --hold)")
    p.add_argument("--samples", type=int, default=2000,
                   help="samples per curve (default 2000); the relaxed model's summaries are "
                        "exact and do not depend on it (it sets the curves of --curves)")
    p.add_argument("--duration-factor", type=float, default=1.5,
                   help="each lift lasts this many times the bound of its jump-off time "
                        "(> 1, default 1.5)")
    p.add_argument("--cells", type=int, default=64,
                   help="foundation cells of --model history (default 64)")
    p.add_argument("--work-rtol", type=float, default=1e-2,
                   help="--model history: the relative sampling error the separation work "
                        "must be within (estimated from the samples), else it is written as "
                        "NaN with separation_work_status undersampled (default 0.01)")
    p.add_argument("--precision", choices=("float32", "float64"), default=None,
                   help="default: float32 on a GPU, float64 on the CPU")
    p.add_argument("--curves", action="store_true",
                   help="also store every curve (time_s, displacement_m, force_N, "
                        "contact_radius_m)")
    p.add_argument("--chunk-size", type=int, default=None,
                   help="curves per compiled call (default: from the memory of a device)")
    p.add_argument("--out", type=Path, required=True, help="output netCDF file (.nc)")
    p.add_argument("--plot", type=Path, default=None,
                   help="plot file (default: --out with .png)")
    p.add_argument("--no-plot", action="store_true", help="do not write the plot")
    p.add_argument("--plot-summary", choices=_SUMMARY_NAMES, default="separation_work_J",
                   help="summary on the plot's y axis (default separation_work_J: from a "
                        "relaxed start the maximum tensile force is the elastic JKR value "
                        "with the effective work of adhesion at every speed, so it is flat; "
                        "the work of separation shows the speed dependence)")
    p.add_argument("--plot-x", default=None,
                   help="swept option on the plot's x axis (default: the one with most values)")
    p.add_argument("--cpu-devices", type=int, default=None,
                   help="JAX devices on the CPU (default: one per usable core)")
    add_process_arguments(p)
    p.set_defaults(func=run)


def parse_range(option: str, text: str, unit: str, *, allow_zero: bool = False):
    """A value or ``LO:HI:N[:log]`` as a list of floats and whether the spacing is log."""
    import numpy as np

    form = "a number or LO:HI:N (linear) or LO:HI:N:log"
    parts = str(text).strip().split(":")
    try:
        if len(parts) == 1:
            values, log = [float(parts[0])], False
        elif len(parts) in (3, 4):
            lo, hi = float(parts[0]), float(parts[1])
            n = int(parts[2])
            log = len(parts) == 4
            if log and parts[3] != "log":
                raise ValueError
            if n < 1:
                raise UsageError(f"argument {option}: N in LO:HI:N must be >= 1; got {n}")
            if not (math.isfinite(lo) and math.isfinite(hi)):
                raise UsageError(f"argument {option}: LO and HI must be finite; got {text!r}")
            if log:
                if lo <= 0 or hi <= 0:
                    raise UsageError(f"argument {option}: a log range needs LO, HI > 0; "
                                     f"got {text!r}")
                values = np.geomspace(lo, hi, n).tolist()
            else:
                values = np.linspace(lo, hi, n).tolist()
        else:
            raise ValueError
    except ValueError:
        raise UsageError(f"argument {option}: expected {form}; got {text!r}") from None
    for v in values:
        check_number(option, v, unit, low_open=not allow_zero)
    return values, log


def _parameters(args):
    """The sweep grid of the options (and which are log ranges), checked."""
    from jaxcontact._vocabulary import parameter

    grid, log = {}, {}
    for dest, name in _OPTIONS.items():
        text = getattr(args, dest)
        if text is None:
            continue
        option = "--" + dest.replace("_", "-")
        info = parameter(name)
        values, is_log = parse_range(option, text, info.unit, allow_zero=info.allow_zero)
        grid[name] = values[0] if len(values) == 1 and ":" not in str(text) else values
        log[name] = is_log
    if max(_as_list(grid["depth"])) >= min(_as_list(grid["R"])):
        raise UsageError(
            "argument --depth: every depth must be small against every --radius (the parabolic, "
            "small-strain model needs depth << radius); check the units")
    if max(_as_list(grid["R"])) > 1.0 or max(_as_list(grid["depth"])) > 1e-2:
        raise UsageError(
            "argument --radius/--depth: values above 1 m / 1 cm look like a unit mistake "
            "(all lengths are in metres, e.g. 5e-6 for 5 µm)")
    return grid, log


def _as_list(x):
    return x if isinstance(x, list) else [x]


def check_args(args):
    if args.stiffness is not None:
        raise UsageError("argument --stiffness: not available in sweep (displacement control "
                         "only); use jaxcontact simulate")
    if args.model == "history" and args.hold is None:
        raise UsageError("argument --hold: required with --model history (0 for none)")
    if args.model == "relaxed":
        for dest in ("hold", "approach_velocity"):
            if getattr(args, dest) is not None:
                raise UsageError(f"argument --{dest.replace('_', '-')}: only with "
                                 "--model history")
    if args.samples < (8 if args.model == "history" else 2):
        low = 8 if args.model == "history" else 2
        raise UsageError(f"argument --samples: must be an integer >= {low}; got {args.samples}")
    check_number("--duration-factor", args.duration_factor, "1", low=1.0)
    check_number("--work-rtol", args.work_rtol, "1")
    if args.cells < 2:
        raise UsageError(f"argument --cells: must be an integer >= 2; got {args.cells}")
    if args.chunk_size is not None and args.chunk_size < 1:
        raise UsageError(f"argument --chunk-size: must be an integer >= 1; got {args.chunk_size}")
    if args.cpu_devices is not None and args.cpu_devices < 1:
        raise UsageError(f"argument --cpu-devices: must be >= 1; got {args.cpu_devices}")
    check_process_arguments(args)
    if args.out.suffix != ".nc":
        raise UsageError(f"argument --out: the file must end in .nc (netCDF); got {args.out}")


def _start_jax(args):
    """Devices and processes: before anything starts a JAX backend."""
    import jax

    # one JAX CPU device per usable core (the sweep shards its chunks over them; on a GPU
    # machine this only splits the CPU backend, which the sweep does not use)
    from jaxcontact._devices import usable_cores

    try:
        jax.config.update("jax_num_cpu_devices", int(args.cpu_devices or usable_cores()))
    except RuntimeError:  # JAX already started (the command called from Python)
        if args.cpu_devices is not None:
            raise UsageError("argument --cpu-devices: JAX has already started in this "
                             "process; it only applies to a fresh process") from None
    return start_processes(args)


def run(args) -> int:
    check_args(args)
    grid, log = _parameters(args)
    out = check_output_file("--out", args.out)
    plot = None
    if not args.no_plot:
        plot = check_output_file("--plot", args.plot if args.plot else out.with_suffix(".png"))
        if plot.resolve() == out.resolve():
            raise UsageError("argument --plot: must differ from --out")
    if args.plot_x is not None:
        names = {dest.replace("_", "-"): name for dest, name in _OPTIONS.items()}
        key = args.plot_x.lstrip("-")
        name = names.get(key, key)
        if not isinstance(grid.get(name), list):
            swept = [o for o, n in names.items() if isinstance(grid.get(n), list)]
            raise UsageError(f"argument --plot-x: must name a swept option "
                             f"({', '.join(swept) or 'none'}); got {args.plot_x!r}")
        args.plot_x = name

    rank = _start_jax(args)
    import numpy as np

    import jaxcontact as jc

    if args.model == "relaxed":
        model = jc.RelaxedStart(samples=args.samples, duration_factor=args.duration_factor)
    else:
        model = jc.ApproachHoldLift(samples=args.samples, duration_factor=args.duration_factor,
                                    cells=args.cells, work_rtol=args.work_rtol)
    size = int(np.prod([len(v) for v in grid.values() if isinstance(v, list)]))
    if rank == 0:
        sampled = args.curves or args.model == "history"
        what = f" x {args.samples} samples" if sampled else " (exact summaries)"
        print(f"jaxcontact {jc.__version__}: sweeping {size:,} point(s){what} "
              f"({args.model} model) ...", file=sys.stderr, flush=True)
    ds = jc.sweep(grid, model=model, curves=args.curves, precision=args.precision,
                  chunk_size=args.chunk_size, progress=True)
    if rank != 0:
        return 0
    ok = {int(jc.RESULTS.detached._value), int(jc.RESULTS.in_contact._value)}
    status = ds.status.values.ravel()
    failed = int(np.sum(~np.isin(status, list(ok))))
    attached = int(np.sum(status == int(jc.RESULTS.in_contact._value)))

    tmp_nc, forget_nc = temp_beside(out, ".tmp")
    tmp_png = forget_png = None
    try:
        ds.to_netcdf(tmp_nc, engine="h5netcdf")
        if plot is not None:
            tmp_png, forget_png = temp_beside(plot, ".tmp")
            from ._plots import plot_sweep

            plot_sweep(ds, tmp_png, args.plot_summary, args.plot_x, log)
        with COMMIT_GUARD:
            os.replace(tmp_nc, out)
            note_written(out)
            if plot is not None:
                os.replace(tmp_png, plot)
                note_written(plot)
    finally:
        for tmp, forget in ((tmp_nc, forget_nc), (tmp_png, forget_png)):
            if tmp is not None and os.path.exists(tmp):
                os.unlink(tmp)
            if forget is not None:
                forget()
    wrote = f"{out}" + (f" and {plot}" if plot is not None else "")
    print(f"wrote {wrote}: {size:,} point(s), {size - failed - attached:,} detached, "
          f"{attached:,} still in contact, {failed:,} failed", file=sys.stderr, flush=True)
    undersampled = int(np.sum(ds.separation_work_status.values == 1))
    if undersampled:
        print(f"jaxcontact sweep: warning: the separation work of {undersampled} point(s) is "
              f"undersampled (estimated error above --work-rtol {args.work_rtol:g}; written as "
              "NaN): use more --samples", file=sys.stderr, flush=True)
    if failed:
        print(f"jaxcontact sweep: warning: {failed} point(s) failed (their status in the file "
              "says why; their summaries are NaN)", file=sys.stderr, flush=True)
    return 1 if failed == size else 0
