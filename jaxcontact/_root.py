r"""Scalar root finding with implicit differentiation (the one home of the root finders).

- `bracketed_root`: any sign change on a bracket (safeguarded Newton, below).
- `concave_root`: the root of a function that is concave on its bracket (monotone Newton
  from the right end, at most a fixed number of steps, each lane stopping once converged;
  the detachment front of the foundation).
- `convex_root`: the root of an increasing function that is convex on its bracket, from a
  start to the right of it (monotone Newton, a fixed number of steps written out, no loop;
  the exact sphere's stationary radius of the criterion in a cell of the foundation grid).
- `fold_root`: the stable root of $h(x) = m$ right of the minimum (the fold) of $h$, by
  Newton's method on the square root of the rise above that minimum, where the root is
  regular even at the fold (a fixed number of steps from a close start, no loop under
  `vmap`; the detachment fronts of the exact sphere and the power law).
- `newton_root`: damped Newton steps from a guess for an increasing function (the
  equilibrium of a compliant loading system), differentiated implicitly.
- `newton_iterate`: the Newton iteration itself, with the caller's evaluation (residual,
  slope, stop) and safeguard: the one loop that solves the spring equation of a loading
  system (`_foundation/_loading.SpringEquation`) in `simulate` (through `newton_root`) and
  in `bem_simulate` (directly: every evaluation is a constrained solve on the grid).

`bracketed_root` solves $f(x) = 0$ on a bracket $[x_\mathrm{lo}, x_\mathrm{hi}]$ with a
safeguarded Newton iteration: it starts from the regula-falsi point of the bracket, takes the
Newton step where it stays inside the shrinking bracket, tries the bracket end where the
step lands on it to round-off, and bisects otherwise; it stops as soon as it has converged
(see below) or after `steps` iterations. An end where $f = 0$ is returned at once, and so is,
without a sign change, the end where $|f|$ is smaller. Under `vmap` the loop runs
until every lane has stopped; finished lanes keep their value. Derivatives do not flow
through the iterations: `jax.lax.custom_root` applies the implicit function theorem,
$\partial x/\partial\theta = -(\partial f/\partial x)^{-1}\,\partial f/\partial\theta$, so
gradients are exact for the converged root and cost one extra evaluation of $f$.

**Stopping.** With $\varepsilon$ the machine epsilon of the bracket's dtype, a lane stops when
$f(x) = 0$; when the Newton correction $|f/f'|$ is below $4\varepsilon|x|$ (also where the
corrected point would land on the bracket end: Newton converging from one side moves only
that end); when the bracket is narrower than
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

from ._sharding import while_loop

__all__ = ["bracketed_root", "concave_root", "convex_root", "fold_root", "newton_iterate",
           "newton_root"]


def _solve(fn, lo, hi, steps, dtype):
    lo = lax.stop_gradient(jnp.asarray(lo, dtype))
    hi = lax.stop_gradient(jnp.asarray(hi, dtype))
    eps4 = 4.0 * jnp.finfo(jnp.result_type(lo, hi)).eps
    width0 = jnp.abs(hi - lo)
    f_lo = fn(lo).astype(dtype)
    f_hi = fn(hi).astype(dtype)
    sign_lo = jnp.sign(f_lo)
    mid = 0.5 * (lo + hi)
    # regula falsi start (the midpoint if it is not strictly inside the bracket)
    den = f_hi - f_lo
    x0 = lo - f_lo * (hi - lo) / jnp.where(den == 0, 1.0, den)
    inside0 = (den != 0) & jnp.isfinite(x0)
    inside0 = inside0 & (x0 > jnp.minimum(lo, hi)) & (x0 < jnp.maximum(lo, hi))
    x0 = jnp.where(inside0, x0, mid)
    # a root at a bracket end is the answer (Newton would land on the end, which is not
    # strictly inside, and the loop would bisect towards it to round-off); without a sign
    # change there is no root to find: the end where |f| is smaller, at once (the loop
    # bisected towards an end for up to `steps` iterations, and under vmap every lane waited)
    no_change = sign_lo * jnp.sign(f_hi) > 0
    end = jnp.where(jnp.abs(f_lo) <= jnp.abs(f_hi), lo, hi)
    x0 = jnp.where(no_change, end, x0)
    x0 = jnp.where(f_hi == 0, hi, jnp.where(f_lo == 0, lo, x0))
    done0 = no_change | (f_lo == 0) | (f_hi == 0)
    inf = jnp.full_like(mid, jnp.inf)

    def cond(carry):
        i, _, _, _, _, done, _ = carry
        return (i < steps) & jnp.logical_not(done)

    def body(carry):
        i, lo, hi, x, prev_step, done, (before, before2) = carry
        # round-off can trap the iteration: where f is quantised (its round-off exceeds f'
        # times the distance of neighbouring points) Newton from each of two adjacent points
        # of opposite sign may land on the other, or a bisection round to its end. The body
        # is a function of the state (lo, hi, x, prev_step) alone, so once the state is the
        # one of two iterations before, it alternates between two states until `steps`
        # (the loop ran to `steps`, and under vmap every lane waited): stop with the x that
        # the last iteration would have left (the same result). Compared are carried values
        # only (XLA may compute a value twice, in two kernels, not always to the same bits).
        state = (lo, hi, x, prev_step)
        periodic = _same(state, before2)
        x_periodic = jnp.where((steps - i) % 2 == 0, x, before[2])
        fx, dfx = jax.jvp(fn, (x,), (jnp.ones_like(x),))
        # `fn` may close over arrays of a wider dtype: the carry keeps the bracket's
        fx, dfx = fx.astype(dtype), dfx.astype(dtype)
        same_as_lo = jnp.sign(fx) == sign_lo
        lo_n = jnp.where(same_as_lo, x, lo)
        hi_n = jnp.where(same_as_lo, hi, x)
        correction = fx / jnp.where(dfx == 0, 1.0, dfx)
        newton = x - correction
        inside = (dfx != 0) & jnp.isfinite(newton)
        inside = inside & (newton > jnp.minimum(lo_n, hi_n)) & (newton < jnp.maximum(lo_n, hi_n))
        # a Newton correction below round-off: converged. (Without this test, Newton that
        # converges from one side lands on the bracket end it has just moved, which is not
        # strictly inside, and the loop bisected away from the root for ~40 more steps.)
        resolved = (dfx != 0) & jnp.isfinite(correction) & (
            jnp.abs(correction) <= eps4 * jnp.abs(x))
        # Newton lands on a bracket end to round-off (a root at the end, e.g. of a linear
        # function): try that end next (from it Newton resolves the root in one step)
        # instead of bisecting towards it
        near_lo = jnp.abs(newton - lo_n) <= eps4 * jnp.abs(lo_n)
        near_hi = jnp.abs(newton - hi_n) <= eps4 * jnp.abs(hi_n)
        target = jnp.where(near_lo, lo_n, hi_n)
        at_end = (dfx != 0) & jnp.isfinite(newton) & jnp.logical_not(inside) & (
            near_lo | near_hi) & (target != x)
        x_new = jnp.where(inside, newton, 0.5 * (lo_n + hi_n))
        x_new = jnp.where(at_end, target, x_new)
        step = jnp.abs(x_new - x)
        zero = fx == 0
        x_new = jnp.where(zero | (resolved & jnp.logical_not(inside)), x, x_new).astype(dtype)
        floor = inside & _round_off_floor(step, prev_step, width0)
        stop = (
            zero
            | resolved
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
            keep(x, jnp.where(periodic, x_periodic, x_new)),
            keep(prev_step, jnp.where(inside, step, inf)),
            done | stop | periodic,
            jax.tree.map(keep, (before, before2), (state, before)),
        )

    nan = (jnp.full_like(mid, jnp.nan),) * 4  # no earlier state: equal to none
    carry = (jnp.asarray(0), lo, hi, x0, inf, done0, (nan, nan))
    return while_loop(cond, body, carry)[3]


def _round_off_floor(step, prev_step, width0):
    """Newton has reached the round-off floor of f: a step below $10^{-9}$ of the initial
    bracket that is not smaller than 0.9 of the previous Newton step (above the floor the
    steps shrink: quadratically, or by 1/2 an iteration near a double root)."""
    return (step <= 1e-9 * width0) & (step >= 0.9 * prev_step)


def _same(a, b):
    """Bitwise-equal states (tuples of arrays; NaN equals nothing)."""
    out = jnp.asarray(True)
    for x, y in zip(a, b, strict=True):
        out = out & (x == y)
    return out


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
      without a sign change the result is the end where $|f|$ is smaller, without
      iterating).
    - `steps`: largest number of safeguarded Newton/bisection steps (64 resolves any
      float64 bracket to round-off by bisection alone); the loop stops earlier once
      converged (module docstring), typically after 3–6 steps.

    **Returns:** the root, a scalar array.
    """
    lo = jnp.asarray(lo)
    hi = jnp.asarray(hi)
    # the precision of the bracket and of the function: a Python-float bracket (weakly
    # typed) takes that of the function's values
    dtype = jnp.result_type(lo, hi, jax.eval_shape(fn, lo).dtype)

    def solve(f, _guess):
        return _solve(f, lo, hi, steps, dtype)

    def tangent_solve(g, y):
        return y / g(jnp.ones_like(y))

    guess = jnp.asarray(0.5 * (lo + hi), dtype)
    return lax.custom_root(fn, guess, solve, tangent_solve)


