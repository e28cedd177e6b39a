"""How far each search ends from the best on a real force map: per curve, the reduced χ² of
several searches against the lowest any of them reached.

    python benchmarks/map_search_quality.py [--map tests/data/bruker-egel-force-volume-16x16.spm]
        [--radius 10e-6] [--max-samples 200] [--searches "default;--starts 32 --screen 4096"]
        [--work DIR] [--out -]

Each search is one cold ``jaxcontact fit MAP --radius R --max-samples N --no-figure
[OPTIONS]`` in a child process (``JAXCONTACT_NO_CACHE=1``), its ``map.csv`` kept in
``--work`` (a run whose ``map.csv`` is there already is not run again: delete the folder to
measure anew). Reported per search: the wall time of the run, and the curves whose reduced
χ² is within 10⁻⁹, 10⁻⁶, 10⁻³ (relative) of the best of all searches, more than 10 % above
it, the worst ratio, and the converged curves. The reference is the best of the searches
run, so a search that no other search beats is "at best" by construction: run a large one
(e.g. ``--starts 48 --screen 8192``) beside the others. Results of 2026-11-27:
`benchmarks/results/fit_each.md`, "How far the default search is from the best on a real
map".
"""

from __future__ import annotations

import argparse
import os
import pathlib
import shlex
import subprocess
import sys
import time

import numpy as np

DEFAULT_SEARCHES = ("default; --screen 1024; --screen 4096; --starts 32; "
                    "--starts 32 --screen 4096; --starts 48 --screen 8192")


def _chi2(csv: pathlib.Path) -> tuple[np.ndarray, np.ndarray]:
    import pandas as pd

    table = pd.read_csv(csv)
    return (table["reduced_chi2"].to_numpy(dtype=float),
            table["converged"].astype(str).str.lower().eq("true").to_numpy())


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--map", default="tests/data/bruker-egel-force-volume-16x16.spm")
    ap.add_argument("--radius", default="10e-6")
    ap.add_argument("--max-samples", default="200")
    ap.add_argument("--searches", default=DEFAULT_SEARCHES,
                    help="searches separated by ';' ('default': no options)")
    ap.add_argument("--work", default="/tmp/map_search_quality")
    ap.add_argument("--out", default="-")
    args = ap.parse_args(argv)
    work = pathlib.Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    searches = [s.strip() for s in args.searches.split(";") if s.strip()]
    runs = {}
    for search in searches:
        extra = [] if search == "default" else shlex.split(search)
        folder = work / ("default" if not extra else "_".join(
            x.strip("-") for x in extra))
        csv = folder / "map.csv"
        seconds = float("nan")
        if not csv.exists():
            cmd = [sys.executable, "-m", "jaxcontact_cli", "fit", args.map, "--radius",
                   args.radius, "--max-samples", args.max_samples, "--no-figure", "--quiet",
                   *extra, "--out", str(folder)]
            t0 = time.perf_counter()
            done = subprocess.run(cmd, env=dict(os.environ, JAXCONTACT_NO_CACHE="1"),
                                  capture_output=True, text=True)
            seconds = time.perf_counter() - t0
            if not csv.exists():
                raise SystemExit(f"{search}: no map.csv (exit {done.returncode}): "
                                 f"{done.stderr.strip()[-500:]}")
        runs[search] = (seconds, *_chi2(csv))
        print(f"{search}: {seconds:.1f} s", file=sys.stderr, flush=True)
    best = np.min(np.stack([chi2 for _, chi2, _ in runs.values()]), axis=0)
    lines = [f"{args.map}, --radius {args.radius} --max-samples {args.max_samples}; "
             f"reference: the best of the {len(runs)} searches per curve ({best.size} curves)",
             "",
             "| search | wall [s] | at best (1e-9) | within 1e-6 | within 1e-3 | > 10 % above "
             "| worst | converged |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for search, (seconds, chi2, converged) in runs.items():
        r = (chi2 - best) / best
        lines.append(f"| {search} | {seconds:.1f} | {int(np.sum(r <= 1e-9))} | "
                     f"{int(np.sum(r <= 1e-6))} | {int(np.sum(r <= 1e-3))} | "
                     f"{int(np.sum(r > 0.1))} | {1 + np.max(r):.4g}x | {int(np.sum(converged))} |")
    text = "\n".join(lines) + "\n"
    if args.out == "-":
        print(text)
    else:
        pathlib.Path(args.out).write_text(text)


if __name__ == "__main__":
    main()
