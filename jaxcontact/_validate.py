r"""Input validation shared by the physics modules.

Three layers, all naming the parameter, its unit and the allowed range:

- **Eager checks** (`check_positive`, `check_finite`, `check_times`, `Constraint.check`,
  `check_plausible`): a `ValueError` as soon as a value is concrete (not a JAX tracer),
  also a value closed over by a caller's `jit`. A limit that a check computes from such
  values (a profile's largest radius) is read with `concrete_float`: inside a `jit` trace JAX
  stages every operation, even on concrete arrays, and `float()` of the result fails.
- **Traced checks** (`Constraint.ok`, `times_ok`, `plausible`): boolean arrays computed inside
  the compiled program, one per batch lane under `vmap`. The entry functions fold them into
  their `.result` (`throw=False`) or raise (`throw=True`) with `equinox.error_if`.
- **Guarded methods** (`guarded`): the methods of profiles and rheologies called under
  `jit`/`vmap` with invalid parameters raise at run time (they have no `.result`). Inside the
  entry functions, which report the same problems per lane, the guard is off (`unchecked`).

Every run-time check goes through `error_if`/`branched_error_if` here (not `equinox.error_if`
directly): their check survives differentiation. `equinox.error_if` passes tangents through
unchecked, so under `jax.jit(jax.grad(f))` or `jax.jit(jax.jacfwd(f))`, where the primal
output is unused, the check was removed as dead code and a bad input gave a NaN or a plausible
gradient instead of an error.

**Plausibility of units.** All inputs are SI. Values far outside the range of their unit
(`PLAUSIBLE`, e.g. a depth of 4000 m: nanometres given as metres) are reported as an error
(`ValueError` eagerly, `RESULTS.implausible_input` per lane). For unusual regimes switch the
check off with `plausibility_checks(False)` (globally, or in a `with` block); the setting is
read when an entry function is called (or traced, under a caller's `jit`).
"""

from __future__ import annotations

import contextvars
import functools
import math
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._solvers import float64_scope

__all__ = [
    "PLAUSIBLE",
    "Condition",
    "Constraint",
    "check_contact_radius",
    "check_finite",
    "check_plausible",
    "check_domain_plausible",
    "check_positive",
    "check_times",
    "branched_error_if",
    "concrete_float",
    "contact_radius_plausible",
    "contact_radius_valid",
    "domain_ok",
    "error_if",
    "domain_plausible",
    "guarded",
    "is_concrete",
    "plausibility_checks",
    "plausibility_enabled",
    "plausible",
    "times_ok",
    "unchecked",
    "without_guards",
]


def is_concrete(value) -> bool:
    """True when `value` holds real numbers (not a JAX tracer)."""
    leaves = jax.tree_util.tree_leaves(value)
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in leaves)


def concrete_float(fn) -> float:
    """`float(fn())` of a closed-form expression of concrete values, computed at once also
    inside a caller's `jit` trace, where JAX would stage its operations and `float()` could
    not read the result (`jax.ensure_compile_time_eval`). Closed-form arithmetic only: a
    nested program with run-time checks (`equinox.error_if`) misfires under it."""
    with jax.ensure_compile_time_eval():
        return float(np.asarray(fn()))


def check_finite(name: str, value, unit: str = "") -> None:
    """Raise `ValueError` if a concrete `value` contains NaN or infinity."""
    if value is None or not is_concrete(value):
        return
    arr = np.asarray(value, dtype=float)
    if not np.all(np.isfinite(arr)):
        bad = int(np.sum(~np.isfinite(arr)))
        raise ValueError(f"`{name}` [{unit}] contains {bad} non-finite value(s) (NaN or inf).")


def _interval(lo, hi, lo_open, hi_open) -> str:
    left = "(" if lo_open else "["
    right = ")" if hi_open else "]"
    lo_s = "-inf" if lo == -math.inf else f"{lo:g}"
    hi_s = "inf" if hi == math.inf else f"{hi:g}"
    return f"{left}{lo_s}, {hi_s}{right}"


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
    hi = math.inf if upper is None else upper
    Constraint(name, value, unit, lo=0.0, hi=hi, lo_open=not allow_zero).check()


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


def times_ok(ts, *, require_nonnegative: bool = False):
    """Traced counterpart of `check_times`: all finite, non-decreasing (and `ts[0] >= 0`)."""
    ok = jnp.all(jnp.isfinite(ts)) & jnp.all(ts[1:] >= ts[:-1])
    if require_nonnegative:
        ok = ok & (ts[0] >= 0)
    return ok


