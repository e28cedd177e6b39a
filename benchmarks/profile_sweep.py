"""Where the time of a relaxed-start sweep goes: one chunk of curves, piece by piece.

Each row times `jax.jit(jax.vmap(...))` of one stage over the same random standard-model
parameter sets in the sweep's scaled units (depth = velocity = R = 1), the stages adding up
to what `RelaxedStart.solve` does per point: the forces of `retract` on a shared time grid
(what the numpy baseline of `bench_sweep.py` computes), its events (jump-off time, largest
tensile force), the per-curve duration (the bound of the jump-off time, a root, and a time
grid per curve), the separation work, and the whole `solve`. Medians of 20 warm calls.

    python benchmarks/profile_sweep.py [--curves 768] [--samples 500]

Prints markdown rows (results in `benchmarks/results/sweep.md`).
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np
from bench_foundation import timed  # median of warm calls (benchmarks/bench_foundation.py)

import jaxcontact as jc
from jaxcontact._pulloff import retract
from jaxcontact._sweep import _models as M

jax.config.update("jax_enable_x64", True)
PROFILE = jc.Parabola(R=1.0)


def stages(samples):
    def bound(g0, g1, eta, dg):
        """The bound of the jump-off time and the touch radius."""
        f = M._front_constants(jc.StandardModel(g0, g1, eta), PROFILE, dg)
        return M._lift_bound(f.ratio, f.tau, f.h_crit, jnp.inf), f.a0

    def shared(g0, g1, eta, dg):
        ts = jnp.linspace(0.0, 0.5, samples)
        return retract(jc.StandardModel(g0, g1, eta), PROFILE, work_of_adhesion=dg, depth=1.0,
                       velocity=1.0, ts=ts, throw=False)

    def per_curve(g0, g1, eta, dg):
        T, a0 = bound(g0, g1, eta, dg)
        ts = jnp.linspace(0.0, 1.0, samples) * 1.5 * T
        return retract(jc.StandardModel(g0, g1, eta), PROFILE, work_of_adhesion=dg,
                       depth=1.0, velocity=1.0, ts=ts, contact_radius=a0, throw=False)

    def work(g0, g1, eta, dg):
        s = per_curve(g0, g1, eta, dg)
        lift = jnp.ones(s.ts.shape, dtype=bool)
        return s.force, M._separation_work(s.displacement, s.force, s.contact_radius > 0,
                                           lift, jnp.isfinite(s.jumpoff_time),
                                           s.jumpoff_displacement, s.jumpoff_force)

    def solve(g0, g1, eta, dg, curves=False):
        return M.RelaxedStart(samples=samples).solve(
            jc.StandardModel(g0, g1, eta), PROFILE,
            {"work_of_adhesion": dg, "depth": 1.0, "velocity": 1.0}, curves=curves)

    def events(f):
        return lambda *a: (lambda s: (s.force, s.jumpoff_time, s.max_tensile_force))(f(*a))

    return [
        ("forces on a shared time grid (`retract`, force only)",
         lambda *a: shared(*a).force),
        ("+ events (jump-off time and force, largest tensile force)", events(shared)),
        ("bound of the jump-off time alone (a root per curve)", lambda *a: bound(*a)[0]),
        ("+ a time grid per curve from that bound, initial radius given", events(per_curve)),
        ("+ separation work", work),
        ("`RelaxedStart.solve`: the summaries (exact, no samples) and status", solve),
        ("`RelaxedStart.solve(curves=True)`: the summaries and the sampled curves",
         lambda *a: solve(*a, curves=True)),
    ]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--curves", type=int, default=768)
    ap.add_argument("--samples", type=int, default=500)
    args = ap.parse_args()
    n, k = args.curves, args.samples
    rng = np.random.default_rng(0)
    g0 = 10 ** rng.uniform(-0.5, 0.5, n)
    g1 = g0 * 10 ** rng.uniform(-1, 0, n)
    eta = (g0 + g1) * 10 ** rng.uniform(-3, -1, n)
    dg = 10 ** rng.uniform(-8, -7, n)
    args_ = [jnp.asarray(x) for x in (g0, g1, eta, dg)]
    print(f"{jax.devices()}; {n} curves x {k} samples per call\n")
    print("| stage | time per call [ms] | samples/s |")
    print("| --- | --- | --- |")
    for name, f in stages(k):
        with jc.plausibility_checks(False):
            t = timed(jax.jit(jax.vmap(f)), *args_, repeats=20)[0]
        print(f"| {name} | {t * 1e3:.2f} | {n * k / t:.3g} |", flush=True)


if __name__ == "__main__":
    main()
