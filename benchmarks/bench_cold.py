"""A first run's time: where a cold `jaxcontact fit` spends it (tracing, lowering, compiling).

    PYTHONPATH=. python benchmarks/bench_cold.py [--runs 3] [--baseline DIR] [-- ARGS...]

Runs ``jaxcontact fit ARGS`` (default: the README's main job, the shipped oocyte curve,
exact sphere of 40 µm, full-history model) in fresh processes without any cache
(``JAXCONTACT_NO_CACHE=1``: no persistent compilation cache, no stored traced programs),
and reports per run the wall time of the process, the seconds JAX spent tracing programs
(``/jax/core/compile/jaxpr_trace_duration``), lowering them to StableHLO and in XLA's
compiler (``jax.monitoring``'s duration events, summed over the process's programs), and the
fit's χ². With ``--baseline DIR`` (another checkout, e.g. ``git archive REV | tar -x -C
DIR``) the runs alternate between the baseline and this checkout, each with its own
``PYTHONPATH``. The tracing of the search's program is Python (one core, whatever the
device); its XLA compilation is the device's compiler (slower for a GPU than for the CPU).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import statistics
import subprocess
import sys
import tempfile
import time

MAIN_JOB = ["tests/data/oocyte-stress-relaxation-cell1-0008.jpk-force", "--profile",
            "sphere:40e-6", "--model", "history"]

# run in the child: the command line with jax.monitoring's compile events summed
_CHILD = r"""
import collections, json, sys
from jax import monitoring
seconds = collections.defaultdict(float)
monitoring.register_event_duration_secs_listener(
    lambda event, duration, **kw: seconds.__setitem__(event, seconds[event] + duration))
from jaxcontact_cli._main import main
rc = main(sys.argv[2:])
json.dump({"rc": rc, "seconds": dict(seconds)}, open(sys.argv[1], "w"))
"""

_EVENTS = {"trace": "/jax/core/compile/jaxpr_trace_duration",
           "lower": "/jax/core/compile/jaxpr_to_mlir_module_duration",
           "compile": "/jax/core/compile/backend_compile_duration"}


def run_once(root: pathlib.Path, args: list[str]) -> dict:
    """One cold process of ``jaxcontact fit args`` from checkout `root`."""
    with tempfile.TemporaryDirectory() as tmp:
        out = pathlib.Path(tmp) / "out"
        report = pathlib.Path(tmp) / "events.json"
        env = dict(os.environ, JAXCONTACT_NO_CACHE="1", PYTHONPATH=str(root))
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-c", _CHILD, str(report), "fit", *args,
                               "--out", str(out), "--quiet"], cwd=root, env=env,
                              capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if proc.returncode != 0 or not report.exists():
            raise SystemExit(f"{root}: the command failed (rc {proc.returncode}):\n"
                             f"{proc.stderr[-2000:]}")
        seconds = json.loads(report.read_text())["seconds"]
        params = out / "parameters.json"
        chi2 = json.loads(params.read_text()).get("chi2") if params.exists() else None
    return {"wall": wall, "chi2": chi2,
            **{k: seconds.get(event, 0.0) for k, event in _EVENTS.items()}}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3, help="processes per checkout")
    ap.add_argument("--baseline", default=None, help="another checkout to alternate with")
    ap.add_argument("args", nargs="*", help="arguments of `jaxcontact fit` (after --)")
    a = ap.parse_args(argv)
    args = a.args or MAIN_JOB
    here = pathlib.Path(__file__).resolve().parents[1]
    roots = ([("baseline", pathlib.Path(a.baseline).resolve())] if a.baseline else []) + \
        [("this", here)]
    rows = {label: [] for label, _ in roots}
    for _ in range(a.runs):
        for label, root in roots:
            r = run_once(root, args)
            rows[label].append(r)
            print(f"{label}: wall {r['wall']:.1f} s, trace {r['trace']:.1f} s, lower "
                  f"{r['lower']:.1f} s, compile {r['compile']:.1f} s, chi2 {r['chi2']!r}",
                  flush=True)
    print(f"jaxcontact fit {' '.join(args)} (cold, no caches), medians of {a.runs}:")
    for label, rs in rows.items():
        med = {k: statistics.median(r[k] for r in rs)
               for k in ("wall", "trace", "lower", "compile")}
        print(f"  {label}: wall {med['wall']:.1f} s (trace {med['trace']:.1f}, lower "
              f"{med['lower']:.1f}, compile {med['compile']:.1f})")


if __name__ == "__main__":
    main()
