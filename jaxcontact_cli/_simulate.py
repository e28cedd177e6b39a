"""``jaxcontact simulate``: one pull-off curve of the standard model, written as CSV."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

from ._common import (
    UsageError,
    add_material_arguments,
    atomic_write_text,
    check_number,
    check_output_file,
)
from ._simulate_bem import add_bem_arguments, check_bem_args, check_bem_extent, simulate_bem

__all__ = ["add_parser", "run"]


def add_parser(sub, common) -> None:
    p = sub.add_parser(
        "simulate", parents=[common],
        help="simulate a pull-off curve of the standard model with a parabolic indenter",
        description=(
            "Simulate the lift of a parabolic indenter from a viscoelastic (standard-model) "
            "half-space with the energetic detachment criterion. Without --hold the indenter "
            "starts from a fully relaxed contact at --depth (relaxed-start model, time 0 = start "
            "of the lift). With --hold the whole test is simulated on the discretised MDR "
            "foundation: approach from first touch to --depth, hold, lift (time 0 = first touch). "
            "With --method bem the same test runs on the boundary element method (--grid, "
            "--extent; --profile ellipsoid:RX,RY for an ellipsoidal indenter; "
            "contact_radius_m is then sqrt(area/pi)). "
            "Writes a CSV with time_s,displacement_m,force_N,contact_radius_m."
        ),
    )
    add_material_arguments(p, radius_required=False)
    add_bem_arguments(p)
    p.add_argument("--duration", type=float, required=True, help="simulated time [s]")
    p.add_argument("--samples", type=int, default=2000, help="number of samples (default 2000)")
    p.add_argument("--out", type=Path, required=True, help="output CSV file")
    p.add_argument("--json", action="store_true", help="print the events as JSON on stdout")
    p.add_argument(
        "--no-plausibility-check", dest="plausibility_check", action="store_false",
        help="accept values far outside the usual range of their unit (e.g. a 1 km radius)",
    )
    p.set_defaults(func=run)


_UNITS = {"G0": "Pa", "G1": "Pa", "eta1": "Pa s", "work_of_adhesion": "J/m^2", "radius": "m",
          "depth": "m", "velocity": "m/s", "duration": "s", "approach_velocity": "m/s",
          "stiffness": "N/m"}
# the library's plausible range of each option's unit (`jaxcontact.PLAUSIBLE`)
_KINDS = {"G0": "modulus", "G1": "modulus", "eta1": "viscosity",
          "work_of_adhesion": "work_of_adhesion", "radius": "length", "depth": "length",
          "velocity": "velocity", "duration": "time", "hold": "time",
          "approach_velocity": "velocity", "stiffness": "stiffness"}


def _check_plausible(args) -> None:
    import jaxcontact as jc

    if not getattr(args, "plausibility_check", True):
        return
    for name, kind in _KINDS.items():
        value = getattr(args, name, None)
        if value is None or value == 0:
            continue
        lo, hi, unit = jc.PLAUSIBLE[kind]
        if not lo <= value <= hi:
            raise UsageError(
                f"argument --{name.replace('_', '-')}: {value:g} {unit} lies outside the "
                f"plausible range [{lo:g}, {hi:g}] {unit} (all values are SI: a unit "
                "mistake?); --no-plausibility-check accepts it"
            )


def check_args(args) -> None:
    if hasattr(args, "method"):
        check_bem_args(args)  # converts --grid and --profile
    if args.radius is None and getattr(args, "profile", None) is None:
        raise UsageError("the following arguments are required: --radius")
    for name, unit in _UNITS.items():
        if hasattr(args, name):
            check_number("--" + name.replace("_", "-"), getattr(args, name), unit)
    check_number("--hold", args.hold, "s", low_open=False)
    if args.samples < 2:
        raise UsageError(f"argument --samples: must be an integer >= 2; got {args.samples}")
    radius = args.radius if args.radius is not None else min(args.profile)
    if args.depth >= radius:
        raise UsageError(
            f"argument --depth: {args.depth} m is not small against the radius {radius} m "
            "(the parabolic, small-strain model needs depth << radius); check the units"
        )
    if radius > 1.0 or args.depth > 1e-2:
        raise UsageError(
            "argument --radius/--depth: values above 1 m / 1 cm look like a unit mistake "
            "(all lengths are in metres, e.g. 5e-6 for 5 µm)"
        )
    _check_plausible(args)
    if args.stiffness is not None and args.hold is None:
        raise UsageError("argument --stiffness: needs --hold (the full-history model)")
    if args.approach_velocity is not None and args.hold is None:
        raise UsageError("argument --approach-velocity: needs --hold")
    if getattr(args, "method", "mdr") == "bem":
        check_bem_extent(args)


def history(args):
    """The sampled input `(t_sim, d_sim, rows)` of the options in `args`.

    Relaxed start (no --hold): the lift $d = d_0 - v t$ at the requested samples, `rows`
    None. With --hold: approach from first touch, hold, lift, sampled at the requested
    times plus the two corners; `rows` selects the requested samples.
    """
    import numpy as np

    ts = np.linspace(0.0, args.duration, args.samples)
    if args.hold is None:
        return ts, args.depth - args.velocity * ts, None
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
    return t_sim, d, (rows if t_sim.shape != t_out.shape else None)


def simulate(args):
    """The solution of the options in `args`: a `ContactSolution` (MDR: relaxed start or
    full history) or a `BEMSolution` (``--method bem``)."""
    import equinox as eqx
    import jax.numpy as jnp

    import jaxcontact as jc

    t_sim, d, rows = history(args)
    if getattr(args, "method", "mdr") == "bem":
        return simulate_bem(args, t_sim, d, rows)
    rheology = jc.StandardModel(G0=args.G0, G1=args.G1, eta1=args.eta1)
    profile = jc.Parabola(R=args.radius)
    if args.hold is None:
        return jc.retract(
            rheology, profile, work_of_adhesion=args.work_of_adhesion, depth=args.depth,
            velocity=args.velocity, ts=jnp.asarray(t_sim), throw=False,
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
    if rows is not None:
        sol = eqx.tree_at(
            lambda s: (s.ts, s.displacement, s.force, s.contact_radius),
            sol,
            (sol.ts[rows], sol.displacement[rows], sol.force[rows], sol.contact_radius[rows]),
        )
    return sol


def _none_if_nan(x) -> float | None:
    x = float(x)
    return None if math.isnan(x) else x


def run(args) -> int:
    import numpy as np

    import jaxcontact as jc

    check_args(args)
    out = check_output_file("--out", args.out)
    print(f"jaxcontact {jc.__version__}: simulating {args.samples} samples ...",
          file=sys.stderr, flush=True)
    with jc.plausibility_checks(getattr(args, "plausibility_check", True)):
        sol = simulate(args)
    if not (bool(sol.result == jc.RESULTS.in_contact) or bool(sol.result == jc.RESULTS.detached)):
        msg = sol.result._enumeration[sol.result]
        print(f"jaxcontact simulate: error: the simulation failed: {msg}", file=sys.stderr)
        return 1
    rows = np.column_stack(
        [np.asarray(sol.ts), np.asarray(sol.displacement), np.asarray(sol.force),
         np.asarray(sol.contact_radius)]
    )
    lines = ["time_s,displacement_m,force_N,contact_radius_m"]
    lines += [",".join(f"{v:.17g}" for v in row) for row in rows]
    atomic_write_text(out, "\n".join(lines) + "\n")
    events = {
        "max_tensile_force_N": _none_if_nan(sol.max_tensile_force),
        "jumpoff_force_N": _none_if_nan(sol.jumpoff_force),
        "jumpoff_time_s": _none_if_nan(sol.jumpoff_time),
        "jumpoff_contact_radius_m": _none_if_nan(sol.jumpoff_radius),
    }
    print(f"wrote {out}; detached: {bool(sol.detached)}", file=sys.stderr, flush=True)
    if args.json:
        print(json.dumps(events, allow_nan=False))
    return 0
