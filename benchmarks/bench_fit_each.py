"""Force maps: curves fitted per second by `fitting.fit_each` against one `fitting.fit` per
curve, in the same run.

A synthetic map of `--curves` retract curves (`jc.retract`, relaxed start, 1 % noise, the
standard model with G0, G1, η1 and Δγ varying from point to point by up to ±30 %),
`--samples` samples each, fitted with the default search (16 starts and the local
rounds), R = 12 µm. Timed: `fit_each` cold (compilation included) and warm (median of
`--repeats` calls), for each `--chunks` value, with the warm time split into its stages
(`FitEachResult.timings`: prepare, optimise, finish; ms a curve); the loop of `fit` over
the same curves (its compilation is shared by all curves after the first: equal shapes;
left out with `--no-loop`). Reported: curves/s, the Levenberg–Marquardt steps a curve
(the cost, independent of the machine's load), the ratio to the loop, and the largest
relative difference of the fitted values between the two (the same optimum is expected),
and the curves whose χ² is at most the loop's.

    python benchmarks/bench_fit_each.py [--curves 32] [--samples 60] [--chunks 8,32]
        [--streams 1,2] [--repeats 1] [--no-loop] [--quick] [--model relaxed|history]
        [--out -]

`--streams`: chunks searched at once (`fitting.BatchOptions.streams`), each value timed
in turn (default: the library's default, one per usable core on a CPU); the χ² of every
curve is compared with the first value's (the results do not depend on it).

`--quick`: 8 curves, chunk 8, no loop, written to stdout only (a smoke run, e.g. on a
GPU machine: about a minute on 2 CPU cores, mostly compilation).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
import warnings

import jax
import numpy as np
from _results import machine, write_table  # benchmarks/_results.py

import fitting
import jaxcontact as jc

jax.config.update("jax_enable_x64", True)

R, D0, V = 12e-6, 1e-6, 2e-6
BASE = {"G0": 10e3, "G1": 5e3, "eta1": 7.5e3, "work_of_adhesion": 1e-3}


def _noisy_map(n: int, seed: int, force_of=None, *, samples: int | None = None,
               forces_of=None) -> list[fitting.Curve]:
    """`n` curves of parameters varying by up to ±30 % around `BASE`, 1 % noise:
    `force_of(p)` gives `(ts, displacement, force, segment, segment_names)` of one curve;
    or `forces_of(P)` those of all (`P`: arrays of `n` values; the force `(n, samples)`)."""
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(n)))
    draws = []
    for _ in range(n):  # the draws in the order of one curve after the other
        p = {k: v * rng.uniform(0.7, 1.3) for k, v in BASE.items()}
        draws.append((p, rng.standard_normal(samples) if samples is not None else rng))
    if forces_of is not None:
        ts, disp, force, seg, names = forces_of({k: np.array([p[k] for p, _ in draws])
                                                for k in BASE})
        each = [(ts, disp, force[i], seg, names) for i in range(n)]
    out = []
    for i, (p, noise) in enumerate(draws):
        ts, disp, f, seg, names = each[i] if forces_of is not None else force_of(p)
        if samples is None:
            noise = rng.standard_normal(ts.size)
        f = f + 0.01 * np.ptp(f) * noise
        out.append(fitting.Curve(
            time=ts, displacement=disp, force=f, segment=seg, segment_names=names,
            metadata={"grid index x": i % side, "grid index y": i // side}))
    return out


def make_map(n: int, samples: int, seed: int = 0) -> list[fitting.Curve]:
    """Retract curves from a relaxed contact (`jc.retract`, vmapped over the curves) at
    constant speed."""
    ts = np.linspace(0.0, 3e-6 / V, samples)

    def one(g0, g1, eta1, w):
        sol = jc.retract(jc.StandardModel(g0, g1, eta1), jc.Parabola(R), work_of_adhesion=w,
                         depth=D0, ts=ts, velocity=V)
        return sol.displacement, sol.force

    def forces_of(P):
        disp, force = jax.jit(jax.vmap(one))(P["G0"], P["G1"], P["eta1"],
                                             P["work_of_adhesion"])
        return (ts, np.asarray(disp[0]), np.asarray(force), np.zeros(samples, int),
                ("retract",))

    return _noisy_map(n, seed, samples=samples, forces_of=forces_of)


def make_history_map(n: int, samples: int, seed: int = 0) -> list[fitting.Curve]:
    """QI-like approach-retract curves without a hold (`jc.simulate`, full history, vmapped
    over the curves): the indentation rises linearly to `D0` and falls back to -0.5 `D0`
    (the probe detaches)."""
    half = samples // 2
    ts = np.linspace(0.0, 2 * D0 / V * 1.25, samples)
    d = np.r_[np.linspace(0.0, D0, half), np.linspace(D0, -0.5 * D0, samples - half)]
    seg = np.r_[np.zeros(half, int), np.ones(samples - half, int)]

    def one(g0, g1, eta1, w):
        return jc.simulate(jc.StandardModel(g0, g1, eta1), jc.Parabola(R), w, ts, d).force

    def forces_of(P):
        force = jax.jit(jax.vmap(one))(P["G0"], P["G1"], P["eta1"], P["work_of_adhesion"])
        return ts, d, np.asarray(force), seg, ("approach", "retract")

    return _noisy_map(n, seed, samples=samples, forces_of=forces_of)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--curves", type=int, default=32)
    ap.add_argument("--samples", type=int, default=60)
    ap.add_argument("--chunks", default="8,32")
    ap.add_argument("--streams", default="",
                    help="comma-separated values of BatchOptions.streams to time (default: "
                         "the library's default only)")
    ap.add_argument("--search-cells", default="",
                    help="comma-separated values of FitOptions.search_cells to time (history "
                         "model; default: the library's default only); each row's chi2 is "
                         "compared with the first value's")
    ap.add_argument("--abandon", default="",
                    help="comma-separated values of FitOptions.abandon to time ('none': no "
                         "start abandoned; default: the library's default only); each row's "
                         "chi2 is compared with the first value's")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--no-loop", action="store_true", help="leave out the loop of fit")
    ap.add_argument("--quick", action="store_true",
                    help="8 curves, chunk 8, no loop, no file written")
    ap.add_argument("--model", default="relaxed", choices=("relaxed", "history"),
                    help="relaxed: retract curves from a relaxed contact (`make_map`); "
                         "history: QI-like approach-retract curves (`make_history_map`)")
    ap.add_argument("--profile", default="paraboloid", choices=("paraboloid", "sphere"),
                    help="the indenter the curves are fitted with, of radius R (the curves are "
                         "made with the paraboloid; their relaxed contacts reach ~0.3 R, where "
                         "the two forces differ by ~1 %%)")
    ap.add_argument("--out", default="-",
                    help="'-' (default): print the table; a path: write it there (replaced: "
                         "benchmarks/results/fit_each.md holds hand-written sections, so "
                         "paste a run's table into it rather than writing over it)")
    args = ap.parse_args(argv)
    if args.quick:
        args.curves, args.chunks, args.no_loop = 8, "8", True
    curves = (make_map if args.model == "relaxed" else make_history_map)(args.curves,
                                                                          args.samples)
    probe = {"radius": R} if args.profile == "paraboloid" else {"profile": jc.Sphere(R)}
    fit_kw = {**probe, "model": args.model, "progress": False}
    warnings.simplefilter("ignore")

    rows, ref, chi_ref, t_loop = [], None, None, None
    if not args.no_loop:
        t0 = time.perf_counter()
        [fitting.fit(c, **fit_kw) for c in curves]
        t_cold = time.perf_counter() - t0
        t0 = time.perf_counter()
        loop = [fitting.fit(c, **fit_kw) for c in curves]
        t_loop = time.perf_counter() - t0
        ref = np.array([r.values for r in loop])
        chi_ref = np.array([r.chi2 for r in loop])
        steps = float(np.mean([np.sum(r.start_steps) for r in loop]))
        rows.append(f"| loop of `fit` | - | - | {t_cold:.1f} | {t_loop:.1f} | "
                    f"{args.curves / t_loop:.2f} | | | | {steps:.0f} | 1 | - | - |")
        print(rows[-1], flush=True)
    streams = [int(k) for k in args.streams.split(",") if k] or [None]
    grids = [int(k) for k in args.search_cells.split(",") if k] or [None]
    abandons = [None if a == "none" else float(a) for a in args.abandon.split(",") if a] \
        or [fitting.DEFAULT_ABANDON]
    chi_first = {}
    for chunk, k, grid, ab in ((int(c), k, g, a) for c in args.chunks.split(",")
                               for k in streams for g in grids for a in abandons):
        kw = dict(fit_kw, chunk=chunk, streams=k, search_cells=grid, abandon=ab)
        t0 = time.perf_counter()
        fitting.fit_each(curves, **kw)
        cold = time.perf_counter() - t0
        warm, stages = [], []
        for _ in range(max(1, args.repeats)):
            t0 = time.perf_counter()
            res = fitting.fit_each(curves, **kw)
            warm.append(time.perf_counter() - t0)
            stages.append(res.timings)
        w = statistics.median(warm)
        ms = {s: 1e3 * statistics.median(t[s] for t in stages) / args.curves
              for s in ("prepare", "optimise", "finish")}
        chi = np.array([r.chi2 for r in res.results])
        same = ""
        if chunk in chi_first:
            first = chi_first[chunk]
            same = f" (χ² of every curve equal to the first row's of this chunk: " \
                   f"{bool(np.array_equal(chi, first))}; relative to it: " \
                   f"{float(np.min(chi / first - 1)):+.2e} to " \
                   f"{float(np.max(chi / first - 1)):+.2e}, " \
                   f"{int(np.sum(chi <= first * (1 + 1e-9)))}/{args.curves} within +1e-9)"
        chi_first.setdefault(chunk, chi)
        steps = float(np.mean([np.sum(r.start_steps) + (0 if r.polish_steps is None else
                                                         np.sum(r.polish_steps))
                               for r in res.results]))
        if ref is not None:
            diff = f"{float(np.max(np.abs(res.values() / ref - 1))):.1e}"
            lower = f"{int(np.sum(chi <= chi_ref * (1 + 1e-9)))}/{args.curves}"
            ratio = f"{t_loop / w:.2f}"
        else:
            diff = lower = ratio = "-"
        n_streams = fitting.BatchOptions(streams=k).streams_for(
            -(-args.curves // chunk))
        label = "`fit_each`" if grid is None else f"`fit_each`, search on {grid} cells"
        if ab != fitting.DEFAULT_ABANDON:
            label += f", abandon {ab}"
        rows.append(f"| {label} | {chunk} | {n_streams} | {cold:.1f} | {w:.2f} | "
                    f"{args.curves / w:.2f} | {ms['prepare']:.1f} | "
                    f"{ms['optimise']:.1f} | {ms['finish']:.1f} | {steps:.0f} | "
                    f"{ratio} | {diff} | {lower} |")
        print(rows[-1], flush=True)
        print(f"  chi2 sum {float(np.sum(chi)):.12g}{same}", flush=True)
    head = [
        "# Force-map fits: `fitting.fit_each` against a loop of `fitting.fit`",
        "",
        f"{machine()}, {jax.devices()[0].platform} ({len(jax.devices())} device(s)); "
        f"{args.curves} synthetic curves × {args.samples} samples, {args.model} model, default "
        f"search ({fitting.DEFAULT_STARTS} starts, up to {fitting.DEFAULT_LOCAL_ROUNDS} "
        f"local rounds); `python benchmarks/bench_fit_each.py {' '.join(sys.argv[1:])}`.",
        "",
        "Times in s. *streams*: chunks searched at once; *cold*: the first call (compilation "
        "included); *warm*: median of the repeats; *prepare*, *optimise*, *finish*: the warm "
        "stages in ms a curve (*optimise*: the time the pipeline waited for the searches, "
        "which overlap each other and the finish); ratio: the "
        "loop's warm time over the warm `fit_each` time; *LM steps*: Levenberg–Marquardt "
        "steps a curve, all starts and rounds (each one Jacobian: the cost, whatever the "
        "machine's load); *max rel. diff.*: largest relative "
        "difference of a fitted value from the loop's; *χ² ≤ loop*: curves whose χ² is at "
        "most the loop's (a chunk runs its local rounds while any of its curves improves, so "
        "a curve may get more rounds than alone).",
        "",
        "| method | chunk | streams | cold [s] | warm [s] | curves/s (warm) | prepare [ms] | "
        "optimise [ms] | finish [ms] | LM steps | ratio | max rel. diff. | χ² ≤ loop |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    if args.quick or args.out == "-":
        print("\n".join(head + rows))
    else:
        write_table(args.out, head + rows)


if __name__ == "__main__":
    main()
