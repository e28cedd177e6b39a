"""Branches under ``vmap`` that run only where some lane takes them
(`jaxcontact._sharding.switch`, `cond`, `any_lane`): the value and the derivatives of every
lane are those of ``lax.switch`` on that lane alone, and a branch that no lane takes does not
run (counted by a host callback inside it)."""

import collections

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import lax

import jaxcontact as jc
from jaxcontact import _sharding
from jaxcontact._sharding import any_lane

pytestmark = pytest.mark.skipif(not _sharding.LANE_BRANCHES,
                                reason="JAXCONTACT_LANE_BRANCHES=0: plain lax.switch")


def _branches(counts=None):
    """Three branches of different smooth functions of (x, y); with `counts`, each branch
    counts its runs through a host callback (without arguments: once a run, for all lanes)."""

    def tagged(k, fn):
        def branch(x, y):
            if counts is not None:
                jax.debug.callback(lambda: counts.update([k]))
            return fn(x, y)
        return branch

    return (tagged(0, lambda x, y: (jnp.sin(x) * y, x + y)),
            tagged(1, lambda x, y: (jnp.exp(0.3 * x) - y ** 2, x * y)),
            tagged(2, lambda x, y: (jnp.log1p(x * x) + 3.0 * y, y - x)))


def test_any_lane_reduces_over_every_vmapped_axis():
    flags = jnp.array([[False, False, True], [False, False, False]])
    assert bool(any_lane(jnp.asarray(True))) and not bool(any_lane(jnp.asarray(False)))
    # one lane true: every lane of both axes reads true (the result is not batched)
    out = jax.vmap(jax.vmap(any_lane))(flags)
    np.testing.assert_array_equal(out, np.ones((2, 3), bool))
    out = jax.vmap(jax.vmap(any_lane))(jnp.zeros((2, 3), bool))
    np.testing.assert_array_equal(out, np.zeros((2, 3), bool))
    # the inner axis alone under jit
    out = jax.jit(jax.vmap(any_lane))(flags[1])
    np.testing.assert_array_equal(out, np.zeros(3, bool))


@pytest.mark.parametrize("index", [[0, 2, 2, 0, 1], [2, 2, 2, 2, 2], [-3, 7, 1, 0, 2]])
def test_switch_equals_lax_switch_per_lane_with_derivatives(index):
    index = jnp.asarray(index)
    xs = jnp.linspace(0.2, 1.4, index.size)
    ys = jnp.linspace(-0.5, 0.7, index.size)
    br = _branches()

    def ours(i, x, y):
        return _sharding.switch(i, br, x, y)

    def plain(i, x, y):
        return lax.switch(i, br, x, y)

    got = jax.jit(jax.vmap(ours))(index, xs, ys)
    want = [plain(i, x, y) for i, x, y in zip(index, xs, ys, strict=True)]
    for g, w in zip(got, zip(*want, strict=True), strict=True):
        np.testing.assert_allclose(g, np.stack(w), rtol=1e-14)
    # forward mode inside vmap (the fitting's Jacobian) and reverse mode
    jac = jax.vmap(jax.jacfwd(lambda x, y, i: ours(i, x, y)[0], argnums=(0, 1)),
                   in_axes=(0, 0, 0))(xs, ys, index)
    grad = jax.vmap(jax.grad(lambda x, y, i: ours(i, x, y)[0], argnums=(0, 1)))(xs, ys, index)
    for i, x, y, jx, jy, gx, gy in zip(index, xs, ys, *jac, *grad, strict=True):
        wx, wy = jax.grad(lambda x, y, i=i: plain(i, x, y)[0], argnums=(0, 1))(x, y)
        np.testing.assert_allclose([jx, jy, gx, gy], [wx, wy, wx, wy], rtol=1e-13)


def test_a_branch_no_lane_takes_does_not_run():
    counts = collections.Counter()
    br = _branches(counts)
    xs, ys = jnp.linspace(0.1, 1.0, 6), jnp.linspace(0.3, 0.9, 6)
    run = jax.jit(jax.vmap(lambda i, x, y: _sharding.switch(i, br, x, y)))
    jax.block_until_ready(run(jnp.zeros(6, int), xs, ys))
    jax.effects_barrier()
    assert dict(counts) == {0: 1}
    counts.clear()
    jax.block_until_ready(run(jnp.array([0, 0, 2, 0, 0, 0]), xs, ys))
    jax.effects_barrier()
    # the branch one lane takes runs (for the batch); the untaken one still does not
    assert dict(counts) == {0: 1, 2: 1}
    counts.clear()
    # unbatched: the one branch taken
    jax.block_until_ready(jax.jit(lambda x, y: _sharding.switch(1, br, x, y))(0.5, 0.2))
    jax.effects_barrier()
    assert dict(counts) == {1: 1}


