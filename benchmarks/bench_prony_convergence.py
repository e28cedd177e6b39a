"""Nested ``prony:N`` fits of real curves: do they converge, in how many steps, at what χ²?

For every file given (the first curve of each, with its probe radius after an ``@``, e.g.
``oocyte.jpk-force@40e-6``; default `--radius`), one
``fitting.fit(curve, model="history", rheology=RHEOLOGY, max_samples=...)`` (the nested
chain: standard, then ``prony:2``, ...), and per stage of the chain: χ² and convergence of
the best start, the runs that stopped at the step limit, the sum of the steps of all runs
(global search and local rounds: the pool's cost, independent of the machine's load), and
the wall and process CPU time of the whole fit. One JSON line per file and stage is
appended to `--jsonl` (so that a run on another checkout, the baseline, can be compared),
and printed.

    python benchmarks/bench_prony_convergence.py FILE[@RADIUS] [...] [--rheology prony:2]
        [--max-samples 150] [--jsonl /tmp/prony.jsonl] [--label after]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import time
import warnings

import jax
import numpy as np

import fitting
from fitting import _optimise

jax.config.update("jax_enable_x64", True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="+")
    ap.add_argument("--radius", type=float, default=10e-6, help="probe radius [m]")
    ap.add_argument("--rheology", default="prony:2")
    ap.add_argument("--max-samples", type=int, default=150)
    ap.add_argument("--jsonl", default=None)
    ap.add_argument("--label", default="")
    args = ap.parse_args(argv)

    stages = []
    original = _optimise._fit_one

    def recording(*a, **kw):
        t0 = time.perf_counter()
        res = original(*a, **kw)
        stages.append((res, time.perf_counter() - t0))
        return res

    _optimise._fit_one = recording
    try:
        for item in args.files:
            path, _, radius = item.partition("@")
            radius = float(radius) if radius else args.radius
            curve = fitting.load_curve(path)[0]
            stages.clear()
            t0, c0 = time.perf_counter(), time.process_time()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                fitting.fit(curve, radius=radius, model="history", rheology=args.rheology,
                            max_samples=args.max_samples, progress=False)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            for res, dt in stages:
                steps = np.asarray(res.start_steps)
                row = dict(label=args.label, file=pathlib.Path(path).name, radius=radius,
                           max_samples=args.max_samples, rheology=res.rheology,
                           chi2=float(res.chi2), converged=bool(res.converged),
                           runs=int(len(steps)), at_limit=int(np.sum(steps > 200)),
                           steps=int(np.sum(steps)), stage_wall_s=round(dt, 1),
                           wall_s=round(wall, 1), cpu_s=round(cpu, 1),
                           r2=float(res.r_squared),
                           values={n: float(v) for n, v in zip(res.names, res.values,
                                                               strict=True)})
                line = json.dumps(row)
                print(line, flush=True)
                if args.jsonl:
                    with open(args.jsonl, "a") as fh:
                        fh.write(line + "\n")
    finally:
        _optimise._fit_one = original


if __name__ == "__main__":
    main()
