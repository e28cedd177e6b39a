"""Memory of a force-map fit: peak and retained resident memory of `fitting.fit_each` per
curve, and what a 16,384-curve map needs.

Each map size runs in a fresh process (so that one size's peak does not hide the next's):
the synthetic relaxed-start map of `bench_fit_each.py` (`make_map`, 60 samples a curve,
default search), `fitting.fit_each(curves, chunk=...)`. Measured per process: the resident
set after the imports and the curves are made (*base*), the peak resident set of the whole
process (`ru_maxrss`), the resident set after the fit with only its result kept
(*retained*, after `gc.collect()`), and the pickled size of the result. Memory per curve is
the slope between the two sizes (what grows with the map), the constant part (compiled
programs, JAX's buffers of one chunk) is the intercept.

    python benchmarks/bench_fit_each_memory.py [--curves 32,256] [--chunk 32]
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import pickle
import resource
import subprocess
import sys
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))


def _rss() -> float:
    """Current resident set [MiB] (Linux `/proc/self/statm`)."""
    with open("/proc/self/statm") as fh:
        pages = int(fh.read().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def child(n: int, chunk: int) -> dict:
    sys.path.insert(0, HERE)
    import jax

    jax.config.update("jax_enable_x64", True)
    from bench_fit_each import R, make_map

    import fitting

    warnings.simplefilter("ignore")
    curves = make_map(n, 60)
    gc.collect()
    base = _rss()
    res = fitting.fit_each(curves, radius=R, chunk=chunk, progress=False)
    del curves
    gc.collect()
    retained = _rss()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux
    return {"curves": n, "base_MiB": base, "peak_MiB": peak, "retained_MiB": retained,
            "result_pickle_MiB": len(pickle.dumps(res)) / 2**20,
            "converged": int(sum(bool(r.converged) for r in res.results))}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--curves", default="32,256")
    ap.add_argument("--chunk", type=int, default=32)
    ap.add_argument("--child", type=int, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child is not None:
        print(json.dumps(child(args.child, args.chunk)))
        return
    rows = []
    for n in (int(c) for c in args.curves.split(",")):
        out = subprocess.run([sys.executable, __file__, "--child", str(n),
                              "--chunk", str(args.chunk)], capture_output=True, text=True,
                             check=True)
        rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
        r = rows[-1]
        print(f"| {n} | {r['base_MiB']:.0f} | {r['peak_MiB']:.0f} | {r['retained_MiB']:.0f} | "
              f"{r['result_pickle_MiB']:.2f} | {r['converged']}/{n} |", flush=True)
    if len(rows) >= 2:
        a, b = rows[0], rows[-1]
        dn = b["curves"] - a["curves"]
        per_peak = (b["peak_MiB"] - a["peak_MiB"]) / dn * 1024
        kept = [r["retained_MiB"] - r["base_MiB"] for r in (a, b)]
        per_kept = (kept[1] - kept[0]) / dn * 1024
        per_pickle = (b["result_pickle_MiB"] - a["result_pickle_MiB"]) / dn * 1024
        big = 16384
        print(f"per curve: peak {per_peak:.1f} KiB, retained {per_kept:.1f} KiB, "
              f"result (pickled) {per_pickle:.1f} KiB; a {big}-curve map: peak about "
              f"{(b['peak_MiB'] + per_peak * (big - b['curves']) / 1024) / 1024:.2f} GiB")


if __name__ == "__main__":
    main()
