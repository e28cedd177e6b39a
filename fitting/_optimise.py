r"""Weighted least squares in log-parameter space: Levenberg–Marquardt or optax L-BFGS.

All starts of a fit run in one compiled call (:func:`solve`): the optimiser runs in one
`lax.while_loop`, `vmap`-ed over the initial guesses; the best final $\chi^2$ wins. The
unknowns are the free entries of $\theta = \log p$ (optionally squashed into bounds, see
:class:`fitting._objective.Parameterisation`); fixed parameters never enter the solver.
Both optimisers minimise the same objective $\tfrac12\sum r_i^2$ (the weighted residuals of
:func:`fitting._objective.residuals`) and return the same `(z, chi2, ok, steps)`.

``optimiser="lm"`` (default): Levenberg–Marquardt, written here (Marquardt scaling,
multiplicative damping, and a step extension that doubles the step while the decrease beats
the Gauss–Newton prediction, see `_lm_method`). The objective is a sum of squares, so the
Gauss–Newton model with the exact forward-mode Jacobian (one linearisation, pushed along
each of the 4–10 free directions) is the natural choice: each step costs one Jacobian, the
steps are scale-invariant, and the final Jacobian is reused for the standard errors. It is
not taken from `optimistix.LevenbergMarquardt` because that one compiled about 4× slower on
this objective (≈45 s against ≈10 s for the relaxed model on 2 CPU cores).

``optimiser="lbfgs"``: `optax.lbfgs` (memory 10) with its zoom line search
(`optax.scale_by_zoom_linesearch`, strong Wolfe conditions), driven by the same
`lax.while_loop`; the gradient $J^\top r$ comes from the same forward-mode Jacobian
(reverse mode through the forward models' jump-off refinement gives NaN). It stops when an
iteration lowers the loss by less than `rtol` relative, or the largest gradient component
falls below `gtol` times the loss; a line search that raises the loss by more than that
ends the run (not converged).

Which to use when (measured on the benchmark data of `benchmarks/bench_fit.py`: 100
synthetic relaxed-model curve sets, 3 speeds × 200 samples, 1 % noise, random true
parameters, data-driven initial guess, one start, `rtol = 1e-8`):

* LM: 18 iterations median (mean 23.7, 90th percentile 44, max 92), one Jacobian each;
  ≈0.08–0.11 ms per iteration for one problem on this CPU (one core, with
  `fitting.XLA_CPU_FLAGS`); the χ² was more than 1 % above the
  best of LM, L-BFGS and scipy in 16 of 100 sets (local minima where the model's jump-off
  crosses samples). Without the step extension plain LM needed 22 median, mean
  33.1, max 199 iterations. scipy `least_squares` (trf): 26 residual evaluations median
  (mean 32.6, max 172), each with a 4-evaluation finite-difference Jacobian; 27 of 100
  sets more than 1 % above the best.
* L-BFGS: 19 iterations median (mean 19.8, max 32) with 25 gradient evaluations median
  (mean 28, max 76); more than 1 % above the best in only 2 of 100 sets: the line search
  crosses the kinks of the jump-off ramp that stall the Gauss–Newton model. But each
  iteration carries the zoom line search's own loop, so a fit took 1.5–2× longer than LM
  (≈4.5–6 ms against ≈3 ms for the curve set of the benchmark), and from a start 3× too
  large in every parameter a single L-BFGS start ended in a local minimum ($G_1 \to 0$)
  where LM did not (the default 4 starts recover).

Use "lm" (default) for speed and for the standard errors; use "lbfgs", with several starts,
when the jump-off of the data is far from that of the initial guess or LM's optimum looks
like a local one (compare `start_losses`).

Starts and batches: a `vmap`-ed `while_loop` runs until its slowest lane stops. For many
independent problems (:func:`solve_batch`) the lanes are therefore scheduled as a pool:
`workers` lanes iterate, and a lane whose problem has stopped takes the next one from the
queue in the same compiled loop, so the cost is the sum of the steps, not
(number of problems) × (largest step count). With several devices (GPUs, or CPU cores that
JAX exposes as devices) every device runs its own pool on an equal share of the problems,
in one `jax.pmap` call. Measured for the 100 sets above (LM; `python
benchmarks/bench_fit.py`, 2-core CPU, 2026-11-23): pool of 8 lanes on each of 2 CPU devices
0.115 s, on one device 0.19–0.21 s, one plain `vmap` over all 100 sets 0.42–0.72 s (every
lane runs the 92 steps of the slowest set), a Python loop over the jitted single-problem
`solve` 0.22–0.24 s; 100 sequential scipy fits 4.95 s. On a CPU the lanes buy little
vectorisation (the per-lane cost of a Jacobian is almost that of one problem alone; 16 or
32 lanes were slower than 8), so no waiting and one pool per core is what counts. L-BFGS
batches poorly (the zoom line search is a nested `while_loop` whose lanes wait for each
other): its pool of 8 lanes was slower than a Python loop over problems.
"""

