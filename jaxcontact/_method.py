r"""Time integration of the viscoelastic internal variables: the `method=` option of
`retract` and `simulate`.

A method advances the Maxwell-arm variables of the MDR springs over the samples of a
piecewise-linear input. `ExactUpdate()` uses the closed-form exponential updates
(`_arms.py`); `DiffraxODE(...)` integrates the same ODEs with diffrax (the same model to the
solver's tolerance). Each method implements the two operations the models need, so the
models never ask for its type:

- `arm_states`: the arm variables $w_k(t_i)$ of the relaxed-start model (`retract`),
  $\dot w_k = (G_k/G_g)\,\dot\delta - w_k/\tau_k$, $w_k(0) = 0$;
- `propagate`: the dashpots $v_k$ of the foundation springs over one sample interval, both
  as attached springs ($u = d(t) - g(x)$) and as load-free ones ($\dot v = A v$)
  (`simulate`, `docs/physics.md` §5).
"""

from __future__ import annotations

import abc

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp

from ._arms import arms_apply, attached_update, states_samples, states_velocity
from ._solvers import safe_div

__all__ = ["AbstractMethod", "DiffraxODE", "ExactUpdate"]


class AbstractMethod(eqx.Module):
    """How the internal viscoelastic variables are integrated in time."""

    @abc.abstractmethod
    def arm_states(self, ts, velocity, delta, arm_ratio, tau):
        r"""Arm variables $w_k(t_i)$ [m] of the relaxed-start model, shape `(n, N)`.

        **Arguments:** `ts` `(n,)` [s]; either `velocity` $v$ [m/s] (a constant-speed lift
        from $t = 0$, $\delta = -vt$; `delta` is then ignored) or `velocity=None` and
        `delta` `(n,)` [m] (the sampled history, linear in between, a step at `ts[0]`);
        `arm_ratio` $G_k/G_g$ and `tau` $\tau_k$ [s], shape `(N,)`.

        **Returns:** `(w, ok, steps)`: the states, whether the integration succeeded, and the
        number of integrator steps taken (0 for closed forms).
        """

    @abc.abstractmethod
    def propagate(self, V, g_points, t0, t1, d0, d1, P, tau, A):
        r"""Dashpots of the foundation springs from `t0` to `t1` [s], $d$ linear from `d0`
        to `d1` [m].

        **Arguments:** `V` `(p, N)` dashpot displacements [m] at `t0` of springs at points
        where the profile is `g_points` `(p,)` [m], or a tuple of such blocks with
        `g_points` a tuple alike (the foundation's nodes and its edge: no concatenation of
        the nodes' array a step); `P` the free-relaxation propagator $e^{A(t_1 - t_0)}$
        `(N, N)`; `tau` `(N,)` [s]; `A` `(N, N)` [1/s].

        **Returns:** `(V_attached, V_free, ok)`: the dashpots at `t1` (blocks as `V`) if the
        springs stay attached all along, if they stay load-free all along, and whether the
        integration succeeded.
        """


class ExactUpdate(AbstractMethod):
    r"""Exact solution for piecewise-linear displacement histories (default, fastest).

    For a constant-speed lift the closed form $w_k = -(G_k/G_g)\tau_k v(1 - e^{-t/\tau_k})$ is
    used; for sampled histories the exact exponential update
    $w_k \leftarrow w_k e^{-\Delta/\tau_k} + (G_k/G_g)\,\Delta\delta\,
    (1 - e^{-\Delta/\tau_k})\tau_k/\Delta$ over each interval, combined by a parallel
    associative scan. In the foundation: the attached update of `_arms.attached_update` and
    the matrix exponential of the free springs.
    """

    def arm_states(self, ts, velocity, delta, arm_ratio, tau):
        if velocity is not None:
            w = states_velocity(ts, velocity, arm_ratio, tau)
        else:
            w = states_samples(ts, delta, arm_ratio, tau)
        return w, jnp.asarray(True), jnp.asarray(0)

    def propagate(self, V, g_points, t0, t1, d0, d1, P, tau, A):
        V_att = jax.tree.map(lambda v, g: attached_update(v, d0 - g, d1 - d0, t1 - t0, tau),
                             V, g_points)
        return V_att, jax.tree.map(lambda v: arms_apply(P, v), V), jnp.asarray(True)


