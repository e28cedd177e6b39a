"""Command line: ``jaxcontact demo | simulate | fit``.

Progress and logs go to stderr; with ``--json`` stdout carries only the JSON document.
Bad arguments exit with status 2 and a message naming the argument; no output file is
written then (files are written to a temporary name and moved into place at the end).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from pathlib import Path

from ._version import __version__

__all__ = ["main"]


class UsageError(Exception):
    """A bad command-line argument (exit status 2)."""


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def _positive(name: str, value: float | None, unit: str, *, allow_zero: bool = False) -> None:
    if value is None:
        return
    ok = math.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if not ok:
        rng = "[0, inf)" if allow_zero else "(0, inf)"
        raise UsageError(f"argument {name}: must be a finite number in {rng} [{unit}]; got {value}")


def _atomic_write_text(path: Path, text: str) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", newline="") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _none_if_nan(x) -> float | None:
    x = float(x)
    return None if math.isnan(x) else x


# --------------------------------------------------------------------------------------
# simulate
# --------------------------------------------------------------------------------------


def _add_simulate(sub) -> None:
    p = sub.add_parser(
        "simulate",
        help="simulate a pull-off curve of the standard model with a parabolic indenter",
        description=(
            "Simulate the lift of a parabolic indenter from a viscoelastic (standard-model) "
            "half-space with the energetic detachment criterion. Without --hold the indenter "
            "starts from a fully relaxed contact at --depth (relaxed-start model, time 0 = start "
            "of the lift). With --hold the whole test is simulated on the discretised MDR "
            "foundation: approach from first touch to --depth, hold, lift (time 0 = first touch). "
            "Writes a CSV with time_s,displacement_m,force_N,contact_radius_m."
        ),
    )
    p.add_argument("--G0", type=float, required=True, help="glass shear modulus [Pa]")
    p.add_argument("--G1", type=float, required=True, help="Kelvin-element shear modulus [Pa]")
    p.add_argument("--eta1", type=float, required=True, help="Kelvin-element viscosity [Pa s]")
    p.add_argument("--work-of-adhesion", type=float, required=True, help="Δγ [J/m^2]")
    p.add_argument("--radius", type=float, required=True, help="indenter radius of curvature R [m]")
    p.add_argument("--depth", type=float, required=True, help="indentation before the lift [m]")
    p.add_argument("--velocity", type=float, required=True, help="lift speed [m/s], > 0")
    p.add_argument("--duration", type=float, required=True, help="simulated time [s]")
    p.add_argument("--samples", type=int, default=2000, help="number of samples (default 2000)")
    p.add_argument("--hold", type=float, default=None, help="hold at --depth [s] (full history)")
    p.add_argument(
        "--approach-velocity", type=float, default=None,
        help="approach speed [m/s] with --hold (default: --velocity)",
    )
    p.add_argument(
        "--stiffness", type=float, default=None,
        help=(
            "stiffness of a compliant loading system (cantilever) [N/m], with --hold: the "
            "approach-hold-lift history is then the drive position (0 where the undeflected "
            "indenter touches) and displacement_m the indentation"
        ),
    )
    p.add_argument("--out", type=Path, required=True, help="output CSV file")
    p.add_argument("--json", action="store_true", help="print the events as JSON on stdout")
    p.set_defaults(func=_run_simulate)


def _check_simulate_args(args) -> None:
    for name, unit in [
        ("G0", "Pa"), ("G1", "Pa"), ("eta1", "Pa s"), ("work_of_adhesion", "J/m^2"),
        ("radius", "m"), ("depth", "m"), ("velocity", "m/s"), ("duration", "s"),
        ("approach_velocity", "m/s"), ("stiffness", "N/m"),
    ]:
        _positive("--" + name.replace("_", "-"), getattr(args, name), unit)
    _positive("--hold", args.hold, "s", allow_zero=True)
    if args.samples < 2:
        raise UsageError(f"argument --samples: must be an integer >= 2; got {args.samples}")
    if args.depth >= args.radius:
        raise UsageError(
            f"argument --depth: {args.depth} m is not small against --radius {args.radius} m "
            "(the parabolic, small-strain model needs depth << radius); check the units"
        )
    if args.radius > 1.0 or args.depth > 1e-2:
        raise UsageError(
            "argument --radius/--depth: values above 1 m / 1 cm look like a unit mistake "
            "(all lengths are in metres, e.g. 5e-6 for 5 µm)"
        )
    if args.out.exists() and args.out.is_dir():
        raise UsageError(f"argument --out: {args.out} is a directory; give a file name")
    if args.stiffness is not None and args.hold is None:
        raise UsageError("argument --stiffness: needs --hold (the full-history model)")
    if args.approach_velocity is not None and args.hold is None:
        raise UsageError("argument --approach-velocity: needs --hold")


def _simulate(args):
    import equinox as eqx
    import jax.numpy as jnp
    import numpy as np

    import jaxcontact as jc

    rheology = jc.StandardModel(G0=args.G0, G1=args.G1, eta1=args.eta1)
    profile = jc.Parabola(R=args.radius)
    ts = jnp.linspace(0.0, args.duration, args.samples)
    if args.hold is None:
        return jc.retract(
            rheology, profile, work_of_adhesion=args.work_of_adhesion, depth=args.depth,
            velocity=args.velocity, ts=ts, throw=False,
        )
    v_in = args.approach_velocity if args.approach_velocity is not None else args.velocity
    t_in = args.depth / v_in
    t_hold = t_in + args.hold
    # The history is piecewise linear with corners at the end of the approach and of the
    # hold. `simulate` takes its input as piecewise linear between the samples, so the two
    # corners are added to the simulated times (the output keeps the requested samples).
    t_out = np.asarray(ts)
    corners = np.array([t for t in (t_in, t_hold) if 0.0 < t < args.duration])
    t_sim = np.union1d(t_out, corners)
    rows = np.searchsorted(t_sim, t_out)
    d = np.where(
        t_sim <= t_in, v_in * t_sim,
        np.where(t_sim <= t_hold, args.depth, args.depth - args.velocity * (t_sim - t_hold)),
    )
    loading = jc.DisplacementControl()
    if args.stiffness is not None:
        # with a compliant loading system the history above is the drive position z(t);
        # the CSV column displacement_m is the indentation d = z - F/k
        loading = jc.CompliantLoading(stiffness=args.stiffness)
    sol = jc.simulate(
        rheology, profile, args.work_of_adhesion, jnp.asarray(t_sim), jnp.asarray(d),
        loading=loading, throw=False,
    )
    if t_sim.shape != t_out.shape:
        sol = eqx.tree_at(
            lambda s: (s.ts, s.displacement, s.force, s.contact_radius),
            sol,
            (sol.ts[rows], sol.displacement[rows], sol.force[rows], sol.contact_radius[rows]),
        )
    return sol


def _run_simulate(args) -> int:
    import numpy as np

    from ._solution import is_error

    _check_simulate_args(args)
    _log(f"jaxcontact {__version__}: simulating {args.samples} samples ...")
    sol = _simulate(args)
    if bool(is_error(sol.result)):
        msg = sol.result._enumeration[sol.result]
        _log(f"error: the simulation failed: {msg}")
        return 1
    rows = np.column_stack(
        [np.asarray(sol.ts), np.asarray(sol.displacement), np.asarray(sol.force),
         np.asarray(sol.contact_radius)]
    )
    lines = ["time_s,displacement_m,force_N,contact_radius_m"]
    lines += [",".join(f"{v:.17g}" for v in row) for row in rows]
    _atomic_write_text(args.out, "\n".join(lines) + "\n")
    events = {
        "max_tensile_force_N": float(sol.max_tensile_force),
        "jumpoff_force_N": _none_if_nan(sol.jumpoff_force),
        "jumpoff_time_s": _none_if_nan(sol.jumpoff_time),
        "jumpoff_contact_radius_m": _none_if_nan(sol.jumpoff_radius),
    }
    _log(f"wrote {args.out}; detached: {bool(sol.detached)}")
    if args.json:
        print(json.dumps(events))
    return 0


# --------------------------------------------------------------------------------------
# demo
# --------------------------------------------------------------------------------------


def _add_demo(sub) -> None:
    p = sub.add_parser(
        "demo",
        help="compute and plot elastic and viscoelastic pull-off curves (writes a PNG)",
    )
    p.add_argument("--out", type=Path, default=Path("demo-output"), help="output folder")
    p.set_defaults(func=_run_demo)


def _run_demo(args) -> int:
    import jax.numpy as jnp
    import numpy as np

    import jaxcontact as jc

    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as err:  # pragma: no cover - depends on the environment
        raise UsageError("the demo needs matplotlib: pip install 'jaxcontact[plot]'") from err

    R, d0, dg = 1e-4, 4e-6, 0.05
    G0, G1, eta1 = 1e6, 2e5, 1e4
    rheology = jc.StandardModel(G0=G0, G1=G1, eta1=eta1)
    profile = jc.Parabola(R=R)
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    # elastic JKR curve with the relaxed modulus and the effective work of adhesion
    Ginf = float(rheology.relaxed_modulus)
    dge = dg * G0 / Ginf
    po = jc.pull_off(profile, effective_modulus=4 * Ginf, work_of_adhesion=dge)
    a = jnp.linspace(float(po.radius), np.sqrt(R * d0), 200)
    kw = dict(effective_modulus=4 * Ginf, work_of_adhesion=dge)
    ax1.plot(jc.jkr_displacement(profile, a, **kw) * 1e6, jc.jkr_force(profile, a, **kw) * 1e6,
             "k--", label="elastic JKR, $E^*=4G_\\infty$, $\\Delta\\gamma_{eff}$")
    rows = []
    for v in [1e-6, 1e-4, 1e-3]:
        t_end = 3 * (d0 + abs(float(po.displacement))) / v + 10 * float(rheology.tau)
        ts = jnp.linspace(0, t_end, 4000)
        sol = jc.retract(rheology, profile, work_of_adhesion=dg, depth=d0, velocity=v, ts=ts)
        on = np.asarray(sol.contact_radius) > 0
        ax1.plot(np.asarray(sol.displacement)[on] * 1e6, np.asarray(sol.force)[on] * 1e6,
                 label=f"viscoelastic, v = {v:g} m/s")
        ax2.plot(np.asarray(sol.ts)[on] / t_end, np.asarray(sol.contact_radius)[on] * 1e6)
        rows.append((v, float(sol.max_tensile_force), float(sol.jumpoff_force),
                     float(sol.jumpoff_time)))
    ax1.set_xlabel("indentation d [µm]")
    ax1.set_ylabel("force F [µN] (adhesive < 0)")
    ax1.legend(fontsize=8)
    ax1.set_title("Pull-off of a parabola, standard model")
    ax2.set_xlabel("t / t_end")
    ax2.set_ylabel("contact radius a [µm]")
    ax2.set_title("Pinned, receding, jump-off")
    fig.tight_layout()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    png = out / "pulloff.png"
    fig.savefig(png, dpi=120)
    plt.close(fig)
    lines = ["velocity_m_s,max_tensile_force_N,jumpoff_force_N,jumpoff_time_s"]
    lines += [",".join(f"{x:.10g}" for x in r) for r in rows]
    _atomic_write_text(out / "pulloff.csv", "\n".join(lines) + "\n")
    _log(f"wrote {png} and {out / 'pulloff.csv'}")
    for r in rows:
        _log(f"  v = {r[0]:g} m/s: max tensile {r[1]:.4g} N, jump-off {r[2]:.4g} N at {r[3]:.4g} s")
    return 0


# --------------------------------------------------------------------------------------
# fit (provided by the fitting package)
# --------------------------------------------------------------------------------------


def _add_fit(sub) -> None:
    from fitting._cli import add_fit_arguments, run_fit

    p = sub.add_parser(
        "fit",
        help="identify G0, G1, eta1 and the work of adhesion from force curves",
    )
    add_fit_arguments(p)
    p.set_defaults(func=run_fit)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jaxcontact",
        description=(
            "Adhesive contact of viscoelastic bodies (MDR, energetic detachment criterion): "
            "forward simulation and parameter identification. SI units throughout."
        ),
    )
    parser.add_argument("--version", action="version", version=f"jaxcontact {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    _add_demo(sub)
    _add_simulate(sub)
    try:
        _add_fit(sub)
    except ImportError:  # the fitting package is optional at this edge
        pass
    return parser


#: XLA options for the CPU that the command line applies (see `tune_xla_cpu`).
XLA_CPU_FLAGS = ("--xla_cpu_use_fusion_emitters=false",)


def tune_xla_cpu() -> list[str]:
    """Add `XLA_CPU_FLAGS` to ``XLA_FLAGS`` before JAX starts its CPU backend.

    XLA's newer CPU fusion emitters compile the element-wise kernels of the fitting
    residuals and their forward-mode tangents into slower code than the previous emitters
    (measured with jaxlib 0.10.2 on an AMD EPYC, one core: the Jacobian of the benchmark
    fit 135 -> 109 µs, a whole Levenberg–Marquardt solve 3.7 -> 2.75 ms, 100 pooled fits
    0.33 -> 0.24 s; `python benchmarks/bench_fit.py` prints which flags were active). The
    flag only chooses the code generator; results agree to round-off (the test suite
    passes either way). Applied only where it is known to exist (jaxlib 0.10: an unknown
    flag makes XLA abort), only before the backend has started, never over a choice made in
    ``XLA_FLAGS`` already, and not at all with ``JAXCONTACT_XLA_TUNING=0``. Returns the
    flags added. The command line calls this first; library users may call it at the top
    of a script, before any JAX computation.
    """
    if os.environ.get("JAXCONTACT_XLA_TUNING", "1") == "0":
        return []
    try:
        import jaxlib

        version = tuple(int(x) for x in jaxlib.__version__.split(".")[:2])
    except Exception:  # pragma: no cover - unusual installs
        return []
    if version != (0, 10):
        return []
    if "jax" in sys.modules:
        from jax._src import xla_bridge

        if getattr(xla_bridge, "_backends", None):
            return []  # the backend has started; XLA_FLAGS is no longer read
    current = os.environ.get("XLA_FLAGS", "")
    added = [f for f in XLA_CPU_FLAGS if f.split("=")[0] not in current]
    if added:
        os.environ["XLA_FLAGS"] = " ".join([current, *added]).strip()
    return added


def main(argv: list[str] | None = None) -> int:
    tune_xla_cpu()
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help(sys.stderr)
        return 2
    try:
        return int(args.func(args) or 0)
    except UsageError as err:
        parser.exit(2, f"jaxcontact {args.command}: error: {err}\n")
    except ValueError as err:  # validation errors from the library name the parameter
        parser.exit(2, f"jaxcontact {args.command}: error: {err}\n")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
