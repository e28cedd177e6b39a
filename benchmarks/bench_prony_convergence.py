"""Nested ``prony:N`` fits of real curves: do they converge, in how many steps, at what χ²?

For every file given (the first curve of each, with its probe radius after an ``@``, e.g.
``oocyte.jpk-force@40e-6``; default `--radius`), one
``fitting.fit(curve, model="history", rheology=RHEOLOGY, max_samples=...)`` (the nested
chain: standard, then ``prony:2``, ..., so ``--rheology prony:3`` measures every stage up
to ``prony:3`` in one fit), and per stage of the chain: χ², R² and convergence of the best
start (its index and steps), the runs that stopped at the step limit (their indices: below
`global_starts` the global search, then the local rounds of as many starts each; and how
far above the best χ² each ended, `limit_gap`), the sum of the steps of all runs (global
search and local rounds: the pool's cost, independent of the machine's load), the stage's
wall time and the wall and process CPU time of the whole fit. One JSON line per file and
stage is appended to `--jsonl` (so that a run on another checkout, the baseline, can be
compared), and printed; `--dump DIR` also writes every run's start and end point per file
and stage (``DIR/<file stem>-<rheology>.npz``: `starts` (the global search's free vectors),
`z`, `chi2`, `steps`, `result`, `names`, `values`), to trace single runs again.

    python benchmarks/bench_prony_convergence.py FILE[@RADIUS] [...] [--rheology prony:3]
        [--max-samples 150] [--jsonl /tmp/prony.jsonl] [--label after] [--dump DIR]
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
    ap.add_argument("--dump", default=None,
                    help="folder: every start's end point per file and stage (.npz)")
    args = ap.parse_args(argv)

    stages = []
    original = _optimise._finish
    clock = [0.0]
    current = [""]

    def recording(pb, *a, **kw):  # each stage of the chain ends in one _finish
        res = original(pb, *a, **kw)
        now = time.perf_counter()
        stages.append((res, now - clock[0], len(pb.zs)))
        if args.dump:
            out = a[0]
            pathlib.Path(args.dump).mkdir(parents=True, exist_ok=True)
            np.savez(pathlib.Path(args.dump) / f"{current[0]}-{res.rheology}.npz",
                     starts=pb.zs, z=np.asarray(out.z), chi2=np.asarray(out.chi2),
                     steps=np.asarray(out.steps), result=np.asarray(out.result),
                     names=np.asarray(res.names), values=np.asarray(res.values))
        clock[0] = now
        return res

    _optimise._finish = recording
    try:
        for item in args.files:
            path, _, radius = item.partition("@")
            radius = float(radius) if radius else args.radius
            curve = fitting.load_curve(path)[0]
            current[0] = pathlib.Path(path).stem
            stages.clear()
            t0, c0 = time.perf_counter(), time.process_time()
            clock[0] = t0
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                fitting.fit(curve, radius=radius, model="history", rheology=args.rheology,
                            max_samples=args.max_samples, progress=False)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            for res, dt, n_global in stages:
                steps = np.asarray(res.start_steps)
                losses = np.asarray(res.start_losses, dtype=float)
                best = int(np.argmin(np.where(np.isfinite(losses), losses, np.inf)))
                row = dict(label=args.label, file=pathlib.Path(path).name, radius=radius,
                           max_samples=args.max_samples, rheology=res.rheology,
                           chi2=float(res.chi2), converged=bool(res.converged),
                           runs=int(len(steps)), global_starts=n_global,
                           at_limit=int(np.sum(steps > 200)),
                           steps=int(np.sum(steps)), best_start=best,
                           best_steps=int(steps[best]),
                           limit_starts=[int(i) for i in np.flatnonzero(steps > 200)],
                           limit_gap=[float(losses[i] / losses[best] - 1.0)
                                      for i in np.flatnonzero(steps > 200)],
                           stage_wall_s=round(dt, 1),
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
        _optimise._finish = original


if __name__ == "__main__":
    main()