class Constraint(NamedTuple):
    """A parameter that must be finite and lie in an interval, for eager and traced checks.

    **Fields:** `name` (as the user writes it), `value` (array or scalar), `unit`, the bounds
    `lo`, `hi` and whether they are excluded (`lo_open`, `hi_open`); `kind`: the entry of
    `PLAUSIBLE` its plausibility is checked against (None: not checked).
    """

    name: str
    value: Any
    unit: str
    lo: float = 0.0
    hi: float = math.inf
    lo_open: bool = True
    hi_open: bool = True
    kind: str | None = None

    def describe(self) -> str:
        """`` `name` must be finite and in (lo, hi) [unit]`` (no value: a static message)."""
        return (f"`{self.name}` must be finite and in "
                f"{_interval(self.lo, self.hi, self.lo_open, self.hi_open)} [{self.unit}]")

    def ok(self):
        """Traced: every entry finite and inside the interval (a boolean scalar array)."""
        v = jnp.asarray(self.value)
        low = v > self.lo if self.lo_open else v >= self.lo
        high = v < self.hi if self.hi_open else v <= self.hi
        return jnp.all(jnp.isfinite(v) & low & high)

    def check(self) -> None:
        """Eager: raise `ValueError` (naming the value) if a concrete value violates it."""
        if self.value is None or not is_concrete(self.value):
            return
        arr = np.asarray(self.value, dtype=float)
        if not np.all(np.isfinite(arr)):
            bad = int(np.sum(~np.isfinite(arr)))
            raise ValueError(
                f"`{self.name}` [{self.unit}] contains {bad} non-finite value(s) (NaN or inf)."
            )
        low = arr > self.lo if self.lo_open else arr >= self.lo
        high = arr < self.hi if self.hi_open else arr <= self.hi
        if not (np.all(low) and np.all(high)):
            got = arr.ravel()[0] if arr.size == 1 else arr
            interval = _interval(self.lo, self.hi, self.lo_open, self.hi_open)
            raise ValueError(f"`{self.name}` must lie in {interval} [{self.unit}]; got {got}.")


class Condition(NamedTuple):
    """A requirement that is not an interval (e.g. a table increasing strictly), for traced
    checks; `holds` is a boolean (array). Eagerly the owner raises its own detailed message;
    `check` is the fallback."""

    description: str
    holds: Any

    def describe(self) -> str:
        return self.description

    def ok(self):
        return jnp.all(jnp.asarray(self.holds))

    def check(self) -> None:
        if is_concrete(self.holds) and not bool(np.all(np.asarray(self.holds))):
            raise ValueError(self.description + ".")


# --------------------------------------------------------------------------------------
# run-time errors that survive differentiation
# --------------------------------------------------------------------------------------


def error_if(x, pred, msg: str):
    """`x` unchanged, with a run-time check that raises `msg` where `pred` holds (any lane
    under `vmap`), like `equinox.error_if`, but also under `jax.grad`/`jax.jacfwd` inside
    `jit` (see `branched_error_if`)."""
    return branched_error_if(x, pred, 0, (msg,))


def branched_error_if(x, pred, index, msgs):
    """As `equinox.branched_error_if` (raise `msgs[index]` where `pred`), with the check
    also attached to the tangents: the tangent of every floating leaf of `x` is multiplied
    by `1 + z`, where `z` is a zero computed behind the same check from the primal values.
    A derivative (forward or reverse mode) therefore depends on the check, which is no
    longer removed as dead code when only the derivative is used; the tangent map stays
    linear (a product with a primal value), so `grad`, `jacfwd`, `jacrev` and `vmap` compose.
    """
    return _checked(x, pred, index, msgs=tuple(msgs))


@eqx.filter_custom_jvp
def _checked(x, pred, index, *, msgs):
    return eqx.branched_error_if(x, pred, index, msgs)


@_checked.def_jvp
def _checked_jvp(primals, tangents, *, msgs):
    x, pred, index = primals
    tx = tangents[0]
    out, zero = eqx.branched_error_if((x, jnp.zeros(())), pred, index, msgs)

    def gate(t):
        if t is None:
            return None
        return t * (1 + zero).astype(t.dtype)

    return out, jax.tree_util.tree_map(gate, tx, is_leaf=lambda t: t is None)


# --------------------------------------------------------------------------------------
# guarded methods of profiles and rheologies
# --------------------------------------------------------------------------------------

_UNCHECKED = contextvars.ContextVar("jaxcontact_unchecked", default=False)


class unchecked:  # noqa: N801 - used like a function: `with unchecked(): ...`
    """Context in which `guarded` methods do not add their run-time check (used by the
    entry functions while they trace: they report invalid parameters in `.result`)."""

    def __enter__(self):
        self._token = _UNCHECKED.set(True)
        return self

    def __exit__(self, *exc):
        _UNCHECKED.reset(self._token)
        return False


