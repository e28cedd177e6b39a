"""Reliability of the forward model: invalid and implausible input eagerly and under
`jit`/`vmap` (per-lane `.result`, `throw=`), mixed precision, recompilation, gradients at a
tie of two estimates and forward-mode derivatives through diffrax.

Compiled functions are shared (module fixtures) and the histories short, so that the file
stays cheap; `benchmarks/fuzz_forward.py` runs the long version of these checks.
"""

import os
import re

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxcontact as jc

R = jc.RESULTS
G0, G1, ETA1, RAD, DG, D0, V = 1e6, 2e5, 1e4, 1e-4, 0.05, 4e-6, 1e-4
N_T = 64
TS = np.linspace(0.0, 0.1, N_T)


def _code(result, i=None):
    value = result._value if i is None else result._value[i]
    return R._index_to_message[int(value)]


def _msg(item):
    return R._index_to_message[item._value]


# --------------------------------------------------------------------------------------
# retract: every input, per lane
# --------------------------------------------------------------------------------------


def _retract_lane(g0, g1, eta1, rad, dg, d0, v, ts):
    return jc.retract(jc.StandardModel(g0, g1, eta1), jc.Parabola(rad), dg, ts, depth=d0,
                      velocity=v, throw=False)


@pytest.fixture(scope="module")
def retract_lanes():
    return jax.jit(jax.vmap(_retract_lane))


BAD_RETRACT = [
    # (parameter index, value, expected RESULTS item)
    (0, -1e6, R.invalid_rheology), (0, 0.0, R.invalid_rheology),
    (0, np.nan, R.invalid_rheology), (0, np.inf, R.invalid_rheology),
    (1, -2e5, R.invalid_rheology), (2, -1e4, R.invalid_rheology), (2, 0.0, R.invalid_rheology),
    (3, 0.0, R.invalid_profile), (3, -1e-4, R.invalid_profile), (3, np.nan, R.invalid_profile),
    (4, -0.05, R.invalid_work_of_adhesion), (4, 0.0, R.invalid_work_of_adhesion),
    (4, np.nan, R.invalid_work_of_adhesion),
    (5, 0.0, R.invalid_depth), (5, -1e-6, R.invalid_depth), (5, np.inf, R.invalid_depth),
    (6, np.nan, R.invalid_velocity), (6, 0.0, R.invalid_velocity), (6, -1e-4, R.invalid_velocity),
    (5, 4000.0, R.implausible_input), (3, 1e-300, R.implausible_input),
    (0, 1e30, R.implausible_input), (6, 1e6, R.implausible_input),
    # a relaxed contact radius sqrt(R d0) = 6.3 R: no sphere contact reaches beyond R
    (5, 4e-3, R.beyond_profile),
]
BAD_TS = [
    (TS[::-1], R.invalid_times), (np.where(np.arange(N_T) == 5, np.nan, TS), R.invalid_times),
    (TS - 0.01, R.invalid_times),
]


def test_retract_reports_every_bad_lane(retract_lanes):
    base = np.array([G0, G1, ETA1, RAD, DG, D0, V])
    rows = [(base, TS, None)]
    for k, value, item in BAD_RETRACT:
        p = base.copy()
        p[k] = value
        rows.append((p, TS, item))
    rows += [(base, ts, item) for ts, item in BAD_TS]
    P = np.stack([r[0] for r in rows])
    T = np.stack([r[1] for r in rows])
    sol = retract_lanes(*[jnp.asarray(P[:, k]) for k in range(7)], jnp.asarray(T))
    assert _code(sol.result, 0) == _msg(R.detached)
    ref = jc.retract(jc.StandardModel(G0, G1, ETA1), jc.Parabola(RAD), DG, jnp.asarray(TS),
                     depth=D0, velocity=V)
    np.testing.assert_allclose(sol.force[0], ref.force, rtol=1e-13, atol=1e-25)
    for i, (_, _, item) in enumerate(rows[1:], start=1):
        assert _code(sol.result, i) == _msg(item), (i, rows[i][0], _code(sol.result, i))
        # no numbers that look plausible on a lane with invalid input
        for field in ("force", "contact_radius", "max_tensile_force", "jumpoff_time"):
            assert np.all(np.isnan(np.asarray(getattr(sol, field)[i]))), (i, field)


