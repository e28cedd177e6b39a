r"""Fit outputs as data: ``parameters.json``, ``parameters.csv``, ``fit.csv``.

``parameters.json`` (strict JSON: no NaN or Infinity; a missing number is ``null`` with the
reason in ``status``): per parameter ``"<name>_<unit>": {"value", "stderr", "stderr_noise",
"relative_stderr", "status", "fixed"}`` (``stderr``: the Gauss–Newton error scaled by
$\sqrt{\chi^2_\mathrm{red}}$, lmfit's ``scale_covar``; ``stderr_noise``: the error the noise
alone would give, ``stderr`` / $\sqrt{\chi^2_\mathrm{red}}$; ``stderr_basis`` says which in
words, ``stderr_scale`` gives the factor); derived quantities with their standard errors
from the covariance and ``"derived": true`` (Young's moduli ``E0_Pa``, ``E1_Pa``,
``E_inf_Pa`` = 3G, incompressible; ``G_inf_Pa``, ``tau_s``; for a Prony series ``G_0_Pa``,
``E_0_Pa``, ``E_inf_Pa``, ``E_k_Pa``; with adhesion Tabor's parameter ``tabor_mu_1``,
:func:`fitting._quality.tabor_entry`); quality (``r_squared`` — weighted by the measured
samples each kept sample stands for, ``r_squared_weighting`` says so —
``r_squared_unweighted``, ``r_squared_contact``, ``reduced_chi2``, ``chi2``, ``aic``,
``bic``, ``n_data``, ``n_free``, ``converged``, ``convergence`` with ``reason`` and
``advice``, ``status`` "ok" or "flagged", ``adequate``, ``flags`` (code → message,
:mod:`fitting._quality`), ``segments``: per fitted segment $R^2$ (weighted and unweighted),
reduced $\chi^2$ and the largest residual in σ); the model (``model``, ``rheology``,
``radius_m``, ``profile`` and ``profile_parameters``, ``loading``, ``contact_point`` and
``force_offset`` choices, ``model_selection`` for ``rheology="auto"``); the search
(``start_losses``, on the search's grid; ``polish_losses``, the search's best end points
continued on the model's own grid when the history model was searched on a coarser one,
else null; ``search``: its settings, ``n_starts``, ``screen``, ``local_rounds``,
``max_steps``, ``explore_steps``, ``abandon``, ``optimiser``, ``rtol``, ``seed``, and for
the history model ``cells``, ``search_cells``); ``correlation``;
``warnings``; ``timings_s``; ``inputs`` (each curve's
source, segments, samples, duration, spring constant, and its detected contact point and
baseline when a loader found them, with the sample's surface height there,
``surface_height_m`` and its standard error: :meth:`fitting.FitResult.surface_height`).

``parameters.csv``: one row per parameter, then one per derived quantity (``derived``
True: Young's moduli E = 3G, G_inf, E_inf, tau, Tabor's mu with errors from the covariance):
``parameter,unit,value,stderr,relative_stderr,status,fixed,stderr_noise,stderr_basis,derived``
(``stderr_basis``: ``noise x sqrt(reduced chi2)``, or ``... (model inadequate)`` when the
residuals are far above the noise).

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
``r_squared,r_squared_contact,reduced_chi2,converged,error``, then the honesty columns of
:func:`map_columns` (``status`` ok/flagged/failed, ``flags``, ``warnings``,
``convergence``, ``r_squared_unweighted``, per segment ``r_squared_<segment>``,
``reduced_chi2_<segment>``, ``max_residual_<segment>``, the derived quantities with their
standard errors: ``E0_Pa``, ``E0_Pa_stderr``, ..., ``G_inf_Pa``, ``E_inf_Pa``,
``tabor_mu_1``), the settings of each curve (``profile``, ``radius_m``,
``contact_point``, ``contact_method``, ``baseline``, ``baseline_region``, ``noise_N``) and
the sample's surface height at the contact (``surface_height_m``,
``surface_height_m_stderr``: :meth:`fitting.FitResult.surface_height`, the map's
topography in the instrument's frame; empty for files whose heights are relative to each
curve's start); empty cells where a value is missing) and
``parameters.json`` (model, counts by status, the settings, the warnings by kind, names
and units, timings, and the rows of ``map.csv`` as objects, strict JSON). ``map.nc`` holds
the same columns as variables and the settings as attributes.

The figures are drawn by the command line layer (``jaxcontact_cli``).
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import pathlib

import numpy as np

from ._prepare import SEGMENTS
from ._quality import warning_kinds

__all__ = ["write_report", "result_table", "write_samples", "write_each_report",
           "map_columns", "map_settings", "each_summary"]


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
        out[col] = {"value": _num(v), "stderr": _num(s),
                    "stderr_noise": _num(float(s) / result.stderr_scale),
                    "relative_stderr": _num(rel), "status": st, "fixed": bool(f)}
    for d in result.derived:
        v, se = d["value"], d["stderr"]
        out[f"{d['name']}_{d['unit']}"] = {
            "value": _num(v), "stderr": _num(se),
            "relative_stderr": _num(se / abs(v)) if v != 0 and math.isfinite(se) else None,
            "status": d["status"], "derived": True, "definition": d["definition"]}
    out.update(
        status="ok" if not result.flags else "flagged", adequate=bool(result.adequate),
        flags=dict(result.flags),
        stderr_basis=result.stderr_basis, stderr_scale=_num(result.stderr_scale),
        r_squared=_num(result.r_squared), r_squared_weighting=_R2_WEIGHTING,
        r_squared_unweighted=_num(result.r_squared_unweighted),
        r_squared_contact=_num(result.r_squared_contact),
        segments=[q.as_dict() for q in result.segments],
        convergence=dict(result.convergence), search=dict(result.search),
        reduced_chi2=_num(result.reduced_chi2), chi2=_num(result.chi2),
        aic=_num(result.aic), bic=_num(result.bic),
        n_data=int(result.n_data), n_free=int(result.n_free),
        converged=bool(result.converged), model=result.spec.model,
        rheology=result.rheology, radius_m=_num(result.radius),
        profile=type(result.profile).__name__,
        profile_parameters=_profile_parameters(result.profile),
        loading=_loading(result),
        contact_point="fit" if result.spec.contact_offset else "fixed",
        force_offset=bool(result.spec.force_offset),
        force_drift=bool(result.spec.force_drift),
        model_selection=[{"rheology": m.rheology, "chi2": _num(m.chi2), "k": m.k,
                          "n": m.n, "aic": _num(m.aic), "bic": _num(m.bic),
                          "chosen": m.chosen} for m in result.model_selection],
        optimiser=result.optimiser,
        start_losses=[_num(x) for x in np.asarray(result.start_losses)],
        polish_losses=None if result.polish_losses is None
        else [_num(x) for x in np.asarray(result.polish_losses)],
        correlation={"names": list(result.columns),
                     "matrix": [[_num(x) for x in row] for row in result.correlation]},
        warnings=list(result.warnings),
        timings_s={k: float(v) for k, v in result.timings.items()},
        inputs=[_input_info(i, c, result) for i, c in enumerate(result.curves)],
    )
    return out


_R2_WEIGHTING = ("each kept sample weighted by the number of measured samples it stands "
                 "for (an estimate of R^2 over all measured samples); r_squared_unweighted "
                 "counts every kept sample once")


def _profile_parameters(profile) -> dict:
    """The probe's parameters in SI units (a tabulated profile: its type only)."""
    out = {}
    for f in dataclasses.fields(profile) if dataclasses.is_dataclass(profile) else []:
        v = np.asarray(getattr(profile, f.name))
        if v.ndim == 0 and np.issubdtype(v.dtype, np.number):
            out[f.name] = _num(v)
    return out