def without_guards(fn):
    """`fn` run (and traced) with the run-time checks of `guarded` methods off, for callers
    whose parameters are valid by construction (a fit's values lie within its bounds): its
    compiled program then holds no host callback, so JAX's persistent compilation cache
    can keep it and a GPU runs it without a round trip to the host. Invalid values give NaN
    or meaningless numbers instead of an error."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with unchecked():
            return fn(*args, **kwargs)

    return wrapper


def domain_ok(obj):
    """Traced: every `Constraint` of `obj.domain()` holds (a boolean scalar array)."""
    ok = jnp.asarray(True)
    for constraint in obj.domain():
        ok = ok & constraint.ok()
    return ok


def domain_plausible(obj):
    """Traced: every `Constraint` of `obj.domain()` with a `kind` is plausible."""
    ok = jnp.asarray(True)
    for c in obj.domain():
        if getattr(c, "kind", None) is not None:
            ok = ok & plausible(c.value, c.kind)
    return ok


def check_domain_plausible(obj) -> None:
    """Eager: `check_plausible` on every `Constraint` of `obj.domain()` with a `kind`."""
    for c in obj.domain():
        if getattr(c, "kind", None) is not None:
            check_plausible(c.name, c.value, c.kind)


def domain_message(obj) -> str:
    """Static message listing the domain of `obj`'s parameters."""
    parts = "; ".join(c.describe() for c in obj.domain())
    return f"{type(obj).__name__}: invalid parameter: {parts}."


def guarded(method):
    """Decorate a method of a class with `domain()` (profiles, rheologies): when the object
    holds traced values (under `jit`/`vmap`) the result carries a run-time check of the
    domain (`equinox.error_if`, the message names every parameter and its range); concrete
    objects were checked when they were built, and the entry functions switch the guard off
    (`unchecked`) because they report the same problem in `.result`. The method runs in
    `float64_scope` (float64 inputs stay float64 whatever the caller's `jax_enable_x64`)."""

    @functools.wraps(method)
    @float64_scope
    def wrapper(self, *args, **kwargs):
        if _UNCHECKED.get() or is_concrete(self):
            return method(self, *args, **kwargs)
        with unchecked():  # one check, on the outermost call
            out = method(self, *args, **kwargs)
            ok = domain_ok(self)
        return error_if(out, jnp.logical_not(ok), domain_message(self))

    return wrapper


# --------------------------------------------------------------------------------------
# plausibility of units
# --------------------------------------------------------------------------------------

#: Plausible ranges of the inputs by kind, `(low, high, unit)`: a value outside is most
#: likely given in other units (all inputs are SI). Lengths include depths, radii and
#: displacement amplitudes; moduli all shear moduli; times relaxation times and sample
#: times.
PLAUSIBLE: dict[str, tuple[float, float, str]] = {
    "length": (1e-12, 1.0, "m"),
    "modulus": (1e-3, 1e13, "Pa"),
    "viscosity": (1e-6, 1e25, "Pa s"),
    "time": (1e-12, 1e12, "s"),
    "work_of_adhesion": (1e-12, 10.0, "J/m^2"),
    "velocity": (1e-15, 1e3, "m/s"),
    "stiffness": (1e-6, 1e12, "N/m"),
}

_PLAUSIBILITY_SESSION = [True]  # the session-wide setting (every thread reads it)
_PLAUSIBILITY_BLOCK: contextvars.ContextVar[bool | None] = contextvars.ContextVar(
    "jaxcontact_plausibility", default=None)  # a `with` block's setting (this context only)


class plausibility_checks:  # noqa: N801 - used like a function
    """Switch the plausibility checks of units on or off.

    `jaxcontact.plausibility_checks(False)` switches them off for the rest of the session
    (in every thread); `with jaxcontact.plausibility_checks(False): ...` only inside the
    block, and only for the code running in it (a context variable: other threads, and
    threads started inside the block, keep the session's setting). The checks compare
    every input of the entry functions (`retract`, `simulate`, `pull_off`, the elastic
    relations) with `PLAUSIBLE` (lengths 1e-12–1 m, moduli 1e-3–1e13 Pa, viscosities
    1e-6–1e25 Pa s, times 1e-12–1e12 s, Δγ 1e-12–10 J/m², speeds 1e-15–1e3 m/s, spring
    stiffnesses 1e-6–1e12 N/m; zero never counts as implausible) and report a value
    outside as an error (most likely a unit mistake: e.g. nanometres given as metres).
    The setting is read when an entry function runs (or is traced under a caller's
    `jit`: a compiled program keeps the setting it was traced with).
    """

    def __init__(self, enabled: bool):
        self._enabled = bool(enabled)
        self._previous = _PLAUSIBILITY_SESSION[0]
        self._token = None
        _PLAUSIBILITY_SESSION[0] = self._enabled

    def __enter__(self):
        # a block: the session's setting stays as it was, the block's lives in the context
        _PLAUSIBILITY_SESSION[0] = self._previous
        self._token = _PLAUSIBILITY_BLOCK.set(self._enabled)
        return self

    def __exit__(self, *exc):
        _PLAUSIBILITY_BLOCK.reset(self._token)
        return False


