r"""Scalar root finding with implicit differentiation.

`bracketed_root` solves $f(x) = 0$ on a bracket $[x_\mathrm{lo}, x_\mathrm{hi}]$ with a
safeguarded Newton iteration: it starts from the regula-falsi point of the bracket, takes the
Newton step where it stays inside the shrinking bracket and bisects otherwise, and stops as
soon as it has converged (see below) or after `steps` iterations. Under `vmap` the loop runs
until every lane has stopped; finished lanes keep their value. Derivatives do not flow
through the iterations: `jax.lax.custom_root` applies the implicit function theorem,
$\partial x/\partial\theta = -(\partial f/\partial x)^{-1}\,\partial f/\partial\theta$, so
gradients are exact for the converged root and cost one extra evaluation of $f$.

**Stopping.** With $\varepsilon$ the machine epsilon of the bracket's dtype, a lane stops when
$f(x) = 0$; when a Newton step is below $4\varepsilon|x|$; when the bracket is narrower than
$4\varepsilon\max(|x_\mathrm{lo}|, |x_\mathrm{hi}|)$; or when Newton has reached the
round-off floor of $f$: a step below $10^{-9}$ of the initial bracket that is not smaller
than 0.9 of the previous Newton step (quadratic convergence has ended; near a double root,
where Newton converges linearly with ratio 1/2, this does not trigger).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jax import lax

__all__ = ["bracketed_root"]


def _solve(fn, lo, hi, steps):
    lo = lax.stop_gradient(lo)
    hi = lax.stop_gradient(hi)
    eps4 = 4.0 * jnp.finfo(jnp.result_type(lo, hi)).eps
    width0 = jnp.abs(hi - lo)
    f_lo = fn(lo)
    f_hi = fn(hi)
    sign_lo = jnp.sign(f_lo)
    mid = 0.5 * (lo + hi)
    # regula falsi start (the midpoint if it is not strictly inside the bracket)
    den = f_hi - f_lo
    x0 = lo - f_lo * (hi - lo) / jnp.where(den == 0, 1.0, den)
    inside0 = (den != 0) & jnp.isfinite(x0)
    inside0 = inside0 & (x0 > jnp.minimum(lo, hi)) & (x0 < jnp.maximum(lo, hi))
    x0 = jnp.where(inside0, x0, mid)
    inf = jnp.full_like(mid, jnp.inf)

    def cond(carry):
        i, _, _, _, _, done = carry
        return (i < steps) & jnp.logical_not(done)

    def body(carry):
        i, lo, hi, x, prev_step, done = carry
        fx, dfx = jax.jvp(fn, (x,), (jnp.ones_like(x),))
        same_as_lo = jnp.sign(fx) == sign_lo
        lo_n = jnp.where(same_as_lo, x, lo)
        hi_n = jnp.where(same_as_lo, hi, x)
        newton = x - fx / jnp.where(dfx == 0, 1.0, dfx)
        inside = (dfx != 0) & jnp.isfinite(newton)
        inside = inside & (newton > jnp.minimum(lo_n, hi_n)) & (newton < jnp.maximum(lo_n, hi_n))
        x_new = jnp.where(inside, newton, 0.5 * (lo_n + hi_n))
        step = jnp.abs(x_new - x)
        zero = fx == 0
        x_new = jnp.where(zero, x, x_new)
        floor = inside & (step <= 1e-9 * width0) & (step >= 0.9 * prev_step)
        stop = (
            zero
            | (inside & (step <= eps4 * jnp.abs(x_new)))
            | (jnp.abs(hi_n - lo_n) <= eps4 * jnp.maximum(jnp.abs(lo_n), jnp.abs(hi_n)))
            | floor
        )
        # a lane that has stopped keeps its state (under vmap the loop runs for all lanes)
        keep = lambda old, new: jnp.where(done, old, new)  # noqa: E731
        return (
            i + 1,
            keep(lo, lo_n),
            keep(hi, hi_n),
            keep(x, x_new),
            keep(prev_step, jnp.where(inside, step, inf)),
            done | stop,
        )

    carry = (jnp.asarray(0), lo, hi, x0, inf, jnp.zeros(jnp.shape(x0), bool))
    return lax.while_loop(cond, body, carry)[3]


def bracketed_root(
    fn: Callable[[jax.Array], jax.Array],
    lo: jax.Array,
    hi: jax.Array,
    *,
    steps: int = 64,
) -> jax.Array:
    r"""Root of the scalar function `fn` inside `[lo, hi]`.

    **Arguments:**

    - `fn`: scalar function of a scalar; it may close over arrays, and derivatives with
      respect to those flow through the root by implicit differentiation.
    - `lo`, `hi`: the bracket; `fn(lo)` and `fn(hi)` must have opposite signs (not checked:
      without a sign change the result is one of the bracket ends).
    - `steps`: largest number of safeguarded Newton/bisection steps (64 resolves any
      float64 bracket to round-off by bisection alone); the loop stops earlier once
      converged (module docstring), typically after 3–6 steps.

    **Returns:** the root, a scalar array.
    """
    lo = jnp.asarray(lo)
    hi = jnp.asarray(hi)

    def solve(f, _guess):
        return _solve(f, lo, hi, steps)

    def tangent_solve(g, y):
        return y / g(jnp.ones_like(y))

    return lax.custom_root(fn, 0.5 * (lo + hi), solve, tangent_solve)
