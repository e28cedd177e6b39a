r"""Small numerical helpers shared by the forward models (one home for each).

The bracketed scalar root finder with implicit derivatives lives in `_root.py`
(`bracketed_root`); this module holds the other helpers:

- `golden_section`: shrink a bracket around the minimum of a unimodal scalar function.
- `quadratic_newton_form`, `quadratic_at`, `quadratic_vertex`: the quadratic through three
  points in Newton's divided-difference form, its value and its stationary point.
- `safe_div`: division that returns a fallback where the denominator vanishes (no NaN in
  either branch of a `jnp.where`, so gradients stay finite).
- `as_float`, `floats_to_arrays`: conversion of inputs to floating arrays.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array

__all__ = [
    "as_float",
    "floats_to_arrays",
    "golden_section",
    "quadratic_at",
    "quadratic_newton_form",
    "quadratic_vertex",
    "safe_div",
]

_GOLDEN = 0.5 * (np.sqrt(5.0) - 1.0)


def as_float(x) -> Array:
    """`x` as a JAX array of inexact dtype: float (and complex) inputs keep their precision
    (so float32 stays float32 for GPU sweeps); integers, bools and Python scalars become the
    default float."""
    x = jnp.asarray(x)
    return x if jnp.issubdtype(x.dtype, jnp.inexact) else x.astype(float)


def floats_to_arrays(tree):
    """Python and NumPy floats in `tree` become float arrays, weakly typed arrays strongly
    typed (the cache key of a compiled program holds the types, not the values, so one
    program serves every value)."""

    def convert(leaf):
        if isinstance(leaf, float | np.floating):
            return jnp.asarray(leaf, dtype=float)
        if isinstance(leaf, jax.Array) and getattr(leaf, "weak_type", False):
            return lax.convert_element_type(leaf, leaf.dtype)
        return leaf

    return jax.tree_util.tree_map(convert, tree)


def safe_div(num, den, fallback=0.0):
    """`num / den` where `den != 0`, else `fallback` (the division never sees a zero)."""
    ok = den != 0
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), fallback)


def golden_section(
    fn: Callable[[Array], Array], lo: Array, hi: Array, *, steps: int
) -> tuple[Array, Array]:
    r"""Golden-section search for the minimum of a unimodal scalar function on `[lo, hi]`.

    Each step evaluates `fn` at the two interior golden points (one `vmap`ped call, so `fn`
    is traced once) and keeps the sub-bracket holding the smaller value; the bracket shrinks
    by $(\sqrt5 - 1)/2 \approx 0.618$ per step. No derivatives flow through the search (the
    values are compared under `stop_gradient`): callers differentiate at the located
    minimiser (envelope theorem) or polish it by Newton steps.

    **Arguments:**

    - `fn`: scalar function of a scalar.
    - `lo`, `hi`: the initial bracket, `lo <= hi` (scalars).
    - `steps`: number of steps (static); the bracket width becomes
      $0.618^\mathrm{steps}$ of the initial one.

    **Returns:** the final bracket `(lo, hi)`.
    """

    def body(_, carry):
        lo, hi = carry
        x1 = hi - _GOLDEN * (hi - lo)
        x2 = lo + _GOLDEN * (hi - lo)
        f1, f2 = lax.stop_gradient(jax.vmap(fn)(jnp.stack([x1, x2])))
        left = f1 <= f2
        return jnp.where(left, lo, x1), jnp.where(left, x2, hi)

    return lax.fori_loop(0, steps, body, (lax.stop_gradient(lo), lax.stop_gradient(hi)))


def quadratic_newton_form(x0, x1, x2, y0, y1, y2, ok=True) -> tuple[Array, Array]:
    r"""Quadratic through three points in Newton form,
    $y(x) = y_0 + b\,(x - x_0) + c\,(x - x_0)(x - x_1)$.

    $b = y[x_0, x_1]$ and $c = y[x_0, x_1, x_2] = (y[x_1, x_2] - y[x_0, x_1])/(x_2 - x_0)$
    are the divided differences. The nodes must be distinct; where `ok` is False the
    spacings are replaced by 1 (nothing divides by zero; the result is meaningless there
    and the caller discards it).

    **Returns:** `(b, c)`.
    """
    h0 = jnp.where(ok, x1 - x0, 1.0)
    h1 = jnp.where(ok, x2 - x1, 1.0)
    b = (y1 - y0) / h0
    return b, ((y2 - y1) / h1 - b) / (h0 + h1)


def quadratic_at(x, x0, x1, y0, b, c) -> Array:
    """Value at `x` of the Newton form returned by `quadratic_newton_form`."""
    return y0 + b * (x - x0) + c * (x - x0) * (x - x1)


def quadratic_vertex(x0, x1, b, c) -> Array:
    r"""Stationary point of the Newton form: $y'(x) = b + c\,(2x - x_0 - x_1) = 0$, i.e.
    $x = (x_0 + x_1)/2 - b/(2c)$ (`c` must be nonzero; a minimum for $c > 0$)."""
    return 0.5 * (x0 + x1) - b / (2.0 * c)
