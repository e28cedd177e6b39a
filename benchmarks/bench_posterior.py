"""Calibration of `fitting.sample` (NUTS posterior) on synthetic curves of known parameters.

Simulation-based calibration in its simplest form: `--curves` sets of true parameters are
drawn at random (log-uniform: G0 in [5, 20] kPa, G1/G0 in [0.3, 0.7], tau = eta1/G1 in
[0.5, 3] s, work of adhesion in [0.5, 2] mJ/m^2), each gives three retract curves of the
relaxed model (`jaxcontact.retract`, parabola R = 12 um, relaxed depth 1 um, lift speeds
0.5, 2 and 8 um/s, 40 samples each) with Gaussian noise of 1 % of each curve's force range.
Every set is fitted (`fitting.fit` with its default search, contact offset fitted: its
truth is 0) and sampled
(`fitting.sample`, `--draws` x `--chains` after `--warmup` warm-up draws). Per parameter the
table gives the fraction of curves whose 90 % credible interval (5-95 % quantiles)
contains the truth (acceptance: 80-97 %), the largest R-hat and the smallest bulk ESS over
the curves (acceptance: R-hat <= 1.01, bulk ESS >= 400), divergences, and the time per
curve of the sampler (the first curve's, compilation included, apart).

`--model history`: the full-history model (`jaxcontact.simulate` on the foundation grid)
instead, on QI-like curves without a hold: per set two approach-retract curves (approach
from 0.3 um above the surface to 1 um at the speed, retract at the same speed to 1.3 um
above the surface, past the pull-off), speeds `HISTORY_SPEEDS`, `--history-samples`
samples each (half approach, half retract), generated on the default foundation grid
(64 cells) and fitted and sampled with `--cells` cells (default 8: the forces of the
8-cell grid differ from a 512-cell grid's by at most 7e-4 of the force range on these
histories, 0.07 noise standard deviations; the check: `--check-cells`).
Records go to `--records` (default `posterior_history_records.jsonl`), the table to
`benchmarks/results/posterior_history.md`.

`--real FILE ...`: also sample the posterior of the shipped real curves (`--real-model`,
default relaxed as `jaxcontact fit`; contact point fitted, as for instrument files;
`--real-draws` per chain) and put the posterior beside the linearised errors.

    python benchmarks/bench_posterior.py [--curves 50] [--draws 1000] [--chains 4]
        [--real tests/data/...] [--out benchmarks/results/posterior.md]

The per-curve records go to `--records` (JSON lines, appended as they come, so a long run
can be followed and resumed: curves already recorded are skipped). `--max-draws N`: chains
whose diagnostics fail continue in blocks of `--draws` up to N draws each
(`fitting.sample(..., max_draws=N)`); `--only 7,18`: only these sets.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys
import time
import warnings

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent))

import fitting  # noqa: E402
import jaxcontact as jc  # noqa: E402
from benchmarks._results import machine, write_table  # noqa: E402

R = 12e-6
D0 = 1e-6
SPEEDS = (0.5e-6, 2e-6, 8e-6)
N = 40
NOISE = 0.01
NAMES = ("G0", "G1", "eta1", "work_of_adhesion", "contact_offset")
HISTORY_SPEEDS = (1e-6, 8e-6)
PRE = 0.3e-6  # the approach starts this far above the surface [m]
LIFT_PAST = 1.3e-6  # the retract ends this far above the surface [m]


def truth(rng) -> dict:
    g0 = math.exp(rng.uniform(math.log(5e3), math.log(20e3)))
    g1 = g0 * math.exp(rng.uniform(math.log(0.3), math.log(0.7)))
    tau = math.exp(rng.uniform(math.log(0.5), math.log(3.0)))
    dg = math.exp(rng.uniform(math.log(0.5e-3), math.log(2e-3)))
    return {"G0": g0, "G1": g1, "eta1": tau * g1, "work_of_adhesion": dg,
            "contact_offset": 0.0}


def curves(p: dict, rng) -> list:
    out = []
    for v in SPEEDS:
        ts = np.linspace(0.0, 3e-6 / v, N)
        sol = jc.retract(jc.StandardModel(p["G0"], p["G1"], p["eta1"]), jc.Parabola(R),
                         work_of_adhesion=p["work_of_adhesion"], depth=D0, ts=ts, velocity=v)
        f = np.asarray(sol.force)
        f = f + NOISE * np.ptp(f) * rng.standard_normal(N)
        out.append(fitting.Curve(time=ts, displacement=np.asarray(sol.displacement), force=f,
                                 segment=np.zeros(N, int), segment_names=("retract",)))
    return out


def history_curve(p: dict, v: float, n: int, rng, cells: int | None = None):
    """One approach-retract curve of the full-history model at speed `v` [m/s], `n`
    samples (half approach, half retract), 1 % noise; `cells`: the foundation grid of the
    simulation (default: the library's)."""
    na = n // 2
    ta = np.linspace(0.0, (PRE + D0) / v, na)
    tr = ta[-1] + np.linspace(0.0, (D0 + LIFT_PAST) / v, n - na + 1)[1:]
    t = np.concatenate([ta, tr])
    d = np.interp(t, [0.0, ta[-1], tr[-1]], [-PRE, D0, -LIFT_PAST])
    grid = jc.FoundationGrid() if cells is None else jc.FoundationGrid(cells=cells)
    sol = jc.simulate(jc.StandardModel(p["G0"], p["G1"], p["eta1"]), jc.Parabola(R),
                      p["work_of_adhesion"], t, d, grid=grid)
    f = np.asarray(sol.force)
    if rng is not None:
        f = f + NOISE * np.ptp(f) * rng.standard_normal(n)
    return fitting.Curve(time=t, displacement=d, force=f,
                         segment=np.repeat([0, 1], [na, n - na]),
                         segment_names=("approach", "retract"))


def make_set(i: int, args):
    """The true parameters and the curves of set `i` (seeded by `i`)."""
    rng = np.random.default_rng(1000 + i)
    p = truth(rng)
    if args.model == "history":
        return p, [history_curve(p, v, args.history_samples, rng) for v in HISTORY_SPEEDS]
    return p, curves(p, rng)


def fit_set(data, args):
    if args.model == "history":
        return fitting.fit(data, radius=R, model="history", cells=args.cells,
                           contact_point="fit", progress=False)
    return fitting.fit(data, radius=R, contact_point="fit", progress=False)


def check_cells(args) -> None:
    """`--check-cells`: the largest force difference of the history curves on
    `--cells` cells against 512 cells, relative to the force range, for the first sets."""
    for i in range(3):
        p, _ = make_set(i, args)
        for v in HISTORY_SPEEDS:
            ref = history_curve(p, v, args.history_samples, None, cells=512).force
            f = history_curve(p, v, args.history_samples, None, cells=args.cells).force
            print(f"set {i} speed {v * 1e6:g} um/s: max |F({args.cells} cells) - F(512)| / "
                  f"force range = {np.max(np.abs(f - ref)) / np.ptp(ref):.2e}", flush=True)


def run_synthetic(args) -> list[dict]:
    path = pathlib.Path(args.records)
    done = {}
    if path.exists():
        for line in path.read_text().splitlines():
            rec = json.loads(line)
            if (rec["draws"], rec["chains"], rec.get("warmup"),
                    rec.get("max_draws", rec["draws"])) == (args.draws, args.chains,
                                                            args.warmup, args.max_draws):
                done[rec["curve"]] = rec
    only = _only(args)
    for i in range(args.curves):
        if i in done or (only is not None and i not in only):
            continue
        p, data = make_set(i, args)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t0 = time.perf_counter()
            res = fit_set(data, args)
            t_fit = time.perf_counter() - t0
            t0 = time.perf_counter()
            post = fitting.sample(res, draws=args.draws, chains=args.chains, seed=i,
                                  warmup=args.warmup, predictive=False, warn=False,
                                  target_accept=args.target_accept,
                                  max_draws=args.max_draws)
        t_sample = time.perf_counter() - t0
        rec = {"curve": i, "draws": args.draws, "chains": args.chains,
               "warmup": args.warmup, "max_draws": args.max_draws,
               "draws_run": post.settings["draws_run"], "model": args.model, "truth": p,
               "settings": {k: post.settings[k] for k in ("target_accept", "max_tree_depth")},
               "max_steps_per_draw": int(post.sample_stats["n_steps"].max()),
               "mean_steps_per_draw": float(post.sample_stats["n_steps"].mean()),
               "time_fit": t_fit, "time_sample": t_sample,
               "time_mcmc": post.timings["mcmc"],
               "divergences": post.divergences, "params": {}}
        for n in NAMES:
            r = post.row(n)
            rec["params"][n] = {k: r[k] for k in ("mean", "sd", "q05", "q95", "r_hat",
                                                  "ess_bulk", "ess_tail", "fit_value",
                                                  "fit_stderr", "fit_status",
                                                  "identifiability")}
            rec["params"][n]["covered"] = bool(r["q05"] <= p[n] <= r["q95"])
        for n in post.names[len(NAMES):]:  # the noise scale of every curve
            r = post.row(n)
            rec["params"][n] = {k: r[k] for k in ("mean", "sd", "q05", "q95", "r_hat",
                                                  "ess_bulk", "ess_tail")}
        with path.open("a") as fh:
            fh.write(json.dumps(rec) + "\n")
        done[i] = rec
        cov = " ".join(f"{n}:{'y' if rec['params'][n]['covered'] else 'N'}" for n in NAMES)
        print(f"curve {i}: sample {t_sample:.1f} s (mcmc {post.timings['mcmc']:.1f} s), "
              f"fit {t_fit:.1f} s, draws {post.settings['draws_run']}, "
              f"divergences {post.divergences}, "
              f"max R-hat {max(rec['params'][n]['r_hat'] for n in rec['params']):.4f}, "
              f"min ESS {min(rec['params'][n]['ess_bulk'] for n in rec['params']):.0f}; "
              f"{cov}", flush=True)
    return [done[i] for i in range(args.curves) if i in done and (only is None or i in only)]


def _only(args) -> set[int] | None:
    """`--only`: the set indices to run (and to tabulate), or None for all."""
    return {int(x) for x in args.only.split(",")} if args.only else None


def run_timing(args) -> None:
    """`--time-only K`: fit and sample the first K sets (or `--sets`), print the device,
    the times and the sampler's diagnostics (the first call compiles); no records, no
    table (the GPU row of the table; the divergence study)."""
    import jax

    print(f"device: {jax.devices()[0].device_kind} ({jax.default_backend()}), jax "
          f"{jax.__version__}, numpyro {_numpyro()}", flush=True)
    sets = ([int(x) for x in args.sets.split(",")] if args.sets
            else list(range(args.time_only)))
    for i in sets:
        p, data = make_set(i, args)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t0 = time.perf_counter()
            res = fit_set(data, args)
            t_fit = time.perf_counter() - t0
            t0 = time.perf_counter()
            post = fitting.sample(res, draws=args.draws, chains=args.chains, seed=i,
                                  warmup=args.warmup, predictive=False, warn=False,
                                  target_accept=args.target_accept)
        print(f"set {i}: sample {time.perf_counter() - t0:.2f} s ({args.chains} chains x "
              f"{args.draws} draws + {args.warmup} warm-up), divergences {post.divergences}, "
              f"max R-hat {max(r['r_hat'] for r in post.rows):.4f}, min bulk ESS "
              f"{min(r['ess_bulk'] for r in post.rows):.0f}, leapfrog steps per draw "
              f"{post.sample_stats['n_steps'].mean():.1f} (max "
              f"{post.sample_stats['n_steps'].max()}), step sizes "
              f"{np.round(post.sample_stats['step_size'][:, -1], 3).tolist()}, divergences "
              f"per chain {post.sample_stats['diverging'].sum(axis=1).tolist()}; fit "
              f"{t_fit:.1f} s", flush=True)


def run_real(files, args) -> list[str]:
    rows = []
    for f in files:
        curve = fitting.load_curve(f)[0]  # the loaders detect the contact point
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t0 = time.perf_counter()
            res = fitting.fit(curve, radius=args.radius, model=args.real_model, progress=False)
            post = fitting.sample(res, draws=args.real_draws, chains=args.chains, seed=0,
                                  warmup=args.warmup, predictive=False, warn=False)
            dt = time.perf_counter() - t0
        name = pathlib.Path(f).name
        rows.append(f"\n**{name}** ({args.real_model} model, standard rheology, radius "
                    f"{args.radius:g} m;"
                    f" {args.chains} x {args.real_draws} draws, {post.divergences} "
                    f"divergences; fit + sampling {dt:.0f} s; "
                    f"reduced chi2 of the fit {res.reduced_chi2:.4g})\n")
        rows.append("| parameter | fit ± linearised error | fit status | posterior mean ± sd "
                    "| 5-95 % | R-hat | ESS bulk | identifiability (posterior) |")
        rows.append("|---|---|---|---|---|---|---|---|")
        for r in post.rows:
            fit_txt = (f"{r['fit_value']:.4g} ± {r['fit_stderr']:.2g}"
                       if r["fit_status"] == "ok" and math.isfinite(r["fit_stderr"])
                       else f"{r['fit_value']:.4g}")
            rows.append(f"| {r['name']} [{r['unit']}] | {fit_txt} | {r['fit_status']} | "
                        f"{r['mean']:.4g} ± {r['sd']:.2g} | {r['q05']:.4g} – {r['q95']:.4g} | "
                        f"{r['r_hat']:.3f} | {r['ess_bulk']:.0f} | {r['identifiability']} |")
        for w in post.warnings:
            rows.append(f"\nwarning: {w}")
    return rows


def _sets_text(args) -> str:
    if args.model == "history":
        return (f"full-history model on {args.cells} foundation cells, standard rheology, "
                f"contact offset fitted; {len(HISTORY_SPEEDS)} approach-retract curves "
                f"(speeds {', '.join(f'{v * 1e6:g}' for v in HISTORY_SPEEDS)} um/s) x "
                f"{args.history_samples} samples without a hold, noise {NOISE:.0%} of the "
                "force range")
    return (f"relaxed model, standard rheology, contact offset fitted; 3 retract curves x {N} "
            f"samples, noise {NOISE:.0%} of the force range")


def _extension_text(recs, args) -> str:
    if args.max_draws == args.draws:
        return ""
    ext = {r["curve"]: r["draws_run"] for r in recs if r.get("draws_run", args.draws) > args.draws}
    listed = ", ".join(f"set {i}: {d}" for i, d in sorted(ext.items())) or "none"
    return (f", continued in blocks of {args.draws} draws up to {args.max_draws} per chain "
            f"while some parameter had R-hat > 1.01 or bulk ESS < 400 (`fitting.sample(..., "
            f"max_draws=)`; draws per chain of the sets continued: {listed})")


def table(recs, args, real_rows, command) -> list[str]:
    title = ("# Posterior calibration (`fitting.sample`, NUTS)" if args.model == "relaxed"
             else "# Posterior calibration, full-history model (`fitting.sample`, NUTS)")
    lines = [title, "",
             f"Measured {machine()}; numpyro {_numpyro()}. Command:", "",
             f"    {command}", "",
             f"{len(recs)} synthetic parameter sets ({_sets_text(args)}; see the script's "
             f"docstring), {args.chains} chains x {args.draws} draws "
             f"after {args.warmup} warm-up each{_extension_text(recs, args)}. Coverage: the "
             "fraction of sets whose 90 % credible interval (5-95 %) contains the truth "
             "(acceptance 80-97 %; with "
             f"{len(recs)} sets its binomial standard error at 90 % is "
             f"{100 * math.sqrt(0.09 / max(len(recs), 1)):.1f} points).", "",
             "| parameter | coverage of the 90 % interval | max R-hat | min bulk ESS | "
             "min tail ESS | median posterior sd / linearised error |",
             "|---|---|---|---|---|---|"]
    noise = [n for n in recs[0]["params"] if n not in NAMES]
    for n in NAMES + tuple(noise):
        ps = [r["params"][n] for r in recs]
        cov = (f"{sum(p['covered'] for p in ps)}/{len(ps)} = "
               f"{100 * np.mean([p['covered'] for p in ps]):.0f} %" if n in NAMES
               else "(sampled; no single truth: the fit's noise estimate times it)")
        ratio = [p["sd"] / p["fit_stderr"] for p in ps
                 if "fit_stderr" in p and p["fit_stderr"] and math.isfinite(p["fit_stderr"])]
        lines.append(f"| {n} | {cov} | {max(p['r_hat'] for p in ps):.4f} | "
                     f"{min(p['ess_bulk'] for p in ps):.0f} | "
                     f"{min(p['ess_tail'] for p in ps):.0f} | "
                     f"{np.median(ratio):.2f} |" if ratio else
                     f"| {n} | {cov} | {max(p['r_hat'] for p in ps):.4f} | "
                     f"{min(p['ess_bulk'] for p in ps):.0f} | "
                     f"{min(p['ess_tail'] for p in ps):.0f} | |")
    if args.model == "relaxed":
        lines += ["", "The noise scale is sampled per curve (`noise_scale_1..3`). An earlier "
                  "run of this benchmark with one noise scale for all curves of a set "
                  "(commit 5fc3f20, first 25 sets, the same settings) covered the truth in "
                  "20, 23, 17, 23 and 20 of 25 sets (G0, G1, eta1, work_of_adhesion, "
                  "contact_offset): eta1 at 68 %. The fit's noise estimate of a curve of 40 "
                  "samples is off by tens of per cent, differently for each curve; one common "
                  "scale cannot correct the weights between the curves."]
    good = [r for r in recs if all(p["r_hat"] <= 1.01 and p["ess_bulk"] >= 400
                                   for p in r["params"].values())]
    others = ", ".join(str(r["curve"]) for r in recs if r not in good) or "none"
    lines += ["", f"Sets whose every parameter has R-hat <= 1.01 and bulk ESS >= 400: "
              f"{len(good)}/{len(recs)} (the others: sets {others}; "
              "the sampler warns about them). Coverage over those sets alone: "
              + ", ".join(f"{n} {100 * np.mean([r['params'][n]['covered'] for r in good]):.0f} %"
                          for n in NAMES) + "." if good else ""]
    ts = np.array([r["time_sample"] for r in recs])
    div = sum(r["divergences"] for r in recs)
    lines += ["", f"Divergent transitions: {div} in {len(recs)} x {args.chains} x {args.draws} "
              "draws.", "",
              f"Time per curve, `fitting.sample` ({args.chains} chains x {args.draws} draws + "
              f"{args.warmup} warm-up, vectorised over the chains, wall clock on this shared "
              f"CPU): median {np.median(ts[1:] if len(ts) > 1 else ts):.1f} s "
              f"(range {np.min(ts[1:] if len(ts) > 1 else ts):.1f}-"
              f"{np.max(ts[1:] if len(ts) > 1 else ts):.1f} s) after the first curve, "
              f"whose {ts[0]:.1f} s include the compilation (one compilation serves every "
              "curve of the same shape). The fit before it: median "
              f"{np.median([r['time_fit'] for r in recs]):.1f} s."]
    if real_rows:
        lines += ["", "## Shipped real curves: posterior against the linearised errors"]
        lines += real_rows
    return lines


def _numpyro() -> str:
    import numpyro

    return numpyro.__version__


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--curves", type=int, default=50)
    ap.add_argument("--draws", type=int, default=1000)
    ap.add_argument("--chains", type=int, default=4)
    ap.add_argument("--warmup", type=int, default=500)
    ap.add_argument("--real", nargs="*", default=[])
    ap.add_argument("--real-draws", type=int, default=500)
    ap.add_argument("--radius", type=float, default=10e-6)
    ap.add_argument("--real-model", choices=("relaxed", "history"), default="relaxed")
    ap.add_argument("--model", choices=("relaxed", "history"), default="relaxed",
                    help="the model of the synthetic sets")
    ap.add_argument("--cells", type=int, default=8, help="foundation cells (history)")
    ap.add_argument("--history-samples", type=int, default=80)
    ap.add_argument("--check-cells", action="store_true")
    ap.add_argument("--records", default=None)
    ap.add_argument("--out", default=None)
    ap.add_argument("--no-table", action="store_true")
    ap.add_argument("--time-only", type=int, default=0, metavar="K")
    ap.add_argument("--sets", default="", help="as --time-only, these sets (e.g. 17,33,48)")
    ap.add_argument("--target-accept", type=float,
                    default=fitting._posterior.DEFAULT_TARGET_ACCEPT)
    ap.add_argument("--max-draws", type=int, default=None,
                    help="fitting.sample's max_draws (default: --draws, no extension)")
    ap.add_argument("--only", default="", help="run and tabulate only these sets (e.g. 7,18)")
    args = ap.parse_args(argv)
    args.max_draws = args.draws if args.max_draws is None else args.max_draws
    stem = "posterior" if args.model == "relaxed" else "posterior_history"
    args.records = args.records or f"benchmarks/results/{stem}_records.jsonl"
    args.out = args.out or f"benchmarks/results/{stem}.md"
    if args.check_cells:
        check_cells(args)
        return 0
    if args.time_only or args.sets:
        run_timing(args)
        return 0
    command = "python benchmarks/bench_posterior.py " + " ".join(sys.argv[1:] if argv is None
                                                                  else argv)
    recs = run_synthetic(args)
    real_rows = run_real(args.real, args) if args.real else []
    if not args.no_table and recs:
        write_table(args.out, table(recs, args, real_rows, command))
    elif real_rows:  # no synthetic sets (--curves 0): the real curves' rows to stdout
        print(f"Measured {machine()}; numpyro {_numpyro()}. Command:\n\n    {command}")
        print("\n".join(real_rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