def plausibility_enabled() -> bool:
    """Whether the plausibility checks of units are on (see `plausibility_checks`)."""
    block = _PLAUSIBILITY_BLOCK.get()
    return _PLAUSIBILITY_SESSION[0] if block is None else block


def _plausible_message(name, kind) -> str:
    lo, hi, unit = PLAUSIBLE[kind]
    return (f"`{name}` lies outside the plausible range [{lo:g}, {hi:g}] {unit} of a "
            f"{kind.replace('_', ' ')}")


def check_plausible(name: str, value, kind: str, *, magnitude: bool = False) -> None:
    """Eager: raise `ValueError` if a concrete `value` lies outside `PLAUSIBLE[kind]` (with
    `magnitude`, only its largest absolute value is checked; zeros and non-finite values
    pass, the latter being the domain checks' business). No-op when the checks are off."""
    if not plausibility_enabled() or value is None:
        return
    if isinstance(value, float | int | np.floating | np.integer) and not isinstance(value, bool):
        # a concrete number plainly inside the range: done (per curve of a map)
        lo, hi, _ = PLAUSIBLE[kind]
        v = abs(float(value))
        if v <= hi if magnitude else lo <= v <= hi:
            return
    elif isinstance(value, np.ndarray):
        # concrete; plainly inside the range: done (the common case, per curve of a map)
        lo, hi, _ = PLAUSIBLE[kind]
        arr = np.abs(value.astype(float, copy=False))
        if arr.size and (arr.max() <= hi if magnitude else lo <= arr.min() and arr.max() <= hi):
            return
    elif not is_concrete(value):
        return
    arr = np.abs(np.asarray(value, dtype=float)).ravel()
    arr = arr[np.isfinite(arr) & (arr != 0)]
    if arr.size == 0:
        return
    lo, hi, unit = PLAUSIBLE[kind]
    if magnitude:
        bad = arr.max() > hi
        got = arr.max()
    else:
        bad = not (np.all(arr >= lo) and np.all(arr <= hi))
        got = arr.ravel()[np.argmax((arr < lo) | (arr > hi))] if bad else None
    if bad:
        raise ValueError(
            f"{_plausible_message(name, kind)} (got {got:g} {unit}): is it in other units? "
            "All inputs are SI. If the value is right, switch the check off with "
            "`jaxcontact.plausibility_checks(False)`."
        )


def plausible(value, kind: str, *, magnitude: bool = False):
    """Traced: `value` (every entry; with `magnitude` its largest absolute value) lies in
    `PLAUSIBLE[kind]`; zeros and non-finite entries pass (the latter are left to the domain
    checks)."""
    lo, hi, _ = PLAUSIBLE[kind]
    v = jnp.abs(jnp.asarray(value))
    skip = jnp.logical_not(jnp.isfinite(v)) | (v == 0)
    if magnitude:
        return jnp.all(skip | (v <= hi))
    return jnp.all(skip | ((v >= lo) & (v <= hi)))


# --------------------------------------------------------------------------------------
# showing values: error messages, constructor fields, reprs
# --------------------------------------------------------------------------------------


def plain(value) -> str:
    """`value` as an error message shows it: a NumPy or JAX scalar as a plain number
    (``1.0``, not ``np.float64(1.0)``), a tuple, list or small array as a list of plain
    numbers, a tracer by its shape and dtype, anything else as its `repr`."""
    if isinstance(value, jax.core.Tracer):
        return f"<traced {value.dtype}{list(value.shape)}>"
    if isinstance(value, bool | np.bool_):
        return repr(bool(value))
    if isinstance(value, np.generic | np.ndarray | jax.Array):
        arr = np.asarray(value)
        if arr.dtype.kind in "biufc":
            if arr.ndim == 0:
                return repr(arr.item())
            if arr.size <= 8:
                return repr(arr.tolist())
            return (f"array of shape {arr.shape} ({arr.dtype}), from {arr.ravel()[0].item()!r} "
                    f"to {arr.ravel()[-1].item()!r}")
        return repr(value)
    if isinstance(value, tuple | list):
        inner = ", ".join(plain(v) for v in value)
        return f"({inner}{',' if len(value) == 1 else ''})" if isinstance(value, tuple) \
            else f"[{inner}]"
    return repr(value)