from __future__ import annotations

import functools
import math
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
import optax.tree_utils as otu

import jaxcontact as jc

from ._curve import Curve
from ._objective import (
    CurveBatch,
    ModelSpec,
    Parameterisation,
    canonical_name,
    initial_guess,
    jacobian_fn,
    log_jacobian,
    make_spec,
    normalise_names,
    parameter_info,
    predict,
    prepare_curves,
    residuals,
)

__all__ = ["FitResult", "OPTIMISERS", "fit", "solve", "solve_batch", "start_points",
           "make_parameterisation"]

#: The optimisers of :func:`fit` and :func:`solve`.
OPTIMISERS = ("lm", "lbfgs")

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
    `ContactSolution` at the optimum), `optimiser` ("lm" or "lbfgs"), `start_steps`
    (iterations of every start).
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
    optimiser: str = "lm"
    start_steps: np.ndarray | None = None

    def as_dict(self) -> dict[str, float]:
        """Parameter values by short name."""
        return dict(zip(self.names, (float(v) for v in self.values), strict=True))

    def __getitem__(self, name: str) -> float:
        return self.as_dict()[canonical_name(name, self.names)]


def make_parameterisation(names, reference: Mapping[str, float],
                          fixed: Mapping[str, float] | None,
                          bounds: Mapping[str, tuple[float, float]] | None) -> Parameterisation:
    """Parameterisation around `reference` (natural values) with fixed values and bounds."""
    fixed = normalise_names(fixed, names, "fixed")
    bounds = normalise_names(bounds, names, "bounds")
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
    reference, lower, upper = jax.device_put((np.log(ref), lo, hi))
    return Parameterisation(free=free, reference=reference, lower=lower, upper=upper)


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


# --------------------------------------------------------------------------------------
# Optimisers: one iteration each, driven by a while_loop (vmap over starts) or a pool
# --------------------------------------------------------------------------------------


def _residual_fn(spec: ModelSpec):
    """`fn_r(z, ctx)`: the weighted residuals at the free vector `z`, `ctx = (param, data)`."""

    def fn_r(z, ctx):
        param, data = ctx
        return residuals(param.theta(z), data, spec)

    return fn_r


class _Method(NamedTuple):
    """An optimiser as `init(z0, ctx) -> state` and `step(state, ctx) -> state`.

    Every state has the fields `z`, `steps`, `done` and `ok`; `chi2(state)` is its
    $\\chi^2 = \\sum r^2$.
    """

    init: object
    step: object
    chi2: object


# ---- Levenberg–Marquardt ------------------------------------------------------------------

_LAM0 = 1e-3
_LAM_MAX = 1e10
_GAIN_EXTEND = 1.25
_MU_MAX = 1e3


class _LMState(NamedTuple):
    z: jax.Array
    r: jax.Array
    J: jax.Array
    chi2: jax.Array
    lam: jax.Array
    mu: jax.Array
    steps: jax.Array
    done: jax.Array
    ok: jax.Array