def test_throw_raises_whichever_field_is_read():
    ts = jnp.asarray(TS)

    def event(dg, field):
        sol = jc.retract(jc.StandardModel(G0, G1, ETA1), jc.Parabola(RAD), dg, ts, depth=D0,
                         velocity=V)
        return getattr(sol, field)

    for field in ("jumpoff_time", "max_tensile_force"):
        f = eqx.filter_jit(lambda dg, field=field: event(dg, field))
        assert np.isfinite(float(f(jnp.asarray(DG))))
        with pytest.raises(Exception, match="work_of_adhesion"):
            jax.block_until_ready(f(jnp.asarray(0.0)))


def test_eager_errors_name_the_parameter():
    ts = jnp.asarray(TS)
    rh, prof = jc.StandardModel(G0, G1, ETA1), jc.Parabola(RAD)
    cases = [
        (dict(work_of_adhesion=-1.0), "work_of_adhesion"),
        (dict(depth=0.0), "depth"),
        (dict(velocity=float("nan")), "velocity"),
        (dict(ts=ts[::-1]), "ts"),
        (dict(depth=4000.0), "plausible"),
        (dict(velocity=1e6), "velocity"),
    ]
    for kw, match in cases:
        args = dict(work_of_adhesion=DG, ts=ts, depth=D0, velocity=V)
        args.update(kw)
        with pytest.raises(ValueError, match=match):
            jc.retract(rh, prof, **args)
    with pytest.raises(ValueError, match="`n`"):
        jc.PowerLaw(1.0, 0.5)
    with pytest.raises(TypeError, match="profile"):
        jc.retract(rh, "sphere", DG, ts, depth=D0, velocity=V)


def test_plausibility_switch():
    ts = jnp.asarray(TS)
    rh = jc.StandardModel(G0, G1, ETA1)
    with pytest.raises(ValueError, match="plausibility_checks"):
        jc.retract(rh, jc.Parabola(1e-300), DG, ts, depth=D0, velocity=V)
    with jc.plausibility_checks(False):
        # the profile's limit (a contact radius sqrt(R d0) = 2e-153 m on a paraboloid of
        # radius 1e-300 m) is a plausibility check too: off here, as in the fitting objective
        # while it searches
        sol = jc.retract(rh, jc.Parabola(1e-300), DG, ts, depth=D0, velocity=V, throw=False)
        # finite inputs that overflow are not called "non-finite input"
        assert sol.result in (R.non_finite_result, R.detached, R.in_contact)
        assert not bool(sol.result == R.invalid_input)
        # a 1 km sphere at 1 cm depth (a glacier on bedrock) is computed when the check is off
        big = jc.retract(jc.StandardModel(1e10, 1e10, 1e12), jc.Parabola(1e3), 1.0, ts,
                         depth=1e-2, velocity=1e-3)
        assert bool(big.ok)
    assert jc.retract(rh, jc.Parabola(RAD), DG, ts, depth=D0, velocity=V).ok


# --------------------------------------------------------------------------------------
# simulate, the elastic relations, profiles and rheologies under jit/vmap
# --------------------------------------------------------------------------------------


