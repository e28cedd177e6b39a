r"""Weighted least squares: Levenberg–Marquardt in log-parameter space.

All starts of a fit run in one compiled call: a Levenberg–Marquardt iteration in one
`lax.while_loop` (:func:`solve`), `vmap`-ed over the initial guesses; the best final
$\chi^2$ wins. It is written here rather than taken from `optimistix.LevenbergMarquardt`
because that one compiled about 4× slower on this objective (≈45 s against ≈10 s for the
relaxed model on 2 CPU cores): here only one function, the residuals with their
forward-mode Jacobian, is traced. The unknowns are the free entries of
$\theta = \log p$ (optionally squashed into bounds, see
:class:`fitting._objective.Parameterisation`); fixed parameters never enter the solver.
Levenberg–Marquardt was chosen over L-BFGS because the objective is a sum of squares: the
Gauss–Newton model uses the Jacobian of the residuals (forward-mode, cheap for 4–10
parameters) and converges in a few tens of iterations where L-BFGS needs hundreds.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxcontact as jc

from ._data import Curve
from ._objective import (
    CurveBatch,
    ModelSpec,
    Parameterisation,
    initial_guess,
    make_spec,
    parameter_info,
    predict,
    prepare_curves,
    residuals,
)

__all__ = ["FitResult", "fit", "solve", "start_points", "make_parameterisation"]

#: Multiplicative spread of the extra starts (in log space: ±log 3 patterns).
_START_SPREAD = math.log(3.0)


@dataclass
class FitResult:
    """The outcome of :func:`fit` (numpy values, SI units).

    **Fields:** `names` (short parameter names), `columns` (names with units, e.g.
    ``G0_Pa``), `values`, `stderr` (nan for fixed parameters), `correlation`, `covariance`
    (natural parameters), `fixed` (bool per parameter), `chi2`, `reduced_chi2`,
    `r_squared`, `n_data`, `n_free`, `converged`, `start_losses` (final χ² of every
    start), `warnings` (identifiability messages), `timings` [s], `spec`, `data`
    (the `CurveBatch`), `curves`, `radius`, `model_solution` (the batched
    `ContactSolution` at the optimum).
    """

    names: list[str]
    columns: list[str]
    values: np.ndarray
    stderr: np.ndarray
    correlation: np.ndarray
    covariance: np.ndarray
    fixed: np.ndarray
    chi2: float
    reduced_chi2: float
    r_squared: float
    n_data: int
    n_free: int
    converged: bool
    start_losses: np.ndarray
    spec: ModelSpec
    data: CurveBatch
    curves: list = field(default_factory=list)
    radius: float | None = None
    warnings: list[str] = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    model_solution: object = None
    parameterisation: object = None

    def as_dict(self) -> dict[str, float]:
        """Parameter values by short name."""
        return dict(zip(self.names, (float(v) for v in self.values), strict=True))

    def __getitem__(self, name: str) -> float:
        return self.as_dict()[_short(name, self.names)]


def _short(name: str, names: Sequence[str]) -> str:
    if name in names:
        return name
    for n in names:
        if name.startswith(n + "_") and name[len(n) + 1:] in ("Pa", "Pa_s", "s", "J_m2"):
            return n
    raise KeyError(f"unknown parameter {name!r}; the parameters are {list(names)}")


def _normalise(mapping, names, what):
    out = {}
    for k, v in (mapping or {}).items():
        try:
            out[_short(k, names)] = v
        except KeyError:
            raise ValueError(f"{what}: unknown parameter {k!r}; the parameters are "
                             f"{list(names)}") from None
    return out


def make_parameterisation(names, reference: Mapping[str, float],
                          fixed: Mapping[str, float] | None,
                          bounds: Mapping[str, tuple[float, float]] | None) -> Parameterisation:
    """Parameterisation around `reference` (natural values) with fixed values and bounds."""
    fixed = _normalise(fixed, names, "fixed")
    bounds = _normalise(bounds, names, "bounds")
    ref = np.array([float(fixed.get(n, reference[n])) for n in names])
    if np.any(~np.isfinite(ref)) or np.any(ref <= 0):
        bad = names[int(np.argmax(~(np.isfinite(ref) & (ref > 0))))]
        raise ValueError(f"parameter {bad!r} must be finite and > 0; got {ref}")
    lo = np.full(len(names), -np.inf)
    hi = np.full(len(names), np.inf)
    for n, (a, b) in bounds.items():
        i = names.index(n)
        if not (0 < a < b):
            raise ValueError(f"bounds for {n!r} must satisfy 0 < lower < upper; got {(a, b)}")
        lo[i], hi[i] = math.log(a), math.log(b)
    free = tuple(i for i, n in enumerate(names) if n not in fixed)
    if not free:
        raise ValueError("fixed: every parameter is fixed; nothing to fit")
    return Parameterisation(free=free, reference=jnp.asarray(np.log(ref)),
                            lower=jnp.asarray(lo), upper=jnp.asarray(hi))


def start_points(n_free: int, n_starts: int) -> np.ndarray:
    """Offsets of the starts in log space, shape `(n_starts, n_free)`.

    Start 0 is the initial guess; the others are deterministic sign patterns of
    ±log 3 (a two-level design), cycling through parameters, then random ±log 3.
    """
    rng = np.random.default_rng(0)
    pts = [np.zeros(n_free)]
    k = 1
    while len(pts) < n_starts:
        if k <= 2 * n_free:
            z = np.zeros(n_free)
            z[(k - 1) // 2] = _START_SPREAD * (1 if k % 2 else -1)
        else:
            z = _START_SPREAD * rng.uniform(-1, 1, n_free)
        pts.append(z)
        k += 1
    return np.stack(pts)


def _lm(fn_jac, z0, rtol, atol, max_steps):
    """Levenberg–Marquardt (Marquardt scaling, multiplicative damping) in a while_loop."""
    r0, J0 = fn_jac(z0)
    dtype = r0.dtype

    def chi2_of(r):
        return jnp.sum(r * r)

    init = (z0, r0, J0, chi2_of(r0), jnp.asarray(1e-3, dtype), jnp.asarray(0),
            jnp.asarray(False), jnp.asarray(False))

    def cond(c):
        return (c[5] < max_steps) & ~c[6]

    def body(c):
        z, r, J, chi2, lam, it, _, _ = c
        A = J.T @ J
        g = J.T @ r
        D = jnp.maximum(jnp.diag(A), 1e-12 * jnp.max(jnp.diag(A)) + 1e-300)
        step = -jnp.linalg.solve(A + lam * jnp.diag(D), g)
        step = jnp.where(jnp.isfinite(step), step, 0.0)
        z_new = z + step
        r_new, J_new = fn_jac(z_new)
        chi2_new = chi2_of(r_new)
        ok = jnp.isfinite(chi2_new) & (chi2_new <= chi2)
        small = (jnp.max(jnp.abs(step)) < atol + rtol * jnp.max(jnp.abs(z))) | (
            (chi2 - chi2_new) <= rtol * chi2)
        converged = (ok & small) | (lam > 1e10)
        z = jnp.where(ok, z_new, z)
        r = jnp.where(ok, r_new, r)
        J = jnp.where(ok, J_new, J)
        chi2 = jnp.where(ok, chi2_new, chi2)
        lam = jnp.where(ok, jnp.maximum(lam * 0.2, 1e-12), lam * 10.0)
        return (z, r, J, chi2, lam, it + 1, converged, ok & small)

    z, r, J, chi2, lam, it, done, success = jax.lax.while_loop(cond, body, init)
    return z, chi2, success | (done & (lam <= 1e10)), it


@eqx.filter_jit
def solve(spec: ModelSpec, param: Parameterisation, data: CurveBatch, z0s, *,
          rtol: float = 1e-10, atol: float = 1e-9, max_steps: int = 200):
    r"""Levenberg–Marquardt from every row of `z0s` (vmapped); returns (z, chi2, ok, steps).

    The Jacobian is exact (`jax.jacfwd`, one forward pass per free parameter, together with
    the residuals); the damped Gauss–Newton step is $(J^\top J + \lambda\,\mathrm{diag}
    (J^\top J))\,\delta = -J^\top r$; $\lambda$ shrinks ×0.2 on an accepted step and
    grows ×10 on a rejected one. Stops when an accepted step changes $z$ by less than
    `atol + rtol·|z|` or $\chi^2$ by less than `rtol·χ²`.
    """

    def fn(z):
        r = residuals(param.theta(z), data, spec)
        return r, r

    def fn_jac(z):
        J, r = jax.jacfwd(fn, has_aux=True)(z)
        return r, J

    return jax.vmap(lambda z0: _lm(fn_jac, z0, rtol, atol, max_steps))(z0s)


_predict_jit = eqx.filter_jit(predict)


class _Progress:
    def __init__(self, enabled: bool):
        self.enabled = enabled
        self.t0 = time.perf_counter()

    def __call__(self, msg: str):
        if self.enabled:
            print(f"[fit {time.perf_counter() - self.t0:7.2f} s] {msg}", file=sys.stderr,
                  flush=True)


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
    n_starts: int = 4,
    max_samples: int | Mapping[str, int] | None = None,
    cells: int = 32,
    max_steps: int = 200,
    progress: bool = True,
) -> FitResult:
    r"""Identify the rheology and $\Delta\gamma$ from one or several curves.

    **Arguments:**

    - `curves`: a :class:`Curve` or a list of them (different speeds and holds share
      the material parameters). Indentation positive into the sample, 0 at contact.
    - `radius`: parabolic indenter radius $R$ [m] (or pass any jaxcontact `profile`).
    - `model`: "relaxed" (`jc.retract`, retract segment after a long hold) or "history"
      (`jc.simulate`, approach–hold–retract).
    - `rheology`: "standard" ($G_0, G_1, \eta_1$) or "prony:N".
    - `spring_constant`: cantilever stiffness [N/m] (one, or one per curve): history model
      under `CompliantLoading` (see `fitting._objective`). `None`: displacement control.
    - `initial`: initial values by name (``"G0"`` or ``"G0_Pa"`` ...); missing ones from
      the data (:func:`fitting._objective.initial_guess`).
    - `fixed`: values of parameters held fixed.
    - `bounds`: `{name: (lower, upper)}` in natural units.
    - `n_starts`: number of starts (vmapped in one call); the best $\chi^2$ is kept.
    - `max_samples`: resampling per segment (see `prepare_curves`).
    - `cells`: foundation grid of the history model.
    - `progress`: print the stages and the per-start results to stderr.

    **Returns:** a :class:`FitResult` with values, standard errors, correlation matrix,
    reduced $\chi^2$, $R^2$ and identifiability warnings (also issued as
    :class:`IdentifiabilityWarning`).
    """
    from ._uncertainty import gauss_newton

    show = _Progress(progress)
    timings = {}
    t_start = time.perf_counter()
    if isinstance(curves, Curve):
        curves = [curves]
    curves = list(curves)
    if n_starts < 1:
        raise ValueError(f"n_starts must be >= 1; got {n_starts}")
    spec = make_spec(model, rheology, compliant=spring_constant is not None, cells=cells)
    if profile is None:
        if radius is None or not (math.isfinite(float(radius)) and float(radius) > 0):
            raise ValueError(f"radius must be finite and > 0 [m]; got {radius!r}")
        profile = jc.Parabola(float(radius))
    data = prepare_curves(curves, spec, profile=profile, spring_constant=spring_constant,
                          max_samples=max_samples)
    names = [n for n, _, _ in parameter_info(spec)]
    columns = [c for _, _, c in parameter_info(spec)]
    guess = initial_guess(curves, spec, profile)
    guess.update(_normalise(initial, names, "initial"))
    param = make_parameterisation(names, guess, fixed, bounds)
    n_free = len(param.free)
    z_init = param.z_of(np.asarray(param.reference))
    z0s = jnp.asarray(z_init[None, :] + start_points(n_free, n_starts))
    show(f"{data.n_curves} curve(s), {int(np.sum(np.asarray(data.valid)))} samples, "
         f"model={spec.model}, rheology={rheology}, {n_free} free parameter(s), "
         f"{n_starts} start(s)")
    timings["prepare"] = time.perf_counter() - t_start

    t0 = time.perf_counter()
    zs, chi2s, oks, steps = solve(spec, param, data, z0s, max_steps=max_steps)
    chi2s = np.asarray(chi2s)
    timings["optimise"] = time.perf_counter() - t0
    for k in range(n_starts):
        show(f"start {k + 1}/{n_starts}: chi2 = {chi2s[k]:.6g}, steps = {int(steps[k])}, "
             f"converged = {bool(oks[k])}")
    best = int(np.nanargmin(np.where(np.isfinite(chi2s), chi2s, np.inf)))
    theta = np.asarray(param.theta(zs[best]))
    p = np.exp(theta)

    t0 = time.perf_counter()
    fixed_mask = np.ones(len(names), dtype=bool)
    fixed_mask[list(param.free)] = False
    unc = gauss_newton(spec, p, data, list(param.free), names)
    timings["uncertainty"] = time.perf_counter() - t0
    sol = _predict_jit(spec, jnp.asarray(p), data)
    valid = np.asarray(data.valid) > 0
    fm = np.asarray(sol.force)[valid]
    fd = np.asarray(data.force)[valid]
    ss_res = float(np.sum((fm - fd) ** 2))
    ss_tot = float(np.sum((fd - fd.mean()) ** 2))
    timings["total"] = time.perf_counter() - t_start
    show(f"done: chi2_red = {unc['reduced_chi2']:.4g}, R^2 = {1 - ss_res / ss_tot:.5f}")
    return FitResult(
        names=names, columns=columns, values=p, stderr=unc["stderr"],
        correlation=unc["correlation"], covariance=unc["covariance"], fixed=fixed_mask,
        chi2=float(chi2s[best]), reduced_chi2=unc["reduced_chi2"],
        r_squared=1.0 - ss_res / ss_tot if ss_tot > 0 else float("nan"),
        n_data=unc["n_data"], n_free=n_free, converged=bool(oks[best]),
        start_losses=chi2s, spec=spec, data=data, curves=curves,
        radius=None if radius is None else float(radius), warnings=unc["warnings"],
        timings=timings, model_solution=sol, parameterisation=param,
    )
