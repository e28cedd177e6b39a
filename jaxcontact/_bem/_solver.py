"""The BEM's solvers: Polonsky-Keer constrained conjugate gradients (displacement and
force control), the equilibrium at a fixed attached set, the cell rule of one load step,
and the single non-adhesive elastic solve `bem_contact` (`jaxcontact._bem`)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .. import _sharding
from .._foundation._loading import SpringEquation
from .._root import newton_iterate
from .._solvers import as_float, float64_scope, floats_to_arrays, safe_div
from .._validate import (
    check_finite,
    check_positive,
    error_if,
)
from ._kernel import BEMGrid, _convolve, _kernel_hat, love_displacement
from ._surfaces import _heights

__all__ = ["bem_contact"]

def _pk_solve(khat, target, bonded, q0, k00, tol, max_iter, frozen=None):
    r"""Polonsky-Keer CG, displacement control: gap $g = \mathcal H q - t$ with `t` the
    `target`; `bonded` cells carry any $q$ ($g = 0$), `frozen` cells (optional) are held at
    $q = 0$, and $q \ge 0$ on the other (free) cells. With every cell bonded or frozen this
    is a plain CG on the bonded set. Returns `(q, Hq, iterations, converged)`."""
    dtype = target.dtype
    free = ~bonded if frozen is None else ~bonded & ~frozen
    q = jnp.where(bonded, q0, jnp.maximum(q0, 0.0))
    if frozen is not None:
        q = jnp.where(frozen, 0.0, q)
    g = _convolve(khat, q) - target
    # seed penetrating free cells so that the active set is never empty when it must not be
    seed = free & (q <= 0) & (g < 0)
    q = jnp.where(seed, -g / k00, q)

    def cond(c):
        return (c[5] < max_iter) & (c[6] > tol)

    def body(c):
        q, hq, t_dir, g_old, delta, it, _ = c
        g = hq - target
        act = bonded | (q > 0)
        gg = jnp.sum(jnp.where(act, g * g, 0.0))
        t_dir = jnp.where(act, g + delta * safe_div(gg, g_old) * t_dir, 0.0)
        r = _convolve(khat, t_dir)
        num = jnp.sum(jnp.where(act, g * t_dir, 0.0))
        den = jnp.sum(jnp.where(act, r * t_dir, 0.0))
        tau = safe_div(num, jnp.where(den > 0, den, 0.0))
        q_lin = q - tau * t_dir
        q_new = jnp.where(bonded, q_lin, jnp.maximum(q_lin, 0.0))
        nol = free & (q_new <= 0) & (g < 0)
        any_nol = jnp.any(nol)
        q_new = jnp.where(nol, q_new - tau * g, q_new)
        # H q is updated linearly (H q - tau r); one more convolution only when the
        # projection or the re-entry of penetrating cells changed q off that line
        fix = q_new - q_lin
        hq = _sharding.cond(jnp.any(fix != 0), lambda: hq - tau * r + _convolve(khat, fix),
                          lambda: hq - tau * r)
        change = jnp.sum(jnp.abs(q_new - q))
        err = safe_div(change, jnp.sum(jnp.abs(q_new)), change)
        err = jnp.where(any_nol, jnp.maximum(err, 2 * tol), err)
        delta = jnp.where(any_nol, 0.0, 1.0).astype(dtype)
        return q_new, hq, t_dir, gg, delta, it + 1, err

    init = (q, _convolve(khat, q), jnp.zeros_like(q), jnp.zeros((), dtype),
            jnp.zeros((), dtype), 0, jnp.asarray(jnp.inf, dtype))
    q, _, _, _, _, it, err = _sharding.while_loop(cond, body, init)
    return q, _convolve(khat, q), it, err <= tol


def _pk_force(khat, h, total, tol, max_iter):
    r"""Polonsky-Keer CG in force control (the original algorithm): $q \ge 0$,
    $\sum q = $ `total`, gap $\mathcal Hq + h - d$ zero on the contact with the rigid
    indentation $d$ found as the mean of $\mathcal Hq + h$ there. Returns `(q, d, converged)`."""
    dtype = h.dtype
    q = jnp.full(h.shape, total / h.size, dtype)

    def mean_on(x, act):
        return safe_div(jnp.sum(jnp.where(act, x, 0.0)), jnp.sum(act))

    def cond(c):
        return (c[5] < max_iter) & (c[6] > tol)

    def body(c):
        q, hq, t_dir, g_old, delta, it, _ = c
        act = q > 0
        g = hq + h
        g = g - mean_on(g, act)
        gg = jnp.sum(jnp.where(act, g * g, 0.0))
        t_dir = jnp.where(act, g + delta * safe_div(gg, g_old) * t_dir, 0.0)
        r_raw = _convolve(khat, t_dir)
        r = r_raw - mean_on(r_raw, act)
        num = jnp.sum(jnp.where(act, g * t_dir, 0.0))
        den = jnp.sum(jnp.where(act, r * t_dir, 0.0))
        tau = safe_div(num, jnp.where(den > 0, den, 0.0))
        q_lin = q - tau * t_dir
        q_new = jnp.maximum(q_lin, 0.0)
        nol = (q_new <= 0) & (g < 0)
        any_nol = jnp.any(nol)
        q_new = jnp.where(nol, q_new - tau * g, q_new)
        fix = q_new - q_lin  # H q follows linearly, plus the projection's correction
        hq = _sharding.cond(jnp.any(fix != 0), lambda: hq - tau * r_raw + _convolve(khat, fix),
                          lambda: hq - tau * r_raw)
        factor = total / jnp.sum(q_new)
        q_new, hq = q_new * factor, hq * factor
        err = jnp.sum(jnp.abs(q_new - q)) / total
        err = jnp.where(any_nol, jnp.maximum(err, 2 * tol), err)
        return (q_new, hq, t_dir, gg, jnp.where(any_nol, 0.0, 1.0).astype(dtype), it + 1,
                err)

    init = (q, _convolve(khat, q), jnp.zeros_like(q), jnp.zeros((), dtype),
            jnp.zeros((), dtype), 0, jnp.asarray(jnp.inf, dtype))
    q, _, _, _, _, _, err = _sharding.while_loop(cond, body, init)
    act = q > 0
    depth = mean_on(_convolve(khat, q) + h, act)
    return q, depth, err <= tol


class _Load(eqx.Module):
    r"""What fixes the indenter at one load step (dimensionless q-units, see `_equilibrium`).

    `fixed`: displacement control (the indentation is `depth`); otherwise the indentation
    solves the loading's `SpringEquation` `equation` (scaled to q-units) for the input `x`:
    $\sum q + k d = c x$ (force control: $k = 0$, $c = 1$; compliant loading: $c = k > 0$,
    `x` the drive position)."""

    fixed: Array
    depth: Array
    equation: SpringEquation
    x: Array


class _Equilibrium(eqx.Module):
    q: Array
    hq: Array
    depth: Array
    slope: Array  # H_A s = k00 on the active set: dq/dd = s / k00
    cg_iterations: Array
    converged: Array
    exists: Array  # False: a tensile dead load and nothing in contact


class _Newton(eqx.Module):
    """What `_equilibrium`'s Newton iteration carries from one evaluation to the next."""

    depth: Array  # the indentation of the last solve
    q: Array  # ... its solution, H q and active set (the warm start of the next solve)
    hq: Array
    active: Array
    slope: Array  # the slope field of the last solve's active set
    no_eq: Array
    cg_iterations: Array
    converged: Array