def test_simulate_reports_every_bad_lane():
    ts = np.linspace(0.0, 0.06, 40)
    d = np.interp(ts, [0, 0.02, 0.03, 0.06], [0, D0, D0, -D0])

    def lane(g0, dg, t, u):
        return jc.simulate(jc.StandardModel(g0, G1, ETA1), jc.Parabola(RAD), dg, t, u,
                           grid=8, throw=False)

    rows = [
        (G0, DG, ts, d, R.detached),
        (-G0, DG, ts, d, R.invalid_rheology),
        (G0, 0.0, ts, d, R.invalid_work_of_adhesion),
        (G0, DG, ts[::-1], d, R.invalid_times),
        (G0, DG, ts, np.where(np.arange(40) == 3, np.nan, d), R.invalid_displacement),
        (G0, DG, ts, d * 1e9, R.implausible_input),
        (G0, DG, ts, d * 40, R.beyond_profile),  # a radius sqrt(R 40 d0) = 4 R
    ]
    cols = [jnp.asarray(np.stack([r[k] for r in rows])) for k in range(4)]
    sol = jax.jit(jax.vmap(lane))(*cols)
    for i, row in enumerate(rows):
        assert _code(sol.result, i) == _msg(row[4]), (i, _code(sol.result, i))
    assert np.all(np.isnan(np.asarray(sol.force[1:])))


def test_elastic_relations_under_jit():
    prof = jc.Parabola(RAD)
    kw = dict(effective_modulus=4e6, work_of_adhesion=DG)
    with pytest.raises(ValueError, match="`a`"):
        jc.jkr_force(prof, -1e-6, **kw)
    with pytest.raises(ValueError, match="displacement"):
        jc.jkr_contact_radius(prof, float("nan"), **kw)
    a = jnp.array([1e-6, -1e-6, jnp.nan])
    out = jax.jit(lambda a: jc.jkr_force(prof, a, **kw, throw=False))(a)
    assert np.isfinite(float(out[0])) and np.all(np.isnan(np.asarray(out[1:])))
    with pytest.raises(Exception, match="contact radius"):
        jax.block_until_ready(jax.jit(lambda a: jc.jkr_force(prof, a, **kw))(a))
    d = jnp.array([1e-7, jnp.nan, -1.0])
    r = jax.jit(lambda d: jc.jkr_contact_radius(prof, d, **kw, throw=False))(d)
    assert float(r[0]) > 0 and np.isnan(float(r[1])) and float(r[2]) == 0.0

    def po(E, dg):
        return jc.pull_off(prof, effective_modulus=E, work_of_adhesion=dg, throw=False)

    sol = jax.jit(jax.vmap(po))(jnp.array([4e6, -1.0, 4e6, 4e6]), jnp.array([DG, DG, 0.0, 1e3]))
    expect = [R.successful, R.invalid_modulus, R.invalid_work_of_adhesion, R.implausible_input]
    assert [_code(sol.result, i) for i in range(4)] == [_msg(e) for e in expect]
    np.testing.assert_allclose(sol.force[0], -5 / 6 * np.pi * DG * RAD, rtol=1e-12)
    assert np.all(np.isnan(np.asarray(sol.force[1:])))


def test_profiles_and_rheologies_raise_under_jit():
    g = jax.jit(lambda n: jc.PowerLaw(1e3, n).g(1e-6))
    assert np.isfinite(float(g(1.5)))
    with pytest.raises(Exception, match="`n` must be finite and in"):
        jax.block_until_ready(g(0.4))
    relax = jax.jit(lambda g0: jc.StandardModel(g0, G1, ETA1).relaxation(0.01))
    assert np.isfinite(float(relax(G0)))
    with pytest.raises(Exception, match="StandardModel"):
        jax.block_until_ready(relax(-G0))


# --------------------------------------------------------------------------------------
# precision, recompilation, gradients
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "dt_ts, dt_par, expect",
    [(jnp.float32, jnp.float64, jnp.float64), (jnp.float64, jnp.float32, jnp.float64),
     (jnp.float32, jnp.float32, jnp.float32)],
)
def test_mixed_precision(dt_ts, dt_par, expect):
    ts = jnp.asarray(TS, dt_ts)
    p = [jnp.asarray(x, dt_par) for x in (G0, G1, ETA1, RAD, DG, D0, V)]
    sol = jc.retract(jc.StandardModel(*p[:3]), jc.Parabola(p[3]), p[4], ts, depth=p[5],
                     velocity=p[6])
    assert sol.force.dtype == expect and sol.jumpoff_time.dtype == expect
    assert bool(sol.ok)
    # a sampled float32 history with float64 parameters (crashed in the root finder)
    disp = jnp.asarray(D0 - V * TS, dt_ts)
    sol = jc.retract(jc.StandardModel(*p[:3]), jc.Parabola(p[3]), p[4], jnp.asarray(TS), disp)
    assert bool(sol.ok)


