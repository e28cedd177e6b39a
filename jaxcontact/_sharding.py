"""Array operations that compose with a user's sharded ``jit(vmap(...))``.

JAX's explicit-axis sharding mode (``jax.make_mesh(..., axis_types=Explicit)``) refuses two
things that plain code does freely; the entry points use these helpers instead.

**Reading one element at a traced index without a gather.**

``x[i]`` with a traced `i` is a gather. Inside a user's ``jit(vmap(...))`` over sharded
inputs in JAX's explicit-axis mode, a gather of a replicated operand (a time grid shared by
every lane) at indices sharded over the batch has no unambiguous output sharding, and JAX
refuses it (``ShardingTypeError: Use .at[...].get(out_sharding=)``). `pick` reads the element
with a one-hot mask and a sum instead: elementwise operations, whose sharding follows the
inputs in every mode, exact (one term is the value, the others are zero), differentiable, at
O(n) cost per read, which the entry points using it already spend per sample. Only under a
mesh with explicit axes; elsewhere ``x[i]`` as before.

**Loops whose carry is batched from the start.** Under ``vmap`` a ``lax.while_loop`` whose
predicate depends on the lane batches every element of its carry; an element that started
unbatched (a step counter, a constant) is broadcast to the batch by the batching rule, and
in explicit mode (jax 0.10) that broadcast is made on an empty mesh and fails (``ValueError:
Resource axis: b of P('b',) is not found in mesh: ()``). `while_loop` ties every element of
the initial carry to all the others (``where(anchor, x, x)`` with one per-lane boolean of
the carry), so that all of them are batched, and sharded, alike from the first step. The
values and the loop are unchanged. Only under a mesh with explicit axes.

With these, `retract` and the elastic functions run inside ``jit(vmap(...))`` over inputs
sharded in either axis mode (`tests/test_sharding.py`). `simulate` runs in automatic mode;
in explicit mode jax 0.10's batching rule of ``lax.switch`` (the foundation's step branches)
re-types the branches' outputs on an empty mesh and fails: not yet supported there.
"""

import jax
import jax.numpy as jnp
from jax import lax

__all__ = ["pick", "while_loop"]


def _explicit_mesh() -> bool:
    """Whether the trace runs under a mesh with explicit axes (``jax.set_mesh``)."""
    mesh = jax.sharding.get_abstract_mesh()
    return not mesh.empty and bool(getattr(mesh, "explicit_axes", ()))


def pick(x, i):
    """``x[i]`` along the first axis of `x` for integer indices `i` in ``[-n, n)``.

    Shapes: `x` (n, ...), `i` any shape → ``i.shape + x.shape[1:]``; the value and dtype of
    ``x[i]``. A plain gather, except under a mesh with explicit axes, where the one-hot sum
    of the module docstring replaces it."""
    x = jnp.asarray(x)
    i = jnp.asarray(i)
    if not _explicit_mesh():
        return x[i]
    n = x.shape[0]
    i = jnp.where(i < 0, i + n, i)
    shape = i.shape + x.shape
    hit = (jnp.arange(n) == i[..., None]).reshape(i.shape + (n,) + (1,) * (x.ndim - 1))
    picked = jnp.where(jnp.broadcast_to(hit, shape), jnp.broadcast_to(x, shape),
                       jnp.zeros((), x.dtype))
    return jnp.sum(picked, axis=i.ndim)


def while_loop(cond_fun, body_fun, init_val):
    """`jax.lax.while_loop` with every element of the initial carry tied to the others
    (module docstring): same arguments, same result."""
    if not _explicit_mesh():
        return lax.while_loop(cond_fun, body_fun, init_val)
    leaves, tree = jax.tree_util.tree_flatten(init_val)
    arrays = [jnp.asarray(x) for x in leaves]
    anchor = jnp.zeros((), bool)
    for x in arrays:  # one boolean per lane that depends on every element (always False)
        anchor = anchor | jnp.any(x != x)
    tied = [jnp.where(anchor, x, x) for x in arrays]
    return lax.while_loop(cond_fun, body_fun, jax.tree_util.tree_unflatten(tree, tied))