def _equilibrium(khat, base, bonded, q0, s0, k00, load: _Load, tol, max_iter, max_newton):
    r"""Equilibrium at a fixed bonded set: $q$ = `_pk_solve` at the target $d - $ `base`.

    In displacement control $d$ is given. Otherwise $d$ solves the spring equation
    $F(d) + k d = c x$ with $F = \sum q$ (`SpringEquation`) by `newton_iterate`: at a fixed
    bonded set $F(d)$ is nondecreasing and convex (pressing deeper raises every pressure of
    the active set $A$, $\partial q/\partial d = \mathcal H_A^{-1}1 > 0$, and only adds
    cells), so Newton's method with the exact slope $\sum_A \mathcal H_A^{-1} 1$ (one CG on
    the fixed set $A$) converges monotonically from the right and overshoots at most once
    from the left; on a fixed active set the force is linear in $d$ and the step is exact.
    Each solve starts from the last one moved along the slope field. Without any active
    cell and $k = 0$ the indenter is moved to first touch (then one cell's compliance
    `k00`, an overshoot); a tensile dead load then has no equilibrium (`exists` False).
    `max_newton = 0` (static) compiles displacement control alone.
    """
    if max_newton == 0:  # displacement control only (static): one solve
        q, hq, it, ok = _pk_solve(khat, load.depth - base, bonded, q0, k00, tol, max_iter)
        return _Equilibrium(q, hq, load.depth, s0, it, ok, jnp.asarray(True))
    d_touch = jnp.min(base)
    eq = load.equation
    target = eq.target(load.x)

    def evaluate(d, c: _Newton):
        q_start = jnp.where(c.active, c.q + (d - c.depth) * c.slope / k00, c.q)
        q, hq, it, conv = _pk_solve(khat, d - base, bonded, q_start, k00, tol, max_iter)
        r = eq.residual(jnp.sum(q), d, load.x)
        scale = jnp.sum(jnp.abs(q)) + jnp.abs(target) + eq.spring * jnp.abs(d)
        act = bonded | (q > 0)
        empty = ~jnp.any(act)
        no_eq = empty & (eq.spring == 0) & (target < 0)
        done = load.fixed | (jnp.abs(r) <= 1e2 * tol * scale) | no_eq

        def slope():
            s1, _, it1, ok1 = _pk_solve(khat, jnp.full_like(base, k00), act,
                                        jnp.where(act, c.slope, 0.0), k00, tol, max_iter,
                                        frozen=~act)
            return s1, it1, ok1

        s, it_s, ok_s = _sharding.cond(done, lambda: (c.slope, 0, jnp.asarray(True)), slope)
        new = _Newton(d, q, hq, act, s, no_eq, c.cg_iterations + it + it_s,
                      c.converged & conv & ok_s)
        return r, eq.slope(jnp.sum(s) / k00), done, new

    def first_touch(d, r, c):
        return jnp.where(target > 0, d_touch + target * k00, d_touch)

    init = _Newton(load.depth, q0, q0, jnp.zeros(q0.shape, bool), s0, jnp.asarray(False),
                   jnp.asarray(0), jnp.asarray(True))
    d, c, done = newton_iterate(evaluate, load.depth, init, steps=max_newton, slope_floor=0.0,
                                fallback=first_touch)
    return _Equilibrium(c.q, c.hq, d, c.slope, c.cg_iterations, c.converged & done, ~c.no_eq)


