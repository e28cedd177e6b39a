r"""`sweep`: the forward model over a grid or a list of parameter sets, as a labelled dataset."""

from __future__ import annotations

import datetime
import functools
from concurrent.futures import ThreadPoolExecutor

import jax
import numpy as np

from .._solution import RESULTS
from .._solvers import float64_scope
from .._validate import PLAUSIBLE, check_plausible, plain, plausibility_enabled
from .._version import __version__
from ._models import _MIN_TENSION_SAMPLES, AbstractSweepModel, RelaxedStart
from ._parameters import INVALID_REASONS, parameter_info, parse_spec, range_text, scale_factors
from ._run import SUMMARY_FIELDS, default_precision, host_threads, run_points

__all__ = ["sweep", "SUMMARIES"]

#: The per-point summaries of a sweep: variable name -> (scaled quantity, dimension, meaning).
SUMMARIES = {
    "max_tensile_force_N": ("max_tensile_force", "force",
                            "largest tensile force: the most negative force of the history"),
    "jumpoff_force_N": ("jumpoff_force", "force", "force just before the jump-off"),
    "jumpoff_displacement_m": ("jumpoff_displacement", "length",
                               "indentation at the jump-off (positive into the sample)"),
    "jumpoff_time_s": ("jumpoff_time", "time", "time of the jump-off from the start of the lift"),
    "jumpoff_contact_radius_m": ("jumpoff_radius", "length",
                                 "contact radius just before the jump-off"),
    "separation_work_J": ("separation_work", "work",
                          "work done against the adhesive force during the lift: "
                          "integral of max(-F, 0) (-dd) from the start of the lift to the "
                          "jump-off (>= 0)"),
    "lift_duration_s": ("lift_duration", "time",
                        "simulated duration of the lift (duration_factor x the bound of the "
                        "jump-off time)"),
}
_CURVES = {
    "time_s": ("time", "time", "time from the start of the lift (negative before it)"),
    "displacement_m": ("displacement", "length", "indentation d(t), positive into the sample"),
    "force_N": ("force", "force", "normal force F(t), compressive positive, adhesive negative"),
    "contact_radius_m": ("contact_radius", "length", "contact radius a(t), 0 when detached"),
}
_UNITS = {"force": "N", "length": "m", "time": "s", "work": "J"}


def _status_attrs():
    return dict(_status_attrs_once())


@functools.lru_cache(maxsize=1)
def _status_attrs_once():
    items = sorted(RESULTS._name_to_item.items(), key=lambda kv: int(kv[1]._value))
    return dict(
        long_name="status of the point (RESULTS code)",
        flag_values=np.array([int(item._value) for _, item in items], dtype=np.int8),
        flag_meanings=" ".join(name for name, _ in items),
        description="detached and in_contact are successes (in_contact: the point did not "
                    "detach within its lift); the others are errors, whose summaries are NaN",
    )


# sweep dimensions -> the kinds of `jaxcontact.PLAUSIBLE` (angles have none)
_PLAUSIBLE_KIND = {"length": "length", "modulus": "modulus", "viscosity": "viscosity",
                   "time": "time", "adhesion": "work_of_adhesion", "velocity": "velocity"}


def _extremes(a):
    """The smallest nonzero and the largest magnitude of `a` (what `check_plausible` needs to
    accept or refuse it), in two reductions instead of its masks over every entry."""
    a = np.abs(np.atleast_1d(a))
    nonzero_min = np.min(a, where=a != 0, initial=np.inf)
    return np.array([nonzero_min if np.isfinite(nonzero_min) else 0.0, a.max()])


def _point_flags(spec, flags):
    """Per point: the code of the first flagged parameter (1-based, in the order of `flags`;
    0 none) and its `INVALID_REASONS` code; `(None, None)` when nothing is flagged."""
    if not flags:
        return None, None
    param = np.zeros(spec.shape, np.int8)
    reason = np.zeros(spec.shape, np.int8)
    for k, (name, f) in enumerate(flags.items(), start=1):
        if spec.grid:
            axis = spec.dims.index(name)
            f = f.reshape([-1 if i == axis else 1 for i in range(len(spec.shape))])
        f = np.broadcast_to(f, spec.shape)
        new = (f != 0) & (param == 0)
        param[new] = k
        reason[new] = f[new]
    return param.ravel(), reason.ravel()


