"""Property tests (hypothesis) of the forward model in float64 and float32.

Invariants on random parameter sets: every lane succeeds (`detached` or `in_contact`), all
outputs are finite, force and radius are exactly zero once the contact has jumped off for
good, the largest tensile force is not above any sampled force (and tensile when the
contact detached), the derivatives of the events are finite; a bad value in one lane gives
that lane's error code and leaves the other lanes unchanged; float32 follows float64 to
its round-off away from the jump-off; a float32 lift never reports a false
`advancing_contact`.

Each strategy draws a whole batch (a fixed number of lanes), so one compiled program per
precision serves every example; the budget is small here (`benchmarks/fuzz_forward.py`
runs thousands of sets and writes `docs/reliability-forward.md`).
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import jaxcontact as jc

R = jc.RESULTS
LANES = 8
N_T = 80
BUDGET = settings(
    max_examples=4,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)


def _ok(codes):
    value = np.asarray(codes)
    return (value == R.detached._value) | (value == R.in_contact._value)


# --------------------------------------------------------------------------------------
# parameter sets: log-uniform over the regimes of cells, gels and elastomers
# --------------------------------------------------------------------------------------


def _log(lo, hi):
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False).map(lambda x: 10.0**x)


# G0 [Pa], G1/G0, tau [s] (as a fraction of the lift duration), dgamma [J/m^2], R [m],
# depth/R, lift distance over the duration in units of the depth
LANE = st.tuples(_log(2, 7), _log(-1.5, 0.5), _log(-3, 0.5), _log(-3.5, -0.5), _log(-6, -3),
                 _log(-3, -1), _log(-0.3, 1.5))
BATCH = st.lists(LANE, min_size=LANES, max_size=LANES)


def _retract_inputs(batch, dtype):
    p = np.array(batch, dtype=float)
    G0, ratio, tau, dg, rad, depth_ratio, lift = p.T
    G1 = G0 * ratio
    eta1 = tau * (G0 + G1)
    depth = depth_ratio * rad
    v = lift * depth  # over a unit duration
    return [jnp.asarray(x, dtype) for x in (G0, G1, eta1, dg, rad, depth, v)]


def _retract_lane(g0, g1, eta1, dg, rad, depth, v, ts):
    return jc.retract(jc.StandardModel(g0, g1, eta1), jc.Parabola(rad), dg, ts, depth=depth,
                      velocity=v, throw=False)


@functools.cache
def _retract_fn(dtype):
    ts = jnp.linspace(0.0, 1.0, N_T, dtype=dtype)

    def lane(*p):
        sol = _retract_lane(*p, ts)
        return (sol.force, sol.contact_radius, sol.max_tensile_force, sol.jumpoff_time,
                sol.result._value)

    return jax.jit(jax.vmap(lane)), np.asarray(ts)


@functools.cache
def _retract_events_jacobian():
    ts = jnp.linspace(0.0, 1.0, N_T)

    def events(q, rad, depth, v):
        sol = _retract_lane(q[0], q[1], q[2], q[3], rad, depth, v, ts)
        return jnp.stack([sol.jumpoff_time, sol.jumpoff_force, sol.max_tensile_force])

    return jax.jit(jax.vmap(jax.jacfwd(events)))


def _check_lane_invariants(F, a, fmax, tj, ts, ok, scale_tol):
    assert np.all(ok)
    assert np.all(np.isfinite(F)) and np.all(np.isfinite(a)) and np.all(np.isfinite(fmax))
    for i in range(F.shape[0]):
        detached = np.isfinite(tj[i])
        if detached:
            after = ts > tj[i]
            assert np.all(F[i, after] == 0) and np.all(a[i, after] == 0)
            assert fmax[i] <= 0
        scale = np.max(np.abs(F[i]))
        assert fmax[i] <= np.min(F[i]) + scale_tol * scale


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
@BUDGET
@given(batch=BATCH)
def test_retract_invariants(dtype, batch):
    fn, ts = _retract_fn(dtype)
    args = _retract_inputs(batch, dtype)
    F, a, fmax, tj, res = (np.asarray(x) for x in fn(*args))
    assert F.dtype == dtype
    tol = 1e-12 if dtype == jnp.float64 else 1e-5
    _check_lane_invariants(F, a, fmax, tj, ts, _ok(res), tol)
    if dtype == jnp.float32:
        # float32 against float64 on the same (rounded) parameters, away from the jump-off
        fn64, _ = _retract_fn(jnp.float64)
        F64, _, fmax64, tj64, _ = (np.asarray(x) for x in fn64(*[a.astype(float) for a in args]))
        scale = np.max(np.abs(F64), axis=1, keepdims=True)
        near = np.abs(ts[None, :] - tj64[:, None]) < 1e-3
        err = np.where(near, 0.0, np.abs(F.astype(float) - F64) / scale)
        assert np.max(err) < 1e-3, np.max(err)
        np.testing.assert_allclose(fmax, fmax64, rtol=1e-3, atol=1e-6 * float(np.max(scale)))
    else:
        jac = np.asarray(_retract_events_jacobian()(jnp.stack(args[:4], axis=1), *args[4:]))
        detached = np.isfinite(tj)
        assert np.all(np.isfinite(jac[detached]))


BAD = [
    (0, -1.0, R.invalid_rheology), (0, np.nan, R.invalid_rheology),
    (2, 0.0, R.invalid_rheology), (1, np.inf, R.invalid_rheology),
    (3, -1.0, R.invalid_work_of_adhesion), (3, 0.0, R.invalid_work_of_adhesion),
    (4, -1.0, R.invalid_profile), (5, 0.0, R.invalid_depth), (5, np.nan, R.invalid_depth),
    (6, np.nan, R.invalid_velocity), (6, -1.0, R.invalid_velocity),
    (5, 1e4, R.implausible_input), (0, 1e20, R.implausible_input),
]


@BUDGET
@given(batch=BATCH, lane=st.integers(0, LANES - 1), bad=st.sampled_from(BAD))
def test_retract_bad_lane_is_reported_alone(batch, lane, bad):
    fn, _ = _retract_fn(jnp.float64)
    args = _retract_inputs(batch, jnp.float64)
    good = [np.asarray(x) for x in fn(*args)]
    k, value, item = bad
    args[k] = args[k].at[lane].set(value)
    F, _, _, _, codes = (np.asarray(x) for x in fn(*args))
    assert codes[lane] == item._value
    others = np.arange(LANES) != lane
    np.testing.assert_array_equal(codes[others], good[4][others])
    np.testing.assert_array_equal(F[others], good[0][others])
    assert np.all(np.isnan(F[lane]))


def test_float32_lift_never_advances():
    # the README tour's material, float32, depths over two decades (the former tolerance
    # of 1e-9 of the depth flagged a third of them as an advancing contact)
    rng = np.random.default_rng(7)
    depths = np.concatenate([[7.960262559627985e-06], 10 ** rng.uniform(-7, -5, 255)])
    f32 = jnp.float32
    ts = jnp.linspace(0.0, 0.1, 200, dtype=f32)

    def code(d):
        sol = jc.retract(jc.StandardModel(f32(1e6), f32(2e5), f32(1e4)), jc.Parabola(f32(1e-4)),
                         f32(0.05), ts, depth=d, velocity=f32(1e-4), throw=False)
        return sol.result._value

    codes = np.asarray(jax.jit(jax.vmap(code))(jnp.asarray(depths, f32)))
    assert np.all((codes == R.detached._value) | (codes == R.in_contact._value)), codes


# --------------------------------------------------------------------------------------
# simulate: approach, hold, lift
# --------------------------------------------------------------------------------------

SIM_T = 48
SIM_LANE = st.tuples(_log(2, 7), _log(-1.5, 0.5), _log(-2, 0.5), _log(-3.5, -0.5))
SIM_BATCH = st.lists(SIM_LANE, min_size=4, max_size=4)


@functools.cache
def _simulate_fn(dtype):
    ts = np.linspace(0.0, 1.0, SIM_T)
    rad, depth = 1e-4, 2e-6
    d = np.interp(ts, [0.0, 0.25, 0.5, 1.0], [0.0, depth, depth, -3 * depth])
    ts, d = jnp.asarray(ts, dtype), jnp.asarray(d, dtype)

    def lane(g0, g1, eta1, dg):
        sol = jc.simulate(jc.StandardModel(g0, g1, eta1), jc.Parabola(jnp.asarray(rad, dtype)),
                          dg, ts, d, grid=8, throw=False)
        return (sol.force, sol.contact_radius, sol.max_tensile_force, sol.jumpoff_time,
                sol.result._value)

    return jax.jit(jax.vmap(lane)), np.asarray(ts)


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
@BUDGET
@given(batch=SIM_BATCH)
def test_simulate_invariants(dtype, batch):
    fn, ts = _simulate_fn(dtype)
    p = np.array(batch)
    G0, G1 = p[:, 0], p[:, 0] * p[:, 1]
    args = [jnp.asarray(x, dtype) for x in (G0, G1, p[:, 2] * (G0 + G1), p[:, 3])]
    F, a, fmax, tj, res = (np.asarray(x) for x in fn(*args))
    assert F.dtype == dtype
    assert np.all(_ok(res))
    assert np.all(np.isfinite(F)) and np.all(np.isfinite(a)) and np.all(np.isfinite(fmax))
    assert np.all(F[a == 0] == 0)
    scale = np.max(np.abs(F), axis=1)
    tol = 1e-12 if dtype == jnp.float64 else 1e-5
    assert np.all(fmax <= np.min(F, axis=1) + tol * scale)
    # a monotone lift: no re-attachment after the jump-off
    for i in np.flatnonzero(np.isfinite(tj)):
        assert np.all(a[i, ts > tj[i]] == 0)
