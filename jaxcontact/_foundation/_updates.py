"""Update rules of the springs over one sample interval, and the front root."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax


def _psi(s):
    r"""$\psi(s) = 1 - (1 - e^{-s})/s$ for $s \ge 0$, $\psi(0) = 0$.

    Evaluated directly: its absolute error is of the order of the machine epsilon for every
    $s$ (the relative error grows like $\epsilon/s$ for small $s$, but $\psi$ only enters
    as the increment $\Delta u\,\psi$ added to a dashpot displacement, so the absolute error
    is what matters).
    """
    pos = s > 0
    ss = jnp.where(pos, s, 1.0)
    return jnp.where(pos, 1.0 + jnp.expm1(-ss) / ss, 0.0)


def _attached_update(v, u0, du, dt, tau):
    r"""Exact update of attached dashpots over `dt` with $u$ linear from `u0` by `du`.

    `v`: (..., N); `u0`, `du`, `dt`: (...) or scalars; returns (..., N).
    """
    rank = max(jnp.ndim(v), jnp.ndim(dt) + 1, jnp.ndim(u0) + 1, jnp.ndim(du) + 1)

    def column(z):  # (...) -> (1, ..., 1, ..., 1) of rank `rank`, a trailing arm axis
        z = jnp.asarray(z)[..., None]
        return jnp.reshape(z, (1,) * (rank - z.ndim) + z.shape)

    s = column(dt) / jnp.reshape(tau, (1,) * (rank - 1) + tau.shape)
    e = jnp.exp(-s)
    v = jnp.reshape(v, (1,) * (rank - jnp.ndim(v)) + jnp.shape(v))
    return v * e - column(u0) * jnp.expm1(-s) + column(du) * _psi(s)


def _concave_root(fn, lo, hi, steps):
    r"""Root of `fn` in [lo, hi] with fn(lo) >= 0 > fn(hi), fn concave there.

    Newton's method started at `hi` converges monotonically from the right for a concave
    function (each tangent lies above the graph); a bisection guard keeps the iterate inside
    the shrinking bracket. Differentiated implicitly (`lax.custom_root`).
    """
    lo = lax.stop_gradient(lo)
    hi = lax.stop_gradient(hi)

    def solve(f, _guess):
        def body(_, carry):
            a, b, x = carry
            fx, dfx = jax.jvp(f, (x,), (jnp.ones_like(x),))
            a = jnp.where(fx >= 0, x, a)
            b = jnp.where(fx >= 0, b, x)
            newton = x - fx / jnp.where(dfx == 0, 1.0, dfx)
            good = (dfx != 0) & jnp.isfinite(newton) & (newton >= a) & (newton <= b)
            x_new = jnp.where(good, newton, 0.5 * (a + b))
            return a, b, jnp.where(fx == 0, x, x_new)

        return lax.fori_loop(0, steps, body, (lo, hi, hi))[2]

    def tangent_solve(g, y):
        slope = g(jnp.ones_like(y))
        return y / jnp.where(slope == 0, 1.0, slope)

    return lax.custom_root(fn, hi, solve, tangent_solve)
