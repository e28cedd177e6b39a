"""Throughput, memory and float32 accuracy of `jaxcontact.sweep` (issue 13).

1. `jc.sweep` (relaxed start, the CPU default float64) against the batch size, from 1 to
   10^6 curves, twice: the default (the summaries, computed exactly without sampling the
   curve: curves/s) and `curves=True` (the summaries and the sampled curves: samples/s, up
   to 10^5 curves: 10^6 would hold 16 GB of curves); against the vectorised-numpy
   implementation of the same closed form on the same number of samples per curve
   (`bench_retract.numpy_model`, which computes the forces only: no events, no separation
   work, no per-curve duration; a numpy user needs these samples to get the summaries), run
   in chunks of 8,192 curves, measured in the same run (interleaved medians). The sweep's
   time is the whole call: scaling, chunks, device transfers and the labelled dataset.
2. Memory per curve: XLA's compiled memory (arguments + outputs + temporaries of one chunk)
   and the growth of the peak resident memory of the process over the largest batch.
3. One, two and four virtual CPU devices (`--xla_force_host_platform_device_count`): the
   overhead of sharding on one machine (this CPU has 2 cores).
4. float32 against float64 over a sweep of random parameter sets (relaxed start and the full
   history), and the speed of float32 on the CPU; full-history curves per second.

    nice -n 10 python benchmarks/bench_sweep.py [--samples 256] [--max-batch 1000000]

Prints markdown rows for `benchmarks/results/sweep.md`.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time

import numpy as np
from bench_retract import D0, R, numpy_model, params  # the baseline, reused

import jaxcontact as jc

HERE = os.path.dirname(os.path.abspath(__file__))


def points(n, seed=0):
    G0, G1, eta1, dg, v = params(n, seed)
    return dict(G0=G0, G1=G1, eta1=eta1, work_of_adhesion=dg, velocity=v, R=R, depth=D0)


def run_sweep(pts, model, **kw):
    return jc.sweep(points=pts, model=model, progress=False, **kw)


def numpy_chunked(pts, samples, chunk=8192):
    ts = np.linspace(0.0, 0.2, samples)
    n = pts["G0"].shape[0]
    total = 0.0
    for lo in range(0, n, chunk):
        sl = slice(lo, lo + chunk)
        F = numpy_model(pts["G0"][sl], pts["G1"][sl], pts["eta1"][sl],
                        pts["work_of_adhesion"][sl], pts["velocity"][sl], ts)
        total += float(F[:, -1].sum())
    return total


def timed(fn):
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def batch_table(samples, max_batch, max_curves_batch=100_000):
    model = jc.RelaxedStart(samples=samples)
    rows = []
    batches = [b for b in (1, 10, 100, 1_000, 10_000, 100_000, 1_000_000) if b <= max_batch]
    for b in batches:
        pts = points(b)
        with_curves = b <= max_curves_batch
        first = timed(lambda p=pts: run_sweep(p, model))  # compile (one per chunk size)
        if with_curves:
            run_sweep(pts, model, curves=True)
        repeats = 5 if b <= 10_000 else (3 if b <= 100_000 else 1)
        tj, tc, tn = [], [], []
        rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        for _ in range(repeats):
            tj.append(timed(lambda p=pts: run_sweep(p, model)))
            if with_curves:
                tc.append(timed(lambda p=pts: run_sweep(p, model, curves=True)))
            tn.append(timed(lambda p=pts: numpy_chunked(p, samples)))
        rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        mj, mn = statistics.median(tj), statistics.median(tn)
        ratio = statistics.median([n / j for j, n in zip(tj, tn, strict=True)])
        mc = statistics.median(tc) if tc else float("nan")
        ratio_c = (statistics.median([n / c for c, n in zip(tc, tn, strict=True)])
                   if tc else float("nan"))
        row = dict(batch=b, first_s=first, sweep_s=mj, curves_s=mc, numpy_s=mn,
                   sweep_cps=b / mj, curves_sps=b * samples / mc, numpy_sps=b * samples / mn,
                   ratio=ratio, ratio_curves=ratio_c, rss_growth_MiB=(rss1 - rss0) / 1024)
        rows.append(row)
        curves = (f"{mc:.4g} | {b * samples / mc:.3g} | {ratio_c:.1f}x" if tc else "- | - | -")
        print(f"| {b:,} | {mj:.4g} | {b / mj:.3g} | {ratio:.1f}x | {curves} | {mn:.4g} | "
              f"{b * samples / mn:.3g} | {first:.2f} |", flush=True)
    return rows


def back_to_back(samples, n=1_000, repeats=10):
    """A 10^3-curve sweep back to back against right after a numpy run of the same curves
    (cold caches and worker threads): medians."""
    model = jc.RelaxedStart(samples=samples)
    pts = points(n)
    run_sweep(pts, model)
    hot = [timed(lambda: run_sweep(pts, model)) for _ in range(repeats)]
    cold = []
    for _ in range(repeats):
        numpy_chunked(pts, samples)
        cold.append(timed(lambda: run_sweep(pts, model)))
    h, c = statistics.median(hot), statistics.median(cold)
    print(f"{n:,} curves: back to back {1e3 * h:.2f} ms, after a numpy run {1e3 * c:.2f} ms",
          flush=True)
    return h, c


def memory_per_curve(samples, chunks=(256, 4096), curves=False):
    """XLA's compiled memory of one chunk, per curve."""
    import jax

    from jaxcontact._sweep._parameters import _ProfileFamily, _StandardFamily
    from jaxcontact._sweep._run import _compiled

    model = jc.RelaxedStart(samples=samples)
    out = {}
    names = tuple(sorted(["G0", "G1", "eta1", "work_of_adhesion", "velocity", "R", "depth"]))
    for c in chunks:
        with jax.enable_x64(True):
            fn, sharding = _compiled(model, _StandardFamily(), _ProfileFamily("R"), names,
                                     curves, tuple(jax.devices()), "float64")
            cols = jax.ShapeDtypeStruct((c, len(names)), np.float64, sharding=sharding)
            mem = fn.lower(cols).compile().memory_analysis()
        total = (mem.argument_size_in_bytes + mem.output_size_in_bytes
                 + mem.temp_size_in_bytes)
        out[c] = total / c
        print(f"compiled memory (curves={curves}), chunk {c}: {total / 2**20:.1f} MiB = "
              f"{total / c / 1024:.2f} KiB per curve ({samples} samples: "
              f"{total / c / samples:.1f} B per sample)", flush=True)
    return out


