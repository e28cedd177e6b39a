"""The input checks of the forward entry functions, one list for both layers.

An entry function (`simulate`, `retract`) describes the requirements on its inputs once,
as a list of `Requirement` built by one function of the inputs, and calls that function
twice: eagerly on the caller's values (`check_eagerly`: a `ValueError` naming the input,
when the value is concrete) and inside its compiled program on the traced, cast values
(`fold_checks`: the first failing requirement, in the list's order, becomes the lane's
`.result`; a lane with invalid input gets NaN fields).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import equinox as eqx
import jax.numpy as jnp

from ._solution import fold_results, nan_where, raise_if_error
from ._validate import (
    Constraint,
    check_domain_plausible,
    check_plausible,
    domain_ok,
    domain_plausible,
    plausible,
)

__all__ = ["Requirement", "constraint", "domain", "domain_plausibility", "plausibility",
           "check_eagerly", "traced_checks", "fold_checks"]


class Requirement(NamedTuple):
    """One requirement on an entry function's inputs.

    **Fields:** `ok` (traced: a boolean scalar array, True where it holds; `None`: checked
    eagerly only, e.g. a static shape), `item` (the `RESULTS` item of a lane that fails it),
    `check` (eager: raises `ValueError` naming the input if a concrete value fails; `None`:
    checked when the value was made, e.g. the domain of a rheology or profile),
    `eager_first` (checked eagerly before the others, whatever its place in the list: the
    sampled arrays, whose message names the array a bad derived value comes from).
    """

    ok: Callable[[], Any] | None
    item: Any
    check: Callable[[], None] | None = None
    eager_first: bool = False


def constraint(c: Constraint, item) -> Requirement:
    """The `Requirement` of a `Constraint` (finite, inside its interval)."""
    return Requirement(c.ok, item, c.check)


def domain(obj, item) -> Requirement:
    """The `Requirement` that the `Constraint`s of `obj.domain()` hold (a rheology, profile,
    loading or grid: checked eagerly when it was made)."""
    return Requirement(lambda: domain_ok(obj), item)


def domain_plausibility(obj, item) -> Requirement:
    """The `Requirement` that the parameters of `obj.domain()` are plausible in their units."""
    return Requirement(lambda: domain_plausible(obj), item,
                       lambda: check_domain_plausible(obj))


def plausibility(name: str, value, kind: str, item, *, magnitude: bool = False
                 ) -> Requirement:
    """The `Requirement` that `value` is plausible as a `kind` (`check_plausible`,
    `plausible`)."""
    return Requirement(lambda: plausible(value, kind, magnitude=magnitude), item,
                       lambda: check_plausible(name, value, kind, magnitude=magnitude))


def check_eagerly(requirements) -> None:
    """Eager: each requirement's `check`, in order, those `eager_first` first (the first
    failing one raises)."""
    for r in sorted(requirements, key=lambda r: not r.eager_first):
        if r.check is not None:
            r.check()


def traced_checks(requirements) -> list:
    """Traced: the `(ok, RESULTS item)` pairs of the requirements, in order of precedence."""
    return [(r.ok(), r.item) for r in requirements if r.ok is not None]


def fold_checks(sol, checks, *, throw: bool = False):
    """`sol` (a `ContactSolution`) with the first failing check of `checks` (`(ok, RESULTS
    item)` pairs in order of precedence) as its `.result`; with `throw`, raising on an error
    result (whichever field is read), otherwise with NaN fields on a lane with invalid input
    (not numbers that look plausible)."""
    inputs_ok = jnp.asarray(True)
    for ok, _ in checks:
        inputs_ok = inputs_ok & ok
    result = fold_results(sol.result, checks)
    sol = eqx.tree_at(lambda s: s.result, sol, result)
    if throw:
        return raise_if_error(sol, result)
    return nan_where(jnp.logical_not(inputs_ok), sol)
