r"""Least-squares solvers, written as optimistix writes them: `init` / `step` / `terminate`.

A solver minimises $\tfrac12\sum r_i^2$ of a residual function `fn(z, ctx)` over the free
vector $z$. Its state is an `eqx.Module` with at least `z`, `steps`, `done`, `ok`; the
drivers below run `step` in a `lax.while_loop` until `terminate` says so:

* :func:`run_starts`: every start in its own lane of one vmapped loop (one start: no batch
  axis inside the loop, so the linear algebra stays unbatched);
* :func:`run_pool`: many independent problems on `workers` lanes; a lane whose problem
  has stopped takes the next one from the queue inside the same loop, so the cost is the
  sum of the steps rather than (problems × the largest step count). Each problem may have
  its own step limit (`limits`; 0: not run, it costs one lane-step) and a bound on its
  $\chi^2$ (`bounds`: a run still above it after :data:`ABANDON_AFTER` steps is abandoned,
  :meth:`AbstractLeastSquaresSolver.abandon`).

Both return a :class:`Solution`: per problem (lane) the end point, $\chi^2$, the steps and
a :class:`RESULTS` code (converged, step limit, stagnated, non-finite start, abandoned), as
optimistix returns one.

:class:`LevenbergMarquardt` (default of :func:`fitting.fit`): Marquardt scaling,
multiplicative damping and a step extension (optionally geodesic acceleration and a bounded
step), each step one exact forward-mode Jacobian (the objective's own,
:func:`fitting._objective.residuals_jacobian`, with one column from the force's
homogeneity; else :func:`fitting._objective.jacobian_fn`). It is not `optimistix.LevenbergMarquardt`
because that one compiled about 4× slower on this objective.

:class:`LBFGS`: `optax.lbfgs` with its zoom line search (strong Wolfe conditions) on the same
objective, the gradient $J^\top r$ from the same forward-mode Jacobian (reverse mode through
the forward models' jump-off refinement gives NaN). Its line search crosses kinks that can
stall the Gauss–Newton model; each iteration costs more.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
import optax.tree_utils as otu

from ._objective import jacobian_fn

__all__ = ["AbstractLeastSquaresSolver", "LevenbergMarquardt", "LBFGS", "RESULTS", "Solution",
           "run_starts", "run_pool"]


class RESULTS:
    r"""Codes of how a solver's run ended, one `int32` per lane (as `optimistix.RESULTS`).

    `successful` (0): converged (the tolerance met); `max_steps_reached` (1): stopped at the
    step limit before converging; `stagnated` (2): no step lowers $\chi^2$ any more without
    meeting the tolerance (Levenberg–Marquardt: the damping grew past $10^{10}$; L-BFGS: a
    line search without decrease); `nonfinite` (3): the residuals at the start are not
    finite (the run did not move); `abandoned` (4): stopped by its driver because its
    $\chi^2$ was still above the problem's bound after :data:`ABANDON_AFTER` steps
    (:meth:`AbstractLeastSquaresSolver.abandon`; a start of a local round that has left the
    neighbourhood of the best end point known).
    """

    successful = 0
    max_steps_reached = 1
    stagnated = 2
    nonfinite = 3
    abandoned = 4
    messages = ("converged", "stopped at the step limit", "stagnated (no step lowers chi2)",
                "non-finite residuals at the start",
                "abandoned (chi2 still above the bound of its problem)")

    @classmethod
    def describe(cls, code) -> str:
        """The message of one code."""
        return cls.messages[int(code)]


class Solution(eqx.Module):
    r"""The end of one run per lane (leading axis: problems or starts).

    **Fields:** `z` (free vectors, `(n, k)`), `chi2` ($\sum r^2$, `(n,)`), `result`
    (:class:`RESULTS` codes, `(n,)`), `steps` (iterations, the first evaluation counted,
    `(n,)`), `r`, `J` (residuals `(n, m)` and their Jacobian w.r.t. `z`, `(n, m, k)`, at
    the end points; `None` unless asked for and the solver carries them), `model` (the
    model at the end points as the fit reports it, :class:`fitting._objective.ModelAt`
    with a leading lane axis, from the search's own evaluation; `None` unless the solver
    carries it: Levenberg–Marquardt with `keep_model`).
    """

    z: jax.Array
    chi2: jax.Array
    result: jax.Array
    steps: jax.Array
    r: jax.Array | None = None
    J: jax.Array | None = None
    model: object = None

    @property
    def converged(self):
        """`result == RESULTS.successful`, per lane."""
        return self.result == RESULTS.successful

    def take(self, index) -> Solution:
        """The lanes `index` (numpy or JAX indexing of the leading axis)."""
        return jax.tree.map(lambda x: x[index], self)

    def concat(self, other: Solution) -> Solution:
        """This solution's lanes followed by `other`'s (host arrays)."""
        return jax.tree.map(lambda a, b: np.concatenate([np.asarray(a), np.asarray(b)]),
                            self, other)


#: Steps (the first evaluation counted, as a state's `steps` counts) after which a run whose
#: $\chi^2$ is still above its bound is abandoned (:meth:`AbstractLeastSquaresSolver.abandon`).
ABANDON_AFTER = 5


def jacobian_of(fn, z, ctx, *, with_model: bool = False):
    """`(r, J, model)` of the objective `fn` at `z` (`model`: `fn.with_model`'s second
    output with `with_model`, else None): by `fn.jacobian(z, ctx, with_model)` where the
    objective brings its own (:func:`fitting._objective.residuals_jacobian`: fewer
    directions through the model), else by :func:`~fitting._objective.jacobian_fn`."""
    own = getattr(fn, "jacobian", None)
    if own is not None:
        return own(z, ctx, with_model)
    if with_model:
        return jacobian_fn(lambda zz: fn.with_model(zz, ctx), has_aux=True)(z)
    return (*jacobian_fn(lambda zz: fn(zz, ctx))(z), None)


class AbstractLeastSquaresSolver(eqx.Module):
    """A solver as `init(fn, z0, ctx) -> state`, `step(fn, state, ctx) -> state`,
    `terminate(state) -> (done, converged)` and `chi2(state)` ($\\sum r^2$)."""

    @abc.abstractmethod
    def init(self, fn: Callable, z0, ctx):
        ...

    @abc.abstractmethod
    def step(self, fn: Callable, state, ctx):
        ...

    @abc.abstractmethod
    def chi2(self, state):
        ...

    @abc.abstractmethod
    def last_jacobian(self, state):
        """`(r, J)` at the state's `z` if the state carries them (`J` w.r.t. `z`), else None."""

    def last_model(self, state):
        """What the fit reports of the model at the state's `z` (`fn.with_model`'s second
        output) if the state carries it, else None."""
        return None

    def with_model(self):
        """This solver carrying the model at its state's `z` (:meth:`last_model`), or None
        where it cannot."""
        return None

    def terminate(self, state):
        """`(done, converged)` of a state (every state carries both flags)."""
        return state.done, state.ok

    def abandon(self, state, bound):
        r"""`state` stopped (done, :attr:`RESULTS.abandoned`) where it is still running
        after at least :data:`ABANDON_AFTER` steps and its $\chi^2$ is above `bound` (one
        lane, under `vmap`; `bound` = $\infty$: never). The state's point, $\chi^2$ and
        carried residuals stay those of its last accepted step."""
        stop = ~state.done & (state.steps >= ABANDON_AFTER) & (self.chi2(state) > bound)
        return eqx.tree_at(lambda s: (s.done, s.result), state,
                           (state.done | stop,
                            jnp.where(stop, RESULTS.abandoned, state.result).astype(
                                state.result.dtype)))

    def hold(self, old, new):
        """The state of a lane after a step from `old` to `new`: `new`, or `old` where `old`
        had stopped (a loop that steps every lane until all have stopped; one lane's
        state, under `vmap`)."""
        return jax.tree.map(lambda a, b: jnp.where(old.done, a, b), old, new)


