"""Helpers of the host path (numpy, per curve of a map): equinox modules built from their
fields without `__init__` (:func:`rebuild`), and a value computed once per object
(:func:`once_per_object`).

The preparation of a force map builds a :class:`fitting.CurveBatch` and a
:class:`fitting.Parameterisation` per curve; an equinox module's construction (its
`__init__` with equinox's checks, 60-120 µs) was a tenth of that work. A pytree's
unflattening is the documented way of building a module from its fields without
`__init__` (JAX does it at every transformation); the fields given are the ones the
checked construction would store (the callers build each module once the checked way
and compare, :func:`rebuild`'s template).
"""

from __future__ import annotations

import functools

import jax

__all__ = ["rebuild", "once_per_object"]

#: Objects :func:`once_per_object` keeps per function (a map shares one profile and one
#: model spec; more means other fits).
_KEPT = 64


def once_per_object(fn):
    """`fn(obj)` computed once per object `obj` (e.g. a profile's radius read from the
    device, a model spec's parameter list): the result is kept with the object itself, so
    that the object's `id` stays its own, for at most 64 objects (then forgotten)."""
    cache: dict[int, tuple] = {}

    @functools.wraps(fn)
    def once(obj):
        hit = cache.get(id(obj))
        if hit is None or hit[0] is not obj:
            if len(cache) >= _KEPT:
                cache.clear()
            hit = cache[id(obj)] = (obj, fn(obj))
        return hit[1]

    return once

_TREEDEFS: dict = {}


def rebuild(template_of, fields: dict, key=()):
    """The equinox module `template_of(dummies)` would be with the dynamic fields `fields`
    (`{name: value}`, every dynamic field; any values, numpy or JAX arrays, any object, each
    taken as a leaf), built by unflattening.

    `template_of(values)`: builds the module the checked way from `values` (a dict of the
    same names); called once per `key` (the static fields, part of the tree's structure),
    with distinct placeholder objects, to learn the tree structure and where each field
    goes among the leaves."""
    hit = _TREEDEFS.get(key)
    if hit is None:
        marks = {name: _Mark(name) for name in fields}
        template = template_of(marks)
        leaves, treedef = jax.tree.flatten(template, is_leaf=lambda x: isinstance(x, _Mark))
        order = [leaf.name for leaf in leaves]
        if sorted(order) != sorted(marks):  # a field not stored as given: not for this path
            raise TypeError(f"rebuild: the fields {sorted(marks)} are not the module's "
                            f"leaves {order}")
        hit = _TREEDEFS[key] = (treedef, order)
    treedef, order = hit
    return jax.tree.unflatten(treedef, [fields[name] for name in order])


class _Mark:
    """A placeholder leaf (the name of the field it stands for)."""

    def __init__(self, name: str):
        self.name = name
