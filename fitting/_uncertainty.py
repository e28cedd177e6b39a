r"""Standard errors, correlations and identifiability at the optimum (Gauss–Newton).

At the optimum the Jacobian $J$ of the weighted residuals with respect to the internal
coordinates $u$ of the free parameters (:mod:`fitting._parameters`: $u = \log p$, or $p/s$
for the offsets) is exact (forward mode). With $s^2 = \chi^2/(m - k)$ the reduced
$\chi^2$ ($m$ samples, $k$ free parameters not at a bound)

$$\mathrm{cov}(u) = s^2 (J^\top J)^{-1}, \qquad
\mathrm{cov}(p) = D\,\mathrm{cov}(u)\,D,\quad D = \mathrm{diag}(\mathrm dp/\mathrm du).$$

When the residuals carry weights (a subsampled curve: $r_i = \sqrt{w_i}\,e_i/\sigma_i$, each
kept sample standing for $w_i$ measured ones; :mod:`fitting._prepare`), the estimator is a
weighted least-squares one on the kept samples, whose noise is that of single samples:
its covariance is the sandwich $s^2 (J^\top J)^{-1} J^\top W J (J^\top J)^{-1}$ with
$W = \mathrm{diag}(w)$ (which reduces to the above for $w = 1$), and $m = \sum w_i$.

The inverse is taken through the eigen-decomposition $J^\top J = V\,\mathrm{diag}(w)\,V^\top$:
$\mathrm{var}(u_i) = s^2\sum_k V_{ik}^2/w_k$. A direction with $w_k \le 10^{-14}\max w$ is one
the data do not see; every parameter with a share in it ($V_{ik}^2 > 10^{-10}$) gets an
infinite variance (dropping such directions instead would report tiny errors for exactly
the parameters the data cannot determine).

A parameter is reported *not determined* (an :class:`IdentifiabilityWarning` naming it,
``status`` "not determined") when its relative standard error exceeds
`max_relative_error` (0.5) — for an offset: its standard error exceeds half its scale —
or when $J^\top J$ has a condition number above `max_condition` ($10^{10}$) and the
parameter dominates the weakest direction (its standard error is then infinite). A
parameter at a bound (:meth:`fitting._parameters.Parameterisation.at_bound`) is held there
for the covariance and has no standard error (``status`` "at lower bound" / "at upper
bound"). With fewer samples than free parameters nothing is determined. Typical cases:
$\eta_1$ when the lift is much slower than the relaxation; $\Delta\gamma$ when no curve
jumps off (:func:`adhesion_note` says what the data bound then: from below when a retract
ends still pulling, from above when none pulls at all).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from ._caller import warn_at_caller
from ._prepare import TENSILE_SIGMA

__all__ = ["IdentifiabilityWarning", "ModelValidityWarning", "Uncertainty", "gauss_newton",
           "derived_quantities", "delta_method", "POISSON"]


class IdentifiabilityWarning(UserWarning):
    """The data cannot determine a parameter (named in the message)."""


class ModelValidityWarning(UserWarning):
    """The fitted model is used outside its range of validity (the message says how)."""


@dataclasses.dataclass
class Uncertainty:
    """Outcome of :func:`gauss_newton` (natural parameters; nan where not applicable).

    **Fields:** `stderr` (p,), `covariance` (p, p), `correlation` (p, p), `status`
    (per parameter: "ok", "fixed", "not determined", "at lower bound", "at upper bound"),
    `chi2`, `reduced_chi2`, `n_data`, `dof`, `condition_number`, `warnings`.
    """

    stderr: np.ndarray
    covariance: np.ndarray
    correlation: np.ndarray
    status: list[str]
    chi2: float
    reduced_chi2: float
    n_data: int
    dof: int
    condition_number: float
    warnings: list[str]


def adhesion_note(retract_ends) -> str:
    r"""What the data bound of $\Delta\gamma$ when no curve's retract jumps off (`retract_ends`:
    one :func:`fitting._prepare.retract_end` per curve): a clause for the message of an
    undetermined work of adhesion, empty when a curve jumps off (or none is known). A
    retract still tensile at its end bounds it from below (a larger $\Delta\gamma$ holds
    the contact longer); retracts that never pull bound it from above (a smaller one pulls
    less than the noise); a gradual return bounds neither in the model's terms."""
    ends = set(retract_ends) - {"no retract"}  # a curve fitted without its retract
    if not ends or "jump-off" in ends:
        return ""
    if "held" in ends:
        return ("; no curve jumps off and a retract ends still pulling (or its baseline lies "
                "below the approach's), so the data bound it only from below: lift until the "
                "contact jumps off, or fix it")
    if ends == {"no adhesion"}:
        return (f"; no curve pulls on the retract (no force below -{TENSILE_SIGMA:g} sigma), "
                "so the data bound it only from above: the adhesion is below what the noise "
                "resolves; fix it (e.g. 0) or leave it out of the conclusions")
    return ("; no curve jumps off: the force returns gradually to the baseline after its "
            "most tensile value (a slow peel, membrane tethers), which the model's sharp "
            "jump-off does not describe")


