r"""Many independent fits with shared settings: force maps, QI series, folders of curves
(:func:`fit_each`).

Every curve is its own problem (its own parameters, data scales, bounds and starts, as
:func:`fitting.fit` would make them for that curve alone). The problems run in chunks of
`chunk` curves; a chunk is one compiled call of :func:`fitting.solve_batch` (all starts of
all its curves scheduled as one pool of lanes, spread over the local devices), padded to a
common number of samples and, for the last chunk, to the chunk size, so that every chunk
reuses one compilation. The local rounds of :func:`fit` follow (starts around each curve's
best end points, the same compiled call; they stop when no curve of the chunk improves).
Then each curve's best start is finished as in :func:`fit` (uncertainty, $R^2$,
warnings): a curve fitted here ends where :func:`fit` on that curve alone ends.

Failures are isolated per curve: a curve that cannot be loaded (a
:class:`fitting.FailedCurve` from ``load_afm(..., on_error="keep")``), prepared (no
contact, too few samples) or finished is a failed point with its reason; the others are
not affected.

The result (:class:`FitEachResult`) is a list of :class:`FitResult` and a labelled
:class:`xarray.Dataset` (:meth:`FitEachResult.to_dataset`): one row per curve with the
map's grid indices and positions when the file has them, each parameter with its standard
error and status, $R^2$, $R^2$ in contact, reduced $\chi^2$, convergence and the reason of
a failure; each curve's status (ok, flagged, failed), flags, warnings and fit quality per
segment, and the settings (:func:`fitting._report.map_columns`, attributes from
:func:`fitting._report.map_settings`).
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Mapping, Sequence

import jax
import numpy as np

from jaxcontact._processes import gather_objects
from jaxcontact._progress import Progress

from ._curve import Curve
from ._io_afm import FailedCurve
from ._optimise import identify
from ._options import BatchOptions, FitOptions, keyword_signature, split_keywords
from ._prepare import contact_point_mode
from ._quality import warn_summary
from ._result import FitResult
from ._spec import parameter_info, rheology_name

__all__ = ["fit_each", "FitEachResult"]

#: Metadata keys of a map position (afmformats' names) and their dataset names.
_POSITION_KEYS = (("grid index x", "grid_x", ""), ("grid index y", "grid_y", ""),
                  ("position x", "position_x", "m"), ("position y", "position_y", "m"))


@dataclasses.dataclass
class FitEachResult:
    """The outcome of :func:`fit_each`: one entry per curve given, in order.

    **Fields:** `results` (a :class:`FitResult`, or `None` for a failed curve), `errors`
    (`None`, or the reason a curve failed), `sources`, `metadata` (per curve), `names`,
    `units`, `columns` (parameter names, units, names with units), `model`, `rheology`,
    `timings` [s] (prepare, optimise, finish, total; optimise: the time the pipeline
    waited for the searches, which overlap each other and the finish).
    """

    results: list[FitResult | None]
    errors: list[str | None]
    sources: list[str]
    metadata: list[Mapping]
    names: list[str]
    units: list[str]
    columns: list[str]
    model: str
    rheology: str
    timings: dict

    @property
    def n_failed(self) -> int:
        """Curves without a result."""
        return sum(e is not None for e in self.errors)

    @property
    def n_converged(self) -> int:
        """Curves whose fit converged."""
        return sum(r is not None and r.converged for r in self.results)

    def values(self) -> np.ndarray:
        """Parameter values, shape `(curves, parameters)` (nan for failed curves)."""
        return np.array([r.values if r is not None else np.full(len(self.names), np.nan)
                         for r in self.results], dtype=float)

    def stderr(self) -> np.ndarray:
        """Standard errors, shape `(curves, parameters)` (see :class:`FitResult`)."""
        return np.array([r.stderr if r is not None else np.full(len(self.names), np.nan)
                         for r in self.results], dtype=float)

    def surface_heights(self) -> tuple[np.ndarray, np.ndarray]:
        """The sample's surface height at each curve's contact [m] and its standard error,
        each of shape `(curves,)` (:meth:`fitting.FitResult.surface_height`: the map's
        topography in the instrument's frame; nan for a failed curve and for files whose
        heights are relative to each curve's start)."""
        pairs = [r.surface_height() if r is not None else (np.nan, np.nan)
                 for r in self.results]
        return (np.array([p[0] for p in pairs], dtype=float),
                np.array([p[1] for p in pairs], dtype=float))

    def to_dataset(self):
        """An :class:`xarray.Dataset` with dimension ``curve`` (see the module docstring).

        Variables: per parameter ``<name>_<unit>`` (value), ``..._stderr`` and
        ``..._status`` ("ok", "fixed", "not determined", "at lower/upper bound", "failed");
        ``r_squared``, ``r_squared_contact``, ``reduced_chi2``, ``converged``, ``error``
        (empty when fitted). Coordinates: ``curve`` (index in the input), ``source``, and
        ``grid_x``, ``grid_y`` (map indices), ``position_x``, ``position_y`` [m] when the
        curves' metadata have them. Units in each variable's ``units`` attribute. Save with
        ``ds.to_netcdf(path, engine="h5netcdf")``; :meth:`grid` arranges a map on
        ``(grid_y, grid_x)``.
        """
        import xarray as xr

        n = len(self.results)
        vals, errs = self.values(), self.stderr()
        data = {}
        for j, (col, unit) in enumerate(zip(self.columns, self.units, strict=True)):
            status = [r.status[j] if r is not None else "failed" for r in self.results]
            data[col] = ("curve", vals[:, j], {"units": unit})
            data[f"{col}_stderr"] = ("curve", errs[:, j], {"units": unit})
            data[f"{col}_status"] = ("curve", np.array(status, dtype=str))

        def per(attr, fill=np.nan):
            return np.array([getattr(r, attr) if r is not None else fill
                             for r in self.results])

        data["r_squared"] = ("curve", per("r_squared").astype(float), {"units": "1"})
        data["r_squared_contact"] = ("curve", per("r_squared_contact").astype(float),
                                     {"units": "1"})
        data["reduced_chi2"] = ("curve", per("reduced_chi2").astype(float), {"units": "1"})
        data["converged"] = ("curve", per("converged", False).astype(bool))
        data["error"] = ("curve", np.array([e or "" for e in self.errors], dtype=str))
        from ._report import map_columns, map_settings

        for key, values in map_columns(self).items():  # status, flags, quality, settings
            arr = np.asarray(values)
            data[key] = ("curve", arr.astype(str) if arr.dtype.kind in "OU" else arr)
        coords = {"curve": np.arange(n), "source": ("curve", np.array(self.sources, dtype=str))}
        for key, name, unit in _POSITION_KEYS:
            got = [m.get(key) for m in self.metadata]
            if all(v is not None for v in got):
                coords[name] = ("curve", np.asarray(got, dtype=int if not unit else float),
                                {"units": unit} if unit else {})
        return xr.Dataset(data, coords=coords, attrs={
            "model": self.model, "rheology": self.rheology,
            "curves": n, "failed": self.n_failed, "converged": self.n_converged,
            "sign_convention": "indentation positive into the sample, compressive force "
                               "positive, adhesion negative",
            **{k: (json.dumps(v) if isinstance(v, dict | bool) else v)
               for k, v in map_settings(self).items() if v is not None}})

    def grid(self):
        """The dataset arranged on ``(grid_y, grid_x)`` (a force map); `ValueError` if the
        curves have no grid indices or two share a grid point."""
        ds = self.to_dataset()
        if "grid_x" not in ds.coords or "grid_y" not in ds.coords:
            raise ValueError("the curves have no grid indices (not a force map)")
        pairs = list(zip(ds["grid_y"].values.tolist(), ds["grid_x"].values.tolist(),
                         strict=True))
        if len(set(pairs)) != len(pairs):
            raise ValueError("two curves share a grid point; no map")
        keep = [v for v in ds.data_vars]
        ds = ds.drop_vars([c for c in ("source", "position_x", "position_y")
                           if c in ds.coords])
        return ds.set_index(curve=["grid_y", "grid_x"]).unstack("curve")[keep]

    def summary(self) -> str:
        """Counts, the median of each parameter with its status, the warnings by kind and
        one line per curve (:func:`fitting._report.each_summary`)."""
        from ._report import each_summary

        return each_summary(self)

    def __str__(self) -> str:
        return self.summary()


@keyword_signature(FitOptions, BatchOptions)
def fit_each(curves: Sequence[Curve | FailedCurve], *, options: FitOptions | None = None,
             batch: BatchOptions | None = None, **keywords) -> FitEachResult:
    r"""Fit every curve on its own, with shared settings, in batched compiled calls.

    **Arguments:**

    - `curves`: :class:`Curve` objects, and :class:`FailedCurve` records for curves that
      could not be loaded (they are reported, not fitted).
    - `options`: a :class:`fitting.FitOptions`, or its fields as keywords: the options of
      :func:`fitting.fit`, with the same meaning, applied to each curve alone (`rheology`
      "standard", "elastic" or "prony:N", nested per curve; "auto" is not offered: a map
      needs one model for all points; one `spring_constant` for all curves, or `None`).
    - `batch`: a :class:`fitting.BatchOptions`, or its fields as keywords (`chunk`: curves
      per compiled call; `workers`: lanes of the pool per device; `devices`; `streams`:
      chunks searched at once, by default one per CPU core, without changing any result):
      how the fits are scheduled, which :func:`fitting.fit` does not need.

    A keyword given beside `options` or `batch` must agree with it.

    How it relates to :func:`fitting.fit`: both run one pipeline
    (:func:`fitting._optimise.identify`); here every curve is its own problem, where
    :func:`fitting.fit` makes one problem of all its curves (a joint fit). A curve fitted
    here ends where :func:`fitting.fit` of that curve alone ends (a chunk runs its local
    rounds while any of its curves improves, so a curve may get more rounds than alone,
    never a worse optimum).

    Several processes (after `jax.distributed.initialize`; every process calls `fit_each`
    with the same curves and options, as any multi-process JAX program): each fits every
    P-th curve on its own devices, and every process returns all results
    (:func:`jaxcontact._processes.gather_objects`; `timings` are the slowest process's).

    **Returns:** a :class:`FitEachResult` (`.to_dataset()`, `.grid()`, `.summary()`).

    **Raises:** `ValueError` naming the argument for bad options, or when no curve can be
    fitted (the reasons are listed); `TypeError` for an unknown keyword. A curve that
    fails is reported in the result.
    """
    items = list(curves)
    if not items or not all(isinstance(c, Curve | FailedCurve) for c in items):
        raise ValueError("curves: give a non-empty list of Curve (or FailedCurve) objects")
    fit_kw, batch_kw = split_keywords(keywords, FitOptions, BatchOptions, where="fit_each")
    options = FitOptions.merge(options, fit_kw, where="fit_each").check_each_curve_alone()
    batch = BatchOptions.merge(batch, batch_kw, where="fit_each")
    errors: list[str | None] = [c.reason if isinstance(c, FailedCurve) else None
                                for c in items]
    good = [i for i, c in enumerate(items) if isinstance(c, Curve)]
    if not good:
        raise ValueError("curves: none could be loaded: "
                         + "; ".join(f"curve {i}: {e}" for i, e in enumerate(errors)))
    t_start = time.perf_counter()
    # several processes (after `jax.distributed.initialize`): each fits every P-th curve
    # on its own devices, and every process gets all results
    n_proc, rank = jax.process_count(), jax.process_index()
    mine = good[rank::n_proc]
    if n_proc > 1 and options.contact_point is None:  # decided over all curves, as alone
        mode = contact_point_mode(None, [items[i] for i in good])
        options = options.replace(contact_point="fit" if mode == "fit" else "detect")
    show = Progress(options.progress and rank == 0, "fit-each",
                    total=len(mine)).stage  # (stage, done)
    out = identify([[items[i]] for i in mine], options, batch, isolate=True, warn=False,
                   progress=show)  # warnings summarised below
    got = {i: (out.errors[g], out.final(g)) for g, i in enumerate(mine)}
    spec, timings = out.spec, dict(out.timings)
    if n_proc > 1:
        parts = gather_objects((got, spec, timings))
        got = {i: v for part, _, _ in parts for i, v in part.items()}
        spec = next((sp for _, sp, _ in parts if sp is not None), None)
        timings = {k: max(t[k] for _, _, t in parts) for k in timings}  # the slowest
    results: list[FitResult | None] = [None] * len(items)
    for i in good:
        errors[i], results[i] = got[i]
    info = parameter_info(spec) if spec is not None else []
    timings = dict(timings, total=time.perf_counter() - t_start)
    warn_summary(results)  # each curve's warnings are in its result: one warning per kind
    return FitEachResult(
        results=results, errors=errors,
        sources=[c.source for c in items],
        metadata=[dict(c.metadata) for c in items],
        names=[n for n, _, _ in info], units=[u for _, u, _ in info],
        columns=[f"{n}_{u}" for n, u, _ in info], model=options.model,
        rheology=rheology_name(spec) if spec is not None else options.rheology,
        timings=timings)
