"""Real curves whose measured force stays off the model's after its jump-off: how often the
`force_after_detachment` flag fires, how much of χ² those samples carry, and what the
flag's advice for a retract offset (``retract_baseline="separate"``) changes.

For every file given (its first curve), `fitting.fit` runs twice with the full-history
standard model, the contact point fitted and the default search: with the loader's default
preprocessing and with the retract given its own constant offset (the mean of its free
tail; :func:`fitting.preprocess`). Reported per file and run: χ², reduced χ², the status
and flags, the share of χ² after the model's jump-off (from the flag's message; "-" when
not flagged), and the relative change of each material parameter between the two runs.

    python benchmarks/after_detachment.py FILE [FILE ...] [--radius 10e-6]
        [--out benchmarks/results/after_detachment.md]

Writes the table (with machine and date) to `--out` and prints it.
"""

from __future__ import annotations

import argparse
import pathlib
import re
import sys
import time
import warnings

import jax
from _results import machine, write_table  # benchmarks/_results.py

import fitting

jax.config.update("jax_enable_x64", True)

MATERIAL = ("G0", "G1", "eta1", "work_of_adhesion")


def _fit(path: str, radius: float, **load):
    curve = fitting.load_curve(path, **load)[0]
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = fitting.fit(curve, radius=radius, model="history", progress=False)
    return res, time.perf_counter() - t0


def _share(res) -> str:
    msg = res.flags.get("force_after_detachment")
    if msg is None:
        return "-"
    m = re.search(r"(\S+) % of the curve's chi2", msg)
    return f"{m.group(1)} %" if m else "?"


def _undetermined(name: str, *results) -> str:
    """" (nd)" when the parameter's status is not "ok" in any of `results`."""
    ok = all(r.status[r.names.index(name)] == "ok" for r in results)
    return "" if ok else " (nd)"


def _row(name: str, label: str, res, dt: float, change: str) -> str:
    status = "ok" if not res.flags else ", ".join(res.flags)
    return (f"| {name} | {label} | {res.chi2:.6g} | {res.reduced_chi2:.4g} | {status} | "
            f"{_share(res)} | {change} | {dt:.0f} |")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="+")
    ap.add_argument("--radius", type=float, default=10e-6)
    ap.add_argument("--out", default="benchmarks/results/after_detachment.md")
    args = ap.parse_args(argv)
    lines = [
        "# Force after the model's jump-off on real curves",
        "",
        f"{machine()}; `python benchmarks/{pathlib.Path(__file__).name} "
        + " ".join(pathlib.Path(f).name for f in args.files)
        + f" --radius {args.radius:g}`. Full-history standard model, a paraboloid of that "
        "radius, contact point fitted, default search. *default*: the loader's "
        "preprocessing; *separate*: the retract with its own constant offset (the mean of its "
        "free tail). *after jump-off*: the share of the curve's χ² after the model's last "
        "jump-off when `force_after_detachment` is flagged. *change*: relative change of "
        "G0, G1, η1, Δγ from default to separate ((nd): not determined, or at a bound, in "
        "either run).",
        "",
        "| file | preprocessing | χ² | χ²_red | status (flags) | after jump-off | change "
        "(G0, G1, η1, Δγ) | time [s] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for f in args.files:
        name = pathlib.Path(f).name
        try:
            base, t0 = _fit(f, args.radius)
            sep, t1 = _fit(f, args.radius, retract_baseline="separate")
        except (ValueError, OSError) as exc:
            lines.append(f"| {name} | - | - | - | not fitted: {exc} | - | - | - |")
            continue
        change = ", ".join(f"{sep[k] / base[k] - 1:+.0%}" + _undetermined(k, base, sep)
                           for k in MATERIAL)
        lines.append(_row(name, "default", base, t0, ""))
        lines.append(_row(name, "separate", sep, t1, change))
        print(lines[-2], lines[-1], sep="\n", file=sys.stderr, flush=True)
    write_table(args.out, lines)


if __name__ == "__main__":
    main()