def test_python_floats_do_not_recompile():
    from jaxcontact._pulloff import _retract

    ts = jnp.asarray(TS)
    rh = jc.StandardModel(G0, G1, ETA1)
    jc.retract(rh, jc.Parabola(RAD), DG, ts, depth=D0, velocity=V)
    size = _retract._cached._cache_size()
    for i in range(3):
        jc.retract(rh, jc.Parabola(RAD * (1.1 + i)), DG * (1 + i), ts, depth=D0 * 0.9,
                   velocity=V * (2 + i))
    assert _retract._cached._cache_size() == size


def test_gradient_of_pinned_jumpoff_on_a_sample():
    # a contact that jumps off straight from the pinned state (a0 below the fold radius),
    # sampled with a sample at the jump-off time: the sampled force there equals the front
    # minimum, and the largest tensile force must carry the derivative of the front, not
    # half of each (a tie inside jnp.minimum gave half of d/d(dgamma) and the wrong sign
    # of d/dG1)
    d0, v = 2e-8, 1e-5

    def mt(p, ts):
        s = jc.retract(jc.StandardModel(p[0], p[1], ETA1), jc.Parabola(RAD), p[2], ts,
                       depth=d0, velocity=v)
        return s.max_tensile_force

    # the jump-off time is refined between samples (exact), so any sampling finds it
    coarse = jc.retract(jc.StandardModel(G0, G1, ETA1), jc.Parabola(RAD), DG,
                        jnp.linspace(0.0, 2.0, 52), depth=d0, velocity=v)
    assert float(coarse.details.initial_radius) < float(coarse.details.fold_radius)
    tj = float(coarse.jumpoff_time)
    ts = jnp.concatenate([jnp.linspace(0.0, tj, 51), jnp.array([1.2 * tj])])
    p = jnp.array([G0, G1, DG])
    g = jax.grad(mt)(p, ts)
    for k in range(3):
        h = 1e-6 * float(p[k])
        fd = (mt(p.at[k].add(h), ts) - mt(p.at[k].add(-h), ts)) / (2 * h)
        np.testing.assert_allclose(float(g[k]), float(fd), rtol=1e-6)


def test_forward_mode_through_diffrax():
    # jacfwd through diffrax needs a forward-mode adjoint (DiffraxODE(adjoint=...)); it
    # agrees with reverse mode through the default adjoint
    ts = jnp.linspace(0.0, 0.06, 25)

    def events(p, method):
        s = jc.retract(jc.StandardModel(p[0], p[1], p[2]), jc.Parabola(RAD), p[3], ts,
                       depth=D0, velocity=V, method=method)
        return jnp.stack([s.jumpoff_time, s.jumpoff_force, s.force[8]])

    p = jnp.array([G0, G1, ETA1, DG])
    method = jc.DiffraxODE(solver=diffrax.Tsit5(), rtol=1e-9)
    rev = jax.jit(jax.jacrev(lambda q: events(q, method)))(p)
    fwd_method = eqx.tree_at(lambda m: m.adjoint, method, diffrax.ForwardMode())
    fwd = jax.jit(jax.jacfwd(lambda q: events(q, fwd_method)))(p)
    scale = np.max(np.abs(np.asarray(rev)), axis=1, keepdims=True)
    assert np.all(np.isfinite(np.asarray(fwd)))
    np.testing.assert_allclose(np.asarray(fwd) / scale, np.asarray(rev) / scale, atol=1e-8)


def test_deprecated_stats_and_positional_signature():
    ts = jnp.asarray(TS)
    rh, prof = jc.StandardModel(G0, G1, ETA1), jc.Parabola(RAD)
    by_kw = jc.retract(rh, prof, work_of_adhesion=DG, ts=ts, displacement=D0 - V * ts)
    by_pos = jc.retract(rh, prof, DG, ts, D0 - V * ts)
    np.testing.assert_array_equal(by_kw.force, by_pos.force)
    with pytest.warns(DeprecationWarning, match="details"):
        stats = by_pos.stats
    assert float(stats["initial_radius"]) == float(by_pos.details.initial_radius)