class _Step(eqx.Module):
    eq: _Equilibrium
    attached: Array
    rounds: Array
    converged: Array


def _consistent(khat, base, attached, q0, s0, k00, q_crit, adhesive, load, tol, max_iter,
                max_rounds, max_newton):
    """Iterate the cell rule to a consistent attached set at one load step.

    `q_crit` is the critical stress over the step's effective modulus (stress rule
    p < sigma_c  <=>  q < q_crit). Non-adhesive (`adhesive=False`): no cell is ever attached.
    """
    if not adhesive:
        no = jnp.zeros_like(attached)
        eq = _equilibrium(khat, base, no, q0, s0, k00, load, tol, max_iter, max_newton)
        return _Step(eq, no, jnp.asarray(1), eq.converged)

    def cond(c):
        return c[3] & (c[2] < max_rounds)

    def body(c):
        eq, att, rounds, _ = c
        eq = _equilibrium(khat, base, att, eq.q, eq.slope, k00,
                          eqx.tree_at(lambda x: x.depth, load, eq.depth), tol, max_iter,
                          max_newton)
        release = att & (eq.q < q_crit)
        touch = (~att) & (eq.q > 0)
        new = (att & ~release) | touch
        changed = jnp.any(new != att)
        eq = eqx.tree_at(lambda x: (x.q, x.cg_iterations, x.converged), eq,
                         (jnp.where(release, 0.0, eq.q), c[0].cg_iterations + eq.cg_iterations,
                          c[0].converged & eq.converged))
        return eq, new, rounds + 1, changed

    z = jnp.zeros_like(q0)
    init = _Equilibrium(q0, z, load.depth, s0, jnp.asarray(0), jnp.asarray(True),
                        jnp.asarray(True))
    eq, att, rounds, changed = _sharding.while_loop(
        cond, body, (init, attached, jnp.asarray(0), jnp.asarray(True)))
    # the last solve used `att` before the update; if nothing changed it is consistent
    return _Step(eq, att, rounds, eq.converged & ~changed)



