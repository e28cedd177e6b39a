"""Relaxed-start sweeps per probe: curves/s of `jc.sweep` with each indenter family.

`--points` random standard-model parameter sets (G0, G1, lift speed vary; float64 on the
CPU), `jc.RelaxedStart(samples=200)` (its summaries do not depend on the samples), one
process, the median of `--repeats` warm calls after one cold call, for the paraboloid
(`R`), the exact sphere (`sphere_radius`), the cone (`half_angle`) and the flat punch
(`punch_radius`). Printed per probe: curves/s, and the sums of the largest tensile force and
the separation work over all points (equal sums across two checkouts: the same numbers).
To compare with another checkout run it there too (`PYTHONPATH=DIR python
benchmarks/bench_sweep_probes.py`, alternating).

    python benchmarks/bench_sweep_probes.py [--points 100000] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import numpy as np
from _results import machine  # benchmarks/_results.py

import jaxcontact as jc

jax.config.update("jax_enable_x64", True)

PROBES = {"paraboloid": ("R", 1e-2), "sphere": ("sphere_radius", 1e-2),
          "cone": ("half_angle", 1.2), "flat punch": ("punch_radius", 1e-3)}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=100_000)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    n = args.points
    rng = np.random.default_rng(0)
    varying = {"G0": rng.uniform(0.5e6, 2e6, n), "G1": rng.uniform(1e5, 1e6, n),
               "velocity": 10 ** rng.uniform(-5, -1, n)}
    print(f"{machine()}; {n:,} points, relaxed start, float64; "
          f"`python benchmarks/bench_sweep_probes.py --points {n} --repeats {args.repeats}`")
    print("| probe | cold [s] | warm [s] | curves/s | Σ max tensile force [N] "
          "| Σ separation work [J] |")
    print("|---|---|---|---|---|---|")
    for name, (key, value) in PROBES.items():
        points = dict(varying, eta1=np.full(n, 1e4), work_of_adhesion=np.full(n, 0.05),
                      depth=np.full(n, 1e-4), **{key: np.full(n, value)})

        def run(points=points):
            return jc.sweep(points=points, model=jc.RelaxedStart(samples=200), progress=False)

        t = time.perf_counter()
        run()
        cold = time.perf_counter() - t
        times = []
        for _ in range(args.repeats):
            t = time.perf_counter()
            ds = run()
            times.append(time.perf_counter() - t)
        warm = statistics.median(times)
        print(f"| {name} | {cold:.2f} | {warm:.3f} | {n / warm:,.0f} | "
              f"{float(ds.max_tensile_force_N.sum()):.12e} | "
              f"{float(ds.separation_work_J.sum()):.12e} |", flush=True)


if __name__ == "__main__":
    main()
