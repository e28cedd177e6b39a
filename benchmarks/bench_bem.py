"""Benchmark of the boundary element method (`jc.bem_simulate`, `jc.bem_contact`).

1. A complete adhesive pull-off of an elastic sphere (paraboloid) in displacement control:
   20 approach steps to 1.5x the JKR pull-off radius, 80 lift steps past the jump-off
   (100 steps), at n x n cells for each n in --cells. Median wall time (compilation
   excluded; first call timed separately) and the pull-off errors against JKR:
   max tensile force vs -3/2 pi dgamma R, jump-off force vs -5/6 pi dgamma R.
2. One non-adhesive elastic (Hertz) solve in force control at each n in --solve-cells,
   `jc.bem_contact` against tamaas' Polonsky-Keer-Rey solver on the same height map
   (if tamaas is installed). tamaas is periodic on n x n (FFT of n^2); jaxcontact is
   non-periodic (zero padding, FFT of (2n)^2), so jaxcontact transforms 4x more points.
3. Elliptical contact: pull-off (max tensile force) of an ellipsoid, principal radii
   R_x = k R_y, against the equivalent sphere sqrt(R_x R_y) (--ellipse). No closed-form
   elliptical JKR reference is implemented here: Johnson & Greenwood (2005) predict a
   pull-off that decreases slowly with the eccentricity from 3/2 pi dgamma R. The grid
   extent grows with sqrt(k), so the cell size (and the BEM's first-order pull-off error,
   about +7 % at k = 1 with 64 cells) grows with k as well: compare rows at equal cell size.

Wall times on a shared machine vary with its load: `uptime` is printed, and the CPU
(process) time of the pull-off runs is reported beside the wall time.

Run:  PYTHONPATH=$PWD python benchmarks/bench_bem.py [--cells 128 256 512]
      [--solve-cells 256 512] [--repeats 3] [--ellipse]
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import numpy as np

import jaxcontact as jc

E_STAR, R, DGAMMA = 1e6, 1e-3, 0.05


CPU = {}


def _timed(fn, repeats):
    """(output, first-call wall time, median wall time); CPU["last"]: median process time."""
    t0 = time.perf_counter()
    c0 = time.process_time()
    out = jax.block_until_ready(fn())
    first = time.perf_counter() - t0
    times, cpu = [], [time.process_time() - c0]
    for _ in range(repeats):
        t0 = time.perf_counter()
        c0 = time.process_time()
        out = jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    CPU["last"] = statistics.median(cpu[1:]) if repeats else cpu[0]
    return out, first, (statistics.median(times) if times else first)


def pulloff(cells, repeats):
    a_fc = (9 * np.pi * DGAMMA * R**2 / (8 * E_STAR)) ** (1 / 3)
    a_dc = (np.pi * DGAMMA * R**2 / (8 * E_STAR)) ** (1 / 3)
    d_dc = a_dc**2 / R - np.sqrt(2 * np.pi * a_dc * DGAMMA / E_STAR)
    a0 = 1.5 * a_fc
    d0 = a0**2 / R
    disp = np.concatenate([np.linspace(0, d0, 20), np.linspace(d0, 1.3 * d_dc, 80)])
    ts = np.arange(disp.size, dtype=float)
    print("\n# adhesive pull-off, elastic sphere, 100 steps (20 approach + 80 lift)")
    print(f"# E*={E_STAR:g} Pa, R={R:g} m, dgamma={DGAMMA:g} J/m^2, extent 2.4 a0 (a0 = 1.5 a_JKR)")
    print("cells  R/Delta  first[s]  median[s]  cpu[s]  CG-iter  rounds  "
          "maxT/(-3/2 pi dg R)-1  jump/(-5/6 pi dg R)-1")
    f_fc, f_dc = -1.5 * np.pi * DGAMMA * R, -5 / 6 * np.pi * DGAMMA * R
    for n in cells:
        grid = jc.BEMGrid(n, 2.4 * a0)

        def run(grid=grid):
            return jc.bem_simulate(jc.Elastic(E_STAR / 4), jc.Parabola(R), DGAMMA, ts, disp,
                                   grid=grid)

        s, first, med = _timed(run, repeats if n <= 128 else max(repeats - 2, 0))
        print(f"{n:5d}  {R / float(grid.cell_size):7.0f}  {first:8.2f}  {med:9.2f}  "
              f"{CPU['last']:6.1f}  "
              f"{int(s.stats['cg_iterations'].sum()):7d}  {int(s.stats['rounds'].sum()):6d}  "
              f"{float(s.max_tensile_force) / f_fc - 1:+21.4f}  "
              f"{float(s.jumpoff_force) / f_dc - 1:+20.4f}", flush=True)


def elastic_solve(cells, repeats):
    try:
        import tamaas as tm

        tm.set_log_level(tm.LogLevel.error)
    except ImportError:
        tm = None
        print("\n# tamaas not installed: jaxcontact timings only")
    d = 1e-5
    a = np.sqrt(R * d)
    force = 4 / 3 * E_STAR * np.sqrt(R) * d**1.5
    print("\n# one non-adhesive Hertz solve, force control, extent 4a, tol 1e-10")
    print("cells  jaxcontact[s]  tamaas[s]  ratio(jc/tamaas)  F-err jc  area jc/tamaas-1  "
          "p_max jc/tamaas-1  depth jc/Hertz-1")
    for n in cells:
        grid = jc.BEMGrid(n, 4 * a)
        h = np.asarray(jc.bem_heights(jc.Parabola(R), grid))

        def run_jc(grid=grid, h=h):
            return jc.bem_contact(h, grid=grid, effective_modulus=E_STAR, force=force)

        (f_jc, d_jc, p_jc), _, t_jc = _timed(run_jc, repeats)
        p_jc = np.asarray(p_jc)
        t_tm, area_tm, pmax_tm = float("nan"), float("nan"), float("nan")
        if tm is not None:
            L = float(grid.extent)
            times = []
            for _ in range(repeats):
                model = tm.ModelFactory.createModel(tm.model_type.basic_2d, [L, L], [n, n])
                model.E, model.nu = E_STAR, 0.0
                surface = np.ascontiguousarray(-h)
                solver = tm.PolonskyKeerRey(model, surface, 1e-10,
                                            tm.PolonskyKeerRey.pressure,
                                            tm.PolonskyKeerRey.pressure)
                solver.max_iter = 5000
                t0 = time.perf_counter()
                solver.solve(force / L**2)
                times.append(time.perf_counter() - t0)
            t_tm = statistics.median(times)
            trac = np.asarray(model.traction).reshape(n, n)
            area_tm, pmax_tm = float(np.sum(trac > 0)), float(trac.max())
        d_hertz = (3 * force / (4 * E_STAR * np.sqrt(R))) ** (2 / 3)
        print(f"{n:5d}  {t_jc:13.3f}  {t_tm:9.3f}  {t_jc / t_tm:16.2f}  "
              f"{float(f_jc) / force - 1:+8.1e}  {np.sum(p_jc > 0) / area_tm - 1:+16.4f}  "
              f"{p_jc.max() / pmax_tm - 1:+17.4f}  {float(d_jc) / d_hertz - 1:+16.4f}",
              flush=True)


def ellipse(cells):
    print("\n# elliptical contact: max tensile force vs the sphere of radius sqrt(Rx Ry)")
    print("Rx/Ry  cells  maxT/(-3/2 pi dg sqrt(RxRy))  jump/(-5/6 pi dg sqrt(RxRy))")
    for k in (1.0, 2.0, 4.0):
        ry = R / np.sqrt(k)
        rx = k * ry
        a_fc = (9 * np.pi * DGAMMA * R**2 / (8 * E_STAR)) ** (1 / 3)
        d0 = (1.5 * a_fc) ** 2 / R
        disp = np.concatenate([np.linspace(0, d0, 20), np.linspace(d0, -0.6 * d0, 80)])
        ts = np.arange(disp.size, dtype=float)
        grid = jc.BEMGrid(cells, 3.6 * a_fc * np.sqrt(k))
        s = jc.bem_simulate(jc.Elastic(E_STAR / 4), jc.ellipsoid_heights(grid, rx, ry), DGAMMA,
                            ts, disp, grid=grid)
        f_fc, f_dc = -1.5 * np.pi * DGAMMA * R, -5 / 6 * np.pi * DGAMMA * R
        print(f"{k:5.1f}  {cells:5d}  {float(s.max_tensile_force) / f_fc:28.4f}"
              f"  {float(s.jumpoff_force) / f_dc:28.4f}", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", type=int, nargs="*", default=[128, 256])
    ap.add_argument("--solve-cells", type=int, nargs="*", default=[256, 512])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--ellipse", type=int, default=0, help="cells for the ellipse table (0: skip)")
    args = ap.parse_args()
    import os

    print(f"jax {jax.__version__}, devices {jax.devices()}, load average {os.getloadavg()}")
    if args.solve_cells:
        elastic_solve(args.solve_cells, args.repeats)
    if args.cells:
        pulloff(args.cells, args.repeats)
    if args.ellipse:
        ellipse(args.ellipse)


if __name__ == "__main__":
    main()