def _first_problem(spec, flags) -> str:
    name, f = next(iter(flags.items()))
    i = int(np.flatnonzero(f)[0])
    return (f"`{name}` must lie in {range_text(name)} and be plausible; got "
            f"{spec.coords[name][i]!r} (entry {i}: {INVALID_REASONS[int(f[i])]}).")


@functools.partial(jax.jit, static_argnames="family")
def _touch_radius(family, value, depth):
    """The contact radius at `depth` of the profile `family` with its parameter `value` (one
    compiled call: built eagerly, the profile and its radius cost ~0.8 ms of dispatches)."""
    return family.build({family.name: value}).contact_radius(depth)


@functools.lru_cache(maxsize=32)
def _model_repr(model) -> str:
    # equinox's pretty printer walks the whole module: once per model, not once per call
    return repr(model)


@float64_scope
def sweep(
    grid=None,
    *,
    points=None,
    model: AbstractSweepModel = RelaxedStart(),
    curves: bool = False,
    precision: str | None = None,
    chunk_size: int | None = None,
    memory_limit: int | None = None,
    progress: bool = True,
    on_error: str = "raise",
):
    r"""Run a forward model over a grid or a list of parameter sets.

    **Arguments:**

    - `grid`: a mapping from parameter names to values; a scalar is fixed, a 1-D array is
      swept. The result has one dimension per swept parameter, in the order given (the
      outer product of the swept values).
    - `points`: instead of `grid`, a list of parameter sets (mappings with the same names) or
      a mapping of equal-length 1-D arrays (and scalars, fixed): one dimension `point`.
    - `model`: `RelaxedStart(...)` (default; `retract`; its summaries are exact and
      computed without samples) or `ApproachHoldLift(...)` (`simulate`; summaries from the
      samples): the protocol, the samples per curve and how long the lift lasts
      (`duration_factor` times a bound of the jump-off time that every point reaches; see
      `jaxcontact._sweep._models`).
    - `curves`: also return the full curves (`time_s`, `displacement_m`, `force_N`,
      `contact_radius_m`, with a last dimension `sample`).
    - `precision`: `"float32"` or `"float64"`; default float32 on accelerators, float64 on the
      CPU. Every point is computed in its own units (depth, lift speed and relaxed modulus
      are 1), so float32 keeps its relative accuracy at any physical scale: the relaxed
      start's summaries within 2e-6 of float64; the full history's forces within 1e-2 at
      the 99th percentile, rare curves up to 3e-2 (`simulate`'s event refinement; measured
      2.8e-2 on a GPU; `benchmarks/results/sweep.md` §7): float64 where every curve must be
      within 1e-2.
    - `chunk_size`: curves per compiled call (rounded up to a multiple of the number of
      devices); default from `memory_limit`.
    - `memory_limit`: bytes per device a chunk may use (default: half the device memory where
      the backend reports it, else the model's `cpu_chunk_budget`: for `RelaxedStart`
      8 MiB, 32 MiB with `curves`; 512 MiB for `ApproachHoldLift`).
    - `progress`: print a progress line on stderr (process 0 only).
    - `on_error`: `"raise"` (default): a swept value outside its allowed range (or, with the
      plausibility checks on, outside its plausible range) raises a `ValueError` naming the
      parameter; `"status"`: such a point gets `status = invalid_input` and NaN summaries,
      the others are computed, and the dataset gains `invalid_parameter` (which parameter,
      codes in its `flag_meanings`) and `invalid_reason` (why: not finite, below or above
      its range, implausible). A fixed parameter out of range, or every point bad, still
      raises.

    Parameter names (SI units; see `jaxcontact._sweep._parameters`): the material `G0`,
    `G1`, `eta1` (standard model) or `G_inf`, `G_1`, `tau_1`, ... (Prony series; `G_inf`
    alone: elastic); the indenter `R` (paraboloid), `sphere_radius` (exact sphere),
    `half_angle` [rad] (cone) or `punch_radius` (flat punch); `work_of_adhesion`, `depth`,
    `velocity` (lift speed); with `ApproachHoldLift` also `hold` and `approach_velocity`
    (default `velocity`).

    **Returns:** an `xarray.Dataset` with a coordinate per parameter (`units` and
    `long_name` attributes; fixed parameters as scalar coordinates) and, per point,
    `max_tensile_force_N`, `jumpoff_force_N`, `jumpoff_displacement_m`, `jumpoff_time_s`
    (from the start of the lift), `jumpoff_contact_radius_m`, `separation_work_J`
    $= \int_\mathrm{lift}\max(-F, 0)\,(-\mathrm{d}d)$ (the work done against adhesion from
    the start of the lift to the jump-off), `lift_duration_s` and `status` (the `RESULTS`
    code of the point as int8, the codes in its `flag_values` / `flag_meanings`: a failed
    point has an error status and NaN summaries, and never affects the others; a point that
    did not detach within its lift is `in_contact` with NaN jump-off values),
    `separation_work_error_J` (its estimated sampling error: 0 for the exact relaxed start,
    from every sample against every other one for the history) and
    `separation_work_status` (0 `converged`: within the model's `work_rtol`; 1
    `undersampled`: beyond it, the work is then NaN; 2 `none`: no work, NaN: an error
    status or no jump-off within the lift). Signs: force
    compressive positive, adhesive negative; indentation positive into the sample. Save it
    with `ds.to_netcdf("sweep.nc", engine="h5netcdf")`.

    Runs on all devices (`jax.devices()`): the batch of each chunk is sharded over a 1-D
    mesh; after `jax.distributed.initialize` the mesh spans every process, each computes its
    share and every process returns the whole dataset (write it from process 0). See
    `jaxcontact._sweep._run`.
    """
    import xarray as xr

    if not isinstance(model, AbstractSweepModel):
        raise TypeError(f"`model` must be RelaxedStart(...) or ApproachHoldLift(...); got "
                        f"{model!r}.")
    if precision is None:
        precision = default_precision()
    if precision not in ("float32", "float64"):
        raise ValueError(f"`precision` must be 'float32' or 'float64'; got {precision!r}.")
    if chunk_size is not None and (not isinstance(chunk_size, int | np.integer)
                                   or chunk_size < 1):
        raise ValueError(f"`chunk_size` must be a positive integer; got {plain(chunk_size)}.")
    if memory_limit is not None and not memory_limit > 0:
        raise ValueError(f"`memory_limit` [bytes] must be > 0; got {plain(memory_limit)}.")
    if on_error not in ("raise", "status"):
        raise ValueError(f"`on_error` must be 'raise' or 'status'; got {on_error!r}.")
    spec = parse_spec(grid, points, required=model.required, optional=model.optional,
                      on_error=on_error)
    n_points = spec.size

    # ---- plausibility of the SI inputs (the run itself works in scaled units) ----------------
    # every point's value is a coordinate value or a fixed one: those are checked (a grid's
    # points are never expanded for it), by their extremes (two reductions per array). With
    # `on_error="status"` an implausible swept value flags its points here, before the run;
    # with "raise" the checks run while the first chunk computes (`while_running` below:
    # they need no result, and the error is raised before anything is returned)
    flags = dict(spec.flags)
    checked = []  # (name, values, plausibility kind) of every input with a plausible range
    if plausibility_enabled():
        values = [*spec.coords.items(), *((n, np.float64(a)) for n, a in spec.fixed.items())]
        checked = [(n, a, _PLAUSIBLE_KIND[parameter_info(n).kind]) for n, a in values
                   if parameter_info(n).kind in _PLAUSIBLE_KIND]
    if on_error == "status":
        for n, a, kind in checked:
            if np.ndim(a) == 0:
                check_plausible(n, _extremes(a), kind)
                continue
            lo, hi, _ = PLAUSIBLE[kind]
            mag = np.abs(a)
            implausible = (mag != 0) & np.isfinite(mag) & ((mag < lo) | (mag > hi))
            if implausible.any():
                f = flags.get(n, np.zeros(a.shape, np.int8)).copy()
                f[implausible & (f == 0)] = 4
                flags[n] = f

    def check_plausibility():  # on_error="raise": a unit mistake raises, naming its input
        if on_error != "raise" or not checked:
            return
        for n, a, kind in checked:
            check_plausible(n, _extremes(a), kind)
        # the contact radius at the deepest point of the flattest profile (it grows with the
        # depth and with every profile parameter: R, a cone's half-angle, a punch's radius)
        # is a length too: a profile so flat that the contact would be kilometres wide (a
        # cone's half-angle near pi/2) is a unit mistake
        ext = {n: (np.max(a) if np.ndim(a) else a)
               for n, a in {**spec.coords, **spec.fixed}.items()}
        touch = _touch_radius(spec.profile, ext[spec.profile.name], ext["depth"])
        check_plausible("the contact radius at `depth`", touch, "length", magnitude=True)

    bad_param, bad_reason = _point_flags(spec, flags)
    good = None if bad_param is None else bad_param == 0
    if good is not None and not good.any():
        raise ValueError("every point of the sweep has a parameter outside its range: "
                         + _first_problem(spec, flags))

    # ---- the points in their own units (float64), chunk by chunk -----------------------------
    v = spec.values
    names = tuple(sorted(v))
    dims_of = {n: parameter_info(n).kind for n in names}
    substitute = 0 if good is None else int(np.flatnonzero(good)[0])

    @np.errstate(all="ignore")  # a flagged point's values are replaced below
    def columns(lo, hi):
        def part(a):
            return a[lo:hi] if np.ndim(a) else a

        length = part(v["depth"])
        modulus = spec.material.relaxed_modulus({n: part(a) for n, a in v.items()})
        tref = length / part(v["velocity"])
        out = np.empty((hi - lo, len(names)))
        for j, n in enumerate(names):
            out[:, j] = part(v[n]) / scale_factors(dims_of[n], length, modulus, tref)
        if good is not None and not good[lo:hi].all():
            # a flagged point computes a valid one's values; its results are dropped
            out[~good[lo:hi]] = columns(substitute, substitute + 1)[0]
        return out

    # ---- the dataset: built while the first chunk computes (it does not need the results),
    # its summaries filled in place afterwards --------------------------------------------------
    dims = spec.dims
    built = {}

    def build():
        with np.errstate(all="ignore"):  # flagged points: NaN below
            length = v["depth"]
            modulus = spec.material.relaxed_modulus(v)
            tref = v["depth"] / v["velocity"]
        built["units"] = {"force": modulus * length**2, "length": length, "time": tref,
                          "work": modulus * length**3}
        coords = {}
        for name, values in spec.coords.items():
            info = parameter_info(name)
            dim = name if spec.grid else "point"
            coords[name] = (dim, values, dict(units=info.unit, long_name=info.long_name))
        for name, (dim, values) in spec.derived.items():
            info = parameter_info(name)
            coords[name] = (dim, values, dict(units=info.unit, long_name=info.long_name))
        for name, value in spec.fixed.items():
            info = parameter_info(name)
            coords[name] = ((), value, dict(units=info.unit,
                                            long_name=info.long_name + " (fixed)"))
        data = {}
        for var, (_, kind, meaning) in SUMMARIES.items():
            data[var] = (dims, np.empty(spec.shape), dict(units=_UNITS[kind], long_name=meaning))
        data["status"] = (dims, np.empty(spec.shape, np.int8), _status_attrs())
        data["separation_work_error_J"] = (dims, np.empty(spec.shape), dict(
            units="J", long_name="estimated sampling error of separation_work_J (before it is "
            "withheld): |W(h) - W(2h)| / (2^1.5 - 1) from every sample and every other one; "
            f"inf with fewer than {_MIN_TENSION_SAMPLES} lift samples under tension; 0 for the "
            "exact relaxed start"))
        data["separation_work_status"] = (dims, np.empty(spec.shape, np.int8), dict(
            long_name="whether separation_work_J is within the model's work_rtol",
            work_rtol=float(model.work_rtol), flag_values=np.array([0, 1, 2], np.int8),
            flag_meanings="converged undersampled none",
            description="undersampled: the estimated sampling error exceeds work_rtol times "
                        "the work, which is then NaN (more `samples` fix it); none: no work, "
                        "NaN (an error status, or no jump-off within the lift)"))
        if bad_param is not None:
            names_flagged = list(flags)
            data["invalid_parameter"] = (dims, bad_param.reshape(spec.shape), dict(
                long_name="the first parameter of the point outside its range (0: none)",
                flag_values=np.arange(len(names_flagged) + 1, dtype=np.int8),
                flag_meanings=" ".join(["none", *names_flagged]),
                ranges="; ".join(f"{n}: {range_text(n)}" for n in names_flagged)))
            data["invalid_reason"] = (dims, bad_reason.reshape(spec.shape), dict(
                long_name="why that parameter was refused (0: valid point)",
                flag_values=np.arange(len(INVALID_REASONS) + 1, dtype=np.int8),
                flag_meanings=" ".join(["valid", *(m.split(" (")[0].replace(" ", "_")
                                                    for m in INVALID_REASONS.values())]),
                description="; ".join(f"{k}: {m}" for k, m in INVALID_REASONS.items())))
        attrs = dict(
            title="jaxcontact forward sweep",
            model=model.name,
            model_repr=_model_repr(model),
            samples=int(model.samples),
            duration_factor=float(model.duration_factor),
            precision=precision,
            chunk_size=0,  # the run's values: set below
            devices=0,
            processes=0,
            jaxcontact_version=__version__,
            created=datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            conventions="SI units; indentation positive into the sample; force compressive "
                        "positive, adhesive negative; moduli are shear moduli of an "
                        "incompressible half-space",
        )
        if hasattr(model, "cells"):
            attrs["cells"] = int(model.cells)
        built["ds"] = xr.Dataset(data, coords=coords, attrs=attrs)

    def while_running():  # the host's work that needs no result, while the first chunk runs
        build()
        check_plausibility()

    packed, curve_data, run_info = run_points(
        model, spec.material, spec.profile, names, n_points, columns,
        dtype=np.dtype(precision), curves=curves, chunk_size=chunk_size,
        memory_limit=memory_limit, progress=progress, while_running=while_running,
    )
    ds, units = built["ds"], built["units"]
    ds.attrs.update(chunk_size=int(run_info["chunk_size"]), devices=int(run_info["devices"]),
                    processes=int(run_info["processes"]))

    def flat(var):
        """The dataset's own array of `var`, as a flat view to write the results into."""
        target = ds.variables[var].data
        assert target.flags.c_contiguous  # np.empty above: reshape is a view
        return target.reshape(-1)

    row = {f: i for i, f in enumerate(SUMMARY_FIELDS)}
    status = flat("status")
    status[...] = packed[row["status"]]
    if good is not None:
        status[~good] = int(RESULTS.invalid_input._value)
    failed = (status != int(RESULTS.detached._value)) & (status != int(RESULTS.in_contact._value))
    any_failed = bool(failed.any())

    # each summary in float64 and its SI unit in one pass, straight into the dataset (large
    # sweeps: the fields side by side in threads; numpy releases the GIL)
    def si(item):
        var, (field, kind, _) = item
        x = flat(var)
        np.multiply(packed[row[field]], units[kind], out=x, dtype=np.float64)
        if any_failed:
            x[failed] = np.nan

    threads = min(len(SUMMARIES), host_threads(n_points))
    if threads > 1:
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(si, SUMMARIES.items()))
    else:
        for item in SUMMARIES.items():
            si(item)
    # the separation work's sampling error (the history model; 0 for the exact relaxed start)
    work = flat("separation_work_J")
    error = flat("separation_work_error_J")
    np.multiply(packed[row["separation_work_error"]], np.abs(units["work"]), out=error,
                dtype=np.float64)
    rtol = float(model.work_rtol)
    with np.errstate(invalid="ignore"):
        converged = error <= rtol * np.abs(work)
    # none where there is no work or no estimate (no jump-off within the lift: the work
    # would stop short of it)
    has_work = np.isfinite(work) & ~np.isnan(error)
    work_status = flat("separation_work_status")
    work_status[...] = np.where(has_work, np.where(converged, 0, 1), 2)
    work[work_status != 0] = np.nan  # a work the samples cannot give within `work_rtol`
    error[failed] = np.nan
    if curves:
        for var, (field, kind, meaning) in _CURVES.items():
            # in place: the curves are large (10^5 x 500 samples: 400 MB per field), and a
            # fresh array per operation costs its page faults (4.6 of 6.8 s there)
            x = curve_data[field].astype(np.float64, copy=False)
            np.multiply(x, np.reshape(units[kind], (-1, 1)), out=x)
            if good is not None:
                x[~good] = np.nan
            ds[var] = (dims + ("sample",), x.reshape(spec.shape + (x.shape[-1],)),
                       dict(units=_UNITS[kind], long_name=meaning))
    return ds
