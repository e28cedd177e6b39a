r"""Posterior distributions of the fitted parameters by NUTS (:func:`sample`).

Why numpyro
-----------
NUTS comes from `numpyro <https://num.pyro.ai>`_ (an optional dependency: ``pip install
"jaxcontact[posterior]"``): it takes a plain potential function (no probabilistic
program to rewrite the model in), vectorises chains with ``chain_method="vectorized"``
(one compiled program, one device), adapts a *dense* mass matrix (the parameters of these
fits are strongly correlated) and differentiates the potential in forward mode on request
(``forward_mode_differentiation=True``). The last one decides it: reverse mode through the
forward models' jump-off refinement gives NaN (:func:`fitting._objective.jacobian_fn`),
and blackjax would need a hand-written custom VJP around the forward-mode Jacobian. Its
``numpyro.diagnostics`` provide the split $\hat R$ and the effective sample size.

The model
---------
It starts from the least-squares optimum of :func:`fitting.fit` (its
:class:`fitting.FitResult`) and reuses the fit's problem as it is: the prepared curves,
the free parameters and their bounds, the residuals
(:func:`fitting._objective.residuals`, the one home of the objective, differentiated by
the fit's own Jacobian, :func:`fitting._objective.residuals_of_free`). Parameters are
sampled in the fit's bounded internal coordinates (:mod:`fitting._parameters`): the
free vector $z$, $u = l + (h - l)\,\sigma(z)$ with $u = \ln p$ for the positive parameters
and $u = p/s$ for the offsets (the contact offset $\delta$ [m] when the fit has it), so no
draw leaves the fit's bounds.

Likelihood: the kept samples $i$ (those the fit used) of every curve $c$, Gaussian with
standard deviation $\varsigma_c\,\sigma_i$: $\sigma_i$ [N] the noise the fit estimated for
each sample and $\varsigma_c$ a dimensionless *noise scale* of the curve, sampled with the
parameters (so a model that misses the data widens its own posterior, as the fit's
$\sqrt{\chi^2_\mathrm{red}}$ does, and a curve whose noise was misjudged by the fit's
estimate from a few dozen samples gets its own weight; with one scale for all curves the
90 % intervals of the calibration benchmark covered the truth too rarely):

$$\ln L = \sum_c\Big[-\frac{1}{2\varsigma_c^2}\sum_{i\in c} \frac{e_i^2}{\sigma_i^2}
- n_c\ln\varsigma_c\Big],\qquad e_i = F^\mathrm{eff}_i + F_0 - F_i .$$

A subsampled curve (``max_samples``) stands in the fit for all its measured samples
(weights $w_i$); the posterior is the one *of the kept samples* (each once): for a uniform
subsample this matches the fit's sandwich covariance (:mod:`fitting._uncertainty`).

Prior (settable, `prior`): independent per parameter in the internal coordinate $u$.
Default, weakly informative within the fit's bounds: a normal of $u$ centred in the middle
of the bounds $[l, h]$ with standard deviation $(h - l)/2$, truncated to the bounds (for
the default bounds of a modulus, 12 decades wide: centre at the data's modulus scale, a
standard deviation of 6 decades; the density at the bounds is 0.61 of the centre's). The
noise scale of every curve: $\ln\varsigma_c \sim N(0, 3^2)$ (centred on the fit's noise
estimate, within a factor 20 at one standard deviation). Per parameter, `prior` gives
instead ``"uniform"`` (flat in $u$ within the bounds: log-uniform for the positive ones)
or ``(centre, width)``:
a normal of $u$ around `centre` (natural units) with standard deviation `width` (in
$\ln p$ for the positive parameters, i.e. a relative width; natural units for the
offsets), truncated to the bounds; ``"noise_scale"`` likewise for every curve's noise
scale (its width in $\ln\varsigma$).

Identifiability in words (per parameter, from the posterior in $u$): *determined* when the
posterior standard deviation of $u$ is at most 0.5 (50 % relative for a positive
parameter, half the scale for an offset: the fit's own limit) and its 5–95 % interval
keeps 10 % of the span of the bounds away from both bounds; *bounded from one side* when
the interval reaches one bound and not the other (the data give only the other limit);
*not determined* otherwise (it reaches both bounds, or is wider than the limit).

Divergences: where they come from
---------------------------------
The likelihood is not Gaussian in the direction that moves the model's jump-off time
$t^*$. The fit gives the last attached and the first detached sample of every curve an
inflated noise ($\sqrt{\sigma^2 + \Delta F^2/12}$, :mod:`fitting._prepare`: point
samples place the jump-off only within their interval), 8-40 times the curve's $\sigma$ on
the synthetic curves of the calibration benchmark. While $t^*$ stays within the intervals
of those two samples the likelihood is nearly flat in that direction; once it enters the
interval of a neighbour (noise $\sigma$), that sample's residual grows by
$|F_\mathrm{jump}|/\sigma$ (tens) per interval: a wall whose curvature is $10^2$-$10^3$
times the bulk's. The step size and mass matrix are adapted on the bulk, so trajectories
that reach a wall integrate unstably (energy error above 1000: a divergent transition).
Measured on the calibration sets (``benchmarks/results/posterior.md``): along a line
through the draws the potential's slope rises from about 0 to about 300 (whitened units)
exactly where $t^*$ crosses into the neighbour's interval; smoothing the kink of the
interval average (a triangular instead of a box kernel) did not reduce the divergences
(it is the stiffness, not the kink), a smaller step did. Hence the default
``target_accept=0.95`` (numpyro's default is 0.8): on the six calibration sets with the
most divergences (same seeds, paired runs) the divergent transitions fell from 4.5 % to
0.8 % of the draws and two of the three sets that failed $\hat R \le 1.01$ / bulk ESS
$\ge 400$ came within the limits, for 1.4-6.8 times the leapfrog steps per draw. The
divergences left are those walls: the draws near a wall may be too few (the calibration's
coverage measures what that costs).

Diagnostics: rank-normalised split $\hat R$ (the larger of the bulk and the folded one),
bulk and tail ESS (Vehtari et al. 2021: rank-normalised split chains, tail from the 5 %
and 95 % quantile indicators), computed with ``numpyro.diagnostics``. A
:class:`PosteriorWarning` names divergent transitions, $\hat R > 1.01$ and bulk ESS below
400.
"""

