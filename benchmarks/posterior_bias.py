"""Bias or spread? The z-scores of the history calibration's posteriors, and the fit's
Δγ on a finer foundation grid.

    PYTHONPATH=. python benchmarks/posterior_bias.py [--records FILE]
        [--refit 0,1,2,3,4,5 --cells 64]

1. From the records of `bench_posterior.py --model history`: per parameter, the z-score of
   the posterior mean, z = (mean − truth) / sd, over the sets: its mean (a bias of the
   posterior in units of its own width) and its standard deviation (1 for a posterior as
   wide as its errors), and the coverage of the 90 % interval.
2. `--refit`: those sets fitted again (`fitting.fit`, as the calibration fits them) on
   `--cells` foundation cells (the curves are generated on 64; the calibration fits on 8)
   and with `--history-samples` samples a curve, with the fit's z-score of Δγ beside the
   calibration's fit's from the records, and their mean: whether the grid or the number
   of samples causes a bias.
"""

import argparse
import json
import pathlib
import sys
import types
import warnings

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent))

PARAMS = ("G0", "G1", "eta1", "work_of_adhesion", "contact_offset")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--records", default=str(pathlib.Path(__file__).resolve().parent
                                             / "results" / "posterior_history_records.jsonl"))
    ap.add_argument("--refit", default="")
    ap.add_argument("--cells", type=int, default=64)
    ap.add_argument("--history-samples", type=int, default=80,
                    help="samples a curve of the refitted sets (the calibration's: 80)")
    args = ap.parse_args(argv)
    recs = [json.loads(line) for line in open(args.records)]
    print(f"{len(recs)} sets ({args.records})\n\n| parameter | z mean | z sd | coverage of "
          "the 90 % interval |\n| --- | --- | --- | --- |")
    for p in PARAMS:
        z = np.array([(r["params"][p]["mean"] - r["truth"][p]) / r["params"][p]["sd"]
                      for r in recs])
        cov = np.mean([r["params"][p]["covered"] for r in recs])
        print(f"| {p} | {z.mean():+.2f} | {z.std(ddof=1):.2f} | {cov:.0%} |")
    if not args.refit:
        return
    import jax

    jax.config.update("jax_enable_x64", True)
    warnings.simplefilter("ignore")
    import bench_posterior as bp

    by_set = {r["curve"]: r for r in recs}
    print(f"\n| set | Δγ fit z, {args.cells} cells, {args.history_samples} samples a curve | "
          "Δγ fit z, 8 cells, 80 samples (records) |\n| --- | --- | --- |")
    zs = []
    for i in (int(x) for x in args.refit.split(",")):
        ns = types.SimpleNamespace(cells=args.cells, history_samples=args.history_samples,
                                   model="history", radius=10e-6)
        p, data = bp.make_set(i, ns)
        res = bp.fit_set(data, ns)
        k = res.names.index("work_of_adhesion")
        t = p["work_of_adhesion"]
        rec = by_set.get(i, {}).get("params", {}).get("work_of_adhesion")
        z8 = (rec["fit_value"] - t) / rec["fit_stderr"] if rec else float("nan")
        zs.append((res.values[k] - t) / res.stderr[k])
        print(f"| {i} | {zs[-1]:+.2f} | {z8:+.2f} |", flush=True)
    se = np.std(zs, ddof=1) / np.sqrt(len(zs))
    print(f"\nmean z {np.mean(zs):+.2f} (standard error {se:.2f})")


if __name__ == "__main__":
    main()