def _lm_method(fn_r, rtol, atol, max_steps) -> _Method:
    r"""Levenberg–Marquardt with step extension.

    Trial step $\delta = -\mu\,(J^\top J + \lambda\,\mathrm{diag}(J^\top J))^{-1}
    J^\top r$. $\lambda$ shrinks ×0.2 on an accepted step and grows ×10 on a rejected one.
    $\mu$ (normally 1) doubles, up to $10^3$, after an accepted step whose actual decrease
    of $\chi^2$ exceeds 1.25× the decrease the Gauss–Newton model predicted: near the jump-
    off the ramp-weighted residuals curve so that the objective is almost linear along the
    step while $J^\top J$ predicts curvature, and plain LM then crawls with equal, collinear
    steps (measured: 40 steps of 5e-5 in log Δγ). $\mu$ falls back to 1 when the gain
    ratio drops below 0.75 or a step is rejected (then without raising $\lambda$).
    Converged when an accepted step changes $z$ by less than `atol + rtol·max|z|` or
    $\chi^2$ by less than `rtol·χ²`; stops unconverged when $\lambda > 10^{10}$ or after
    `max_steps`.
    """

    def jac(z, ctx):
        return jacobian_fn(lambda zz: fn_r(zz, ctx))(z)

    def init(z0, ctx):
        r0, J0 = jac(z0, ctx)
        one = jnp.asarray(1.0, r0.dtype)
        return _LMState(z0, r0, J0, jnp.sum(r0 * r0), _LAM0 * one, one, jnp.asarray(0),
                        jnp.asarray(max_steps <= 0), jnp.asarray(False))

    def step(s, ctx):
        A = s.J.T @ s.J
        g = s.J.T @ s.r
        diag = jnp.diag(A)
        D = jnp.maximum(diag, 1e-12 * jnp.max(diag) + 1e-300)
        delta = -s.mu * jnp.linalg.solve(A + s.lam * jnp.diag(D), g)
        delta = jnp.where(jnp.isfinite(delta), delta, 0.0)
        r_new, J_new = jac(s.z + delta, ctx)
        chi2_new = jnp.sum(r_new * r_new)
        ok = jnp.isfinite(chi2_new) & (chi2_new <= s.chi2)
        predicted = -(2.0 * g @ delta + delta @ A @ delta)
        gain = (s.chi2 - chi2_new) / jnp.maximum(predicted, 1e-300)
        small = (jnp.max(jnp.abs(delta)) < atol + rtol * jnp.max(jnp.abs(s.z))) | (
            (s.chi2 - chi2_new) <= rtol * s.chi2)
        converged = ok & small
        lam = jnp.where(ok, jnp.maximum(s.lam * 0.2, 1e-12),
                        jnp.where(s.mu > 1.0, s.lam, s.lam * 10.0))
        mu = jnp.where(ok & (gain > _GAIN_EXTEND), jnp.minimum(2.0 * s.mu, _MU_MAX),
                       jnp.where(ok & (gain > 0.75), s.mu, 1.0))
        steps = s.steps + 1
        return _LMState(
            z=jnp.where(ok, s.z + delta, s.z),
            r=jnp.where(ok, r_new, s.r),
            J=jnp.where(ok, J_new, s.J),
            chi2=jnp.where(ok, chi2_new, s.chi2),
            lam=lam,
            mu=mu,
            steps=steps,
            done=converged | (lam > _LAM_MAX) | (steps >= max_steps),
            ok=converged,
        )

    return _Method(init, step, lambda s: s.chi2)


# ---- optax L-BFGS -------------------------------------------------------------------------


def _half_ssq(fn_r, z, ctx):
    r = fn_r(z, ctx)
    return 0.5 * jnp.sum(r * r)


def _half_ssq_fwd(fn_r, z, ctx):
    r, J = jacobian_fn(lambda zz: fn_r(zz, ctx))(z)
    return 0.5 * jnp.sum(r * r), (J.T @ r, ctx)


def _zero_cotangent(x):
    x = jnp.asarray(x)
    if jnp.issubdtype(x.dtype, jnp.inexact):
        return jnp.zeros_like(x)
    return np.zeros(x.shape, dtype=jax.dtypes.float0)


