"""Fit outputs as data: ``parameters.json``, ``parameters.csv``, ``fit.csv``.

``parameters.json`` (strict JSON: no NaN or Infinity; a missing number is ``null`` with the
reason in ``status``): per parameter ``"<name>_<unit>": {"value", "stderr",
"relative_stderr", "status", "fixed"}``; derived values of the standard model (``G_inf_Pa``,
``tau_s``); quality (``r_squared``, ``r_squared_contact``, ``reduced_chi2``, ``chi2``,
``aic``, ``bic``, ``n_data``, ``n_free``, ``converged``); the model (``model``,
``rheology``, ``radius_m``, ``loading``, ``contact_point`` and ``force_offset`` choices,
``model_selection`` for ``rheology="auto"``); the search (``start_losses``);
``correlation``; ``warnings``; ``timings_s``; ``inputs`` (each curve's
source, segments, samples, duration, spring constant, and its detected contact point and
baseline when a loader found them).

``parameters.csv``: one row per parameter:
``parameter,unit,value,stderr,relative_stderr,status,fixed``.

``fit.csv``: one row per fitted sample:
``curve,segment,time_s,indentation_m,force_N,model_force_N,residual,weight,contact_radius_m``
(``time_s`` from the first fitted sample of the curve; ``model_force_N``: the model's
force at the sample time; ``residual``: the fitted residual (model − data)/σ with σ the
sample's noise, which at the sample whose interval holds the model's jump-off compares the
interval average of the model force (:mod:`fitting._objective`); ``weight``: the number
of measured samples the row stands for, its factor in χ² = Σ weight·residual²;
``contact_radius_m`` of the model).

One fit per curve (:func:`fitting.fit_each`, :func:`write_each_report`): ``map.nc`` (the
labelled dataset of :meth:`fitting.FitEachResult.to_dataset`, netCDF-4 through h5netcdf),
``map.csv`` (one row per curve: ``curve,source,grid_x,grid_y,position_x_m,position_y_m``,
then per parameter ``<name>_<unit>``, ``..._stderr``, ``..._status``, then
``r_squared,r_squared_contact,reduced_chi2,converged,error``; empty cells where a value is
missing) and ``parameters.json`` (model, counts, names and units, timings, and the rows of
``map.csv`` as objects, strict JSON).

The figures are drawn by the command line layer (``jaxcontact_cli``).
"""

from __future__ import annotations

import csv
import json
import math
import pathlib

import numpy as np

from ._prepare import SEGMENTS

__all__ = ["write_report", "result_table", "write_samples", "write_each_report"]


def _num(x):
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def result_table(result) -> dict:
    """The content of ``parameters.json`` as a dict (strict-JSON values)."""
    out: dict = {}
    for col, v, s, st, f in zip(result.columns, result.values, result.stderr,
                                result.status, result.fixed, strict=True):
        rel = float(s) / abs(float(v)) if (math.isfinite(float(s)) and float(v) != 0) else None
        out[col] = {"value": _num(v), "stderr": _num(s), "relative_stderr": _num(rel),
                    "status": st, "fixed": bool(f)}
    if result.spec.rheology == "standard":
        g0, g1, eta = (float(result.values[i]) for i in range(3))
        out["G_inf_Pa"] = {"value": _num(g0 * g1 / (g0 + g1)), "derived": True}
        out["tau_s"] = {"value": _num(eta / (g0 + g1)), "derived": True}
    out.update(
        r_squared=_num(result.r_squared), r_squared_contact=_num(result.r_squared_contact),
        reduced_chi2=_num(result.reduced_chi2), chi2=_num(result.chi2),
        aic=_num(result.aic), bic=_num(result.bic),
        n_data=int(result.n_data), n_free=int(result.n_free),
        converged=bool(result.converged), model=result.spec.model,
        rheology=result.rheology, radius_m=_num(result.radius),
        profile=type(result.profile).__name__,
        loading=_loading(result),
        contact_point="fit" if result.spec.contact_offset else "fixed",
        force_offset=bool(result.spec.force_offset),
        model_selection=[{"rheology": m.rheology, "chi2": _num(m.chi2), "k": m.k,
                          "n": m.n, "aic": _num(m.aic), "bic": _num(m.bic),
                          "chosen": m.chosen} for m in result.model_selection],
        optimiser=result.optimiser,
        start_losses=[_num(x) for x in np.asarray(result.start_losses)],
        correlation={"names": list(result.columns),
                     "matrix": [[_num(x) for x in row] for row in result.correlation]},
        warnings=list(result.warnings),
        timings_s={k: float(v) for k, v in result.timings.items()},
        inputs=[_input_info(c) for c in result.curves],
    )
    return out


def _loading(result) -> dict:
    if not result.spec.compliant:
        return {"type": "displacement", "spring_constant_N_m": None}
    return {"type": "compliant",
            "spring_constant_N_m": [float(k) for k in np.asarray(result.data.stiffness)]}