def float_field(name: str, unit: str, *, arms: bool = False):
    """The converter of a module field that holds a real number (`arms`: a 1-D array of
    them): the value as a float array (`jaxcontact._solvers.as_float`; integers become the
    default float, float32 stays float32), or a `TypeError` naming the field, its unit and
    the value when it is not a number (a string, None, an object); tracers pass."""
    from ._solvers import as_float

    def convert(x):
        try:
            out = as_float(x)
        except (TypeError, ValueError):
            what = "1-D array of real numbers" if arms else "real number"
            raise TypeError(f"`{name}` must be a {what} [{unit}]; got {plain(x)} "
                            f"({type(x).__name__}).") from None
        return jnp.atleast_1d(out) if arms else out

    return convert


def module_repr(module) -> str:
    """``Name(field=value, ...)`` of a rheology or profile with the values themselves
    (``StandardModel(G0=1000000.0, ...)``; equinox shows ``G0=weak_f64[]``): scalars as
    numbers, small arrays as lists, large arrays and tracers by shape and dtype."""
    import dataclasses

    parts = []
    for f in dataclasses.fields(module):
        if not f.repr:
            continue
        value = getattr(module, f.name, None)
        if isinstance(value, eqx.Module):
            text = repr(value)
        elif isinstance(value, jax.core.Tracer) or (
                isinstance(value, jax.Array | np.ndarray) and np.size(value) > 8):
            text = eqx.tree_pformat(value)
        else:
            text = plain(value)
        parts.append(f"{f.name}={text}")
    return f"{type(module).__name__}({', '.join(parts)})"
# validity of a contact radius computed from the inputs
# --------------------------------------------------------------------------------------


def contact_radius_valid(profile, a):
    """Traced: no entry of the contact radius `a` [m] beyond `profile.valid_radius` (a
    Parabola's `R`, a bounded shape's edge); NaN entries pass (other checks report them).

    Part of the plausibility checks: `plausibility_checks(False)` switches it off (always
    True), as the fitting objective does while it searches (a start whose paraboloid
    contact passes R is a point of the search, not a result; the fit's report checks the
    result against the profile's limit)."""
    if not plausibility_enabled():
        return jnp.asarray(True)
    return jnp.all(jnp.logical_not(jnp.asarray(a) > profile.valid_radius))


def contact_radius_plausible(a):
    """Traced: the contact radius `a` [m] (its largest entry) is a plausible length
    (`PLAUSIBLE["length"]`): a profile so flat that the contact would be kilometres wide (a
    Cone with half-angle near pi/2, a PowerLaw with a tiny prefactor) is a unit mistake as
    surely as a Parabola with `R` = 1e29 m."""
    return plausible(a, "length", magnitude=True)


def check_contact_radius(profile, a, source: str) -> None:
    """Eager: `ValueError` if a concrete contact radius `a` [m], computed from `source` (the
    inputs that set it, e.g. "`depth` = 0.004 m"), exceeds `profile.valid_radius` or (with
    the plausibility checks on) the plausible range of a length."""
    if not (is_concrete(a) and is_concrete(profile)):
        return
    arr = np.asarray(a, dtype=float).ravel()
    arr = arr[np.isfinite(arr)]
    if arr.size == 0:
        return
    got = float(arr.max())
    limit = concrete_float(lambda: profile.valid_radius)
    name = type(profile).__name__
    if got > limit and plausibility_enabled():
        what = ("radius `R`" if math.isfinite(limit) and hasattr(profile, "R")
                else "`valid_radius`")
        raise ValueError(
            f"{source} gives a contact radius of {got:g} m, beyond the {name}'s {what} "
            f"{limit:g} m, the largest contact radius it describes (a paraboloid stands for a "
            "sphere: no sphere contact reaches a > R). Indent less, or use a larger indenter."
        )
    lo, hi, unit = PLAUSIBLE["length"]
    if plausibility_enabled() and got > hi:
        raise ValueError(
            f"{source} gives a contact radius of {got:g} m with the {name}, outside the "
            f"plausible range [{lo:g}, {hi:g}] {unit} of a length: is a parameter of the "
            "profile in other units (a Cone's `half_angle` near pi/2, a PowerLaw's `c` far "
            "too small)? If the values are right, switch the check off with "
            "`jaxcontact.plausibility_checks(False)`."
        )
