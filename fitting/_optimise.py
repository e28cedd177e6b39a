r"""Identification: a global search to convergence, then the uncertainty (:func:`fit`).

How :func:`fit` finds the optimum
---------------------------------
1. **Prepare** the curves (:func:`fitting.prepare_curves`): every selected sample, or at
   most `max_samples` per curve, subsampled without averaging (no bias).
2. **Global search.** `n_starts` starts (:func:`fitting._start.search_starts`: the
   data-based guess and a Latin hypercube over physically bounded ranges; for a Prony
   series also the nested starts from the simpler model's optimum) each run to
   convergence (`rtol`, at most `max_steps` iterations) in one compiled call, scheduled
   as a pool of lanes (:func:`fitting._least_squares.run_pool`: a lane whose start has
   converged takes the next one). Then up to `local_rounds` rounds of as many starts
   around the best end points (:func:`fitting._start.local_starts`: the best continued,
   pattern moves along the line of the best optima, a small Latin hypercube, widened
   after a round without progress), the same compiled call, until the widest round no
   longer lowers $\chi^2$. The smallest $\chi^2$ wins;
   the pool also returns the Jacobian of every end point, so the best one's is reused
   for the uncertainty.
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
at the detection ($\delta = 0$); ``force_offset=True`` adds a force offset $F_0$ [N].

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
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

import jaxcontact as jc
from jaxcontact._progress import Progress
from jaxcontact._validate import plain

from ._caller import warn_at_caller
from ._curve import Curve
from ._least_squares import LBFGS, RESULTS, LevenbergMarquardt, Solution, run_pool, run_starts
from ._objective import effective_force, internal_jacobian, predict, residuals
from ._parameters import Parameterisation, make_parameterisation
from ._prepare import (
    SEGMENTS,
    CurveBatch,
    check_indentation_range,
    check_segments,
    contact_point_mode,
    prepare_curves,
    select_fit_segments,
)
from ._quality import assess, check_contact_signal, r_squared
from ._result import FitResult, ModelChoice
from ._spec import (
    ModelSpec,
    make_spec,
    normalise_names,
    offsets,
    parameter_info,
    rheology_name,
)
from ._start import (
    LocalRounds,
    data_scales,
    default_bounds,
    initial_guess,
    local_starts,
    nested_starts,
    search_starts,
)
from ._uncertainty import IdentifiabilityWarning, ModelValidityWarning, gauss_newton

__all__ = ["OPTIMISERS", "fit", "solve", "solve_batch", "DEFAULT_STARTS",
           "DEFAULT_LOCAL_ROUNDS"]

#: The optimisers of :func:`fit` and :func:`solve`.
OPTIMISERS = ("lm", "lbfgs")

#: Default number of starts of the global search.
DEFAULT_STARTS = 16

#: Default largest number of local rounds after the global search.
DEFAULT_LOCAL_ROUNDS = 3


def _fn(spec: ModelSpec):
    """`fn(z, ctx)`: weighted residuals at the free vector `z`, `ctx = (param, data)`."""

    def fn(z, ctx):
        param, data = ctx
        return residuals(param.natural(z), data, spec)

    return fn


def _solver(optimiser: str, rtol: float, atol: float, gtol: float, max_steps: int):
    if optimiser == "lm":
        return LevenbergMarquardt(rtol=rtol, atol=atol, max_steps=max_steps)
    if optimiser == "lbfgs":
        return LBFGS(rtol=rtol, gtol=gtol, max_steps=max_steps)
    raise ValueError(f"optimiser must be one of {OPTIMISERS}; got {optimiser!r}")


_OPTIONS = ("rtol", "atol", "gtol", "max_steps", "optimiser", "workers")


@functools.partial(jax.jit, static_argnames=_OPTIONS)
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
                keep_jacobian: bool = False, limits=None) -> Solution:
    """Independent problems in one compiled call, scheduled as a pool of `workers` lanes.

    `params`, `datas` and `z0s` carry a leading problem axis (stack equally shaped problems
    with ``jax.tree.map(lambda *x: jnp.stack(x), *problems)``; the free parameters must be
    the same); one start per problem. Returns a :class:`fitting.Solution` per problem
    (`z`, `chi2`, `result`, `steps`; with `keep_jacobian` also the residuals `r` and their
    Jacobian `J` with respect to `z` at the end point of each, Levenberg–Marquardt only).
    `limits`: a step limit per problem (default `max_steps` for all; 0: not run).

    `devices`: the devices to spread the problems over (default: every local device of
    JAX's default backend). With more than one, the problems are split into equal shares
    (the last problem repeated to fill them; its copies are dropped) and every device runs
    its own pool, in one `jax.pmap` call. Results do not depend on the split.
    """
    devices = list(jax.local_devices() if devices is None else devices)
    if not devices:
        raise ValueError("devices: give at least one device (or None for all local ones)")
    n = z0s.shape[0]
    n_dev = max(1, min(len(devices), n))
    opts = dict(workers=int(workers), rtol=float(rtol), atol=float(atol), gtol=float(gtol),
                max_steps=int(max_steps), optimiser=optimiser,
                keep_jacobian=bool(keep_jacobian))
    limits = np.broadcast_to(np.asarray(max_steps if limits is None else limits,
                                        dtype=np.int32), (n,))
    if n_dev == 1:
        with jax.default_device(devices[0]):
            return _solve_batch(spec, params, datas, z0s, limits, **opts)
    share = -(-n // n_dev)
    fill = np.minimum(np.arange(n_dev * share), n - 1)

    def split(x):
        x = jnp.asarray(x)[fill]
        return x.reshape((n_dev, share) + x.shape[1:])

    run = _pmapped_pool(spec, tuple(devices[:n_dev]), tuple(sorted(opts.items())))
    out = run(jax.tree.map(split, params), jax.tree.map(split, datas), split(z0s),
              split(limits))
    return jax.tree.map(lambda x: x.reshape((n_dev * share,) + x.shape[2:])[:n], out)


@functools.partial(jax.jit, static_argnames=_OPTIONS + ("keep_jacobian",))
def _solve_batch(spec, params, datas, z0s, limits, *, workers, rtol, atol, gtol, max_steps,
                 optimiser, keep_jacobian):
    solver = _solver(optimiser, rtol, atol, gtol, max_steps)
    return run_pool(solver, _fn(spec), z0s, (params, datas), workers, limits=limits,
                    keep_jacobian=keep_jacobian)


@functools.lru_cache(maxsize=16)
def _pmapped_pool(spec, devices, opts):
    # every device runs `_solve_batch` on its share
    return jax.pmap(lambda p, d, z, lim: _solve_batch(spec, p, d, z, lim, **dict(opts)),
                    devices=list(devices))


@functools.partial(jax.jit, static_argnames=("solver", "workers"))
def _search(spec, param, data, z0s, limits, solver, workers) -> Solution:
    """All starts in one pool, each with its step limit; the :class:`Solution` of each
    (with `r`, `J`; J w.r.t. z)."""
    n = z0s.shape[0]
    ctxs = jax.tree.map(lambda x: jnp.broadcast_to(x, (n,) + jnp.shape(x)), (param, data))
    return run_pool(solver, _fn(spec), z0s, ctxs, workers, limits=limits,
                    keep_jacobian=True)


@jax.jit
def _model_at(spec, param, u, data):
    """At internal coordinates `u`: the model solution, the model force at the sample times
    and the force as fitted (jump-off resolved inside its sample interval), with the force
    offset."""
    p = param.to_natural(u)
    sol = predict(spec, p, data)
    _, f0 = offsets(spec, p)
    point = jnp.where(jnp.isfinite(sol.force), sol.force, 0.0) + f0
    return sol, point, effective_force(sol, data) + f0


def _compile_in_background(fn, *args) -> threading.Thread:
    """Call the jitted `fn(*args)` once in a thread, so that its compilation (XLA compiles
    outside the GIL) overlaps the search's; a later call with equally shaped arguments
    finds it compiled. Join the thread before that call. An error is left for that call
    to raise."""

    def run():
        try:
            jax.block_until_ready(fn(*args))
        except Exception:  # noqa: BLE001 - the real call reports it
            pass

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def _r2(model, data, mask) -> float:
    """$R^2$ over the masked samples, each weighted by the measured samples it stands for."""
    return r_squared(model, data.force, data.weight, mask)


def _check_options(n_starts, max_steps, optimiser, rtol):
    for name, v, lo in (("n_starts", n_starts, 1), ("max_steps", max_steps, 1)):
        if v is not None and (not isinstance(v, int | np.integer) or v < lo):
            raise ValueError(f"{name} must be an integer >= {lo}; got {plain(v)}")
    if optimiser not in OPTIMISERS:
        raise ValueError(f"optimiser must be one of {OPTIMISERS}; got {optimiser!r}")
    if not (isinstance(rtol, int | float) and 0 < rtol < 1):
        raise ValueError(f"rtol must be a number in (0, 1); got {plain(rtol)}")


def _options(curves, *, radius, profile, model, rheology, spring_constant, initial, fixed,
             bounds, contact_point, force_offset, n_starts, max_samples, cells, max_steps,
             optimiser, rtol, seed, local_rounds, indentation_range=None, segments=None):
    """Checked options of :func:`fit` (`ValueError` naming the argument): the curves as a
    list, the options of every step of the chain of models, and the chain (rheologies)."""
    if isinstance(curves, Curve):
        curves = [curves]
    curves = list(curves)
    if not curves or not all(isinstance(c, Curve) for c in curves):
        raise ValueError("curves: give a Curve or a non-empty list of Curve objects")
    n_starts = DEFAULT_STARTS if n_starts is None else n_starts
    _check_options(n_starts, max_steps, optimiser, rtol)
    if not (isinstance(local_rounds, int | np.integer) and local_rounds >= 0):
        raise ValueError(f"local_rounds must be an integer >= 0; got {plain(local_rounds)}")
    contact_point = contact_point_mode(contact_point, curves)
    indentation_range = check_indentation_range(indentation_range)
    segments = check_segments(segments, model)
    if profile is None:
        if radius is None or not (isinstance(radius, int | float) and math.isfinite(radius)
                                  and radius > 0):
            raise ValueError(f"radius must be finite and > 0 [m]; got {plain(radius)}")
        profile = jc.Parabola(float(radius))
    elif radius is not None:
        raise ValueError("give either radius or profile, not both")
    if spring_constant is not None:
        ks = np.atleast_1d(np.asarray(spring_constant, dtype=float))
        if not np.all(np.isfinite(ks) & (ks > 0)):
            raise ValueError(f"spring_constant must be finite and > 0 [N/m]; got "
                             f"{plain(spring_constant)}")
    if rheology == "auto":
        chain = ["standard", "prony:2", "prony:3"]
    else:
        spec0 = make_spec(model, rheology, compliant=spring_constant is not None, cells=cells)
        chain = ["standard"] + [f"prony:{k}" for k in range(2, spec0.arms + 1)] \
            if spec0.rheology == "prony" and spec0.arms > 1 else [rheology]
    opts = dict(radius=radius, profile=profile, model=model, spring_constant=spring_constant,
                initial=initial, fixed=fixed, bounds=bounds, contact_point=contact_point,
                force_offset=force_offset, n_starts=n_starts, max_samples=max_samples,
                cells=cells, max_steps=max_steps, optimiser=optimiser, rtol=rtol, seed=seed,
                local_rounds=int(local_rounds), indentation_range=indentation_range,
                segments=segments)
    return curves, opts, chain


def fit(
    curves: Curve | Sequence[Curve],
    *,
    radius: float | None = None,
    profile: jc.AbstractProfile | None = None,
    model: str = "relaxed",
    rheology: str = "standard",
    spring_constant: float | Sequence[float] | None = None,
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
    progress: bool = True,
    optimiser: str = "lm",
    rtol: float = 1e-8,
    seed: int = 0,
    local_rounds: int = DEFAULT_LOCAL_ROUNDS,
) -> FitResult:
    r"""Identify the rheology, $\Delta\gamma$ (and the contact point) from one or more curves.

    **Arguments:**

    - `curves`: a :class:`Curve` or a list of them (different speeds and holds share the
      material parameters). Indentation [m] positive into the sample, 0 at the contact
      point; force [N] compressive positive, adhesive negative.
    - `radius`: parabolic indenter radius $R$ [m], or any jaxcontact `profile`.
    - `model`: "relaxed" (default, as ``jaxcontact fit --model``: :func:`jaxcontact.retract`
      on the retract after a hold long enough to relax; a `ModelValidityWarning` says when
      the curves have no such hold) or "history" (:func:`jaxcontact.simulate`: approach,
      hold, retract).
    - `rheology`: "standard" ($G_0, G_1, \eta_1$), "prony:N" ($G_\infty$, $G_k$, $\tau_k$;
      fitted nested from the standard model) or "auto" (standard, prony:2, prony:3; the
      smallest BIC is kept).
    - `spring_constant`: cantilever stiffness [N/m] (one, or one per curve): history model
      under :class:`jaxcontact.CompliantLoading`. `None`: displacement control.
    - `initial`, `fixed`: values by name (``"G0"`` or ``"G0_Pa"``); `initial` sets the first
      start, `fixed` holds a parameter.
    - `bounds`: `{name: (lower, upper)}` natural units; replaces the default bounds of that
      parameter (:func:`fitting._start.default_bounds`).
    - `contact_point` (the vocabulary of ``jaxcontact fit --contact-point``,
      :data:`fitting._prepare.CONTACT_POINT`): "fit" (the indentation offset $\delta$ [m]
      is fitted, started at the detected contact), "detect" (the contact point the loader
      detected is used as it is), "none" (the curves are indentation already, 0 at
      contact; used as they are), or `None`: "fit" when a curve's contact point was
      detected by a loader, else as it is. "fixed" (older spelling) means "detect".
    - `force_offset`: also fit a force offset $F_0$ [N] (a baseline error).
    - `n_starts`: starts of the global search (default :data:`DEFAULT_STARTS`).
    - `max_samples`: largest number of samples per curve (default by model:
      :data:`fitting._prepare.DEFAULT_MAX_SAMPLES`).
    - `indentation_range`: ``(low, high)`` [m]: only samples with indentation in it are
      fitted (nanite's ``range_x``); the model still runs through the whole history.
    - `segments`: the segments fitted, e.g. ``("approach",)`` or ``"approach,retract"``
      (`None` or ``"all"``: every segment the model uses). The history model needs the
      approach; the relaxed model (the retract-only fit of any rheology) the retract. An
      approach-only fit determines the moduli and nothing of $\Delta\gamma$ (the model's
      approach is non-adhesive, the JKR limit): `work_of_adhesion` is then held at its
      `fixed` value, or at its start value, and the result's `warnings` say so.
    - `cells`: foundation grid of the history model. `max_steps`: iterations per start.
    - `progress`: print the stages to stderr. `optimiser`: "lm" (Levenberg–Marquardt) or
      "lbfgs" (optax L-BFGS). `rtol`:
      convergence tolerance. `seed`: of the Latin hypercube.
    - `local_rounds`: at most this many further rounds of as many starts around the best
      end points (:func:`fitting._start.local_starts`; they reuse the compiled search, a
      round without progress is followed by a wider one, and they stop when the widest
      does not lower $\chi^2$), default
      :data:`DEFAULT_LOCAL_ROUNDS`; 0: the global search alone.

    **Returns:** a :class:`FitResult` (print it for a summary). Parameters the data do not
    determine, or that sit at a bound, are named in its `warnings` and `status` (also
    issued as :class:`IdentifiabilityWarning`).

    **Raises:** `ValueError` naming the argument for bad options or data.
    """
    show = Progress(progress, "fit").message  # one timestamped line per call
    curves, opts, chain = _options(
        curves, radius=radius, profile=profile, model=model, rheology=rheology,
        spring_constant=spring_constant, initial=initial, fixed=fixed, bounds=bounds,
        contact_point=contact_point, force_offset=force_offset, n_starts=n_starts,
        max_samples=max_samples, cells=cells, max_steps=max_steps, optimiser=optimiser,
        rtol=rtol, seed=seed, local_rounds=local_rounds, indentation_range=indentation_range,
        segments=segments)
    results: list[FitResult] = []
    for rh in chain:
        previous = results[-1] if results else None
        quiet = rh != chain[-1] and rheology != "auto"
        with warnings.catch_warnings():
            if quiet:  # a step of the nested chain: its warnings are not the result's
                warnings.simplefilter("ignore", IdentifiabilityWarning)
                warnings.simplefilter("ignore", ModelValidityWarning)
            results.append(_fit_one(curves, rheology=rh, previous=previous, show=show,
                                    warn=not quiet and rheology != "auto", **opts))
    if len(results) == 1:
        return results[0]
    if rheology != "auto":
        return results[-1]
    choices = [ModelChoice(rheology=r.rheology, chi2=r.chi2, k=r.n_free, n=r.n_data,
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


def _problem(curves, *, profile, model, rheology, spring_constant, initial, fixed, bounds,
             contact_point, force_offset, n_starts, max_samples, cells, seed, previous,
             indentation_range=None, host=False, segments=None, **_) -> _Problem:
    spec = make_spec(model, rheology, compliant=spring_constant is not None, cells=cells,
                     contact_offset=contact_point == "fit", force_offset=force_offset)
    info = parameter_info(spec)
    names = [n for n, _, _ in info]
    curves = select_fit_segments(curves, segments)
    check_contact_signal(curves, spec)
    data = prepare_curves(curves, spec, profile=profile, spring_constant=spring_constant,
                          max_samples=max_samples, indentation_range=indentation_range,
                          host=host)
    scales = data_scales(curves, spec, profile)
    guess = initial_guess(curves, spec, profile, scales)
    guess.update(normalise_names(initial, names, "initial"))
    fixed, notes = _approach_only(data, guess, normalise_names(fixed, names, "fixed"))
    bnds = default_bounds(spec, scales)
    starts = [guess] + search_starts(spec, scales, n_starts - 1, seed=seed)
    if previous is not None:
        nested = nested_starts(spec, previous.spec, previous.as_dict(), scales)
        starts += nested
        _contain(bnds, nested, [n for n, _, kind in info if kind == "time"])
    bnds.update(normalise_names(bounds, names, "bounds"))
    param = make_parameterisation(info, guess, fixed=fixed, bounds=bnds,
                                  scales={"contact_offset": scales.depth,
                                          "force_offset": scales.force_range})
    zs = param.z_of(param.to_internal([[s.get(n, guess[n]) for n in names]
                                       for s in starts]))
    return _Problem(spec, info, names, param, data, zs, curves, notes)


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
    if np.any(retract):
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


def _improved(chi2, before: float) -> bool:
    """A round improved the best loss by more than a relative 1e-7."""
    return _best_loss(chi2) < before * (1.0 - 1e-7)


def _local_search(params, outs: list[Solution], run, *, n: int, local_rounds: int,
                  seed: int, max_steps: int, show=None) -> list[Solution]:
    """The local rounds of each problem after its global search (one home for :func:`fit`
    and :func:`fitting.fit_each`).

    `params`: the problems' parameterisations; `outs`: their global searches (host
    :class:`Solution`, one lane per start); `run(starts, limits)`: one compiled call of
    the pool on `n` starts per problem with a step limit per start, returning a host
    :class:`Solution` per problem. Each round gives every problem whose rounds are not
    done `n` starts (:func:`fitting._start.local_starts`) with `max_steps` each; a problem
    whose rounds are done gets limit 0 (not run: it costs one lane-step a start). Returns
    the merged solutions.
    """
    outs = list(outs)
    rounds = [LocalRounds() for _ in outs]
    for k in range(local_rounds):
        if all(r.done for r in rounds):
            break
        before = [_best_loss(o.chi2) for o in outs]
        starts = [local_starts(param, o.z, o.chi2, n, seed=seed + 1 + k, widen=r.widen)
                  for param, o, r in zip(params, outs, rounds, strict=True)]
        limits = [np.full(n, 0 if r.done else max_steps, dtype=np.int32) for r in rounds]
        new = run(starts, limits)
        for j, r in enumerate(rounds):  # a problem whose rounds are done keeps its lanes
            if r.done:
                continue
            widen = r.widen
            outs[j] = outs[j].concat(new[j])
            r.update(_improved(outs[j].chi2, before[j]))
            if show is not None:
                show(f"local round {k + 1} (width x{widen:g}): chi2 {before[j]:.8g} -> "
                     f"{_best_loss(outs[j].chi2):.8g}")
    return outs


def _fit_one(curves, *, rheology, previous, show, warn, **opts) -> FitResult:
    timings = {}
    t_start = time.perf_counter()
    pb = _problem(curves, rheology=rheology, previous=previous, **opts)
    show(f"{pb.spec.model} model, {rheology_name(pb.spec)}: {pb.data.n_curves} curve(s), "
         f"{pb.data.n_samples} samples (standing for {pb.data.n_measured} measured), "
         f"{len(pb.param.free)} free parameter(s), {len(pb.zs)} start(s)")
    timings["prepare"] = time.perf_counter() - t_start

    t0 = time.perf_counter()
    # the forward model at the optimum (`_finish`) compiles while the search runs
    model_at = _compile_in_background(_model_at, pb.spec, pb.param,
                                      jnp.asarray(pb.param.internal_host(pb.zs[0])), pb.data)
    max_steps = int(opts["max_steps"])
    solver = _solver(opts["optimiser"], float(opts["rtol"]), 1e-9, 1e-8, max_steps)

    def run(starts, limits):
        return [jax.device_get(_search(pb.spec, pb.param, pb.data, jnp.asarray(zs),
                                       jnp.asarray(lim), solver, min(8, len(zs))))
                for zs, lim in zip(starts, limits, strict=True)]

    out = run([pb.zs], [np.full(len(pb.zs), max_steps, dtype=np.int32)])
    out = _local_search([pb.param], out, run, n=len(pb.zs),
                        local_rounds=opts["local_rounds"], seed=opts["seed"],
                        max_steps=max_steps, show=show)[0]
    model_at.join()
    timings["optimise"] = time.perf_counter() - t0
    return _finish(pb, curves, opts["profile"], out, opts["optimiser"], show=show,
                   warn=warn, timings=timings, t_start=t_start, max_steps=max_steps)


def _finish(pb: _Problem, curves, profile, out: Solution, optimiser, *, show, warn, timings,
            t_start, max_steps=None) -> FitResult:
    """The :class:`FitResult` of problem `pb` from the search's :class:`Solution` `out`
    (every start; its `r`, `J` if kept, J with respect to z)."""
    spec, param, data, names, info = pb.spec, pb.param, pb.data, pb.names, pb.info
    t0 = time.perf_counter()
    z_all, chi2_all, steps_all = (np.asarray(x) for x in (out.z, out.chi2, out.steps))
    ok_all = np.asarray(out.converged)
    finite = np.isfinite(chi2_all)
    best = int(np.argmin(np.where(finite, chi2_all, np.inf)))
    z = z_all[best]
    u = param.internal_host(z)
    dudz = param.dinternal_dz(z)
    if out.J is not None and np.all(np.abs(dudz) > 1e-8):
        r, J = np.asarray(out.r[best]), np.asarray(out.J[best]) / dudz[None, :]
    else:
        r, J = (np.asarray(x) for x in internal_jacobian(spec, param, jnp.asarray(u), data))
    u, J = _sort_arms(spec, param, u, J)
    order = np.argsort(np.where(finite, chi2_all, np.inf))
    show(f"search: chi2 of the best starts {', '.join(f'{chi2_all[i]:.6g}' for i in order[:4])}"
         f"; {RESULTS.describe(out.result[best])}, {int(steps_all[best])} steps "
         f"({len(chi2_all)} starts, {int(np.sum(steps_all))} steps in all)")
    sol, model_force, fitted_force = jax.device_get(
        _model_at(spec, param, jnp.asarray(u), data))
    timings["optimise"] = timings.get("optimise", 0.0) + time.perf_counter() - t0

    t0 = time.perf_counter()
    p = param.to_natural_host(u)
    no_jump = not np.any(np.asarray(data.detaches) > 0)
    unc = gauss_newton(param, u, r, J, names, n_data=data.n_measured,
                       weights=np.asarray(data.weight).ravel(), no_detachment=no_jump,
                       warn=warn)
    valid = np.asarray(data.valid) > 0
    model_force = np.asarray(model_force)
    radius_model = np.asarray(sol.contact_radius)
    in_contact = valid & ((np.asarray(data.contact) > 0) | (np.nan_to_num(radius_model) > 0))
    k = int(sum(1 for i in param.free if not unc.status[i].startswith("at ")))
    n = data.n_measured
    chi2 = unc.chi2
    ll = n * math.log(max(chi2, 1e-300) / n)
    curves = pb.curves or curves  # as fitted: restricted to the chosen segments
    msgs = list(unc.warnings)
    msgs += _validity_warnings(spec, curves, profile, radius_model, valid)
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
        r_squared=_r2(model_force, data, valid),
        r_squared_contact=_r2(model_force, data, in_contact),
        aic=ll + 2 * k, bic=ll + k * math.log(n), converged=bool(ok_all[best]),
        start_losses=chi2_all,
        spec=spec, data=data, curves=curves, profile=profile,
        radius=float(profile.R) if isinstance(profile, jc.Parabola | jc.Sphere) else None,
        model_solution=sol, model_force=model_force,
        fitted_force=np.asarray(fitted_force), in_contact=in_contact,
        parameterisation=param, optimiser=optimiser, start_steps=steps_all,
        warnings=msgs, timings=timings,
    )
    flagged = assess(result, max_steps=max_steps)  # quality per segment, flags, convergence
    if warn:
        for m in flagged:
            warn_at_caller(m, ModelValidityWarning)
    show(f"done: chi2_red = {result.reduced_chi2:.4g}, R^2 = {result.r_squared:.5f}, "
         f"R^2 in contact = {result.r_squared_contact:.5f}")
    return result


def _sort_arms(spec, param, u, J):
    """Prony arms in increasing order of relaxation time (the model does not depend on the
    order; a reported ``tau_1 < tau_2 < ...`` does). Only when every arm is free with the
    same bounds, so that the order is the only difference between them."""
    if spec.rheology != "prony" or spec.arms < 2:
        return u, J
    n = spec.arms
    g_idx = list(range(1, 1 + n))
    t_idx = list(range(1 + n, 1 + 2 * n))
    free = list(param.free)
    lo, hi = np.asarray(param.lower), np.asarray(param.upper)
    for idx in (g_idx, t_idx):
        if not all(i in free for i in idx):
            return u, J
        if not (np.all(lo[idx] == lo[idx[0]]) and np.all(hi[idx] == hi[idx[0]])):
            return u, J
    order = np.argsort(u[t_idx], kind="stable")
    perm = np.arange(len(u))
    perm[g_idx] = np.asarray(g_idx)[order]
    perm[t_idx] = np.asarray(t_idx)[order]
    col = {i: c for c, i in enumerate(free)}
    return u[perm], J[:, [col[perm[i]] for i in free]]


def _validity_warnings(spec, curves, profile, radius_model, valid) -> list[str]:
    out = []
    a_max = float(np.nanmax(np.where(valid, radius_model, 0.0)))
    check = jc.profile_validity(profile, a_max)  # the profile's own limit (every profile)
    if not bool(check.valid):
        out.append(f"the model's contact radius reaches {a_max:.3g} m, {float(check.fraction):.2f} "
                   f"times the limit {float(check.limit):.3g} m of the {type(profile).__name__} "
                   f"profile: {check.reason}; check the probe")
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
