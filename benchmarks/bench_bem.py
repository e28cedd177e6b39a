"""Benchmark of the boundary element method (`jc.bem_simulate`, `jc.bem_contact`).

Prints markdown (the committed tables are in `benchmarks/results/bem.md`). Sections:

- `--timing`: a complete adhesive pull-off of an elastic sphere (paraboloid) in
  displacement control, 20 approach steps to 1.5x the JKR pull-off radius and 80 lift
  steps past the jump-off (100 steps), at n x n cells for each n in `--cells`: the first
  call (compilation included), the median of `--repeats` further calls (wall and CPU
  time; above 128 cells the first call alone, "–" in the median column), the CG
  iterations and cell-rule rounds, and the pull-off errors against JKR.
- `--solve`: one non-adhesive elastic (Hertz) solve in force control at each n in
  `--solve-cells`, `jc.bem_contact` (non-periodic: zero padding to (2n)^2) against tamaas'
  Polonsky-Keer-Rey solver (periodic) on the same height map, on n x n (the same cells,
  periodic images one side away) and on the 2n x 2n zero-padded map (the same FFT size
  as jaxcontact, images two sides away), timed in the same run.
- `--convergence`: the pull-off of the adhesive sphere against JKR at each n in
  `--conv-cells`: displacement control (largest tensile force vs -3/2 pi dgamma R,
  jump-off force vs -5/6 pi dgamma R) and force control (jump-off vs -3/2 pi dgamma R),
  with the observed order log2(e_n / e_2n).
- `--ellipse`: an ellipsoid with R_x = k R_y (k in `--ratios`), pull-off over
  3/2 pi dgamma sqrt(R_x R_y) at each n in `--ellipse-cells`, the Richardson extrapolation
  of the last two grids (first order), and the two approximate elliptical JKR theories of
  `benchmarks/elliptic_jkr.py` (Johnson-Greenwood: Griffith at the axis ends; energy:
  the approach of Giudici-Vella-Griffiths), computed there from their formulas.
- `--viscoelastic`: a standard-model half-space, relaxed start and constant-speed lift
  against `jc.retract`, approach-hold-lift against `jc.simulate` (MDR), at each n in
  `--visco-cells`: the largest force error before the jump-off over the peak force, the
  largest tensile force and the jump-off time.

Wall times on a shared machine vary with its load: the load average and the CPU time of
the timed calls are printed. Run with `nice`:

    nice -n 10 env PYTHONPATH=$PWD python benchmarks/bench_bem.py --all > out.md
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import statistics
import subprocess
import sys
import time

import jax
import numpy as np

import jaxcontact as jc

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import elliptic_jkr  # noqa: E402

E_STAR, R, DGAMMA = 1e6, 1e-3, 0.05
F_FC, F_DC = -1.5 * np.pi * DGAMMA * R, -5 / 6 * np.pi * DGAMMA * R
A_FC = (9 * np.pi * DGAMMA * R**2 / (8 * E_STAR)) ** (1 / 3)
A_DC = (np.pi * DGAMMA * R**2 / (8 * E_STAR)) ** (1 / 3)
D_DC = A_DC**2 / R - np.sqrt(2 * np.pi * A_DC * DGAMMA / E_STAR)


def _timed(fn, repeats):
    """(output, first-call wall time, median wall time, median CPU time)."""
    t0, c0 = time.perf_counter(), time.process_time()
    out = jax.block_until_ready(fn())
    first, cpu_first = time.perf_counter() - t0, time.process_time() - c0
    times, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        out = jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    if not times:
        return out, first, float("nan"), cpu_first
    return out, first, statistics.median(times), statistics.median(cpu)


def _machine() -> str:
    try:
        lscpu = subprocess.run(["lscpu"], capture_output=True, text=True).stdout
        model = next((ln.split(":", 1)[1].strip() for ln in lscpu.splitlines()
                      if ln.startswith("Model name")), platform.processor())
    except OSError:
        model = platform.processor()
    return (f"{model}, {os.cpu_count()} cores (`nproc`), jax {jax.__version__}, devices "
            f"{jax.devices()}, {datetime.datetime.now().strftime('%Y-%m-%d %H:%M')}, load "
            f"average {tuple(round(x, 1) for x in os.getloadavg())}")


def _sphere_history(approach, lift, a0_factor=1.5):
    a0 = a0_factor * A_FC
    d0 = a0**2 / R
    disp = np.concatenate([np.linspace(0, d0, approach), np.linspace(d0, 1.3 * D_DC, lift)])
    return np.arange(disp.size, dtype=float), disp, a0


def timing(cells, repeats):
    ts, disp, a0 = _sphere_history(20, 80)
    print("\n## Complete adhesive pull-off, elastic sphere, 100 steps\n")
    print(f"E* = {E_STAR:g} Pa, R = {R:g} m, dgamma = {DGAMMA:g} J/m², square of side "
          "2.4 a0 (a0 = 1.5 a_JKR), displacement control, 20 approach + 80 lift steps. "
          "Errors: largest tensile force / (-3/2 pi dgamma R) - 1, jump-off force / "
          "(-5/6 pi dgamma R) - 1.\n")
    print("| cells | R/Δ | first call [s] | median [s] | CPU [s] | CG iterations | rounds "
          "| max tensile err | jump-off err |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for n in cells:
        grid = jc.BEMGrid(n, 2.4 * a0)

        def run(grid=grid):
            return jc.bem_simulate(jc.Elastic(E_STAR / 4), jc.Parabola(R), DGAMMA, ts, disp,
                                   grid=grid)

        # above 128 cells the run is minutes long and compilation a small part of it: the
        # first call alone is timed (its CPU time in the CPU column)
        s, first, med, cpu = _timed(run, repeats if n <= 128 else 0)
        med = "–" if np.isnan(med) else f"{med:.1f}"
        print(f"| {n}² | {R / float(grid.cell_size):.0f} | {first:.1f} | {med} | {cpu:.1f} "
              f"| {int(s.details.cg_iterations.sum())} | {int(s.details.rounds.sum())} "
              f"| {float(s.max_tensile_force) / F_FC - 1:+.4f} "
              f"| {float(s.jumpoff_force) / F_DC - 1:+.4f} |", flush=True)


def elastic_solve(cells, repeats):
    try:
        import tamaas as tm

        tm.set_log_level(tm.LogLevel.error)
        version = tm.__version__
    except ImportError as err:  # pragma: no cover - reported in the table
        tm, version = None, f"not importable ({err})"
    d = 1e-5
    a = np.sqrt(R * d)
    force = 4 / 3 * E_STAR * np.sqrt(R) * d**1.5
    print("\n## One non-adhesive elastic solve (Hertz, force control) against tamaas\n")
    print(f"tamaas {version}, `PolonskyKeerRey` (pressure constraint, tolerance 1e-10); "
          "jaxcontact `bem_contact(force=...)` (tolerance 1e-10). Sphere R = 1 mm, "
          f"F = {force:.4g} N, square of side 4a (a the Hertz radius). Medians of "
          f"{repeats} solves after a first (compiling) call. tamaas n²: periodic on the same "
          "cells; tamaas (2n)²: the height map padded with far-away heights to the FFT size "
          "of jaxcontact. Wall time, CPU time (all threads) in parentheses. Differences of the "
          "contact area (cells) and of the peak pressure are between jaxcontact and tamaas "
          "(2n)².\n")
    print("| cells | jaxcontact [s] | tamaas n² [s] | tamaas (2n)² [s] | jc / tamaas n² "
          "| jc / tamaas (2n)² | area jc/tm - 1 | p_max jc/tm - 1 | depth jc/Hertz - 1 |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for n in cells:
        grid = jc.BEMGrid(n, 4 * a)
        h = np.asarray(jc.bem_heights(jc.Parabola(R), grid))

        def run_jc(grid=grid, h=h):
            return jc.bem_contact(h, grid=grid, effective_modulus=E_STAR, force=force)

        (_, d_jc, p_jc), _, t_jc, c_jc = _timed(run_jc, repeats)
        p_jc = np.asarray(p_jc)
        res = {}
        if tm is not None:
            L = float(grid.extent)
            far = h.max() * 10 + 1e-3
            padded = np.full((2 * n, 2 * n), far)
            padded[:n, :n] = h
            for key, surf, size in (("n", h, L), ("2n", padded, 2 * L)):
                m = surf.shape[0]
                times, cpus = [], []
                for _ in range(repeats + 1):
                    model = tm.ModelFactory.createModel(tm.model_type.basic_2d, [size, size],
                                                        [m, m])
                    model.E, model.nu = E_STAR, 0.0
                    solver = tm.PolonskyKeerRey(model, np.ascontiguousarray(-surf), 1e-10,
                                                tm.PolonskyKeerRey.pressure,
                                                tm.PolonskyKeerRey.pressure)
                    solver.max_iter = 10000
                    t0, c0 = time.perf_counter(), time.process_time()
                    solver.solve(force / size**2)
                    times.append(time.perf_counter() - t0)
                    cpus.append(time.process_time() - c0)
                trac = np.asarray(model.traction).reshape(m, m)[:n, :n]
                res[key] = (statistics.median(times[1:]), statistics.median(cpus[1:]), trac)
        d_hertz = (3 * force / (4 * E_STAR * np.sqrt(R))) ** (2 / 3)
        nan = float("nan")
        t_n, c_n, _ = res.get("n", (nan, nan, None))
        t_2n, c_2n, trac = res.get("2n", (nan, nan, np.full_like(p_jc, nan)))
        print(f"| {n}² | {t_jc:.3f} ({c_jc:.3f}) | {t_n:.3f} ({c_n:.3f}) "
              f"| {t_2n:.3f} ({c_2n:.3f}) | {t_jc / t_n:.2f} ({c_jc / c_n:.2f}) "
              f"| {t_jc / t_2n:.2f} ({c_jc / c_2n:.2f}) "
              f"| {np.sum(p_jc > 0) / np.sum(trac > 0) - 1:+.1e} "
              f"| {p_jc.max() / trac.max() - 1:+.1e} | {float(d_jc) / d_hertz - 1:+.4f} |",
              flush=True)


def _order(errs):
    out = [""]
    for e0, e1 in zip(errs[:-1], errs[1:], strict=True):
        ok = e0 != 0 and e1 != 0 and np.sign(e0) == np.sign(e1)
        out.append(f"{np.log2(abs(e0 / e1)):.2f}" if ok else "–")
    return out


def convergence(cells):
    ts, disp, a0 = _sphere_history(15, 60)
    # force control: load to the JKR force at 2 a_JKR, unload past -3/2 pi dgamma R
    a1 = 2.0 * A_FC
    f1 = 4 * E_STAR * a1**3 / (3 * R) - np.sqrt(8 * np.pi * E_STAR * DGAMMA * a1**3)
    f_in = np.concatenate([np.linspace(0, f1, 15), np.linspace(f1, 2.0 * F_FC, 60)])
    print("\n## Pull-off of the adhesive sphere against JKR\n")
    print("Elastic sphere, E* = 1 MPa, R = 1 mm, dgamma = 0.05 J/m². Displacement control: "
          "15 approach steps to 1.5 a_JKR, 60 lift steps to 1.3 d_JKR,dc (square of side 2.4 "
          "x 1.5 a_JKR). Force control: 15 loading steps to the JKR force at 2 a_JKR, 60 "
          "unloading steps to 2 x (-3/2 pi dgamma R) (side 2.4 x 2 a_JKR). Errors relative "
          "to the JKR values (the jump-off displacement against d_JKR,dc = a²/R - "
          "sqrt(2 pi a dgamma / E*) at a = (pi dgamma R²/(8E*))^(1/3)); order = "
          "log2(e_n / e_2n).\n")
    rows = []
    for n in cells:
        dc = jc.bem_simulate(jc.Elastic(E_STAR / 4), jc.Parabola(R), DGAMMA, ts, disp,
                             grid=jc.BEMGrid(n, 2.4 * a0))
        grid_fc = jc.BEMGrid(n, 2.4 * a1)
        fc = jc.bem_simulate(jc.Elastic(E_STAR / 4), jc.Parabola(R), DGAMMA, ts, f_in,
                             grid=grid_fc, loading=jc.ForceControl())
        rows.append((n, R / float(jc.BEMGrid(n, 2.4 * a0).cell_size),
                     float(dc.max_tensile_force) / F_FC - 1, float(dc.jumpoff_force) / F_DC - 1,
                     R / float(grid_fc.cell_size), float(fc.jumpoff_force) / F_FC - 1,
                     float(dc.jumpoff_displacement) / D_DC - 1))
        print(f"<!-- {rows[-1]} -->", flush=True)
    o1, o2, o3, o4 = (_order([r[k] for r in rows]) for k in (2, 3, 5, 6))
    print("| cells | R/Δ (dc) | dc: max tensile err | order | dc: jump-off force err | order "
          "| dc: jump-off displacement err | order | R/Δ (fc) | fc: pull-off err | order |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for k, r in enumerate(rows):
        print(f"| {r[0]}² | {r[1]:.0f} | {r[2]:+.4f} | {o1[k]} | {r[3]:+.4f} | {o2[k]} "
              f"| {r[6]:+.4f} | {o4[k]} | {r[4]:.0f} | {r[5]:+.4f} | {o3[k]} |")


def ellipse(cells, ratios):
    print("\n## Ellipsoid: pull-off against the elliptical JKR theories\n")
    print("R_x = k R_y, sqrt(R_x R_y) = 1 mm, E* = 1 MPa, dgamma = 0.05 J/m². Displacement "
          "control: 20 approach steps to the depth where sqrt(R_x d0) = 1.5 a_x (a_x the "
          "semi-axis along x at the force-control pull-off of the energy theory), 80 lift "
          "steps to -0.8 d0; square of side 2.1 sqrt(2 R_x d0). Pull-off forces over "
          "3/2 pi dgamma sqrt(R_x R_y): fc = the largest tensile force, dc = the force at "
          "jump-off. 'extrap.': first-order Richardson extrapolation 2 F(2n) - F(n) of the "
          "last two grids. JG: Griffith at the ends of both axes (Johnson & Greenwood 2005); "
          "energy: stationary total energy over the two semi-axes (the approach of "
          "Giudici, Vella & Griffiths 2025); both computed by `benchmarks/elliptic_jkr.py` "
          "from their formulas, not taken from the papers' tables.\n")
    L0 = (DGAMMA * R**2 / E_STAR) ** (1 / 3)
    scale = 1.5 * np.pi * DGAMMA * R
    head = " | ".join(f"{n}² fc | {n}² dc" for n in cells)
    print(f"| R_x/R_y | a_x/Δ at {cells[-1]}² | {head} | extrap. fc | JG fc | energy fc "
          "| JG dc | energy dc |")
    print("|---:" * (2 + 2 * len(cells) + 5) + "|")
    for k in ratios:
        jg, en = elliptic_jkr.pull_off("jg", k), elliptic_jkr.pull_off("energy", k)
        ax = en["axes"][0] * L0
        rx, ry = R * np.sqrt(k), R / np.sqrt(k)
        d0 = 2.25 * ax**2 / rx
        disp = np.concatenate([np.linspace(0, d0, 20), np.linspace(d0, -0.8 * d0, 80)])
        ts = np.arange(disp.size, dtype=float)
        vals = []
        for n in cells:
            grid = jc.BEMGrid(n, 2.1 * np.sqrt(2 * rx * d0))
            s = jc.bem_simulate(jc.Elastic(E_STAR / 4), jc.ellipsoid_heights(grid, rx, ry),
                                DGAMMA, ts, disp, grid=grid)
            vals.append((float(s.max_tensile_force) / scale, float(s.jumpoff_force) / scale))
            print(f"<!-- k={k} n={n} {vals[-1]} -->", flush=True)
        extrap = 2 * vals[-1][0] - vals[-2][0]
        cols = " | ".join(f"{fc:+.4f} | {dc:+.4f}" for fc, dc in vals)
        print(f"| {k:g} | {ax / float(grid.cell_size):.0f} | {cols} | {extrap:+.4f} "
              f"| {jg['force_control']:+.4f} | {en['force_control']:+.4f} "
              f"| {jg['displacement_control']:+.4f} | {en['displacement_control']:+.4f} |",
              flush=True)


def viscoelastic(cells):
    rh = jc.StandardModel(1e6, 0.5e6, 5e4)
    d0 = 7e-6
    a0 = np.sqrt(R * d0)
    tau = float(rh.tau)
    v = d0 / (5 * tau)
    ts_r = np.linspace(0, 12 * tau, 80)
    ref_r = jc.retract(rh, jc.Parabola(R), work_of_adhesion=DGAMMA, depth=d0, ts=ts_r,
                       velocity=v)
    t1 = np.linspace(0, 2 * tau, 20)
    t2 = np.linspace(2 * tau, 4 * tau, 11)[1:]
    t3 = np.linspace(4 * tau, 10 * tau, 51)[1:]
    ts_h = np.concatenate([t1, t2, t3])
    d_h = np.concatenate([d0 * t1 / (2 * tau), np.full(10, d0),
                          d0 - (t3 - 4 * tau) * d0 / (3 * tau)])
    ref_h = jc.simulate(rh, jc.Parabola(R), DGAMMA, ts_h, d_h)
    print("\n## Viscoelastic sphere against the MDR models\n")
    print("Standard model G0 = 1 MPa, G1 = 0.5 MPa, eta1 = 5e4 Pa s (tau = 33 ms), R = 1 mm, "
          "dgamma = 0.05 J/m², d0 = 7 µm, square of side 2.6 sqrt(R d0). Relaxed start: "
          "lift at d0/(5 tau), 80 samples over 12 tau, against `retract`. Approach-hold-lift: "
          "approach in 2 tau, hold 2 tau, lift at d0/(3 tau), 80 samples, against `simulate` "
          "(MDR foundation). Force error: largest |F_BEM - F_MDR| before 90 % of the first "
          "jump-off time over the largest |F_MDR| (near the jump-off the discrete ring-by-ring "
          "detachment makes a sawtooth); rms: root mean square of F_BEM - F_MDR before the "
          "first jump-off over the largest |F_MDR|; the relative errors of the largest "
          "tensile force and of the jump-off time.\n")
    print("| cells | a0/Δ | relaxed: force err | rms | max tensile | jump-off time "
          "| a-h-l: force err | rms | max tensile | jump-off time |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for n in cells:
        grid = jc.BEMGrid(n, 2.6 * a0)
        out = []
        for ts, disp, ref, relaxed in ((ts_r, d0 - v * ts_r, ref_r, d0),
                                       (ts_h, d_h, ref_h, None)):
            s = jc.bem_simulate(rh, jc.Parabola(R), DGAMMA, ts, disp, grid=grid,
                                relaxed_depth=relaxed)
            t_j = min(float(ref.jumpoff_time), float(s.jumpoff_time))
            e = np.asarray(s.force - ref.force) / np.max(np.abs(ref.force))
            out += [np.max(np.abs(e[ts < 0.9 * t_j])), np.sqrt(np.mean(e[ts < t_j] ** 2)),
                    float(s.max_tensile_force) / float(ref.max_tensile_force) - 1,
                    float(s.jumpoff_time) / float(ref.jumpoff_time) - 1]
        print(f"| {n}² | {a0 / float(grid.cell_size):.1f} | "
              + " | ".join(f"{x:+.4f}" for x in out) + " |", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--all", action="store_true", help="every section")
    for name in ("timing", "solve", "convergence", "ellipse", "viscoelastic"):
        ap.add_argument(f"--{name}", action="store_true")
    ap.add_argument("--cells", type=int, nargs="*", default=[128, 256])
    ap.add_argument("--solve-cells", type=int, nargs="*", default=[256, 512])
    ap.add_argument("--conv-cells", type=int, nargs="*", default=[32, 64, 128])
    ap.add_argument("--ellipse-cells", type=int, nargs="*", default=[32, 64, 128])
    ap.add_argument("--ratios", type=float, nargs="*", default=[1.0, 2.0, 4.0, 10.0])
    ap.add_argument("--visco-cells", type=int, nargs="*", default=[32, 64])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    print("# BEM benchmark (`benchmarks/bench_bem.py`)\n")
    print(_machine())
    if args.all or args.timing:  # first: its first call includes the compilation
        timing(args.cells, args.repeats)
    if args.all or args.solve:
        elastic_solve(args.solve_cells, args.repeats)
    if args.all or args.convergence:
        convergence(args.conv_cells)
    if args.all or args.viscoelastic:
        viscoelastic(args.visco_cells)
    if args.all or args.ellipse:
        ellipse(args.ellipse_cells, args.ratios)
    print(f"\nFinished {datetime.datetime.now().strftime('%Y-%m-%d %H:%M')}, load average "
          f"{tuple(round(x, 1) for x in os.getloadavg())}.")


if __name__ == "__main__":
    main()
