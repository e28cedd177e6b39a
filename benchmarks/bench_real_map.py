"""`fitting.fit_each` on the first curves of a real force map: a cold and a warm call.

    PYTHONPATH=. python benchmarks/bench_real_map.py [FILE] [--curves 16]
        [--max-samples N] [--radius 10e-6] [--model relaxed]

Prints, per call, the wall and process CPU time, the stages (prepare / optimise / finish),
the LM steps a curve and the samples kept (the "A real force volume on this CPU" section of
`benchmarks/results/fit_each.md`).
"""

import argparse
import time
import warnings

import jax
import numpy as np

import fitting


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("file", nargs="?", default="tests/data/bruker-egel-force-volume-16x16.spm")
    ap.add_argument("--curves", type=int, default=16)
    ap.add_argument("--max-samples", type=int, default=None)
    ap.add_argument("--radius", type=float, default=10e-6)
    ap.add_argument("--model", default="relaxed")
    args = ap.parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    warnings.simplefilter("ignore")
    curves = [c for c in fitting.load_curve(args.file, on_error="keep")
              if isinstance(c, fitting.Curve)][: args.curves]
    kw = dict(radius=args.radius, model=args.model, progress=False)
    if args.max_samples:
        kw["max_samples"] = args.max_samples
    for label in ("cold", "warm"):
        t0, c0 = time.perf_counter(), time.process_time()
        res = fitting.fit_each(curves, **kw)
        done = [r for r in res.results if r is not None]
        steps = np.mean([np.sum(r.start_steps) for r in done])
        print(f"{label}: {len(curves)} curves, wall {time.perf_counter() - t0:.1f} s, CPU "
              f"{time.process_time() - c0:.1f} s, stages "
              f"{ {k: round(v, 2) for k, v in res.timings.items()} }, "
              f"{steps:.0f} LM steps a curve, {done[0].data.n_samples} samples kept",
              flush=True)


if __name__ == "__main__":
    main()