from __future__ import annotations

import dataclasses
import datetime
import functools
import json
import math
import time
from collections.abc import Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxcontact._validate import plain

from ._caller import warn_at_caller
from ._objective import predict, residuals_of_free
from ._result import FitResult
from ._spec import canonical_name, force_baseline

__all__ = ["sample", "PosteriorResult", "PosteriorWarning", "DEFAULT_NOISE_PRIOR",
           "DEFAULT_TARGET_ACCEPT",
           "RHAT_LIMIT", "ESS_LIMIT", "summary_columns"]

#: Prior of the noise scale: normal of $\ln\varsigma$ (centre $\varsigma$, width in ln).
DEFAULT_NOISE_PRIOR = (1.0, 3.0)

#: NUTS' target acceptance probability by default (module docstring: the walls at the
#: jump-off intervals need a smaller step than numpyro's 0.8 gives).
DEFAULT_TARGET_ACCEPT = 0.95

#: $\hat R$ above which a :class:`PosteriorWarning` is issued.
RHAT_LIMIT = 1.01

#: Bulk ESS below which a :class:`PosteriorWarning` is issued.
ESS_LIMIT = 400

#: Largest posterior standard deviation of $u$ of a *determined* parameter (the fit's
#: ``max_relative_error``).
DETERMINED_SD = 0.5

#: Fraction of the bounds' span within which a quantile *reaches* a bound.
NEAR_BOUND = 0.1

#: Draws per chain of the posterior-predictive band (at most).
PREDICTIVE_DRAWS = 50

#: The columns of :meth:`PosteriorResult.table` (and of ``posterior.csv``).
summary_columns = ("name", "unit", "mean", "sd", "q05", "median", "q95", "r_hat",
                   "ess_bulk", "ess_tail", "identifiability", "fit_value", "fit_stderr",
                   "fit_status")


class PosteriorWarning(UserWarning):
    """The sampler's diagnostics fail (divergences, $\\hat R$, ESS: named in the message)."""


