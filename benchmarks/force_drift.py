"""Real curves fitted with and without a fitted force drift (`FitOptions.force_drift`: the
model force plus a line F0 + s t): does the drift lower χ² by more than its two
parameters, is it the free force's own slope, and what does it change in the values?

For every file given, its first curve is loaded with the loader's default (constant)
baseline and fitted twice with the standard model (`--model`: the full history by
default, or the relaxed start; a paraboloid of `--radius`, contact point fitted, default
search): as it is and with the drift. Both fits
see the same preprocessed curve; the drift fit's noise is the free force's scatter about
its straight line (`ContactPoint.trend_noise`), the other's the scatter about the constant
baseline, so their χ² are compared in one noise (the drift fit's). Reported: χ²_red of both
(each against its own noise), the ratio of their χ² in one noise, ΔBIC in one noise (drift
minus none, with the drift's two parameters: below −10 the data clearly want it), the
fitted drift with its standard error, the free force's own slope before contact
(`ContactPoint.trend_slope`, with its standard error: what the drift is where it is a
baseline), the line's change over the fitted curve in units of the curve's noise
(|s| T / σ), the relative change of G0, G1, η1, Δγ, the flags of both fits and the time.

    python benchmarks/force_drift.py FILE [FILE ...] [--radius 10e-6] [--model history]
        [--out benchmarks/results/force_drift.md]

(`--model relaxed` gave `results/force_drift_relaxed.md` with the library of commit
b7c41e2; since then the relaxed model refuses the drift, for the reasons that file gives,
and its rows say so.)
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time
import warnings

import jax
import numpy as np
from _results import machine, write_table  # benchmarks/_results.py

import fitting

jax.config.update("jax_enable_x64", True)

MATERIAL = ("G0", "G1", "eta1", "work_of_adhesion")


def _fit(curve, radius: float, model: str, **kw):
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = fitting.fit(curve, radius=radius, model=model, progress=False, **kw)
    return res, time.perf_counter() - t0


def _row(name: str, curve, radius: float, model: str) -> str:
    (a, ta), (b, tb) = _fit(curve, radius, model), _fit(curve, radius, model, force_drift=True)
    j = b.names.index("force_drift")
    s, se = b.values[j], b.stderr[j]
    valid = np.asarray(b.data.valid)[0] > 0
    span = float(np.ptp(np.asarray(b.data.ts)[0][valid]))
    sigma_b, sigma_a = (float(np.asarray(r.data.sigma)[0]) for r in (b, a))
    chi2_a = a.chi2 * (sigma_a / sigma_b) ** 2  # the fit without the drift in b's noise
    dbic = b.chi2 - chi2_a + (b.n_free - a.n_free) * np.log(b.n_data)
    cp = curve.contact
    free = f"{cp.trend_slope - cp.force_slope:.3g} ± {cp.trend_slope_error:.2g}"
    change = ", ".join(f"{b[k] / a[k] - 1:+.0%}" for k in MATERIAL)
    return (f"| {name} | {a.reduced_chi2:.4g} | {b.reduced_chi2:.4g} | {b.chi2 / chi2_a:.3g} | "
            f"{dbic:+.4g} | {s:.3g} ± {se:.2g} | {free} | {abs(s) * span / sigma_b:.3g} | "
            f"{change} | {', '.join(a.flags) or 'ok'} | {', '.join(b.flags) or 'ok'} | "
            f"{ta:.0f} / {tb:.0f} |")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="+")
    ap.add_argument("--radius", type=float, default=10e-6)
    ap.add_argument("--model", choices=("history", "relaxed"), default="history")
    ap.add_argument("--out", default="benchmarks/results/force_drift.md")
    args = ap.parse_args(argv)
    names = " ".join(pathlib.Path(f).name for f in args.files)
    rows = []
    for f in args.files:
        name = pathlib.Path(f).name
        try:
            curve = next(c for c in fitting.load_curve(f, on_error="keep")
                         if isinstance(c, fitting.Curve))
            rows.append(_row(name, curve, args.radius, args.model))
        except (ValueError, OSError, StopIteration) as exc:
            rows.append(f"| {name} | not fitted: {' '.join(str(exc).split())[:120]} |")
        print(rows[-1], file=sys.stderr, flush=True)
    lines = [
        "# A fitted force drift on real curves",
        "",
        f"{machine()}; `python benchmarks/{pathlib.Path(__file__).name} {names} --radius "
        f"{args.radius:g} --model {args.model}`. Each file's first curve, constant "
        f"baseline, the standard model ({args.model}), contact point fitted, default "
        "search; fitted as it is (*none*) "
        "and with `force_drift=True` (*drift*: the model force plus F0 + s t). *χ²_red*: "
        "each against its own noise (the drift fit's: the scatter about the free line); "
        "*χ² ratio*: drift over none in one noise (the drift fit's); *ΔBIC*: drift − none "
        "in one noise (< −10: the data clearly want the drift; it adds two parameters); "
        "*free slope*: the free force's own slope before contact (what the drift is where "
        "it is a baseline; `drift_not_baseline` flags a drift 5 standard errors away from "
        "it); *line over the curve*: |s| T / σ, the fitted line's change over the fitted "
        "samples' duration T in units of the drift fit's noise σ; *change*: G0, G1, η1, Δγ "
        "from none to drift; *time*: none / drift [s].",
        "",
        "| file | χ²_red none | χ²_red drift | χ² ratio | ΔBIC | drift s [N/s] | free slope "
        "[N/s] | line over the curve [σ] | change (G0, G1, η1, Δγ) | flags none | flags "
        "drift | time [s] |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
        *rows,
    ]
    write_table(args.out, lines)


if __name__ == "__main__":
    main()
