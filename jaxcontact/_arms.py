r"""Exact updates of the Maxwell-arm (dashpot) variables for piecewise-linear inputs.

A Maxwell arm $k$ with relaxation time $\tau_k$ driven by a displacement $u(t)$ that is linear
over a step of length $\Delta$ has the dashpot displacement
$v \leftarrow v\,e^{-s} + u_0(1 - e^{-s}) + \Delta u\,\psi(s)$, $s = \Delta/\tau_k$
(`attached_update`, `docs/physics.md` §5). The relaxed-start model (`retract`) needs the
same update in the form of an internal variable per arm, $w_k \leftarrow \alpha w_k +
(G_k/G_g)\,\Delta\delta\,\phi(s)$ with $\alpha = e^{-s}$ (`states_samples`, all samples by
one associative scan), or in closed form for a constant-speed lift (`states_velocity`).

- `phi(s)` $= (1 - e^{-s})/s$, `dphi(s)` $= \phi'(s)$, `psi(s)` $= 1 - \phi(s)$ (absolute
  accuracy, for increments), `psi_relative(s)` (the same to relative accuracy).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jax import lax
from jax.custom_derivatives import SymbolicZero

__all__ = [
    "attached_update",
    "decay",
    "dphi",
    "phi",
    "psi",
    "psi_relative",
    "states_samples",
    "states_velocity",
]


def arms_sum(x, w):
    r"""$\sum_k x_{\ldots k} w_k$: a contraction over the arms' (last) axis.

    Shapes: `x` (..., N), `w` (N,) → (...). Written as a product and a sum rather than a
    matrix product: the arms are few (N = 1 for the standard model), and XLA's CPU
    backend lays a small `dot` out by transposes and copies of its operands and their
    tangents, which cost more than the arithmetic in the foundation's time step.
    """
    x = jnp.asarray(x)
    return jnp.sum(x * jnp.asarray(w)[(None,) * (x.ndim - 1)], axis=-1)


def arms_apply(P, x):
    r"""$x P^\top$, i.e. $y_{\ldots i} = \sum_j P_{ij} x_{\ldots j}$, over the arms' axis.

    Shapes: `P` (N, N), `x` (..., N) → (..., N); a product and a sum, as `arms_sum`.
    """
    x = jnp.asarray(x)
    return jnp.sum(x[..., None, :] * jnp.asarray(P)[(None,) * (x.ndim - 1)], axis=-1)


def phi(x):
    r"""$\phi(x) = (1 - e^{-x})/x$ for $x \ge 0$, with the limit $\phi(0) = 1$."""
    safe = jnp.where(x > 0, x, 1.0)
    return jnp.where(x > 0, -jnp.expm1(-safe) / safe, 1.0)


def dphi(x):
    r"""$\phi'(x) = (e^{-x} - \phi(x))/x$ without cancellation (series below $x = 0.01$)."""
    small = x < 0.01
    xs = jnp.where(small, x, 0.0)
    series = -1 / 2 + xs * (1 / 3 + xs * (-1 / 8 + xs * (1 / 30 + xs * (-1 / 144 + xs / 840))))
    xl = jnp.where(small, 1.0, x)
    return jnp.where(small, series, (jnp.exp(-xl) - phi(xl)) / xl)


def psi(s):
    r"""$\psi(s) = 1 - (1 - e^{-s})/s$ for $s \ge 0$, $\psi(0) = 0$.

    Evaluated directly: its absolute error is of the order of the machine epsilon for every
    $s$ (the relative error grows like $\epsilon/s$ for small $s$, but $\psi$ only enters
    as the increment $\Delta u\,\psi$ added to a dashpot displacement, so the absolute error
    is what matters).
    """
    pos = s > 0
    ss = jnp.where(pos, s, 1.0)
    return jnp.where(pos, 1.0 + jnp.expm1(-ss) / ss, 0.0)


def decay(s):
    r"""$(e^{-s},\ \mathrm{expm1}(-s),\ \psi(s))$ for $s \ge 0$: the three factors of an
    exact dashpot update, all from one `expm1` (per spring and step the costly part of the
    full-history model's forward-mode Jacobian: `benchmarks/results/fit_each.md`, "One
    transcendental a spring").

    $\psi$ as `psi` computes it (the same values: `psi` evaluates `expm1` at the same
    argument); $e^{-s}$ as $1 + \mathrm{expm1}(-s)$, whose absolute error stays below an
    ulp of 1, as `psi`'s: what an update $v\,e^{-s} + \dots$ of a displacement needs (its
    relative accuracy is lost below $e^{-s} \approx 10^{-16}$, where the arm has relaxed
    and the term is below the round-off of the others)."""
    m1 = jnp.expm1(-s)
    pos = s > 0
    # psi(s) = 1 + expm1(-s)/s where s > 0: `psi` evaluates expm1 at where(s > 0, s, 1),
    # which is expm1(-s) on those elements
    return 1.0 + m1, m1, jnp.where(pos, 1.0 + m1 / jnp.where(pos, s, 1.0), 0.0)


def psi_relative(s):
    r"""$\psi(s) = 1 - (1 - e^{-s})/s$ for $s \ge 0$ to a relative error of a few $\epsilon$.

    For a sum of positive terms (the sweep's separation work), where `psi`'s relative error
    $\sim 2\epsilon/s$ at small $s$ would matter (2e-5 in float32 at $s = 0.01$): its
    Taylor series $s/2 - s^2/6 + s^3/24 - \dots$ (18 terms: truncation below 1e-17) below
    $s = 1$, `psi` above (relative error below $2\epsilon$ there).
    """
    s = jnp.asarray(s)
    small = s < 1.0
    ss = jnp.where(small, s, 0.0)
    # sum_{n>=1} (-1)^(n+1) s^n / (n+1)!, Horner from the 18th term
    series = jnp.zeros_like(ss)
    for n in range(18, 0, -1):
        series = ss * ((-1.0) ** (n + 1) / math.factorial(n + 1) + series)
    return jnp.where(small, series, psi(jnp.where(small, 1.0, s)))