DEVICES_CHILD = """
import json, statistics, time, sys
sys.path.insert(0, {here!r})
import jax, jaxcontact as jc
from bench_sweep import points, run_sweep
pts = points({n})
m = jc.RelaxedStart(samples={samples})
run_sweep(pts, m)
t = []
for _ in range(5):
    t0 = time.perf_counter(); run_sweep(pts, m); t.append(time.perf_counter() - t0)
print(json.dumps(dict(devices=len(jax.devices()), t=statistics.median(t))))
"""


def devices_overhead(samples, n=10_000):
    res = {}
    for count in (1, 2, 4):
        env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={count}")
        code = DEVICES_CHILD.format(here=HERE, n=n, samples=samples)
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                             text=True, check=True)
        res[count] = json.loads(out.stdout.strip().splitlines()[-1])
    print(f"| {n:,} curves x {samples} samples | {res[1]['t']:.3f} s | {res[2]['t']:.3f} s "
          f"({res[2]['t'] / res[1]['t']:.2f}) | {res[4]['t']:.3f} s "
          f"({res[4]['t'] / res[1]['t']:.2f}) |", flush=True)
    return res


COMPARE_CHILD = """
import json, statistics, sys, time
sys.path.insert(0, {here!r})
import jaxcontact as jc
from bench_sweep import points
m = jc.RelaxedStart(samples={samples})
out = {{}}
for b in {batches!r}:
    pts = points(b)
    jc.sweep(points=pts, model=m, progress=False)
    t = []
    for _ in range(max(1, {repeats} if b <= 10_000 else 3 if b <= 100_000 else 1)):
        t0 = time.perf_counter(); jc.sweep(points=pts, model=m, progress=False)
        t.append(time.perf_counter() - t0)
    out[b] = statistics.median(t)
print(json.dumps(out))
"""


