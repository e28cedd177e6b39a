r"""The options of an identification as one validated, frozen object (:class:`FitOptions`),
and the options that only the batched :func:`fitting.fit_each` understands
(:class:`BatchOptions`).

:func:`fitting.fit` and :func:`fitting.fit_each` take either an options object
(``options=FitOptions(...)``) or the same fields as keywords (``fit(curve, radius=...)``):
both become one :class:`FitOptions` (:meth:`FitOptions.merge`), checked once, when it is
made, with a `ValueError` naming the option and its allowed values. The rest of the
pipeline (:mod:`fitting._pipeline`) reads the checked object only.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import math
import types
from collections.abc import Callable, Mapping, Sequence

import jax
import numpy as np

import jaxcontact as jc
from jaxcontact._devices import memory_limit, usable_cores
from jaxcontact._validate import plain

from ._least_squares import LBFGS, AbstractLeastSquaresSolver, LevenbergMarquardt
from ._prepare import CONTACT_POINT, check_indentation_range, check_segments
from ._spec import ModelSpec, make_spec, rheology_kind, rheology_name

__all__ = ["FitOptions", "BatchOptions", "OPTIMISERS", "DEFAULT_STARTS",
           "DEFAULT_LOCAL_ROUNDS", "DEFAULT_SCREEN", "DEFAULT_EXPLORE_STEPS",
           "DEFAULT_ABANDON", "make_solver"]

#: Default number of starts of the global search.
DEFAULT_STARTS = 16

#: Default largest number of local rounds after the global search.
DEFAULT_LOCAL_ROUNDS = 3

#: Default iterations per start.
DEFAULT_MAX_STEPS = 200

#: Default iterations of an exploring start (every start but the continued best of a local
#: round, and with local rounds the global search's).
DEFAULT_EXPLORE_STEPS = 200

#: Default factor of a local round's bound on $\chi^2$: a start of a round that is not
#: widened (not the continued best) whose $\chi^2$ is still above this many times the best
#: known before the round after :data:`fitting._least_squares.ABANDON_AFTER` steps is
#: abandoned (measured: ``benchmarks/results/fit_each.md``, "Abandoning a local round's
#: far starts").
DEFAULT_ABANDON = 100.0

#: Default number of screened points of the global search (0: not screened).
DEFAULT_SCREEN = 0

#: Distinct end points of a search on a coarser grid (`FitOptions.search_cells`) that are
#: continued on the fit's own grid, the best first.
POLISHED_POINTS = 3

#: The optimisers by name: each makes its least-squares solver from the tolerances.
_SOLVERS: dict[str, Callable[..., AbstractLeastSquaresSolver]] = {
    "lm": lambda rtol, atol, gtol, max_steps: LevenbergMarquardt(
        rtol=rtol, atol=atol, max_steps=max_steps),
    "lbfgs": lambda rtol, atol, gtol, max_steps: LBFGS(
        rtol=rtol, gtol=gtol, max_steps=max_steps),
}

#: The optimisers of :func:`fitting.fit` and :func:`fitting.solve`.
OPTIMISERS = tuple(_SOLVERS)

#: The rheologies that ``rheology="auto"`` compares (nested; the smallest BIC is kept).
AUTO_CHAIN = ("standard", "prony:2", "prony:3")


def make_solver(optimiser: str, *, rtol: float = 1e-8, atol: float = 1e-9,
                gtol: float = 1e-8, max_steps: int = DEFAULT_MAX_STEPS
                ) -> AbstractLeastSquaresSolver:
    """The least-squares solver of `optimiser` (one of :data:`OPTIMISERS`); `ValueError`
    naming the allowed ones."""
    if optimiser not in _SOLVERS:
        raise ValueError(f"optimiser must be one of {OPTIMISERS}; got {optimiser!r}")
    return _SOLVERS[optimiser](rtol, atol, gtol, max_steps)


def _integer(name: str, value, lo: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < lo:
        raise ValueError(f"{name} must be an integer >= {lo}; got {plain(value)}")
    return int(value)


def _mapping(name: str, value) -> Mapping | None:
    """A read-only copy of `value` (None stays None); the names are checked against the
    model's parameters when the problem is made (they depend on the model and the
    contact point)."""
    if value is None:
        return None
    if not isinstance(value, Mapping):
        raise ValueError(f"{name} must be a mapping {{parameter name: value}} or None; got "
                         f"{plain(value)}")
    return types.MappingProxyType(dict(value))


def _same(a, b) -> bool:
    """`a` and `b` hold the same values (arrays, profiles and mappings compared by their
    leaves)."""
    if a is b:
        return True
    a, b = (dict(x) if isinstance(x, Mapping) else x for x in (a, b))
    la, ta = jax.tree.flatten(a)
    lb, tb = jax.tree.flatten(b)
    if ta != tb:
        return False
    try:
        return all(np.array_equal(np.asarray(x), np.asarray(y))
                   for x, y in zip(la, lb, strict=True))
    except (TypeError, ValueError):
        return False


class _Options:
    """What both option classes share: made from keywords or merged with them."""

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """The option names (the keywords of the functions that take them)."""
        return tuple(f.name for f in dataclasses.fields(cls))

    def replace(self, **changes):
        """A copy with `changes` (checked like a new object)."""
        return dataclasses.replace(self, **changes)

    @classmethod
    def merge(cls, options, keywords: Mapping, *, where: str):
        """The options of a call of `where` given `options` (an object of this class, or
        None) and the same options as `keywords`: a keyword that agrees with `options`
        is accepted, one that differs is a `ValueError` naming it (give each option in
        one place)."""
        if options is None:
            return cls(**keywords)
        if not isinstance(options, cls):
            raise TypeError(f"{where}: options must be a fitting.{cls.__name__}; got "
                            f"{type(options).__name__}")
        if not keywords:
            return options
        merged = options.replace(**keywords)
        clash = [k for k in keywords if not _same(getattr(merged, k), getattr(options, k))]
        if clash:
            raise ValueError(
                f"{where}: {', '.join(clash)} given both in options ("
                + ", ".join(f"{k}={plain(getattr(options, k))}" for k in clash)
                + ") and as keywords (" + ", ".join(f"{k}={plain(keywords[k])}" for k in clash)
                + "); give each option in one place, e.g. options.replace("
                + ", ".join(f"{k}=..." for k in clash) + ")")
        return merged


def split_keywords(keywords: Mapping, *classes, where: str) -> list[dict]:
    """`keywords` split by the option class that has each (in the order of `classes`);
    `TypeError` naming an unknown one and the known ones."""
    parts = [{} for _ in classes]
    for k, v in keywords.items():
        for part, cls in zip(parts, classes, strict=True):
            if k in cls.names():
                part[k] = v
                break
        else:
            known = [n for cls in classes for n in cls.names()]
            raise TypeError(f"{where}() got an unexpected keyword argument {k!r}; the options "
                            f"are {', '.join(known)} (and options=)")
    return parts


def keyword_signature(*classes):
    """A decorator giving `fn(curves, *, options=None, **keywords)` the signature of its
    keywords (the fields of `classes`, with their defaults), so that `help()` and
    `inspect` show them."""

    def decorate(fn):
        sig = inspect.signature(fn)
        head = [p for p in sig.parameters.values() if p.kind is not p.VAR_KEYWORD]
        fields = [inspect.Parameter(f.name, inspect.Parameter.KEYWORD_ONLY,
                                    default=f.default, annotation=f.type)
                  for cls in classes for f in dataclasses.fields(cls)]
        fn.__signature__ = sig.replace(parameters=head + fields)
        return fn

    return decorate


@dataclasses.dataclass(frozen=True, kw_only=True)
class FitOptions(_Options):
    r"""The options of :func:`fitting.fit` and :func:`fitting.fit_each`: one checked, frozen
    object (keywords only). Each field is also a keyword of both functions.

    Checked when made: a bad value is a `ValueError` naming the option and its allowed
    values (the parameter names in `initial`, `fixed` and `bounds` are checked against
    the model's when a fit starts: they depend on the rheology and the contact point).
    :meth:`replace` makes a changed copy (checked again).

    **Fields** (SI units; indentation positive into the sample, compressive force
    positive, adhesion negative):

    - `radius`: parabolic indenter radius $R$ [m], finite and > 0 (default `None`); or
    - `profile`: any :class:`jaxcontact.AbstractProfile` (default `None`). Give exactly
      one of `radius` and `profile` (:attr:`probe` is the profile used).
    - `model`: "relaxed" (default: :func:`jaxcontact.retract` on the retract after a hold
      long enough to relax; a `ModelValidityWarning` says when the curves have no such
      hold) or "history" (:func:`jaxcontact.simulate`: approach, hold, retract).
    - `rheology`: "standard" (default; $G_0, G_1, \eta_1$ [Pa, Pa, Pa s]), "elastic",
      "prony:N" with N in [1, 8] ($G_\infty$, $G_k$ [Pa], $\tau_k$ [s]; fitted nested from
      the standard model, :meth:`chain`) or "auto" (:func:`fitting.fit` only: standard,
      prony:2, prony:3, the smallest BIC kept).
    - `spring_constant`: cantilever stiffness [N/m], finite and > 0: one value, or (for
      :func:`fitting.fit` of several curves) one per curve; needs ``model="history"``
      (:class:`jaxcontact.CompliantLoading`). Default `None`: displacement control.
    - `initial`, `fixed`: `{name: value}` (``"G0"`` or ``"G0_Pa"``; Young's moduli ``E0``,
      ``E1``, ``E``, ``E_inf``, ``E_k`` as three times the shear modulus), natural units;
      `initial` sets the first start, `fixed` holds a parameter. Default `None`.
    - `bounds`: `{name: (lower, upper)}`, natural units; replaces the default bounds of
      that parameter (:func:`fitting.default_bounds`). Default `None`.
    - `contact_point`: "fit" (the indentation offset $\delta$ [m] is fitted, started at
      the detected contact), "detect" (the detected contact point is used as it is),
      "none" (the curves are indentation already, 0 at contact), "fixed" (older spelling
      of "detect"), or `None` (default): "fit" when a loader detected a curve's contact
      point, else as it is (:data:`fitting._prepare.CONTACT_POINT`).
    - `force_offset`: also fit a force offset $F_0$ [N] (a baseline error). Default False.
    - `force_drift`: also fit a force drift $s$ [N/s]: the model force plus the line
      $F_0 + s\,t$ ($t$ from the first fitted sample; implies `force_offset`), so that the
      data, not the preprocessing, decide how much of a trend in the force is baseline (the
      free approach and the free retract carry it). The history model only: the relaxed
      model fits the retract in contact, where a line and the relaxation trade off (on 17
      real curves the drift moved its values by tens of per cent on curves it did not
      flag: ``benchmarks/results/force_drift_relaxed.md``). Default False. Where the
      baseline was fitted constant and the free force rises (the `baseline_trend` flag),
      this is the fit that answers the flag. Its noise is the free force's scatter about
      its straight line (``ContactPoint.trend_noise``:
      :func:`fitting._prepare.curve_noise`), the fit without's the scatter about the
      baseline (``ContactPoint.noise``, which counts a trend as noise): compare the two
      $\chi^2$ in one noise, the other's times
      $(\sigma_\mathrm{noise}/\sigma_\mathrm{trend})^2$. A drift that is not the free
      force's own slope before contact takes up a misfit of the model instead (flag
      ``drift_not_baseline``, :func:`fitting._quality.drift_not_baseline`).
    - `n_starts`: starts of the global search, an integer >= 1 (default
      :data:`DEFAULT_STARTS`; `None` is the default).
    - `screen`: screened points of the global search, 0 or an integer >= `n_starts`
      (default :data:`DEFAULT_SCREEN`; `None` is the default): $\chi^2$ is evaluated (no
      Jacobian, no iteration: about a third of a Levenberg–Marquardt step each, measured)
      at `screen` points of the search's Latin hypercube, and the `n_starts` − 1 random
      starts are the best of them (the first start stays the data-based guess). 0: the
      random starts are the hypercube's first `n_starts` − 1 points, unscreened.
    - `max_samples`: largest number of samples per curve, an integer >= 4 (default `None`:
      by model, :data:`fitting._prepare.DEFAULT_MAX_SAMPLES`); subsampled without
      averaging.
    - `indentation_range`: ``(low, high)`` [m], finite, low < high: only samples with
      indentation in it are fitted (nanite's ``range_x``); the model still runs through
      the whole history. Default `None`: every sample.
    - `segments`: the segments fitted, names from ("approach", "hold", "retract") as a
      sequence or a comma-separated string (default `None` or "all": every segment the
      model uses). The history model needs the approach, the relaxed model the retract.
      An approach-only fit determines the moduli and nothing of $\Delta\gamma$:
      `work_of_adhesion` is then held (its `fixed` value, or its start value) and the
      result's `warnings` say so.
    - `cells`: foundation grid of the history model, an integer >= 2 (default 32): the
      grid of the result (its $\chi^2$, Jacobian, uncertainty and model curves).
    - `search_cells`: foundation grid of the history model's search (the global search
      and the local rounds), an integer in [2, `cells`] (default `None`: `cells`, one
      grid). Below `cells`, the best :data:`POLISHED_POINTS` distinct end points of the
      search are continued on `cells` (with `max_steps`, no rounds) and the best of those
      is the result (its $\chi^2$, Jacobian and model curves on `cells`;
      `start_losses` are the search's, on `search_cells`). A step costs less on a coarser
      grid, but the continuation is a second compiled program (~12 s on a 2-core CPU):
      worth it for maps of many curves, not for one. Measured with 16 of 32 cells
      (`benchmarks/results/fit_each.md`): a 64-curve history map 1.14–1.29 times
      faster once compiled; the optima within ±2·10⁻⁶ of the one-grid search's $\chi^2$ on real
      curves, lower on some and higher on others (neighbouring local optima of a rugged
      landscape, far inside the standard errors). Not used by the relaxed model.
    - `max_steps`: iterations per start, an integer >= 1 (default 200; `None` is the
      default).
    - `explore_steps`: iterations of an exploring start, an integer >= 1 (default
      :data:`DEFAULT_EXPLORE_STEPS`; `None` is the default; at most `max_steps`): with
      local rounds, every start of the global search and of a round except the first of
      a round (the best end point so far, continued with `max_steps`); a best end point
      stopped at this limit is continued with `max_steps` after the rounds. A start that
      crawls does not hold the search: the best one goes on.
    - `abandon`: a number > 1, or `None` (default :data:`DEFAULT_ABANDON`; `None`: never):
      a start of a local round that is not widened, other than the continued best, whose
      $\chi^2$ is still above `abandon` × the best $\chi^2$ known before the round after
      :data:`fitting._least_squares.ABANDON_AFTER` steps (the first evaluation counted) is
      stopped, :attr:`fitting.RESULTS.abandoned`: it started next to the best end points
      and went to a far basin. Its $\chi^2$ there is in `start_losses`. The global search,
      the widened rounds (exploring: their far starts found lower optima on real maps) and
      the continued best are never abandoned. Measured (``fit_each.md``): 5–10 % fewer
      steps on synthetic maps, the same optima on them and on real curves and maps.
    - `optimiser`: "lm" (Levenberg–Marquardt, default) or "lbfgs" (L-BFGS), see
      :data:`OPTIMISERS` and :meth:`solver`.
    - `rtol`: convergence tolerance (relative change of $\chi^2$, and for "lm" of the
      step), a number in (0, 1) (default 1e-8).
    - `seed`: of the Latin hypercube of starts, an integer >= 0 (default 0).
    - `local_rounds`: at most this many further rounds of `n_starts` starts around the
      best end points (:func:`fitting._start.local_starts`: a round without progress is
      followed by a wider one; they stop when the widest does not lower $\chi^2$), an
      integer >= 0 (default :data:`DEFAULT_LOCAL_ROUNDS`; 0: the global search alone).
    - `progress`: print the stages to stderr (default True).
    """

    radius: float | None = None
    profile: jc.AbstractProfile | None = None
    model: str = "relaxed"
    rheology: str = "standard"
    spring_constant: float | tuple[float, ...] | None = None
    initial: Mapping[str, float] | None = None
    fixed: Mapping[str, float] | None = None
    bounds: Mapping[str, tuple[float, float]] | None = None
    contact_point: str | None = None
    force_offset: bool = False
    force_drift: bool = False
    n_starts: int = DEFAULT_STARTS
    screen: int | None = None
    max_samples: int | None = None
    indentation_range: tuple[float, float] | None = None
    segments: tuple[str, ...] | None = None
    cells: int = 32
    search_cells: int | None = None
    max_steps: int = DEFAULT_MAX_STEPS
    explore_steps: int | None = None
    abandon: float | None = DEFAULT_ABANDON
    optimiser: str = "lm"
    rtol: float = 1e-8
    seed: int = 0
    local_rounds: int = DEFAULT_LOCAL_ROUNDS
    progress: bool = True

    def __post_init__(self):
        def put(name, value):
            object.__setattr__(self, name, value)

        if self.model not in ("relaxed", "history"):
            raise ValueError(f"model must be 'relaxed' or 'history'; got {self.model!r}")
        put("cells", _integer("cells", self.cells, 2))
        put("search_cells", self.cells if self.search_cells is None
            else _integer("search_cells", self.search_cells, 2))
        if self.search_cells > self.cells:
            raise ValueError(f"search_cells must be an integer in [2, cells = {self.cells}]; "
                             f"got {self.search_cells}")
        put("n_starts", _integer("n_starts", DEFAULT_STARTS if self.n_starts is None
                                 else self.n_starts, 1))
        put("screen", _integer("screen", DEFAULT_SCREEN if self.screen is None
                               else self.screen, 0))
        if 0 < self.screen < self.n_starts:
            raise ValueError(f"screen must be 0 or an integer >= n_starts ({self.n_starts}); "
                             f"got {self.screen}")
        put("max_steps", _integer("max_steps", DEFAULT_MAX_STEPS if self.max_steps is None
                                  else self.max_steps, 1))
        put("explore_steps", _integer("explore_steps", DEFAULT_EXPLORE_STEPS
                                      if self.explore_steps is None else self.explore_steps,
                                      1))
        if self.optimiser not in OPTIMISERS:
            raise ValueError(f"optimiser must be one of {OPTIMISERS}; got {self.optimiser!r}")
        if self.abandon is not None:
            if isinstance(self.abandon, bool) or not (
                    isinstance(self.abandon, int | float) and self.abandon > 1):
                raise ValueError(f"abandon must be a number > 1 or None; got "
                                 f"{plain(self.abandon)}")
            put("abandon", float(self.abandon))
        if isinstance(self.rtol, bool) or not (isinstance(self.rtol, int | float)
                                               and 0 < self.rtol < 1):
            raise ValueError(f"rtol must be a number in (0, 1); got {plain(self.rtol)}")
        put("rtol", float(self.rtol))
        put("local_rounds", _integer("local_rounds", self.local_rounds, 0))
        put("seed", _integer("seed", self.seed, 0))
        if self.max_samples is not None:
            put("max_samples", _integer("max_samples", self.max_samples, 4))
        if self.contact_point is not None and self.contact_point not in CONTACT_POINT:
            raise ValueError(f"contact_point must be one of "
                             f"{', '.join(map(repr, CONTACT_POINT))} or None; got "
                             f"{plain(self.contact_point)}")
        put("indentation_range", check_indentation_range(self.indentation_range))
        put("segments", check_segments(self.segments, self.model))
        if self.profile is None:
            r = self.radius
            if r is None or isinstance(r, bool) or not (isinstance(r, int | float)
                                                        and math.isfinite(r) and r > 0):
                raise ValueError(f"radius must be finite and > 0 [m]; got {plain(r)}")
            put("radius", float(r))
        elif self.radius is not None:
            raise ValueError("give either radius or profile, not both")
        elif not isinstance(self.profile, jc.AbstractProfile):
            raise ValueError(f"profile must be a jaxcontact profile (e.g. jc.Parabola(R)); "
                             f"got {type(self.profile).__name__}")
        if self.spring_constant is not None:
            try:
                ks = np.atleast_1d(np.asarray(self.spring_constant, dtype=float))
            except (TypeError, ValueError):
                ks = np.array([np.nan])
            if ks.ndim != 1 or not np.all(np.isfinite(ks) & (ks > 0)):
                raise ValueError(f"spring_constant must be finite and > 0 [N/m]; got "
                                 f"{plain(self.spring_constant)}")
            put("spring_constant", float(ks[0]) if np.ndim(self.spring_constant) == 0
                else tuple(float(k) for k in ks))
        for name in ("force_offset", "force_drift"):
            if not isinstance(getattr(self, name), bool | np.bool_):
                raise ValueError(f"{name} must be True or False; got "
                                 f"{plain(getattr(self, name))}")
        # a drift is a line: its offset is fitted with it
        put("force_offset", bool(self.force_offset) or bool(self.force_drift))
        put("force_drift", bool(self.force_drift))
        for name in ("initial", "fixed", "bounds"):
            put(name, _mapping(name, getattr(self, name)))
        if self.rheology != "auto":  # the model, rheology, loading and grid (named errors)
            make_spec(self.model, self.rheology, compliant=self.spring_constant is not None,
                      cells=self.cells, force_drift=self.force_drift)
        elif self.force_drift and self.model != "history":
            make_spec(self.model, force_drift=True)  # the named error
        elif self.spring_constant is not None and self.model != "history":
            raise ValueError("a compliant loading system (spring_constant) needs "
                             "model='history'")
        put("progress", bool(self.progress))

    @functools.cached_property
    def probe(self) -> jc.AbstractProfile:
        """The indenter's profile: `profile`, or a :class:`jaxcontact.Parabola` of `radius`."""
        return self.profile if self.profile is not None else jc.Parabola(self.radius)

    def chain(self) -> list[str]:
        """The rheologies fitted in turn, each started also from the previous optimum
        (:func:`fitting._start.nested_starts`): "prony:N" is "standard", "prony:2", …,
        "prony:N" (a richer model never ends worse than the simpler one it contains; the
        rheology's :attr:`fitting._spec.RheologyKind.nested`); "auto" is
        :data:`AUTO_CHAIN`; any other rheology is fitted alone."""
        if self.rheology == "auto":
            return list(AUTO_CHAIN)
        spec = make_spec(self.model, self.rheology, cells=self.cells)
        return rheology_kind(spec).nested(spec.arms) + [rheology_name(spec)]

    def search_spec(self, spec: ModelSpec) -> ModelSpec:
        """The model of the search for a fit of `spec`: the history model on its grid of
        `search_cells` (when coarser than ``spec.cells``), else `spec` itself."""
        if spec.model != "history" or self.search_cells >= spec.cells:
            return spec
        return dataclasses.replace(spec, cells=self.search_cells)

    def solver(self) -> AbstractLeastSquaresSolver:
        """The least-squares solver of every start (:func:`make_solver` of `optimiser`,
        `rtol` and `max_steps`)."""
        return make_solver(self.optimiser, rtol=self.rtol, max_steps=self.max_steps)

    def check_each_curve_alone(self) -> FitOptions:
        """These options for curves fitted one by one (:func:`fitting.fit_each`): one model
        for all (not "auto") and one spring constant (or each curve's own); `ValueError`
        naming the option otherwise. Returns `self`."""
        if self.rheology == "auto":
            raise ValueError("rheology: 'auto' is not offered by fit_each (a map needs one "
                             "model for all points); choose 'standard' or 'prony:N'")
        if self.spring_constant is not None and np.ndim(self.spring_constant) != 0:
            raise ValueError("spring_constant: give one value for all curves (or None: each "
                             "curve's own)")
        return self


@dataclasses.dataclass(frozen=True, kw_only=True)
class BatchOptions(_Options):
    """How :func:`fitting.fit_each` schedules its independent fits (what :func:`fitting.fit`,
    one problem, does not need). Checked when made, frozen, keywords only; each field is
    also a keyword of :func:`fitting.fit_each`.

    **Fields:**

    - `chunk`: curves per compiled call, an integer >= 1 (default `None`: 64 on a CPU,
      fewer where a small map would leave a stream without a chunk; 4,096 on an
      accelerator; :meth:`chunk_for`); every chunk has one shape (the last one padded with
      copies that are never run), so one compilation serves all.
    - `workers`: lanes of the pool of starts per device, an integer >= 1 (default `None`:
      :meth:`lanes`).
    - `devices`: the devices the chunk's starts are spread over (default `None`: every
      local device of JAX's default backend; :func:`fitting.solve_batch`).
    - `streams`: chunks searched at the same time, each from its own host thread, an
      integer >= 1 (default `None`: :meth:`streams_for`: on a CPU one per usable core
      and device, on an accelerator 1). The results do not depend on it: every chunk's
      search is its own (the same chunks, starts and rounds), only when it runs.

    Why the defaults differ by platform: a step of the pool costs a CPU core time in
    proportion to its lanes, and a lane idles once its start has converged, so a CPU runs
    a few lanes that refill from the queue, and a chunk holds many times more starts than
    lanes (about 8 a lane), so that the pool's tail (a few long runs after the queue is
    empty, the other lanes idle) is a small part of each call (64 curves a chunk ran a map
    2–3 times faster than 8 curves on 64 lanes on 2 cores, the same steps and optima; 8
    curves on 16 lanes 1.6 times faster than on 64); an accelerator costs about the same per step
    for one lane or $10^5$ (the step's kernels are launch-bound below that), so every start
    of a large chunk gets its own lane and the chunk's problems share every step
    (measured: ``benchmarks/results/fit_each.md``). A CPU searches one chunk per core at
    once: XLA spreads one chunk's small kernels over the cores at a loss (a 256-curve map
    on 2 cores: 1.3 times the speed of one core, 1.8 times with two chunks at once,
    ``fit_each.md``, "Two chunks at once"); an accelerator's one device is kept busy by one.
    """

    chunk: int | None = None
    workers: int | None = None
    devices: Sequence | None = None
    streams: int | None = None

    def __post_init__(self):
        if self.chunk is not None:
            object.__setattr__(self, "chunk", _integer("chunk", self.chunk, 1))
        if self.workers is not None:
            object.__setattr__(self, "workers", _integer("workers", self.workers, 1))
        if self.streams is not None:
            object.__setattr__(self, "streams", _integer("streams", self.streams, 1))
        if self.devices is not None:
            devices = tuple(self.devices)
            if not devices:
                raise ValueError("devices: give at least one device (or None for all local "
                                 "ones)")
            object.__setattr__(self, "devices", devices)

    @property
    def accelerated(self) -> bool:
        """Whether the fits run on an accelerator (the first of `devices`, or JAX's default
        backend, is not a CPU)."""
        if self.devices is not None:
            return self.devices[0].platform != "cpu"
        return jax.default_backend() != "cpu"

    def chunk_for(self, problems: int, *, problem_bytes: int | None = None) -> int:
        """Problems per compiled call for `problems` problems: `chunk`, or on a CPU 64
        (the problems over the streams of :meth:`streams_for` where 64 would give fewer
        chunks than streams), and 4,096 on an accelerator, fewer where `problem_bytes` (an
        upper estimate of one problem's device memory during the search, all its starts)
        times the chunk would pass half of the device's memory; never more than
        `problems`."""
        if self.chunk is not None:
            size = self.chunk
        elif not self.accelerated:
            # a map of fewer chunks than streams split so that every stream has one
            # (faster than one chunk whose kernels XLA spreads over the cores:
            # benchmarks/results/fit_each.md, "A small map's chunks")
            streams = self._streams()
            size = (_CPU_CHUNK if -(-problems // _CPU_CHUNK) >= streams
                    else -(-problems // streams))
        else:
            size = _ACCELERATOR_CHUNK
            device = self.devices[0] if self.devices is not None else jax.local_devices()[0]
            limit = memory_limit(device)
            if limit is not None and problem_bytes:
                size = min(size, max(1, (limit // 2) // int(problem_bytes)))
        return max(1, min(size, problems))

    def streams_for(self, chunks: int) -> int:
        """Chunks searched at once, for `chunks` chunks: `streams`; or on an accelerator 1,
        on a CPU the usable cores (:func:`jaxcontact._devices.usable_cores`) over the
        devices the chunks are spread over (JAX's CPU devices share the cores); never more
        than `chunks`, at least 1."""
        return max(1, min(self._streams(), chunks))

    def _streams(self) -> int:
        if self.streams is not None:
            return self.streams
        if self.accelerated:
            return 1
        devices = self.devices if self.devices is not None else jax.local_devices()
        return max(1, usable_cores() // max(1, len(devices)))

    def lanes(self, problems: int, starts: int, *, model: str = "relaxed") -> int:
        """Lanes of the pool for `problems` problems of `starts` starts each of the forward
        model `model` ("relaxed" or "history"): `workers`; or on a CPU one per 8 starts, at
        least 8 and at most 64 for the relaxed model, 32 for the full-history one (never
        more than the starts); on an accelerator one per start.

        Why fewer for the full history: its step's branches run where some lane of the
        pool takes them (`jaxcontact._sharding.switch`), and the more lanes, the more often
        some lane takes a rare one; its 64-curve map ran 2.2 curves/s on 64 lanes, 2.7 on
        16 to 32 (``benchmarks/results/fit_each.md``, "Branches that no lane takes")."""
        if self.workers is not None:
            return self.workers
        total = problems * starts
        if self.accelerated:
            return total
        most = _CPU_LANES_HISTORY if model == "history" else _CPU_LANES
        return min(most, total, max(_CPU_MIN_LANES, total // _CPU_STARTS_PER_LANE))


def padded_indices(n: int, size: int) -> np.ndarray:
    """The indices of `n` items padded to `size` (>= n) by repeating the last: the one
    padding rule of a chunk of problems (every chunk one compiled shape; the copies'
    results are dropped) and of a chunk's share per device."""
    return np.minimum(np.arange(max(int(size), int(n))), int(n) - 1)


#: The platform defaults of :class:`BatchOptions` (see its docstring).
_CPU_CHUNK, _CPU_LANES, _CPU_MIN_LANES, _CPU_STARTS_PER_LANE, _ACCELERATOR_CHUNK = (
    64, 64, 8, 8, 4096)
#: At most this many lanes on a CPU for the full-history model (:meth:`BatchOptions.lanes`).
_CPU_LANES_HISTORY = 32

#: Device memory of the search per start and residual [bytes], an upper estimate: measured
#: peaks on one H100 were ~320 (relaxed model, 65,536 starts of 60 samples: 1.16 GiB) and
#: ~490 (full history, 32 cells, 8,192 starts of 200 samples: 0.74 GiB)
#: (`benchmarks/results/fit_each.md`); twice the larger.
SEARCH_BYTES_PER_RESIDUAL = 1024


#: How :func:`fitting.fit` runs its one problem on the batched path: one problem a
#: chunk, its starts on 8 lanes on a CPU (a lane whose start has converged takes the
#: next), each start its own lane on an accelerator (:meth:`BatchOptions.lanes`).
SINGLE = BatchOptions(chunk=1)