class DiffraxODE(AbstractMethod):
    r"""Integrate the internal variables with diffrax.

    In `retract` the arm ODE $\dot w_k = (G_k/G_g)\dot\delta - w_k/\tau_k$ over the whole
    history (one solve, saved at the samples); in `simulate` the dashpot ODEs of all springs
    over every sample interval.

    **Arguments:**

    - `solver`: a diffrax solver (default `diffrax.Tsit5()`, whose dense output keeps the
      saved values at the step accuracy; for relaxation times far shorter than the sampling
      interval choose an L-stable one such as `diffrax.Kvaerno5()`).
    - `rtol`, `atol`: tolerances of the PID step-size controller (`atol` in metres).
    - `max_steps`: step budget; exceeding it gives `RESULTS.solver_failed`.
    - `adjoint`: how derivatives flow through the solve. The default
      `diffrax.RecursiveCheckpointAdjoint()` supports reverse mode (`jax.grad`,
      `jax.jacrev`) only; pass `diffrax.ForwardMode()` for forward mode (`jax.jvp`,
      `jax.jacfwd`, the Jacobians of a Levenberg–Marquardt fit).
    """

    solver: diffrax.AbstractSolver = diffrax.Tsit5()
    rtol: float = 1e-10
    atol: float = 1e-18
    max_steps: int = 16384
    adjoint: diffrax.AbstractAdjoint = diffrax.RecursiveCheckpointAdjoint()

    def arm_states(self, ts, velocity, delta, arm_ratio, tau):
        if velocity is not None:
            t0 = jnp.zeros_like(ts[0])
            y0 = jnp.zeros_like(tau)

            def rate(t):
                return -velocity

            jump_ts = None
        else:
            t0 = ts[0]
            y0 = arm_ratio * delta[0]
            path = diffrax.LinearInterpolation(ts=ts, ys=delta)

            def rate(t):
                return path.derivative(t)

            jump_ts = ts

        def vector_field(t, w, args):
            return arm_ratio * rate(t) - w / tau

        controller = diffrax.PIDController(rtol=self.rtol, atol=self.atol)
        if jump_ts is not None:
            controller = diffrax.ClipStepSizeController(controller, jump_ts=jump_ts)
        span = ts[-1] - t0
        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(vector_field),
            self.solver,
            t0=t0,
            t1=ts[-1],
            dt0=jnp.maximum(span, jnp.finfo(span.dtype).tiny) * 1e-4,
            y0=y0,
            saveat=diffrax.SaveAt(ts=ts),
            stepsize_controller=controller,
            max_steps=self.max_steps,
            adjoint=self.adjoint,
            throw=False,
        )
        ok = sol.result == diffrax.RESULTS.successful
        return sol.ys, ok, sol.stats["num_steps"]

    def propagate(self, V, g_points, t0, t1, d0, d1, P, tau, A):
        dt = t1 - t0
        rate = safe_div(d1 - d0, dt)
        has_span = dt > 0

        def field(t, y, args):
            va, vf = y
            d = d0 + rate * (t - t0)
            attached = jax.tree.map(lambda v, g: ((d - g)[:, None] - v) / tau[None, :], va,
                                    g_points)
            return attached, jax.tree.map(lambda v: arms_apply(A, v), vf)

        # a zero-length step (instantaneous jump of d) leaves the dashpots unchanged
        t1_safe = jnp.where(has_span, t1, t0 + 1.0)
        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(field),
            self.solver,
            t0=t0,
            t1=t1_safe,
            dt0=None,
            y0=(V, V),
            saveat=diffrax.SaveAt(t1=True),
            stepsize_controller=diffrax.PIDController(rtol=self.rtol, atol=self.atol),
            max_steps=self.max_steps,
            adjoint=self.adjoint,
            throw=False,
        )
        va, vf = sol.ys
        va = jax.tree.map(lambda y, v: jnp.where(has_span, y[0], v), va, V)
        vf = jax.tree.map(lambda y, v: jnp.where(has_span, y[0], v), vf, V)
        ok = (sol.result == diffrax.RESULTS.successful) | jnp.logical_not(has_span)
        return va, vf, ok
