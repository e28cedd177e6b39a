"""Fit speed: `fitting.fit` (JAX, Levenberg–Marquardt) against scipy `least_squares`.

Workload: synthetic retract curves from the relaxed-start model (`jc.retract`), standard
model, parabola (R = 10 µm, relaxed depth 1 µm), three lift speeds, `--samples` samples per
curve, 1 % noise (as in tests/test_fitting.py). Both fitters start from the same data-driven
initial guess (`fitting.initial_guess`, the default of `fit`), use one start, work on
log-parameters, and minimise the same weighted residual vector (`fitting.residuals`: ramp-
weighted force residuals plus the pull-off and jump-off event residuals) on the same
prepared `CurveBatch`. The scipy side is what a user would write today: the same closed
form in vectorised numpy (exact exponential update of the arm variable via `lfilter`,
running minimum, Ferrari root of the front equation, `brentq` for the jump-off time inside
its sampling interval) and `least_squares(method="trf")` with its default 2-point
finite-difference Jacobian and default tolerances.

Measured, in one run:

1. warm time of one fit: `fitting.fit` end to end (preparation, optimisation, Gauss–Newton
   uncertainty, prediction), the jitted optimiser `fitting._optimise.solve` alone, and
   `least_squares`; medians over `--repeats`, the ratios, and the parameter agreement;
2. the cold time of the first `fitting.fit` call (compilation included);
3. `--batch` independent curve sets (different true parameters and noise) fitted in one
   `vmap`-ed call of the optimiser against the same number of sequential scipy fits.

    python benchmarks/bench_fit.py [--samples 200] [--repeats 7] [--batch 100]
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import time
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import brentq, least_squares
from scipy.signal import lfilter

import fitting
import jaxcontact as jc
from fitting._objective import initial_guess, make_spec, prepare_curves, residuals
from fitting._optimise import make_parameterisation, solve

R = 10e-6
D0 = 1e-6
LIFT = 2.5e-6
SPEEDS = (0.5e-6, 2e-6, 8e-6)
TRUE = {"G0": 10e3, "G1": 5e3, "eta1": 7.5e3, "work_of_adhesion": 5e-3}
NAMES = ("G0", "G1", "eta1", "work_of_adhesion")


# --------------------------------------------------------------------------------------
# Synthetic data (as in tests/test_fitting.py)
# --------------------------------------------------------------------------------------


def make_curves(p, n, noise, seed):
    rng = np.random.default_rng(seed)
    out = []
    for v in SPEEDS:
        ts = np.linspace(0.0, LIFT / v, n)
        sol = jc.retract(jc.StandardModel(p["G0"], p["G1"], p["eta1"]), jc.Parabola(R),
                         work_of_adhesion=p["work_of_adhesion"], depth=D0, ts=ts, velocity=v)
        f = np.asarray(sol.force)
        f = f + noise * np.ptp(f) * rng.standard_normal(n)
        out.append(fitting.Curve(time=ts, displacement=np.asarray(sol.displacement), force=f,
                                 segment=np.zeros(n, int), segment_names=("retract",)))
    return out


def random_truth(rng):
    G0 = TRUE["G0"] * 10 ** rng.uniform(-0.3, 0.3)
    G1 = G0 * 10 ** rng.uniform(-0.5, 0.0)
    tau = 0.5 * 10 ** rng.uniform(-0.5, 0.3)
    dg = TRUE["work_of_adhesion"] * 10 ** rng.uniform(-0.3, 0.3)
    return {"G0": G0, "G1": G1, "eta1": tau * (G0 + G1), "work_of_adhesion": dg}


# --------------------------------------------------------------------------------------
# The scipy side: the same residuals in vectorised numpy
# --------------------------------------------------------------------------------------


class NumpyData:
    """The prepared `CurveBatch` as numpy arrays (curves of one length, uniform sampling)."""

    def __init__(self, data):
        for key in ("ts", "drive", "force", "valid", "sigma", "ramp_width", "depth",
                    "pull_force", "pull_sigma", "jump_disp", "jump_sigma", "has_jump"):
            setattr(self, key, np.asarray(getattr(data, key)))
        self.R = float(data.profile.R)
        if not np.all(self.valid > 0):
            raise ValueError("the numpy model assumes curves of one length (no padding)")
        dt = np.diff(self.ts, axis=1)
        if not np.allclose(dt, dt[:, :1], rtol=1e-9, atol=0):
            raise ValueError("the numpy model assumes uniform sampling per curve")
        self.dt = dt[:, 0]


def _phi(x):
    return np.where(x > 0, -np.expm1(-x) / np.where(x > 0, x, 1.0), 1.0)


def _stable_radius(m, c, R):
    """Stable root of a²/R - c√a = m (Ferrari closed form + one Newton polish)."""
    lam = np.cbrt(c * R)
    mu = np.maximum(R * m / lam**4, -0.75 * 4.0 ** (-1.0 / 3.0))
    disc = np.maximum(1.0 / 256.0 + mu**3 / 27.0, 0.0)
    t1 = np.cbrt(1.0 / 16.0 + np.sqrt(disc))
    y = t1 - mu / (3.0 * t1)
    r2y = np.sqrt(2.0 * y)
    s = 0.5 * (r2y + np.sqrt(np.maximum(2.0 / r2y - 2.0 * y, 0.0)))
    slope = 4.0 * s**3 - 1.0
    s = np.where(slope > 1e-3, s - (s**4 - s - mu) / np.where(slope > 1e-3, slope, 1.0), s)
    return (lam * s) ** 2


def numpy_residuals(theta, d: NumpyData):
    """`fitting.residuals` (relaxed model, standard rheology, parabola) in numpy."""
    with np.errstate(all="ignore"):
        return _numpy_residuals(theta, d)


def _numpy_residuals(theta, d: NumpyData):
    G0, G1, eta1, dg = np.exp(theta)
    R = d.R
    G_inf = G0 * G1 / (G0 + G1)
    G_arm = G0 * G0 / (G0 + G1)
    G_g = G_inf + G_arm
    tau = eta1 / (G0 + G1)
    ratio, rho = G_arm / G_g, G_g / G_inf
    depth = d.depth[:, None]
    delta = d.drive - depth
    # exact exponential update of the arm variable over each (uniform) interval
    ddelta = np.diff(delta, axis=1, prepend=0.0)
    w = np.empty_like(delta)
    for k in range(delta.shape[0]):
        alpha = math.exp(-d.dt[k] / tau)
        beta = ratio * ddelta[k] * _phi(np.r_[0.0, np.full(delta.shape[1] - 1, d.dt[k] / tau)])
        w[k] = lfilter([1.0], [1.0, -alpha], beta)
    d_eff = d.drive + rho * w
    c = math.sqrt(0.5 * math.pi * dg * G_g) / G_inf
    a0 = np.sqrt(R * d.depth)

    def h(a):
        return a * a / R - c * np.sqrt(a)

    a_fold = (0.5 * c * R / 2) ** (2 / 3)
    a_fc = (1.5 * c * R / 2) ** (2 / 3)
    h_pin = h(a0)
    a_crit = np.minimum(a_fold, a0)
    h_crit = h(a_crit)
    m = np.minimum.accumulate(d_eff, axis=1)
    attached = m >= h_crit[:, None]
    receding = attached & (m < h_pin[:, None]) & (a0 > a_fold)[:, None]
    a_safe = np.maximum(a0, 2 * a_fold)
    m_safe = np.where(receding, m, h(a_safe)[:, None])
    radius = np.where(receding, _stable_radius(m_safe, c, R),
                      np.where(attached, a0[:, None], 0.0))
    radius_safe = np.where(attached, radius, a0[:, None])

    def force_at(a, deff):
        return 8 * G_inf * (a * deff - a**3 / (3 * R))

    force = np.where(attached, force_at(radius_safe, d_eff), 0.0)
    detached = ~attached[:, -1]
    a_end = np.where(detached, a_crit, radius[:, -1])
    visited = detached | receding[:, -1]
    a_min = np.clip(a_fc, a_end, a0)
    f_front = force_at(a_min, h(a_min))
    max_tensile = np.minimum(force.min(axis=1), np.where(visited, f_front, np.inf))

    # jump-off time, refined inside its sampling interval
    n_c = delta.shape[0]
    t_jump = np.full(n_c, np.inf)
    jump_disp = np.full(n_c, np.nan)
    for k in np.flatnonzero(detached):
        i_j = int(np.argmax(~attached[k]))
        i_a = max(i_j - 1, 0)
        t_a, delta_a, w_a = d.ts[k, i_a], delta[k, i_a], w[k, i_a]
        span = d.ts[k, i_j] - t_a
        if i_j == 0 or span <= 0:
            t_jump[k] = d.ts[k, i_j]
            jump_disp[k] = depth[k, 0] + delta_a
            continue
        slope = (delta[k, i_j] - delta_a) / span

        def resid(u, k=k, delta_a=delta_a, w_a=w_a, slope=slope):
            ww = w_a * math.exp(-u / tau) + ratio * slope * u * float(_phi(u / tau))
            return d.depth[k] + delta_a + slope * u + rho * ww - h_crit[k]

        lo, hi = resid(0.0), resid(span)
        u = brentq(resid, 0.0, span, xtol=1e-14 * span) if lo * hi < 0 else (
            0.0 if abs(lo) < abs(hi) else span)
        t_jump[k] = t_a + u
        jump_disp[k] = d.depth[k] + delta_a + slope * u

    ramp_x = np.clip((t_jump[:, None] - d.ts) / d.ramp_width[:, None], 0.0, 1.0)
    ramp = ramp_x * ramp_x * (3.0 - 2.0 * ramp_x)
    force = np.where(np.isfinite(force), force, 0.0)
    r_force = d.valid * ramp * (force - d.force) / d.sigma[:, None]
    r_pull = (max_tensile - d.pull_force) / d.pull_sigma
    jd = np.where(np.isfinite(jump_disp), jump_disp, d.jump_disp)
    r_jump = d.has_jump * (jd - d.jump_disp) / d.jump_sigma
    r = np.concatenate([r_force.ravel(), r_pull, r_jump])
    return np.where(np.isfinite(r), r, 1e6)


def scipy_fit(theta0, d: NumpyData):
    return least_squares(numpy_residuals, theta0, args=(d,), method="trf")


# --------------------------------------------------------------------------------------
# The JAX side
# --------------------------------------------------------------------------------------


def setup(curves, spec):
    """(data, parameterisation, z0s, initial log-parameters) exactly as `fitting.fit` does."""
    profile = jc.Parabola(R)
    data = prepare_curves(curves, spec, profile=profile)
    guess = initial_guess(curves, spec, profile)
    param = make_parameterisation(list(NAMES), guess, None, None)
    z0s = jnp.asarray(param.z_of(np.asarray(param.reference))[None, :])
    return data, param, z0s, np.log([guess[k] for k in NAMES])


def run_fit(curves):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fitting.IdentifiabilityWarning)
        return fitting.fit(curves, radius=R, n_starts=1, progress=False)


def timed(fn, repeats):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def rel(a, b):
    return np.abs(np.asarray(a) / np.asarray(b) - 1.0)


def fmt(p):
    return ", ".join(f"{k}={v:.5g}" for k, v in zip(NAMES, p, strict=True))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--samples", type=int, default=200, help="samples per curve")
    ap.add_argument("--repeats", type=int, default=7, help="repeats of the warm timings")
    ap.add_argument("--batch", type=int, default=100, help="independent curve sets")
    ap.add_argument("--noise", type=float, default=0.01, help="noise, fraction of the range")
    args = ap.parse_args()

    print(f"devices: {jax.devices()}; {os.cpu_count()} CPU(s); load average "
          f"{', '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"data: relaxed model, standard rheology, parabola R = {R:g} m, "
          f"{len(SPEEDS)} speeds x {args.samples} samples, {args.noise:.0%} noise; "
          "one start, same initial guess for both")
    spec = make_spec("relaxed", "standard")
    curves = make_curves(TRUE, args.samples, args.noise, seed=1)

    # ---- 2. cold --------------------------------------------------------------------
    t0 = time.perf_counter()
    res = run_fit(curves)
    cold_fit = time.perf_counter() - t0
    print(f"\n[cold] first fitting.fit call (compile + run): {cold_fit:.2f} s "
          f"(its own timings: optimise {res.timings['optimise']:.2f} s, "
          f"uncertainty {res.timings['uncertainty']:.2f} s)")

    # ---- 1. warm single fit -----------------------------------------------------------
    data, param, z0s, theta0 = setup(curves, spec)
    nd = NumpyData(data)
    th_true = np.log([TRUE[k] for k in NAMES])
    r_jax = np.asarray(residuals(jnp.asarray(th_true), data, spec))
    r_np = numpy_residuals(th_true, nd)
    r_jax0 = np.asarray(residuals(jnp.asarray(theta0), data, spec))
    r_np0 = numpy_residuals(theta0, nd)
    print(f"residual check (numpy vs JAX), max |diff| / max |r|: at truth "
          f"{np.max(np.abs(r_np - r_jax)) / np.max(np.abs(r_jax)):.1e}, at the initial guess "
          f"{np.max(np.abs(r_np0 - r_jax0)) / np.max(np.abs(r_jax0)):.1e}")

    def jax_solve():
        out = solve(spec, param, data, z0s)
        jax.block_until_ready(out)
        return out

    jax_solve()  # compiled already by fit(); this call only warms the dispatch cache
    t_fit, res = timed(lambda: run_fit(curves), args.repeats)
    t_solve, (zs, chi2s, oks, steps) = timed(jax_solve, args.repeats)
    t_scipy, sres = timed(lambda: scipy_fit(theta0, nd), args.repeats)
    p_jax = np.asarray(res.values)
    p_solve = np.exp(np.asarray(param.theta(zs[0])))
    p_scipy = np.exp(sres.x)
    print(f"\n[warm, single fit] medians of {args.repeats}")
    print(f"  fitting.fit (end to end)      : {t_fit * 1e3:9.2f} ms   "
          f"(optimise {res.timings['optimise'] * 1e3:.2f} ms, uncertainty "
          f"{res.timings['uncertainty'] * 1e3:.2f} ms, prepare {res.timings['prepare'] * 1e3:.2f}"
          f" ms of the last call)")
    print(f"  jitted optimiser (solve)      : {t_solve * 1e3:9.2f} ms   "
          f"({int(steps[0])} LM steps, converged={bool(oks[0])}, chi2={float(chi2s[0]):.6g})")
    print(f"  scipy least_squares (trf, FD) : {t_scipy * 1e3:9.2f} ms   "
          f"({sres.nfev} residual evaluations + {sres.njev} FD Jacobians "
          f"= {sres.nfev + 4 * sres.njev} calls, status {sres.status}, "
          f"chi2={2 * sres.cost:.6g})")
    print(f"  ratio scipy / fitting.fit     : {t_scipy / t_fit:6.1f}x")
    print(f"  ratio scipy / solve           : {t_scipy / t_solve:6.1f}x")
    print(f"  fitting.fit : {fmt(p_jax)}")
    print(f"  scipy       : {fmt(p_scipy)}")
    print(f"  truth       : {fmt([TRUE[k] for k in NAMES])}")
    print(f"  max relative difference fit vs scipy: {rel(p_jax, p_scipy).max():.2e} "
          f"(fit vs solve {rel(p_jax, p_solve).max():.1e}); "
          f"fit vs truth {rel(p_jax, [TRUE[k] for k in NAMES]).max():.2e}, scipy vs truth "
          f"{rel(p_scipy, [TRUE[k] for k in NAMES]).max():.2e}; "
          f"GN stderr/value {fmt(res.stderr / res.values)}")

    # ---- 3. batch -----------------------------------------------------------------------
    rng = np.random.default_rng(2024)
    truths, sets = [], []
    for k in range(args.batch):
        p = random_truth(rng)
        truths.append([p[n] for n in NAMES])
        sets.append(setup(make_curves(p, args.samples, args.noise, seed=1000 + k), spec))
    truths = np.array(truths)
    free = param.free
    stack = lambda *xs: jnp.stack(xs)  # noqa: E731
    datas = jax.tree.map(stack, *[s[0] for s in sets])
    params = jax.tree.map(stack, *[s[1] for s in sets])
    z0b = jnp.stack([s[2] for s in sets])

    def make_batched(rtol):
        @eqx.filter_jit
        def batched(params, datas, z0b):
            def one(pa, da, z0):
                z, chi2, ok, it = solve(spec, pa, da, z0, rtol=rtol)
                return pa.theta(z[0]), chi2[0], ok[0], it[0]

            return jax.vmap(one)(params, datas, z0b)

        return batched

    assert all(s[1].free == free for s in sets)
    n_rep = max(3, args.repeats // 2)
    runs = {}
    for rtol in (1e-10, 1e-8):  # 1e-10: the default of solve; 1e-8: scipy's ftol
        batched = make_batched(rtol)
        t0 = time.perf_counter()
        jax.block_until_ready(batched(params, datas, z0b))
        cold_b = time.perf_counter() - t0
        t_b, out = timed(lambda batched=batched: jax.block_until_ready(
            batched(params, datas, z0b)), n_rep)
        runs[rtol] = (t_b, cold_b, out)
    t_batch, cold_batch, (th_b, chi2_b, ok_b, it_b) = runs[1e-10]

    t0 = time.perf_counter()
    loop = [jax.block_until_ready(solve(spec, s[1], s[0], s[2])) for s in sets]
    t_loop = time.perf_counter() - t0
    steps_loop = np.array([int(o[3][0]) for o in loop])

    t0 = time.perf_counter()
    sc = [scipy_fit(s[3], NumpyData(s[0])) for s in sets]
    t_seq = time.perf_counter() - t0
    p_b = np.exp(np.asarray(th_b))
    p_s = np.exp(np.array([r.x for r in sc]))
    diff = rel(p_b, p_s).max(axis=1)
    chi_j = np.asarray(chi2_b)
    chi_s = np.array([2 * r.cost for r in sc])
    err_j = rel(p_b, truths).max(axis=1)
    err_s = rel(p_s, truths).max(axis=1)
    print(f"\n[batch] {args.batch} independent curve sets "
          f"({len(SPEEDS)} x {args.samples} samples each)")
    for rtol, (t_b, cold_b, (_, _, ok_r, it_r)) in runs.items():
        it_r = np.asarray(it_r)
        print(f"  JAX vmapped optimiser, one call, rtol={rtol:.0e}: {t_b:8.3f} s (median of "
              f"{n_rep}; first call incl. compile {cold_b:.2f} s); LM steps per set median "
              f"{int(np.median(it_r))}, 90th pct {int(np.percentile(it_r, 90))}, max "
              f"{int(np.max(it_r))}; converged {int(np.sum(ok_r))}/{args.batch}; "
              f"ratio scipy/this {t_seq / t_b:.1f}x")
    print(f"  JAX jitted solve, python loop over sets : {t_loop:8.3f} s (steps median "
          f"{int(np.median(steps_loop))}, max {int(np.max(steps_loop))}); "
          f"ratio scipy/this {t_seq / t_loop:.1f}x")
    print(f"  scipy, {args.batch} sequential fits        : {t_seq:8.3f} s "
          f"(median {statistics.median(r.nfev for r in sc)} evaluations + "
          f"{statistics.median(r.njev for r in sc)} Jacobians per fit)")
    print(f"  ratio sequential scipy / batched JAX (rtol=1e-10, as fit uses): "
          f"{t_seq / t_batch:6.1f}x")
    p_8 = np.exp(np.asarray(runs[1e-8][2][0]))
    print(f"  rtol=1e-8 vs rtol=1e-10 parameters: max relative difference "
          f"{rel(p_8, p_b).max():.1e}")
    print(f"  agreement JAX vs scipy (max relative parameter difference per set): median "
          f"{np.median(diff):.1e}, max {np.max(diff):.1e}; sets within 1e-3: "
          f"{int(np.sum(diff < 1e-3))}/{args.batch}")
    print(f"  chi2 JAX - scipy (per set): median {np.median(chi_j - chi_s):.2e}, "
          f"min {np.min(chi_j - chi_s):.2e}, max {np.max(chi_j - chi_s):.2e}")
    tol = 1e-6 * np.maximum(chi_s, 1.0)
    print(f"  lower chi2 (by > 1e-6 relative): JAX in {int(np.sum(chi_j < chi_s - tol))} sets, "
          f"scipy in {int(np.sum(chi_s < chi_j - tol))} sets")
    slow = np.argsort(np.asarray(it_b))[-10:]
    print(f"  the 10 sets with most JAX LM steps: steps {np.asarray(it_b)[slow].tolist()}; "
          f"scipy evaluations there {[int(sc[i].nfev) for i in slow]}; their error vs truth "
          f"(JAX) {[float(f'{e:.2g}') for e in err_j[slow]]}")
    print(f"  error vs truth (max over parameters): JAX median {np.median(err_j):.2e}, "
          f"max {np.max(err_j):.2e}; scipy median {np.median(err_s):.2e}, max {np.max(err_s):.2e}")
    print(f"\nload average at the end: {', '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
