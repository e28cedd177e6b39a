"""``jaxcontact demo``: elastic and viscoelastic pull-off curves of the paper's example."""

from __future__ import annotations

import sys
from pathlib import Path

from ._common import OutputFolder, UsageError

__all__ = ["add_parser", "run"]


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def add_parser(sub, common) -> None:
    p = sub.add_parser(
        "demo", parents=[common],
        help="compute and plot elastic and viscoelastic pull-off curves (writes a PNG)",
    )
    p.add_argument("--out", type=Path, default=Path("demo-output"), help="output folder")
    p.set_defaults(func=run)


def run(args) -> int:
    import jax.numpy as jnp
    import numpy as np

    import jaxcontact as jc

    try:
        import matplotlib  # noqa: F401 - the figure (`_plots.plot_pulloff_demo`) needs it
    except ImportError as err:  # pragma: no cover - depends on the environment
        raise UsageError("the demo needs matplotlib: pip install 'jaxcontact[plot]'") from err
    from ._plots import plot_pulloff_demo

    folder = OutputFolder("--out", args.out, command="demo")
    R, d0, dg = 1e-4, 4e-6, 0.05
    G0, G1, eta1 = 1e6, 2e5, 1e4
    rheology = jc.StandardModel(G0=G0, G1=G1, eta1=eta1)
    profile = jc.Parabola(R=R)
    # elastic JKR curve with the relaxed modulus and the effective work of adhesion
    Ginf = float(rheology.relaxed_modulus)
    dge = dg * G0 / Ginf
    po = jc.pull_off(profile, effective_modulus=4 * Ginf, work_of_adhesion=dge)
    a = jnp.linspace(float(po.radius), np.sqrt(R * d0), 200)
    kw = dict(effective_modulus=4 * Ginf, work_of_adhesion=dge)
    elastic = (np.asarray(jc.jkr_displacement(profile, a, **kw)),
               np.asarray(jc.jkr_force(profile, a, **kw)))
    rows, lifts = [], []
    for v in [1e-6, 1e-4, 1e-3]:
        t_end = 3 * (d0 + abs(float(po.displacement))) / v + 10 * float(rheology.tau)
        ts = jnp.linspace(0, t_end, 4000)
        sol = jc.retract(rheology, profile, work_of_adhesion=dg, depth=d0, velocity=v, ts=ts)
        on = np.asarray(sol.contact_radius) > 0
        lifts.append((v, np.asarray(sol.displacement)[on], np.asarray(sol.force)[on],
                      np.asarray(sol.ts)[on] / t_end, np.asarray(sol.contact_radius)[on]))
        rows.append((v, float(sol.max_tensile_force), float(sol.jumpoff_force),
                     float(sol.jumpoff_time)))
    title = (f"Pull-off of a parabola, standard model\nR = {R * 1e6:g} µm, "
             f"d0 = {d0 * 1e6:g} µm, G0 = {G0:g} Pa, G1 = {G1:g} Pa, "
             f"η1 = {eta1:g} Pa s, Δγ = {dg:g} J/m²")
    lines = ["velocity_m_s,max_tensile_force_N,jumpoff_force_N,jumpoff_time_s"]
    lines += [",".join(f"{x:.10g}" for x in r) for r in rows]
    staging = folder.stage()
    try:
        plot_pulloff_demo(elastic, lifts, title, staging / "pulloff.png")
        (staging / "pulloff.csv").write_text("\n".join(lines) + "\n")
        out = folder.commit()
    finally:
        folder.discard()
    _log(f"wrote {out / 'pulloff.png'} and {out / 'pulloff.csv'}")
    _log(f"parameters: R = {R:g} m, relaxed at depth d0 = {d0:g} m, G0 = {G0:g} Pa, "
         f"G1 = {G1:g} Pa, eta1 = {eta1:g} Pa s, work of adhesion {dg:g} J/m^2")
    for r in rows:
        _log(f"  v = {r[0]:g} m/s: max tensile {r[1]:.4g} N, jump-off {r[2]:.4g} N at "
             f"{r[3]:.4g} s, displacement {d0 - r[0] * r[3]:.4g} m")
    _log("The forces are the same at every speed: from a fully relaxed contact the receding "
         "front is the elastic JKR front with the relaxed modulus and the effective work of "
         f"adhesion Δγ G0/G∞ = {dge:.4g} J/m^2 (dashed line); the speed changes how long the "
         "contact stays pinned, so the jump-off displacement and the work of separation "
         "depend on it (jaxcontact sweep plots separation_work_J against speed).")
    return 0