# ---- Levenberg–Marquardt ------------------------------------------------------------------


class _LMState(eqx.Module):
    """The state of :class:`LevenbergMarquardt`. The residuals, Jacobian and model at `z`
    are those of the last trial point where the last step was accepted (`took`: `z` moved
    there), else those kept before it (:meth:`LevenbergMarquardt._at_z`): a step carries
    its trial point's values as they are and chooses at the start of the next step, so
    that the choice reads stored arrays (chosen at the end of the step, XLA computed the
    model's Jacobian into the choice, a second time beside the residuals: ~1/4 of a step
    of the relaxed model, ``benchmarks/results/fit_each.md``)."""

    z: jax.Array
    r: jax.Array
    J: jax.Array
    chi2: jax.Array
    lam: jax.Array
    mu: jax.Array
    steps: jax.Array
    limit: jax.Array
    done: jax.Array
    ok: jax.Array
    result: jax.Array
    model: object = None
    took: jax.Array | None = None
    r_trial: jax.Array | None = None
    J_trial: jax.Array | None = None
    model_trial: object = None


class LevenbergMarquardt(AbstractLeastSquaresSolver):
    r"""Levenberg–Marquardt with step extension.

    Trial step $\delta = -\mu\,(J^\top J + \lambda\,\mathrm{diag}(J^\top J))^{-1}J^\top r$.
    $\lambda$ shrinks ×0.2 on an accepted step and grows ×10 on a rejected one. $\mu$
    (normally 1) doubles, up to $10^3$, after an accepted step whose actual decrease of
    $\chi^2$ exceeds 1.25× the Gauss–Newton prediction (where the objective is almost
    linear along the step while $J^\top J$ predicts curvature, plain LM crawls with equal,
    collinear steps); it falls back to 1 when the gain ratio drops below 0.75 or a step is
    rejected (then without raising $\lambda$).

    With `geodesic` (off by default: see below) the step carries the geodesic acceleration
    of Transtrum & Sethna (arXiv:1201.5885): $\delta = v + a/2$ with the velocity $v$ (the
    step above, at $\mu = 1$) and $a = -(J^\top J + \lambda D)^{-1}J^\top r''_v$, the second
    directional derivative of the residuals along $v$ by a finite difference (one residual
    evaluation more per step); it is kept where $2\|D^{1/2}a\| \le 0.75\|D^{1/2}v\|$. Why:
    where two moduli of a Prony series trade off (an arm whose relaxation time lies far
    beyond the curve acts as a spring beside $G_\infty$; two arms at nearly one relaxation
    time), the data fix their sum, a narrow valley that is curved in the logarithmic
    coordinates of the fit, and plain Levenberg–Marquardt crawls along it at
    $10^{-6}$–$10^{-5}$ of $\chi^2$ per step to the step limit (measured on real curves:
    `benchmarks/results/prony_convergence.md`). `max_step` bounds every component of a step
    (the free coordinates are logarithms or logistic arguments: a larger step at once pushes
    a bounded parameter deep into its logistic, where its derivative is 0 in floating point
    and it can never return). Neither is the default of :func:`fitting.fit`, measured on
    full searches of real curves (same file): the geodesic acceleration cut the steps by
    6–13 % only; the bounded step (4) cost steps (up to +69 %) and left more runs at the
    step limit than the bound that removes the valley at its cause (a Prony series'
    relaxation times bounded by the curve's duration, :func:`fitting._start.default_bounds`):
    the runs whose steps saturate stop early and cost little; the search keeps the best.

    **Fields:** `rtol` (converged when an accepted step changes $z$ by less than
    `atol + rtol·max|z|` or $\chi^2$ by less than `rtol·χ²`), `atol`, `max_steps`
    (stops unconverged after that many steps: :attr:`RESULTS.max_steps_reached`; or when
    $\lambda > 10^{10}$: :attr:`RESULTS.stagnated`; at once when the start's residuals are
    not finite: :attr:`RESULTS.nonfinite`), `geodesic`, `max_step` (largest change of a free
    coordinate in one step). The state's `steps` counts the first evaluation at the start as
    a step; its `limit` (default `max_steps`) may be set per lane by a driver. With
    `keep_model` the state also carries what `fn.with_model(z, ctx)` returns beside the
    residuals at its `z` (the model as a fit reports it, from the evaluation that gave the
    residuals: no evaluation of the model after the search); `fn.model_struct(z, ctx)`
    states its shapes.
    """

    rtol: float = eqx.field(static=True, default=1e-8)
    atol: float = eqx.field(static=True, default=1e-9)
    max_steps: int = eqx.field(static=True, default=200)
    geodesic: bool = eqx.field(static=True, default=False)
    max_step: float = eqx.field(static=True, default=float("inf"))
    keep_model: bool = eqx.field(static=True, default=False)

    def init(self, fn, z0, ctx):
        # no evaluation here: the state starts at chi2 = inf with J = 0, so the first step
        # is delta = 0 and evaluates r and J at z0 (one copy of the Jacobian in the
        # compiled loop instead of two: the model's Jacobian dominates compile time)
        r0 = residual_struct(fn, z0, ctx)
        r = jnp.zeros(r0.shape, r0.dtype)
        J = jnp.zeros(r0.shape + z0.shape, r0.dtype)
        one = jnp.asarray(1.0, r0.dtype)
        limit = jnp.asarray(self.max_steps)
        model = None
        if self.keep_model:
            model = jax.tree.map(lambda x: jnp.full(x.shape, jnp.nan, x.dtype),
                                 fn.model_struct(z0, ctx))
        return _LMState(z=z0, r=r, J=J, chi2=jnp.asarray(jnp.inf, r0.dtype),
                        lam=5e-3 * one, mu=one, steps=jnp.asarray(0), limit=limit,
                        done=limit <= 0, ok=jnp.asarray(False),
                        result=jnp.asarray(RESULTS.max_steps_reached, jnp.int32),
                        model=model, took=jnp.asarray(False), r_trial=r, J_trial=J,
                        model_trial=model)

    @staticmethod
    def _at_z(s):
        """`(r, J, model)` at the state's `z` (see :class:`_LMState`)."""
        pick = lambda new, old: jnp.where(s.took, new, old)  # noqa: E731
        model = None if s.model is None else jax.tree.map(pick, s.model_trial, s.model)
        return pick(s.r_trial, s.r), pick(s.J_trial, s.J), model

    def step(self, fn, s, ctx):
        r_z, J_z, model_z = self._at_z(s)
        s = dataclasses.replace(s, r=r_z, J=J_z, model=model_z)
        A = s.J.T @ s.J
        g = s.J.T @ s.r
        diag = jnp.diag(A)
        D = jnp.maximum(diag, 1e-12 * jnp.max(diag) + 1e-300)
        M = A + s.lam * jnp.diag(D)
        v = -jnp.linalg.solve(M, g)
        v = jnp.where(jnp.isfinite(v), v, 0.0)
        delta = s.mu * v
        if self.geodesic:
            # geodesic acceleration (Transtrum & Sethna 2012): the second directional
            # derivative of r along v (finite difference) bends the step along a curved
            # valley; kept when small against v (scaled norms), else the plain step
            h = 0.1
            r_h = fn(s.z + h * v, ctx)
            rpp = (2.0 / h) * ((r_h - s.r) / h - s.J @ v)
            acc = -jnp.linalg.solve(M, s.J.T @ rpp)
            sq = jnp.sqrt(D)
            use = (jnp.all(jnp.isfinite(acc)) & (s.mu <= 1.0) & jnp.isfinite(s.chi2)
                   & (2.0 * jnp.linalg.norm(sq * acc) <= 0.75 * jnp.linalg.norm(sq * v)))
            delta = jnp.where(use, v + 0.5 * jnp.where(jnp.isfinite(acc), acc, 0.0), delta)
        # no component of the free vector moves by more than `max_step` in one step
        delta = delta * jnp.minimum(1.0, self.max_step / jnp.maximum(jnp.max(jnp.abs(delta)),
                                                                     1e-300))
        r_new, J_new, model_new = jacobian_of(fn, s.z + delta, ctx,
                                                   with_model=self.keep_model)
        chi2_new = jnp.sum(r_new * r_new)
        ok = jnp.isfinite(chi2_new) & (chi2_new <= s.chi2)
        predicted = -(2.0 * g @ delta + delta @ A @ delta)
        gain = (s.chi2 - chi2_new) / jnp.maximum(predicted, 1e-300)
        small = (jnp.max(jnp.abs(delta)) < self.atol + self.rtol * jnp.max(jnp.abs(s.z))) | (
            (s.chi2 - chi2_new) <= self.rtol * s.chi2)
        converged = ok & small & jnp.isfinite(s.chi2)
        lam = jnp.where(ok, jnp.maximum(s.lam * 0.2, 1e-12),
                        jnp.where(s.mu > 1.0, s.lam, s.lam * 10.0))
        mu = jnp.where(ok & (gain > 1.25), jnp.minimum(2.0 * s.mu, 1e3),
                       jnp.where(ok & (gain > 0.75), s.mu, 1.0))
        mu = jnp.where(jnp.isfinite(s.chi2), mu, s.mu)  # the evaluation step changes nothing
        steps = s.steps + 1
        # the start itself not finite: delta stays 0, no later step can move
        nonfinite = ~jnp.isfinite(s.chi2) & ~jnp.isfinite(chi2_new)
        stagnated = lam > 1e10
        limited = steps > s.limit
        result = jnp.select([converged, nonfinite, stagnated, limited],
                            [RESULTS.successful, RESULTS.nonfinite, RESULTS.stagnated,
                             RESULTS.max_steps_reached], s.result).astype(jnp.int32)
        return _LMState(
            z=jnp.where(ok, s.z + delta, s.z),
            r=s.r, J=s.J,
            chi2=jnp.where(ok, chi2_new, s.chi2),
            lam=lam, mu=mu, steps=steps, limit=s.limit,
            done=converged | nonfinite | stagnated | limited,
            ok=converged, result=result, model=s.model,
            took=ok, r_trial=r_new, J_trial=J_new, model_trial=model_new,
        )

    def chi2(self, state):
        return state.chi2

    def last_jacobian(self, state):
        r, J, _ = self._at_z(state)
        return r, J

    def last_model(self, state):
        return self._at_z(state)[2]

    def with_model(self):
        return dataclasses.replace(self, keep_model=True)

    def hold(self, old, new):
        # a stopped lane keeps everything but its trial point, which is never read again
        # (`took` False): no choice between the trial point's Jacobian and an old one, into
        # which XLA would compute the Jacobian a second time; the residuals, Jacobian and
        # model of `new` are those at `old.z` already (chosen from stored arrays)
        # (the choice between two equal arrays is no choice: XLA drops it)
        kept = dataclasses.replace(
            old, r=new.r, J=new.J, model=new.model, took=jnp.zeros_like(old.took),
            r_trial=new.r_trial, J_trial=new.J_trial, model_trial=new.model_trial)
        return jax.tree.map(lambda a, b: jnp.where(old.done, a, b), kept, new)