@dataclasses.dataclass
class PosteriorResult:
    """The outcome of :func:`sample` (numpy, natural SI units).

    **Fields:** `names`, `units` (the sampled parameters: the fit's free ones, then the
    noise scale of every curve, dimensionless: ``noise_scale``, or ``noise_scale_1``, ...
    for several curves), `samples` (name → array `(chains, draws)`),
    `internal` (the sampled coordinates $u$, `(chains, draws, k)`; $\\ln\\varsigma$ last),
    `sample_stats` (name → `(chains, draws)`: ``diverging``, ``n_steps``, ``tree_depth``,
    ``acceptance_rate``, ``energy``, ``lp``, ``step_size``: the leapfrog step of the
    whitened coordinates, adapted per chain in the warm-up and fixed after it), `rows` (the
    summary, one dict per parameter with the keys of :data:`summary_columns`),
    `divergences`, `fit` (the
    :class:`fitting.FitResult` it started from), `prior` (name → description), `predictive`
    (`(3, curves, samples)`: the 5 %, 50 % and 95 % quantiles over draws of the model force
    at the sample times [N], force offset included: the posterior band of the model curve,
    noise not included; `None` if not computed), `warnings`, `timings` [s], `seed`.
    """

    names: list[str]
    units: list[str]
    samples: dict
    internal: np.ndarray
    sample_stats: dict
    rows: list[dict]
    divergences: int
    fit: FitResult
    prior: dict
    predictive: np.ndarray | None = None
    warnings: list[str] = dataclasses.field(default_factory=list)
    timings: dict = dataclasses.field(default_factory=dict)
    seed: int = 0
    settings: dict = dataclasses.field(default_factory=dict)

    @property
    def chains(self) -> int:
        return int(self.internal.shape[0])

    @property
    def draws(self) -> int:
        return int(self.internal.shape[1])

    def __getitem__(self, name: str) -> np.ndarray:
        """Draws `(chains, draws)` of a parameter by name (``"G0"`` or ``"G0_Pa"``)."""
        return self.samples[canonical_name(name, self.names)]

    def row(self, name: str) -> dict:
        """The summary row of a parameter."""
        name = canonical_name(name, self.names)
        return next(r for r in self.rows if r["name"] == name)

    def table(self) -> list[dict]:
        """The summary rows (keys: :data:`summary_columns`)."""
        return [dict(r) for r in self.rows]

    def summary(self) -> str:
        """The summary as text: one line per parameter beside the fit's linearised error,
        then the warnings."""
        s = self.settings
        lines = [f"[[posterior]] NUTS (numpyro), {self.chains} chain(s) x {self.draws} draws "
                 f"after {s.get('warmup', '?')} warm-up; {self.divergences} divergent "
                 f"transition(s); prior: {s.get('prior_text', '')}",
                 f"    {'parameter':<24} {'mean':>11} {'sd':>10} {'5 %':>11} {'95 %':>11} "
                 f"{'R-hat':>6} {'ESS bulk':>8} {'ESS tail':>8}  {'identifiability':<24} "
                 f"fit (linearised)"]
        for r in self.rows:
            col = f"{r['name']}_{r['unit']}" if r["unit"] != "1" else r["name"]
            fit = (f"{r['fit_value']:.4g} +/- {r['fit_stderr']:.2g}"
                   if r["fit_status"] == "ok" else f"{r['fit_value']:.4g} ({r['fit_status']})")
            lines.append(f"    {col:<24} {r['mean']:11.4g} {r['sd']:10.3g} {r['q05']:11.4g} "
                         f"{r['q95']:11.4g} {r['r_hat']:6.3f} {r['ess_bulk']:8.0f} "
                         f"{r['ess_tail']:8.0f}  {r['identifiability']:<24} {fit}")
        if self.warnings:
            lines.append("[[posterior warnings]]")
            lines += [f"    {w}" for w in self.warnings]
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.summary()

    def to_json(self, path=None) -> str:
        """The summary, settings and warnings as JSON (written to `path` if given)."""
        doc = {"sampler": "NUTS (numpyro)", "chains": self.chains, "draws": self.draws,
               "divergences": self.divergences, "settings": self.settings,
               "prior": self.prior, "parameters": [_jsonable(r) for r in self.rows],
               "warnings": list(self.warnings), "timings": self.timings}
        text = json.dumps(doc, indent=2, allow_nan=False) + "\n"
        if path is not None:
            with open(path, "w", encoding="utf-8") as fh:
                fh.write(text)
        return text

    def to_csv(self, path=None) -> str:
        """The summary as CSV (columns :data:`summary_columns`; written to `path` if
        given)."""
        out = [",".join(summary_columns)]
        for r in self.rows:
            out.append(",".join(_csv_cell(r[c]) for c in summary_columns))
        text = "\n".join(out) + "\n"
        if path is not None:
            with open(path, "w", encoding="utf-8") as fh:
                fh.write(text)
        return text

    def datasets(self) -> dict:
        """The ArviZ groups as `xarray.Dataset` objects: ``posterior`` (every parameter,
        dims `(chain, draw)`, natural units in `attrs`), ``sample_stats`` and
        ``observed_data`` (the fitted force of the kept samples [N] with their time,
        indentation and noise, dims `(curve, sample)`; padding NaN)."""
        import xarray as xr

        created = datetime.datetime.now(datetime.UTC).isoformat()
        common = {"created_at": created, "inference_library": "numpyro",
                  "inference_library_version": _numpyro_version(),
                  "creation_library": "jaxcontact"}
        coords = {"chain": np.arange(self.chains), "draw": np.arange(self.draws)}
        post = xr.Dataset(
            {n: (("chain", "draw"), np.asarray(self.samples[n]), {"units": u})
             for n, u in zip(self.names, self.units, strict=True)}, coords=coords,
            attrs=dict(common, prior=json.dumps(self.prior)))
        stats = xr.Dataset({k: (("chain", "draw"), np.asarray(v))
                            for k, v in self.sample_stats.items()}, coords=coords,
                           attrs=common)
        data = self.fit.data
        kept = (np.asarray(data.valid) > 0) & (np.asarray(data.weight) > 0)

        def masked(x):
            return np.where(kept, np.asarray(x, dtype=float), np.nan)

        dims = ("curve", "sample")
        obs = xr.Dataset({"force": (dims, masked(data.force), {"units": "N"}),
                          "time": (dims, masked(data.ts), {"units": "s"}),
                          "indentation": (dims, masked(data.indentation), {"units": "m"}),
                          "noise": (dims, masked(data.noise), {"units": "N"})},
                         coords={"curve": np.arange(kept.shape[0]),
                                 "sample": np.arange(kept.shape[1])}, attrs=common)
        return {"posterior": post, "sample_stats": stats, "observed_data": obs}

    def to_netcdf(self, path) -> None:
        """Write the groups of :meth:`datasets` to one netCDF-4 file (h5netcdf), as ArviZ
        reads it (``arviz.from_netcdf``)."""
        mode = "w"
        for group, ds in self.datasets().items():
            ds.to_netcdf(path, mode=mode, group=group, engine="h5netcdf")
            mode = "a"


def _numpyro_version() -> str:
    import numpyro

    return numpyro.__version__


def _jsonable(row: dict) -> dict:
    out = {}
    for k, v in row.items():
        if isinstance(v, float | np.floating):
            v = float(v)
            out[k] = v if math.isfinite(v) else ("inf" if v > 0 else "-inf" if v < 0 else None)
        else:
            out[k] = v
    return out


def _csv_cell(v) -> str:
    if isinstance(v, float | np.floating):
        return repr(float(v))
    text = str(v)
    return f'"{text}"' if ("," in text or '"' in text) else text


