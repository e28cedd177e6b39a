"""Fits of real instrument curves: does the default search reach the best optimum?

For every file given (the first curve of each; files that nothing reads are listed as
such), `fitting.fit` runs

1. with the default number of starts (`fitting.DEFAULT_STARTS`) and with `--brute` starts
   (a brute-force search over the same bounded ranges with another seed), standard model;
2. the same for `prony:2` (nested: it starts from the standard optimum as well);

and the table reports R², R² in contact, χ² and the wall time of each, whether the default
search reached the brute-force χ² (relative difference below 1e-6, or lower), and whether
`prony:2` ended at least as good as `standard` (the issue's acceptance checks). The model
is `--model`: "history" by default (the whole approach-(hold-)retract, as `jaxcontact fit`
fits an instrument file), "relaxed" (the retract after a relaxed start: a poor model for a
curve without a hold), or "auto" (history for curves with a hold segment, relaxed
otherwise); the probe radius is `--radius` (files rarely store it; moduli scale with
it, the quality of the fit does not). The contact point is fitted (the default for
instrument files).

Curves used during development: the shipped `tests/data` files. Held-out curves (never used
to tune anything): `benchmarks/data/` (afmformats test data, MIT licence) and further
afmformats test files (`git show HEAD:tests/data/<name>` in a clone of
github.com/AFM-analysis/afmformats), e.g. `fmt-jpk-fd_single-modified_2023.jpk-force`,
`fmt-hdf5-fd_version_0.13.3.h5`.

A file that lacks metadata takes loader options after an ``@``, e.g.
``ws.csv@spring_constant=0.2,sensitivity=5e-8,sample_rate=1000`` (AFM Workshop).

    python benchmarks/eval_real_fits.py FILE[@OPT=V,...] [FILE ...] [--brute 64] [--radius 10e-6]
        [--max-samples 300] [--out benchmarks/results/real_fits.md]

Writes the table (with machine and date) to `--out` and prints it.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time
import warnings

import jax
from _results import machine, write_table  # benchmarks/_results.py

import fitting

jax.config.update("jax_enable_x64", True)


def _one(curve, model, rheology, starts, seed, args):
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = fitting.fit(curve, radius=args.radius, model=model, rheology=rheology,
                          n_starts=starts, seed=seed, max_samples=args.max_samples,
                          progress=False)
    return res, time.perf_counter() - t0


def _reached(chi2, best):
    return chi2 <= best * (1 + 1e-6) + 1e-12


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="+")
    ap.add_argument("--brute", type=int, default=64, help="starts of the brute-force search")
    ap.add_argument("--radius", type=float, default=10e-6, help="probe radius [m]")
    ap.add_argument("--max-samples", type=int, default=None)
    ap.add_argument("--out", default="benchmarks/results/real_fits.md")
    ap.add_argument("--model", choices=("history", "relaxed", "auto"), default="history",
                    help="history: the whole curve, as `jaxcontact fit` does by default; "
                         "relaxed: the retract after a relaxed start; auto: history for "
                         "curves with a hold segment, relaxed otherwise")
    ap.add_argument("--rheologies", default="standard,prony:2",
                    help="comma-separated rheologies to compare (default standard,prony:2)")
    ap.add_argument("--history-rheologies", default=None,
                    help="the same for curves fitted with the history model (default: as "
                         "--rheologies; prony:2 brute-force fits of long history curves take "
                         "minutes each)")
    args = ap.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)

    rows = []
    for item in args.files:
        path, _, opts = item.partition("@")
        name = pathlib.Path(path).name + (f" ({opts})" if opts else "")
        try:
            load_kw = {k: float(v) for k, v in
                       (o.split("=", 1) for o in opts.split(",") if o)}
            curve = fitting.load_curve(path, **load_kw)[0]
        except Exception as exc:  # noqa: BLE001 - reported in the table
            rows.append(f"| {name} | - | not loaded: {type(exc).__name__}: "
                        f"{str(exc)[:200]} | | | | | | | |")
            print(rows[-1], flush=True)
            continue
        model = args.model
        if model == "auto":
            model = "history" if "hold" in curve.segment_names else "relaxed"
        chi2 = {}
        chosen = args.history_rheologies if model == "history" and args.history_rheologies \
            else args.rheologies
        for rheology in [r.strip() for r in chosen.split(",") if r.strip()]:
            out = {}
            for label, starts, seed in (("default", None, 0), ("brute", args.brute, 1)):
                try:
                    res, dt = _one(curve, model, rheology, starts, seed, args)
                except Exception as exc:  # noqa: BLE001 - reported in the table
                    out[label] = None
                    rows.append(f"| {name} | {model} {rheology} {label} | failed: "
                                f"{type(exc).__name__}: {str(exc)[:200]} | | | | | | | |")
                    print(rows[-1], flush=True)
                    continue
                out[label] = (res, dt)
            if out.get("default") is None or out.get("brute") is None:
                continue
            (res, dt), (bres, bdt) = out["default"], out["brute"]
            chi2[rheology] = min(res.chi2, bres.chi2)
            reached = _reached(res.chi2, bres.chi2)
            nested = ""
            if rheology == "prony:2" and "standard" in chi2:
                nested = "yes" if res.chi2 <= chi2["standard"] * (1 + 1e-6) else "**no**"
            gap = (res.chi2 - bres.chi2) / bres.reduced_chi2
            rows.append(
                f"| {name} | {model} {rheology} | {res.r_squared:.4f} / "
                f"{res.r_squared_contact:.4f} | {bres.r_squared:.4f} / "
                f"{bres.r_squared_contact:.4f} | {res.chi2:.9g} | {bres.chi2:.9g} | "
                f"{gap:+.3g} | {'yes' if reached else '**no**'} | {nested} | "
                f"{dt:.1f} / {bdt:.1f} |")
            print(rows[-1], flush=True)

    head = [
        "# Fits of real curves: default search against brute force",
        "",
        f"{machine()}; default starts "
        f"{fitting.DEFAULT_STARTS}, brute force {args.brute} starts (another seed); radius "
        f"{args.radius:g} m; local rounds {fitting.DEFAULT_LOCAL_ROUNDS} in both; "
        f"`python benchmarks/eval_real_fits.py {' '.join(args.argv)}`.",
        "",
        "R² over all fitted samples / over the samples in contact; χ² of the default and the "
        "brute-force search; Δχ²/χ²_red: their difference in units of the brute-force "
        "reduced χ² (below 1: the two optima are statistically indistinguishable, the "
        "difference in the log-likelihood under the fitted noise level is below 1/2); "
        "*reached*: the default search ends at the brute-force χ² or "
        "lower; *prony:2 ≥ standard*: the nested fit is at least as good; times [s] of one "
        "fit each (compilation included: each fit compiles its own programs).",
        "",
        "| file | model | R² default (all / contact) | R² brute | χ² default | χ² brute | "
        "Δχ²/χ²_red | reached | prony:2 ≥ standard | time default / brute [s] |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    write_table(args.out, head + rows)


if __name__ == "__main__":
    main()
