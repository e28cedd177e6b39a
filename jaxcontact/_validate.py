"""Input validation shared by the physics modules.

Checks run eagerly, with a `ValueError` that names the parameter, its unit and the allowed
range, whenever the value is concrete. Under `jit`/`vmap` tracing the value is abstract and
the check is skipped here; the entry functions then check at run time with
`equinox.error_if` (see `throw=`).
"""

from __future__ import annotations

import jax
import numpy as np

__all__ = ["check_positive", "check_finite", "check_times", "is_concrete"]


def is_concrete(value) -> bool:
    """True when `value` holds real numbers (not a JAX tracer)."""
    leaves = jax.tree_util.tree_leaves(value)
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in leaves)


def check_finite(name: str, value, unit: str = "") -> None:
    """Raise `ValueError` if a concrete `value` contains NaN or infinity."""
    if value is None or not is_concrete(value):
        return
    arr = np.asarray(value, dtype=float)
    if not np.all(np.isfinite(arr)):
        bad = int(np.sum(~np.isfinite(arr)))
        raise ValueError(f"`{name}` [{unit}] contains {bad} non-finite value(s) (NaN or inf).")


def check_positive(
    name: str,
    value,
    unit: str = "",
    *,
    upper: float | None = None,
    allow_zero: bool = False,
) -> None:
    """Raise `ValueError` unless every concrete entry of `value` is finite and > 0.

    With `allow_zero=True` the bound is >= 0; with `upper` the value must also be < `upper`.
    """
    if value is None or not is_concrete(value):
        return
    arr = np.asarray(value, dtype=float)
    check_finite(name, arr, unit)
    low_ok = np.all(arr >= 0) if allow_zero else np.all(arr > 0)
    high_ok = True if upper is None else np.all(arr < upper)
    if not (low_ok and high_ok):
        lo = "[0" if allow_zero else "(0"
        hi = f"{upper:g})" if upper is not None else "inf)"
        bad = arr.ravel()[0] if arr.size == 1 else arr
        raise ValueError(
            f"`{name}` must lie in {lo}, {hi} [{unit}]; got {bad}."
        )


def check_times(ts, *, require_nonnegative: bool = False) -> None:
    """Validate sample times `ts` [s]: 1-D, at least one, finite, non-decreasing (>= 0)."""
    shape = np.shape(ts)
    if len(shape) != 1 or shape[0] < 1:
        raise ValueError(f"`ts` [s] must be a 1-D array with at least one time; got shape {shape}.")
    if not is_concrete(ts):
        return
    arr = np.asarray(ts, dtype=float)
    check_finite("ts", arr, "s")
    bad = np.flatnonzero(np.diff(arr) < 0)
    if bad.size:
        i = int(bad[0])
        raise ValueError(
            f"`ts` [s] must be non-decreasing; ts[{i + 1}] = {arr[i + 1]:g} < ts[{i}] = {arr[i]:g}."
        )
    if require_nonnegative and arr[0] < 0:
        raise ValueError(f"`ts` [s] must be >= 0 (t = 0 is the start of the lift); got {arr[0]:g}.")