@float64_scope
def bem_contact(
    indenter,
    depth: Float[ArrayLike, ""] | None = None,
    *,
    grid: BEMGrid,
    effective_modulus: Float[ArrayLike, ""],
    force: Float[ArrayLike, ""] | None = None,
    tol: float = 1e-10,
    max_iter: int = 2000,
    throw: bool = True,
) -> tuple[Array, Array, Array]:
    r"""Non-adhesive elastic contact of a rigid indenter, displacement or force control.

    **Arguments:**

    - `indenter`: an `AbstractProfile` (axisymmetric) or a height map [m] of shape
      `(n, n)` on the grid (shifted so that its lowest cell is at 0).
    - `depth`: indentation $d$ [m], positive into the sample (displacement control): of the
      apex $f(0) = 0$ for a profile, of the lowest cell for a height map.
    - `grid`: a `BEMGrid`.
    - `effective_modulus`: $E^*$ [Pa], > 0 ($4G$ for an incompressible half-space).
    - `force`: alternatively the normal force $F$ [N], > 0 (force control: the original
      Polonsky-Keer algorithm with the load constraint). Give exactly one of `depth`, `force`.
    - `tol`: relative change of the pressure at which the CG stops.
    - `max_iter`: CG iteration limit (static).
    - `throw`: raise if the CG did not converge (under `jit` via `equinox.error_if`).

    **Returns:** `(force, depth, pressure)`: the normal force [N] (compressive positive),
    the indentation [m] and the cell pressures [Pa], shape `(n, n)`; the contact area is
    $\Delta^2\cdot\#\{p > 0\}$.
    """
    if (depth is None) == (force is None):
        raise ValueError("Give exactly one of `depth` [m] and `force` [N].")
    check_positive("effective_modulus", effective_modulus, "Pa")
    if depth is not None:
        check_finite("depth", depth, "m")
    else:
        check_positive("force", force, "N")
    h = _heights(indenter, grid)
    out = _bem_contact(*floats_to_arrays((h, None if depth is None else as_float(depth),
                                          None if force is None else as_float(force), grid,
                                          as_float(effective_modulus))), tol, max_iter)
    if throw:
        out = error_if(out, ~out[3], "BEM: the constrained CG did not converge (raise "
                           "`max_iter` or `tol`).")
    return out[:3]


@eqx.filter_jit
def _bem_contact(h, depth, force, grid, modulus, tol, max_iter):
    delta = grid.cell_size
    khat = _kernel_hat(grid.cells, delta)
    if depth is None:
        q, depth, ok = _pk_force(khat, h, force / (modulus * delta * delta), tol, max_iter)
    else:
        k00 = love_displacement(0.0, 0.0, 0.5 * delta, 0.5 * delta)
        att = jnp.zeros(h.shape, bool)
        q, _, _, ok = _pk_solve(khat, depth - h, att, jnp.zeros_like(h), k00, tol, max_iter)
    p = modulus * q
    return jnp.sum(p) * delta * delta, depth, p, ok