# --- the prior -----------------------------------------------------------------------


def _prior_arrays(prior, fit: FitResult, free_names, lo, hi, log):
    """Per free parameter and the noise scale (last): (kind: 1 normal / 0 uniform,
    centre, width) in internal coordinates, and a description per name."""
    param = fit.parameterisation
    spec = dict(prior or {}) if not isinstance(prior, str) else None
    if isinstance(prior, str):
        if prior not in ("uniform", "default"):
            raise ValueError(f"prior must be a mapping, 'default' or 'uniform'; got {prior!r}")
        spec = {n: prior for n in free_names}
    elif not isinstance(prior, Mapping | type(None)):
        raise ValueError(f"prior must be a mapping {{name: 'uniform' | (centre, width)}}; "
                         f"got {plain(prior)}")
    names_all = list(free_names) + ["noise_scale"]
    given = {}
    for key, val in (spec or {}).items():
        if key == "noise_scale":
            given[key] = val
            continue
        try:
            name = canonical_name(key, fit.names)
        except (KeyError, ValueError):
            raise ValueError(f"prior: unknown parameter {key!r}; sampled: {names_all}") from None
        if name not in free_names:
            raise ValueError(f"prior: {name!r} is fixed in the fit; sampled: {names_all}")
        given[name] = val
    kinds, centres, widths, text = [], [], [], {}
    scale = np.asarray(param.scale)[list(param.free)]
    for j, name in enumerate(names_all):
        val = given.get(name, "default")
        noise = name == "noise_scale"
        if noise and val == "uniform":
            raise ValueError("prior: 'noise_scale' cannot be uniform (no bounds); give "
                             "(centre, width)")
        if val == "default" and noise:
            val = DEFAULT_NOISE_PRIOR
        if val == "default":
            kinds.append(1.0)
            centres.append(0.5 * (lo[j] + hi[j]))
            widths.append(0.5 * (hi[j] - lo[j]))
            text[name] = ("default: normal in the internal coordinate, centred in the bounds, "
                          "sd = half their span, truncated to them")
            continue
        if val == "uniform":
            kinds.append(0.0)
            centres.append(0.0)
            widths.append(1.0)
            text[name] = "uniform in the internal coordinate within the bounds"
            continue
        try:
            c, w = (float(x) for x in val)
        except (TypeError, ValueError):
            raise ValueError(f"prior for {name!r} must be 'uniform', 'default' or (centre, "
                             f"width); got {plain(val)}") from None
        is_log = noise or log[j]
        if not (math.isfinite(c) and math.isfinite(w) and w > 0 and (c > 0 or not is_log)):
            need = "centre > 0 and width > 0" if is_log else "finite centre and width > 0"
            raise ValueError(f"prior for {name!r} needs {need}; got {plain((c, w))}")
        kinds.append(1.0)
        if is_log:
            centres.append(math.log(c))
            widths.append(w)
            text[name] = f"normal of ln({name}) around ln({c:.4g}), sd {w:.4g}"
        else:
            centres.append(c / scale[j])
            widths.append(w / scale[j])
            text[name] = f"normal around {c:.4g}, sd {w:.4g} (natural units)"
        if not noise:
            text[name] += ", truncated to the bounds"
    return np.array(kinds), np.array(centres), np.array(widths), text


# --- diagnostics ---------------------------------------------------------------------


def _split(x: np.ndarray) -> np.ndarray:
    """`(chains, draws)` → `(2 chains, draws // 2)` (split chains)."""
    n = x.shape[1] // 2
    return np.concatenate([x[:, :n], x[:, x.shape[1] - n:]], axis=0)


def _rank_normal(x: np.ndarray) -> np.ndarray:
    from scipy import special, stats

    r = stats.rankdata(x, method="average").reshape(x.shape)
    return special.ndtri((r - 0.375) / (x.size + 0.25))


def diagnostics(x: np.ndarray) -> tuple[float, float, float]:
    """Rank-normalised split $\\hat R$ (max of bulk and folded), bulk ESS and tail ESS of
    draws `x` `(chains, draws)` (Vehtari et al. 2021), with ``numpyro.diagnostics``."""
    from numpyro.diagnostics import effective_sample_size, split_gelman_rubin

    x = np.asarray(x, dtype=float)
    if x.shape[1] < 4 or np.ptp(x) == 0:
        return math.nan, math.nan, math.nan
    z = _rank_normal(x)
    zf = _rank_normal(np.abs(x - np.median(x)))
    rhat = max(float(split_gelman_rubin(z)), float(split_gelman_rubin(zf)))
    bulk = float(effective_sample_size(_split(z)))
    tails = []
    for q in (0.05, 0.95):
        ind = (x <= np.quantile(x, q)).astype(float)
        tails.append(float(effective_sample_size(_split(ind))) if np.ptp(ind) > 0 else math.nan)
    return rhat, bulk, float(np.nanmin(tails)) if np.any(np.isfinite(tails)) else math.nan