# ---- optax L-BFGS -------------------------------------------------------------------------


def _half_ssq(fn, z, ctx):
    r = fn(z, ctx)
    return 0.5 * jnp.sum(r * r)


def _half_ssq_fwd(fn, z, ctx):
    r, J, _ = jacobian_of(fn, z, ctx)
    return 0.5 * jnp.sum(r * r), (J.T @ r, ctx)


def _zero_cotangent(x):
    x = jnp.asarray(x)
    if jnp.issubdtype(x.dtype, jnp.inexact):
        return jnp.zeros_like(x)
    return np.zeros(x.shape, dtype=jax.dtypes.float0)


def _half_ssq_bwd(fn, res, ct):
    g, ctx = res
    return ct * g, jax.tree.map(_zero_cotangent, ctx)


# ½ Σ r²; its gradient J^T r comes from the forward-mode Jacobian
_half_ssq = jax.custom_vjp(_half_ssq, nondiff_argnums=(0,))
_half_ssq.defvjp(_half_ssq_fwd, _half_ssq_bwd)


class _LBFGSState(eqx.Module):
    z: jax.Array
    opt_state: tuple
    value: jax.Array
    grad: jax.Array
    steps: jax.Array
    evaluations: jax.Array
    limit: jax.Array
    done: jax.Array
    ok: jax.Array
    result: jax.Array