def _half_ssq_bwd(fn_r, res, ct):
    g, ctx = res
    return ct * g, jax.tree.map(_zero_cotangent, ctx)


# ½ Σ r²; its gradient J^T r comes from the forward-mode Jacobian
_half_ssq = jax.custom_vjp(_half_ssq, nondiff_argnums=(0,))
_half_ssq.defvjp(_half_ssq_fwd, _half_ssq_bwd)


class _LBFGSState(NamedTuple):
    z: jax.Array
    opt_state: tuple
    value: jax.Array
    grad: jax.Array
    steps: jax.Array
    evaluations: jax.Array
    done: jax.Array
    ok: jax.Array


def _lbfgs_method(fn_r, rtol, gtol, max_steps, memory=10, linesearch_steps=20) -> _Method:
    """optax L-BFGS with the zoom line search on ½ Σ r² (see the module docstring)."""
    opt = optax.lbfgs(memory_size=memory, linesearch=optax.scale_by_zoom_linesearch(
        max_linesearch_steps=linesearch_steps, initial_guess_strategy="one"))

    def value_fn(z, ctx):
        return _half_ssq(fn_r, z, ctx)

    def init(z0, ctx):
        v0, g0 = jax.value_and_grad(value_fn)(z0, ctx)
        return _LBFGSState(z0, opt.init(z0), v0, g0, jnp.asarray(0), jnp.asarray(1),
                           jnp.asarray(max_steps <= 0), jnp.asarray(False))

    def step(s, ctx):
        # value and gradient at s.z are carried in the state (not re-evaluated: optax's
        # `value_and_grad_from_state` would do so in a `lax.cond`, i.e. always under vmap)
        updates, opt_state = opt.update(s.grad, s.opt_state, s.z, value=s.value,
                                        grad=s.grad, value_fn=value_fn, ctx=ctx)
        z_new = optax.apply_updates(s.z, updates)
        v_new = otu.tree_get(opt_state, "value")
        g_new = otu.tree_get(opt_state, "grad")
        n_eval = otu.tree_get(opt_state, "info").num_linesearch_steps
        better = jnp.isfinite(v_new) & (v_new <= s.value)
        scale = jnp.maximum(jnp.abs(v_new), 1e-300)
        # at the optimum round-off decides whether the last step is "better": a change of
        # the loss within rtol either way is convergence
        flat = jnp.isfinite(v_new) & (jnp.abs(s.value - v_new) <= rtol * scale)
        grad_small = better & (jnp.max(jnp.abs(g_new)) <= gtol * scale)
        converged = flat | grad_small
        steps = s.steps + 1
        return _LBFGSState(
            z=jnp.where(better, z_new, s.z),
            opt_state=opt_state,
            value=jnp.where(better, v_new, s.value),
            grad=jnp.where(better, g_new, s.grad),
            steps=steps,
            evaluations=s.evaluations + n_eval,
            # a line search without decrease ends the run (not converged)
            done=converged | ~better | (steps >= max_steps),
            ok=converged,
        )

    return _Method(init, step, lambda s: 2.0 * s.value)


def _method(spec, optimiser, rtol, atol, gtol, max_steps) -> _Method:
    fn_r = _residual_fn(spec)
    if optimiser == "lm":
        return _lm_method(fn_r, rtol, atol, max_steps)
    if optimiser == "lbfgs":
        return _lbfgs_method(fn_r, rtol, gtol, max_steps)
    raise ValueError(f"optimiser must be one of {OPTIMISERS}; got {optimiser!r}")


# ---- drivers ------------------------------------------------------------------------------


def _keep_done(step):
    """`step` that leaves a finished state unchanged."""

    def safe(s, ctx):
        new = step(s, ctx)
        return jax.tree.map(lambda a, b: jnp.where(s.done, a, b), s, new)

    return safe


