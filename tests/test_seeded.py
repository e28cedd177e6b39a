"""`jaxcontact._sharding.seeded`: a loop's initial carry with the same values, batched and
carrying tangents wherever its dependencies are, so that JAX's fixed point over which
elements of a loop's carry are batched ends after one rewrite of the loop's body per
``vmap`` (counted by the batching rule of a ``custom_vmap`` inside the body), with the same
values and derivatives."""

import collections

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.custom_batching import custom_vmap

from jaxcontact._sharding import seeded


def test_seeded_carry_holds_the_same_values():
    carry = (jnp.zeros(3), jnp.asarray(jnp.inf), jnp.asarray(-2.5), jnp.asarray(True),
             jnp.asarray(7, jnp.int32), jnp.ones(2, jnp.float32))
    for deps in ((jnp.asarray(3.0), jnp.arange(4.0)), (jnp.asarray(jnp.nan), jnp.inf),
                 (jnp.asarray(-1e300), jnp.asarray(1e300), jnp.full(3, 1e308)),
                 jnp.full(4, 3e38, jnp.float32), ("a name", None, 2.0, True)):
        out = seeded(carry, deps)
        for a, b in zip(out, carry, strict=True):
            assert a.dtype == b.dtype and a.shape == b.shape
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def _scan_counted(counts):
    """A scan whose carry starts at constants and depends on the lane's `p` from the
    second step on; the body's batching rewrites counted."""

    @custom_vmap
    def mark(x):
        return x

    @mark.def_vmap
    def _rule(axis_size, in_batched, x):
        del axis_size
        counts["rewrites"] += 1
        return x, in_batched[0]

    def f(p, seed):
        def body(c, x):
            a, b = c
            return (mark(b * x), a + p * x), a

        init = (jnp.zeros(()), jnp.zeros(()))
        if seed:
            init = seeded(init, p)
        return lax.scan(body, init, jnp.arange(1.0, 5.0))

    return f


def test_seeded_loop_is_rewritten_once_per_vmap_with_the_same_values_and_derivatives():
    counts = collections.Counter()
    f = _scan_counted(counts)
    ps = jnp.linspace(0.5, 2.0, 5)
    outs = {}
    for seed in (False, True):
        counts.clear()
        fn = jax.vmap(lambda p, s=seed: jax.jvp(lambda q: f(q, s), (p,), (jnp.ones_like(p),)))
        outs[seed] = jax.jit(fn)(ps)
        # zeros at the start: batched after the first step, so JAX rewrites the body twice
        # to learn it; seeded, once
        assert counts["rewrites"] == (1 if seed else 2)
    leaves = jax.tree_util.tree_leaves
    for a, b in zip(leaves(outs[True]), leaves(outs[False]), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # against the loop written out, and its derivative by central differences
    p, h = 1.3, 1e-6

    def written(q):
        a = b = 0.0
        for x in range(1, 5):
            a, b = b * x, a + q * x
        return a, b

    (a, b), _ = f(jnp.asarray(p), True)
    np.testing.assert_allclose([a, b], written(p), rtol=1e-15)
    _, (da, db) = jax.jvp(lambda q: f(q, True)[0], (jnp.asarray(p),), (jnp.asarray(1.0),))
    fd = (np.asarray(written(p + h)) - np.asarray(written(p - h))) / (2 * h)
    np.testing.assert_allclose([da, db], fd, rtol=1e-8)
