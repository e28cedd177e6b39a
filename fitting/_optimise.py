r"""Identification: a global search to convergence, then the uncertainty (:func:`fit`).

How :func:`fit` finds the optimum
---------------------------------
1. **Prepare** the curves (:func:`fitting.prepare_curves`): every selected sample, or at
   most `max_samples` per curve, subsampled without averaging (no bias).
2. **Global search.** `n_starts` starts (:func:`fitting._start.search_starts`: the
   data-based guess and a Latin hypercube over physically bounded ranges; for a Prony
   series also the nested starts from the simpler model's optimum) each run to
   convergence (`rtol`, at most `max_steps` iterations) in one compiled call
   (:func:`solve_batch`), scheduled as a pool of lanes
   (:func:`fitting._least_squares.run_pool`: a lane whose start has converged takes the
   next one). Then up to `local_rounds` rounds of as many starts
   around the best end points (:func:`fitting._start.local_starts`: the best continued,
   pattern moves along the line of the best optima, a small Latin hypercube, widened
   after a round without progress), the same compiled call, until the widest round no
   longer lowers $\chi^2$. The smallest $\chi^2$ wins;
   the pool also returns the Jacobian of every end point, so the best one's is reused
   for the uncertainty. With `search_cells` below `cells` the history model is searched
   on that coarser foundation grid (a step costs less), and the best distinct end points
   of that search are continued on `cells` (:func:`_polish`): the result, its $\chi^2$
   and Jacobian are those of the model on `cells`.
3. **Uncertainty** (:func:`fitting._uncertainty.gauss_newton`), statistics ($R^2$ over all
   samples and over the samples in contact, reduced $\chi^2$, AIC, BIC) and warnings
   about the model's validity (contact radius beyond $0.3R$ for a parabola; the relaxed
   model on curves without a hold).

One compilation serves all starts; a second (the forward model alone) gives the model
curves at the optimum for the report.

Nested models: ``rheology="prony:N"`` first fits the standard model (the same as
``prony:1``) and ``prony:2``, …, each starting also from the previous optimum with one arm
added (:func:`fitting._start.nested_starts`), so a richer model never ends worse than
the simpler one it contains. ``rheology="auto"`` fits standard, ``prony:2`` and
``prony:3`` this way and keeps the smallest BIC (AIC and BIC of each are in
``result.model_selection``).

Contact point: with ``contact_point="fit"`` (default for curves whose contact point was
detected by a loader) the indentation offset $\delta$ [m] is a fitted parameter, started
at the detection ($\delta = 0$); ``force_offset=True`` adds a force offset $F_0$ [N],
``force_drift=True`` a line $F_0 + s\,t$ (drift $s$ [N/s], started at 0 in every start).

One pipeline: :func:`fit` and :func:`fitting.fit_each` both run :func:`identify` (their
options one checked :class:`fitting.FitOptions`). :func:`fit` is its case of one problem
(all its curves together, a joint fit), :func:`fitting.fit_each` that of one problem per
curve, in chunks (:class:`fitting.BatchOptions`); every step above (preparation, starts,
global search, local rounds, finish) is the same code for both, each search one call of
:func:`solve_batch`.

Batches: :func:`solve` runs the optimiser from several starts of one problem;
:func:`solve_batch` runs many independent problems in one compiled pool, spread over the
local devices.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import threading
import time
import warnings
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

import jaxcontact as jc
from jaxcontact._progress import Progress

from . import _programs
from ._caller import warn_at_caller
from ._curve import Curve
from ._least_squares import RESULTS, Solution, run_pool, run_starts
from ._objective import (
    ModelAt,
    internal_jacobian,
    residuals,
    residuals_and_model,
    residuals_jacobian,
)
from ._options import (
    POLISHED_POINTS,
    SEARCH_BYTES_PER_RESIDUAL,
    SINGLE,
    BatchOptions,
    FitOptions,
    keyword_signature,
    make_solver,
    padded_indices,
    split_keywords,
)
from ._parameters import Parameterisation, make_parameterisation
from ._prepare import (
    SEGMENTS,
    CurveBatch,
    contact_point_mode,
    prepare_curves,
    retract_ends,
    select_fit_segments,
    stack_batches,
)
from ._quality import (
    assess,
    check_contact_signal,
    r_squared_rows,
    segment_quality_rows,
    tabor_fn,
)
from ._result import FitResult, ModelChoice
from ._spec import (
    ModelSpec,
    make_spec,
    normalise_names,
    parameter_info,
    rheology_kind,
    rheology_name,
)
from ._start import (
    LocalRounds,
    data_scales,
    default_bounds,
    initial_guess,
    local_starts_batch,
    nested_starts,
    probe_radius,
    search_points,
)
from ._uncertainty import (
    IdentifiabilityWarning,
    ModelValidityWarning,
    derived_fn,
    gauss_newton,
)
from ._xla import model_jit, program_options

__all__ = ["fit", "solve", "solve_batch", "identify", "Identified"]


def _fn(spec: ModelSpec):
    """`fn(z, ctx)`: weighted residuals at the free vector `z`, `ctx = (param, data)`."""

    def fn(z, ctx):
        param, data = ctx
        return residuals(param.natural(z), data, spec)

    def with_model(z, ctx):  # the residuals and the model as the fit reports it
        param, data = ctx
        return residuals_and_model(param.natural(z), data, spec)

    def dtype(z, data):
        return jnp.result_type(data.force, data.weight, data.noise, z, float)

    def residual_struct(z, ctx):  # without tracing the model (`residuals`: C*n, flat)
        _, data = ctx
        return jax.ShapeDtypeStruct((math.prod(jnp.shape(data.force)),), dtype(z, data))

    def model_struct(z, ctx):  # the same for `with_model`'s `ModelAt`: each like the data
        _, data = ctx
        one = jax.ShapeDtypeStruct(jnp.shape(data.force), dtype(z, data))
        return ModelAt(one, one, one)

    fn.with_model = with_model
    fn.jacobian = residuals_jacobian(spec)
    fn.residual_struct = residual_struct
    fn.model_struct = model_struct
    return fn


def _solver(optimiser: str, rtol: float, atol: float, gtol: float, max_steps: int):
    return make_solver(optimiser, rtol=rtol, atol=atol, gtol=gtol, max_steps=max_steps)


_OPTIONS = ("rtol", "atol", "gtol", "max_steps", "optimiser", "workers")


@model_jit(static_argnames=_OPTIONS)
def solve(spec: ModelSpec, param: Parameterisation, data: CurveBatch, z0s, *,
          rtol: float = 1e-8, atol: float = 1e-9, gtol: float = 1e-8, max_steps: int = 200,
          optimiser: str = "lm", workers: int | None = None) -> Solution:
    r"""Minimise ½ Σ r² from every row of `z0s`; a :class:`fitting.Solution` per start
    (`z`, `chi2`, `result` codes of :class:`fitting.RESULTS`, `steps`, `converged`).

    **Arguments:** `spec`, `param`, `data` (the problem: residuals
    `residuals(param.natural(z), data, spec)`), `z0s` (starts, shape `(starts, n_free)`),
    `optimiser` ("lm" or "lbfgs"), `rtol` (relative change of $\chi^2$, and for "lm" of the
    step, at which a run has converged), `atol` (absolute step, "lm"), `gtol` (largest
    gradient component relative to the loss, "lbfgs"), `max_steps` (iterations per start),
    `workers` (`None`: one vmapped lane per start; an integer: that many lanes scheduled
    as a pool).
    """
    solver = _solver(optimiser, rtol, atol, gtol, max_steps)
    fn = _fn(spec)
    if workers is None:
        return run_starts(solver, fn, z0s, (param, data))
    n = z0s.shape[0]
    ctxs = jax.tree.map(lambda x: jnp.broadcast_to(x, (n,) + jnp.shape(x)), (param, data))
    return run_pool(solver, fn, z0s, ctxs, workers)


def solve_batch(spec: ModelSpec, params: Parameterisation, datas: CurveBatch, z0s, *,
                workers: int = 8, rtol: float = 1e-8, atol: float = 1e-9, gtol: float = 1e-8,
                max_steps: int = 200, optimiser: str = "lm", devices=None,
                keep_jacobian: bool = False, limits=None, bounds=None,
                traced=None) -> Solution:
    r"""Independent problems in one compiled call, scheduled as a pool of `workers` lanes.

    `params`, `datas` and `z0s` carry a leading problem axis (stack equally shaped problems
    with ``jax.tree.map(lambda *x: jnp.stack(x), *problems)``; the free parameters must be
    the same); one start per problem. Returns a :class:`fitting.Solution` per problem
    (`z`, `chi2`, `result`, `steps`; with `keep_jacobian` also the residuals `r` and their
    Jacobian `J` with respect to `z` at the end point of each, Levenberg–Marquardt only).
    `limits`: a step limit per problem (default `max_steps` for all; 0: not run).
    `bounds`: a bound on each problem's $\chi^2$ (default $\infty$ for all): a run still
    above it after :data:`fitting._least_squares.ABANDON_AFTER` steps is abandoned
    (:attr:`fitting.RESULTS.abandoned`).

    `devices`: the devices to spread the problems over (default: every local device of
    JAX's default backend). With more than one, the problems are split into equal shares
    (the last problem repeated to fill them; its copies are dropped) and every device runs
    its own pool, in one `jax.pmap` call. Results do not depend on the split.

    `traced()`: called once the program is traced, before it is compiled and run (with
    several devices: before the call), so that a caller can start other Python work in a
    thread then: tracing is Python, and two traces in two threads take turns on the GIL.
    """
    devices = list(jax.local_devices() if devices is None else devices)
    if not devices:
        raise ValueError("devices: give at least one device (or None for all local ones)")
    n = z0s.shape[0]
    n_dev = max(1, min(len(devices), n))
    share = -(-n // n_dev)
    # more lanes than a device's problems would idle (the pool takes the smaller number):
    # the same program, so one compilation serves both
    opts = dict(workers=max(1, min(int(workers), share)), rtol=float(rtol), atol=float(atol),
                gtol=float(gtol), max_steps=int(max_steps), optimiser=optimiser,
                keep_jacobian=bool(keep_jacobian))
    limits = np.broadcast_to(np.asarray(max_steps if limits is None else limits,
                                        dtype=np.int32), (n,))
    bounds = np.broadcast_to(np.asarray(np.inf if bounds is None else bounds,
                                        dtype=np.asarray(z0s).dtype), (n,))
    if n_dev == 1:
        with jax.default_device(devices[0]):  # (a part of the key of JAX's trace cache)
            # the traced program from the on-disk cache when it is on (fitting._programs)
            run = _programs.cached("solve_batch", _solve_batch,
                                   (spec, params, datas, jnp.asarray(z0s),
                                    jnp.asarray(limits), jnp.asarray(bounds)), opts,
                                   flatten_out=_solution_fields, unflatten_out=_as_solution,
                                   compiler_options=program_options(spec.model))
            if run is not None:
                if traced is not None:
                    traced()
                return run()
            if traced is not None:  # JAX keeps the trace for the call below
                _solve_batch.trace(spec, params, datas, z0s, limits, bounds, **opts)
                traced()
            return _solve_batch(spec, params, datas, z0s, limits, bounds, **opts)
    if traced is not None:
        traced()
    fill = padded_indices(n, n_dev * share)

    def split(x):
        x = jnp.asarray(x)[fill]
        return x.reshape((n_dev, share) + x.shape[1:])

    run = _pmapped_pool(spec, tuple(devices[:n_dev]), tuple(sorted(opts.items())))
    out = run(jax.tree.map(split, params), jax.tree.map(split, datas), split(z0s),
              split(limits), split(bounds))
    return jax.tree.map(lambda x: x.reshape((n_dev * share,) + x.shape[2:])[:n], out)


def _solution_fields(s: Solution) -> tuple:
    m = (None,) * len(ModelAt._fields) if s.model is None else tuple(s.model)
    return (s.z, s.chi2, s.result, s.steps, s.r, s.J, *m)


def _as_solution(fields) -> Solution:
    m = fields[6:]
    return Solution(*fields[:6], model=None if m[0] is None else ModelAt(*m))


@model_jit(static_argnames=_OPTIONS + ("keep_jacobian",))
def _solve_batch(spec, params, datas, z0s, limits, bounds, *, workers, rtol, atol, gtol,
                 max_steps, optimiser, keep_jacobian):
    solver = _solver(optimiser, rtol, atol, gtol, max_steps)
    if keep_jacobian:  # and the model at the end points, where the solver can carry it
        solver = solver.with_model() or solver
    return run_pool(solver, _fn(spec), z0s, (params, datas), workers, limits=limits,
                    bounds=bounds, keep_jacobian=keep_jacobian)


@functools.lru_cache(maxsize=16)
def _pmapped_pool(spec, devices, opts):
    # every device runs `_solve_batch` on its share
    return jax.pmap(lambda p, d, z, lim, b: _solve_batch(spec, p, d, z, lim, b, **dict(opts)),
                    devices=list(devices))


def _model_at(spec, param, u, data) -> ModelAt:
    """The model at internal coordinates `u` as the fit reports it (:class:`ModelAt`)."""
    return residuals_and_model(param.to_natural(u), data, spec)[1]


@functools.partial(jax.jit, static_argnames=("tabor", "model"))
def _evaluate_chunk(spec, params, us, ps, datas, radius, *, tabor, model=True):
    """The finish's device work of a chunk in one compiled call, vmapped over its problems
    (leading axis of `params`, `us` [internal], `ps` [natural], `datas`): with `model`
    the model at the optimum (:func:`_model_at`; without, `None`: the search's solver
    carried it, :attr:`Solution.model`), the derived
    quantities with their Jacobian (:func:`fitting._uncertainty.derived_fn`) and, with
    `tabor` (the index of the work of adhesion; `None`: not computed), Tabor's parameter at
    `radius` [m] with its gradient (:func:`fitting._quality.tabor_fn`)."""
    model = jax.vmap(_model_at, in_axes=(None, 0, 0, 0))(spec, params, us, datas) \
        if model else None
    derived = jax.vmap(derived_fn(spec)[1])(ps)
    mu = None if tabor is None else jax.vmap(tabor_fn(spec, tabor), in_axes=(0, None))(
        ps, radius)
    return model, derived, mu


def _in_thread(fn):
    """`fn` wrapped to run in another thread with this thread's 64-bit setting and default
    device (JAX's settings are local to a thread: a search traced without them would be a
    float32 program, or on another device)."""
    x64 = bool(jax.config.jax_enable_x64)
    device = jax.config.jax_default_device

    def run(*args, **kwargs):
        with jax.enable_x64(x64), jax.default_device(device):
            return fn(*args, **kwargs)

    return run


class _Background:
    """The jitted `fn` compiled in a thread for `(*args, **static)` (`static`: its static
    keywords), started by :meth:`start` (again: nothing), so that its tracing and
    compilation overlap other work (XLA compiles outside the GIL); :meth:`call` then runs
    that executable. Start it once the caller's own tracing is done: tracing is Python,
    and two traces in two threads take turns on the GIL (each then takes about as long as
    both together: `benchmarks/results/fit_each.md`, "A cold fit"). Not a call of `fn`
    in the thread, whose compilation a later call was meant to find: the call traced and
    compiled the finish again on the main thread (``fit_each.md``, "Repeated runs"). An
    error is left for :meth:`call`, which then calls `fn` itself. The thread traces with
    the creating thread's 64-bit setting and default device (:func:`_in_thread`;
    `jax.enable_x64` is local to a thread: `fit` turns it on for its own duration, and the
    thread's trace was float32 where Python scalars entered it, a program the call could
    not use)."""

    def __init__(self, fn, *args, **static):
        self._fn, self._static, self._compiled = fn, static, None

        def run():
            try:
                self._compiled = fn.lower(*args, **static).compile()
            except Exception:  # noqa: BLE001 - the real call reports it
                pass

        self._thread = threading.Thread(target=_in_thread(run), daemon=True)

    def start(self) -> None:
        if self._thread.ident is None:
            self._thread.start()

    def join(self) -> None:
        self.start()
        self._thread.join()

    def call(self, *args, **static):
        """`fn(*args, **static)`, by the executable compiled in the thread when these are
        the argument types and static keywords it was compiled for."""
        self.join()
        if self._compiled is not None and static == self._static:
            try:
                return self._compiled(*args)
            except (TypeError, ValueError):  # other shapes or structure than compiled for
                pass
        return self._fn(*args, **static)


class _Streams:
    """The searches of a stage's `n` chunks, `search(k, searched)` for chunk `k`, run in
    `streams` host threads at once and taken in chunk order (:meth:`take`); with one
    stream each runs in the calling thread when it is taken (no thread).

    The first chunk starts alone, the others once its first pool call has returned
    (`searched`): one thread traces and compiles the search's program, and the others
    find it (two threads compiling one program take about as long each as both). At
    most ``2 * streams`` chunks are searched ahead of the one taken (their host results
    bound the memory). The threads are daemons, carry the calling thread's 64-bit setting
    and default device (JAX's settings are local to a thread), and start no chunk after
    :meth:`close`: an error or an interrupt of the caller leaves at most the running
    chunks to end on their own. An error of a search is raised by :meth:`take` of its
    chunk. The results do not depend on `streams`: each chunk's search is its own."""

    def __init__(self, search, n: int, streams: int):
        self._search, self._n = search, n
        self._results: list = [None] * n
        self._done = [threading.Event() for _ in range(n)]
        self._first = threading.Event()
        self._lock = threading.Lock()
        self._room = threading.Semaphore(2 * streams)
        self._next, self._closed = 0, False
        self._threads = []
        if streams > 1:
            work = _in_thread(self._work)
            for _ in range(min(streams, n)):
                t = threading.Thread(target=work, daemon=True)
                self._threads.append(t)
                t.start()

    def _work(self) -> None:
        while True:
            self._room.acquire()
            with self._lock:
                if self._closed or self._next >= self._n:
                    self._room.release()
                    return
                k, self._next = self._next, self._next + 1
            if k:
                self._first.wait()
            self._run(k)

    def _run(self, k: int) -> None:
        try:
            if self._closed:
                raise RuntimeError("the searches were closed")
            self._results[k] = (True, self._search(k, self._first.set if k == 0 else None))
        except BaseException as exc:  # noqa: BLE001 - raised by `take` in the caller
            self._results[k] = (False, exc)
        finally:
            if k == 0:
                self._first.set()
            self._done[k].set()

    def take(self, k: int):
        """The result of chunk `k`'s search (raises its error)."""
        if self._threads:
            self._done[k].wait()
            self._room.release()
        else:
            self._run(k)
        (ok, value), self._results[k] = self._results[k], None
        if not ok:
            raise value
        return value

    def close(self) -> None:
        """Start no more chunks (the running ones end on their own)."""
        with self._lock:
            self._closed = True
        self._first.set()
        for _ in self._threads:
            self._room.release()


@keyword_signature(FitOptions)
def fit(curves: Curve | Sequence[Curve], *, options: FitOptions | None = None,
        **keywords) -> FitResult:
    r"""Identify the rheology, $\Delta\gamma$ (and the contact point) from one or more curves.

    **Arguments:**

    - `curves`: a :class:`Curve` or a list of them, fitted jointly: different speeds and
      holds share the material parameters (one problem). Indentation [m] positive into
      the sample, 0 at the contact point; force [N] compressive positive, adhesive
      negative.
    - `options`: a :class:`fitting.FitOptions`, or its fields as keywords (`radius`,
      `profile`, `model`, `rheology`, `spring_constant`, `initial`, `fixed`, `bounds`,
      `contact_point`, `force_offset`, `n_starts`, `max_samples`, `indentation_range`,
      `segments`, `cells`, `search_cells`, `max_steps`, `optimiser`, `rtol`, `seed`,
      `local_rounds`, `progress`; meanings, units and defaults there). A keyword given
      beside `options` must agree with it.

    How it relates to :func:`fitting.fit_each`: both run one pipeline (:func:`identify`:
    the same preparation, starts, global search, local rounds and finish); `fit` is its
    case of one problem, made of all `curves` together, its starts on at most 8 lanes of
    the pool (spread over the local devices, as :func:`solve_batch` does; the results do
    not depend on the split, up to round-off).
    :func:`fitting.fit_each` makes one problem of each curve instead (a curve fitted there
    ends where `fit` of that curve alone ends). Only `fit` offers ``rheology="auto"``
    (standard, prony:2 and prony:3 fitted nested; the smallest BIC is kept, all three in
    ``result.model_selection``) and one spring constant per curve.

    **Returns:** a :class:`FitResult` (print it for a summary). Parameters the data do not
    determine, or that sit at a bound, are named in its `warnings` and `status` (also
    issued as :class:`IdentifiabilityWarning`).

    **Raises:** `ValueError` naming the argument for bad options or data; `TypeError` for
    an unknown keyword.
    """
    if isinstance(curves, Curve):
        curves = [curves]
    curves = list(curves)
    if not curves or not all(isinstance(c, Curve) for c in curves):
        raise ValueError("curves: give a Curve or a non-empty list of Curve objects")
    (keywords,) = split_keywords(keywords, FitOptions, where="fit")
    options = FitOptions.merge(options, keywords, where="fit")
    show = Progress(options.progress, "fit").message  # one timestamped line per call
    auto = options.rheology == "auto"
    out = identify([curves], options, SINGLE, show=show, warn=not auto, keep_steps=True)
    results = out.steps[0]
    if not auto:
        return results[-1]
    choices = [ModelChoice(rheology=r.rheology, chi2=r.chi2,
                           k=int(np.sum(~np.asarray(r.fixed, dtype=bool))), n=r.n_data,
                           aic=r.aic, bic=r.bic) for r in results]
    best = int(np.argmin([c.bic for c in choices]))
    choices[best].chosen = True
    chosen = results[best]
    chosen.model_selection = choices
    show(f"model selection: {', '.join(f'{c.rheology} BIC {c.bic:.6g}' for c in choices)}; "
         f"chosen {chosen.rheology}")
    for m in chosen.warnings:
        warn_at_caller(m, IdentifiabilityWarning)
    return chosen


@dataclasses.dataclass
class _Problem:
    """One identification problem: the model, the parameterisation, the prepared data and
    the starts of the global search (rows of `zs`, free vectors)."""

    spec: ModelSpec
    info: list
    names: list[str]
    param: Parameterisation
    data: CurveBatch
    zs: np.ndarray
    curves: list = dataclasses.field(default_factory=list)
    notes: list = dataclasses.field(default_factory=list)
    #: with ``screen``: the screened points (free vectors, rows), whose best replace the
    #: random starts, rows 1 to `n_starts` - 1 of `zs`
    pool: np.ndarray | None = None


def _problem(curves, options: FitOptions, *, rheology: str, contact_point: str,
             previous: FitResult | None) -> _Problem:
    """The problem of `curves` (fitted jointly) for `rheology` (a step of
    ``options.chain()``; `previous`: the step before's result, whose optimum adds nested
    starts), with the contact point "fit" or "fixed"; prepared in numpy."""
    o = options
    profile = o.probe
    spec = make_spec(o.model, rheology, compliant=o.spring_constant is not None,
                     cells=o.cells, contact_offset=contact_point == "fit",
                     force_offset=o.force_offset, force_drift=o.force_drift)
    info = parameter_info(spec)
    names = [n for n, _, _ in info]
    curves = select_fit_segments(curves, o.segments)
    check_contact_signal(curves, spec)
    data = prepare_curves(curves, spec, profile=profile, spring_constant=o.spring_constant,
                          max_samples=o.max_samples, indentation_range=o.indentation_range,
                          host=True)
    scales = data_scales(curves, spec, profile)
    guess = initial_guess(curves, spec, profile, scales)
    guess.update(normalise_names(o.initial, names, "initial"))
    fixed, notes = _approach_only(data, guess, normalise_names(o.fixed, names, "fixed"))
    bnds = default_bounds(spec, scales)
    # the starts (rows, natural values): the guess, the search's points
    # (:func:`search_starts` as one array), the nested starts
    nested = []
    if previous is not None:
        nested = nested_starts(spec, previous.spec, previous.as_dict(), scales)
        _contain(bnds, nested, [n for n, _, kind in info if kind == "time"])
    bnds.update(normalise_names(o.bounds, names, "bounds"))
    param = make_parameterisation(info, guess, fixed=fixed, bounds=bnds,
                                  scales={"contact_offset": scales.depth,
                                          "force_offset": scales.force_range,
                                          "force_drift": scales.force_range / scales.duration},
                                  host=True)
    starts = np.empty((o.n_starts + len(nested), len(names)))
    starts[0] = [guess[n] for n in names]
    if o.n_starts > 1:
        points = search_points(spec, scales, o.n_starts - 1, seed=o.seed)
        for j, n in enumerate(names):
            starts[1:o.n_starts, j] = points[n] if n in points else guess[n]
    for i, q in enumerate(nested, start=o.n_starts):
        starts[i] = [q.get(n, guess[n]) for n in names]
    zs = param.z_of(param.to_internal(starts))
    pool = None
    if o.screen:
        points = search_points(spec, scales, o.screen, seed=o.seed)
        pool = param.z_of(param.to_internal(np.stack(
            [points[n] if n in points else np.full(o.screen, guess[n]) for n in names],
            axis=1)))
    return _Problem(spec, info, names, param, data, zs, curves, notes, pool)


def _contain(bounds, starts, names) -> None:
    """Widen the default bounds of the parameters `names` (relaxation times) to contain
    the nested `starts` (with room: a start at a bound would sit in the flat end of the
    logistic): the simpler model's optimum stays a point of the richer one, so the nested
    fit never ends above it (a standard fit that is elastic in effect has a relaxation
    time far below two sampling intervals). All of `names` get the same bounds (the arms
    stay interchangeable: :func:`_sort_arms`)."""
    values = [float(q[n]) for q in starts for n in names]
    if not values:
        return
    top, bottom = max(values), min(values)
    for n in names:
        lo, hi = bounds[n]
        bounds[n] = (min(lo, bottom / 1.5) if bottom < 1.5 * lo else lo,
                     max(hi, 1.5 * top) if top > hi / 1.5 else hi)


def _approach_only(data: CurveBatch, guess, fixed) -> tuple[dict, list[str]]:
    """`fixed` with the work of adhesion held when no retract sample is fitted (the model's
    approach is non-adhesive, the JKR limit: it does not depend on it), and the note."""
    retract = (np.asarray(data.segment) == SEGMENTS.index("retract")) & \
        (np.asarray(data.valid) > 0) & (np.asarray(data.weight) > 0)
    if retract.any():
        return fixed, []
    held = "work_of_adhesion" in fixed
    fixed = dict(fixed)
    value = fixed.setdefault("work_of_adhesion", float(guess["work_of_adhesion"]))
    return fixed, [
        f"work_of_adhesion: not fitted: no retract sample is fitted, and the model's "
        f"approach does not depend on it (non-adhesive loading, the JKR limit); held at "
        f"{value:.4g} J/m^2 ({'the fixed value' if held else 'its start value, no result'})"]


def _best_loss(chi2) -> float:
    chi2 = np.asarray(chi2, dtype=float)
    return float(np.min(np.where(np.isfinite(chi2), chi2, np.inf)))


def _best_index(chi2) -> int:
    r"""The start of smallest finite $\chi^2$ (the first of equals; 0 if none is finite)."""
    chi2 = np.asarray(chi2, dtype=float)
    return int(np.argmin(np.where(np.isfinite(chi2), chi2, np.inf)))


def _improved(chi2, before: float) -> bool:
    """A round improved the best loss by more than a relative 1e-7."""
    return _best_loss(chi2) < before * (1.0 - 1e-7)


def _round_bounds(best: float, n: int, abandon: float | None) -> np.ndarray:
    r"""The bounds on $\chi^2$ of a local round's `n` starts (:func:`_local_search`): none
    for the first (the best end point continued), `abandon` × `best` for the others
    (none without `abandon` or a finite `best`)."""
    out = np.full(n, np.inf)
    if abandon is not None and np.isfinite(best):
        out[1:] = abandon * best
    return out


def _local_search(params, outs: list[Solution], run, *, n: int, local_rounds: int,
                  seed: int, max_steps: int, explore_steps: int, abandon: float | None = None,
                  limits=None, show=None) -> list[Solution]:
    r"""The local rounds of each problem after its global search (one home for :func:`fit`
    and :func:`fitting.fit_each`).

    `params`: the problems' parameterisations; `outs`: their global searches (host
    :class:`Solution`, one lane per start) and `limits` the step limit each start ran with
    (default `max_steps`); `run(starts, limits, bounds)`: one compiled call of the pool on
    `n` starts per problem with a step limit and a bound on $\chi^2$ per start
    (:func:`solve_batch`), returning a host :class:`Solution` per problem. Each round gives
    every problem whose rounds are not done `n` starts (:func:`fitting._start.local_starts`):
    the first, the best end point continued, with `max_steps`, the others (exploring) with
    `explore_steps` and, with `abandon` and in a round that is not widened, the bound
    `abandon` × the best $\chi^2$ known before the round (a start still above it after
    :data:`fitting._least_squares.ABANDON_AFTER` steps has left the best's neighbourhood
    and is abandoned); a problem whose rounds are done gets limit 0 (not run: it costs
    one lane-step a start). After the rounds, a
    problem whose best end point stopped unconverged at an exploring limit is continued
    from there with `max_steps` (one more call, only if some problem needs it). Returns
    the merged solutions. A problem none of whose starts ran (limit 0: a chunk's
    padding) is not searched further: no rounds, no continuation.
    """
    outs = list(outs)
    ran = [np.full(len(o.chi2), max_steps, np.int32) if limits is None
           else np.asarray(limits[j], np.int32) for j, o in enumerate(outs)]
    searched = [bool(r.any()) for r in ran]
    rounds = [LocalRounds(done=not on) for on in searched]
    explore = np.full(n, min(explore_steps, max_steps), np.int32)
    explore[0] = max_steps
    for k in range(local_rounds):
        if all(r.done for r in rounds):
            break
        before = [_best_loss(o.chi2) for o in outs]
        # the starts of the problems whose rounds go on, in one batch (their searches
        # have equally many end points); the others' are not run (limit 0)
        going = [j for j, r in enumerate(rounds) if not r.done]
        batch = local_starts_batch([params[j] for j in going],
                                   np.stack([outs[j].z for j in going]),
                                   np.stack([outs[j].chi2 for j in going]), n,
                                   seed=seed + 1 + k, widen=[rounds[j].widen for j in going])
        starts = [np.asarray(o.z[:1]).repeat(n, axis=0) for o in outs]
        for i, j in enumerate(going):
            starts[j] = batch[i]
        new = run(starts, [np.zeros(n, np.int32) if r.done else explore for r in rounds],
                  [_round_bounds(b, n, abandon if r.widen == 1.0 else None)
                   for b, r in zip(before, rounds, strict=True)])
        for j, r in enumerate(rounds):  # a problem whose rounds are done keeps its lanes
            if r.done:
                continue
            widen = r.widen
            outs[j] = outs[j].concat(new[j])
            ran[j] = np.concatenate([ran[j], explore])
            r.update(_improved(outs[j].chi2, before[j]))
            if show is not None:
                show(f"local round {k + 1} (width x{widen:g}): chi2 {before[j]:.8g} -> "
                     f"{_best_loss(outs[j].chi2):.8g}")
    # the best end point of a problem stopped by an exploring limit: continued
    best = [_best_index(o.chi2) for o in outs]
    cut = [searched[j] and int(o.result[b]) == RESULTS.max_steps_reached
           and ran[j][b] < max_steps for j, (o, b) in enumerate(zip(outs, best, strict=True))]
    if any(cut):
        starts = [np.asarray(o.z[b:b + 1]).repeat(n, axis=0) for o, b in zip(outs, best,
                                                                                strict=True)]
        lim = np.zeros(n, np.int32)
        lim[0] = max_steps
        new = run(starts, [lim if c else np.zeros(n, np.int32) for c in cut],
                  [np.full(n, np.inf)] * len(outs))
        for j, c in enumerate(cut):
            if c:
                outs[j] = outs[j].concat(new[j].take(slice(0, 1)))
                if show is not None:
                    show(f"continued the best start: chi2 {_best_loss(outs[j].chi2):.8g}")
    return outs


@dataclasses.dataclass
class Identified:
    """The outcome of :func:`identify`, per group of curves (in order): `steps` (the
    :class:`FitResult` of each step of the chain of models reached, or with `keep_steps`
    false only the last one), `errors` (`None`, or why the group failed: with `isolate`),
    and for all: `spec` (the model of the last step run; `None` if no group was prepared)
    and `timings` [s] (prepare, optimise, finish: summed over the steps and chunks;
    optimise is the time spent waiting for the chunks' searches, which run in
    `BatchOptions.streams_for` threads at once and overlap the finish)."""

    steps: list[list[FitResult]]
    errors: list[str | None]
    spec: ModelSpec | None
    timings: dict

    def final(self, g: int) -> FitResult | None:
        """Group `g`'s result of the chain's last model (`None` if it failed before)."""
        return self.steps[g][-1] if self.errors[g] is None and self.steps[g] else None


def _message(exc: BaseException) -> str:
    text = str(exc) if isinstance(exc, ValueError) else f"{type(exc).__name__}: {exc}"
    return " ".join(text.split())


def identify(groups: Sequence[Sequence[Curve]], options: FitOptions, batch: BatchOptions, *,
             show=None, warn: bool = True, isolate: bool = False, keep_steps: bool = False,
             progress=None) -> Identified:
    r"""The identification pipeline of :func:`fit` and :func:`fitting.fit_each`: one
    problem per group of curves (the curves of a group share the parameters), for each
    rheology of ``options.chain()`` in turn (each problem started also from its own
    previous optimum):

    1. **Prepare** each problem (:func:`_problem`: data, parameterisation, starts), in
       numpy; the contact-point mode is decided once over all curves
       (:func:`fitting._prepare.contact_point_mode`).
    2. **Search** the problems in chunks of ``batch.chunk_for(...)``, padded to one shape (samples,
       starts, and the last chunk to the chunk size) so that one compilation serves all:
       the global search of all starts of the chunk, then the local rounds
       (:func:`_local_search`), each one call of :func:`solve_batch` on
       ``batch.lanes(...)`` lanes over ``batch.devices``; ``batch.streams_for(...)``
       chunks at once, each from its own host thread (:class:`_Streams`).
    3. **Finish** each problem's best start: the device work of a chunk in one compiled
       call (:func:`_finish_chunk`: the derived quantities and Tabor's parameter with
       their gradients, vmapped over the chunk's problems, padded to the chunk size; the
       model at the optimum comes with the search's solution where its solver carries it,
       :attr:`fitting.Solution.model`, else it is evaluated in the same call), then per
       problem on the host (:func:`_finish`: uncertainty, $R^2$, warnings, the
       :class:`FitResult`).

    `show(message)`: the stages of each problem (`None`: silent); `progress(stage, done)`:
    after each chunk. `warn`: issue the last model's warnings (the chain's earlier steps
    are always quiet). `isolate`: a problem that cannot be prepared or finished is an
    error of its group (else the exception propagates). Returns :class:`Identified`.
    """
    groups = [list(g) for g in groups]
    n = len(groups)
    contact_point = contact_point_mode(options.contact_point, [c for g in groups for c in g])
    chain = options.chain()
    steps: list[list[FitResult]] = [[] for _ in groups]
    errors: list[str | None] = [None] * n
    timings = {"prepare": 0.0, "optimise": 0.0, "finish": 0.0}
    caught = (ValueError, ArithmeticError) if isolate else ()
    failed = (*caught, np.linalg.LinAlgError) if isolate else ()
    say = show if show is not None else (lambda _m: None)
    spec = None
    for rh in chain:
        last = rh == chain[-1]
        problems, started, prepared = {}, {}, {}
        for g in range(n):
            if errors[g] is not None:
                continue
            started[g] = t0 = time.perf_counter()
            try:
                problems[g] = _problem(groups[g], options, rheology=rh,
                                       contact_point=contact_point,
                                       previous=steps[g][-1] if steps[g] else None)
            except caught as exc:
                errors[g] = _message(exc)
                continue
            pb = problems[g]
            if show is not None:  # (the message's sums are not made for no one, per curve)
                say(f"{pb.spec.model} model, {rheology_name(pb.spec)}: {pb.data.n_curves} "
                    f"curve(s), {pb.data.n_samples} samples (standing for "
                    f"{pb.data.n_measured} measured), {len(pb.param.free)} free "
                    f"parameter(s), {len(pb.zs)} start(s)")
            prepared[g] = time.perf_counter() - t0
            timings["prepare"] += prepared[g]
        if not problems:
            break
        idx = list(problems)
        spec = problems[idx[0]].spec
        _pad(problems)
        pb0 = problems[idx[0]]
        n_z = len(pb0.zs)
        size = batch.chunk_for(len(idx), problem_bytes=SEARCH_BYTES_PER_RESIDUAL * n_z
                               * int(np.size(pb0.data.ts)))
        # the finish's device work compiles during the search (started once the search's
        # program is traced)
        args, kw = _chunk_inputs([pb0], [pb0.param.internal_host(pb0.zs[0])], size, options,
                                 model=not _carries_model(options))
        model_at = _Background(_evaluate_chunk, *args, **kw)
        # the chunks' searches, one per stream at once (`BatchOptions.streams_for`), each
        # finished here in order
        chunks = [idx[c0:c0 + size] for c0 in range(0, len(idx), size)]
        lanes = batch.lanes(size, n_z, model=options.model)
        search = functools.partial(_timed_search, [[problems[g] for g in part]
                                                   for part in chunks],
                                   size, options, batch, lanes=lanes, show=show,
                                   traced=model_at.start)
        searches = _Streams(search, len(chunks), batch.streams_for(len(chunks)))
        try:
            for k, part in enumerate(chunks):
                t0 = time.perf_counter()
                outs, t_search = searches.take(k)
                model_at.join()
                timings["optimise"] += time.perf_counter() - t0  # waited for, in order
                t0 = time.perf_counter()
                pres = _finish_chunk([problems[g] for g in part], outs, size, options,
                                     failed, evaluate=model_at.call)
                for g, out, pre in zip(part, outs, pres, strict=True):
                    stage = {"prepare": prepared[g], "optimise": t_search}  # the chunk's
                    try:
                        if isinstance(pre, BaseException):
                            raise pre
                        with warnings.catch_warnings():
                            if not last:  # a step of the chain: not the result's warnings
                                warnings.simplefilter("ignore", IdentifiabilityWarning)
                                warnings.simplefilter("ignore", ModelValidityWarning)
                            res = _finish(problems[g], out, options, pre, show=say,
                                          warn=warn and last, timings=stage,
                                          t_start=started[g])
                    except failed as exc:
                        errors[g] = _message(exc)
                        continue
                    steps[g] = steps[g] + [res] if keep_steps else [res]
                timings["finish"] += time.perf_counter() - t0
                if progress is not None:
                    progress(rheology_name(spec), min((k + 1) * size, len(idx)))
        finally:
            searches.close()
    for g in range(n):  # a group that failed at a later step of the chain has no result
        if errors[g] is not None:
            steps[g] = []
    return Identified(steps=steps, errors=errors, spec=spec, timings=timings)


def _timed_search(chunks: list[list[_Problem]], size: int, options: FitOptions,
                  batch: BatchOptions, k: int, searched=None, **kw) -> tuple:
    """:func:`_search_chunk` of `chunks[k]` and its wall time [s]."""
    t0 = time.perf_counter()
    outs = _search_chunk(chunks[k], size, options, batch, searched=searched, **kw)
    return outs, time.perf_counter() - t0


def _pad(problems: dict) -> None:
    """Every problem to one shape, in place: its samples padded to the longest problem's
    (:func:`fitting.stack_batches`) and its starts to the most starts (the first repeated)."""
    idx = list(problems)
    length = max(problems[g].data.ts.shape[1] for g in idx)
    n_z = max(len(problems[g].zs) for g in idx)
    for g in idx:
        pb = problems[g]
        data = pb.data if pb.data.ts.shape[1] == length else \
            stack_batches([pb.data], length, host=True)
        zs = np.concatenate([pb.zs, np.repeat(pb.zs[:1], n_z - len(pb.zs), axis=0)])
        problems[g] = dataclasses.replace(pb, data=data, zs=zs)


@dataclasses.dataclass
class _Searched:
    """A problem's search (host solutions, :class:`Solution`, one lane per start):
    `final`, the starts on the fit's own grid, whose best is the result (the search
    itself, or with a coarser search grid the polished end points, :func:`_polish`), and
    `search`, the search on the coarser grid (``FitOptions.search_cells``; `None`: it ran
    on the fit's grid, `final`)."""

    final: Solution
    search: Solution | None = None

    @property
    def starts(self) -> Solution:
        """The global search's and local rounds' starts (on the search's grid)."""
        return self.final if self.search is None else self.search


def _search_chunk(problems: list[_Problem], size: int, options: FitOptions,
                  batch: BatchOptions, *, lanes: int, show=None,
                  traced=None, searched=None) -> list[_Searched]:
    """The global search and the local rounds of equally shaped `problems` in one compiled
    pool (:func:`solve_batch`), padded to `size` problems (the last one repeated; its
    copies are never run, and dropped), on the search's grid
    (:meth:`fitting.FitOptions.search_spec`); where that is coarser than the fit's own, its
    best end points continued on the fit's grid (:func:`_polish`). Returns a
    :class:`_Searched` per problem.
    `traced()`: called once the pool's program is traced (before its first call);
    `searched()`: once its first call has returned (the program is compiled)."""
    fill = [problems[j] for j in padded_indices(len(problems), size)]
    n_z = len(fill[0].zs)
    if fill[0].pool is not None:
        fill = _screened(fill, options)
    params = _stack([pb.param for pb in fill], n_z)
    datas = _stack([pb.data for pb in fill], n_z)
    spec = options.search_spec(fill[0].spec)

    def run(starts, limits, bounds=None):
        nonlocal traced, searched  # called on the first call only
        hook, traced = traced, None
        out = jax.device_get(solve_batch(
            spec, params, datas, np.concatenate(starts), limits=np.concatenate(limits),
            bounds=None if bounds is None else np.concatenate(bounds),
            workers=lanes, rtol=options.rtol, max_steps=options.max_steps,
            optimiser=options.optimiser, devices=batch.devices, keep_jacobian=True,
            traced=hook))
        if searched is not None:
            done, searched = searched, None
            done()
        return [out.take(slice(j * n_z, (j + 1) * n_z)) for j in range(len(starts))]

    # with local rounds to follow, the global search explores (its best is continued)
    first = np.full(n_z, options.max_steps if options.local_rounds == 0
                    else min(options.explore_steps, options.max_steps), np.int32)
    # the padding's copies (one compiled shape for every chunk) are never run (limit 0:
    # no lane takes them), nor are problems whose rounds are done
    n = len(problems)
    limits = [first if j < n else np.zeros(n_z, np.int32) for j in range(size)]
    outs = run([pb.zs for pb in fill], limits)
    outs = _local_search([pb.param for pb in fill], outs, run, n=n_z,
                         local_rounds=options.local_rounds, seed=options.seed,
                         max_steps=options.max_steps, explore_steps=options.explore_steps,
                         abandon=options.abandon, limits=limits, show=show)
    if spec == fill[0].spec:
        return [_Searched(final=o) for o in outs[:n]]
    polished = _polish(fill, outs, n, options, batch, lanes=lanes, show=show)
    return [_Searched(final=p, search=o) for p, o in zip(polished, outs[:n], strict=True)]


def distinct_best(chi2, k: int, *, rtol: float = 1e-7) -> np.ndarray:
    r"""The indices of the `k` best distinct end points by $\chi^2$ (finite only; two end
    points whose $\chi^2$ agree within a relative `rtol` count as one optimum), best first;
    fewer where there are fewer."""
    chi2 = np.asarray(chi2, dtype=float)
    picked: list[int] = []
    for i in np.argsort(np.where(np.isfinite(chi2), chi2, np.inf), kind="stable"):
        if not np.isfinite(chi2[i]) or len(picked) == k:
            break
        if all(abs(chi2[i] - chi2[j]) > rtol * abs(chi2[j]) for j in picked):
            picked.append(int(i))
    return np.asarray(picked, dtype=int)


def _polish(fill: list[_Problem], outs: list[Solution], n: int, options: FitOptions,
            batch: BatchOptions, *, lanes: int, show=None) -> list[Solution]:
    """The best :data:`fitting._options.POLISHED_POINTS` distinct end points of each of
    the first `n` problems' searches (`outs`, on the coarser search grid) continued on the
    fit's own grid (``fill[0].spec``) with `max_steps`, in one compiled pool: the host
    :class:`Solution` of those starts per problem (a point not there, fewer distinct
    optima or a padding problem, is not run: limit 0, and dropped)."""
    k = POLISHED_POINTS
    spec = fill[0].spec
    # a search without a finite end point still has its first start continued
    picks = [(distinct_best(o.chi2, k) if np.isfinite(o.chi2).any() else np.zeros(1, int))
             if j < n else np.zeros(0, int) for j, o in enumerate(outs)]
    starts = np.concatenate([
        np.asarray(o.z)[np.concatenate([p, np.full(k - len(p), p[0] if len(p) else 0)])]
        for o, p in zip(outs, picks, strict=True)])
    limits = np.concatenate([np.where(np.arange(k) < len(p), options.max_steps, 0)
                             for p in picks]).astype(np.int32)
    out = jax.device_get(solve_batch(
        spec, _stack([pb.param for pb in fill], k), _stack([pb.data for pb in fill], k),
        starts, limits=limits, workers=lanes, rtol=options.rtol,
        max_steps=options.max_steps, optimiser=options.optimiser, devices=batch.devices,
        keep_jacobian=True))
    polished = [out.take(slice(j * k, j * k + max(len(picks[j]), 1))) for j in range(n)]
    if show is not None:
        for o, p in zip(polished, picks, strict=True):
            show(f"continued the best {len(p)} end point(s) of the search on {spec.cells} "
                 f"cells (searched on {options.search_cells}): chi2 "
                 f"{', '.join(f'{c:.8g}' for c in np.asarray(o.chi2))}")
    return polished


#: Screened points evaluated at once per problem (bounds the memory of a screen like that
#: of a search's lanes).
SCREEN_BATCH = 64


@model_jit()
def _screen_chi2(spec, params, datas, pools):
    r"""$\chi^2$ at every screened point of every problem (leading axis of `params`,
    `datas`, `pools`; `pools`: free vectors `(problems, points, k)`), `(problems, points)`;
    non-finite as $\infty$."""
    fn = _fn(spec)

    def one(param, data, pool):
        chi2 = jax.lax.map(lambda z: jnp.sum(fn(z, (param, data)) ** 2), pool,
                           batch_size=min(SCREEN_BATCH, pool.shape[0]))
        return jnp.where(jnp.isfinite(chi2), chi2, jnp.inf)

    return jax.vmap(one)(params, datas, pools)


def _screened(problems: list[_Problem], options: FitOptions) -> list[_Problem]:
    r"""`problems` with their random starts (rows 1 to `n_starts` - 1 of `zs`) replaced by
    the best of their screened points (:attr:`_Problem.pool`, in order of $\chi^2$): one
    compiled call for the chunk."""
    chi2 = np.asarray(jax.device_get(_screen_chi2(
        problems[0].spec, _stack([pb.param for pb in problems], 1),
        _stack([pb.data for pb in problems], 1),
        jnp.asarray(np.stack([pb.pool for pb in problems])))))
    k = options.n_starts - 1
    best = np.argsort(chi2, axis=1, kind="stable")[:, :k]
    out = []
    for pb, rows in zip(problems, best, strict=True):
        zs = pb.zs.copy()
        zs[1:1 + k] = pb.pool[rows]
        out.append(dataclasses.replace(pb, zs=zs))
    return out


def _stack(trees, repeat: int):
    """One pytree with a leading problem axis: each of `trees` repeated `repeat` times."""
    # flattened once each (the problems' arrays are in numpy), one transfer for all
    flat = [jax.tree.flatten(t) for t in trees]
    treedef = flat[0][1]
    if any(d != treedef for _, d in flat[1:]):  # e.g. other free parameters: no one batch
        raise ValueError("the problems of a chunk differ in structure (e.g. which "
                         "parameters are free); they cannot be stacked into one batch")
    leaves = [lv for lv, _ in flat]
    stacked = [np.repeat(np.stack([np.asarray(row[i]) for row in leaves]), repeat, axis=0)
               for i in range(len(leaves[0]))]
    return jax.device_put(jax.tree.unflatten(treedef, stacked))


def _best_point(pb: _Problem, out: Solution):
    """Problem `pb`'s best start of the search `out`: its index, its internal coordinates
    `u` (Prony arms sorted) and the residuals `r` and their Jacobian `J` with respect to
    the free internal coordinates there (the search's own, else computed)."""
    spec, param = pb.spec, pb.param
    z_all, chi2_all = np.asarray(out.z), np.asarray(out.chi2)
    best = _best_index(chi2_all)
    z = z_all[best]
    u = param.internal_host(z)
    dudz = param.dinternal_dz(z)
    # a column whose logistic has saturated (du/dz ~ 0) cannot be divided back; it is not
    # needed where its parameter is at its bound (the covariance leaves such a parameter
    # out: `gauss_newton`), so the model's own Jacobian is computed (compiled) only when
    # a saturated parameter is not at its bound
    flat = np.abs(dudz) <= 1e-8
    at = param.at_bound(u)
    unused = np.array([at[i] is not None for i in param.free], dtype=bool)
    if out.J is not None and not np.any(flat & ~unused):
        r = np.asarray(out.r[best])
        J = np.asarray(out.J[best]) / np.where(flat, 1.0, dudz)[None, :]
        J[:, flat] = np.nan  # not used: at a bound
    else:
        r, J = (np.asarray(x) for x in internal_jacobian(spec, param, jnp.asarray(u), pb.data))
    u, J = _sort_arms(spec, param, u, J)
    return best, u, r, J


def _chunk_inputs(problems: list[_Problem], us, size: int, options: FitOptions, *,
                  model: bool):
    """Arguments and keywords of :func:`_evaluate_chunk` for `problems` at internal
    coordinates `us`, padded to `size` problems (the last one repeated): one compilation
    serves every chunk. `model`: evaluate the model too (not carried by the search)."""
    fill = padded_indices(len(problems), size).tolist()
    radius = probe_radius(options.probe)
    pb0 = problems[0]
    us = np.stack([np.asarray(us[j], dtype=float) for j in fill])
    ps = np.stack([problems[j].param.to_natural_host(us[i]) for i, j in enumerate(fill)])
    # the model's inputs only where the call evaluates it
    params, datas = ((_stack([problems[j].param for j in fill], 1),
                      _stack([problems[j].data for j in fill], 1)) if model else (None, None))
    args = (pb0.spec, params, jnp.asarray(us) if model else None, jnp.asarray(ps), datas,
            0.0 if radius is None else radius)
    tabor = pb0.names.index("work_of_adhesion") if radius is not None else None
    return args, {"tabor": tabor, "model": model}


def _finish_chunk(problems: list[_Problem], outs: list[_Searched], size: int,
                  options: FitOptions, failed=(), *, evaluate=None) -> list:
    """What :func:`_finish` needs of each problem's best start, for a chunk of equally
    shaped `problems` at once (:func:`_evaluate_chunk`, padded to `size` problems; the
    probe's validity at every curve's largest contact radius in one call): per problem
    a dict, or the exception (one of `failed`) that its preparation raised. A chunk whose
    joint evaluation raises one of `failed` is evaluated problem by problem, so that a
    failure stays with its problem."""
    out: list = [None] * len(problems)
    ok = []
    for j, (pb, o) in enumerate(zip(problems, outs, strict=True)):
        try:
            out[j] = {"best": _best_point(pb, o.final)}
            ok.append(j)
        except failed as exc:
            out[j] = exc
    if not ok:
        return out
    # the model at each best start: carried by the search's solver, else evaluated here
    carried = all(outs[j].final.model is not None for j in ok)
    try:
        args, kw = _chunk_inputs([problems[j] for j in ok], [out[j]["best"][1] for j in ok],
                                 size, options, model=not carried)
        model, derived, mu = jax.device_get((evaluate or _evaluate_chunk)(*args, **kw))
    except failed as exc:
        if len(ok) == 1:
            out[ok[0]] = exc
            return out
        for j in ok:  # one by one: the failure is the failing problem's
            one = _finish_chunk([problems[j]], [outs[j]], 1, options, failed)[0]
            out[j] = one
        return out
    profile = options.probe
    if carried:
        models = [ModelAt(*(np.asarray(x[out[j]["best"][0]]) for x in outs[j].final.model))
                  for j in ok]
    else:
        models = [ModelAt(*(np.asarray(x[i]) for x in model)) for i in range(len(ok))]
    a_max = []
    for m, j in zip(models, ok, strict=True):
        valid = np.asarray(problems[j].data.valid) > 0
        a_max.append(float(np.nanmax(np.where(valid, m.contact_radius, 0.0))))
    check = jax.device_get(jc.profile_validity(profile, np.asarray(a_max)))
    radius = probe_radius(profile)
    quality = _chunk_quality([problems[j].data for j in ok], models)
    for i, j in enumerate(ok):
        out[j].update(
            model=models[i], radius=radius, quality=quality[i],
            evaluated=((derived[0][i], derived[1][i]),
                       None if mu is None else (mu[0][i], mu[1][i])),
            validity=(a_max[i], bool(check.valid[i]), float(check.fraction[i]),
                      float(check.limit), check.reason, type(profile).__name__))
    return out


def _chunk_quality(datas: list, models: list[ModelAt]) -> list[dict]:
    r"""The quality numbers of a chunk's fits at once (one set of array operations for all):
    per fit $R^2$ over every fitted sample and over those in contact (the data's contact, or
    a model contact radius > 0: `in_contact`), both weighted by the measured samples each
    stands for, $R^2$ of the kept samples each once (`r_squared_unweighted`) and the quality
    of each segment (:func:`fitting._quality.segment_quality_rows`)."""
    def stack(xs):
        return np.stack([np.asarray(x) for x in xs])

    force, noise, weight = (stack([getattr(d, k) for d in datas])
                            for k in ("force", "noise", "weight"))
    valid, contact, segment = (stack([getattr(d, k) for d in datas])
                               for k in ("valid", "contact", "segment"))
    model, fitted, radius = (stack([getattr(m, k) for m in models])
                             for k in ("force", "fitted", "contact_radius"))
    valid = valid > 0
    in_contact = valid & ((contact > 0) | (np.nan_to_num(radius) > 0))
    rows = len(datas)

    def flat(x):
        return np.reshape(x, (rows, -1))

    r2 = r_squared_rows(flat(model), flat(force), flat(weight), flat(valid))
    r2c = r_squared_rows(flat(model), flat(force), flat(weight), flat(in_contact))
    r2u = r_squared_rows(flat(model), flat(force), None, flat(valid))
    segments = segment_quality_rows(force, fitted, model, noise, weight, valid, segment)
    return [{"r_squared": float(r2[i]), "r_squared_contact": float(r2c[i]),
             "r_squared_unweighted": float(r2u[i]), "segments": segments[i],
             "in_contact": in_contact[i]} for i in range(rows)]


def _finish(pb: _Problem, out: _Searched, options: FitOptions, pre: dict, *, show, warn,
            timings, t_start) -> FitResult:
    """The :class:`FitResult` of problem `pb` from its search `out` (:class:`_Searched`:
    every start; the `r`, `J` of its final starts if kept, J with respect to z) and what
    :func:`_finish_chunk` computed for its chunk (`pre`)."""
    spec, param, data, names, info = pb.spec, pb.param, pb.data, pb.names, pb.info
    final, starts = out.final, out.starts
    chi2_all, steps_all = np.asarray(final.chi2), np.asarray(final.steps)
    ok_all = np.asarray(final.converged)
    best, u, r, J = pre["best"]
    searched = np.asarray(starts.chi2)
    order = np.argsort(np.where(np.isfinite(searched), searched, np.inf))
    grid = "" if out.search is None else f" on {options.search_cells} cells"
    show(f"search{grid}: chi2 of the best starts "
         f"{', '.join(f'{searched[i]:.6g}' for i in order[:4])} ({len(searched)} starts, "
         f"{int(np.sum(np.asarray(starts.steps)))} steps in all)")
    show(f"{'best' if out.search is None else f'continued on {spec.cells} cells'}: chi2 "
         f"{chi2_all[best]:.8g}; {RESULTS.describe(final.result[best])}, "
         f"{int(steps_all[best])} steps")
    model_force, fitted_force, radius_model = pre["model"]

    t0 = time.perf_counter()
    p = param.to_natural_host(u)
    unc = gauss_newton(param, u, r, J, names, n_data=data.n_measured,
                       weights=np.asarray(data.weight).ravel(),
                       retract_ends=retract_ends(data), warn=warn)
    quality = pre["quality"]
    k = int(sum(1 for i in param.free if not unc.status[i].startswith("at ")))
    n = data.n_measured
    chi2 = unc.chi2
    # the likelihood of a weighted chi2 counts Kish's effective samples, not the measured
    # ones the kept samples stand for: a subsampled curve's chi2 differences are inflated by
    # the weights (with n, BIC gave standard-model data a second arm:
    # test_fitting_history.py::test_model_selection_on_a_subsampled_curve)
    n_eff = max(data.n_effective, 1.0)
    ll = n_eff * math.log(max(chi2, 1e-300) / n)
    # the criteria count the model's fitted parameters, those ending at a bound too: a richer
    # model whose extra arm ends at a bound is the simpler one at the same chi2, not a
    # cheaper model (sin-force-distance.ibw, auto: prony:2 with 3 parameters off their
    # bounds had been chosen over the standard model's 4 at an equal chi2)
    k_model = len(param.free)
    curves, profile = pb.curves, options.probe  # as fitted: the chosen segments
    msgs = list(unc.warnings)
    msgs += _validity_warnings(spec, curves, pre["validity"])
    if warn:
        for m in msgs[len(unc.warnings):]:
            warn_at_caller(m, ModelValidityWarning)
        for m in pb.notes:
            warn_at_caller(m, IdentifiabilityWarning)
    msgs = list(pb.notes) + msgs
    fixed_mask = np.ones(len(names), dtype=bool)
    fixed_mask[list(param.free)] = False
    timings["uncertainty"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_start
    result = FitResult(
        names=names, units=[u_ for _, u_, _ in info], columns=[f"{n_}_{u_}" for n_, u_, _ in info],
        values=p, stderr=unc.stderr, status=unc.status, covariance=unc.covariance,
        correlation=unc.correlation, fixed=fixed_mask, chi2=chi2,
        reduced_chi2=unc.reduced_chi2, n_data=n, n_free=k,
        r_squared=quality["r_squared"], r_squared_contact=quality["r_squared_contact"],
        aic=ll + 2 * k_model, bic=ll + k_model * math.log(n_eff),
        converged=bool(ok_all[best]),
        start_losses=searched,
        spec=spec, data=data, curves=curves, profile=profile, radius=pre["radius"],
        model_at=(u, spec, param, data), model_force=model_force,
        model_contact_radius=radius_model, fitted_force=fitted_force,
        in_contact=quality["in_contact"],
        parameterisation=param, optimiser=options.optimiser,
        start_steps=np.asarray(starts.steps),
        polish_losses=None if out.search is None else chi2_all,
        polish_steps=None if out.search is None else steps_all,
        warnings=msgs, timings=timings,
        search={"n_starts": options.n_starts, "screen": options.screen,
                "local_rounds": options.local_rounds, "max_steps": options.max_steps,
                "explore_steps": min(options.explore_steps, options.max_steps),
                "abandon": options.abandon, "optimiser": options.optimiser,
                "rtol": options.rtol, "seed": options.seed,
                **({"cells": spec.cells, "search_cells": options.search_spec(spec).cells}
                   if spec.model == "history" else {})},
    )
    # quality per segment, flags, convergence, derived quantities
    flagged = assess(result, max_steps=options.max_steps, evaluated=pre["evaluated"],
                     quality=quality)
    if warn:
        for m in flagged:
            warn_at_caller(m, ModelValidityWarning)
    show(f"done: chi2_red = {result.reduced_chi2:.4g}, R^2 = {result.r_squared:.5f}, "
         f"R^2 in contact = {result.r_squared_contact:.5f}")
    return result


def _carries_model(options: FitOptions) -> bool:
    """Whether the search's solver carries the model at its end points
    (:attr:`fitting.Solution.model`), so that the finish need not evaluate it."""
    return make_solver(options.optimiser).with_model() is not None


def _sort_arms(spec, param, u, J):
    """Prony arms in increasing order of relaxation time (the model does not depend on the
    order; a reported ``tau_1 < tau_2 < ...`` does; the arms of the rheology's
    :attr:`fitting._spec.RheologyKind.arm_indices`). Only when every arm is free with the
    same bounds, so that the order is the only difference between them."""
    arm_indices = rheology_kind(spec).arm_indices
    if arm_indices is None or spec.arms < 2:
        return u, J
    groups = arm_indices(spec.arms)  # one list per per-arm parameter, the times last
    free = list(param.free)
    lo, hi = np.asarray(param.lower), np.asarray(param.upper)
    for idx in groups:
        if not all(i in free for i in idx):
            return u, J
        if not (np.all(lo[idx] == lo[idx[0]]) and np.all(hi[idx] == hi[idx[0]])):
            return u, J
    order = np.argsort(u[groups[-1]], kind="stable")
    perm = np.arange(len(u))
    for idx in groups:
        perm[idx] = np.asarray(idx)[order]
    col = {i: c for c, i in enumerate(free)}
    return u[perm], J[:, [col[perm[i]] for i in free]]


def _validity_warnings(spec, curves, validity) -> list[str]:
    """The model-validity warnings of a fit of `curves`; `validity`: the largest contact
    radius of the model [m], the probe's limit there (:func:`jc.profile_validity`: valid,
    fraction, limit [m], reason) and the profile's class name (computed per chunk by
    :func:`_finish_chunk`)."""
    out = []
    a_max, valid, fraction, limit, reason, profile = validity
    if not valid:
        out.append(f"the model's contact radius reaches {a_max:.3g} m, {fraction:.2f} "
                   f"times the limit {limit:.3g} m of the {profile} "
                   f"profile: {reason}; check the probe")
    # a curve whose approach was measured but not held: the relaxed start is contradicted by
    # the curve itself (a retract-only curve says nothing about how the contact was made)
    # (a loader's inferred one-sample "approach" at the top of a pure lift is no approach)
    def measured_approach(c):
        return ("approach" in c.segment_names
                and np.count_nonzero(c.segment == c.segment_names.index("approach")) > 1)

    unheld = [c for c in curves if measured_approach(c) and "hold" not in c.segment_names]
    if spec.model == "relaxed" and unheld:
        out.append("the relaxed model assumes the contact was held until fully relaxed before "
                   f"the lift, but {len(unheld)} curve(s) have an approach and no hold segment; "
                   "consider model='history'")
    return out