def _loading(result) -> dict:
    if not result.spec.compliant:
        return {"type": "displacement", "spring_constant_N_m": None}
    return {"type": "compliant",
            "spring_constant_N_m": [float(k) for k in np.asarray(result.data.stiffness)]}


def _input_info(i, curve, result) -> dict:
    k = curve.spring_constant
    time = np.asarray(curve.time)
    out = {"source": curve.source, "segments": list(curve.segment_names),
           "samples": len(time), "duration_s": float(time[-1] - time[0]),
           "spring_constant_N_m": None if k is None else float(k), "contact": None}
    c = curve.contact
    if c is not None:
        height, height_se = result.surface_height(i)
        out["contact"] = {"method": c.method, "time_s": _num(c.time),
                          "baseline": c.baseline, "baseline_region": c.baseline_region,
                          "noise_N": _num(c.noise), "surface_height_m": _num(height),
                          "surface_height_m_stderr": _num(height_se)}
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
    a = np.asarray(result.model_contact_radius)
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
                    "fixed", "stderr_noise", "stderr_basis", "derived"])
        basis = "noise x sqrt(reduced chi2)" + ("" if result.adequate else
                                                " (model inadequate)")
        for name, unit, col in zip(result.names, result.units, result.columns, strict=True):
            e = table[col]
            w.writerow([name, unit, _cell(e["value"]), _cell(e["stderr"]),
                        _cell(e["relative_stderr"]), e["status"], e["fixed"],
                        _cell(e["stderr_noise"]), basis if e["stderr"] is not None else "",
                        False])
        for d in result.derived:
            e = table[f"{d['name']}_{d['unit']}"]
            se = e["stderr"]
            w.writerow([d["name"], d["unit"], _cell(e["value"]), _cell(se),
                        _cell(e["relative_stderr"]), e["status"], False,
                        _cell(None if se is None else se / result.stderr_scale),
                        basis if se is not None else "", True])
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
    extra = map_columns(result)
    for i, row in enumerate(rows):
        for key, values in extra.items():
            v = values[i]
            row[key] = _num(v) if isinstance(v, float) else v
    return rows


