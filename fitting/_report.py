"""Fit outputs: ``parameters.json``, ``parameters.csv``, ``fit.png`` in an output folder.

``parameters.json``: ``{"<name>_<unit>": {"value": v, "stderr": s, "fixed": bool}, ...,
"r_squared": R², "reduced_chi2": χ²_red, "chi2": χ², "n_data": m, "n_free": k,
"converged": bool, "model": ..., "rheology": ..., "radius_m": R, "loading":
{"type": "displacement" | "compliant", "spring_constant_N_m": [k per curve] | null},
"correlation": {"names": [...], "matrix": [[...]]}, "warnings": [...], "timings_s": {...},
"curves": [sources], "inputs": [{"source", "segments", "samples", "duration_s",
"spring_constant_N_m"}, ...]}`` (``inputs``: each curve as loaded, its segments and the
cantilever spring constant it carries, from the instrument file or the loader; ``null``
if none). Standard-model fits also carry the derived ``G_inf_Pa`` and
``tau_s`` (values only). ``parameters.csv``: one row per parameter with the columns
``parameter,unit,value,stderr,relative_stderr,fixed``.
"""

from __future__ import annotations

import csv
import json
import math
import pathlib

import numpy as np

__all__ = ["write_report", "result_table"]


def _num(x):
    x = float(x)
    return x if math.isfinite(x) else None


def result_table(result) -> dict:
    """The content of ``parameters.json`` as a dict."""
    out: dict = {}
    for col, v, s, f in zip(result.columns, result.values, result.stderr, result.fixed,
                            strict=True):
        out[col] = {"value": _num(v), "stderr": _num(s), "fixed": bool(f)}
    if result.spec.rheology == "standard":
        g0, g1, eta = (float(result.values[i]) for i in range(3))
        out["G_inf_Pa"] = {"value": g0 * g1 / (g0 + g1), "derived": True}
        out["tau_s"] = {"value": eta / (g0 + g1), "derived": True}
    out.update(
        r_squared=_num(result.r_squared), reduced_chi2=_num(result.reduced_chi2),
        chi2=_num(result.chi2), n_data=int(result.n_data), n_free=int(result.n_free),
        converged=bool(result.converged), model=result.spec.model,
        rheology=(result.spec.rheology if result.spec.rheology == "standard"
                  else f"prony:{result.spec.arms}"),
        radius_m=result.radius,
        loading=_loading(result),
        correlation={"names": list(result.columns),
                     "matrix": [[_num(x) for x in row] for row in result.correlation]},
        warnings=list(result.warnings),
        timings_s={k: float(v) for k, v in result.timings.items()},
        curves=[getattr(c, "source", "") for c in result.curves],
        inputs=[_input_info(c) for c in result.curves],
    )
    return out


def _loading(result) -> dict:
    if not result.spec.compliant:
        return {"type": "displacement", "spring_constant_N_m": None}
    return {"type": "compliant",
            "spring_constant_N_m": [float(k) for k in np.asarray(result.data.stiffness)]}


def _input_info(curve) -> dict:
    k = getattr(curve, "spring_constant", None)
    time = np.asarray(curve.time)
    return {"source": getattr(curve, "source", ""),
            "segments": list(curve.segment_names),
            "samples": len(time),
            "duration_s": float(time[-1] - time[0]),
            "spring_constant_N_m": None if k is None else float(k)}


def _write_figure(result, path: pathlib.Path) -> None:
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    data, sol = result.data, result.model_solution
    valid = np.asarray(data.valid) > 0
    fig, axes = plt.subplots(3, 1, figsize=(7, 9), sharex=True,
                             gridspec_kw={"height_ratios": [3, 1.3, 1.5]})
    for c in range(data.n_curves):
        m = valid[c]
        x = np.asarray(data.indentation[c])[m] * 1e6
        fd = np.asarray(data.force[c])[m] * 1e9
        fm = np.asarray(sol.force[c])[m] * 1e9
        line = axes[0].plot(x, fd, ".", ms=2, alpha=0.5, label=f"data {c + 1}")[0]
        axes[0].plot(x, fm, "-", color=line.get_color(), lw=1.2, label=f"fit {c + 1}")
        axes[1].plot(x, (fd - fm) / (float(data.sigma[c]) * 1e9), ".", ms=2,
                     color=line.get_color())
        axes[2].plot(x, np.asarray(sol.contact_radius[c])[m] * 1e6, "-",
                     color=line.get_color())
    axes[0].set_ylabel("force [nN]")
    axes[0].legend(fontsize=7, ncol=2)
    axes[0].set_title(f"{result.spec.model} model, R² = {result.r_squared:.4f}, "
                      f"χ²_red = {result.reduced_chi2:.3g}")
    axes[1].set_ylabel("residual / σ")
    axes[1].axhline(0, color="k", lw=0.5)
    axes[2].set_ylabel("contact radius [µm]")
    axes[2].set_xlabel("indentation [µm]")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write_report(result, out_dir, *, figure: bool = True) -> dict[str, pathlib.Path]:
    """Write ``parameters.json``, ``parameters.csv`` and ``fit.png`` into `out_dir`.

    The folder is created if needed. **Returns** the paths by kind.
    """
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    table = result_table(result)
    paths = {"json": out / "parameters.json", "csv": out / "parameters.csv"}
    paths["json"].write_text(json.dumps(table, indent=2, allow_nan=False) + "\n")
    with paths["csv"].open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["parameter", "unit", "value", "stderr", "relative_stderr", "fixed"])
        for col, v, s, f in zip(result.columns, result.values, result.stderr, result.fixed,
                                strict=True):
            name, unit = col.rsplit("_", 1) if not col.endswith("_Pa_s") else (
                col[:-5], "Pa_s")
            if col.endswith("_J_m2"):
                name, unit = col[:-5], "J_m2"
            rel = float(s) / float(v) if math.isfinite(float(s)) else float("nan")
            w.writerow([name, unit, repr(float(v)), repr(float(s)), repr(rel), bool(f)])
    if figure:
        paths["figure"] = out / "fit.png"
        _write_figure(result, paths["figure"])
    return paths