def test_cond_runs_only_the_taken_side_under_vmap():
    counts = collections.Counter()
    br = _branches(counts)
    xs = jnp.linspace(0.1, 1.0, 4)
    out = jax.jit(jax.vmap(lambda x: _sharding.cond(x > 2.0, br[1], br[0], x, x)))(xs)
    jax.effects_barrier()
    np.testing.assert_allclose(out[0], jnp.sin(xs) * xs, rtol=1e-14)
    assert dict(counts) == {0: 1}


def _three_lanes():
    """A history (times [s], indentation [m]), a probe, and three lanes' G0 [Pa] and drive
    offsets [m]: one lane touches later, one never lifts off, so that at one sample the
    lanes take different branches."""
    ts = jnp.linspace(0.0, 2.0, 60)
    d = 1e-6 * jnp.sin(jnp.pi * ts / 1.6)
    return ts, d, jc.Parabola(1e-5), jnp.array([2e3, 8e3, 3e4]), jnp.array([0.0, -3e-7, 2e-7])


def test_simulate_vmapped_equals_each_lane_alone():
    # lanes in different branches at the same sample (one touches later, one never lifts
    # off): every lane's force, jump-off and derivatives (forward and reverse mode) equal
    # its own unbatched history; the reverse-mode gradient also a central difference (a
    # branch run for another lane's sake has infinite derivatives where it is not taken:
    # without care, 0 x inf = NaN in the gradient of that lane)
    ts, d, prof, G0s, offsets = _three_lanes()

    def one(G0, off):
        s = jc.simulate(jc.StandardModel(G0, 0.5 * G0, 0.2 * G0), prof, 1e-3, ts, d + off,
                        grid=16, throw=False)
        return s.force, s.jumpoff_time

    def dforce(G0, off):
        return jax.jacfwd(lambda g: one(g, off)[0])(G0)

    def work(G0, off):  # the contact's work over the approach and part of the lift [J]
        f = one(G0, off)[0]
        return jnp.sum(0.5 * (f[1:41] + f[:40]) * jnp.diff(d[:41]))

    # every function compiled once, batched and alone (one lane per call)
    batched = jax.jit(jax.vmap(one))(G0s, offsets)
    dbatched = jax.jit(jax.vmap(dforce))(G0s, offsets)
    grads = jax.jit(jax.vmap(jax.grad(work)))(G0s, offsets)
    one_, dforce_, grad_, work_ = (jax.jit(f) for f in (one, dforce, jax.grad(work), work))
    for k in range(3):
        f, t = one_(G0s[k], offsets[k])
        np.testing.assert_allclose(batched[0][k], f, rtol=1e-12, atol=1e-18)
        np.testing.assert_allclose(batched[1][k], t, rtol=1e-12)
        np.testing.assert_allclose(dbatched[k], dforce_(G0s[k], offsets[k]), rtol=1e-9,
                                   atol=1e-22)
        g, h = G0s[k], 1e-6 * G0s[k]
        central = (work_(g + h, offsets[k]) - work_(g - h, offsets[k])) / (2 * h)
        assert np.isfinite(grads[k])
        np.testing.assert_allclose(grads[k], grad_(g, offsets[k]), rtol=1e-10)
        np.testing.assert_allclose(grads[k], central, rtol=1e-6)


def test_unmasked_branches_keep_every_lanes_values_and_derivatives():
    # `masked=False` (branches differentiable on every lane): the same values, forward- and
    # reverse-mode derivatives as lax.switch on each lane alone
    index = jnp.asarray([0, 2, 1, 0, 2])
    xs = jnp.linspace(0.2, 1.4, index.size)
    ys = jnp.linspace(-0.5, 0.7, index.size)
    br = _branches()

    def ours(i, x, y):
        return _sharding.switch(i, br, x, y, masked=False)[0]

    jac = jax.vmap(jax.jacfwd(lambda x, y, i: ours(i, x, y), argnums=(0, 1)))(xs, ys, index)
    grad = jax.vmap(jax.grad(lambda x, y, i: ours(i, x, y), argnums=(0, 1)))(xs, ys, index)
    got = jax.vmap(ours)(index, xs, ys)
    for k, (i, x, y) in enumerate(zip(index, xs, ys, strict=True)):
        want = lax.switch(i, br, x, y)[0]
        wx, wy = jax.grad(lambda x, y, i=i: lax.switch(i, br, x, y)[0], argnums=(0, 1))(x, y)
        np.testing.assert_allclose(got[k], want, rtol=1e-14)
        np.testing.assert_allclose([jac[0][k], jac[1][k], grad[0][k], grad[1][k]],
                                   [wx, wy, wx, wy], rtol=1e-13)