class LBFGS(AbstractLeastSquaresSolver):
    """optax L-BFGS with the zoom line search on $\\tfrac12\\sum r^2$.

    Converged when an iteration changes the loss by less than `rtol` relative (either way:
    at the optimum round-off decides the sign) or the largest gradient component falls
    below `gtol` times the loss; a line search without decrease ends the run unconverged.
    **Fields:** `rtol`, `gtol`, `max_steps`, `memory` (L-BFGS pairs), `linesearch_steps`.
    """

    rtol: float = eqx.field(static=True, default=1e-8)
    gtol: float = eqx.field(static=True, default=1e-8)
    max_steps: int = eqx.field(static=True, default=200)
    memory: int = eqx.field(static=True, default=10)
    linesearch_steps: int = eqx.field(static=True, default=20)

    def _opt(self):
        return optax.lbfgs(memory_size=self.memory, linesearch=optax.scale_by_zoom_linesearch(
            max_linesearch_steps=self.linesearch_steps, initial_guess_strategy="one"))

    def init(self, fn, z0, ctx):
        v0, g0 = jax.value_and_grad(lambda z, c: _half_ssq(fn, z, c))(z0, ctx)
        limit = jnp.asarray(self.max_steps)
        nonfinite = ~jnp.isfinite(v0)
        return _LBFGSState(z=z0, opt_state=self._opt().init(z0), value=v0, grad=g0,
                           steps=jnp.asarray(0), evaluations=jnp.asarray(1), limit=limit,
                           done=(limit <= 0) | nonfinite, ok=jnp.asarray(False),
                           result=jnp.where(nonfinite, RESULTS.nonfinite,
                                            RESULTS.max_steps_reached).astype(jnp.int32))

    def step(self, fn, s, ctx):
        # value and gradient at s.z are carried in the state (not re-evaluated: optax's
        # `value_and_grad_from_state` would do so in a `lax.cond`, i.e. always under vmap)
        def value_fn(z, ctx):
            return _half_ssq(fn, z, ctx)

        updates, opt_state = self._opt().update(s.grad, s.opt_state, s.z, value=s.value,
                                                grad=s.grad, value_fn=value_fn, ctx=ctx)
        z_new = optax.apply_updates(s.z, updates)
        v_new = otu.tree_get(opt_state, "value")
        g_new = otu.tree_get(opt_state, "grad")
        n_eval = otu.tree_get(opt_state, "info").num_linesearch_steps
        better = jnp.isfinite(v_new) & (v_new <= s.value)
        scale = jnp.maximum(jnp.abs(v_new), 1e-300)
        flat = jnp.isfinite(v_new) & (jnp.abs(s.value - v_new) <= self.rtol * scale)
        grad_small = better & (jnp.max(jnp.abs(g_new)) <= self.gtol * scale)
        converged = flat | grad_small
        steps = s.steps + 1
        limited = steps >= s.limit
        result = jnp.select([converged, ~better, limited],
                            [RESULTS.successful, RESULTS.stagnated, RESULTS.max_steps_reached],
                            s.result).astype(jnp.int32)
        return _LBFGSState(
            z=jnp.where(better, z_new, s.z), opt_state=opt_state,
            value=jnp.where(better, v_new, s.value),
            grad=jnp.where(better, g_new, s.grad), steps=steps,
            evaluations=s.evaluations + n_eval, limit=s.limit,
            done=converged | ~better | limited, ok=converged, result=result,
        )

    def chi2(self, state):
        return 2.0 * state.value

    def last_jacobian(self, state):
        return None