def identifiability(u: np.ndarray, lower: float, upper: float) -> str:
    """The words of the module docstring for draws `u` of an internal coordinate within
    the bounds `[lower, upper]` (for the noise scale: unbounded)."""
    q05, q95 = np.quantile(u, [0.05, 0.95])
    if math.isfinite(lower) and math.isfinite(upper):
        span = upper - lower
        low = q05 - lower < NEAR_BOUND * span
        high = upper - q95 < NEAR_BOUND * span
    else:
        low = high = False
    if low and high:
        return "not determined"
    if low:
        return "bounded from above only"
    if high:
        return "bounded from below only"
    return "determined" if float(np.std(u)) <= DETERMINED_SD else "not determined"


# --- the sampler ---------------------------------------------------------------------


def _check_int(name, v, low):
    if not (isinstance(v, int | np.integer) and not isinstance(v, bool) and v >= low):
        raise ValueError(f"{name} must be an integer >= {low}; got {plain(v)}")


def sample(
    fit: FitResult,
    *,
    draws: int = 1000,
    chains: int = 4,
    warmup: int | None = None,
    prior: Mapping | str | None = None,
    seed: int = 0,
    target_accept: float = DEFAULT_TARGET_ACCEPT,
    max_tree_depth: int = 8,
    max_draws: int | None = None,
    predictive: bool = True,
    warn: bool = True,
) -> PosteriorResult:
    r"""Sample the posterior of the free parameters of a fit by NUTS (numpyro).

    **Arguments:**

    - `fit`: the :class:`fitting.FitResult` of :func:`fitting.fit` (any model and
      rheology): its optimum starts the chains, its prepared curves, free parameters,
      bounds and residuals define the posterior (module docstring).
    - `draws`: draws per chain kept after the warm-up; `chains`: chains, vectorised in
      one compiled program (numpyro ``chain_method="vectorized"``); `warmup`: warm-up
      iterations per chain (step size and dense mass matrix adaptation; default
      `draws`).
    - `prior`: `None` (the default prior of the module docstring), ``"uniform"`` (flat in
      the internal coordinates within the bounds for every parameter), or a mapping
      `{name: "uniform" | "default" | (centre, width)}` (names as in `fit`, and
      ``"noise_scale"``).
    - `seed`: of the chains' random numbers and starts; `target_accept`: NUTS' target
      acceptance probability (default :data:`DEFAULT_TARGET_ACCEPT` = 0.95, above
      numpyro's 0.8 for the stiff likelihood near the jump-off: module docstring; raise
      it, e.g. 0.99, when divergences are reported);
      `max_tree_depth`: at most $2^d$ leapfrog steps per draw.
    - `max_draws`: draws per chain at most (default `draws`: no extension). While some
      parameter's $\hat R$ exceeds :data:`RHAT_LIMIT` or its bulk ESS is below
      :data:`ESS_LIMIT`, every chain continues from its last state (the warm-up's step
      size and mass matrix kept, no further adaptation) for another `draws` draws, as long
      as the total stays within `max_draws`; all draws are kept and the diagnostics are
      those of all of them (``settings["draws_run"]``, ``settings["extensions"]``). A
      chain stuck in another mode is not cured by this: the warning stays.
    - `predictive`: also compute the posterior band of the model force
      (:attr:`PosteriorResult.predictive`). `warn`: issue :class:`PosteriorWarning`.

    **Returns:** a :class:`PosteriorResult` (print it for the summary).

    **Calibration** (synthetic sets of known parameters; ``benchmarks/results/posterior*.md``):
    the 90 % intervals of the relaxed model cover the truth in 84–94 % of 50 sets; the
    full-history model's are as wide as the errors, but with few samples around the jump-off
    (80 a curve) the work of adhesion comes out high by ~0.4–0.8 of its standard error, in
    the fit and the posterior alike, a bias that vanished with 320 samples a curve
    (``posterior_history_bias.md``).

    **Raises:** `ValueError` naming the argument; `ImportError` when numpyro is missing.
    """
    try:
        import numpyro.infer.hmc  # noqa: F401 - the NUTS kernel of `_run_chains`
    except ImportError as exc:  # pragma: no cover - an optional dependency
        raise ImportError("fitting.sample needs numpyro: pip install 'jaxcontact[posterior]' "
                          "(or pip install numpyro)") from exc
    if not isinstance(fit, FitResult):
        raise ValueError(f"fit must be a FitResult of fitting.fit; got {type(fit).__name__}")
    _check_int("draws", draws, 10)
    _check_int("chains", chains, 1)
    warmup = draws if warmup is None else warmup
    _check_int("warmup", warmup, 10)
    _check_int("max_tree_depth", max_tree_depth, 1)
    _check_int("seed", seed, 0)
    max_draws = draws if max_draws is None else max_draws
    _check_int("max_draws", max_draws, draws)
    if not (isinstance(target_accept, int | float) and 0.5 <= target_accept < 1):
        raise ValueError(f"target_accept must be in [0.5, 1); got {plain(target_accept)}")
    t_start = time.perf_counter()
    spec, param, data = fit.spec, fit.parameterisation, fit.data
    free = list(param.free)
    k = len(free)
    free_names = [fit.names[i] for i in free]
    lo = np.asarray(param.lower)[free]
    hi = np.asarray(param.upper)[free]
    log = [bool(param.log[i]) for i in free]
    if not np.all(np.isfinite(lo) & np.isfinite(hi)):
        bad = [n for n, a, b in zip(free_names, lo, hi, strict=True)
               if not (math.isfinite(a) and math.isfinite(b))]
        raise ValueError(f"fit: sample needs finite bounds on every free parameter; "
                         f"unbounded: {bad}")
    kinds, centres, widths, prior_text = _prior_arrays(
        prior, fit, free_names, np.append(lo, 0.0), np.append(hi, 0.0), log)
    n_curves = int(data.n_curves)
    m = k + n_curves  # sampled: the free parameters, then one noise scale per curve
    kinds, centres, widths = (np.append(x[:k], np.full(n_curves, x[k]))
                              for x in (kinds, centres, widths))

    weight = np.asarray(data.weight, dtype=float)
    kept = (np.asarray(data.valid) > 0) & (weight > 0)
    inv_w = np.where(kept, 1.0 / np.where(kept, weight, 1.0), 0.0)
    n_kept = np.count_nonzero(kept, axis=1)
    if np.any(n_kept < 2):
        raise ValueError("fit: every curve needs at least 2 fitted samples for its noise "
                         f"scale; kept per curve: {n_kept.tolist()}")
    ctx = _Context(spec=spec, param=param, data=data, inv_w=jnp.asarray(inv_w),
                   n_kept=jnp.asarray(n_kept.astype(float)), lower=jnp.asarray(lo),
                   span=jnp.asarray(hi - lo), kinds=jnp.asarray(kinds),
                   centres=jnp.asarray(centres), widths=jnp.asarray(widths),
                   shift=jnp.zeros(m), chol=jnp.eye(m))

    # starts: the optimum, spread by the fit's linearised covariance (in z)
    u_opt = param.to_internal(fit.values)
    z_opt = np.clip(param.z_of(u_opt), -6.0, 6.0)
    # each curve's noise scale starts at its rms normalised residual at the optimum
    e2 = np.where(kept, np.nan_to_num(fit.normalised_residuals) ** 2, 0.0)
    rms = np.sqrt(np.maximum(e2.sum(axis=1) / n_kept, 1e-300))
    theta0 = np.append(z_opt, np.log(rms))
    cov0 = _start_covariance(fit, u_opt, z_opt, n_kept)
    # the sampler works in whitened coordinates eta: theta = theta0 + L eta (L L^T = cov0),
    # so that the posterior is near N(0, I) and the warm-up's mass matrix (estimated from a
    # few draws and shrunk towards the identity) is well scaled in every direction
    chol = np.linalg.cholesky(cov0)
    rng = np.random.default_rng(seed)
    starts = theta0 + 0.5 * rng.standard_normal((chains, m)) @ chol.T
    starts[:, :k] = np.clip(starts[:, :k], -8.0, 8.0)
    inits = np.linalg.solve(chol, (starts - theta0).T).T
    ctx = eqx.tree_at(
        lambda c: (c.shift, c.chol), ctx, (jnp.asarray(theta0), jnp.asarray(chol)))

    t0 = time.perf_counter()
    keys = jax.random.split(jax.random.PRNGKey(seed), chains)
    kernel = {"warmup": int(warmup), "draws": int(draws),
              "target_accept": float(target_accept), "max_tree_depth": int(max_tree_depth)}
    out, state = _run_chains(ctx, jnp.asarray(inits), keys, **kernel)
    blocks = [jax.device_get(out)]
    # more draws while the diagnostics fail and the budget allows (module docstring); the
    # diagnostics of the last draws are the summary's
    while True:
        eta, diverging, num_steps, accept, energy, pot, step = (
            np.concatenate([np.asarray(b[i]) for b in blocks], axis=1) for i in range(7))
        theta = theta0 + eta @ chol.T
        internal = _internal(theta, lo, hi)
        diags = [diagnostics(internal[..., j]) for j in range(internal.shape[-1])]
        met = all(r <= RHAT_LIMIT and b >= ESS_LIMIT for r, b, _ in diags)
        if met or (len(blocks) + 1) * draws > max_draws:
            break
        out, state = _continue_chains(ctx, state, **kernel)
        blocks.append(jax.device_get(out))
    extensions = len(blocks) - 1
    extra = {"diverging": diverging, "num_steps": num_steps, "accept_prob": accept,
             "energy": energy, "potential_energy": pot}
    t_mcmc = time.perf_counter() - t0

    z = theta[..., :k]
    u_all = param.internal_host(z)
    p_all = param.to_natural_host(u_all)
    noise_names = (["noise_scale"] if n_curves == 1 else
                   [f"noise_scale_{c + 1}" for c in range(n_curves)])
    names = free_names + noise_names
    units = [fit.units[i] for i in free] + ["1"] * n_curves
    samples = {n: p_all[..., i] for n, i in zip(free_names, free, strict=True)}
    for c, n in enumerate(noise_names):
        samples[n] = np.exp(theta[..., k + c])
    n_steps = extra["num_steps"].astype(int)
    stats = {"diverging": extra["diverging"].astype(bool), "n_steps": n_steps,
             "tree_depth": np.floor(np.log2(np.maximum(n_steps, 1))).astype(int) + 1,
             "acceptance_rate": extra["accept_prob"], "energy": extra["energy"],
             "lp": -extra["potential_energy"], "step_size": step}
    divergences = int(np.sum(stats["diverging"]))

    rows = []
    bounds_all = list(zip(lo, hi, strict=True)) + [(-math.inf, math.inf)] * n_curves
    for j, name in enumerate(names):
        x = samples[name]
        rhat, bulk, tail = diags[j]
        q05, q50, q95 = np.quantile(x, [0.05, 0.5, 0.95])
        if j >= k:
            fv, fs, fst = float(rms[j - k]), math.nan, "rms residual / noise at the fit"
        else:
            i = fit.names.index(name)
            fv, fs, fst = float(fit.values[i]), float(fit.stderr[i]), fit.status[i]
        rows.append({"name": name, "unit": units[j], "mean": float(np.mean(x)),
                     "sd": float(np.std(x, ddof=1)), "q05": float(q05), "median": float(q50),
                     "q95": float(q95), "r_hat": rhat, "ess_bulk": bulk, "ess_tail": tail,
                     "identifiability": identifiability(internal[..., j].ravel(),
                                                        *bounds_all[j]),
                     "fit_value": fv, "fit_stderr": fs, "fit_status": fst})

    msgs = []
    if divergences:
        msgs.append(f"{divergences} divergent transition(s) of {chains * draws}: the draws "
                    "may miss part of the posterior (near the model's jump-off, where the "
                    "likelihood is stiff); raise target_accept (e.g. 0.99)")
    bad_rhat = [r["name"] for r in rows if not (r["r_hat"] <= RHAT_LIMIT)]
    if bad_rhat:
        msgs.append(f"R-hat above {RHAT_LIMIT} (chains disagree) for {', '.join(bad_rhat)}: "
                    "run longer (draws, warmup) or check for several modes")
    low_ess = [r["name"] for r in rows if not (r["ess_bulk"] >= ESS_LIMIT)]
    if low_ess:
        msgs.append(f"bulk ESS below {ESS_LIMIT} for {', '.join(low_ess)}: the summary's "
                    "quantiles are imprecise; run more draws")
    if warn:
        for m in msgs:
            warn_at_caller(m, PosteriorWarning)

    band = None
    t0 = time.perf_counter()
    if predictive:
        band = _predictive_band(fit, u_all, seed)
    prior_desc = "default" if prior is None else (prior if isinstance(prior, str) else "custom")
    settings = {"draws": draws, "chains": chains, "warmup": warmup, "seed": seed,
                "max_draws": max_draws, "draws_run": int(eta.shape[1]),
                "extensions": extensions,
                "target_accept": target_accept, "max_tree_depth": max_tree_depth,
                "chain_method": "vectorized", "dense_mass": True,
                "n_kept_samples": n_kept.tolist(), "prior_text": prior_desc}
    return PosteriorResult(
        names=names, units=units, samples=samples, internal=internal, sample_stats=stats,
        rows=rows, divergences=divergences, fit=fit, prior=prior_text, predictive=band,
        warnings=msgs, seed=seed, settings=settings,
        timings={"mcmc": t_mcmc, "predictive": time.perf_counter() - t0,
                 "total": time.perf_counter() - t_start})