def test_plausibility_block_is_local_to_its_context_and_the_session_switch_global():
    """A `with plausibility_checks(False)` block in one thread leaves another thread's
    checks on (a context variable); the session-wide call reaches every thread."""
    import threading

    from jaxcontact._validate import plausibility_enabled

    seen = {}
    inside, done = threading.Event(), threading.Event()

    def other():
        inside.wait(5)
        seen["during block"] = plausibility_enabled()
        done.set()

    t = threading.Thread(target=other)
    t.start()
    with jc.plausibility_checks(False):
        assert not plausibility_enabled()
        inside.set()
        done.wait(5)
    t.join()
    assert seen["during block"] is True
    assert plausibility_enabled()
    try:
        jc.plausibility_checks(False)
        box = []
        t = threading.Thread(target=lambda: box.append(plausibility_enabled()))
        t.start()
        t.join()
        assert box == [False] and not plausibility_enabled()
    finally:
        jc.plausibility_checks(True)
    assert plausibility_enabled()


# --------------------------------------------------------------------------------------
# throw=True under differentiation (jit(grad), jit(jacfwd)); per-lane .result under
# jit(vmap(grad)) with throw=False
# --------------------------------------------------------------------------------------

# one bad value of every kind a parameter vector (G0, G1, eta1, R, dgamma, d0, v) can carry,
# including the two that gave a plausible gradient instead of an error (a depth of 4000 m,
# G0 = 1e40 Pa)
BAD_GRAD = [
    (0, -1e6, R.invalid_rheology), (2, 0.0, R.invalid_rheology),
    (3, 0.0, R.invalid_profile), (4, np.nan, R.invalid_work_of_adhesion),
    (5, -1e-6, R.invalid_depth), (6, -1e-4, R.invalid_velocity),
    (5, 4000.0, R.implausible_input), (0, 1e40, R.implausible_input),
]


def _retract_p(p, ts, throw):
    return jc.retract(jc.StandardModel(p[0], p[1], p[2]), jc.Parabola(p[3]), p[4], ts,
                      depth=p[5], velocity=p[6], throw=throw)


def _raises_item(fn, item, *args):
    with pytest.raises(Exception, match=re.escape(_msg(item)[:40])):
        jax.block_until_ready(fn(*args))


@pytest.mark.parametrize("transform", [jax.grad, jax.jacfwd])
def test_throw_raises_under_jit_of_a_derivative(transform):
    """The checks of `retract`, `pull_off`, the elastic relations and the guarded profile
    methods survive `jit(grad)` / `jit(jacfwd)` (they were removed as dead code: NaN or a
    plausible gradient, e.g. 1896 for a depth of 4000 m)."""
    ts = jnp.asarray(TS)
    base = np.array([G0, G1, ETA1, RAD, DG, D0, V])
    d_retract = jax.jit(transform(lambda p: _retract_p(p, ts, True).max_tensile_force))
    assert np.all(np.isfinite(np.asarray(d_retract(jnp.asarray(base)))))
    for k, value, item in BAD_GRAD:
        p = base.copy()
        p[k] = value
        _raises_item(d_retract, item, jnp.asarray(p))

    d_po = jax.jit(transform(lambda q: jc.pull_off(
        jc.Parabola(q[0]), effective_modulus=q[1], work_of_adhesion=DG).force))
    assert np.all(np.isfinite(np.asarray(d_po(jnp.array([RAD, 4 * G0])))))
    _raises_item(d_po, R.invalid_modulus, jnp.array([RAD, -4 * G0]))
    _raises_item(d_po, R.implausible_input, jnp.array([5e3, 4 * G0]))

    d_jkr = jax.jit(transform(lambda a: jc.jkr_force(
        jc.Parabola(RAD), a, effective_modulus=4 * G0, work_of_adhesion=DG)))
    _raises_item(d_jkr, R.invalid_radius, jnp.asarray(-1e-6))

    d_g = jax.jit(transform(lambda n: jc.PowerLaw(1e3, n).g(1e-6)))
    assert np.isfinite(float(d_g(1.5)))
    with pytest.raises(Exception, match="`n` must be finite and in"):
        jax.block_until_ready(d_g(0.4))