# ---- drivers ------------------------------------------------------------------------------


def residual_struct(fn, z0, ctx) -> jax.ShapeDtypeStruct:
    """The shape and dtype of the residuals `fn(z0, ctx)`: from ``fn.residual_struct(z0,
    ctx)`` where `fn` states them, else by `jax.eval_shape` (which traces `fn`: for the
    full-history model a trace as long as the compiled loop's own; measured in
    `benchmarks/results/fit_each.md`, "A cold fit")."""
    known = getattr(fn, "residual_struct", None)
    return known(z0, ctx) if known is not None else jax.eval_shape(fn, z0, ctx)


def _solution(solver, s, keep_jacobian: bool) -> Solution:
    rj = solver.last_jacobian(s) if keep_jacobian else None
    r, J = rj if rj is not None else (None, None)
    return Solution(z=s.z, chi2=solver.chi2(s), result=s.result, steps=s.steps, r=r, J=J,
                    model=solver.last_model(s))


def run_starts(solver: AbstractLeastSquaresSolver, fn, z0s, ctx, *,
               keep_jacobian: bool = False) -> Solution:
    """The :class:`Solution` of every start (rows of `z0s`), one vmapped loop, shared
    `ctx`."""

    states = jax.vmap(lambda z: solver.init(fn, z, ctx))(z0s)
    return jax.vmap(lambda s: _solution(solver, s, keep_jacobian))(
        _every_lane(solver, fn, states, lambda s: ctx, in_axes=None))