def _curve_status(r, e) -> str:
    return "failed" if r is None or e else ("flagged" if r.flags else "ok")


def map_columns(result) -> dict[str, list]:
    """The per-curve honesty and settings columns of a :class:`fitting.FitEachResult`
    (``map.csv``, ``map.nc``; see the module docstring): name → one value per curve
    (nan or "" where a curve failed)."""
    nan = float("nan")
    segs = [s for s in SEGMENTS if any(
        r is not None and any(q.segment == s for q in r.segments) for r in result.results)]
    cols: dict[str, list] = {k: [] for k in ("status", "flags", "warnings", "convergence",
                                             "r_squared_unweighted")}
    for s in segs:
        for k in ("r_squared", "reduced_chi2", "max_residual"):
            cols[f"{k}_{s}"] = []
    first = next((r for r in result.results if r is not None), None)
    derived = [f"{d['name']}_{d['unit']}" for d in first.derived] if first is not None else []
    for k in derived:
        cols[k], cols[f"{k}_stderr"] = [], []
    for k in ("profile", "radius_m", "contact_point", "contact_method", "baseline",
              "baseline_region", "noise_N"):
        cols[k] = []
    settings = map_settings(result)
    heights, height_se = result.surface_heights()
    cols["surface_height_m"], cols["surface_height_m_stderr"] = list(heights), list(height_se)
    for r, e, curve in zip(result.results, result.errors, _curves(result), strict=True):
        cols["status"].append(_curve_status(r, e))
        cols["flags"].append(";".join(r.flags) if r is not None else "")
        cols["warnings"].append(" | ".join(r.warnings) if r is not None else "")
        cols["convergence"].append(r.convergence.get("reason", "") if r is not None else "")
        cols["r_squared_unweighted"].append(r.r_squared_unweighted if r is not None else nan)
        got = {f"{d['name']}_{d['unit']}": d for d in r.derived} if r is not None else {}
        for k in derived:
            d = got.get(k)
            cols[k].append(d["value"] if d else nan)
            cols[f"{k}_stderr"].append(d["stderr"] if d else nan)
        by = {q.segment: q for q in r.segments} if r is not None else {}
        for s in segs:
            q = by.get(s)
            cols[f"r_squared_{s}"].append(q.r_squared if q else nan)
            cols[f"reduced_chi2_{s}"].append(q.reduced_chi2 if q else nan)
            cols[f"max_residual_{s}"].append(q.max_residual if q else nan)
        cols["profile"].append(settings.get("profile", ""))
        cols["radius_m"].append(float(settings["radius_m"])
                                if settings.get("radius_m") is not None else nan)
        cols["contact_point"].append(settings.get("contact_point", ""))
        c = getattr(curve, "contact", None)
        cols["contact_method"].append(c.method if c is not None else "")
        cols["baseline"].append(c.baseline if c is not None else "")
        cols["baseline_region"].append(c.baseline_region if c is not None else "")
        cols["noise_N"].append(float(c.noise) if c is not None and c.noise is not None
                               else nan)
    return cols


def _curves(result) -> list:
    return [r.curves[0] if r is not None and r.curves else None for r in result.results]