def test_simulate_throw_raises_under_jit_of_a_derivative():
    """`simulate` shares the mechanism (`raise_if_error`); one transform (its derivative
    compiles slowly), a scalar parameter."""
    t_sim = np.linspace(0.0, 0.06, 24)
    u_sim = jnp.asarray(np.interp(t_sim, [0, 0.02, 0.03, 0.06], [0, D0, D0, -D0]))

    def sim(dg):
        return jc.simulate(jc.StandardModel(G0, G1, ETA1), jc.Parabola(RAD), dg,
                           jnp.asarray(t_sim), u_sim, grid=8).max_tensile_force

    d_sim = jax.jit(jax.jacfwd(sim))
    assert np.isfinite(float(d_sim(DG)))
    _raises_item(d_sim, R.invalid_work_of_adhesion, -DG)
    _raises_item(d_sim, R.implausible_input, 1e3)


def test_vmapped_gradients_report_every_lane():
    """jit(vmap(value_and_grad)) with `throw=False`: the status per lane (aux), the gradient
    of the good lane that of the unbatched call, no error raised."""
    ts = jnp.asarray(TS)
    base = np.array([G0, G1, ETA1, RAD, DG, D0, V])
    rows = [base]
    for k, value, _ in BAD_GRAD:
        p = base.copy()
        p[k] = value
        rows.append(p)

    def f(p):
        sol = _retract_p(p, ts, False)
        return sol.max_tensile_force, sol.result

    vg = jax.jit(jax.vmap(jax.value_and_grad(f, has_aux=True)))
    (_, result), grads = vg(jnp.asarray(np.stack(rows)))
    expect = [R.detached] + [item for _, _, item in BAD_GRAD]
    assert [_code(result, i) for i in range(len(rows))] == [_msg(e) for e in expect]
    ref = jax.grad(lambda p: _retract_p(p, ts, True).max_tensile_force)(jnp.asarray(base))
    np.testing.assert_allclose(np.asarray(grads[0]), np.asarray(ref), rtol=1e-12)


# --------------------------------------------------------------------------------------
# importing leaves the caller's jax_enable_x64 alone; eager calls stay float64
# --------------------------------------------------------------------------------------

_X64_SCRIPT = r"""
import warnings
warnings.simplefilter("error")
import jax, jax.numpy as jnp, numpy as np
import jaxcontact as jc, fitting
assert not jax.config.jax_enable_x64, "import switched x64 on"
ts = np.linspace(0.0, 0.1, 32)
rh, prof = jc.StandardModel(1e6, 2e5, 1e4), jc.Parabola(1e-4)
sol = jc.retract(rh, prof, 0.05, ts, depth=4e-6, velocity=1e-4)
po = jc.pull_off(prof, effective_modulus=4e6, work_of_adhesion=0.05)
u = np.interp(ts, [0.0, 0.05, 0.1], [0.0, 4e-6, -4e-6])
sim = jc.simulate(rh, prof, 0.05, ts, u, grid=8)
# the caller's own arrays and a float32 program inside the caller's jit stay float32
f32 = jax.jit(lambda t, d: jc.retract(rh, prof, 0.05, t, d).force)(
    jnp.asarray(ts, jnp.float32), jnp.asarray(4e-6 - 1e-4 * ts, jnp.float32))
# a fitting entry function: the truth of synthetic data has zero residuals
curve = fitting.Curve(time=ts, displacement=np.asarray(sol.displacement),
                      force=np.asarray(sol.force), segment=np.zeros(32, int),
                      segment_names=("retract",))
spec = fitting.make_spec()
data = fitting.prepare_curves([curve], spec, radius=1e-4)
r = fitting.residuals(np.array([1e6, 2e5, 1e4, 0.05]), data, spec)
# every profile and rheology built and used eagerly, without a warning (a table's checks
# warned of float64 truncated to float32)
xs = np.linspace(0.0, 3e-5, 64)
for p in (jc.Sphere(4e-5), jc.Cone(1.2), jc.pyramid(1.2), jc.PowerLaw(1e10, 3.0),
          jc.FlatPunch(1e-5), jc.Tabulated(xs, xs**2 / 8e-5)):
    assert jc.profile_radius(p, 1e-6).dtype == np.float64, p
for rheo in (jc.PronySeries(1e5, np.array([1e5, 2e5]), np.array([0.1, 1.0])),
             jc.CreepChain(1e6, np.array([1e5]), np.array([1e4])), jc.Elastic(1e6)):
    assert rheo.relaxation(np.array([0.0, 1.0])).dtype == np.float64, rheo
print(jax.config.jax_enable_x64, sol.force.dtype, float(po.force), sim.force.dtype,
      jnp.ones(2).dtype, f32.dtype, data.ts.dtype, r.dtype, float(np.max(np.abs(r))))
"""


