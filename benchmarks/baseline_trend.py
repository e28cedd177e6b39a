"""Real curves whose free force before contact has a trend: how often the `baseline_trend`
flag fires, how far a linear baseline moves the detected contact point, and what it changes
in a fit.

For every file given, every curve is loaded twice, with the loader's default (constant)
baseline and with ``baseline="linear"``; reported per file: the curves, the median and
largest rise of the free force's straight line by the end of the approach in units of its
scatter (``ContactPoint.trend / trend_noise``), the curves flagged (the rise at least
:data:`fitting._quality.TREND_SIGMA` times both the scatter and its standard error), the
constant baseline's noise over the scatter about the line (median), and the median and
largest shift of the detected contact (tip position, linear minus constant). With `--fit`,
a file's first curve is also fitted with both baselines (`fitting.fit`, full-history
standard model, a paraboloid of `--radius`, contact point fitted, default search): χ²_red
(against each run's own noise estimate, and both against one noise, the free force's
scatter about its straight line, so that the baselines compare), R² in contact,
the fitted contact (tip position, detected plus the fitted offset) and the relative change
of G0, G1, η1, Δγ.

    python benchmarks/baseline_trend.py FILE [FILE ...] [--fit] [--radius 10e-6]
        [--out benchmarks/results/baseline_trend.md]
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
from fitting._quality import TREND_SIGMA

jax.config.update("jax_enable_x64", True)

MATERIAL = ("G0", "G1", "eta1", "work_of_adhesion")


def _curves(path: str, baseline: str) -> list:
    return [c for c in fitting.load_curve(path, baseline=baseline, on_error="keep")
            if isinstance(c, fitting.Curve)]


def _stats(path: str) -> str:
    const, lin = _curves(path, "constant"), _curves(path, "linear")
    cps = [c.contact for c in const]
    rise = np.array([abs(cp.trend) / cp.trend_noise for cp in cps])
    flagged = sum(abs(cp.trend) >= TREND_SIGMA * max(cp.trend_noise, cp.trend_error)
                  for cp in cps)
    inflation = np.array([cp.noise / cp.trend_noise for cp in cps])
    shift = np.array([b.contact.tip_position - a.contact.tip_position
                      for a, b in zip(const, lin, strict=True)]) if len(lin) == len(const) \
        else np.array([np.nan])
    big = shift[np.argmax(np.abs(shift))]
    return (f"{len(cps)} | {np.median(rise):.1f} / {rise.max():.1f} | {flagged} | "
            f"{np.median(inflation):.2f} | {np.median(shift) * 1e6:+.3g} / "
            f"{big * 1e6:+.3g}")


def _fit(path: str, baseline: str, radius: float):
    curve = fitting.load_curve(path, baseline=baseline)[0]
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = fitting.fit(curve, radius=radius, model="history", progress=False)
    contact = curve.contact.tip_position - res["contact_offset"]
    return res, curve.contact, contact, time.perf_counter() - t0


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="+")
    ap.add_argument("--fit", action="store_true")
    ap.add_argument("--radius", type=float, default=10e-6)
    ap.add_argument("--out", default="benchmarks/results/baseline_trend.md")
    args = ap.parse_args(argv)
    names = " ".join(pathlib.Path(f).name for f in args.files)
    lines = [
        "# A trend in the free force before contact, on real curves",
        "",
        f"{machine()}; `python benchmarks/{pathlib.Path(__file__).name} {names}"
        f"{' --fit' if args.fit else ''} --radius {args.radius:g}`. *rise*: the free "
        "force's straight line in time, its rise by the end of the approach over its "
        "scatter about the line (median / largest over the file's curves); *flagged*: "
        f"curves `baseline_trend` names (rise ≥ {TREND_SIGMA:g} × the scatter and × its "
        "standard error); *noise ratio*: the constant baseline's noise estimate over the "
        "scatter about the line (median); *contact shift*: the detected contact's tip "
        "position with a linear baseline minus with a constant one [µm] (median / largest).",
        "",
        "| file | curves | rise [σ] (median / max) | flagged | noise ratio | contact shift "
        "[µm] (median / largest) |",
        "|---|---|---|---|---|---|",
    ]
    fits = []
    for f in args.files:
        name = pathlib.Path(f).name
        try:
            lines.append(f"| {name} | {_stats(f)} |")
        except (ValueError, OSError) as exc:
            lines.append(f"| {name} | not loaded: {' '.join(str(exc).split())[:120]} |")
            continue
        print(lines[-1], file=sys.stderr, flush=True)
        if args.fit:
            try:
                (a, pa, ca, ta), (b, pb, cb, tb) = (_fit(f, bl, args.radius)
                                                    for bl in ("constant", "linear"))
            except (ValueError, OSError) as exc:
                fits.append(f"| {name} | not fitted: {' '.join(str(exc).split())[:120]} |")
                continue
            change = ", ".join(f"{b[k] / a[k] - 1:+.0%}" for k in MATERIAL)
            unit = pa.trend_noise  # one noise for both: the scatter about the free line
            for label, r, cp, c, dt, ch in (("constant", a, pa, ca, ta, ""),
                                            ("linear", b, pb, cb, tb, change)):
                flags = ", ".join(r.flags) or "ok"
                common = r.reduced_chi2 * (cp.noise / unit) ** 2
                fits.append(f"| {name} | {label} | {r.reduced_chi2:.4g} | {common:.4g} | "
                            f"{r.r_squared_contact:.4f} | {c * 1e6:.3f} | {flags} | {ch} | "
                            f"{dt:.0f} |")
            print(*fits[-2:], sep="\n", file=sys.stderr, flush=True)
    if fits:
        lines += ["", "Fits of each file's first curve (full-history standard model, contact "
                  "point fitted, default search): *χ²_red* against each run's own noise "
                  "estimate; *χ²_red, one noise*: both against the scatter of the free force "
                  "about its straight line (the constant baseline's run's `trend_noise`), so "
                  "that the two baselines compare; *fitted contact*: the detected contact's "
                  "tip position less the fitted offset [µm]; *change*: G0, G1, η1, Δγ from "
                  "the constant to the linear baseline.", "",
                  "| file | baseline | χ²_red | χ²_red, one noise | R² in contact | fitted "
                  "contact [µm] | flags | change (G0, G1, η1, Δγ) | time [s] |",
                  "|---|---|---|---|---|---|---|---|---|", *fits]
    write_table(args.out, lines)


if __name__ == "__main__":
    main()