def _divide_by_slope(g, y):
    """The tangent solve of a scalar `custom_root`: `y / f'(x)` (`g` the linearised `f`;
    a zero slope divides by 1, leaving a finite tangent where the root is not used)."""
    slope = g(jnp.ones_like(y))
    return y / jnp.where(slope == 0, 1.0, slope)


def concave_root(
    fn: Callable[[jax.Array], jax.Array],
    lo: jax.Array,
    hi: jax.Array,
    *,
    steps: int,
    active: jax.Array | None = None,
    unrolled: int = 0,
) -> jax.Array:
    r"""Root of `fn` in `[lo, hi]` with `fn(lo) >= 0 > fn(hi)` and `fn` concave there.

    Newton's method started at `hi` converges monotonically from the right for a concave
    function (each tangent lies above the graph); a bisection guard keeps the iterate inside
    the shrinking bracket. At most `steps` iterations (static); a lane stops once its
    Newton correction is below $4\varepsilon|x|$ (after applying it: the iterates left
    move by round-off), `fn` vanishes, the bracket has collapsed or Newton has reached the
    round-off floor of `fn` (a step below $10^{-9}$ of the bracket not smaller than 0.9 of
    the previous one, as `bracketed_root`), and at once where `active` is False (a root
    that is not used: under `vmap` the loop runs until every lane has stopped, so the
    lanes of a branch not taken must not hold it). Near a double root (the fold of the
    front) Newton converges linearly, halving its step, until that floor or `steps`.
    `unrolled` (static, at most `steps`): that many iterations written out before the loop,
    the same iterates (a lane that has stopped keeps its values), so that the usual few
    iterations run as straight-line code without the loop's dispatch and carry copies.
    Differentiated implicitly (`jax.lax.custom_root`).
    """
    lo = lax.stop_gradient(lo)
    hi = lax.stop_gradient(hi)
    idle = jnp.asarray(False) if active is None else jnp.logical_not(active)

    def solve(f, _guess):
        eps4 = 4.0 * jnp.finfo(jnp.result_type(hi)).eps

        def f_df(x):
            return jax.jvp(f, (x,), (jnp.ones_like(x),))

        def cond(carry):
            i, _, _, _, _, _, _, done = carry
            return (i < steps) & jnp.logical_not(done)

        width0 = jnp.abs(hi - lo)

        # f and f' of an iterate are evaluated once, at the end of the iteration that makes
        # it, and carried: every decision of the next iteration reads the same stored
        # values (XLA may compute one expression in two kernels, not always to the same
        # bits: near the root the sign of f in the bracket update and in the stop test
        # could disagree)
        def body(carry):
            i, a, b, x, fx, dfx, prev_step, done = carry
            a_n = jnp.where(fx >= 0, x, a)
            b_n = jnp.where(fx >= 0, b, x)
            newton = x - fx / jnp.where(dfx == 0, 1.0, dfx)
            good = (dfx != 0) & jnp.isfinite(newton) & (newton >= a_n) & (newton <= b_n)
            x_new = jnp.where(good, newton, 0.5 * (a_n + b_n))
            x_new = jnp.where(fx == 0, x, x_new).astype(x.dtype)
            # a collapsed bracket (`fn(hi) > 0` by round-off: the root is the end) leaves x
            # where it is: stop (the loop bisected in place to the step limit)
            stop = (fx == 0) | (good & (jnp.abs(newton - x) <= eps4 * jnp.abs(x)))
            stop = stop | (b_n <= a_n)
            # Newton at the round-off floor of f (near a double root f' is small and f's
            # round-off moves the iterate by more than 4 eps |x|): a step below 1e-9 of the
            # bracket that is not smaller than 0.9 of the previous one (above the floor the
            # steps shrink, by 1/2 an iteration or faster), as `bracketed_root`
            step = jnp.abs(x_new - x)
            stop = stop | (good & _round_off_floor(step, prev_step, width0))
            f_new, df_new = f_df(x_new)
            keep = lambda old, new: jnp.where(done, old, new)  # noqa: E731
            return (i + 1, keep(a, a_n), keep(b, b_n), keep(x, x_new),
                    keep(fx, f_new.astype(fx.dtype)), keep(dfx, df_new.astype(dfx.dtype)),
                    keep(prev_step, jnp.where(good, step, jnp.inf)), done | stop)

        f0, df0 = f_df(hi)
        inf = jnp.full_like(hi, jnp.inf)
        carry = (jnp.asarray(0), lo, hi, hi, f0, df0, inf,
                 jnp.broadcast_to(idle, jnp.shape(hi)))
        for _ in range(min(unrolled, steps)):
            carry = body(carry)
        return while_loop(cond, body, carry)[3]

    return lax.custom_root(fn, hi, solve, _divide_by_slope)