def attached_update(v, u0, du, dt, tau):
    r"""Exact update of attached dashpots over `dt` with $u$ linear from `u0` by `du`.

    `v`: (..., N); `u0`, `du`, `dt`: (...) or scalars; `tau`: (N,); returns (..., N).
    """
    rank = max(jnp.ndim(v), jnp.ndim(dt) + 1, jnp.ndim(u0) + 1, jnp.ndim(du) + 1)

    def column(z):  # (...) -> (1, ..., 1, ..., 1) of rank `rank`, a trailing arm axis
        z = jnp.asarray(z)[..., None]
        return jnp.reshape(z, (1,) * (rank - z.ndim) + z.shape)

    s = column(dt) / jnp.reshape(tau, (1,) * (rank - 1) + tau.shape)
    e, m1, ps = decay(s)
    v = jnp.reshape(v, (1,) * (rank - jnp.ndim(v)) + jnp.shape(v))
    return v * e - column(u0) * m1 + column(du) * ps


def states_velocity(ts, velocity, arm_ratio, tau):
    r"""Arm variables of a constant-speed lift from rest, shape `(n, N)`:
    $w_k(t) = -(G_k/G_g)\,\tau_k v\,(1 - e^{-t/\tau_k})$.

    Written without a per-sample division, so that XLA fuses it with the front root into one
    pass.
    """
    t, arm_ratio, tau = ts[:, None], arm_ratio[None, :], tau[None, :]
    return (arm_ratio * velocity * tau) * jnp.expm1(t * (-1.0 / tau))


def _combine(left, right):
    a1, b1 = left
    a2, b2 = right
    return a1 * a2, a2 * b1 + b2


def _recurrence(alpha, beta):
    """$w_i = \\alpha_i w_{i-1} + \\beta_i$, $w_{-1} = 0$, along axis 0; `beta` may carry
    extra trailing axes (several right-hand sides share the products of the alphas)."""
    extra = beta.ndim - alpha.ndim
    a = alpha.reshape(alpha.shape + (1,) * extra)
    return lax.associative_scan(_combine, (a, beta), axis=0)[1]


def _increments(dt, tau):
    x = dt / tau
    return x, jnp.exp(-x), phi(x)


@jax.custom_jvp
def _states_increments(dt, ddelta, arm_ratio, tau):
    # w = L(alpha) (arm_ratio ddelta phi(x)), x = dt/tau; shapes (n, 1), (n, 1), (1, N), (1, N)
    _, alpha, ph = _increments(dt, tau)
    return _recurrence(alpha, arm_ratio * ddelta * ph)


def _states_increments_jvp(primals, tangents):
    r"""Tangents of the arm states through two fixed sensitivities.

    With $u = L(\alpha)(\Delta\delta\,\phi(x))$ the states are $w = (G_k/G_g)\,u$, and
    $v = \partial w/\partial\tau = L(\alpha)\,q$ with
    $q = x\,[\alpha\,w_{i-1} - (G_k/G_g)\Delta\delta\,\phi'(x)]/\tau$. Both come
    from one scan that shares the products of the $\alpha$s, so any number of tangent
    directions (the Jacobian's columns) costs two element-wise products,
    $\dot w = u\,\dot r + v\,\dot\tau$, and under `jax.linearize` no scan is left in the
    linear map. Tangents of the sampling (`dt`, `ddelta`: a differentiated displacement
    history) need their own scan and only run when present.
    """
    dt, ddelta, arm_ratio, tau = primals
    t_dt, t_ddelta, t_ratio, t_tau = tangents
    x, alpha, ph = _increments(dt, tau)
    u = _recurrence(alpha, ddelta * ph)
    w = arm_ratio * u
    w_prev = jnp.concatenate([jnp.zeros_like(w[:1]), w[:-1]])
    dph = dphi(x)
    q = x * (alpha * w_prev - arm_ratio * ddelta * dph) / tau
    v = _recurrence(alpha, q)
    zero = lambda t: isinstance(t, SymbolicZero)  # noqa: E731 - JAX's marker of a zero tangent
    dw = jnp.zeros_like(w)
    if not zero(t_ratio):
        dw = dw + u * t_ratio
    if not zero(t_tau):
        dw = dw + v * t_tau
    if not (zero(t_dt) and zero(t_ddelta)):
        # dw = L(alpha) (dbeta + dalpha w_prev) for the sampling's own tangents
        forcing = jnp.zeros_like(w)
        if not zero(t_ddelta):
            forcing = forcing + arm_ratio * t_ddelta * ph
        if not zero(t_dt):
            forcing = forcing + (arm_ratio * ddelta * dph - alpha * w_prev) * (t_dt / tau)
        dw = dw + _recurrence(alpha, forcing)
    return w, dw


_states_increments.defjvp(_states_increments_jvp, symbolic_zeros=True)


def states_samples(ts, delta, arm_ratio, tau):
    r"""Arm variables at the samples of a piecewise-linear history $\delta(t_i)$, shape
    `(n, N)`: the exact update over each interval, the first sample responding as a step
    from rest. One associative scan; a custom JVP through two fixed sensitivities."""
    dt = jnp.diff(ts, prepend=ts[:1])[:, None]
    ddelta = jnp.diff(delta, prepend=0.0)[:, None]
    # all four of rank 2: (n, 1), (n, 1), (1, N), (1, N)
    return _states_increments(dt, ddelta, arm_ratio[None, :], tau[None, :])