def _every_lane(solver, fn, states, ctx_of, *, in_axes, bounds=None):
    r"""Step every lane (leading axis of `states`) until all have stopped, each stopped
    lane held (:meth:`AbstractLeastSquaresSolver.hold`; a `while_loop` under `vmap` would
    choose every leaf of every lane's state, the trial point's Jacobian included, after
    each step). `ctx_of(states)`: the contexts, batched as `in_axes` says; `bounds`: each
    lane's bound on $\chi^2$ (:meth:`AbstractLeastSquaresSolver.abandon`; None: none)."""

    def body(s):
        def one(old, ctx, bound):
            new = solver.step(fn, old, ctx)
            if bound is not None:
                new = solver.abandon(new, bound)
            return solver.hold(old, new)

        return jax.vmap(one, in_axes=(0, in_axes, None if bounds is None else 0))(
            s, ctx_of(s), bounds)

    return jax.lax.while_loop(lambda s: ~jnp.all(s.done), body, states)


def _take(tree, i):
    return jax.tree.map(lambda x: x[i], tree)


def run_pool(solver: AbstractLeastSquaresSolver, fn, z0s, ctxs, workers: int, *,
             limits=None, bounds=None, keep_jacobian: bool = False) -> Solution:
    r"""The :class:`Solution` of `len(z0s)` problems solved on `workers` lanes, with the
    residuals and Jacobian of each final state when `keep_jacobian` and the solver
    carries them.

    `ctxs` has a leading problem axis. `limits`: the step limit of each problem (default:
    the solver's `max_steps`; 0: not run, its result reads `max_steps_reached` with
    $\chi^2 = \infty$ for Levenberg–Marquardt). `bounds`: a bound on each problem's
    $\chi^2$ (default none): a run still above it after :data:`ABANDON_AFTER` steps stops,
    :attr:`RESULTS.abandoned` (:meth:`AbstractLeastSquaresSolver.abandon`; $\infty$:
    never). All initial states are made first (one
    batched call); then one loop iterates all lanes; a lane whose problem is done writes
    its result and is refilled from the queue (the problems not run, limit 0, are written
    from their initial states and take no lane). The loop ends when every problem is
    written.
    """
    n_tasks = z0s.shape[0]
    w = max(1, min(int(workers), n_tasks))
    states0 = jax.vmap(lambda z, c: solver.init(fn, z, c))(z0s, ctxs)
    if limits is not None:
        limits = jnp.broadcast_to(jnp.asarray(limits, states0.limit.dtype), (n_tasks,))
        states0 = eqx.tree_at(lambda s: (s.limit, s.done), states0,
                              (limits, states0.done | (limits <= 0)))
    if bounds is not None:
        bounds = jnp.broadcast_to(jnp.asarray(bounds, solver.chi2(states0).dtype), (n_tasks,))

    def result(s):
        return _solution(solver, s, keep_jacobian)

    if w == n_tasks:  # a lane per problem: no queue, no gather of contexts, one write
        return jax.vmap(result)(_every_lane(solver, fn, states0, lambda s: ctxs, in_axes=0,
                                            bounds=bounds))

    # the queue: the problems to run (not done at the start: limit > 0), in their order;
    # the others are written as they start (their initial states' results)
    runnable = jnp.logical_not(states0.done)
    order = jnp.argsort(jnp.logical_not(runnable), stable=True)
    n_run = jnp.sum(runnable)

    def task(q):  # the problem at queue position q (clamped: a dead lane's stand-in)
        return order[jnp.minimum(q, n_tasks - 1)]

    def collect(work, pos, out, queued, written):
        # the lanes whose problem has finished: written out and refilled from the queue
        # (a lane past its end is dead: it steps a stand-in that is never written). Done
        # at the top of the next iteration (and once after the loop), from the carried
        # state: written from the step's output, XLA fuses the Jacobian's computation into
        # both the scatter and the carry, i.e. computes it twice a step
        finished = (pos < n_run) & work.done
        slot = jnp.where(finished, task(pos), n_tasks)  # out of range: dropped
        out = jax.tree.map(lambda o, x: o.at[slot].set(x, mode="drop"), out,
                           jax.vmap(result)(work))
        new = queued + jnp.cumsum(finished) - 1
        refill = finished & (new < n_run)
        fresh = _take(states0, task(new))
        work = jax.tree.map(
            lambda x, f: jnp.where(refill.reshape((-1,) + (1,) * (x.ndim - 1)), f, x),
            work, fresh)
        pos = jnp.where(finished, new, pos)
        n_fin = jnp.sum(finished)
        return work, pos, out, queued + n_fin, written + n_fin

    def body(c):
        # every lane that is done has just been written and refilled, or is dead, so a
        # step may change it: no choice of each lane's old state (that choice made XLA
        # compute the model's Jacobian a second time, inside it: 1/4 of a step)
        work, pos, out, queued, written = collect(*c)
        ctx = _take(ctxs, task(pos))
        work = jax.vmap(lambda s, x: solver.step(fn, s, x))(work, ctx)
        if bounds is not None:
            work = jax.vmap(solver.abandon)(work, bounds[task(pos)])
        return work, pos, out, queued, written

    def cond(c):  # some problem is neither written nor finished
        work, pos, _, _, written = c
        return written + jnp.sum((pos < n_run) & work.done) < n_tasks

    first = jnp.arange(w)
    init = (_take(states0, task(first)), first, jax.vmap(result)(states0), jnp.asarray(w),
            n_tasks - n_run)
    return collect(*jax.lax.while_loop(cond, body, init))[2]