def _start_covariance(fit: FitResult, u_opt, z_opt, n_kept) -> np.ndarray:
    """The fit's linearised covariance in the sampled coordinates `(z, ln ς)` (the first
    inverse mass matrix and the spread of the chains' starts): parameters without a finite
    error (not determined, at a bound) get variance 1 in $z$ and no correlation; made
    positive definite."""
    param = fit.parameterisation
    free = list(param.free)
    k = len(free)
    dp = param.dnatural(u_opt)[free]
    dudz = param.dinternal_dz(z_opt)
    scale = dp * dudz
    with np.errstate(all="ignore"):
        cov = np.asarray(fit.covariance, dtype=float)[np.ix_(free, free)] / np.outer(scale,
                                                                                    scale)
    bad = ~np.all(np.isfinite(cov), axis=1) | ~(np.diag(cov) > 0)
    cov[bad, :] = 0.0
    cov[:, bad] = 0.0
    cov[bad, bad] = 1.0
    c = len(n_kept)
    out = np.zeros((k + c, k + c))
    out[:k, :k] = 0.5 * (cov + cov.T)
    out[k:, k:] = np.diag(1.0 / (2.0 * np.maximum(n_kept, 1)))  # ln(noise scale): 1 / (2 n)
    w, v = np.linalg.eigh(out)
    w = np.clip(w, float(np.max(w)) * 1e-10, None)
    return (v * w) @ v.T


