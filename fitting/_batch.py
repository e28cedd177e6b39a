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
import jax.numpy as jnp
import numpy as np

import jaxcontact as jc
from jaxcontact._progress import Progress
from jaxcontact._validate import plain

from ._curve import Curve
from ._io_afm import FailedCurve
from ._least_squares import Solution
from ._optimise import (
    DEFAULT_LOCAL_ROUNDS,
    _compile_in_background,
    _finish,
    _local_search,
    _model_at,
    _options,
    _problem,
    solve_batch,
)
from ._prepare import stack_batches
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
    `timings` [s] (prepare, optimise, finish, total).
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


def _message(exc: BaseException) -> str:
    text = str(exc) if isinstance(exc, ValueError) else f"{type(exc).__name__}: {exc}"
    return " ".join(text.split())


def fit_each(
    curves: Sequence[Curve | FailedCurve],
    *,
    radius: float | None = None,
    profile: jc.AbstractProfile | None = None,
    model: str = "relaxed",
    rheology: str = "standard",
    spring_constant: float | None = None,
    initial: Mapping[str, float] | None = None,
    fixed: Mapping[str, float] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    contact_point: str | None = None,
    force_offset: bool = False,
    n_starts: int | None = None,
    max_samples: int | None = None,
    indentation_range: tuple[float, float] | None = None,
    segments: Sequence[str] | str | None = None,
    cells: int = 32,
    max_steps: int = 200,
    optimiser: str = "lm",
    rtol: float = 1e-8,
    seed: int = 0,
    local_rounds: int = DEFAULT_LOCAL_ROUNDS,
    chunk: int = 8,
    workers: int | None = None,
    devices=None,
    progress: bool = True,
) -> FitEachResult:
    r"""Fit every curve on its own, with shared settings, in batched compiled calls.

    **Arguments:** `curves` (:class:`Curve` objects, and :class:`FailedCurve` records for
    curves that could not be loaded: they are reported, not fitted); the options of
    :func:`fitting.fit` (the same meaning, applied to each curve alone; `rheology` is
    "standard", "elastic" or "prony:N", nested per curve as in :func:`fit`; "auto" is not offered: a
    map needs one model for all points); `chunk` (curves per compiled call; every chunk
    has this shape, so one compilation serves all); `workers` (lanes of the pool per
    device; default: all starts of the chunk, at most 64); `devices` (see
    :func:`fitting.solve_batch`); `progress` (stages on stderr).

    **Returns:** a :class:`FitEachResult` (`.to_dataset()`, `.grid()`, `.summary()`).

    **Raises:** `ValueError` naming the argument for bad options, or when no curve can be
    fitted (the reasons are listed). A curve that fails is reported in the result.
    """
    items = list(curves)
    if not items or not all(isinstance(c, Curve | FailedCurve) for c in items):
        raise ValueError("curves: give a non-empty list of Curve (or FailedCurve) objects")
    if rheology == "auto":
        raise ValueError("rheology: 'auto' is not offered by fit_each (a map needs one model "
                         "for all points); choose 'standard' or 'prony:N'")
    if not (isinstance(chunk, int | np.integer) and chunk >= 1):
        raise ValueError(f"chunk must be an integer >= 1; got {plain(chunk)}")
    if workers is not None and not (isinstance(workers, int | np.integer) and workers >= 1):
        raise ValueError(f"workers must be an integer >= 1; got {plain(workers)}")
    if spring_constant is not None and np.ndim(spring_constant) != 0:
        raise ValueError("spring_constant: give one value for all curves (or None: each "
                         "curve's own)")
    errors: list[str | None] = [c.reason if isinstance(c, FailedCurve) else None
                                for c in items]
    good = [i for i, c in enumerate(items) if isinstance(c, Curve)]
    if not good:
        raise ValueError("curves: none could be loaded: "
                         + "; ".join(f"curve {i}: {e}" for i, e in enumerate(errors)))
    _, opts, chain = _options(
        [items[i] for i in good], radius=radius, profile=profile, model=model,
        rheology=rheology, spring_constant=spring_constant, initial=initial, fixed=fixed,
        bounds=bounds, contact_point=contact_point, force_offset=force_offset,
        n_starts=n_starts, max_samples=max_samples, cells=cells, max_steps=max_steps,
        optimiser=optimiser, rtol=rtol, seed=seed, local_rounds=local_rounds,
        indentation_range=indentation_range, segments=segments)
    t_start = time.perf_counter()
    timings = {"prepare": 0.0, "optimise": 0.0, "finish": 0.0}
    show = Progress(progress, "fit-each", total=len(items)).stage  # (stage, done)
    results: list[FitResult | None] = [None] * len(items)
    previous: dict[int, FitResult] = {}
    spec = None
    for rh in chain:
        t0 = time.perf_counter()
        problems = {}
        for i in good:
            if errors[i] is not None:
                continue
            try:
                problems[i] = _problem([items[i]], rheology=rh, previous=previous.get(i),
                                       host=True, **opts)
            except (ValueError, ArithmeticError) as exc:
                errors[i] = _message(exc)
        timings["prepare"] += time.perf_counter() - t0
        if not problems:
            break
        idx = list(problems)
        spec = problems[idx[0]].spec
        length = max(problems[i].data.ts.shape[1] for i in idx)
        n_z = max(len(problems[i].zs) for i in idx)
        for i in idx:  # one shape for all: padded samples, equal numbers of starts
            pb = problems[i]
            zs = np.concatenate([pb.zs, np.repeat(pb.zs[:1], n_z - len(pb.zs), axis=0)])
            problems[i] = dataclasses.replace(pb, data=stack_batches([pb.data], length,
                                                                   host=True),
                                              zs=zs)
        pb0 = problems[idx[0]]  # the finish's forward model compiles during the search
        model_at = _compile_in_background(
            _model_at, pb0.spec, pb0.param, jnp.asarray(pb0.param.internal_host(pb0.zs[0])),
            pb0.data)
        size = min(chunk, len(idx))
        lanes = workers if workers is not None else min(64, size * n_z)
        for c0 in range(0, len(idx), size):
            part = idx[c0:c0 + size]
            fill = part + [part[-1]] * (size - len(part))  # the last chunk padded
            t0 = time.perf_counter()
            params = _stack([problems[i].param for i in fill], n_z)
            datas = _stack([problems[i].data for i in fill], n_z)

            solve = dict(spec=spec, params=params, datas=datas, n_z=n_z, workers=lanes,
                         rtol=float(rtol), max_steps=int(max_steps), optimiser=optimiser,
                         devices=devices)

            def run(starts, limits, solve=solve):
                return _run_chunk(starts, limits=np.concatenate(limits), **solve)

            outs = run([problems[i].zs for i in fill],
                       [np.full(n_z, int(max_steps), dtype=np.int32)] * len(fill))
            # as in `fit`, for each curve (a curve whose rounds are done is not run)
            outs = _local_search([problems[i].param for i in fill], outs, run, n=n_z,
                                 local_rounds=opts["local_rounds"], seed=seed,
                                 max_steps=int(max_steps))
            model_at.join()
            timings["optimise"] += time.perf_counter() - t0
            t0 = time.perf_counter()
            for j, i in enumerate(part):
                try:
                    res = _finish(problems[i], [items[i]], opts["profile"], outs[j], optimiser,
                                  show=lambda _m: None, warn=False,  # summarised below
                                  timings={}, t_start=time.perf_counter(),
                                  max_steps=int(max_steps))
                except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
                    errors[i] = _message(exc)
                    continue
                previous[i] = res
                results[i] = res if rh == chain[-1] else None
            timings["finish"] += time.perf_counter() - t0
            show(f"{rheology_name(spec)}", min(c0 + size, len(idx)))
    for i in good:  # a curve that failed in a later step of the chain has no result
        if errors[i] is not None:
            results[i] = None
    info = parameter_info(spec) if spec is not None else []
    timings["total"] = time.perf_counter() - t_start
    warn_summary(results)  # each curve's warnings are in its result: one warning per kind
    return FitEachResult(
        results=results, errors=errors,
        sources=[c.source for c in items],
        metadata=[dict(c.metadata) for c in items],
        names=[n for n, _, _ in info], units=[u for _, u, _ in info],
        columns=[f"{n}_{u}" for n, u, _ in info], model=model,
        rheology=rheology_name(spec) if spec is not None else rheology, timings=timings)


def _run_chunk(z0s, *, spec, params, datas, n_z, optimiser, **kw) -> list[Solution]:
    """The host :class:`Solution` of the `n_z` starts of each problem of a chunk."""
    out = jax.device_get(solve_batch(spec, params, datas, np.concatenate(z0s),
                                     optimiser=optimiser, keep_jacobian=optimiser == "lm",
                                     **kw))
    return [out.take(np.arange(j * n_z, (j + 1) * n_z)) for j in range(len(z0s))]


def _stack(trees, repeat: int):
    """One pytree with a leading problem axis: each of `trees` repeated `repeat` times."""
    host = [jax.device_get(t) for t in trees]
    return jax.device_put(jax.tree.map(lambda *x: np.repeat(np.stack(x), repeat, axis=0),
                                       *host))
