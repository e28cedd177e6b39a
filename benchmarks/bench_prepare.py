"""The per-curve preparation of `fitting.fit_each` (`fitting._optimise._problem`: segments,
contact signal, samples and weights, data scales, guess, bounds, parameterisation, starts):
process CPU time a curve, warm, on the synthetic map of `bench_fit_each.py`.

    python benchmarks/bench_prepare.py [--curves 64] [--samples 60] [--model relaxed|history]
        [--repeats 7] [--screen 0]

Prints the median and every repeat (ms a curve of process CPU time: the machine's other
load inflates it less than wall time). For a before/after comparison run it alternately
with ``PYTHONPATH`` on a copy of the old code (``git archive <rev> fitting jaxcontact | tar
-x -C /tmp/old``) and on the new; the curves are made by the `jaxcontact` found first.
"""

from __future__ import annotations

import argparse
import statistics
import time
import warnings

import jax
from _results import machine  # benchmarks/_results.py
from bench_fit_each import R, make_history_map, make_map

import fitting
import fitting._optimise as optimise

jax.config.update("jax_enable_x64", True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--curves", type=int, default=64)
    ap.add_argument("--samples", type=int, default=None,
                    help="samples a curve (default: 60 relaxed, 200 history)")
    ap.add_argument("--model", default="relaxed", choices=("relaxed", "history"))
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--screen", type=int, default=0)
    args = ap.parse_args(argv)
    samples = args.samples or (60 if args.model == "relaxed" else 200)
    curves = (make_map if args.model == "relaxed" else make_history_map)(args.curves, samples)
    opts = fitting.FitOptions(radius=R, model=args.model, progress=False, screen=args.screen)
    cp = fitting._prepare.contact_point_mode(opts.contact_point, curves)

    def run():
        return [optimise._problem([c], opts, rheology="standard", contact_point=cp,
                                  previous=None) for c in curves]

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run()
        run()  # warm: caches of the probe, the spec and the starts' design filled
        times = []
        for _ in range(args.repeats):
            t0 = time.process_time()
            run()
            times.append((time.process_time() - t0) / len(curves) * 1e3)
    print(f"{machine()}; fitting from {fitting.__file__}")
    print(f"{args.model}, {args.curves} curves x {samples} samples, screen {args.screen}: "
          f"preparation {statistics.median(times):.3f} ms a curve (median of "
          f"{args.repeats}; all: {' '.join(f'{t:.3f}' for t in times)})")


if __name__ == "__main__":
    main()