def convex_root(
    fn: Callable[[jax.Array], jax.Array],
    start: jax.Array,
    lo: jax.Array,
    hi: jax.Array,
    *,
    steps: int,
) -> jax.Array:
    r"""Root of `fn`, increasing and convex on `[lo, hi]`, clipped to `[lo, hi]`.

    Newton's method from `start` $\ge \min(x^*, \mathrm{hi})$: the tangent of a convex
    function lies below it, so every iterate stays to the right of the root and the
    iterates decrease monotonically onto it (onto `lo` when the root lies below it; a root
    above `hi` gives `hi`). Exactly `steps` (static) iterations, without a convergence
    test (a lane-dependent `while` under `vmap` runs every lane to the slowest); the caller
    picks `steps` from a measured worst case. The iteration is traced once: on the CPU a
    loop of `steps` trips (its program smaller and compiled faster than the iterations
    written out, and as fast: `benchmarks/results/fit.md`, "The exact sphere's stationary
    radius in a loop"), on other platforms written out at lowering (straight-line code that
    XLA fuses; a GPU pays a launch per kernel and iteration of a loop). Differentiated
    implicitly (`jax.lax.custom_root`), as `bracketed_root` (also at a clipped end).
    """
    lo = lax.stop_gradient(lo)
    hi = lax.stop_gradient(hi)

    def solve(f, x0):
        x = jnp.clip(lax.stop_gradient(x0), lo, hi)

        def body(_, x):
            fx, dfx = jax.jvp(f, (x,), (jnp.ones_like(x),))
            newton = x - fx / jnp.where(dfx > 0, dfx, 1.0)
            return jnp.where((dfx > 0) & jnp.isfinite(newton), jnp.clip(newton, lo, hi), x)

        # the platform is the compiled program's (`lax.platform_dependent`), not the default
        return lax.platform_dependent(
            x, cpu=lambda x: lax.fori_loop(0, steps, body, x),
            default=lambda x: lax.fori_loop(0, steps, body, x, unroll=True))

    return lax.custom_root(fn, start, solve, _divide_by_slope)


