"""One short run on an accelerator: the identification and sweep rows of the benchmark
tables that need a GPU (issues: identification at scale, sweeps at device speed).

    PYTHONPATH=. python benchmarks/device_check.py [--fit-curves 128,4096,16384]
        [--baseline-workers 64] [--history-fit 256] [--sweep-max 10000000]
        [--history 32768,131072] [--repeats 2] [--search JSON ...]
        [--history-search JSON ...] [--history-options JSON]

Prints markdown rows (warm medians of `--repeats` calls after one cold call):
`fitting.fit_each` on the synthetic relaxed-start map of `bench_fit_each.py` with the
platform's default schedule (curves/s, the per-stage split, LM steps a curve, peak device
memory), on the first size also with the CPU's schedule as a paired baseline (and every
curve's χ² compared), and on full-history QI-like maps (`make_history_map`, 200 samples);
`jc.sweep` relaxed-start summaries at 10^4..`--sweep-max` points in
float32 and float64 (curves/s); full-history sweeps at `--history` curves in float32. Runs on
the CPU too (smaller sizes), which is how it is smoke-tested.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
import warnings

import jax
import numpy as np

import fitting
import jaxcontact as jc

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from bench_fit_each import R, make_history_map, make_map  # noqa: E402


def timed(fn, repeats):
    """(cold, warm median, output): `repeats` warm calls after the first (0: warm = cold)."""
    t0 = time.perf_counter()
    out = fn()
    cold = time.perf_counter() - t0
    warm = [] if repeats else [cold]
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        warm.append(time.perf_counter() - t0)
    return cold, statistics.median(warm), out


def _peak_gib():
    stats = jax.devices()[0].memory_stats() or {}
    return stats.get("peak_bytes_in_use", float("nan")) / 2**30


def fit_rows(curves, sizes, baseline_workers, model, repeats, searches=(), base=None):
    """`fitting.fit_each` on the first `n` of `curves` for each `n` of `sizes` with the
    platform's default schedule (`BatchOptions()`: chunk and lanes) and the search options
    `base` (a dict as `searches`' below; default none: the default search); on the first size
    also the CPU schedule (`chunk=n, workers=baseline_workers`) for a paired baseline, and
    each of `searches` (dicts of search options of `fitting.FitOptions`, e.g. ``{"screen":
    1024, "n_starts": 8}``), with the χ² of every curve compared to the default's."""
    kw = dict(radius=R, progress=False, model=model)
    print(f"\n{model} model, {curves[0].time.size} samples a curve, default search\n\n"
          "| schedule | curves | chunk | lanes | cold [s] | warm [s] | curves/s | prepare / "
          "optimise / finish [ms per curve] | LM steps a curve | peak device memory [GiB] |\n"
          "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |", flush=True)
    first = {}
    base = dict(base or {})
    for i, n in enumerate(sizes):
        runs = [("platform default" + (f", search {json.dumps(base)}" if base else ""), {},
                 base)]
        if i == 0 and baseline_workers:
            runs.append((f"CPU's ({baseline_workers} lanes)",
                         dict(chunk=n, workers=baseline_workers), {}))
        if i == 0:
            runs += [(f"search {json.dumps(s)}", {}, dict(s)) for s in searches]
        for label, extra, search in runs:
            batch = fitting.BatchOptions(**extra)
            size = batch.chunk_for(n)
            lanes = batch.lanes(size, search.get("n_starts", fitting.DEFAULT_STARTS),
                                model=model)
            # sizes whose chunk was compiled by an earlier row: one call only
            seen = (any(batch.chunk_for(m) == size for m in sizes[:i]) and not extra
                    and search is base)
            cold, warm, res = timed(lambda b=batch, n=n, s=search: fitting.fit_each(
                curves[:n], batch=b, **kw, **s), 0 if seen else repeats)
            t = res.timings
            steps = np.mean([np.sum(r.start_steps) + (0 if r.polish_steps is None
                                                      else np.sum(r.polish_steps))
                             for r in res.results if r is not None])
            print(f"| {label} | {n:,} | {size} | {lanes:,} | "
                  f"{'-' if seen else f'{cold:.1f}'} | {warm:.2f} | {n / warm:.1f} | "
                  f"{1e3 * t['prepare'] / n:.2f} / {1e3 * t['optimise'] / n:.2f} / "
                  f"{1e3 * t['finish'] / n:.2f} | {steps:.0f} | {_peak_gib():.2f} |",
                  flush=True)
            if i == 0:
                first[label] = np.array([r.chi2 if r is not None else np.nan
                                         for r in res.results])
    ref_label = runs[0][0] if sizes else None
    ref = first.pop(ref_label, None)
    for label, other in first.items():
        lower = int(np.sum(ref <= other * (1 + 1e-9)))
        print(f"\nχ² of the {ref_label} against {label} on the same "
              f"{other.size} curves: no higher (+1e-9 relative) on {lower}/{other.size}; "
              f"{label} higher by at most {np.nanmax(other / ref - 1):.2g} (relative), "
              f"lower by at most {np.nanmax(1 - other / ref):.2g}", flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fit-curves", default="128,4096,16384",
                    help="curves of the relaxed-start maps fitted, comma-separated")
    ap.add_argument("--baseline-workers", type=int, default=64,
                    help="lanes of the CPU schedule run on the first map size as a paired "
                         "baseline (0: not run)")
    ap.add_argument("--history-fit", default="256",
                    help="curves of the full-history maps fitted (200 samples), "
                         "comma-separated (empty: none)")
    ap.add_argument("--sweep-max", type=int, default=10_000_000)
    ap.add_argument("--history", default="32768,131072",
                    help="curves of the full-history sweeps, comma-separated")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--search", action="append", default=[], metavar="JSON",
                    help="search options run on the first relaxed map size beside the "
                         "default, e.g. '{\"screen\": 1024, \"n_starts\": 8}' (repeatable)")
    ap.add_argument("--history-search", action="append", default=[], metavar="JSON",
                    help="search options run on the first history map size beside the "
                         "default, e.g. '{\"search_cells\": 16}' (repeatable)")
    ap.add_argument("--history-options", default=None, metavar="JSON",
                    help="search options of every history map row instead of the default "
                         "search, e.g. '{\"search_cells\": 16}'")
    args = ap.parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    warnings.simplefilter("ignore")
    dev = jax.devices()[0]
    print(f"{dev.platform}: {getattr(dev, 'device_kind', dev)}; jax {jax.__version__}; "
          f"{platform.node()}", flush=True)

    fit_sizes = [int(x) for x in str(args.fit_curves).split(",") if x.strip()]
    if fit_sizes:
        fit_rows(make_map(max(fit_sizes), 60), fit_sizes, args.baseline_workers, "relaxed",
                 args.repeats, [json.loads(s) for s in args.search])
    hist_sizes = [int(x) for x in str(args.history_fit).split(",") if x.strip()]
    if hist_sizes:
        fit_rows(make_history_map(max(hist_sizes), 200), hist_sizes, 0, "history",
                 args.repeats, [json.loads(s) for s in args.history_search],
                 json.loads(args.history_options) if args.history_options else None)

    print("\n| relaxed sweep points | precision | cold [s] | warm [s] | curves/s |\n"
          "| --- | --- | --- | --- | --- |", flush=True)
    sizes = [s for s in (10_000, 1_000_000, 10_000_000) if s <= args.sweep_max]
    for size in sizes:
        for precision in ("float32", "float64"):
            grid = {"G0": 1e6, "G1": np.geomspace(1e5, 1e6, 10), "eta1": 1e4,
                    "work_of_adhesion": 0.05, "R": 1e-2, "depth": 1e-4,
                    "velocity": np.geomspace(1e-5, 1e-1, size // 10)}
            cold, warm, ds = timed(lambda grid=grid, precision=precision: jc.sweep(
                grid, model=jc.RelaxedStart(), precision=precision, progress=False),
                args.repeats)
            ok = int(np.sum(ds["status"].values == 0))
            print(f"| {size:,} | {precision} | {cold:.2f} | {warm:.3f} | {size / warm:.3g} | "
                  f"({ok:,} status OK)", flush=True)

    print("\n| history sweep curves | precision | warm [s] | curves/s |\n"
          "| --- | --- | --- | --- |", flush=True)
    for m in (int(x) for x in str(args.history).split(",") if x.strip()):
        grid = {"G0": 1e6, "G1": np.geomspace(1e5, 1e6, 8), "eta1": 1e4,
                "work_of_adhesion": 0.05, "R": 1e-2, "depth": 1e-4,
                "velocity": np.geomspace(1e-5, 1e-2, m // 8), "hold": 1.0}
        cold, warm, ds = timed(lambda grid=grid: jc.sweep(
            grid, model=jc.ApproachHoldLift(samples=2000), precision="float32",
            progress=False), args.repeats)
        print(f"| {m:,} | float32 | {warm:.3f} | {m / warm:.3g} | (cold {cold:.1f} s)",
              flush=True)


if __name__ == "__main__":
    main()
