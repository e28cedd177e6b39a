"""One short run on an accelerator: the identification and sweep rows of the benchmark
tables that need a GPU (issues: identification at scale, sweeps at device speed).

    PYTHONPATH=. python benchmarks/device_check.py [--fit-curves 256] [--sweep-max 10000000]

Prints markdown rows (warm medians of `--repeats` calls after one cold call):
`fitting.fit_each` on the synthetic relaxed-start map of `bench_fit_each.py` (curves/s, the
per-stage split); `jc.sweep` relaxed-start summaries at 10^4..`--sweep-max` points in
float32 and float64 (curves/s); full-history sweeps at `--history` curves in float32. Runs on
the CPU too (smaller sizes), which is how it is smoke-tested.
"""

from __future__ import annotations

import argparse
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
from bench_fit_each import R, make_map  # noqa: E402


def timed(fn, repeats):
    t0 = time.perf_counter()
    out = fn()
    cold = time.perf_counter() - t0
    warm = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        warm.append(time.perf_counter() - t0)
    return cold, statistics.median(warm), out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fit-curves", type=int, default=256)
    ap.add_argument("--sweep-max", type=int, default=10_000_000)
    ap.add_argument("--history", default="32768,131072",
                    help="curves of the full-history sweeps, comma-separated")
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    warnings.simplefilter("ignore")
    dev = jax.devices()[0]
    print(f"{dev.platform}: {getattr(dev, 'device_kind', dev)}; jax {jax.__version__}; "
          f"{platform.node()}", flush=True)

    print("\n| fit_each curves | chunk | cold [s] | warm [s] | curves/s | prepare / optimise / "
          "finish [ms per curve] |\n| --- | --- | --- | --- | --- | --- |", flush=True)
    curves = make_map(args.fit_curves, 60)
    n = args.fit_curves
    cold, warm, res = timed(lambda: fitting.fit_each(curves, radius=R, chunk=n,
                                                      progress=False), 1)
    t = res.timings
    print(f"| {n} | {n} | {cold:.1f} | {warm:.2f} | {n / warm:.1f} | "
          f"{1e3 * t['prepare'] / n:.1f} / {1e3 * t['optimise'] / n:.1f} / "
          f"{1e3 * t['finish'] / n:.1f} |", flush=True)

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
