"""Fit speed on the shipped oocyte curve: `fitting.fit`, cold and warm, against scipy.

Workload: the shipped JPK stress-relaxation curve of a mouse oocyte
(`tests/data/oocyte-stress-relaxation-cell1-0008.jpk-force`: approach, 30 s hold, retract;
R = 40 µm assumed), full-history model, contact point fitted (the default for instrument
files), default sample budget.

Measured, in one run:

1. `fitting.fit` with the default number of starts (`fitting.DEFAULT_STARTS`), standard
   model and `prony:2` (nested: the standard fit first): the cold time (first call in the
   process: compilation included) and the warm time (median of `--repeats` calls), R², R²
   in contact, χ²;
2. the baseline: one local fit from the same data-based start (`fitting.initial_guess`)
   by `scipy.optimize.least_squares` (method "trf", its default 2-point finite-difference
   Jacobian and tolerances) on the same weighted residual vector (`fitting.residuals`,
   jitted, called from numpy) in log-parameters, against `fitting.fit(n_starts=1,
   local_rounds=0)` (one local fit, no rounds) from the
   same start (warm medians, round-robin, and their ratio).

    python benchmarks/bench_fit.py [--repeats 3] [--rheologies standard,prony:2]
        [--out benchmarks/results/fit.md]

The XLA options of `jaxcontact fit` (`fitting.tune_xla_cpu`) are applied first; no
persistent compilation cache (cold: everything compiled in the process). Writes the table
with machine and date to `--out`. Run time about 10 min on 2 CPU cores.
"""

from __future__ import annotations

import argparse
import pathlib
import statistics
import time
import warnings

import jax
import jax.numpy as jnp
import numpy as np
from _results import machine, write_table  # benchmarks/_results.py
from scipy.optimize import least_squares

import fitting

jax.config.update("jax_enable_x64", True)

DATA = pathlib.Path(__file__).resolve().parents[1] / "tests" / "data"
CURVE = DATA / "oocyte-stress-relaxation-cell1-0008.jpk-force"
R = 40e-6


def _fit(curve, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t0 = time.perf_counter()
        res = fitting.fit(curve, radius=R, model="history", progress=False, **kw)
        return res, time.perf_counter() - t0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--rheologies", default="standard,prony:2",
                    help="comma-separated rheologies of part 1 (prony:2 takes minutes)")
    ap.add_argument("--out", default="benchmarks/results/fit.md")
    args = ap.parse_args(argv)
    flags = fitting.tune_xla_cpu()  # as `jaxcontact fit` does, before JAX starts its backend
    print(f"XLA flags added: {flags or 'none'}", flush=True)
    curve = fitting.load_curve(CURVE)[0]
    rows = []

    # 1. default search, cold and warm
    for rheology in args.rheologies.split(","):
        res, cold = _fit(curve, rheology=rheology)
        warm = [_fit(curve, rheology=rheology)[1] for _ in range(args.repeats)]
        rows.append(f"| fit, {rheology}, {fitting.DEFAULT_STARTS} starts and up to "
                    f"{fitting.DEFAULT_LOCAL_ROUNDS} local rounds | {cold:.1f} | "
                    f"{statistics.median(warm):.1f} | {res.r_squared:.4f} | "
                    f"{res.r_squared_contact:.4f} | {res.chi2:.6g} |")
        print(rows[-1], flush=True)

    # 2. one local fit from the same start: fitting.fit(n_starts=1) against scipy
    one, _ = _fit(curve, n_starts=1, local_rounds=0)  # compiles the one-start program
    spec, data = one.spec, one.data
    guess = fitting.initial_guess([curve], spec, one.profile,
                                  fitting.data_scales([curve], spec, one.profile))
    x0 = np.log(np.abs([guess[n] for n in one.names]))
    sign = np.sign([guess[n] if guess[n] != 0 else 1.0 for n in one.names])
    lin = np.array([n in ("contact_offset", "force_offset") for n in one.names])
    x0[lin] = np.array([guess[n] for n in one.names])[lin]
    res_fn = jax.jit(lambda p: fitting.residuals(p, data, spec))

    def natural(x):
        return np.where(lin, x, sign * np.exp(x))

    def fun(x):
        return np.asarray(res_fn(jnp.asarray(natural(x))))

    fun(x0)  # compile
    t_jax, t_scipy, chi2_scipy = [], [], None
    for _ in range(args.repeats):
        t_jax.append(_fit(curve, n_starts=1, local_rounds=0)[1])
        t0 = time.perf_counter()
        sp = least_squares(fun, x0, method="trf")
        t_scipy.append(time.perf_counter() - t0)
        chi2_scipy = float(2 * sp.cost)
    mj, ms = statistics.median(t_jax), statistics.median(t_scipy)
    rows.append(f"| fit, standard, 1 start (data-based guess) | | {mj:.2f} | "
                f"{one.r_squared:.4f} | {one.r_squared_contact:.4f} | {one.chi2:.6g} |")
    rows.append(f"| scipy least_squares (trf, 2-point FD Jacobian), same start, same "
                f"residuals | | {ms:.2f} | | | {chi2_scipy:.6g} |")
    rows.append(f"| ratio scipy / fitting (1 start, warm medians) | | {ms / mj:.2f} | | | |")
    print("\n".join(rows[-3:]), flush=True)

    head = [
        "# Fit speed: the shipped oocyte curve (history model, contact point fitted)",
        "",
        f"{machine()} (shared machine: other work may have run at the same time); "
        f"`python benchmarks/bench_fit.py --repeats {args.repeats}`. Cold: first call in the "
        "process (compilation included); warm: median of the repeats.",
        "",
        "| what | cold [s] | warm [s] | R² | R² in contact | χ² |",
        "|---|---|---|---|---|---|",
    ]
    write_table(args.out, head + rows)


if __name__ == "__main__":
    main()