def _run_vmap(method: _Method, z0s, ctx):
    """Every start in its own lane of one vmapped while_loop (shared `ctx`)."""

    def one(z0):
        s = method.init(z0, ctx)
        return jax.lax.while_loop(lambda s: ~s.done, lambda s: method.step(s, ctx), s)

    if z0s.shape[0] == 1:  # one start: no batch axis inside the loop (unbatched algebra)
        return jax.tree.map(lambda x: x[None], one(z0s[0]))
    return jax.vmap(one)(z0s)


def _take(tree, i):
    return jax.tree.map(lambda x: x[i], tree)


def _run_pool(method: _Method, z0s, ctxs, workers: int):
    """Solve `len(z0s)` problems with `workers` lanes; a finished lane takes the next one.

    `ctxs` has a leading task axis. All initial states are evaluated first (one batched
    call); then one while_loop iterates all lanes; a lane whose problem is done writes
    `(z, chi2, ok, steps)` to the output and is refilled from the queue. The loop ends when
    every problem is written. Cost: about (sum of steps)/`workers` iterations plus the tail
    of the last problems, instead of (largest step count) for every problem.
    """
    n_tasks = z0s.shape[0]
    w = max(1, min(int(workers), n_tasks))
    states0 = jax.vmap(method.init)(z0s, ctxs)
    step = _keep_done(method.step)

    def result(s):
        return s.z, method.chi2(s), s.ok, s.steps

    def body(c):
        work, tasks, out, queued, written = c
        ctx = _take(ctxs, jnp.minimum(tasks, n_tasks - 1))
        work = jax.vmap(step)(work, ctx)
        finished = (tasks < n_tasks) & work.done
        slot = jnp.where(finished, tasks, n_tasks)  # out of range: dropped
        out = jax.tree.map(lambda o, x: o.at[slot].set(x, mode="drop"), out,
                           jax.vmap(result)(work))
        new = queued + jnp.cumsum(finished) - 1
        refill = finished & (new < n_tasks)
        fresh = _take(states0, jnp.minimum(new, n_tasks - 1))
        work = jax.tree.map(
            lambda x, f: jnp.where(refill.reshape((-1,) + (1,) * (x.ndim - 1)), f, x),
            work, fresh)
        tasks = jnp.where(finished, new, tasks)
        n_fin = jnp.sum(finished)
        return work, tasks, out, queued + n_fin, written + n_fin

    init = (_take(states0, jnp.arange(w)), jnp.arange(w), jax.vmap(result)(states0),
            jnp.asarray(w), jnp.asarray(0))
    return jax.lax.while_loop(lambda c: c[4] < n_tasks, body, init)[2]


# `jax.jit` with the options static, rather than `eqx.filter_jit`: the problem's pytrees hold
# arrays only (the model choice and the free indices are static fields), and jit's C++
# dispatch saves the ~0.2-0.5 ms per call of partitioning them in Python (measured on the
# benchmark fit of `benchmarks/bench_fit.py`, where a whole solve takes ~3 ms).
_OPTIONS = ("rtol", "atol", "gtol", "max_steps", "optimiser", "workers")


@functools.partial(jax.jit, static_argnames=_OPTIONS)
def solve(spec: ModelSpec, param: Parameterisation, data: CurveBatch, z0s, *,
          rtol: float = 1e-8, atol: float = 1e-9, gtol: float = 1e-8, max_steps: int = 200,
          optimiser: str = "lm", workers: int | None = None):
    r"""Minimise ½ Σ r² from every row of `z0s`; returns `(z, chi2, ok, steps)` per start.

    **Arguments:** `spec`, `param`, `data` (the problem: residuals
    `residuals(param.theta(z), data, spec)`), `z0s` (starts, shape `(starts, n_free)`),
    `optimiser` ("lm" or "lbfgs", see the module docstring), `rtol` (relative change of
    $\chi^2$, and for "lm" of the step, at which a run has converged; scipy's
    `least_squares` default `ftol = xtol = 1e-8`), `atol` (absolute step size, "lm"),
    `gtol` (largest gradient component relative to the loss, "lbfgs"), `max_steps`
    (iterations per start), `workers` (`None`: one vmapped lane per start; an integer:
    that many lanes scheduled as a pool, see :func:`solve_batch`).

    The Jacobian is exact (forward mode). `steps` counts iterations (for "lm" one Jacobian
    each, for "lbfgs" one line search of one or more gradient evaluations).
    """
    method = _method(spec, optimiser, rtol, atol, gtol, max_steps)
    if workers is None:
        s = _run_vmap(method, z0s, (param, data))
        return s.z, jax.vmap(method.chi2)(s), s.ok, s.steps
    n = z0s.shape[0]
    ctxs = jax.tree.map(lambda x: jnp.broadcast_to(x, (n,) + jnp.shape(x)), (param, data))
    return _run_pool(method, z0s, ctxs, workers)


