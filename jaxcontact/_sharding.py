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

**Branches.** In explicit mode jax 0.10's batching rule of ``lax.cond``/``lax.switch``
inside a loop re-types the branches' outputs on an empty mesh and fails the same way.
`switch` and `cond` evaluate every branch and select the taken one elementwise
(``lax.select_n``) under a mesh with explicit axes: what ``vmap`` does anyway with a
per-lane predicate (its batching rule turns the branch into a select of all branches), so a
vmapped program computes the same values at the same cost. Branches must therefore be safe
to evaluate when not taken (they are: every caller is vmapped by the sweeps and fits).

**Constants from outside the mesh, nested programs, Python scalars.** An array the caller's
program closed over (a time grid made before ``jax.set_mesh``) has no mesh; jax 0.10 cannot
batch a lane-dependent operation of it inside a loop. `on_mesh` replicates such arrays on
the context mesh at an entry point (the same values); `compiled` traces an entry point's
body into the caller's program instead of calling its own nested ``jit``, whose batching
rule fails the same way; a ``jnp.where`` with a bare Python scalar inside a scanned branch
does too (``lax.select`` with an array of the same type is used there).

**Branches under `vmap` that only run where some lane takes them.** Outside explicit
mode, `switch` and `cond` run each branch inside a ``lax.cond`` whose predicate is "some lane
of the batch takes this branch" (`any_lane`: a ``custom_vmap`` whose batching rule reduces
the predicate over the vmapped axis, so that the result is not batched and the
``lax.cond`` stays a conditional under every ``vmap`` above it), then select per lane as
``vmap`` does. Every lane gets the value of its own branch, as with ``lax.switch``; only
the work of branches that no lane takes is skipped. Unbatched, one branch runs. A branch
run for another lane's sake passes no derivative to a lane that does not take it (its
inputs, closed-over values included, through ``where(taken, x, stop_gradient(x))``): it
may have infinite derivatives there (a square root at 0), and in reverse mode its zero
cotangent times those would be a NaN added to that lane's gradient. Why all this: the
foundation model's step has three branches (pinned, advancing, receding front), and under
``vmap`` ``lax.switch`` computes all three for every lane at every sample, while the lanes
of a fit or a sweep mostly take the same one (the front advances on the approach and
recedes on the lift); measured (``benchmarks/results/fit_each.md``, "Branches that no lane
takes"): the fitting's full-history Jacobian 1.5–1.8× faster a lane, `simulate`'s 2.2×,
full-history sweeps 2.2–2.7×, the same values to round-off. In a program sharded over
several devices in automatic mode the predicate is reduced over all of them (a collective a
branch and time step); `jc.sweep` therefore runs each device's slice as a ``shard_map``.
``JAXCONTACT_LANE_BRANCHES=0`` (read at import) restores ``lax.switch`` (the baseline of
the benchmarks; tests: ``tests/test_branches.py``).

**Forward mode only.** The masks that keep a branch's infinite derivatives off the lanes
that do not take it matter in reverse mode only (in forward mode the select of the outputs
drops those lanes' tangents), and cost a select per input and tangent direction (~9 % of
the full-history Jacobian of a fit). Inside `forward_only()` the branches traced leave them
out; a caller uses it around a trace that it differentiates in forward mode only (the
fitting objective's Jacobian). `compiled` then returns the entry point's forward-mode
twin, which traces the entry point's body into the caller's program (no nested ``jit``,
so no cached program without the masks reaches a later trace that is differentiated in
reverse mode) and, called with concrete arguments, runs its own nested program with its
own cache (a distinct function object). Traced inline, the fitting's Jacobian is
transformed by one rule less per ``vmap`` and ``jvp`` above it: the search program of
the README main job traces in ~1 s less (``benchmarks/results/fit.md``, "The search
program traced in half the time").

With these, `retract`, `simulate`, `bem_simulate` and the elastic functions run inside
``jit(vmap(...))`` over inputs sharded in either axis mode (`tests/test_sharding.py`).
"""

import contextlib
import contextvars
import functools
import os

import equinox as eqx
import jax
import jax.numpy as jnp
from jax import lax
from jax.custom_batching import custom_vmap

from ._validate import is_concrete

__all__ = ["any_lane", "compiled", "cond", "forward_only", "on_mesh", "pick", "scan",
           "searchsorted", "seeded", "switch", "while_loop"]

#: `switch` and `cond` skip the branches no lane takes (module docstring); ``0`` in the
#: environment variable ``JAXCONTACT_LANE_BRANCHES`` at import: plain ``lax.switch``.
LANE_BRANCHES = os.environ.get("JAXCONTACT_LANE_BRANCHES", "1") != "0"


_FORWARD_ONLY = contextvars.ContextVar("jaxcontact_forward_only", default=False)


@contextlib.contextmanager
def forward_only():
    """Within: what is traced is differentiated in forward mode only (module docstring):
    `switch` and `cond` leave out their reverse-mode masks, `compiled` returns the entry
    points' forward-mode twins."""
    token = _FORWARD_ONLY.set(True)
    try:
        yield
    finally:
        _FORWARD_ONLY.reset(token)


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


def _tie(carry, *others):
    """`carry` with every element tied to all elements of `carry` and `others` (module
    docstring): the same values, batched alike."""
    leaves, tree = jax.tree_util.tree_flatten(carry)
    arrays = [jnp.asarray(x) for x in leaves]
    anchor = jnp.zeros((), bool)
    for x in arrays + [jnp.asarray(y) for y in jax.tree_util.tree_leaves(others)]:
        anchor = anchor | jnp.any(x != x)  # one boolean per lane, always False
    return jax.tree_util.tree_unflatten(tree, [jnp.where(anchor, x, x) for x in arrays])


def seeded(carry, deps):
    r"""`carry` (a loop's initial carry) with the same values, but batched and carrying
    tangents wherever `deps` (the values the loop's lanes differ by and are differentiated
    with respect to) are: every floating element plus $z$, every other element selected by
    $z = z$, with $z = \sum 0\cdot x$ over the finite elements $x$ of `deps` (exactly 0,
    whatever their size).

    Under ``vmap`` and ``jvp`` JAX finds which elements of a loop's carry are batched, or
    carry a non-zero tangent, by a fixed point: it rewrites the loop's body with the
    initial carry's pattern, learns which outputs came out batched (non-zero), and rewrites
    it again until nothing changes. A carry that starts as constants (zeros: the unloaded
    sample) and becomes lane-dependent after a step or two costs two or three rewrites of the
    whole body per transformation, every nested loop and branch included. Seeded, the
    first rewrite is the last. For a carry that depends on `deps` after the first steps
    anyway (the history loop's state) the compiled program is the same but for the seed's
    few operations; an element that would have stayed without a tangent (a time) gets a
    zero one."""
    zero = jnp.zeros((), jnp.result_type(float))
    for x in jax.tree_util.tree_leaves(deps):
        if not eqx.is_array_like(x):  # (a name, a flag of a module: not a value)
            continue
        x = jnp.asarray(x)
        if jnp.issubdtype(x.dtype, jnp.inexact):
            x = jnp.real(x)
            zero = zero + jnp.sum(0.0 * jnp.where(jnp.isfinite(x), x, 0.0)).astype(zero.dtype)
    same = zero == zero  # True, batched as `deps` are

    def seed(x):
        x = jnp.asarray(x)
        if jnp.issubdtype(x.dtype, jnp.inexact):
            return x + zero.astype(x.dtype)
        return jnp.where(same, x, x)

    return jax.tree_util.tree_map(seed, carry)


def while_loop(cond_fun, body_fun, init_val):
    """`jax.lax.while_loop` with every element of the initial carry tied to the others
    (module docstring): same arguments, same result."""
    if not _explicit_mesh():
        return lax.while_loop(cond_fun, body_fun, init_val)
    return lax.while_loop(cond_fun, body_fun, _tie(init_val))


def scan(f, init, xs=None, length=None, *, tie=()):
    """`jax.lax.scan` with every element of the initial carry tied to the others, to the
    scanned inputs and to `tie` (the values the body closes over that make the carry differ
    between lanes; module docstring): same arguments, same result."""
    if not _explicit_mesh():
        return lax.scan(f, init, xs, length=length)
    return lax.scan(f, _tie(init, xs, tie), xs, length=length)




@custom_vmap
def any_lane(flag):
    """`flag` (a boolean array); under ``vmap``, whether it holds on any lane of the batch
    (and of every batch above), not batched (module docstring). Not differentiable (a
    boolean)."""
    return flag


@any_lane.def_vmap
def _any_lane_rule(axis_size, in_batched, flag):
    del axis_size
    (batched,) = in_batched
    return any_lane(jnp.any(flag, axis=0) if batched else flag), False


def switch(index, branches, *operands, masked: bool = True):
    """`jax.lax.switch` (same arguments, same result per lane; `index` clamped to the
    branches as there). Under ``vmap`` a branch runs only where some lane takes it, then
    each lane's own branch is selected; under a mesh with explicit axes every branch is
    evaluated and the taken one selected (module docstring). `masked=False`: the branches'
    inputs keep their derivatives on the lanes that do not take them (one select less per
    input and tangent direction), for branches whose derivatives are finite on every lane
    (what a select of all branches, ``vmap``'s own rule, requires of them anyway)."""
    which = jnp.clip(jnp.asarray(index, jnp.int32), 0, len(branches) - 1)
    if not _explicit_mesh():
        if not LANE_BRANCHES:
            return lax.switch(which, branches, *operands)
        outs = [_lane_branch(which == k, branch, operands, masked) for k, branch in
                enumerate(branches)]
    else:
        outs = [branch(*operands) for branch in branches]
    return jax.tree.map(lambda *xs: lax.select_n(which, *xs), *outs)


def _lane_branch(taken, branch, operands, masked=True):
    """`branch(*operands)` where some lane takes it (`taken`, per lane), zeros elsewhere
    (module docstring). The branch's inputs, the values it closes over included
    (``jax.closure_convert``), carry no derivative on a lane that does not take it: a
    branch evaluated for another lane's sake may have infinite derivatives where it is
    not taken (a square root at 0), and in reverse mode its zero cotangent times those
    would be a NaN added to the lane's gradient (the select of the outputs keeps it out of
    the values and of forward-mode derivatives)."""
    converted, consts = jax.closure_convert(branch, *operands)

    def no_derivative_off_lane(x):
        x = jnp.asarray(x)
        if not jnp.issubdtype(x.dtype, jnp.inexact):
            return x
        return jnp.where(taken, x, lax.stop_gradient(x))

    args = (operands, list(consts))
    if masked and not _FORWARD_ONLY.get():
        args = jax.tree.map(no_derivative_off_lane, args)

    def run(a):
        return converted(*a[0], *a[1])

    shapes = jax.eval_shape(run, args)

    def skipped(_):
        return jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)

    return lax.cond(any_lane(lax.stop_gradient(taken)), run, skipped, args)


def cond(pred, true_fun, false_fun, *operands, masked: bool = True):
    """`jax.lax.cond` (same arguments, same result per lane), as `switch`: under ``vmap`` a
    branch runs only where some lane takes it; under a mesh with explicit axes both
    branches are evaluated and the taken one selected (module docstring). `masked`: as
    `switch`'s."""
    if not _explicit_mesh() and not LANE_BRANCHES:
        return lax.cond(pred, true_fun, false_fun, *operands)
    return switch(jnp.asarray(pred).astype(jnp.int32), (false_fun, true_fun), *operands,
                  masked=masked)


def searchsorted(a, v, side="left"):
    """`jnp.searchsorted` (same result); under a mesh with explicit axes by comparing `v`
    with every element of `a` (``method="compare_all"``: elementwise, O(len(a)) per value)
    instead of the default bisection, a ``lax.scan`` whose carry JAX's batching rule
    re-types on an empty mesh."""
    if not _explicit_mesh():
        return jnp.searchsorted(a, v, side=side)
    return jnp.searchsorted(a, v, side=side, method="compare_all")


_FORWARD_TWINS: dict = {}


def compiled(jitted, plain):
    """The function to call: `jitted` (``eqx.filter_jit(plain)``: its own compiled program,
    cached), except

    - inside a trace under a mesh with explicit axes: `plain`, traced into the caller's
      program (the same operations; jax 0.10's batching rule of a nested ``jit`` re-types
      its outputs on an empty mesh there);
    - inside `forward_only`: `plain` traced into the caller's program when the call's
      arguments are traced, the entry point's forward-mode twin when they are concrete
      (module docstring)."""
    if _explicit_mesh():
        return plain
    if not _FORWARD_ONLY.get():
        return jitted
    twin = _FORWARD_TWINS.get(plain)
    if twin is None:  # a new function object: jit caches its traces apart from `jitted`'s
        jit_twin = eqx.filter_jit(functools.wraps(plain)(lambda *a, **k: plain(*a, **k)))

        @functools.wraps(plain)
        def twin(*args, **kwargs):
            return (jit_twin if is_concrete((args, kwargs)) else plain)(*args, **kwargs)

        twin = _FORWARD_TWINS.setdefault(plain, twin)
    return twin


def on_mesh(tree):
    """`tree` with every array leaf that lives outside the context mesh (a constant the
    caller's program closed over, created before ``jax.set_mesh``) replicated on that mesh
    (``jax.sharding.reshard(x, P())``), under a mesh with explicit axes; elsewhere `tree`
    unchanged. The values are the same; jax 0.10 cannot batch a lane-dependent operation
    of such a constant inside a loop (``Resource axis ... not found in mesh: ()``)."""
    if not _explicit_mesh():
        return tree

    def put(x):
        if not isinstance(x, jax.Array):
            return x
        if not jax.typeof(x).sharding.mesh.empty:
            return x
        return jax.sharding.reshard(x, jax.sharding.PartitionSpec())

    return jax.tree_util.tree_map(put, tree)
