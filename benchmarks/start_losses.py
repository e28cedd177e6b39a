"""Every start's final χ² per curve (the global search's starts, then the local rounds'), as
JSON lines: the data of "Can the local rounds be skipped when many starts agree?" in
`benchmarks/results/fit_each.md`.

    PYTHONPATH=. python benchmarks/start_losses.py relaxed OUT.jsonl 64 [SEED]
    PYTHONPATH=. python benchmarks/start_losses.py history OUT.jsonl 16 [SEED]
    PYTHONPATH=. python benchmarks/start_losses.py real:history OUT.jsonl FILE[@OPT=V,...] ...

`relaxed`/`history`: the synthetic maps of `bench_fit_each.py` through `fitting.fit_each`;
`real:MODEL`: the first curve of each file through `fitting.fit` (R = 10 µm, contact point
fitted; loader options after ``@`` as in `eval_real_fits.py`). Each line: name, `losses`
(`FitResult.start_losses`: the first `fitting.DEFAULT_STARTS` are the global search),
`steps`, `chi2`, `chi2_red`, time [s].
"""

import json
import sys
import time
import warnings

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)
warnings.simplefilter("ignore")
sys.path.insert(0, __file__.rsplit("/", 1)[0])

from bench_fit_each import R, make_history_map, make_map  # noqa: E402

import fitting  # noqa: E402


def main(argv):
    kind, path = argv[0], argv[1]
    with open(path, "a") as out:
        def record(name, r, t):
            out.write(json.dumps({
                "name": name, "losses": [float(x) for x in np.asarray(r.start_losses)],
                "steps": [int(x) for x in np.asarray(r.start_steps)], "chi2": float(r.chi2),
                "chi2_red": float(r.chi2 / max(r.n_data - r.n_free, 1)), "time": t}) + "\n")
            out.flush()

        if kind in ("relaxed", "history"):
            n = int(argv[2])
            seed = int(argv[3]) if len(argv) > 3 else 0
            make = make_map if kind == "relaxed" else make_history_map
            curves = make(n, 60 if kind == "relaxed" else 200, seed)
            t0 = time.time()
            res = fitting.fit_each(curves, radius=R, model=kind, progress=False)
            for i, r in enumerate(res.results):
                if r is not None:
                    record(f"{kind}-s{seed}-{i}", r, (time.time() - t0) / n)
            return
        model = kind.split(":")[1]
        for spec in argv[2:]:
            name, _, opts = spec.partition("@")
            kw = {k: float(v) for k, v in (item.split("=") for item in opts.split(",") if item)}
            try:
                curve = fitting.load_curve(name, **kw)[0]
                t0 = time.time()
                r = fitting.fit(curve, radius=10e-6, model=model, progress=False)
                record(f"{model}:{name.rsplit('/', 1)[-1]}", r, time.time() - t0)
            except (ValueError, OSError) as exc:
                print(f"{name}: failed: {exc}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