def fold_root(
    fn: Callable[[jax.Array], jax.Array],
    start: jax.Array,
    lo: jax.Array,
    hi: jax.Array,
    *,
    steps: int,
) -> jax.Array:
    r"""Root of `fn` on `[lo, hi]` where `lo` is the minimum of `fn` (its fold) and `fn`
    increases on `[lo, hi]`; the root where `fn` rises through zero, clipped to the bracket.

    Near the fold the root is a near-double root: Newton's method on `fn` itself converges
    linearly there (halving its error each step), and `bracketed_root` took 6-13 iterations
    on a force map's samples and 34 at $10^{-7}$ of the fold (the exact sphere's front).
    With $f_0 = f(\mathrm{lo}) \le 0$ this solves instead
    $$U(x) = \sqrt{f(x) - f_0} - \sqrt{-f_0} = 0,$$
    the same root ($f(x) = 0$), where $U$ is regular: near the fold
    $f - f_0 \approx \tfrac12 f''(\mathrm{lo})(x - \mathrm{lo})^2$, so $U$ is nearly
    linear with slope $U' = f'/(2\sqrt{f - f_0}) \to \sqrt{f''(\mathrm{lo})/2}$ (used where
    $f = f_0$). Newton on $U$ from `start`, each step clipped to `lo` and the nearest point
    evaluated right of the root (next to the fold $U'$ is a ratio of round-off, and the
    step from it may land anywhere), exactly `steps` (static) iterations written out,
    without a convergence test (under `vmap` a loop runs every lane to the slowest, and each
    of its iterations is a pass over memory; written out, XLA fuses the iterations into one
    element-wise pass). The caller picks `start` (a closed form of a nearby problem) and
    `steps` from a measured worst case.
    With `fn` $= h - m$ batched in $m$ alone (`lo` and $h$ shared), $h(\mathrm{lo})$ and
    $f''(\mathrm{lo})$ are computed once under `vmap`. Where $f_0 \ge 0$ the result is `lo`
    (the root at the fold, or none); a root beyond `hi` gives `hi`. Differentiated
    implicitly (`jax.lax.custom_root`), as `bracketed_root`.
    """
    lo = lax.stop_gradient(lo)
    hi = lax.stop_gradient(hi)

    def solve(f, x0):
        def slope(x):
            return jax.jvp(f, (x,), (jnp.ones_like(x),))[1]

        f0 = f(lo)
        curvature = jax.jvp(slope, (lo,), (jnp.ones_like(lo),))[1]
        rise = jnp.sqrt(jnp.maximum(-f0, 0.0))
        slope_at_fold = jnp.sqrt(jnp.maximum(0.5 * curvature, 0.0))
        x = jnp.clip(lax.stop_gradient(x0), lo, hi)
        x = jnp.where(jnp.isfinite(x), x, hi)
        right = hi  # the nearest point known to lie right of the root (U > 0 there)
        for _ in range(steps):
            fx, dfx = jax.jvp(f, (x,), (jnp.ones_like(x),))
            u = jnp.sqrt(jnp.maximum(fx - f0, 0.0))
            r = u - rise
            right = jnp.where(r > 0, x, right)
            # U' = f'/(2u) is 0/0 at the fold: its limit there; next to it both are
            # round-off (f and f0 may come from differently fused code), and a step from
            # their ratio may land anywhere: each step is clipped to [lo, right] (a step
            # past the fold onto `lo`, where U' is known, is how a concave U converges)
            du = jnp.where((u > 0) & (x > lo), dfx / (2.0 * jnp.where(u > 0, u, 1.0)),
                           slope_at_fold)
            newton = x - r / jnp.where(du > 0, du, 1.0)
            ok = (du > 0) & jnp.isfinite(newton)
            x = jnp.where(ok, jnp.clip(newton, lo, right), x)
        # f0 >= 0: the minimum reaches zero (the root is the fold) or there is no root
        return jnp.where(f0 >= 0, lo, x)

    return lax.custom_root(fn, start, solve, _divide_by_slope)


