"""The latency of the full-history model's data-dependent loops on an accelerator.

    PYTHONPATH=. python benchmarks/loop_latency.py [--lanes 8192] [--samples 200]
        [--variants while,fixed48,unroll8] [--repeats 3]

Times the vmapped forward-mode Jacobian of `jc.simulate`'s force (the work of one
Levenberg–Marquardt step of a history fit) over `--lanes` parameter sets, with the root
finders' `while` loops (`jaxcontact._root`: the event refinements inside the history's
`scan`) as they are (`while`) and replaced, for this measurement only, by loops of a fixed
trip count K with finished lanes masked (`fixedK`: the same results when K is at least each
loop's own limit; `unrollK`: the same, unrolled). Prints the warm median per call and the
largest relative difference of the Jacobian to the `while` variant.
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

import jaxcontact as jc
import jaxcontact._root as _root


def fixed_loop(k, unroll):
    def loop(cond, body, carry):
        def step(_, c):
            new = body(c)
            go = cond(c)
            return jax.tree.map(lambda a, b: jnp.where(go, a, b), new, c)
        return lax.fori_loop(0, k, step, carry, unroll=unroll)
    return loop


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--lanes", type=int, default=8192)
    ap.add_argument("--samples", type=int, default=200)
    ap.add_argument("--variants", default="while,fixed48,unroll8")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    dev = jax.devices()[0]
    print(f"{dev.platform}: {getattr(dev, 'device_kind', dev)}; jax {jax.__version__}",
          flush=True)
    R, D0, V = 10e-6, 1e-6, 1e-6
    n = args.samples
    half = n // 2
    ts = np.linspace(0.0, 2 * D0 / V * 1.25, n)
    d = np.r_[np.linspace(0.0, D0, half), np.linspace(D0, -0.5 * D0, n - half)]
    rng = np.random.default_rng(0)
    P = np.stack([rng.uniform(500, 2000, args.lanes), rng.uniform(200, 2000, args.lanes),
                  10 ** rng.uniform(1, 3, args.lanes), rng.uniform(1e-4, 1e-3, args.lanes)], 1)

    def force(p):
        return jc.simulate(jc.StandardModel(p[0], p[1], p[2]), jc.Parabola(R), p[3],
                           ts, d).force

    original = _root.while_loop
    ref = None
    print("| variant | lanes | cold [s] | warm [s] | per lane [µs] | max rel diff of J |\n"
          "| --- | --- | --- | --- | --- | --- |", flush=True)
    for v in args.variants.split(","):
        if v == "while":
            _root.while_loop = original
        elif v.startswith("fixed"):
            _root.while_loop = fixed_loop(int(v[5:]), 1)
        elif v.startswith("unroll"):
            _root.while_loop = fixed_loop(int(v[6:]), True)
        fn = jax.jit(jax.vmap(jax.jacfwd(lambda p: force(p))))
        x = jnp.asarray(P)
        t0 = time.perf_counter()
        J = np.asarray(fn(x))
        cold = time.perf_counter() - t0
        warm = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            J = np.asarray(fn(x))
            warm.append(time.perf_counter() - t0)
        w = statistics.median(warm)
        if ref is None:
            ref, diff = J, 0.0
        else:
            scale = np.maximum(np.abs(ref).max(axis=1, keepdims=True), 1e-300)
            diff = float(np.nanmax(np.abs(J - ref) / scale))
        print(f"| {v} | {args.lanes} | {cold:.1f} | {w:.4f} | {1e6 * w / args.lanes:.2f} | "
              f"{diff:.2e} |", flush=True)
    _root.while_loop = original


if __name__ == "__main__":
    main()
