"""Fit speed: `fitting.fit` (JAX; Levenberg–Marquardt or optax L-BFGS) against scipy.

Workload: synthetic retract curves from the relaxed-start model (`jc.retract`), standard
model, parabola (R = 10 µm, relaxed depth 1 µm), three lift speeds, `--samples` samples per
curve, 1 % noise (as in tests/test_fitting.py). Both fitters start from the same data-driven
initial guess (`fitting.initial_guess`, the default of `fit`), use one start, work on
log-parameters, and minimise the same weighted residual vector (`fitting.residuals`: ramp-
weighted force residuals plus the pull-off and jump-off event residuals) on the same
prepared `CurveBatch`. The scipy side is what a user would write today: the same closed
form in vectorised numpy (exact exponential update of the arm variable via `lfilter`,
running minimum, the stable closed-form front root, `brentq` for the jump-off time inside
its sampling interval) and `least_squares(method="trf")` with its default 2-point
finite-difference Jacobian and default tolerances (`ftol = xtol = gtol = 1e-8`). The JAX
optimisers run with `rtol = 1e-8` (relative change of chi2, and for LM of the step), the
default of `fitting.fit`.

Measured, in one run (the CPU may be shared: warm timings are taken round-robin, one call
of each contender per round, and the medians are compared):

1. warm time of one fit: `fitting.fit` end to end (preparation, optimisation, Gauss–Newton
   uncertainty, prediction) with `optimiser="lm"` and `"lbfgs"`, the jitted optimiser
   `fitting._optimise.solve` alone (both optimisers), and `least_squares`; the ratios and
   the parameter agreement;
2. the cold time of the first `fitting.fit` call of each optimiser (compilation included);
3. `--batch` independent curve sets (different true parameters and noise) against the same
   number of sequential scipy fits: `fitting._optimise.solve_batch` (one compiled call,
   `--workers` lanes scheduled as a pool: a lane whose set has converged takes the next
   one) spread over every CPU device and on one device, one plain `vmap` over all sets
   (every lane runs until the slowest set stops), and a Python loop over the jitted
   `solve` (LM and L-BFGS).

JAX setup (printed at the start): the XLA CPU option of the command line
(`fitting.tune_xla_cpu`; `--no-xla-tuning` leaves XLA's defaults) and one JAX CPU
device per usable core (`--cpu-devices`); single fits run on the first device. scipy and
numpy run on one core. On a shared machine, pinning the process to one core
(``taskset -c 0 python benchmarks/bench_fit.py``) gives steadier single-fit timings: XLA
then keeps its small kernels on one thread.

    python benchmarks/bench_fit.py [--samples 200] [--repeats 7] [--batch 100] [--workers 8]

Run time about 1.5–2 min on 2 CPU cores (mostly compilation and the scipy fits).
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
from fitting import tune_xla_cpu
from fitting._objective import initial_guess, make_spec, prepare_curves, residuals
from fitting._optimise import make_parameterisation, solve, solve_batch

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
        # one-sided jump-off residual of curves that end still attached (if the objective has it)
        self.attached_end = np.asarray(getattr(data, "attached_end", np.zeros_like(self.has_jump)))
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
    r_jump = (d.has_jump * (jd - d.jump_disp)
              + d.attached_end * np.maximum(jd - d.jump_disp, 0.0)) / d.jump_sigma
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


def run_fit(curves, optimiser="lm"):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fitting.IdentifiabilityWarning)
        return fitting.fit(curves, radius=R, n_starts=1, progress=False, optimiser=optimiser)


def timed(fn, repeats):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def timed_round_robin(fns, repeats):
    """Median time of each function, calling each once per round (shared-CPU drift cancels)."""
    times = {k: [] for k in fns}
    outs = {}
    for _ in range(repeats):
        for k, fn in fns.items():
            t0 = time.perf_counter()
            outs[k] = fn()
            times[k].append(time.perf_counter() - t0)
    return {k: statistics.median(v) for k, v in times.items()}, outs, times


def rel(a, b):
    return np.abs(np.asarray(a) / np.asarray(b) - 1.0)


def fmt(p):
    return ", ".join(f"{k}={v:.5g}" for k, v in zip(NAMES, p, strict=True))


def load():
    return ", ".join(f"{x:.2f}" for x in os.getloadavg())


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--samples", type=int, default=200, help="samples per curve")
    ap.add_argument("--repeats", type=int, default=7, help="rounds of the warm timings")
    ap.add_argument("--batch", type=int, default=100, help="independent curve sets")
    ap.add_argument("--workers", type=int, default=8,
                    help="lanes of the pooled batch solve (solve_batch)")
    ap.add_argument("--noise", type=float, default=0.01, help="noise, fraction of the range")
    ap.add_argument("--no-xla-tuning", action="store_true",
                    help="leave XLA's CPU options at their defaults (the command line applies "
                         "fitting.XLA_CPU_FLAGS; see fitting.tune_xla_cpu)")
    ap.add_argument("--cpu-devices", type=int, default=None,
                    help="CPU devices JAX exposes (default: the usable cores); solve_batch "
                         "spreads the batch over them, single fits use the first")
    args = ap.parse_args()
    # before the first JAX computation starts the backend:
    if not args.no_xla_tuning:
        tune_xla_cpu()
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 1
    jax.config.update("jax_num_cpu_devices", args.cpu_devices or usable)

    print(f"devices: {jax.devices()}; {usable} of {os.cpu_count()} CPU(s) usable; "
          f"XLA_FLAGS={os.environ.get('XLA_FLAGS', '')!r}; load average {load()}")
    print(f"data: relaxed model, standard rheology, parabola R = {R:g} m, "
          f"{len(SPEEDS)} speeds x {args.samples} samples, {args.noise:.0%} noise; "
          "one start, same initial guess for both; JAX rtol = 1e-8, scipy default tolerances")
    spec = make_spec("relaxed", "standard")
    curves = make_curves(TRUE, args.samples, args.noise, seed=1)

    # ---- 2. cold --------------------------------------------------------------------
    for opt in ("lm", "lbfgs"):
        t0 = time.perf_counter()
        res = run_fit(curves, opt)
        cold_fit = time.perf_counter() - t0
        print(f"[cold] first fitting.fit(optimiser={opt!r}) call (compile + run): "
              f"{cold_fit:.2f} s")

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

    def jax_solve(opt):
        out = solve(spec, param, data, z0s, optimiser=opt)
        jax.block_until_ready(out)
        return out

    for opt in ("lm", "lbfgs"):
        jax_solve(opt)  # compile the stand-alone optimisers (fit() compiles its own call)
    fns = {
        "fit_lm": lambda: run_fit(curves, "lm"),
        "fit_lbfgs": lambda: run_fit(curves, "lbfgs"),
        "solve_lm": lambda: jax_solve("lm"),
        "solve_lbfgs": lambda: jax_solve("lbfgs"),
        "scipy": lambda: scipy_fit(theta0, nd),
    }
    t, outs, _ = timed_round_robin(fns, args.repeats)
    sres = outs["scipy"]
    p_scipy = np.exp(sres.x)
    truth = [TRUE[k] for k in NAMES]
    print(f"\n[warm, single fit] medians of {args.repeats} rounds")
    for opt in ("lm", "lbfgs"):
        res = outs[f"fit_{opt}"]
        tm = res.timings
        print(f"  fitting.fit, {opt:5s} (end to end) : {t[f'fit_{opt}'] * 1e3:9.2f} ms   "
              f"(of the last call: prepare {tm['prepare'] * 1e3:.2f} ms, optimise + Jacobian"
              f" + prediction {tm['optimise'] * 1e3:.2f} ms, uncertainty "
              f"{tm['uncertainty'] * 1e3:.2f} ms; {int(res.start_steps[0])} steps)")
    for opt in ("lm", "lbfgs"):
        zs, chi2s, oks, steps = outs[f"solve_{opt}"]
        print(f"  jitted optimiser solve, {opt:5s}  : {t[f'solve_{opt}'] * 1e3:9.2f} ms   "
              f"({int(steps[0])} steps, converged={bool(oks[0])}, chi2={float(chi2s[0]):.9g})")
    print(f"  scipy least_squares (trf, FD)   : {t['scipy'] * 1e3:9.2f} ms   "
          f"({sres.nfev} residual evaluations + {sres.njev} FD Jacobians "
          f"= {sres.nfev + 4 * sres.njev} calls, status {sres.status}, "
          f"chi2={2 * sres.cost:.9g})")
    for k in ("fit_lm", "fit_lbfgs", "solve_lm", "solve_lbfgs"):
        print(f"  ratio scipy / {k:12s}     : {t['scipy'] / t[k]:6.1f}x")
    for opt in ("lm", "lbfgs"):
        res = outs[f"fit_{opt}"]
        print(f"  fitting.fit {opt:5s}: {fmt(res.values)}; max rel. difference to scipy "
              f"{rel(res.values, p_scipy).max():.1e}, chi2 - scipy "
              f"{res.chi2 - 2 * sres.cost:+.2e}")
    print(f"  scipy            : {fmt(p_scipy)}")
    print(f"  truth            : {fmt(truth)}")
    res = outs["fit_lm"]
    print(f"  fit vs truth {rel(res.values, truth).max():.2e}, scipy vs truth "
          f"{rel(p_scipy, truth).max():.2e}; GN stderr/value {fmt(res.stderr / res.values)}")

    # ---- 3. batch -----------------------------------------------------------------------
    rng = np.random.default_rng(2024)
    truths, sets = [], []
    for k in range(args.batch):
        p = random_truth(rng)
        truths.append([p[n] for n in NAMES])
        sets.append(setup(make_curves(p, args.samples, args.noise, seed=1000 + k), spec))
    truths = np.array(truths)
    assert all(s[1].free == param.free for s in sets)
    stack = lambda *xs: jnp.stack(xs)  # noqa: E731
    datas = jax.tree.map(stack, *[s[0] for s in sets])
    params = jax.tree.map(stack, *[s[1] for s in sets])
    z0b = jnp.concatenate([s[2] for s in sets])
    n_rep = max(3, args.repeats // 2)

    def pooled():  # spread over every device (the CPU cores, see --cpu-devices)
        return jax.block_until_ready(
            solve_batch(spec, params, datas, z0b, workers=args.workers))

    def pooled_one():  # one device: one core
        return jax.block_until_ready(solve_batch(spec, params, datas, z0b, workers=args.workers,
                                                 devices=jax.devices()[:1]))

    @eqx.filter_jit
    def vmapped(params, datas, z0b):
        def one(pa, da, z0):
            z, chi2, ok, it = solve(spec, pa, da, z0[None])
            return z[0], chi2[0], ok[0], it[0]

        return jax.vmap(one)(params, datas, z0b)

    def loop(opt):
        return [jax.block_until_ready(solve(spec, s[1], s[0], s[2], optimiser=opt))
                for s in sets]

    print(f"\n[batch] {args.batch} independent curve sets "
          f"({len(SPEEDS)} x {args.samples} samples each); load average {load()}")
    t0 = time.perf_counter()
    sc = [scipy_fit(s[3], NumpyData(s[0])) for s in sets]
    t_seq = time.perf_counter() - t0
    t0 = time.perf_counter()
    pooled()
    cold_pool = time.perf_counter() - t0
    t_pool, (z_b, chi2_b, ok_b, it_b) = timed(pooled, n_rep)
    t0 = time.perf_counter()
    pooled_one()
    cold_one = time.perf_counter() - t0
    t_one, out_one = timed(pooled_one, n_rep)
    t0 = time.perf_counter()
    jax.block_until_ready(vmapped(params, datas, z0b))
    cold_vmap = time.perf_counter() - t0
    t_vmap, out_vmap = timed(lambda: jax.block_until_ready(vmapped(params, datas, z0b)), 1)
    t_loop, out_loop = timed(lambda: loop("lm"), 1)
    t_lb, out_lb = timed(lambda: loop("lbfgs"), 1)
    t0 = time.perf_counter()
    sc = [scipy_fit(s[3], NumpyData(s[0])) for s in sets]
    t_seq = min(t_seq, time.perf_counter() - t0)  # the faster of two runs (favours scipy)

    it_b = np.asarray(it_b)
    th_b = np.array([np.asarray(s[1].theta(z)) for s, z in zip(sets, np.asarray(z_b),
                                                                 strict=True)])
    p_b = np.exp(th_b)
    p_s = np.exp(np.array([r.x for r in sc]))
    p_lb = np.exp(np.array([np.asarray(s[1].theta(o[0][0])) for s, o in zip(sets, out_lb,
                                                                               strict=True)]))
    chi_j = np.asarray(chi2_b)
    chi_s = np.array([2 * r.cost for r in sc])
    chi_lb = np.array([float(o[1][0]) for o in out_lb])
    it_lb = np.array([int(o[3][0]) for o in out_lb])
    it_v = np.asarray(out_vmap[3])
    print(f"  scipy, {args.batch} sequential fits            : {t_seq:8.3f} s (faster of 2 "
          f"runs; median {statistics.median(r.nfev for r in sc)} evaluations + "
          f"{statistics.median(r.njev for r in sc)} Jacobians per fit)")
    n_dev = jax.device_count()
    print(f"  JAX solve_batch LM, {n_dev} device(s) x pool of {args.workers} lanes: {t_pool:8.3f} s"
          f" (median of {n_rep}; first call incl. compile {cold_pool:.2f} s); steps per set "
          f"median {int(np.median(it_b))}, 90th pct {int(np.percentile(it_b, 90))}, max "
          f"{int(np.max(it_b))}, sum {int(np.sum(it_b))}; converged "
          f"{int(np.sum(ok_b))}/{args.batch}; ratio scipy/this {t_seq / t_pool:.1f}x")
    same = np.allclose(np.asarray(out_one[1]), np.asarray(chi2_b), rtol=1e-9)
    print(f"  JAX solve_batch LM, 1 device x pool of {args.workers} lanes : {t_one:8.3f} s "
          f"(median of {n_rep}; first call incl. compile {cold_one:.2f} s); same chi2 as the "
          f"spread batch: {same}; ratio scipy/this {t_seq / t_one:.1f}x")
    print(f"  JAX LM, one plain vmap over all sets : {t_vmap:8.3f} s (first call incl. compile "
          f"{cold_vmap:.2f} s; every lane runs {int(np.max(it_v))} steps, the slowest set's); "
          f"ratio scipy/this {t_seq / t_vmap:.1f}x")
    print(f"  JAX LM, Python loop of jitted solve  : {t_loop:8.3f} s; "
          f"ratio scipy/this {t_seq / t_loop:.1f}x")
    print(f"  JAX L-BFGS, Python loop of jitted solve: {t_lb:6.3f} s (iterations per set "
          f"median {int(np.median(it_lb))}, max {int(np.max(it_lb))}; converged "
          f"{sum(bool(o[2][0]) for o in out_lb)}/{args.batch}); ratio scipy/this "
          f"{t_seq / t_lb:.1f}x")
    print(f"  ratio sequential scipy / solve_batch (LM): {t_seq / t_pool:6.1f}x on {n_dev} "
          f"device(s), {t_seq / t_one:6.1f}x on one (scipy runs on one core)")
    best = np.minimum(np.minimum(chi_j, chi_s), chi_lb)
    for name, chi, p in (("JAX LM", chi_j, p_b), ("JAX L-BFGS", chi_lb, p_lb),
                         ("scipy", chi_s, p_s)):
        gap = (chi - best) / best
        err = rel(p, truths).max(axis=1)
        print(f"  {name:10s}: chi2 above the best of the three by > 1e-6 relative in "
              f"{int(np.sum(gap > 1e-6))} sets, by > 1 % in {int(np.sum(gap > 0.01))}; "
              f"error vs truth (max over parameters) median {np.median(err):.2e}, "
              f"90th pct {np.percentile(err, 90):.2e}")
    diff = rel(p_b, p_s).max(axis=1)
    print(f"  JAX LM vs scipy, max relative parameter difference per set: median "
          f"{np.median(diff):.1e}; sets within 1e-3: {int(np.sum(diff < 1e-3))}/{args.batch};"
          f" sets with the same chi2 (1e-6 relative): "
          f"{int(np.sum(np.abs(chi_j - chi_s) <= 1e-6 * chi_s))}")
    print(f"\nload average at the end: {load()}")


if __name__ == "__main__":
    main()