def newton_iterate(evaluate, x0, aux0, *, steps, slope_floor, fallback):
    r"""Newton's method on a scalar equation $r(x) = 0$ with the caller's safeguard.

    Each iteration calls `evaluate(x, aux) -> (r, slope, stop, aux)`: the residual, its
    slope $dr/dx$, whether `x` is accepted (the loop then ends with this `x` and the new
    `aux`), and values carried to the next evaluation (warm starts, counters; any pytree).
    Otherwise $x \leftarrow x - r/r'$ where the slope exceeds `slope_floor`, and
    $x \leftarrow$ `fallback(x, r, aux)` elsewhere (a flat or decreasing residual). At most
    `steps` iterations (a `lax.while_loop`; forward-mode derivatives flow through it).

    **Returns:** `(x, aux, stopped)`, `stopped` True where an evaluation accepted `x`.
    """

    def cond(c):
        i, _, _, stop = c
        return (i < steps) & jnp.logical_not(stop)

    def body(c):
        i, x, aux, _ = c
        r, slope, stop, aux = evaluate(x, aux)
        step = jnp.where(slope > slope_floor, x - r / slope, fallback(x, r, aux))
        return i + 1, jnp.where(stop, x, step), aux, stop

    _, x, aux, stop = while_loop(cond, body, (jnp.asarray(0), x0, aux0, jnp.asarray(False)))
    return x, aux, stop