def test_a_history_step_does_the_contacts_work_only_where_some_lane_touches(monkeypatch):
    # the foundation's step out of contact (before the touch, after the jump-off) skips the
    # contact's work (the front's branches and the force integral) unless some lane of the
    # batch is in contact or touches in the step: counted by a host callback inside the
    # force integral, against the samples where some lane's contact radius is positive
    # before or after the step
    from jaxcontact._foundation import _model

    calls = collections.Counter()
    force = _model._Model.force

    def counted(self, *args):
        jax.debug.callback(lambda: calls.update(["force"]))
        return force(self, *args)

    monkeypatch.setattr(_model._Model, "force", counted)
    ts = jnp.linspace(0.0, 2.0, 50)
    d = 1.2e-6 * jnp.sin(jnp.pi * ts / 1.4) - 4e-7  # apart, a contact, apart again
    offsets = jnp.array([0.0, -2e-7, 1e-7])

    def one(off):
        s = jc.simulate(jc.StandardModel(4e4, 2e4, 1e4), jc.Parabola(1e-5), 1e-3, ts,
                        d + off, grid=16, throw=False)
        return s.force, s.contact_radius

    run = jax.jit(jax.vmap(one))
    # the calls after the time loop (the jump-off's and the largest tension's refinements,
    # on stand-ins where there is none): a batch that never touches
    _, a_never = jax.block_until_ready(run(offsets - 2e-6))
    jax.effects_barrier()
    assert not np.any(np.asarray(a_never) > 0)
    after_loop, _ = calls["force"], calls.clear()
    assert after_loop <= 4
    f, a = jax.block_until_ready(run(offsets))
    jax.effects_barrier()
    touching = np.asarray(a) > 0
    before = np.concatenate([np.zeros((3, 1), bool), touching[:, :-1]], axis=1)
    busy = np.any(touching | before, axis=0)
    assert 0 < int(busy.sum()) < ts.size - 10  # most samples apart on every lane
    assert calls["force"] == after_loop + int(busy.sum())
    # out of contact no force; each lane equals its own unbatched history
    assert np.all(np.asarray(f)[~touching] == 0.0)
    for k in range(3):
        fk, ak = jax.jit(one)(offsets[k])
        np.testing.assert_allclose(f[k], fk, rtol=1e-12, atol=1e-18)
        np.testing.assert_allclose(a[k], ak, rtol=1e-12, atol=1e-18)


def test_forward_only_traces_leave_values_derivatives_and_later_gradients_alone():
    # inside `forward_only` (the fitting objective's Jacobian) the branches leave out their
    # reverse-mode masks: the values and forward-mode derivatives of every lane are the same;
    # the entry point is its forward-mode twin (traced into the caller's program, or its
    # own nested program cached apart from the entry point's for concrete arguments), so a
    # later reverse-mode gradient in the same process, lanes in different branches, is
    # still finite and equals a central difference
    seen = []

    def plain(x):
        seen.append(isinstance(x, jax.core.Tracer))
        return 2.0 * x

    jitted = jax.jit(plain)
    assert _sharding.compiled(jitted, plain) is jitted
    with _sharding.forward_only():
        twin = _sharding.compiled(jitted, plain)
        assert twin is not jitted and twin is not plain
        assert _sharding.compiled(jitted, plain) is twin
        # concrete: its own program (traced once)
        assert float(twin(jnp.asarray(1.5))) == 3.0
        assert float(twin(jnp.asarray(2.5))) == 5.0 and seen == [True]
        # traced: the body in the caller's program, no nested jit
        jaxpr = jax.make_jaxpr(twin)(1.5)
        assert [e.primitive.name for e in jaxpr.eqns] == ["mul"]
    assert _sharding.compiled(jitted, plain) is jitted
    ts, d, prof, G0s, offsets = _three_lanes()

    def force(G0, off):
        return jc.simulate(jc.StandardModel(G0, 0.5 * G0, 0.2 * G0), prof, 1e-3, ts,
                           d + off, grid=16, throw=False).force

    def dforce(G0, off):
        return jax.jvp(lambda g: force(g, off), (G0,), (jnp.ones_like(G0),))

    with _sharding.forward_only():
        f_fwd, df_fwd = jax.jit(jax.vmap(dforce))(G0s, offsets)
    f, df = jax.jit(jax.vmap(dforce))(G0s, offsets)
    np.testing.assert_allclose(f_fwd, f, rtol=1e-13, atol=1e-22)
    np.testing.assert_allclose(df_fwd, df, rtol=1e-13, atol=1e-22)

    def work(G0, off):
        fo = force(G0, off)
        return jnp.sum(0.5 * (fo[1:41] + fo[:40]) * jnp.diff(d[:41]))

    grads = jax.jit(jax.vmap(jax.grad(work)))(G0s, offsets)
    work_ = jax.jit(work)
    for k in range(3):
        g, h = G0s[k], 1e-6 * G0s[k]
        central = (work_(g + h, offsets[k]) - work_(g - h, offsets[k])) / (2 * h)
        assert np.isfinite(grads[k])
        np.testing.assert_allclose(grads[k], central, rtol=1e-6)
