"""Throughput of the vmapped relaxed-start pull-off model against vectorised numpy.

Workload (issue 3): 10,000 parameter sets (G0, G1, eta1, work of adhesion, speed drawn at random)
x 2,000 samples each, standard model, parabola, constant-speed lift. Both implementations use
the same closed form (exact arm variables, running minimum, Ferrari root of the front
equation with the cancellation-free Cardano step and one Newton polish); the numpy one is
what a careful user would write with whole-array operations.

Reports medians of repeated warm runs (interleaved, so that both sides see the same load),
samples per second, the ratio, the compile time, and the float32 error of the JAX path
measured against float64 (force samples and events).

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


def jax_model(ts, events=False):
    def one(G0, G1, eta1, dg, v):
        sol = jc.retract(
            jc.StandardModel(G0=G0, G1=G1, eta1=eta1), jc.Parabola(R=R),
            work_of_adhesion=dg, depth=D0, velocity=v, ts=ts, throw=False,
        )
        if events:
            return sol.force, sol.jumpoff_time, sol.jumpoff_force, sol.max_tensile_force
        return sol.force

    return jax.jit(jax.vmap(one))


def interleaved_medians(fns, repeats):
    """Median time of each function, the runs interleaved so that all see the same load;
    also the median of the per-round ratios to the first function."""
    times = [[] for _ in fns]
    for _ in range(repeats):
        for k, fn in enumerate(fns):
            t0 = time.perf_counter()
            fn()
            times[k].append(time.perf_counter() - t0)
    ratios = [statistics.median(np.array(t) / np.array(times[0])) for t in times]
    return [statistics.median(t) for t in times], ratios


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
    f32 = jax_model(jnp.asarray(ts, dtype=jnp.float32))
    args32 = [jnp.asarray(x, dtype=jnp.float32) for x in p64]
    t0 = time.perf_counter()
    out32 = f32(*args32).block_until_ready()
    compile32 = time.perf_counter() - t0
    (t_jax, t_np, t_32), (_, r_np, r_32) = interleaved_medians(
        [lambda: f64(*args64).block_until_ready(), lambda: numpy_model(*p64, ts),
         lambda: f32(*args32).block_until_ready()],
        args.repeats,
    )
    ref = numpy_model(*p64, ts)
    scale = np.max(np.abs(ref), axis=1, keepdims=True)
    agree = np.max(np.abs(np.asarray(out64) - ref) / scale)
    print(f"float64 jax : first call (compile + run) {compile64:.2f} s; warm median {t_jax:.3f} s "
          f"-> {n * k / t_jax:.3g} samples/s")
    print(f"float64 numpy: warm median {t_np:.3f} s -> {n * k / t_np:.3g} samples/s")
    print(f"ratio numpy/jax (float64): {t_np / t_jax:.1f}x (median of per-round ratios "
          f"{r_np:.1f}x); max |F_jax - F_np| / max|F| = {agree:.2e}")
    print(f"float32 jax : first call {compile32:.2f} s; warm median {t_32:.3f} s -> "
          f"{n * k / t_32:.3g} samples/s, {1 / r_32:.1f}x float64 (dtype {out32.dtype})")

    # float32 accuracy, measured against float64: force samples, and the events
    ev64 = [np.asarray(x) for x in jax_model(jnp.asarray(ts), events=True)(*args64)]
    ev32 = [np.asarray(x, dtype=np.float64)
            for x in jax_model(jnp.asarray(ts, dtype=jnp.float32), events=True)(*args32)]
    err = np.abs(ev32[0] - ev64[0]) / scale
    # a sample closer to the jump-off than float32 resolves in time (1e-6 of the duration)
    # may be attached in one precision and detached in the other
    near = np.abs(ts[None, :] - ev64[1][:, None]) < 1e-6 * ts[-1]
    print(f"float32 error vs float64, relative to each curve's peak |F|: median "
          f"{np.median(err):.2e}, 99th percentile {np.percentile(err, 99):.2e}, max "
          f"{err[~near].max():.2e} away from the jump-off; {int(near.sum())} sample(s) within "
          f"1e-6 of the duration of a jump-off (max there {err[near].max(initial=0):.2e})")
    det = np.isfinite(ev64[1])
    for name, a, b in (("jump-off time", ev32[1], ev64[1]), ("jump-off force", ev32[2], ev64[2]),
                       ("max tensile force", ev32[3], ev64[3])):
        rel = np.abs(a[det] / b[det] - 1)
        print(f"float32 {name:17s}: median rel. error {np.median(rel):.1e}, max {rel.max():.1e} "
              f"({int(det.sum())} detaching curves)")


if __name__ == "__main__":
    main()