def test_import_leaves_x64_alone_and_eager_calls_stay_float64():
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "JAX_ENABLE_X64"}
    out = subprocess.run([sys.executable, "-c", _X64_SCRIPT], env=env, capture_output=True,
                         text=True, timeout=1800)  # a hang's limit, not a speed
    assert out.returncode == 0, out.stderr[-3000:]
    x64, f, po, fs, ones, f32, dts, dr, rmax = out.stdout.split()
    assert x64 == "False" and ones == "float32" and f32 == "float32"
    assert f == fs == dts == dr == "float64"
    # float64 accuracy: the closed form of the parabola's pull-off under displacement control
    assert float(po) == pytest.approx(-5 / 6 * np.pi * 0.05 * 1e-4, rel=1e-13)
    assert float(rmax) <= np.sqrt(12.0) + 1e-6  # only the samples at the jump-off differ


def test_traced_answers_as_an_eager_zeros_does():
    # `float64_scope` asks `_traced` whether a call runs inside a trace; without one active it
    # answers at once (JAX's trace state), else as `jnp.zeros(())` being a tracer, its
    # definition, in every context: eager, jit, vmap (constant or traced arguments), grad
    from jaxcontact._solvers import _traced

    seen = []

    def probe(*args):
        seen.append((_traced((args, {})),
                     any(isinstance(a, jax.core.Tracer) for a in args)
                     or isinstance(jnp.zeros(()), jax.core.Tracer)))
        return 0.0

    probe(1.0)
    jax.jit(lambda x: probe() + x)(1.0)
    jax.jit(lambda x: probe(x) + x)(1.0)
    jax.vmap(lambda x: probe() + x)(jnp.ones(2))
    jax.vmap(lambda x: probe(x) + x)(jnp.ones(2))
    jax.grad(lambda x: probe() + x)(1.0)
    got, definition = zip(*seen, strict=True)
    assert got == definition == (False, True, True, False, True, False)


# --------------------------------------------------------------------------------------
# odd geometry: a contact radius beyond what the profile describes, or kilometres wide
# --------------------------------------------------------------------------------------