def compare(old_root, samples, batches, rounds=2, repeats=5):
    """Relaxed summaries of this checkout against another (`old_root`, e.g. `git archive` of
    the commit before) in child processes, alternating (old, new) `rounds` times; the numpy
    baseline in this process in between. Medians."""
    new_root = os.path.dirname(HERE)
    times = {"old": {b: [] for b in batches}, "new": {b: [] for b in batches}}
    tn = {b: [] for b in batches}
    for _ in range(rounds):
        for label, root in (("old", old_root), ("new", new_root)):
            env = dict(os.environ, PYTHONPATH=root)
            code = COMPARE_CHILD.format(here=os.path.join(root, "benchmarks"), samples=samples,
                                        batches=list(batches), repeats=repeats)
            out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                                 text=True, check=True, cwd=root)
            for b, t in json.loads(out.stdout.strip().splitlines()[-1]).items():
                times[label][int(b)].append(t)
        for b in batches:
            if b <= 100_000:
                pts = points(b)
                tn[b].append(timed(lambda p=pts: numpy_chunked(p, samples)))
    print("\n| curves | before [s] | before curves/s | after [s] | after curves/s | after/before "
          "speed | numpy [s] | after / numpy |\n| --- | --- | --- | --- | --- | --- | --- | --- |")
    for b in batches:
        to, tw = statistics.median(times["old"][b]), statistics.median(times["new"][b])
        n = statistics.median(tn[b]) if tn[b] else float("nan")
        print(f"| {b:,} | {to:.4g} | {b / to:.3g} | {tw:.4g} | {b / tw:.3g} | {to / tw:.2f} | "
              f"{n:.4g} | {n / tw:.1f}x |", flush=True)
    return times, tn


PAIRED_CHILD = """
import json, os, statistics, sys, time, resource
sys.path.insert(0, os.path.join(os.getcwd(), "benchmarks"))
import jax
import jaxcontact as jc
from bench_sweep import points, numpy_chunked
m = jc.RelaxedStart(samples={samples})
def cpu():
    r = resource.getrusage(resource.RUSAGE_SELF); return r.ru_utime + r.ru_stime
out = {{"devices": len(jax.devices())}}
for b, pairs, b2b in ((1000, 20, 30), (10000, 6, 10), (100000, 2, 3)):
    if b > {max_batch}:
        continue
    pts = points(b)
    jc.sweep(points=pts, model=m, progress=False); jc.sweep(points=pts, model=m, progress=False)
    d = dict(sweep=[], cpu=[], numpy=[], ratio=[], b2b=[])
    for _ in range(pairs):
        t0 = time.perf_counter(); numpy_chunked(pts, {samples}); tn = time.perf_counter() - t0
        c0 = cpu(); t0 = time.perf_counter(); jc.sweep(points=pts, model=m, progress=False)
        ts = time.perf_counter() - t0
        d["cpu"].append(cpu() - c0); d["sweep"].append(ts); d["numpy"].append(tn)
        d["ratio"].append(tn / ts)
    for _ in range(b2b):
        t0 = time.perf_counter(); jc.sweep(points=pts, model=m, progress=False)
        d["b2b"].append(time.perf_counter() - t0)
    out[b] = d
print(json.dumps(out))
"""