def newton_root(
    fn: Callable[[jax.Array], jax.Array],
    guess: jax.Array,
    *,
    steps: int,
    slope_floor: jax.Array,
    fallback_slope: jax.Array,
    tangent_floor: jax.Array,
) -> jax.Array:
    r"""Root of an increasing scalar function by a fixed number of damped Newton steps.

    Each step divides by the slope $f'(x)$ where it exceeds `slope_floor`, and by
    `fallback_slope` elsewhere (a damped step where the function is flat or decreasing:
    e.g. a loading spring of stiffness $k$ in series with a contact whose stiffness is about
    to vanish). `steps` (static) iterations from `guess`, no early stop and no convergence
    check (the caller checks the residual). Differentiated implicitly; the tangent divides
    by the slope at the root, or by `fallback_slope` where its magnitude is below
    `tangent_floor`.
    """

    def solve(f, x0):
        def body(_, x):
            fx, dfx = jax.jvp(f, (x,), (jnp.ones_like(x),))
            dfx = jnp.where(dfx > slope_floor, dfx, fallback_slope)
            return x - fx / dfx

        return lax.fori_loop(0, steps, body, lax.stop_gradient(x0))

    def tangent_solve(g, y):
        slope = g(jnp.ones_like(y))
        return y / jnp.where(jnp.abs(slope) > tangent_floor, slope, fallback_slope)

    return lax.custom_root(fn, guess, solve, tangent_solve)