def solve_batch(spec: ModelSpec, params: Parameterisation, datas: CurveBatch, z0s, *,
                workers: int = 8, rtol: float = 1e-8, atol: float = 1e-9, gtol: float = 1e-8,
                max_steps: int = 200, optimiser: str = "lm", devices=None):
    """Independent problems in one compiled call, scheduled as a pool of `workers` lanes.

    `params`, `datas` and `z0s` carry a leading problem axis (stack equally shaped problems
    with ``jax.tree.map(lambda *x: jnp.stack(x), *problems)``; the free parameters must be
    the same); one start per problem (repeat a problem for several starts). A lane whose
    problem has stopped takes the next one from the queue inside the same `while_loop`,
    so the slowest problem no longer holds all lanes. Returns `(z, chi2, ok, steps)` per
    problem, as :func:`solve`.

    `devices`: the devices to spread the problems over (default: every local device of
    JAX's default backend). With more than one, the problems are split into equal shares
    (the last problem repeated to fill them; its copies are dropped) and every device runs
    its own pool of `workers` lanes, all in one `jax.pmap` call: several GPUs, or several
    CPU cores once JAX exposes them as devices (``jax.config.update("jax_num_cpu_devices",
    n)`` before the first computation, as `benchmarks/bench_fit.py` does for the usable
    cores). Results do not depend on the split.
    """
    devices = list(jax.local_devices() if devices is None else devices)
    if not devices:
        raise ValueError("devices: give at least one device (or None for all local ones)")
    n = z0s.shape[0]
    n_dev = max(1, min(len(devices), n))
    opts = dict(workers=int(workers), rtol=float(rtol), atol=float(atol), gtol=float(gtol),
                max_steps=int(max_steps), optimiser=optimiser)
    if n_dev == 1:
        with jax.default_device(devices[0]):
            return _solve_batch(spec, params, datas, z0s, **opts)
    share = -(-n // n_dev)
    fill = np.minimum(np.arange(n_dev * share), n - 1)

    def split(x):
        x = jnp.asarray(x)[fill]
        return x.reshape((n_dev, share) + x.shape[1:])

    run = _pmapped_pool(spec, tuple(devices[:n_dev]), tuple(sorted(opts.items())))
    out = run(jax.tree.map(split, params), jax.tree.map(split, datas), split(z0s))
    return tuple(x.reshape((n_dev * share,) + x.shape[2:])[:n] for x in out)


@functools.partial(jax.jit, static_argnames=_OPTIONS)
def _solve_batch(spec, params, datas, z0s, *, workers, rtol, atol, gtol, max_steps,
                 optimiser):
    method = _method(spec, optimiser, rtol, atol, gtol, max_steps)
    return _run_pool(method, z0s, (params, datas), workers)


@functools.lru_cache(maxsize=16)
def _pmapped_pool(spec, devices, opts):
    # every device runs `_solve_batch` on its share
    return jax.pmap(lambda p, d, z: _solve_batch(spec, p, d, z, **dict(opts)),
                    devices=list(devices))


@functools.partial(jax.jit, static_argnums=(4, 5, 6, 7, 8))
def _fit_core(spec, param, data, z0s, optimiser, rtol, atol, gtol, max_steps):
    """The optimisation, the Jacobian at the optimum and the prediction in one call."""
    method = _method(spec, optimiser, rtol, atol, gtol, max_steps)
    s = _run_vmap(method, z0s, (param, data))
    chi2 = jax.vmap(method.chi2)(s)
    best = jnp.argmin(jnp.where(jnp.isfinite(chi2), chi2, jnp.inf))
    z = s.z[best]
    theta = param.theta(z)
    idx = jnp.asarray(param.free)

    def fresh():
        return log_jacobian(spec, param.free, theta, data)

    if optimiser == "lm":
        # reuse the last accepted Jacobian: d r/d log p = (d r/d z) / (d theta/d z)
        dtheta = jnp.diagonal(jax.jacfwd(lambda zz: param.theta(zz)[idx])(z))
        r, J = jax.lax.cond(jnp.all(jnp.abs(dtheta) > 1e-8),
                            lambda: (s.r[best], s.J[best] / dtheta[None, :]), fresh)
    else:
        r, J = fresh()
    sol = predict(spec, jnp.exp(theta), data)
    valid = data.valid > 0
    n = jnp.sum(valid)
    mean = jnp.sum(jnp.where(valid, data.force, 0.0)) / n
    ss_res = jnp.sum(jnp.where(valid, (sol.force - data.force) ** 2, 0.0))
    ss_tot = jnp.sum(jnp.where(valid, (data.force - mean) ** 2, 0.0))
    return dict(z=s.z, chi2=chi2, ok=s.ok, steps=s.steps, best=best, theta=theta, r=r, J=J,
                ss_res=ss_res, ss_tot=ss_tot), sol


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
    optimiser: str = "lm",
    rtol: float = 1e-8,
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
    - `max_steps`: iterations per start.
    - `progress`: print the stages and the per-start results to stderr.
    - `optimiser`: "lm" (Levenberg–Marquardt, default) or "lbfgs" (optax L-BFGS with a
      zoom line search); see :mod:`fitting._optimise` for which to use when.
    - `rtol`: convergence tolerance (relative change of $\chi^2$ per iteration).

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
    if optimiser not in OPTIMISERS:
        raise ValueError(f"optimiser must be one of {OPTIMISERS}; got {optimiser!r}")
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
    guess.update(normalise_names(initial, names, "initial"))
    param = make_parameterisation(names, guess, fixed, bounds)
    n_free = len(param.free)
    z_init = param.z_of(np.asarray(param.reference))
    z0s = jnp.asarray(z_init[None, :] + start_points(n_free, n_starts))
    show(f"{data.n_curves} curve(s), {int(np.sum(np.asarray(data.valid)))} samples, "
         f"model={spec.model}, rheology={rheology}, {n_free} free parameter(s), "
         f"{n_starts} start(s)")
    timings["prepare"] = time.perf_counter() - t_start

    t0 = time.perf_counter()
    core, sol = _fit_core(spec, param, data, z0s, optimiser, float(rtol), 1e-9, 1e-8,
                          int(max_steps))
    core = jax.device_get(core)
    chi2s, oks, steps, best = core["chi2"], core["ok"], core["steps"], int(core["best"])
    timings["optimise"] = time.perf_counter() - t0
    for k in range(n_starts):
        show(f"start {k + 1}/{n_starts}: chi2 = {chi2s[k]:.6g}, steps = {int(steps[k])}, "
             f"converged = {bool(oks[k])}")
    p = np.exp(core["theta"])

    t0 = time.perf_counter()
    fixed_mask = np.ones(len(names), dtype=bool)
    fixed_mask[list(param.free)] = False
    # the residuals and Jacobian at the optimum come from the optimiser's compiled call
    unc = gauss_newton(spec, p, data, list(param.free), names,
                       jacobian=(core["r"], core["J"]))
    timings["uncertainty"] = time.perf_counter() - t0
    ss_res, ss_tot = float(core["ss_res"]), float(core["ss_tot"])
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
        timings=timings, model_solution=sol, parameterisation=param, optimiser=optimiser,
        start_steps=np.asarray(steps),
    )
