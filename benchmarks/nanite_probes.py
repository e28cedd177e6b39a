"""The probes against nanite's indenter models, on the same indentations.

nanite (PyPI, the field's fitting tool) is not a dependency: install it beside the project,
e.g. ``pip install --target /tmp/nanite nanite``, and run

    python benchmarks/nanite_probes.py --nanite /tmp/nanite

The folder is appended to the end of ``sys.path`` (the project's numpy/scipy win). For every
probe and indentation the non-adhesive elastic force of jaxcontact (`jkr_force` with
$\\Delta\\gamma = 0$ at `profile_radius(d)`, $E^* = E/(1-\\nu^2) = 4G$, $\\nu = 0.5$) is
compared with nanite's model function called as nanite calls it (indentation $-\\delta$ beyond
the contact point). nanite 4.2.3 has no four-sided pyramid: its row gives Bilodeau's (1992)
formula instead. Writes ``benchmarks/results/probes.md``.
"""

from __future__ import annotations

import argparse
import importlib
import math
import sys

import numpy as np
from _results import machine, write_table

import jaxcontact as jc

E, NU = 3e3, 0.5  # Young's modulus [Pa], Poisson's ratio (incompressible)
R = 10e-6  # sphere radius [m]
DEPTHS = [0.01, 0.1, 0.3, 0.6, 1.0]  # indentation / R for the sphere; times 1 um for tips


def _nanite(module, function):
    return getattr(importlib.import_module(f"nanite.model.{module}"), function)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nanite", default="/tmp/nanite", help="folder with nanite installed")
    ap.add_argument("--out", default="benchmarks/results/probes.md")
    args = ap.parse_args(argv)
    sys.path.append(args.nanite)
    import nanite  # noqa: F401 (fails here if not installed)

    version = importlib.import_module("nanite").__version__
    e_star = E / (1 - NU**2)
    sphere_approx = _nanite("model_sneddon_spherical_approximation",
                            "hertz_sneddon_spherical_approx")
    paraboloid = _nanite("model_hertz_paraboloidal", "hertz_paraboloidal")
    cone = _nanite("model_conical_indenter", "hertz_conical")
    pyr3 = _nanite("model_hertz_three_sided_pyramid", "hertz_three_sided_pyramid")

    def ours(profile, d):
        a = jc.profile_radius(profile, np.asarray(d))
        return np.asarray(jc.jkr_force(profile, a, effective_modulus=e_star,
                                       work_of_adhesion=0.0))

    rows = []
    d_sphere = np.array(DEPTHS) * R
    d_tip = np.array(DEPTHS) * 1e-6
    cases = [
        ("jc.Sphere(10 µm) vs nanite sneddon_spherical_approx (series)", jc.Sphere(R), d_sphere,
         sphere_approx(-d_sphere, E, R, NU)),
        ("jc.Parabola(10 µm) vs nanite hertz_paraboloidal", jc.Parabola(R), d_sphere,
         paraboloid(-d_sphere, E, R, NU)),
        ("jc.Cone(20°) vs nanite hertz_cone", jc.Cone(math.radians(20)), d_tip,
         cone(-d_tip, E, 20.0, NU)),
        ("jc.pyramid(20°, 3) vs nanite hertz_pyr3s", jc.pyramid(math.radians(20), 3), d_tip,
         pyr3(-d_tip, E, 20.0, NU)),
        ("jc.pyramid(20°, 4) vs Bilodeau 1992 (not in nanite)", jc.pyramid(math.radians(20), 4),
         d_tip, 1.4906 / 2 * math.tan(math.radians(20)) * e_star * d_tip**2),
        ("jc.Sphere(10 µm) vs nanite hertz_paraboloidal (the approximation's error)",
         jc.Sphere(R), d_sphere, paraboloid(-d_sphere, E, R, NU)),
    ]
    for name, profile, d, ref in cases:
        mine = ours(profile, d)
        for di, f_ref, f_mine in zip(d, ref, mine, strict=True):
            rows.append(f"| {name} | {di:.3g} | {f_ref:.6g} | {f_mine:.6g} | "
                        f"{f_mine / f_ref - 1:+.2e} |")
    lines = [
        "# Probes against nanite",
        "",
        f"Measured {machine()}, nanite {version}: `python benchmarks/nanite_probes.py`.",
        f"E = {E:g} Pa, ν = {NU} (E* = 4G = {e_star:g} Pa); non-adhesive elastic force at the",
        "same indentation. nanite's Sneddon sphere is its (and JPK's) truncated series of the",
        "exact solution, so the exact `Sphere` departs from it only by the truncation; the last",
        "rows show how far the paraboloid (`--radius`) is from the exact sphere.",
        "",
        "| probe | indentation [m] | nanite (or reference) F [N] | jaxcontact F [N] | relative |",
        "|---|---|---|---|---|",
        *rows,
    ]
    write_table(args.out, lines)


if __name__ == "__main__":
    main()