def test_contact_beyond_the_sphere_or_implausibly_wide_is_refused():
    """Every entry point refuses (eagerly, naming the parameter) a contact radius beyond a
    Parabola's R, and (plausibility of units) one beyond 1 m: a PowerLaw with a tiny
    prefactor is refused as the equivalent Parabola (f = r^2/(2R): c = 1/(2R)) is, a cone
    with a half-angle near pi/2. These gave -2.2e13 N, -4.1e7 N, a positive "max tensile
    force" of 2.24 N and 5.3e10 N before."""
    ts = jnp.asarray(TS)
    rh = jc.StandardModel(G0, G1, ETA1)
    kw = dict(effective_modulus=4 * G0, work_of_adhesion=DG)
    with pytest.raises(ValueError, match=r"`depth` = 0.004 m .* beyond the Parabola's radius"):
        jc.retract(rh, jc.Parabola(RAD), DG, ts, depth=4e-3, velocity=V)
    # just inside: a0 = 0.9 R
    assert bool(jc.retract(rh, jc.Parabola(RAD), DG, ts, depth=0.81 * RAD, velocity=V).ok)
    with pytest.raises(ValueError, match="contact_radius"):
        jc.retract(rh, jc.Parabola(RAD), DG, ts, depth=D0, velocity=V,
                   contact_radius=1.5 * RAD)
    with pytest.raises(ValueError, match=r"`a` \(contact radius\) .*valid_radius"):
        jc.jkr_force(jc.Parabola(RAD), 1.0, **kw)
    with pytest.raises(ValueError, match="`depth` .* beyond"):
        jc.profile_radius(jc.Parabola(RAD), 4e-3)
    with pytest.raises(ValueError, match="`displacement` up to .* beyond"):
        jc.simulate(rh, jc.Parabola(RAD), DG, ts, 4e-3 * np.sin(np.pi * TS / TS[-1]))
    steep = jc.Cone(np.pi / 2 - 1e-12)
    for prof in (jc.PowerLaw(1e-30, 2.0), jc.Parabola(5e29), steep):
        with pytest.raises(ValueError, match="plausible range"):
            jc.retract(rh, prof, DG, ts, depth=1e-6, velocity=V)
    with pytest.raises(ValueError, match="plausible range"):
        jc.pull_off(steep, **kw)
    with pytest.raises(ValueError, match="plausible range"):
        jc.jkr_contact_radius(steep, 1e-6, **kw)
    # both are plausibility checks (switchable: the fitting objective searches with them
    # off, and its report checks the result against the profile's limit)
    with jc.plausibility_checks(False):
        assert bool(jc.retract(rh, jc.PowerLaw(1e-30, 2.0), DG, ts, depth=1e-6,
                               velocity=V).ok)
        assert bool(jc.retract(rh, jc.Parabola(RAD), DG, ts, depth=4e-3, velocity=V,
                               throw=False).result != jc.RESULTS.beyond_profile)


def test_odd_geometry_is_flagged_per_lane():
    def po(half_angle, E):
        return jc.pull_off(jc.Cone(half_angle), effective_modulus=E, work_of_adhesion=DG,
                           throw=False)

    sol = jax.jit(jax.vmap(po))(jnp.array([1.2, np.pi / 2 - 1e-12]), jnp.array([4e6, 4e6]))
    assert [_code(sol.result, i) for i in range(2)] == [_msg(R.successful),
                                                        _msg(R.implausible_input)]
    assert np.isfinite(float(sol.force[0])) and np.isnan(float(sol.force[1]))
    a = jnp.array([0.5 * RAD, 2 * RAD])
    out = jax.jit(lambda a: jc.jkr_force(jc.Parabola(RAD), a, effective_modulus=4e6,
                                         work_of_adhesion=DG, throw=False))(a)
    assert np.isfinite(float(out[0])) and np.isnan(float(out[1]))


def test_sweep_flags_points_beyond_the_sphere_and_refuses_a_flat_cone():
    ds = jc.sweep({"G_inf": 1e5, "work_of_adhesion": DG, "R": RAD,
                   "depth": np.array([1e-6, 4e-3]), "velocity": 1e-4},
                  model=jc.RelaxedStart(samples=20), progress=False, precision="float64")
    assert int(ds.status[0]) == int(R.detached._value)
    assert int(ds.status[1]) == int(R.beyond_profile._value)
    assert np.isnan(float(ds.max_tensile_force_N[1]))
    with pytest.raises(ValueError, match="contact radius at `depth`"):
        jc.sweep({"G_inf": 1e5, "work_of_adhesion": DG, "half_angle": np.pi / 2 - 1e-12,
                  "depth": 1e-6, "velocity": 1e-4}, model=jc.RelaxedStart(samples=20),
                 progress=False, precision="float64")