class _Context(eqx.Module):
    """The sampled problem, passed to the compiled sampler as an argument (so that curves
    of one shape share one compilation)."""

    spec: object
    param: object
    data: object
    inv_w: jax.Array
    n_kept: jax.Array
    lower: jax.Array
    span: jax.Array
    kinds: jax.Array
    centres: jax.Array
    widths: jax.Array
    shift: jax.Array
    chol: jax.Array


def _potential_fn(ctx: _Context):
    r"""The potential energy $-\ln$ (likelihood × prior × Jacobian) of `theta = (z, ln ς)`
    (module docstring), as a function of the whitened `eta` (`theta = shift + chol eta`; a
    constant Jacobian)."""
    k = ctx.lower.shape[0]

    def potential(eta):
        theta = ctx.shift + ctx.chol @ eta
        z, log_s = theta[:k], theta[k:]
        # the fit's residuals (the one home of the objective), each kept sample once; their
        # derivative the fit's one Jacobian, whatever the number of directions numpyro
        # pushes (the noise scales' too)
        r = residuals_of_free(ctx.spec, ctx.param, ctx.data)(z).reshape(ctx.inv_w.shape)
        chi2 = jnp.sum(ctx.inv_w * r * r, axis=1)  # per curve
        u = ctx.lower + ctx.span * jax.nn.sigmoid(z)
        v = jnp.concatenate([u, log_s])
        log_lik = jnp.sum(-0.5 * chi2 * jnp.exp(-2.0 * log_s) - ctx.n_kept * log_s)
        log_prior = jnp.sum(ctx.kinds * -0.5 * ((v - ctx.centres) / ctx.widths) ** 2)
        log_jac = -jnp.sum(jax.nn.softplus(z) + jax.nn.softplus(-z))  # du/dz, logistic
        return -(log_lik + log_prior + log_jac)

    return potential


