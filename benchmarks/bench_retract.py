"""Throughput of the vmapped relaxed-start pull-off model against vectorised numpy.

Workload (issue 3): 10,000 parameter sets (G0, G1, eta1, work of adhesion, speed drawn at random)
x 2,000 samples each, standard model, parabola, constant-speed lift. Both implementations use
the same closed form (exact arm variables, running minimum, Ferrari root of the front
equation with the cancellation-free Cardano step and one Newton polish); the numpy one is
what a careful user would write with whole-array operations.

Reports medians of repeated warm runs, samples per second, the ratio, the compile time, and
the float32 error of the JAX path measured against float64.

    python benchmarks/bench_retract.py [--sets 10000] [--samples 2000] [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxcontact as jc


def params(n, seed=0):
    rng = np.random.default_rng(seed)
    G0 = 10 ** rng.uniform(5.5, 6.5, n)
    G1 = G0 * 10 ** rng.uniform(-1.0, 0.0, n)
    eta1 = (G0 + G1) * 10 ** rng.uniform(-3, -1, n)  # tau from 1 ms to 100 ms
    dg = 10 ** rng.uniform(-2, -1, n)
    v = 10 ** rng.uniform(-5, -3, n)
    return G0, G1, eta1, dg, v


R, D0 = 1e-4, 4e-6


def numpy_model(G0, G1, eta1, dg, v, ts):
    """Vectorised numpy, same closed form (one row per parameter set)."""
    G0, G1, eta1, dg, v = (x[:, None] for x in (G0, G1, eta1, dg, v))
    t = ts[None, :]
    tau = eta1 / (G0 + G1)
    Ginf = G0 * G1 / (G0 + G1)
    d = D0 - v * t
    d_eff = d - (G0 / Ginf) * (G0 / (G0 + G1)) * v * tau * (1 - np.exp(-t / tau))
    m = np.minimum.accumulate(d_eff, axis=1)
    c = np.sqrt(0.5 * np.pi * dg * G0) / Ginf
    a0 = np.sqrt(R * D0)
    a_fold = (0.5 * c * R / 2) ** (2 / 3)
    h = lambda a: a**2 / R - c * np.sqrt(a)  # noqa: E731
    h_pin, h_fold = h(a0), h(np.minimum(a_fold, a0))
    attached = m >= h_fold
    receding = attached & (m < h_pin) & (a0 > a_fold)
    lam = np.cbrt(c * R)
    mu = np.maximum(R * np.where(receding, m, h_pin) / lam**4, -0.75 * 4 ** (-1 / 3))
    disc = np.maximum(1 / 256 + mu**3 / 27, 0)
    u = np.cbrt(1 / 16 + np.sqrt(disc))
    D = u**2 + mu / 3 + (mu / (3 * u)) ** 2  # Cardano without cancellation: y = 1 / (8 D)
    y = 1 / (8 * D)
    r2y = np.sqrt(2 * y)
    s = 0.5 * (r2y + np.sqrt(np.maximum(2 / r2y - 2 * y, 0)))
    slope = 4 * s**3 - 1
    s = np.where(slope > 1e-3, s - (s**4 - s - mu) / np.where(slope > 1e-3, slope, 1.0), s)
    a = np.where(receding, (lam * s) ** 2, np.where(attached, a0, 0.0))
    return np.where(attached, 8 * Ginf * (a * d_eff - a**3 / (3 * R)), 0.0)


def jax_model(ts):
    def one(G0, G1, eta1, dg, v):
        sol = jc.retract(
            jc.StandardModel(G0=G0, G1=G1, eta1=eta1), jc.Parabola(R=R),
            work_of_adhesion=dg, depth=D0, velocity=v, ts=ts, throw=False,
        )
        return sol.force

    return jax.jit(jax.vmap(one))


def median_time(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sets", type=int, default=10_000)
    ap.add_argument("--samples", type=int, default=2_000)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    n, k = args.sets, args.samples
    p64 = params(n)
    ts = np.linspace(0, 0.2, k)
    print(f"devices: {jax.devices()}; {n} parameter sets x {k} samples = {n * k:.3g} samples")

    f64 = jax_model(jnp.asarray(ts))
    args64 = [jnp.asarray(x) for x in p64]
    t0 = time.perf_counter()
    out64 = f64(*args64).block_until_ready()
    compile64 = time.perf_counter() - t0
    t_jax = median_time(lambda: f64(*args64).block_until_ready(), args.repeats)
    t_np = median_time(lambda: numpy_model(*p64, ts), args.repeats)
    ref = numpy_model(*p64, ts)
    scale = np.max(np.abs(ref), axis=1, keepdims=True)
    agree = np.max(np.abs(np.asarray(out64) - ref) / scale)
    print(f"float64 jax : first call (compile + run) {compile64:.2f} s; warm median {t_jax:.3f} s "
          f"-> {n * k / t_jax:.3g} samples/s")
    print(f"float64 numpy: warm median {t_np:.3f} s -> {n * k / t_np:.3g} samples/s")
    print(f"ratio numpy/jax (float64): {t_np / t_jax:.1f}x; "
          f"max |F_jax - F_np| / max|F| = {agree:.2e}")

    f32 = jax_model(jnp.asarray(ts, dtype=jnp.float32))
    args32 = [jnp.asarray(x, dtype=jnp.float32) for x in p64]
    out32 = f32(*args32).block_until_ready()
    t_32 = median_time(lambda: f32(*args32).block_until_ready(), args.repeats)
    err = np.abs(np.asarray(out32, dtype=np.float64) - np.asarray(out64)) / np.asarray(scale)
    print(f"float32 jax : warm median {t_32:.3f} s -> {n * k / t_32:.3g} samples/s "
          f"(dtype {out32.dtype})")
    print(f"float32 error vs float64, relative to each curve's peak |F|: median "
          f"{np.median(err):.2e}, 99th percentile {np.percentile(err, 99):.2e}, "
          f"max {err.max():.2e}")


if __name__ == "__main__":
    main()