def map_settings(result) -> dict:
    """The settings shared by every curve of a :class:`fitting.FitEachResult` (from its
    first fitted curve; empty when none was fitted): model, rheology, profile and its
    parameters, radius, contact point (fitted or fixed), force offset, loading, samples."""
    first = next((r for r in result.results if r is not None), None)
    if first is None:
        return {}
    return {"model": first.spec.model, "rheology": first.rheology,
            "profile": type(first.profile).__name__,
            "profile_parameters": _profile_parameters(first.profile),
            "radius_m": _num(first.radius),
            "contact_point": "fit" if first.spec.contact_offset else "fixed",
            "force_offset": bool(first.spec.force_offset),
            "force_drift": bool(first.spec.force_drift),
            "loading": "compliant" if first.spec.compliant else "displacement",
            "max_samples_per_curve": int(np.asarray(first.data.ts).shape[1]),
            "search": dict(first.search),
            "r_squared_weighting": _R2_WEIGHTING,
            "stderr_basis": "Gauss-Newton standard error scaled by sqrt(reduced chi2) "
                            "(lmfit's scale_covar); with the model inadequate (flag "
                            "model_inadequate) not a measurement precision"}


def each_summary(result) -> str:
    """The console summary of a :class:`fitting.FitEachResult`: counts by status, the
    median of each parameter over the curves where it is "ok" (with the counts of every
    status beside it) and, where the heights are the instrument's frame, of the surface
    height with the map's relief, the warnings by kind, and one line per curve (at most
    20)."""
    stat = [_curve_status(r, e) for r, e in zip(result.results, result.errors, strict=True)]
    n = len(stat)
    lines = [f"[[fit each]] model={result.model}, rheology={result.rheology}, {n} curve(s): "
             f"{stat.count('ok')} ok, {stat.count('flagged')} flagged "
             f"({n - stat.count('failed') - result.n_converged} not converged), "
             f"{stat.count('failed')} failed; "
             f"{result.timings.get('total', float('nan')):.1f} s"]
    fitted = [r for r in result.results if r is not None]
    if fitted:
        lines.append("[[medians]] over the curves where the parameter is ok (status counts)")
        for j, col in enumerate(result.columns):
            st = [r.status[j] for r in fitted]
            ok = [float(r.values[j]) for r in fitted if r.status[j] == "ok"]
            counts = ", ".join(f"{k} {st.count(k)}" for k in dict.fromkeys(st))
            med = f"{np.median(ok):12.5g}" if ok else f"{'-':>12}"
            lines.append(f"    {col:<26} {med}   ({counts})")
        r2 = [r.r_squared_contact for r in fitted]
        lines.append(f"    {'R^2 in contact':<26} {np.nanmedian(r2):12.4f}   "
                     f"(weighted; range {np.nanmin(r2):.3g} to {np.nanmax(r2):.3g})")
        heights = result.surface_heights()[0]
        known = heights[np.isfinite(heights)]
        if known.size:
            lines.append(f"    {'surface height [m]':<26} {np.median(known):12.6g}   "
                         f"(relief {np.ptp(known):.3g} m over {known.size} curve(s): the "
                         "topography, in the instrument's frame)")
    kinds = warning_kinds(result.results)
    if kinds:
        lines.append("[[warnings]] by kind (fitted curves with it: an example)")
        lines += [f"    {k}x: {example}" for _, k, example in kinds]
    lines.append("[[curves]]" + (" (the first 20)" if n > 20 else ""))
    for i, (r, e) in enumerate(zip(result.results, result.errors, strict=True)):
        if i >= 20:
            break
        meta = result.metadata[i]
        gx, gy = meta.get("grid index x"), meta.get("grid index y")
        where = f"curve {i} (x {gx}, y {gy})" if gx is not None and gy is not None \
            else f"curve {i}"
        if r is None:
            lines.append(f"    {where}: failed: {e}")
            continue
        vals = ", ".join(f"{nm}={v:.4g}" + ("" if st in ("ok", "fixed") else f" ({st})")
                         for nm, v, st in zip(result.names, r.values, r.status, strict=True))
        lines.append(f"    {where}: {stat[i]}"
                     + (f" [{', '.join(r.flags)}]" if r.flags else "")
                     + f": {vals}; R^2 contact {r.r_squared_contact:.4f}")
    return "\n".join(lines)


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
    stat = [row["status"] for row in rows]
    table = {"model": result.model, "rheology": result.rheology,
             "curves": len(result.results), "failed": result.n_failed,
             "converged": result.n_converged, "ok": stat.count("ok"),
             "flagged": stat.count("flagged"), "settings": map_settings(result),
             "warnings": [{"kind": k, "curves": n, "example": ex}
                          for k, n, ex in warning_kinds(result.results)],
             "parameters": list(result.columns),
             "units": list(result.units),
             "timings_s": {k: float(v) for k, v in result.timings.items()},
             "sign_convention": "indentation positive into the sample, compressive force "
                                "positive, adhesion negative",
             "rows": rows}
    paths["json"].write_text(json.dumps(table, indent=2, allow_nan=False) + "\n")
    return paths