def _input_info(curve) -> dict:
    k = curve.spring_constant
    time = np.asarray(curve.time)
    out = {"source": curve.source, "segments": list(curve.segment_names),
           "samples": len(time), "duration_s": float(time[-1] - time[0]),
           "spring_constant_N_m": None if k is None else float(k), "contact": None}
    c = curve.contact
    if c is not None:
        out["contact"] = {"method": c.method, "time_s": _num(c.time),
                          "baseline": c.baseline, "baseline_region": c.baseline_region,
                          "noise_N": _num(c.noise)}
    return out


def write_samples(result, path) -> pathlib.Path:
    """Write ``fit.csv`` (one row per fitted sample; see the module docstring)."""
    path = pathlib.Path(path)
    data = result.data
    valid = np.asarray(data.valid) > 0
    ts, d, f = (np.asarray(x) for x in (data.ts, data.indentation, data.force))
    seg = np.asarray(data.segment)
    fm = np.asarray(result.model_force)
    res = result.normalised_residuals
    a = np.asarray(result.model_solution.contact_radius)
    weight = np.asarray(data.weight)
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["curve", "segment", "time_s", "indentation_m", "force_N", "model_force_N",
                    "residual", "weight", "contact_radius_m"])
        for c in range(data.n_curves):
            for i in np.flatnonzero(valid[c]):
                w.writerow([c, SEGMENTS[int(seg[c, i])], repr(float(ts[c, i])),
                            repr(float(d[c, i])), repr(float(f[c, i])), repr(float(fm[c, i])),
                            repr(float(res[c, i])),
                            repr(float(weight[c, i])), repr(float(a[c, i]))])
    return path


def write_report(result, out_dir) -> dict[str, pathlib.Path]:
    """Write ``parameters.json``, ``parameters.csv`` and ``fit.csv`` into `out_dir`
    (created if needed). **Returns** the paths by kind ("json", "csv", "samples")."""
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    table = result_table(result)
    paths = {"json": out / "parameters.json", "csv": out / "parameters.csv",
             "samples": out / "fit.csv"}
    paths["json"].write_text(json.dumps(table, indent=2, allow_nan=False) + "\n")
    with paths["csv"].open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["parameter", "unit", "value", "stderr", "relative_stderr", "status",
                    "fixed"])
        for name, unit, col in zip(result.names, result.units, result.columns, strict=True):
            e = table[col]
            w.writerow([name, unit, _cell(e["value"]), _cell(e["stderr"]),
                        _cell(e["relative_stderr"]), e["status"], e["fixed"]])
    write_samples(result, paths["samples"])
    return paths


def _cell(x):
    return "" if x is None else repr(float(x))


_POSITION = (("grid_x", "grid index x", int), ("grid_y", "grid index y", int),
             ("position_x_m", "position x", float), ("position_y_m", "position y", float))


def _each_rows(result) -> list[dict]:
    rows = []
    vals, errs = result.values(), result.stderr()
    for i, (r, e) in enumerate(zip(result.results, result.errors, strict=True)):
        row: dict = {"curve": i, "source": result.sources[i]}
        meta = result.metadata[i]
        for key, mkey, kind in _POSITION:
            v = meta.get(mkey)
            row[key] = None if v is None else (int(v) if kind is int else _num(v))
        for j, col in enumerate(result.columns):
            row[col] = _num(vals[i, j])
            row[f"{col}_stderr"] = _num(errs[i, j])
            row[f"{col}_status"] = r.status[j] if r is not None else "failed"
        row.update(r_squared=_num(r.r_squared) if r is not None else None,
                   r_squared_contact=_num(r.r_squared_contact) if r is not None else None,
                   reduced_chi2=_num(r.reduced_chi2) if r is not None else None,
                   converged=bool(r is not None and r.converged), error=e or "")
        rows.append(row)
    return rows


def write_each_report(result, out_dir) -> dict[str, pathlib.Path]:
    """Write ``map.nc``, ``map.csv`` and ``parameters.json`` of a
    :class:`fitting.FitEachResult` into `out_dir` (see the module docstring). **Returns**
    the paths by kind ("netcdf", "csv", "json")."""
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"netcdf": out / "map.nc", "csv": out / "map.csv", "json": out / "parameters.json"}
    result.to_dataset().to_netcdf(paths["netcdf"], engine="h5netcdf")
    rows = _each_rows(result)
    with paths["csv"].open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(list(rows[0]))
        for row in rows:
            w.writerow(["" if v is None else (repr(v) if isinstance(v, float) else v)
                        for v in row.values()])
    table = {"model": result.model, "rheology": result.rheology,
             "curves": len(result.results), "failed": result.n_failed,
             "converged": result.n_converged, "parameters": list(result.columns),
             "units": list(result.units),
             "timings_s": {k: float(v) for k, v in result.timings.items()},
             "sign_convention": "indentation positive into the sample, compressive force "
                                "positive, adhesion negative",
             "rows": rows}
    paths["json"].write_text(json.dumps(table, indent=2, allow_nan=False) + "\n")
    return paths