def gauss_newton(param, u, r, J, names, *, n_data: int, weights=None,
                 retract_ends=(), max_relative_error: float = 0.5,
                 max_condition: float = 1e10, warn: bool = True) -> Uncertainty:
    """Gauss–Newton covariance at internal coordinates `u` (see the module docstring).

    `param`: the `Parameterisation`; `r`, `J`: residuals and their Jacobian with respect
    to the internal coordinates of ``param.free`` (in that order); `n_data`: number of
    (measured) samples; `weights`: the weight $w_i$ of every residual (`None`: 1);
    `retract_ends`: how each curve's retract ends (:func:`fitting._prepare.retract_end`;
    the message about an undetermined $\\Delta\\gamma$ says what the data bound when no
    curve jumps off: :func:`adhesion_note`).
    """
    names = list(names)
    u = np.asarray(u, dtype=float)
    r = np.asarray(r, dtype=float)
    J = np.array(J, dtype=float)
    free = list(param.free)
    if J.shape != (r.size, len(free)):
        raise ValueError(f"J must have shape ({r.size}, {len(free)}); got {J.shape}")
    k_all = len(u)
    status = ["fixed"] * k_all
    bound = param.at_bound(u)
    active = []  # columns of J that are free and not at a bound
    for col, i in enumerate(free):
        if bound[i] is not None:
            status[i] = f"at {bound[i]} bound"
        else:
            status[i] = "ok"
            active.append(col)
    messages = []
    for i in free:
        if bound[i] is not None:
            messages.append(f"{names[i]} is at its {bound[i]} bound "
                            f"({_bound_value(param, i, bound[i]):.4g}): the data push it "
                            "there; no standard error")
    Ja = J[:, active]
    finite_col = np.all(np.isfinite(Ja), axis=0)
    Ja[:, ~finite_col] = 0.0
    chi2 = float(np.sum(r * r))
    k = len(active)
    dof = n_data - k
    s2 = chi2 / dof if dof > 0 else math.inf
    A = Ja.T @ Ja
    W = np.ones(r.size) if weights is None else np.asarray(weights, dtype=float).ravel()
    B = (Ja * W[:, None]).T @ Ja
    var = np.full(k, np.inf)
    cov_u = np.full((k, k), np.nan)
    cond = math.inf
    if k and dof > 0:
        w, V = np.linalg.eigh(A)
        wmax = float(np.max(w)) if w.size else 0.0
        cond = wmax / float(np.min(w)) if np.min(w) > 0 else math.inf
        seen = w > 1e-14 * wmax if wmax > 0 else np.zeros_like(w, dtype=bool)
        inv_w = np.where(seen, 1.0 / np.where(seen, w, 1.0), 0.0)
        a_inv = (V * inv_w) @ V.T
        cov_u = s2 * a_inv @ B @ a_inv
        blind = np.sum(V[:, ~seen] ** 2, axis=1) > 1e-10
        var = np.where(blind, np.inf, np.diag(cov_u))
        cov_u[blind, :] = np.nan
        cov_u[:, blind] = np.nan
        if cond > max_condition:
            weakest = int(np.argmax(np.abs(V[:, 0])))
            var[weakest] = np.inf
            cov_u[weakest, :] = np.nan
            cov_u[:, weakest] = np.nan
    sd_u = np.sqrt(np.maximum(var, 0.0))
    dp = param.dnatural(u)
    cols = [free[c] for c in active]
    stderr = np.full(k_all, np.nan)
    cov = np.full((k_all, k_all), np.nan)
    corr = np.full((k_all, k_all), np.nan)
    with np.errstate(over="ignore", invalid="ignore"):
        stderr[cols] = np.abs(dp[cols]) * sd_u
        cov[np.ix_(cols, cols)] = cov_u * np.outer(dp[cols], dp[cols])
        d = np.sqrt(np.where(np.isfinite(var) & (var > 0), var, np.nan))
        corr[np.ix_(cols, cols)] = np.clip(cov_u / np.outer(d, d), -1.0, 1.0)
    if dof <= 0:
        messages.append(f"too few samples: {n_data} samples for {k} free parameters; "
                        "nothing is determined")
    for j, i in enumerate(cols):
        # u = log p: sd(u) is the relative error; u = p/s: the error in units of the scale
        rel = sd_u[j]
        limit = max_relative_error
        if dof > 0 and np.isfinite(rel) and rel <= limit and finite_col[j]:
            continue
        status[i] = "not determined"
        if dof <= 0:
            continue
        if not finite_col[j]:
            why = "the derivative of the residuals with respect to it is not finite"
        elif not np.isfinite(rel):
            why = ("the residuals do not change along a direction that is mostly it"
                   if cond <= max_condition else
                   f"the Gauss-Newton matrix has condition number {cond:.3g} and its weakest "
                   "direction is mostly it")
        else:
            what = "relative standard error" if param.log[i] else "standard error / scale"
            why = f"{what} {rel:.3g} (> {limit:g})"
        if names[i] == "work_of_adhesion":
            why += adhesion_note(retract_ends)
        messages.append(f"{names[i]} is not determined by the data: {why}")
    if warn:
        for m in messages:
            warn_at_caller(m, IdentifiabilityWarning)
    return Uncertainty(stderr=stderr, covariance=cov, correlation=corr, status=status,
                       chi2=chi2, reduced_chi2=s2, n_data=int(n_data), dof=int(dof),
                       condition_number=float(cond), warnings=messages)


