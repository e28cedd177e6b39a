"""``jaxcontact simulate --method bem``: the same test on the boundary element method.

The options, the CSV columns and the ``--json`` events are those of the MDR ``simulate``
(:mod:`._simulate`); the BEM adds the grid (``--grid N`` cells per side of a square of side
``--extent M``) and non-axisymmetric indenters (``--profile ellipsoid:RX,RY``). The
``contact_radius_m`` column is the equivalent radius $\\sqrt{A/\\pi}$ of the contact area.

Default extent: the square covers the largest contact with a margin. The largest contact
is the non-adhesive (Hertz) one at the largest indentation (``--depth``: cells enter the
contact when they touch, so adhesion never widens it; under a compliant loading system the
indentation stays below the drive): radius $\\sqrt{R d}$ for a sphere, and for an
ellipsoid the semi-major axis $a$ of the Hertz ellipse, $a^2 = 2R_x d\\,(K - E)/(e^2 K)$
with $K(e)$, $E(e)$ the complete elliptic integrals of the contact eccentricity $e$, which
solves $R_x/R_y = ((1 - e^2)^{-1}E - K)/(K - E)$ (Johnson, *Contact Mechanics*, §4.2;
$R_x \\ge R_y$). The side is ``EXTENT_FACTOR`` times that radius.
"""

from __future__ import annotations

import math

from ._common import UsageError, check_number

__all__ = ["EXTENT_FACTOR", "add_bem_arguments", "check_bem_args", "check_bem_extent",
           "default_extent", "hertz_semi_major", "simulate_bem"]

EXTENT_FACTOR = 2.5  # side of the default square / radius of the largest contact
_GRID_RANGE = (8, 4096)


def add_bem_arguments(p) -> None:
    """``--method``, ``--grid``, ``--extent``, ``--profile`` (the BEM options of simulate)."""
    p.add_argument(
        "--method", default="mdr",
        help="mdr (default: the MDR models) or bem (boundary elements on a square grid, "
             "the paper's cell criterion; every sample is a constrained solve on the grid, so "
             "give a few hundred --samples)",
    )
    p.add_argument(
        "--grid", default=None,
        help=f"BEM: number of cells per side of the square, an integer in "
             f"[{_GRID_RANGE[0]}, {_GRID_RANGE[1]}] (default 64)",
    )
    p.add_argument(
        "--extent", type=float, default=None,
        help=f"BEM: side of the simulated square [m] (default {EXTENT_FACTOR} times the "
             "radius of the largest contact)",
    )
    p.add_argument(
        "--profile", default=None,
        help="BEM: ellipsoid:RX,RY, an ellipsoidal indenter with principal radii RX, RY [m] "
             "(instead of --radius)",
    )


def _parse_ellipsoid(spec: str) -> tuple[float, float]:
    kind, _, rest = spec.partition(":")
    if kind != "ellipsoid":
        raise UsageError(f"argument --profile: unknown shape {kind!r}; use ellipsoid:RX,RY "
                         "(a sphere is --radius R)")
    try:
        vals = [float(x) for x in rest.split(",")] if rest else []
    except ValueError:
        raise UsageError(f"argument --profile: bad numbers in {spec!r}") from None
    if len(vals) != 2:
        raise UsageError(f"argument --profile: ellipsoid takes 2 numbers RX,RY; got {spec!r}")
    check_number("--profile ellipsoid:RX", vals[0], "m", high=1.0)
    check_number("--profile ellipsoid:RY", vals[1], "m", high=1.0)
    return vals[0], vals[1]


def check_bem_args(args) -> None:
    """Validate the BEM options; converts ``args.grid`` to an int and ``args.profile`` to
    ``(RX, RY)`` (or None). Raises `UsageError` naming the option."""
    if args.method not in ("mdr", "bem"):
        raise UsageError(f"argument --method: must be mdr or bem; got {args.method!r}")
    if args.method == "mdr":
        for name in ("grid", "extent", "profile"):
            if getattr(args, name) is not None:
                raise UsageError(f"argument --{name}: only with --method bem")
        return
    grid = 64 if args.grid is None else args.grid
    try:
        grid = int(str(grid))
    except ValueError:
        raise UsageError(f"argument --grid: must be an integer in [{_GRID_RANGE[0]}, "
                         f"{_GRID_RANGE[1]}]; got {args.grid!r}") from None
    if not _GRID_RANGE[0] <= grid <= _GRID_RANGE[1]:
        raise UsageError(f"argument --grid: must be an integer in [{_GRID_RANGE[0]}, "
                         f"{_GRID_RANGE[1]}]; got {grid}")
    args.grid = grid
    check_number("--extent", args.extent, "m", high=1.0)
    if args.profile is not None:
        if args.radius is not None:
            raise UsageError("argument --radius: not together with --profile")
        args.profile = _parse_ellipsoid(args.profile)
    elif args.radius is None:
        raise UsageError("argument --radius/--profile: give the indenter, e.g. --radius 1e-4 "
                         "or --profile ellipsoid:2e-4,5e-5")