def paired(old_root, samples, max_batch, rounds=3, devices2=False):
    """Relaxed summaries of another checkout (`old_root`) and this one, each in child
    processes run with that checkout as working directory and PYTHONPATH, alternated over
    `rounds`; inside each child, per batch, the numpy baseline and the sweep alternate (the
    order of `batch_table`: a sweep right after a numpy run), the ratio taken per pair, then
    back-to-back sweeps. With `devices2` also this checkout on 2 virtual CPU devices. Medians;
    the sweep's process CPU time too (less sensitive to other jobs on the machine)."""
    new_root = os.path.dirname(HERE)
    variants = [("before", old_root, {}), ("after", new_root, {})]
    if devices2:
        variants.append(("after, 2 CPU devices", new_root,
                         {"XLA_FLAGS": "--xla_force_host_platform_device_count=2"}))
    res = {label: {} for label, _, _ in variants}
    for r in range(rounds):
        for label, root, extra in (variants if r % 2 == 0 else variants[::-1]):
            env = dict(os.environ, PYTHONPATH=root, **extra)
            code = PAIRED_CHILD.format(samples=samples, max_batch=max_batch)
            out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                                 text=True, check=True, cwd=root)
            got = json.loads(out.stdout.strip().splitlines()[-1])
            for b, d in got.items():
                if b != "devices":
                    for k, vals in d.items():
                        res[label].setdefault(int(b), {}).setdefault(k, []).extend(vals)
    med = statistics.median
    print("\n| version | curves | sweep after numpy [ms] | its CPU time [ms] | back to back [ms] "
          "| curves/s | numpy [ms] | numpy / sweep (median of pairs) | numpy / back to back |"
          "\n| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for label, rows in res.items():
        for b, d in sorted(rows.items()):
            t, c, bb, n = med(d["sweep"]), med(d["cpu"]), med(d["b2b"]), med(d["numpy"])
            print(f"| {label} | {b:,} | {1e3 * t:.2f} | {1e3 * c:.2f} | {1e3 * bb:.2f} | "
                  f"{b / t:.3g} | {1e3 * n:.1f} | {med(d['ratio']):.1f}x | {n / bb:.1f}x |",
                  flush=True)
    return res


def floor(samples, n=1_000, triples=25):
    """The computation's floor at `n` points: the numpy baseline, the compiled chunk call
    alone (the sweep's own program and padded chunk, its input already in host memory), and
    the whole `jc.sweep` call, interleaved in triples; medians of wall and process CPU time,
    and of the per-triple ratios."""
    import jax

    from jaxcontact._sweep import _run
    from jaxcontact._sweep import _sweep as sweep_module

    model = jc.RelaxedStart(samples=samples)
    pts = points(n)
    seen = {}
    real = sweep_module.run_points

    def spy(*args, **kw):
        seen["args"] = args
        return real(*args, **kw)

    sweep_module.run_points = spy
    try:
        run_sweep(pts, model)
    finally:
        sweep_module.run_points = real
    m, material, profile, names, n_points, columns = seen["args"]
    chunk = _run.chunk_size_for(m, getattr(material, "arms", 1), 8, False, n_points, 1, None,
                                jax.local_devices())
    fn, _ = _run._compiled(m, material, profile, names, False, tuple(jax.devices()), "float64")
    host = np.empty((chunk, len(names)))
    host[:n] = columns(0, n)
    host[n:] = host[0]

    def compiled():
        with jax.enable_x64(True):
            np.asarray(fn(host)[0])

    def cpu():
        r = resource.getrusage(resource.RUSAGE_SELF)
        return r.ru_utime + r.ru_stime

    compiled()
    calls = (("numpy", lambda: numpy_chunked(pts, samples)), ("compiled", compiled),
             ("sweep", lambda: run_sweep(pts, model)))
    wall, proc = {k: [] for k, _ in calls}, {k: [] for k, _ in calls}
    for _ in range(triples):
        for k, f in calls:
            c0, t0 = cpu(), time.perf_counter()
            f()
            wall[k].append(time.perf_counter() - t0)
            proc[k].append(cpu() - c0)
    med = statistics.median
    ratio_c = med([a / b for a, b in zip(wall["numpy"], wall["compiled"], strict=True)])
    ratio_s = med([a / b for a, b in zip(wall["numpy"], wall["sweep"], strict=True)])
    host_ms = 1e3 * med([a - b for a, b in zip(wall["sweep"], wall["compiled"], strict=True)])
    print(f"\n{n:,} points (chunk {chunk}): numpy {1e3 * med(wall['numpy']):.1f} ms (CPU "
          f"{1e3 * med(proc['numpy']):.1f}), compiled call {1e3 * med(wall['compiled']):.2f} ms "
          f"(CPU {1e3 * med(proc['compiled']):.2f}), sweep {1e3 * med(wall['sweep']):.2f} ms "
          f"(CPU {1e3 * med(proc['sweep']):.2f}); numpy / compiled call {ratio_c:.1f}x, "
          f"numpy / sweep {ratio_s:.1f}x, sweep - compiled call {host_ms:.2f} ms", flush=True)
    return wall, proc


def relative(a, b):
    ok = np.isfinite(a) & np.isfinite(b) & (b != 0)
    return np.abs(a[ok] / b[ok] - 1)


def float32_table(n_relaxed=10_000, n_history=256, samples=2000):
    rows = []
    cases = [("relaxed", jc.RelaxedStart(samples=samples), points(n_relaxed, seed=1))]
    rng = np.random.default_rng(2)
    hist = points(n_history, seed=3)
    hist["hold"] = 10 ** rng.uniform(-3, 0, n_history)
    cases.append(("history", jc.ApproachHoldLift(samples=samples), hist))
    for label, model, pts in cases:
        d64 = run_sweep(pts, model, precision="float64")
        t64 = timed(lambda p=pts, m=model: run_sweep(p, m, precision="float64"))
        d32 = run_sweep(pts, model, precision="float32")
        t32 = timed(lambda p=pts, m=model: run_sweep(p, m, precision="float32"))
        n = pts["G0"].shape[0]
        same = float(np.mean(d32.status.values == d64.status.values))
        print(f"{label}: {n} curves ({samples} samples for the history): float64 {t64:.2f} s "
              f"({n / t64:.3g} curves/s, {n * samples / t64:.3g} samples/s), float32 {t32:.2f} s "
              f"({n * samples / t32:.3g} samples/s); same status {100 * same:.2f} %", flush=True)
        for name in ("max_tensile_force_N", "jumpoff_force_N", "jumpoff_time_s",
                     "separation_work_J"):
            r = relative(d32[name].values, d64[name].values)
            rows.append((label, name, np.median(r), np.percentile(r, 99), r.max()))
        dd = np.abs(d32.jumpoff_displacement_m.values - d64.jumpoff_displacement_m.values) / D0
        dd = dd[np.isfinite(dd)]
        rows.append((label, "jumpoff_displacement_m (/ depth)", np.median(dd),
                     np.percentile(dd, 99), dd.max()))
        rows.append((label, "speed", n * samples / t64, n * samples / t32, n / t64))
    for label, name, a, b, c in rows:
        if name == "speed" and label == "relaxed":  # the summaries do not sample the curve
            print(f"| {label} | curves/s float64 {c:.3g}, float32 {c * b / a:.3g} |", flush=True)
        elif name == "speed":
            print(f"| {label} | samples/s float64 {a:.3g}, float32 {b:.3g}; curves/s float64 "
                  f"{c:.3g} |", flush=True)
        else:
            print(f"| {label} | {name} | {a:.1e} | {b:.1e} | {c:.1e} |", flush=True)
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--samples", type=int, default=256)
    ap.add_argument("--max-batch", type=int, default=1_000_000)
    ap.add_argument("--skip", default="", help="comma list of: batch,memory,devices,float32")
    ap.add_argument("--quick", action="store_true",
                    help="batches up to 10^5, no memory or devices sections, a small float32 "
                         "table")
    ap.add_argument("--compare", metavar="DIR", default=None,
                    help="also time the relaxed summaries of another checkout (e.g. `git "
                         "archive` of the previous commit unpacked in DIR) against this one")
    ap.add_argument("--paired", metavar="DIR", default=None,
                    help="relaxed summaries of another checkout (DIR) and this one at 10^3-10^5 "
                         "points, each sweep paired with a numpy run (child processes "
                         "alternated; see `paired`); skips the other sections")
    ap.add_argument("--rounds", type=int, default=3, help="rounds of --paired")
    ap.add_argument("--devices2", action="store_true",
                    help="--paired also runs this checkout on 2 virtual CPU devices")
    ap.add_argument("--floor", action="store_true",
                    help="only the computation's floor at 10^3 points (see `floor`)")
    args = ap.parse_args()
    if args.floor:
        floor(args.samples)
        return
    if args.paired:
        paired(os.path.abspath(args.paired), args.samples, min(args.max_batch, 100_000),
               args.rounds, args.devices2)
        return
    skip = set(args.skip.split(","))
    if args.quick:
        args.max_batch = min(args.max_batch, 100_000)
        skip |= {"memory", "devices"}
    import jax

    print(f"devices: {jax.devices()}; jaxcontact {jc.__version__}; jax {jax.__version__}")
    if "batch" not in skip:
        print("\n| curves | summaries [s] | curves/s | ratio to numpy | with curves [s] | "
              "samples/s | ratio to numpy | numpy [s] | numpy samples/s | first call [s] |\n"
              "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
        rows = batch_table(args.samples, args.max_batch)
        big = rows[-1]
        print(f"peak resident memory growth over the {big['batch']:,}-curve runs: "
              f"{big['rss_growth_MiB']:.0f} MiB")
        back_to_back(args.samples)
    if "memory" not in skip:
        memory_per_curve(args.samples)
        memory_per_curve(args.samples, curves=True)
        memory_per_curve(2000, chunks=(4096,), curves=True)
    if "devices" not in skip:
        print("\n| batch | 1 device | 2 devices (ratio) | 4 devices (ratio) |\n"
              "| --- | --- | --- | --- |")
        devices_overhead(args.samples)
    if args.compare:
        batches = [b for b in (1_000, 10_000, 100_000, 1_000_000) if b <= args.max_batch]
        compare(os.path.abspath(args.compare), args.samples, batches)
    if "float32" not in skip:
        print("\n| model | summary | median | 99th pct | max |\n| --- | --- | --- | --- | --- |")
        if args.quick:
            float32_table(n_relaxed=1_000, n_history=64, samples=500)
        else:
            float32_table()


if __name__ == "__main__":
    main()