def _bound_value(param, i, which) -> float:
    lim = float(np.asarray(param.lower if which == "lower" else param.upper)[i])
    return math.exp(lim) if param.log[i] else lim * float(np.asarray(param.scale)[i])


#: Poisson's ratio of the model's half-space (incompressible): $E = 2(1+\nu)G = 3G$.
POISSON = 0.5


def derived_quantities(spec, p, covariance, status, *, evaluated=None) -> list[dict]:
    r"""Quantities derived from the natural parameters `p` with their standard errors by
    the delta method ($\sigma_f^2 = \nabla f^\top C\,\nabla f$ over the free parameters,
    $\nabla f$ by forward-mode differentiation; a fixed parameter contributes nothing).

    Young's moduli $E = 2(1+\nu)G = 3G$ ($\nu$ = :data:`POISSON`, the model's
    incompressible half-space) beside every shear modulus, and the relaxed modulus
    $G_\infty$ (the rheology's ``relaxed_modulus``; the one modulus curves without a hold
    determine) with $E_\infty$. Standard model: ``E0``, ``E1``, ``G_inf``, ``E_inf``, ``tau``
    ($\eta_1/(G_0+G_1)$, the relaxation time at fixed strain). Elastic: ``E``. Prony series: ``G_0``
    (glass modulus $G_\infty + \sum G_k$), ``E_0``, ``E_inf``, ``E_k``.

    `evaluated`: the values and Jacobian of :func:`derived_fn` at `p` when already computed
    (e.g. for a chunk of curves in one call: :func:`fitting._optimise.identify`).

    **Returns:** one dict per quantity: ``name``, ``unit``, ``value``, ``stderr`` (nan when
    a parameter it depends on is not determined or at a bound), ``status`` ("ok" or "not
    determined"), ``definition``.
    """
    rows, fn = derived_fn(spec)
    values, grad = fn(np.asarray(p, dtype=float)) if evaluated is None else evaluated
    values = np.asarray(values)
    stderr, ok = delta_method(grad, covariance, status)
    out = []
    for i, (name, unit, definition) in enumerate(rows):
        se = float(stderr[i])
        out.append({"name": name, "unit": unit, "value": float(values[i]), "stderr": se,
                    "status": "ok" if ok[i] and math.isfinite(se) else "not determined",
                    "definition": definition + (" (E = 2(1 + nu) G, nu = 0.5)"
                                                if name.startswith("E") else "")})
    return out


def delta_method(grad, covariance, status) -> tuple[np.ndarray, np.ndarray]:
    r"""Standard errors of quantities with gradients `grad` `(q, p)` with respect to the
    natural parameters (`p`: those of `covariance` `(p, p)` and `status`), by the delta
    method $\sigma_f = \sqrt{\nabla f^\top C\,\nabla f}$ over the parameters each quantity
    depends on (a nonzero gradient) that are not fixed: `(stderr (q,), ok (q,))`. `ok`:
    every such parameter has status "ok"; otherwise the error is NaN. A quantity of fixed
    parameters only is exact (error 0); NaN where the covariance block it needs is not
    finite. The one home of the derived quantities' and Tabor's parameter's errors."""
    grad = np.atleast_2d(np.asarray(grad, dtype=float))
    cov = np.asarray(covariance, dtype=float)
    fixed = np.array([st == "fixed" for st in status], dtype=bool)
    good = np.array([st == "ok" for st in status], dtype=bool)
    used = (grad != 0) & ~fixed
    ok = np.all(good | ~used, axis=1)
    finite = np.isfinite(cov)
    # every covariance entry between two used parameters finite
    block = ~np.any(used[:, :, None] & used[:, None, :] & ~finite, axis=(1, 2))
    g = np.where(used, grad, 0.0)
    var = np.sum((g @ np.where(finite, cov, 0.0)) * g, axis=1)
    with np.errstate(invalid="ignore"):
        se = np.where(block, np.sqrt(np.where(var >= 0, var, np.nan)), np.nan)
    se = np.where(np.any(used, axis=1), se, 0.0)
    return np.where(ok, se, np.nan), ok


@functools.lru_cache(maxsize=16)
def derived_fn(spec):
    """The rows of :func:`derived_quantities` for `spec` and a function of the parameter
    vector returning their values and Jacobian, compiled once per model (not an eager
    forward-mode Jacobian traced again for every curve of a force map)."""
    import jax

    from jaxcontact._validate import without_guards

    from ._spec import rheology_kind

    rows, fn = rheology_kind(spec).derived(spec.arms)
    fn = without_guards(fn)  # the fit's values: no host callback in the finish's program
    return rows, jax.jit(lambda q: (fn(q), jax.jacfwd(fn)(q)))
