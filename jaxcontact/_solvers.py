r"""Small numerical helpers shared by the forward models (one home for each).

The bracketed scalar root finder with implicit derivatives lives in `_root.py`
(`bracketed_root`); this module holds the other helpers:

- `golden_section`: shrink a bracket around the minimum of a unimodal scalar function
  (`golden_section_host`: the same steps for a NumPy/Python function, outside a trace).
- `gauss_legendre_unit`: Gauss–Legendre nodes and weights on $[0, 1]$.
- `newton_iterate`, `implicit_extremum`: Newton's method on $f'(x) = 0$ for a stationary
  point without derivatives, and the one Newton step that gives it the implicit derivative.
- `quadratic_newton_form`, `quadratic_at`, `quadratic_vertex`: the quadratic through three
  points in Newton's divided-difference form, its value and its stationary point.
- `smallest`: the minimum of several estimates with the derivative of one of them.
- `safe_div`: division that returns a fallback where the denominator vanishes (no NaN in
  either branch of a `jnp.where`, so gradients stay finite).
- `as_float`, `float_dtype`, `cast_floats`: conversion of inputs to floating arrays and the
  precision policy of the entry functions (float32 when every floating input is float32,
  float64 otherwise; Python scalars are weakly typed and take the precision of the arrays
  they meet, as in JAX).
- `float64_scope`: runs a public function called eagerly with JAX's 64-bit types switched
  on for its own duration (`jax.enable_x64(True)`, local to the calling thread), so that the
  policy above holds whatever the caller's `jax_enable_x64`; under the caller's own `jit`,
  `grad` or `vmap` the caller's setting holds. Importing the library changes nothing.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array

__all__ = [
    "as_float",
    "cast_floats",
    "float_dtype",
    "float64_scope",
    "floats_to_arrays",
    "gauss_legendre_unit",
    "golden_section",
    "golden_section_host",
    "implicit_extremum",
    "newton_iterate",
    "quadratic_at",
    "quadratic_newton_form",
    "quadratic_vertex",
    "safe_div",
    "smallest",
]

_GOLDEN = float(0.5 * (np.sqrt(5.0) - 1.0))  # a Python float: weakly typed


def _traced(tree) -> bool:
    """Whether `tree` holds a JAX tracer or the call runs inside a `jit` trace."""
    if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(tree)):
        return True
    if _trace_state_clean is not None and _trace_state_clean():
        # no transformation is running: not inside a trace (the same answer as below, without
        # an eager dispatch of ~0.1 ms on the CPU per entry-function call)
        return False
    return isinstance(jnp.zeros(()), jax.core.Tracer)


try:  # JAX's own test for "no trace active" (absent in other versions: the dispatch above)
    from jax._src.core import trace_state_clean as _trace_state_clean
except ImportError:  # pragma: no cover - other JAX versions
    _trace_state_clean = None


def float64_scope(fn):
    """Decorate a public function (entry function, constructor converter, profile or
    rheology method) to run with JAX's 64-bit types on (`jax.enable_x64(True)`, local to
    the calling thread) when it is called eagerly, the caller's setting restored afterwards.

    The caller's `jax_enable_x64` is never changed (importing `jaxcontact` leaves it alone),
    yet eagerly float64 inputs (Python floats, NumPy's default float64 arrays) are computed
    in float64 and float32 inputs in float32 (`float_dtype`). Called inside the caller's
    own transformation (`jit`, `grad`, `vmap`: a tracer among the arguments, or a `jit`
    trace) the function follows the caller's setting, because JAX lowers and differentiates
    the caller's program after this call returns: with x64 off that program is float32
    throughout (switch x64 on, globally or with `jax.enable_x64(True)` around the
    transformed call, for float64). The returned arrays keep their dtype; with x64 off, JAX
    truncates float64 arrays to float32 (with its warning) in the caller's own operations.
    """

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        if jax.config.jax_enable_x64 or _traced((args, kwargs)):
            return fn(*args, **kwargs)
        with jax.enable_x64(True):
            return fn(*args, **kwargs)

    return wrapper


@float64_scope
def as_float(x) -> Array:
    """`x` as a JAX array of inexact dtype: float (and complex) inputs keep their precision
    (so float32 stays float32 for GPU sweeps); integers, bools and Python scalars become the
    default float (float64 when called eagerly, whatever the caller's `jax_enable_x64`:
    `float64_scope`)."""
    x = jnp.asarray(x)
    return x if jnp.issubdtype(x.dtype, jnp.inexact) else x.astype(float)


def _is_float_leaf(leaf) -> bool:
    if isinstance(leaf, bool | int | np.integer | np.bool_):
        return False
    if isinstance(leaf, float | np.floating):
        return True
    return isinstance(leaf, jax.Array | np.ndarray) and jnp.issubdtype(leaf.dtype, jnp.floating)


def float_dtype(*trees):
    """The precision of a computation on the floating leaves of `trees`.

    float32 when every floating array is float32 (Python floats, being weakly typed, do
    not count), float64 (the default float) when any is float64 or when there is no
    floating array at all. Integer leaves (counts, options) do not take part. float32
    whenever JAX's 64-bit types are off (inside a caller's transformation with x64 off;
    see `float64_scope`): float64 leaves are then cast down by `cast_floats`.
    """
    if not jax.config.jax_enable_x64:
        return jnp.dtype(jnp.float32)
    leaves = [leaf for leaf in jax.tree_util.tree_leaves(trees) if _is_float_leaf(leaf)]
    return jnp.result_type(*leaves, 0.0) if leaves else jnp.result_type(0.0)


def cast_floats(tree, dtype):
    """Every floating leaf of `tree` (Python floats included) as a strongly typed array of
    `dtype`; other leaves unchanged.

    The cache key of a compiled program holds the types, not the values, so after this one
    program serves every value of the parameters (a Python float field would otherwise be
    a static value and recompile the program on every new value).
    """

    def convert(leaf):
        if not _is_float_leaf(leaf):
            return leaf
        return lax.convert_element_type(jnp.asarray(leaf), dtype)

    return jax.tree_util.tree_map(convert, tree)


def floats_to_arrays(tree):
    """Every floating leaf of `tree` as a strongly typed array of the tree's precision
    (`float_dtype`): one compiled program then serves every value and float32 inputs
    stay float32."""
    return cast_floats(tree, float_dtype(tree))


def smallest(values: Array) -> Array:
    """The smallest entry of `values`, with the derivative of the first smallest one.

    (`jnp.minimum` and `jnp.min` split the derivative of a tie between the tied entries,
    which mixes different sensitivities where two estimates of one quantity coincide; here
    the order of the entries is the order of preference.)
    """
    values = jnp.ravel(values)
    return values[jnp.argmin(values)]


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
        x1, x2 = _golden_points(lo, hi)
        f1, f2 = lax.stop_gradient(jax.vmap(fn)(jnp.stack([x1, x2])))
        left = f1 <= f2
        return jnp.where(left, lo, x1), jnp.where(left, x2, hi)

    return lax.fori_loop(0, steps, body, (lax.stop_gradient(lo), lax.stop_gradient(hi)))


def _golden_points(lo, hi):
    """The two interior golden points of `[lo, hi]` (one step of both golden searches)."""
    return hi - _GOLDEN * (hi - lo), lo + _GOLDEN * (hi - lo)


def golden_section_host(
    fn: Callable[[float], float], lo: float, hi: float, *, steps: int
) -> tuple[float, float]:
    """`golden_section` for a plain (NumPy/Python) scalar function, run on the host.

    The same steps (both interior points evaluated each step, the left sub-bracket kept on a
    tie), without tracing or compiling `fn`: for data-dependent objectives called once, such
    as the contact-point fit of `fitting.preprocess`, where a compiled loop would recompile
    for every curve. **Returns:** the final bracket `(lo, hi)` as Python floats.
    """
    lo, hi = float(lo), float(hi)
    for _ in range(steps):
        x1, x2 = _golden_points(lo, hi)
        if fn(x1) <= fn(x2):
            hi = x2
        else:
            lo = x1
    return lo, hi


@functools.cache
def gauss_legendre_unit(n: int) -> tuple[np.ndarray, np.ndarray]:
    r"""`n`-point Gauss–Legendre nodes and weights on $[0, 1]$ (NumPy, float64; cached):
    $\int_0^1 f \approx \sum_i w_i f(u_i)$, exact for polynomials of degree $2n - 1$."""
    x, w = np.polynomial.legendre.leggauss(n)
    u, w = 0.5 * (x + 1.0), 0.5 * w
    u.flags.writeable = False
    w.flags.writeable = False
    return u, w


def newton_iterate(
    df: Callable[[Array], Array],
    x0: Array,
    lo: Array,
    hi: Array,
    *,
    steps: int,
    max_step: Array | None = None,
) -> Array:
    r"""Newton's method on $f'(x) = 0$ for a stationary point of a scalar function.

    `steps` iterations (static) from `x0`, each clipped to `[lo, hi]`; a non-finite step
    (and, with `max_step`, a step not smaller than `max_step`: a polish that must not jump
    across a kink) leaves the iterate where it is. No derivatives flow through the
    iterations: follow with `implicit_extremum` for them.

    **Arguments:** `df`: $f'$, a scalar function of a scalar (it may close over
    parameters); `x0`, `lo`, `hi`: start and bounds.

    **Returns:** the last iterate (derivative-free).
    """
    lo, hi = lax.stop_gradient(lo), lax.stop_gradient(hi)
    d2f = jax.grad(df)

    def body(_, x):
        step = df(x) / d2f(x)
        ok = jnp.isfinite(step)
        if max_step is not None:
            ok = ok & (jnp.abs(step) < max_step)
        return jnp.clip(jnp.where(ok, x - step, x), lo, hi)

    x0 = lax.stop_gradient(jnp.clip(x0, lo, hi))
    return lax.stop_gradient(lax.fori_loop(0, steps, body, x0))


def implicit_extremum(
    df: Callable[[Array], Array],
    x: Array,
    lo: Array,
    hi: Array,
    *,
    maximum: bool,
    ok: Array | bool = True,
    fallback: Array | None = None,
    keep_value: bool = False,
) -> Array:
    r"""A stationary point `x` of $f$, located without derivatives, made differentiable.

    One Newton step on $f'(x) = 0$ at `x` with derivatives carries the implicit
    derivative of the extremum, $\mathrm{d}x/\mathrm{d}p = -\partial_p f'/f''$, where `x`
    is an interior extremum of the requested kind: `lo < x < hi`, $f''$ finite with the sign
    of a maximum (`maximum=True`, $f'' < 0$) or a minimum ($f'' > 0$), and `ok`. Elsewhere
    the result is `fallback` (default `x` itself).

    With `keep_value=True` the step enters only the derivative (the value stays `x`);
    otherwise the value also moves by the (converged, round-off sized) Newton step.
    """
    curv = jax.grad(df)(x)
    sign_ok = curv < 0 if maximum else curv > 0
    good = ok & sign_ok & jnp.isfinite(curv) & (x > lo) & (x < hi)
    slope = df(x)
    if keep_value:
        slope = slope - lax.stop_gradient(slope)
    moved = x - slope / jnp.where(good, curv, -1.0 if maximum else 1.0)
    return jnp.where(good, moved, x if fallback is None else fallback)


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