def check_bem_extent(args) -> None:
    """Refuse an ``--extent`` that cannot hold the largest contact (after the other
    checks): its inner square, one cell in from the edge, must be wider than the Hertz
    contact at ``--depth``. A contact that still reaches the edge (adhesion, creep) is
    reported after the run."""
    if args.extent is None:
        return
    a = default_extent(args) / EXTENT_FACTOR
    if args.extent * (1.0 - 2.0 / args.grid) <= 2.0 * a:
        raise UsageError(
            f"argument --extent: {args.extent:g} m cannot hold the contact at --depth "
            f"(diameter {2 * a:.3g} m plus one cell on each side); give a larger --extent "
            "or leave it out"
        )


def hertz_semi_major(radius_x: float, radius_y: float, depth: float) -> float:
    """Semi-major axis [m] of the non-adhesive (Hertz) contact ellipse of an ellipsoid
    with principal radii `radius_x`, `radius_y` [m] at indentation `depth` [m] (module
    docstring); `sqrt(R depth)` for a sphere."""
    from scipy.special import ellipe, ellipk

    rx, ry = max(radius_x, radius_y), min(radius_x, radius_y)
    if rx == ry:
        return math.sqrt(rx * depth)

    def ratio(m):  # R_x / R_y of the contact with e^2 = m
        k, e = ellipk(m), ellipe(m)
        return (e / (1.0 - m) - k) / (k - e)

    lo, hi = 1e-12, 1.0 - 1e-15  # ratio increases from 1 to infinity with m
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ratio(mid) < rx / ry else (lo, mid)
    m = 0.5 * (lo + hi)
    k, e = ellipk(m), ellipe(m)
    return math.sqrt(2.0 * rx * depth * (k - e) / (m * k))


def default_extent(args) -> float:
    """The side [m] of the default square (module docstring)."""
    if args.profile is None:
        a = math.sqrt(args.radius * args.depth)
    else:
        a = hertz_semi_major(args.profile[0], args.profile[1], args.depth)
    return EXTENT_FACTOR * a


def simulate_bem(args, t_sim, d_sim, rows):
    """The `BEMSolution` of the options in `args` on the sampled input `d_sim` at `t_sim`
    (the MDR history: relaxed start when `rows` is None, else the approach-hold-lift with
    its corners, `rows` selecting the requested samples)."""
    import equinox as eqx
    import jax.numpy as jnp

    import jaxcontact as jc

    rheology = jc.StandardModel(G0=args.G0, G1=args.G1, eta1=args.eta1)
    extent = args.extent if args.extent is not None else default_extent(args)
    grid = jc.BEMGrid(args.grid, extent)
    if args.profile is None:
        indenter = jc.Parabola(R=args.radius)
    else:
        indenter = jc.ellipsoid_heights(grid, args.profile[0], args.profile[1])
    loading = jc.DisplacementControl()
    if args.stiffness is not None:
        # the history is then the drive position z(t), displacement_m the indentation
        loading = jc.CompliantLoading(stiffness=args.stiffness)
    sol = jc.bem_simulate(
        rheology, indenter, args.work_of_adhesion, jnp.asarray(t_sim), jnp.asarray(d_sim),
        grid=grid, loading=loading,
        relaxed_depth=args.depth if args.hold is None else None, throw=False,
    )
    if bool(sol.details.touches_edge):
        raise UsageError(
            f"argument --extent: the contact reached the edge of the {extent:g} m square; "
            "give a larger --extent"
        )
    if rows is not None:
        sol = eqx.tree_at(
            lambda s: (s.ts, s.displacement, s.force, s.contact_area, s.contact_radius),
            sol,
            (sol.ts[rows], sol.displacement[rows], sol.force[rows], sol.contact_area[rows],
             sol.contact_radius[rows]),
        )
    return sol