def _internal(theta: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """The summary's coordinates of draws `theta = (z, ln ς)` `(..., m)`: the internal
    $u = l + (h - l)\\,\\sigma(z)$ of the `len(lower)` parameters, then $\\ln\\varsigma$."""
    k = len(lower)
    z = theta[..., :k]
    u = lower + (upper - lower) * (1.0 / (1.0 + np.exp(-z)))
    return np.concatenate([u, theta[..., k:]], axis=-1)


def _kernels(ctx, init, key, *, warmup, target_accept, max_tree_depth):
    """numpyro's NUTS kernel for the potential of `ctx`: `(state at init, sample_kernel)`.
    The kernel's settings (warm-up length, tree depth) live in the closure that
    `init_kernel` sets, so a continued chain calls it too (its state then unused)."""
    from numpyro.infer.hmc import hmc

    init_kernel, sample_kernel = hmc(potential_fn_gen=_potential_fn, algo="NUTS")
    state = init_kernel(init, num_warmup=warmup,
                        dense_mass=True, target_accept_prob=target_accept,
                        max_tree_depth=max_tree_depth,
                        forward_mode_differentiation=True, model_args=(ctx,),
                        rng_key=key)
    return state, sample_kernel


def _scan_draws(ctx, sample_kernel, state, length):
    """`length` NUTS transitions from `state`: `(last state, (eta, diverging, num_steps,
    accept_prob, energy, potential_energy, step_size))` per transition."""

    def step(s, _):
        s = sample_kernel(s, model_args=(ctx,))
        return s, (s.z, s.diverging, s.num_steps, s.accept_prob, s.energy,
                   s.potential_energy, s.adapt_state.step_size)

    return jax.lax.scan(step, state, None, length=length)


@functools.partial(jax.jit, static_argnames=("warmup", "draws", "target_accept",
                                             "max_tree_depth"))
def _run_chains(ctx, inits, keys, *, warmup, draws, target_accept, max_tree_depth):
    """NUTS (numpyro's kernel, dense mass matrix adapted in the warm-up from the identity,
    gradients in forward mode) from every row of `inits` (whitened), chains vectorised:
    `((eta, diverging, num_steps, accept_prob, energy, potential_energy, step_size), last
    states)`, the first each `(chains, draws, ...)` (the warm-up dropped)."""

    def chain(init, key):
        state, sample_kernel = _kernels(ctx, init, key, warmup=warmup,
                                        target_accept=target_accept,
                                        max_tree_depth=max_tree_depth)
        # one scan over the warm-up and the draws (the model compiled once in the loop)
        last, out = _scan_draws(ctx, sample_kernel, state, warmup + draws)
        return jax.tree.map(lambda x: x[warmup:], out), last

    return jax.vmap(chain)(inits, keys)


@functools.partial(jax.jit, static_argnames=("warmup", "draws", "target_accept",
                                             "max_tree_depth"))
def _continue_chains(ctx, states, *, warmup, draws, target_accept, max_tree_depth):
    """`draws` more transitions of every chain from its last state (`_run_chains`' second
    output; past the warm-up, so nothing is adapted any more): the same outputs."""

    def chain(state):
        _, sample_kernel = _kernels(ctx, state.z, state.rng_key, warmup=warmup,
                                    target_accept=target_accept,
                                    max_tree_depth=max_tree_depth)
        last, out = _scan_draws(ctx, sample_kernel, state, draws)
        return out, last

    return jax.vmap(chain)(states)


@jax.jit
def _model_forces(spec, param, us, data):
    """The model force at the sample times (fitted baseline included) for every row of the
    internal coordinates `us` `(draws, p)`, `(draws, curves, samples)`."""

    def one(u):
        p = param.to_natural(u)
        sol = predict(spec, p, data)
        f0 = force_baseline(spec, p, data.ts)
        return jnp.where(jnp.isfinite(sol.force), sol.force, jnp.nan) + f0

    return jax.lax.map(one, us)


def _predictive_band(fit: FitResult, u_all: np.ndarray, seed: int) -> np.ndarray:
    """5/50/95 % quantiles over draws of the model force (the posterior band)."""
    flat = u_all.reshape(-1, u_all.shape[-1])
    rng = np.random.default_rng(seed + 1)
    pick = rng.choice(len(flat), size=min(len(flat), PREDICTIVE_DRAWS * u_all.shape[0]),
                      replace=False)
    forces = np.asarray(_model_forces(fit.spec, fit.parameterisation,
                                      jnp.asarray(flat[pick]), fit.data))
    return np.nanquantile(forces, [0.05, 0.5, 0.95], axis=0)
