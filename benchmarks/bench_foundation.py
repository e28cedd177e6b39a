"""Benchmark of `jaxcontact.simulate` (the MDR foundation) and its discretisation error.

Run: `python benchmarks/bench_foundation.py [--samples 5000] [--batch 1000] [--repeats 7]`
(about 8 minutes on 2 shared CPU cores; `--skip-checks` for the speed and error tables only).

Claims measured here:

1. Time per curve for an approach-hold-lift history of 5,000 samples at the default grid
   (`FoundationGrid()`, 64 cells), after compilation, and for a batch of curves under `vmap`
   (1,000 by default); medians over repeats and the ratio batch/single per curve; the time
   of the Jacobian of the force curve with respect to (G0, G1, eta1, dgamma) (forward mode,
   what a Levenberg-Marquardt fit evaluates per iteration).
2. The discretisation error at that grid, against a fine reference grid: the largest force
   error over the samples where both grids are in contact, the jump-off time and force and
   the largest tensile force; a table of the error against the number of cells with the
   observed order (second order expected).
3. Heavier correctness checks that the test file leaves out: the gradient through the
   compliant loading system (Newton's method, implicit differentiation) against finite
   differences; reverse against forward mode for the rigid loading; the long hold then lift
   against `retract` for a cone, a power law and a tabulated profile; the compliant loading
   of an elastic JKR contact against its closed form down to the soft-spring (force-control)
   limit; the convergence of the viscoelastic compliant jump-off with the sampling.

Everything runs on the CPU in float64.
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxcontact as jc

R = 1e-3  # m
D0 = 1e-5  # m
DGAMMA = 0.01  # J/m^2
G0, G1, ETA1 = 1e5, 2e4, 2e2  # Pa, Pa, Pa s -> tau = eta1 / (G0 + G1) = 1/600 s
TAU = ETA1 / (G0 + G1)
PROFILE = jc.Parabola(R)


def history(n: int):
    """Approach in tau, hold tau, lift at 0.53 d0/tau to -0.6 d0 (through jump-off)."""
    knots_t = np.array([0.0, TAU, 2 * TAU, 5 * TAU])
    knots_d = np.array([0.0, D0, D0, -0.6 * D0])
    ts = np.linspace(0.0, knots_t[-1], n)
    return jnp.asarray(ts), jnp.asarray(np.interp(ts, knots_t, knots_d))


def timed(fn, *args, repeats: int):
    out = fn(*args)
    jax.block_until_ready(out)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return statistics.median(times), times, out


def bench_speed(n_samples: int, batch: int, repeats: int):
    ts, d = history(n_samples)

    def one(g0, g1, eta1, dgamma):
        sol = jc.simulate(jc.StandardModel(g0, g1, eta1), PROFILE, dgamma, ts, d, throw=False)
        return sol.force, sol.jumpoff_time, sol.max_tensile_force

    single = jax.jit(one)
    t0 = time.perf_counter()
    jax.block_until_ready(single(G0, G1, ETA1, DGAMMA))
    compile_single = time.perf_counter() - t0
    med_single, _, _ = timed(single, G0, G1, ETA1, DGAMMA, repeats=repeats)

    rng = np.random.default_rng(0)
    g0 = jnp.asarray(G0 * rng.uniform(0.8, 1.2, batch))
    g1 = jnp.asarray(G1 * rng.uniform(0.8, 1.2, batch))
    eta = jnp.asarray(ETA1 * rng.uniform(0.8, 1.2, batch))
    dg = jnp.asarray(DGAMMA * rng.uniform(0.8, 1.2, batch))
    batched = jax.jit(jax.vmap(one))
    t0 = time.perf_counter()
    jax.block_until_ready(batched(g0, g1, eta, dg))
    first_batch = time.perf_counter() - t0
    med_batch, _, _ = timed(batched, g0, g1, eta, dg, repeats=max(1, repeats // 3))

    print(f"== speed: approach-hold-lift, {n_samples} samples, default grid "
          f"({jc.FoundationGrid().cells} cells), StandardModel, Parabola, CPU float64")
    print(f"  single curve: compile+first run {compile_single:.2f} s, "
          f"median run {med_single * 1e3:.1f} ms")
    print(f"  batch of {batch} under vmap: first call {first_batch:.2f} s, "
          f"median {med_batch:.2f} s = {med_batch / batch * 1e3:.2f} ms per curve")
    print(f"  ratio (per-curve batch / single): {med_batch / batch / med_single:.2f}")

    def curve(p):
        sol = jc.simulate(jc.StandardModel(p[0], p[1], p[2]), PROFILE, p[3], ts, d, throw=False)
        return sol.force

    jac = jax.jit(jax.jacfwd(curve))
    p = jnp.array([G0, G1, ETA1, DGAMMA])
    t0 = time.perf_counter()
    jax.block_until_ready(jac(p))
    compile_jac = time.perf_counter() - t0
    med_jac, _, _ = timed(jac, p, repeats=repeats)
    print(f"  Jacobian of the {n_samples}-sample force curve w.r.t. 4 parameters (jacfwd): "
          f"compile+first run {compile_jac:.2f} s, median run {med_jac * 1e3:.1f} ms")
    return med_single, med_batch


def bench_error(n_samples: int, cells_list, ref_cells: int):
    ts, d = history(n_samples)
    rheo = jc.StandardModel(G0, G1, ETA1)

    def run(cells):
        f = jax.jit(lambda dd: jc.simulate(rheo, PROFILE, DGAMMA, ts, dd, grid=cells))
        return f(d)

    ref = run(ref_cells)
    F_ref = np.asarray(ref.force)
    scale = np.max(np.abs(F_ref))
    hold_end = np.asarray(ts) <= 2 * TAU
    print(f"\n== discretisation error, {n_samples} samples, reference grid {ref_cells} cells")
    print("  errors relative to max|F|; 'max|dF|' over samples where both grids are in "
          "contact;\n  'pre-lift' over approach and hold; jump-off time in units of tau")
    print(f"  {'cells':>6} {'max|dF|':>10} {'pre-lift':>10} {'order':>6} {'t_jump':>10} "
          f"{'order':>6} {'F_jump':>10} {'F_max_tens':>10}")
    prev = None
    rows = {}
    for cells in cells_list:
        sol = run(cells)
        F = np.asarray(sol.force)
        both = (np.asarray(sol.contact_radius) > 0) == (np.asarray(ref.contact_radius) > 0)
        e_all = np.max(np.abs(F - F_ref)[both]) / scale
        e_pre = np.max(np.abs(F - F_ref)[hold_end]) / scale
        e_t = abs(float(sol.jumpoff_time - ref.jumpoff_time)) / TAU
        e_fj = abs(float(sol.jumpoff_force - ref.jumpoff_force)) / scale
        e_ft = abs(float(sol.max_tensile_force - ref.max_tensile_force)) / scale
        o_pre = o_t = float("nan")
        if prev is not None:
            o_pre = np.log2(prev[0] / e_pre) / np.log2(cells / prev[2])
            o_t = np.log2(prev[1] / e_t) / np.log2(cells / prev[2])
        prev = (e_pre, e_t, cells)
        rows[cells] = (e_all, e_pre, e_t, e_fj, e_ft)
        print(f"  {cells:6d} {e_all:10.2e} {e_pre:10.2e} {o_pre:6.2f} {e_t:10.2e} {o_t:6.2f} "
              f"{e_fj:10.2e} {e_ft:10.2e}")
    default = jc.FoundationGrid().cells
    est = jax.jit(
        lambda dd: jc.simulate(rheo, PROFILE, DGAMMA, ts, dd,
                               estimate_error=True).details.error_estimate
    )(d)
    print(f"  default grid ({default} cells): Richardson estimate from simulate(..., "
          f"estimate_error=True): {float(est.relative_force):.2e} "
          f"(force), {float(est.jumpoff_time) / TAU:.2e} tau (jump-off time)")
    return rows


def check_gradients():
    print("\n== gradient checks (finite differences, central, relative step 1e-6)")
    ts, z = history(600)

    # compliant loading: through Newton's method on the loading spring and the jump-off
    # solved inside the step (sum of forces, largest tensile force, jump-off force and time)
    loading = jc.CompliantLoading(50.0)

    def total(p, loading=loading):
        sol = jc.simulate(jc.StandardModel(p[0], p[1], p[2]), PROFILE, p[3], ts, z, grid=16,
                          loading=loading)
        before = ts < 3 * TAU
        jump = sol.jumpoff_force * 100 + sol.jumpoff_time / TAU * 1e-2
        return jnp.sum(jnp.where(before, sol.force, 0.0)) + sol.max_tensile_force * 100 + jump

    p = jnp.array([G0, G1, ETA1, DGAMMA])
    f = jax.jit(total)
    g = np.asarray(jax.jit(jax.grad(total))(p))
    for k, name in enumerate(("G0", "G1", "eta1", "dgamma")):
        h = 1e-6 * float(p[k])
        fd = float((f(p.at[k].add(h)) - f(p.at[k].add(-h))) / (2 * h))
        print(f"  compliant k=50 N/m, d/d{name:6s}: grad {g[k]: .6e}  fd {fd: .6e}  "
              f"rel.diff {abs(g[k] - fd) / abs(fd):.1e}")

    # rigid loading: reverse against forward mode on several outputs
    def outputs(p):
        sol = jc.simulate(jc.StandardModel(p[0], p[1], p[2]), PROFILE, p[3], ts, z, grid=16)
        return jnp.stack([sol.jumpoff_time, sol.jumpoff_force, sol.max_tensile_force,
                          sol.jumpoff_radius])

    jf = np.asarray(jax.jit(jax.jacfwd(outputs))(p))
    jr = np.asarray(jax.jit(jax.jacrev(outputs))(p))
    print(f"  rigid loading: max |jacrev - jacfwd| / |jacfwd| = "
          f"{np.max(np.abs(jr - jf) / np.abs(jf)):.1e}")


def check_profiles_and_limits():
    """Long hold then lift against `retract` for other profiles; soft compliant spring."""
    retract = jc.retract

    print("\n== long hold (60 tau) then lift at d0/tau, default grid, against retract")
    rheo = jc.StandardModel(G0, G1, ETA1)
    r = np.linspace(0, 3e-4, 200)
    profiles = {
        "parabola": PROFILE,
        "cone": jc.Cone(1.2),
        "power law n=3": jc.PowerLaw(1e6, 3.0),
        "tabulated parabola": jc.Tabulated(r, r**2 / (2 * R)),
    }
    for name, prof in profiles.items():
        d0 = float(prof.g(1e-4))  # a0 = 1e-4 m
        v = d0 / TAU
        ts = np.concatenate([
            np.linspace(0, 0.5 * TAU, 20, endpoint=False),
            0.5 * TAU + np.linspace(0, 60 * TAU, 40, endpoint=False),
            60.5 * TAU + np.linspace(0, 6 * TAU, 241),
        ])
        d = np.concatenate([d0 * np.linspace(0, 1, 20, endpoint=False), np.full(40, d0),
                            d0 - v * (ts[60:] - ts[60])])
        sol = jc.simulate(rheo, prof, DGAMMA, jnp.asarray(ts), jnp.asarray(d))
        ref = retract(rheo, prof, work_of_adhesion=DGAMMA, depth=d0, ts=ts[60:] - ts[60],
                      displacement=d[60:])
        F, Fr = np.asarray(sol.force)[60:], np.asarray(ref.force)
        errs = [
            np.max(np.abs(F - Fr)) / np.max(np.abs(Fr)),
            abs(float(sol.jumpoff_time) - ts[60] - float(ref.jumpoff_time)) / TAU,
            abs(float(sol.jumpoff_force / ref.jumpoff_force) - 1),
            abs(float(sol.max_tensile_force / ref.max_tensile_force) - 1),
        ]
        print(f"  {name:20s} force {errs[0]:.1e}  jump-off time {errs[1]:.1e} tau  "
              f"jump-off force {errs[2]:.1e}  max tensile {errs[3]:.1e}")

    print("\n== compliant loading, elastic JKR, against the closed form (dF/dd = -k on JKR)")
    G = 1e5
    E = 4 * G
    fc = -1.5 * np.pi * DGAMMA * R
    ts = np.linspace(0, 2, 3001)
    for k in (1e7, 10.0, 1.0, 0.1, 0.01):
        # preload to d0 (contact radius 1e-4 m > the force-control radius), then lift the
        # drive far enough for the spring to pull beyond the pull-off force
        preload = 4 / 3 * E * np.sqrt(R) * D0**1.5
        z_top, z_end = D0 + preload / k, -2 * D0 + 1.5 * fc / k
        z = np.interp(ts, [0, 1, 2], [0, z_top, z_end])
        sol = jc.simulate(jc.Elastic(G), PROFILE, DGAMMA, jnp.asarray(ts), jnp.asarray(z),
                          loading=jc.CompliantLoading(k))
        a_c, F_c, d_c = _jkr_compliant(E, DGAMMA, k)
        t_c = 1 + (z_top - (d_c + F_c / k)) / (z_top - z_end)
        print(f"  k = {k:7.2g} N/m: jump-off force / (-3/2 pi dgamma R) = "
              f"{float(sol.jumpoff_force) / fc:.9f} (closed form {F_c / fc:.9f}); "
              f"rel. errors: force {abs(float(sol.jumpoff_force) / F_c - 1):.1e}, radius "
              f"{abs(float(sol.jumpoff_radius) / a_c - 1):.1e}, time "
              f"{abs(float(sol.jumpoff_time) / t_c - 1):.1e}")

    print("\n== compliant loading, gradient of the jump-off (elastic) against the closed form")
    ts2, z2 = jnp.linspace(0, 2, 201), jnp.interp(jnp.linspace(0, 2, 201),
                                                  jnp.array([0.0, 1.0, 2.0]),
                                                  jnp.array([0.0, D0, -2 * D0]))

    def jump(p):
        sol = jc.simulate(jc.Elastic(p[0]), PROFILE, p[1], ts2, z2,
                          loading=jc.CompliantLoading(p[2]))
        return jnp.stack([sol.jumpoff_force, sol.jumpoff_radius])

    p = np.array([G, DGAMMA, 20.0])
    jac = np.asarray(jax.jit(jax.jacrev(jump))(jnp.asarray(p)))
    for i, name in enumerate(("G", "dgamma", "k")):
        h = 1e-5 * p[i]
        plus, minus = p.copy(), p.copy()
        plus[i] += h
        minus[i] -= h
        fd = (np.array(_jkr_compliant(4 * plus[0], plus[1], plus[2])[1::-1])
              - np.array(_jkr_compliant(4 * minus[0], minus[1], minus[2])[1::-1])) / (2 * h)
        print(f"  d/d{name:6s}: force {jac[0, i]: .6e} (closed form {fd[0]: .6e}), radius "
              f"{jac[1, i]: .6e} ({fd[1]: .6e}); rel.diff "
              f"{np.max(np.abs(jac[:, i] / fd - 1)):.1e}")

    print("\n== compliant loading, standard model: jump-off against the sampling "
          "(approach-hold-lift, 32 cells; reference 19,200 samples)")
    rheo = jc.StandardModel(G0, G1, ETA1)
    for k in (50.0, 2.0):
        knots_z = [0.0, D0, D0, -0.6 * D0 - 3 * np.pi * DGAMMA * R / k]
        res = {}
        for n in (600, 2400, 19200):
            ts = np.linspace(0, 5 * TAU, n)
            z = np.interp(ts, [0, TAU, 2 * TAU, 5 * TAU], knots_z)
            sol = jc.simulate(rheo, PROFILE, DGAMMA, jnp.asarray(ts), jnp.asarray(z), grid=32,
                              loading=jc.CompliantLoading(k))
            res[n] = (float(sol.jumpoff_time), float(sol.jumpoff_force))
        for n in (600, 2400):
            print(f"  k = {k:4.0f} N/m, {n:5d} samples: jump-off time error "
                  f"{abs(res[n][0] - res[19200][0]) / TAU:.1e} tau "
                  f"({abs(res[n][0] - res[19200][0]) / (5 * TAU / (n - 1)):.2f} sample "
                  f"intervals), force {abs(res[n][1] / res[19200][1] - 1):.1e}")


def _jkr_compliant(E, dgamma, k):
    """(radius, force, indentation) where dF/dd = -k on the JKR curve of a parabola."""
    from scipy.optimize import brentq

    dF = lambda s: 4 * E * s**2 / R - 1.5 * np.sqrt(8 * np.pi * E * dgamma * s)  # noqa: E731
    dd = lambda s: 2 * s / R - 0.5 * np.sqrt(2 * np.pi * dgamma / (E * s))  # noqa: E731
    a_fold = (np.pi * dgamma * R**2 / (8 * E)) ** (1 / 3)
    a_fc = (9 * np.pi * dgamma * R**2 / (8 * E)) ** (1 / 3)
    a = brentq(lambda s: dF(s) + k * dd(s), a_fold * (1 + 1e-13), a_fc, xtol=1e-25, rtol=1e-15)
    F = 4 * E * a**3 / (3 * R) - np.sqrt(8 * np.pi * E * dgamma * a**3)
    return a, F, a**2 / R - np.sqrt(2 * np.pi * a * dgamma / E)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=5000)
    parser.add_argument("--batch", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--skip-checks", action="store_true")
    args = parser.parse_args()
    print(f"jax {jax.__version__}, devices {jax.devices()}")
    bench_speed(args.samples, args.batch, args.repeats)
    bench_error(args.samples, (8, 16, 32, 64, 128, 256), ref_cells=1024)
    if not args.skip_checks:
        check_gradients()
        check_profiles_and_limits()


if __name__ == "__main__":
    main()
