"""Fitting the relaxed-start model: objective, search, optimisers, uncertainty, report.

The synthetic curves come from `jc.retract` (the forward model) with known parameters;
every fit here uses 3 × 60 samples and 4 starts, so one compilation serves most tests.
"""

import csv
import dataclasses
import json
import re
import types
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fitting
import jaxcontact as jc
from fitting import make_spec, prepare_curves, residuals

R = 12e-6  # relaxed contact radius sqrt(R D0) = 0.29 R: within the parabolic model
D0 = 1e-6
TRUE = {"G0": 10e3, "G1": 5e3, "eta1": 7.5e3, "work_of_adhesion": 1e-3}
NAMES = ("G0", "G1", "eta1", "work_of_adhesion")
SPEEDS = (0.5e-6, 2e-6, 8e-6)
N = 60
STARTS = 4


def _rheology(p=TRUE):
    return jc.StandardModel(p["G0"], p["G1"], p["eta1"])


def _curves(noise=0.0, seed=0, speeds=SPEEDS, lift=3e-6, p=TRUE, n=N):
    """Retract curves from a relaxed contact at D0; `noise` relative to the force range."""
    rng = np.random.default_rng(seed)
    out = []
    for v in speeds:
        ts = np.linspace(0.0, lift / v, n)
        sol = jc.retract(_rheology(p), jc.Parabola(R), work_of_adhesion=p["work_of_adhesion"],
                         depth=D0, ts=ts, velocity=v)
        f = np.asarray(sol.force)
        f = f + noise * np.ptp(f) * rng.standard_normal(n)
        out.append(fitting.Curve(time=ts, displacement=np.asarray(sol.displacement), force=f,
                                 segment=np.zeros(n, int), segment_names=("retract",)))
    return out


def _fit(curves, **kw):
    kw.setdefault("n_starts", STARTS)
    kw.setdefault("local_rounds", 1)  # the suite's time; the default's rounds: own tests
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fitting.IdentifiabilityWarning)
        warnings.simplefilter("ignore", fitting.ModelValidityWarning)
        return fitting.fit(curves, radius=R, progress=False, **kw)


def _errors(res):
    return {k: abs(res[k] / v - 1) for k, v in TRUE.items()}


@pytest.fixture(scope="module")
def noisy():
    return _curves(noise=0.01, seed=1)


@pytest.fixture(scope="module")
def noisy_fit(noisy):
    return _fit(noisy)


def test_curves_detach_from_a_receding_front():
    # the test data exercise the physics the fit must see: every curve detaches, after
    # its front receded (contact radius below the relaxed one before the jump-off)
    for c, v in zip(_curves(), SPEEDS, strict=True):
        sol = jc.retract(_rheology(), jc.Parabola(R), depth=D0, ts=c.time, velocity=v,
                         work_of_adhesion=TRUE["work_of_adhesion"])
        assert np.isfinite(float(sol.jumpoff_time)) and float(sol.jumpoff_time) < c.time[-1]
        a = np.asarray(sol.contact_radius)
        assert np.any((a > 0) & (a < 0.99 * a[0]))


@pytest.mark.parametrize("factor", [pytest.param(3.0, marks=pytest.mark.slow), 1 / 3])
def test_recovery_noiseless_from_a_bad_guess(factor):
    res = _fit(_curves(), initial={k: v * factor for k, v in TRUE.items()},
               fixed={"G1": TRUE["G1"]} if factor < 1 else None)
    err = _errors(res)
    # Δγ is known to the resolution of the jump-off sample (see test_jump_resolution)
    assert max(err.values()) < 0.01, err
    assert res.converged
    assert res.r_squared > 0.99999
    if factor < 1:  # a fixed parameter stays at its value, without an error
        i = res.names.index("G1")
        assert res.values[i] == pytest.approx(TRUE["G1"], rel=1e-14)
        assert res.fixed[i] and res.status[i] == "fixed"
        assert np.isnan(res.stderr[i]) and res.n_free == 3


def test_global_search_recovers_from_any_start():
    # every start the search uses, and the data-based guess, lead to the optimum in most
    # lanes; the best of them is the truth (noiseless)
    res = _fit(_curves(), initial={k: v * 30 for k, v in TRUE.items()})
    assert max(_errors(res).values()) < 0.01
    losses = np.sort(res.start_losses)
    assert losses[0] < 1e-6 * losses[-1] or losses[-1] < 1e-10


def test_local_starts_continue_step_along_the_ladder_and_stay_inside(noisy_fit):
    # the starts of a local round: the best end point first, then pattern moves through
    # it from the next-best distinct optima, then a hypercube around it; all inside the
    # bounds (finite free vectors) and as many as asked
    from fitting._start import PATTERN_STEPS, local_starts

    param = noisy_fit.parameterisation
    k = len(param.free)
    rng = np.random.default_rng(0)
    best = rng.normal(size=k)
    others = [best + 0.3 * rng.normal(size=k), best - 0.5 * rng.normal(size=k)]
    z_end = np.stack([others[0], best, others[1], best + 1e-5])  # the last: not distinct
    chi2 = np.array([2.0, 1.0, 3.0, 1.0 + 1e-9])
    zs = local_starts(param, z_end, chi2, 16, seed=3)
    assert zs.shape == (16, k) and np.all(np.isfinite(zs))
    np.testing.assert_array_equal(zs[0], best)
    steps = len(PATTERN_STEPS)
    for j, other in enumerate(others):  # in the order of their losses
        for m, step in enumerate(PATTERN_STEPS):
            np.testing.assert_allclose(zs[1 + j * steps + m], best + step * (best - other))
    rest = zs[1 + 2 * steps:]
    assert len({tuple(r) for r in rest}) == len(rest)  # distinct hypercube points
    # a round that reuses the compiled search: as many starts as the first one
    assert local_starts(param, z_end[:1], chi2[:1], 5).shape == (5, k)


def test_local_starts_of_a_chunk_equal_each_problem_alone(noisy_fit):
    # a force map's round: the starts of several problems in one batch, each its own
    # (other bounds, other widths, one optimum or three distinct ones, a non-finite end
    # point), equal to the same problem's starts alone (every problem's rows are its own,
    # to the bit)
    from fitting._start import local_starts, local_starts_batch

    base = noisy_fit.parameterisation
    k = len(base.free)
    rng = np.random.default_rng(4)
    params, zs, chi2s = [], [], []
    for i in range(4):
        shift = np.asarray(base.reference) * 0 + 0.1 * i
        param = eqx.tree_at(lambda q: (q.lower, q.upper), base,
                            (np.asarray(base.lower) - shift, np.asarray(base.upper) + shift))
        z = rng.normal(size=(8, k))
        if i == 1:
            z[:] = z[0] + 1e-6 * rng.normal(size=z.shape)  # all at one optimum
        if i == 2:
            z[3] = np.nan
        chi2 = rng.uniform(1.0, 2.0, 8)
        chi2[5] = np.inf if i == 3 else chi2[5]
        params.append(param), zs.append(z), chi2s.append(chi2)
    widen = [1.0, 1.0, 2.5, 6.25]
    got = local_starts_batch(params, np.stack(zs), np.stack(chi2s), 12, seed=7, widen=widen)
    assert got.shape == (4, 12, k)
    for i in range(4):
        alone = local_starts(params[i], zs[i], chi2s[i], 12, seed=7, widen=widen[i])
        np.testing.assert_array_equal(got[i], alone)
        assert np.all(np.isfinite(alone))


def test_widened_rounds_leave_out_pattern_moves_and_stay_in_the_wider_box(noisy_fit):
    # a round after one without progress: the best end point, then only hypercube points
    # within `widen` times the first round's half-widths (internal coordinates), inside
    # the bounds; the schedule widens twice, then stops; progress keeps the width
    from fitting._start import (
        LOCAL_LINEAR_WIDTH,
        LOCAL_LOG_WIDTH,
        LOCAL_MAX_WIDEN,
        LOCAL_WIDEN,
        PATTERN_STEPS,
        LocalRounds,
        local_starts,
    )

    param = noisy_fit.parameterisation
    free = list(param.free)
    best = np.asarray(param.z_of(param.to_internal(noisy_fit.values)))
    z_end = np.stack([best, best + 0.3])
    chi2 = np.array([1.0, 2.0])
    half = np.where(np.asarray(param.log)[free], LOCAL_LOG_WIDTH, LOCAL_LINEAR_WIDTH)
    u_best = np.asarray(param.internal(best))[free]
    for widen in (1.0, LOCAL_WIDEN, LOCAL_MAX_WIDEN):
        zs = local_starts(param, z_end, chi2, 12, seed=1, widen=widen)
        np.testing.assert_array_equal(zs[0], best)
        box = zs[1:] if widen > 1.0 else zs[1 + len(PATTERN_STEPS):]
        u = np.stack([np.asarray(param.internal(z))[free] for z in box])
        dist = np.abs(u - u_best) / half
        assert np.all(dist <= widen * (1 + 1e-9))
        if widen > 1.0:  # no pattern move (they lie on the line through z_end[1])
            assert np.all(dist.max(axis=0) > 0.3 * widen)  # the box is used, not a line
        else:
            np.testing.assert_allclose(zs[1], best + 0.5 * (best - z_end[1]))
    r = LocalRounds()
    r.update(True)
    assert (r.widen, r.done) == (1.0, False)
    r.update(False)
    assert (r.widen, r.done) == (LOCAL_WIDEN, False)
    r.update(False)
    assert (r.widen, r.done) == (LOCAL_MAX_WIDEN, False)
    r.update(False)
    assert r.done


def test_recovery_noisy_within_standard_errors(noisy_fit):
    res = noisy_fit
    assert max(_errors(res).values()) < 0.05
    assert 0.7 < res.reduced_chi2 < 1.3
    for k, v in TRUE.items():
        i = res.names.index(k)
        assert res.status[i] == "ok"
        assert abs(res.values[i] - v) < 4 * res.stderr[i], (k, res.values[i], res.stderr[i])


@pytest.mark.slow
def test_lbfgs_reaches_the_lm_optimum(noisy, noisy_fit):
    lb = _fit(noisy, optimiser="lbfgs")
    assert lb.optimiser == "lbfgs" and noisy_fit.optimiser == "lm"
    # L-BFGS carries no model: the finish evaluates it (the same quantities as the search's)
    np.testing.assert_allclose(lb.model_contact_radius, lb.model_solution.contact_radius,
                               rtol=1e-9, atol=1e-12 * R)
    assert lb.converged
    # the same optimum, far inside the statistical uncertainty (L-BFGS may stop a little
    # early at a kink of the piecewise-smooth loss, where a sample interval begins)
    assert lb.chi2 == pytest.approx(noisy_fit.chi2, rel=1e-3)
    assert np.all(np.abs(lb.values - noisy_fit.values) < 0.2 * noisy_fit.stderr)
    np.testing.assert_allclose(lb.stderr, noisy_fit.stderr, rtol=0.05)


def test_bad_options_name_the_argument():
    c = _curves(n=20, speeds=(8e-6,))
    for kw, needle in (({"optimiser": "adam"}, "optimiser"), ({"n_starts": 0}, "n_starts"),
                       ({"contact_point": "guess"}, "contact_point"),
                       ({"rheology": "prony:0"}, "prony:N"),
                       ({"spring_constant": -1.0, "model": "history"}, "spring_constant"),
                       ({"bounds": {"G0": (5.0, 1.0)}}, "bounds for 'G0'"),
                       ({"fixed": {"G9": 1.0}}, "fixed: unknown parameter"),
                       ({"initial": {"eta1": -1.0}}, "'eta1' must be finite")):
        with pytest.raises(ValueError, match=needle):
            fitting.fit(c, radius=R, progress=False, **kw)
    with pytest.raises(ValueError, match="either radius or profile"):
        fitting.fit(c, radius=R, profile=jc.Parabola(R), progress=False)


def test_reused_jacobian_matches_a_fresh_one(noisy_fit):
    """fit() reuses the search's last Jacobian (converted from z to the internal
    coordinates through the bounds); a fresh forward-mode Jacobian at the optimum gives
    the same standard errors."""
    from fitting._objective import internal_jacobian
    from fitting._uncertainty import gauss_newton

    res = noisy_fit
    param = res.parameterisation
    u = param.to_internal(res.values)
    r, J = internal_jacobian(res.spec, param, jnp.asarray(u), res.data)
    fresh = gauss_newton(param, u, r, J, res.names, n_data=res.n_data,
                         weights=np.asarray(res.data.weight).ravel(), warn=False)
    np.testing.assert_allclose(res.stderr, fresh.stderr, rtol=1e-5)
    np.testing.assert_allclose(res.correlation, fresh.correlation, rtol=1e-5, atol=1e-8)
    assert res.reduced_chi2 == pytest.approx(fresh.reduced_chi2, rel=1e-9)


def test_delta_method_errors_and_statuses():
    """The derived quantities' and Tabor's errors (one function): sqrt(g C g) over the
    parameters a quantity depends on, by hand on a small covariance."""
    from fitting._uncertainty import delta_method

    cov = np.array([[4.0, 1.0, np.nan], [1.0, 9.0, np.nan], [np.nan, np.nan, np.nan]])
    status = ["ok", "ok", "not determined"]
    grad = np.array([[1.0, 2.0, 0.0],  # 1*4*1 + 2*(1*1*2) + 2*9*2 = 44
                     [0.0, 0.0, 3.0],  # depends on a parameter not determined
                     [0.0, 0.0, 0.0]])  # depends on nothing: exact
    se, ok = delta_method(grad, cov, status)
    assert se[0] == pytest.approx(np.sqrt(44.0), rel=1e-15) and ok[0]
    assert np.isnan(se[1]) and not ok[1]
    assert se[2] == 0.0 and ok[2]
    # a fixed parameter contributes nothing, whatever its gradient
    se, ok = delta_method([[1.0, 2.0, 5.0]], cov, ["ok", "ok", "fixed"])
    assert se[0] == pytest.approx(np.sqrt(44.0), rel=1e-15) and ok[0]
    # a covariance entry the quantity needs is not finite: no error (its statuses are ok)
    bad = cov.copy()
    bad[0, 1] = bad[1, 0] = np.inf
    se, ok = delta_method(grad[:1], bad, status)
    assert np.isnan(se[0]) and ok[0]


def test_stderr_against_monte_carlo():
    """Gauss-Newton standard errors agree with the scatter of refits of noisy copies."""
    clean = _curves()
    fits = []
    for seed in range(12):
        rng = np.random.default_rng(100 + seed)
        noisy = [c.replace(force=c.force + 0.01 * np.ptp(c.force) * rng.standard_normal(len(c)))
                 for c in clean]
        res = _fit(noisy, initial=TRUE)
        fits.append(np.log(res.values))
        if seed == 0:
            rel_se = res.stderr / res.values
    scatter = np.std(np.array(fits), axis=0, ddof=1)
    ratio = rel_se / scatter
    # 12 refits: the scatter itself is uncertain by ~20 %
    assert np.all((ratio > 0.5) & (ratio < 2.0)), ratio


def test_parameter_at_a_bound_is_reported_not_crashed(tmp_path, monkeypatch):
    # eta1 confined far below the truth: the data push it to the upper bound
    from fitting import _optimise
    from fitting._uncertainty import gauss_newton

    calls = []
    real = _optimise.internal_jacobian
    monkeypatch.setattr(_optimise, "internal_jacobian",
                        lambda *a: (calls.append(1), real(*a))[1])
    res = _fit(_curves(noise=0.01, seed=2), bounds={"eta1": (1e2, 1e3)})
    i = res.names.index("eta1")
    # its logistic saturates there, so the search's Jacobian cannot be divided back in
    # that column; the parameter is left out of the covariance, so the finish does not
    # compile the model's own Jacobian (a second compilation of the model); the errors
    # equal those of the covariance from that Jacobian (the second route)
    assert calls == []
    param = res.parameterisation
    u = param.to_internal(res.values)
    r, J = (np.asarray(x) for x in real(res.spec, param, jnp.asarray(u), res.data))
    unc = gauss_newton(param, u, r, J, res.names, n_data=res.data.n_measured,
                       weights=np.asarray(res.data.weight).ravel(), warn=False)
    assert unc.status == res.status
    np.testing.assert_allclose(res.stderr, unc.stderr, rtol=1e-7)
    np.testing.assert_allclose(res.covariance, unc.covariance, rtol=1e-7, atol=0)
    assert res["eta1"] == pytest.approx(1e3, rel=1e-3)
    assert res.status[i] == "at upper bound" and np.isnan(res.stderr[i])
    assert any(w.startswith("eta1 is at its upper bound") for w in res.warnings)
    assert res.n_free == 3
    table = json.loads(fitting.write_report(res, tmp_path)["json"].read_text())
    assert table["eta1_Pa_s"]["stderr"] is None
    assert table["eta1_Pa_s"]["status"] == "at upper bound"


def test_identifiability_warning_eta1():
    """Lift much slower than the relaxation: eta1 cannot be determined."""
    slow = dict(TRUE, eta1=TRUE["eta1"] * 1e-4)  # tau = 50 µs, lift ~ 1 s
    curves = _curves(noise=0.01, speeds=(2e-6, 3e-6, 4e-6), p=slow)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = fitting.fit(curves, radius=R, initial=slow, n_starts=STARTS, progress=False)
    messages = [str(w.message) for w in caught
                if issubclass(w.category, fitting.IdentifiabilityWarning)]
    i = res.names.index("eta1")
    assert any(m.startswith("eta1 ") for m in messages), messages
    # never a confident number: either its error is large or it is at its bound
    assert res.status[i] != "ok"
    assert not (np.isfinite(res.stderr[i]) and res.stderr[i] < 0.5 * res.values[i])


def test_too_few_samples_is_not_a_confident_fit(noisy_fit):
    # 3 samples for 4 free parameters: nothing is determined (a fit used to report
    # R² = 1 with relative errors of 1e-15)
    from fitting._uncertainty import gauss_newton

    param = noisy_fit.parameterisation
    u = param.to_internal(noisy_fit.values)
    J = np.random.default_rng(0).standard_normal((3, 4))
    unc = gauss_newton(param, u, np.zeros(3), J, noisy_fit.names, n_data=3, warn=False)
    assert unc.status == ["not determined"] * 4
    assert np.all(np.isinf(unc.stderr) | np.isnan(unc.stderr))
    assert any("too few samples" in w for w in unc.warnings)


def test_blind_direction_gets_an_infinite_error(noisy_fit):
    # a column of J that is a combination of others: the data see only the combination;
    # both parameters get an infinite error (dropping the direction would report tiny
    # ones), the others keep theirs
    from fitting._uncertainty import gauss_newton

    param = noisy_fit.parameterisation
    u = param.to_internal(noisy_fit.values)
    rng = np.random.default_rng(1)
    J = rng.standard_normal((50, 4))
    J[:, 2] = 2.0 * J[:, 1]
    r = 0.1 * rng.standard_normal(50)
    unc = gauss_newton(param, u, r, J, noisy_fit.names, n_data=50, warn=False)
    assert np.isinf(unc.stderr[1]) and np.isinf(unc.stderr[2])
    assert np.isfinite(unc.stderr[0]) and np.isfinite(unc.stderr[3])
    assert unc.status == ["ok", "not determined", "not determined", "ok"]


def test_residuals_at_truth_vanish_and_are_continuous(noisy):
    spec = make_spec()
    data = prepare_curves(_curves(), spec, radius=R)
    p = jnp.array([TRUE[k] for k in NAMES])
    r = residuals(p, data, spec)
    assert r.shape == (3 * N,)
    # at the truth only the two samples at each jump-off are not exactly matched (the model
    # resolves its jump inside the sample interval): |r| <= sqrt(12) there (their noise
    # carries the jump / sqrt(12), see fitting._prepare), round-off elsewhere
    a = np.abs(np.asarray(r))
    assert np.max(a) <= np.sqrt(12.0) + 1e-6
    assert np.sum(a > 1e-6) <= 2 * 3
    # continuity in Δγ across the jump-offs (noisy data, realistic weights): refining the
    # scan tenfold shrinks the largest change between neighbours about tenfold; a jump
    # of the loss would not shrink
    data = prepare_curves(noisy, spec, radius=R)
    # the loss as one compiled function of the scale (442 eager calls dispatch every
    # operation: 4x the CPU time; the same values to round-off)
    loss = jax.jit(lambda s: jnp.sum(residuals(p.at[3].multiply(s), data, spec) ** 2))

    def chi2(scales):
        return np.array([float(loss(s)) for s in scales])

    coarse = chi2(np.linspace(0.96, 1.04, 41))
    fine = chi2(np.linspace(0.96, 1.04, 401))
    assert np.all(np.isfinite(fine))
    assert np.max(np.abs(np.diff(fine))) < 0.25 * np.max(np.abs(np.diff(coarse)))


def _step_solution(ts, force, t_jump):
    # a forward solution whose force is `force` until `t_jump` and 0 after
    f = np.where(ts < t_jump, force, 0.0)
    j = np.interp(t_jump, ts, force)
    return types.SimpleNamespace(force=jnp.asarray(f)[None],
                                 jumpoff_time=jnp.asarray([t_jump]),
                                 jumpoff_force=jnp.asarray([j]))


def test_early_jumpoff_never_lowers_the_loss():
    """Every sample counts: with data that detach at t_d, a model identical to the data
    but detaching at any earlier time t* < t_d has a larger loss, the more so the earlier
    (under the old ramp objective the samples after the model's jump-off were dropped)."""
    spec = make_spec()
    n = 200
    ts = np.linspace(0.0, 1.0, n)
    attached = -1e-7 * (1.0 + ts)  # an adhesive (tensile) force
    t_d = 0.8037
    f = np.where(ts < t_d, attached, 0.0)
    curve = fitting.Curve(time=ts, displacement=1e-6 * (1 - ts), force=f + 1e-10 * np.sin(ts),
                          segment=np.zeros(n, int), segment_names=("retract",))
    data = prepare_curves([curve], spec, radius=R)
    loss = []
    grid = np.linspace(0.3, t_d, 400)
    for t_star in grid:
        model = fitting.effective_force(_step_solution(ts, attached, t_star), data)
        r = np.asarray(jnp.sqrt(data.weight) * (model - data.force) / data.noise)
        loss.append(float(np.sum(r * r)))
    loss = np.array(loss)
    assert np.all(np.diff(loss) <= 1e-9 * loss.max()), "moving t* earlier lowered the loss"
    assert loss[0] > 100 * loss[-1]
    # and the loss is continuous in t* (no step where t* crosses a sample)
    assert np.max(np.abs(np.diff(loss))) < 0.02 * (loss.max() - loss.min())


def test_loss_is_continuous_where_the_jumpoff_leaves_the_simulated_times():
    """The models are simulated up to the last sample: a model whose jump-off time t* tends
    to t_end from below must tend to the loss of the same model still attached at t_end (no
    jump-off found). Measured on the README's oocyte curve: a last interval mirrored beyond
    t_end made the loss drop by 1.7 % at that edge, a spurious optimum that a search found."""
    spec = make_spec()
    n = 50
    ts = np.linspace(0.0, 1.0, n)
    attached = -1e-7 * (1.0 + ts)  # an adhesive (tensile) force, still attached at t_end
    curve = fitting.Curve(time=ts, displacement=1e-6 * (1 - ts),
                          force=attached + 1e-10 * np.sin(7 * ts),
                          segment=np.zeros(n, int), segment_names=("retract",))
    data = prepare_curves([curve], spec, radius=R)

    def loss(sol):
        model = fitting.effective_force(sol, data)
        r = np.asarray(jnp.sqrt(data.weight) * (model - data.force) / data.noise)
        return float(np.sum(r * r))

    still_attached = types.SimpleNamespace(force=jnp.asarray(attached)[None],
                                           jumpoff_time=jnp.asarray([np.nan]),
                                           jumpoff_force=jnp.asarray([np.nan]))
    l_end = loss(still_attached)
    gaps = [abs(loss(_step_solution(ts, attached, 1.0 - eps)) - l_end)
            for eps in (1e-3, 1e-5, 1e-7)]
    one_sample = loss(_step_solution(ts, attached, ts[-2] - 1e-9)) - l_end  # one sample lost
    assert one_sample > 0
    assert gaps[0] < 0.2 * one_sample
    assert gaps[2] < 1e-3 * one_sample and gaps[2] < gaps[0]


def test_jump_resolution_in_the_standard_error():
    """The jump-off time is known from point samples only to the sampling interval; the
    two samples at the measured jump carry that in their noise, so a pinned jump-off does
    not give Δγ a precision the samples lack. Refits of noisy copies: the truth lies within
    3 standard errors of Δγ in every refit."""
    for seed in range(4):
        res = _fit(_curves(noise=0.01, seed=20 + seed), initial=TRUE)
        i = res.names.index("work_of_adhesion")
        assert abs(res.values[i] - TRUE["work_of_adhesion"]) < 3 * res.stderr[i]


def test_select_samples_keeps_the_structure():
    from fitting._prepare import sample_weights

    n = 5000
    f = np.r_[np.linspace(0, 1, 2000), np.exp(-np.linspace(0, 5, 2000)), np.zeros(1000)]
    seg = np.r_[np.zeros(2000, int), np.ones(2000, int), 2 * np.ones(1000, int)]
    pick = fitting.select_samples(f, seg, 200, keep=[4200, 4201])
    assert pick.size <= 210 and np.all(np.diff(pick) > 0)
    for i in (0, 1999, 2000, 3999, 4000, 4999, 4200, 4201):
        assert i in pick
    # denser where the force changes fast (start of the relaxation) than on the flat tail
    dense = np.sum((pick >= 2000) & (pick < 2400))
    flat = np.sum((pick >= 4500) & (pick < 4900))
    assert dense > 2 * flat
    w = sample_weights(pick, n)
    assert w.sum() == n and np.all(w >= 1)


def test_report_files_and_summary(noisy_fit, tmp_path):
    res = noisy_fit
    paths = fitting.write_report(res, tmp_path / "out")
    table = json.loads(paths["json"].read_text())
    for key in ("G0_Pa", "G1_Pa", "eta1_Pa_s", "work_of_adhesion_J_m2"):
        assert set(table[key]) >= {"value", "stderr", "relative_stderr", "status"}
    for key in ("r_squared", "r_squared_contact", "reduced_chi2", "aic", "bic", "correlation",
                "G_inf_Pa", "tau_s", "start_losses", "model_selection"):
        assert key in table
    rows = paths["csv"].read_text().splitlines()
    assert rows[0] == ("parameter,unit,value,stderr,relative_stderr,status,fixed,"
                       "stderr_noise,stderr_basis,derived")
    # 4 parameters, 6 derived (E0, E1, G_inf, E_inf, tau, Tabor's mu)
    assert len(rows) == 5 + 6
    samples = paths["samples"].read_text().splitlines()
    assert samples[0] == ("curve,segment,time_s,indentation_m,force_N,model_force_N,residual,"
                          "weight,contact_radius_m")
    assert len(samples) == 1 + 3 * N
    # fit.csv reproduces chi2: sum of weight * residual^2
    arr = np.array([[float(x) for x in line.split(",")[2:]] for line in samples[1:]])
    assert np.sum(arr[:, 5] * arr[:, 4] ** 2) == pytest.approx(res.chi2, rel=1e-9)
    text = str(res)
    assert "G0_Pa" in text and "R^2 (in contact)" in text and len(text.splitlines()) < 30
    assert "G0=" in repr(res)


def test_r_squared_in_contact_excludes_the_free_tail(noisy_fit):
    # the samples after the jump-off, where data and model are free, are not in contact;
    # R² in contact is R² over the others (each kept sample weighted)
    res = noisy_fit
    mask = res.in_contact
    after = np.asarray(res.model_solution.contact_radius) == 0
    sigma = np.asarray(res.data.sigma)[:, None]
    free_tail = after & (np.abs(np.asarray(res.data.force)) < 3 * sigma)
    assert free_tail.sum() > 20 and not np.any(mask & free_tail)
    f, m = np.asarray(res.data.force)[mask], res.model_force[mask]
    w = np.asarray(res.data.weight)[mask]
    mean = np.sum(w * f) / np.sum(w)
    r2 = 1 - np.sum(w * (m - f) ** 2) / np.sum(w * (f - mean) ** 2)
    assert res.r_squared_contact == pytest.approx(r2, rel=1e-12)


def test_validity_warnings():
    # retract-only curves: the relaxed start is the user's statement, nothing in the data
    # contradicts it (the notebook's synthetic relaxed-start fit was warned before)
    with warnings.catch_warnings():
        warnings.simplefilter("error", fitting.ModelValidityWarning)
        res = fitting.fit(_curves(), radius=R, n_starts=STARTS, progress=False)
    assert not any("hold" in w for w in res.warnings)
    assert not any("contact radius reaches" in w for w in res.warnings)  # a0 = 0.29 R
    # a measured approach straight into the lift (no hold) contradicts the relaxed start;
    # one of the three curves has one (the fit keeps the retracts: the shapes, and so the
    # compiled search, of the fit above)
    c, *others = _curves()
    k = 8
    t_app = np.linspace(-1.0, 0.0, k + 1)[:-1]
    approach = fitting.Curve(
        time=np.r_[t_app, c.time], displacement=np.r_[D0 * (t_app + 1.0), c.displacement],
        force=np.r_[np.linspace(0.0, c.force[0], k), c.force],
        segment=np.r_[np.zeros(k, int), np.ones(len(c), int)],
        segment_names=("approach", "retract"))
    with pytest.warns(fitting.ModelValidityWarning, match="an approach and no hold"):
        res = fitting.fit([approach, *others], radius=R, n_starts=STARTS, progress=False)
    assert any("1 curve(s) have an approach and no hold" in w for w in res.warnings)


# --------------------------------------------------------------------------------------
# honesty: model inadequacy, the meaning of the error bars, the contact point, no contact
# --------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def inadequate_fit():
    # the curves with a systematic distortion the model cannot follow (10 % of the force
    # range, two periods) over 0.2 % noise: residuals far above the noise
    out = []
    for k, c in enumerate(_curves(noise=0.002, seed=3)):
        ripple = 0.1 * np.ptp(c.force) * np.sin(4 * np.pi * np.linspace(0, 1, len(c)) + k)
        out.append(c.replace(force=c.force + ripple))
    return _fit(out)


def test_inadequate_model_is_flagged_everywhere(inadequate_fit, tmp_path):
    res = inadequate_fit
    paths = fitting.write_report(res, tmp_path)
    # the reduced chi2 from fit.csv alone (sum of weight * residual^2 over m - k)
    with paths["samples"].open() as fh:
        rows = list(csv.DictReader(fh))
    chi2 = sum(float(r["weight"]) * float(r["residual"]) ** 2 for r in rows)
    red = chi2 / (len(rows) - res.n_free)
    assert red > 25 and red == pytest.approx(res.reduced_chi2, rel=1e-9)
    assert "model_inadequate" in res.flags and not res.adequate
    assert "model inadequate" in res.summary() and "not the measurement precision" in \
        res.summary()
    table = json.loads(paths["json"].read_text())
    assert table["status"] == "flagged" and table["adequate"] is False
    assert "model_inadequate" in table["flags"]
    assert "not the measurement precision" in table["stderr_basis"]
    assert table["stderr_scale"] == pytest.approx(np.sqrt(red), rel=1e-9)
    with paths["csv"].open() as fh:
        prow = list(csv.DictReader(fh))
    assert all(r["stderr_basis"] == "noise x sqrt(reduced chi2) (model inadequate)"
               for r in prow)
    # the figure says so in red
    from jaxcontact_cli import plot_fit

    fig = plot_fit(res)
    texts = " ".join(t.get_text() for t in [*fig.texts, *(t for a in fig.axes for t in a.texts)])
    assert "MODEL INADEQUATE" in texts and "√χ²_red" in texts and "E_inf" in texts


def test_force_after_detachment_named_against_constructed_residuals():
    # one retract of 200 samples: the model in contact up to sample 79, free after it
    from fitting._quality import force_after_detachment

    rng = np.random.default_rng(0)
    n, sig = 200, 1e-11
    ts = np.linspace(0.0, 2.0, n)[None]
    model = np.where(np.arange(n) < 80, -5e-10, 0.0)[None]
    radius = np.where(np.arange(n) < 80, 1e-6, 0.0)[None]
    seg = np.full((1, n), 2)  # SEGMENTS: approach, hold, retract
    ones = np.ones((1, n))

    def named(plateau, weight=ones, rad=radius, misfit=0.0):
        f = model + sig * rng.standard_normal((1, n)) + np.where(np.arange(n) >= 80,
                                                                 plateau, misfit)
        return force_after_detachment(ts, f, model, sig * ones, weight, ones, seg, rad)

    assert named(0.0) == []  # noise alone: the mean residual ~ 1/sqrt(120) sigma
    assert named(-2 * sig) == []  # below 3 sigma on average
    (msg,) = named(-5 * sig)  # a tether's plateau
    assert "t = 0.794 s" in msg and "below the model's free force (tensile)" in msg
    mean = float(re.search(r"on average (\S+) N below", msg).group(1))
    assert mean == pytest.approx(5 * sig, rel=0.1)  # the plateau, within the noise's mean
    assert "120 measured samples" in msg and "--retract-baseline separate" in msg
    assert "tethers" in msg and "--baseline linear --retract-baseline include" in msg
    assert re.search(r"9\d % of the curve's chi2", msg)  # 120 * 25 of 80 + 120 * 26
    # the same plateau beside a misfit of 100 sigma in contact: 0.4 % of chi2, not named
    assert named(-5 * sig, misfit=100 * sig) == []
    assert len(named(-5 * sig, misfit=10 * sig)) == 1  # 27 %
    (msg,) = named(+5 * sig)
    assert "above the model's free force (compressive)" in msg
    # the same plateau standing for fewer than 10 measured samples: not named
    few = np.where(np.arange(n) >= 80, 0.05, 1.0)[None]
    assert named(-5 * sig, weight=few) == []
    # two kept samples after a late jump-off, however many they stand for: not named
    late = np.where(np.arange(n) < 198, 1e-6, 0.0)[None]
    assert named(-50 * sig, weight=20 * ones, rad=late) == []
    # the model still in contact at the last sample, or never on the retract: nothing after
    assert named(-5 * sig, rad=np.full((1, n), 1e-6)) == []
    assert named(-5 * sig, rad=np.zeros((1, n))) == []


def test_tether_plateau_after_the_jump_off_is_flagged(noisy):
    # the first curve's force held 10 sigma below the baseline after its measured jump-off
    # (a membrane tether): flagged, naming that curve; the clean curves are not named
    c0 = noisy[0]
    sig = 0.01 * np.ptp(_curves()[0].force)
    jump = int(np.argmax(np.diff(c0.force))) + 1  # the rise at the jump-off
    assert jump < len(c0) - 15
    tether = c0.replace(force=np.where(np.arange(len(c0)) >= jump, c0.force - 10 * sig,
                                       c0.force))
    res = _fit([tether, *noisy[1:]])
    msg = res.flags["force_after_detachment"]
    assert msg.startswith("curve 0: after the model's jump-off") and "curve 1" not in msg
    assert "tensile" in msg and "force_after_detachment" in res.summary()
    from jaxcontact_cli._plots import _FLAG_TEXT

    assert "force_after_detachment" in _FLAG_TEXT


def test_retract_offset_flagged_and_removed_as_the_flag_advises():
    # a raw approach-hold-retract curve: the Hertz approach of the relaxed modulus, a hold
    # much longer than the relaxation, the relaxed-start retract of `jc.retract` (1 % noise),
    # and the whole retract 6 sigma lower (viscous drag on the cantilever). The loader's
    # default leaves the offset: flagged after the jump-off, and the fit biased; with
    # retract_baseline="separate" (the flag's advice) the flag goes and the truth returns
    v, lift = 2e-6, 3e-6
    ta = np.linspace(0.0, 1.0, 150, endpoint=False)
    th = 1.0 + np.linspace(0.0, 5.0, 100, endpoint=False)
    tr = np.linspace(0.0, lift / v, 120)
    sol = jc.retract(_rheology(), jc.Parabola(R), work_of_adhesion=TRUE["work_of_adhesion"],
                     depth=D0, ts=tr, velocity=v)
    g_inf = TRUE["G0"] * TRUE["G1"] / (TRUE["G0"] + TRUE["G1"])
    ua = -1e-6 + v * ta
    f = np.r_[16 / 3 * g_inf * np.sqrt(R) * np.clip(ua, 0.0, None) ** 1.5,
              np.full(100, float(sol.force[0])), np.asarray(sol.force)]
    sig = 0.01 * float(np.ptp(np.asarray(sol.force)))
    drag = np.r_[np.zeros(250), np.full(120, -6 * sig)]
    raw = fitting.Curve(
        time=np.r_[ta, th, 6.0 + tr], displacement=np.r_[ua, np.full(100, D0), D0 - v * tr],
        force=f + drag + sig * np.random.default_rng(4).standard_normal(370),
        segment=np.repeat([0, 1, 2], [150, 100, 120]),
        segment_names=("approach", "hold", "retract"))
    fits = {}
    for rb in (None, "separate"):
        curve = fitting.preprocess(raw, baseline="constant", contact_point="fit",
                                   retract_baseline=rb)
        fits[rb] = _fit([curve], model="relaxed", contact_point="detect", n_starts=16,
                        local_rounds=3)  # one speed: the default search
    assert "force_after_detachment" in fits[None].flags
    assert "below the model's free force (tensile)" in fits[None].flags[
        "force_after_detachment"]
    assert fits["separate"].flags == {}
    assert fits["separate"].chi2 < 0.1 * fits[None].chi2
    # the truth within 3 standard errors and 10 %: the contact, detected by the onset's
    # power law in the noise, lies ~12 nm off (1 % of the depth, up to ~8 % of a modulus)
    good, bad = fits["separate"], fits[None]
    for k, value in TRUE.items():
        se = good.stderr[good.names.index(k)]
        assert abs(good[k] - value) < 0.1 * value + 3 * se, (k, good[k], se)
    assert abs(bad["G1"] / TRUE["G1"] - 1) > 0.15  # the offset's bias


def test_good_fit_is_ok_and_reports_its_quality(noisy_fit, tmp_path):
    res = noisy_fit
    assert res.flags == {} and res.adequate and res.convergence["reason"] == "converged"
    (seg,) = res.segments  # the relaxed model fits the retract only
    assert seg.segment == "retract" and seg.described
    assert seg.n_measured == res.n_data == 180
    # without subsampling every weight is 1: weighted and unweighted R² agree, and the
    # segment's reduced chi2 is chi2 per sample
    assert res.r_squared_unweighted == pytest.approx(res.r_squared, rel=1e-12)
    assert seg.reduced_chi2 == pytest.approx(res.chi2 / 180, rel=1e-9)
    table = json.loads(fitting.write_report(res, tmp_path)["json"].read_text())
    assert table["status"] == "ok" and table["segments"][0]["segment"] == "retract"
    assert "weighted" in table["r_squared_weighting"]
    assert "weighted by the measured samples" in res.summary()


def test_stderr_is_scaled_by_the_reduced_chi2_lmfit_style(noisy_fit):
    # lmfit's scale_covar: with the noise sigma wrong by a factor c (residuals and Jacobian
    # scaled by 1/c) the standard errors do not change, the reduced chi2 does by 1/c²;
    # the noise-only error (stderr / sqrt(reduced chi2)) scales with c
    from fitting._uncertainty import gauss_newton

    param = noisy_fit.parameterisation
    u = param.to_internal(noisy_fit.values)
    rng = np.random.default_rng(5)
    J = rng.standard_normal((180, 4))
    r = 3.0 * rng.standard_normal(180)
    one = gauss_newton(param, u, r, J, noisy_fit.names, n_data=180, warn=False)
    c = 10.0
    other = gauss_newton(param, u, r / c, J / c, noisy_fit.names, n_data=180, warn=False)
    np.testing.assert_allclose(other.stderr, one.stderr, rtol=1e-10)
    assert other.reduced_chi2 == pytest.approx(one.reduced_chi2 / c**2, rel=1e-12)
    noise_only = np.sqrt(np.diag(np.linalg.inv(J.T @ J))) * np.abs(param.dnatural(u))
    np.testing.assert_allclose(one.stderr / np.sqrt(one.reduced_chi2), noise_only, rtol=1e-8)


def test_contact_outside_the_data_is_flagged():
    from fitting._quality import contact_outside

    # an approach from -0.3 µm to 1 µm; the data show no force before the contact at 0
    d = np.linspace(-0.3e-6, 1e-6, 50)[None, :]
    f = np.where(d > 0, 1.0 * d, 0.0)  # 1 N/m
    noise = np.full_like(d, 1e-10)
    valid = np.ones_like(d)
    seg = np.zeros(d.shape, int)
    for delta, expect in ((0.5e-6, "before the first"), (-2e-6, "never touches"),
                          (0.1e-6, None)):
        model = np.where(d + delta > 0, d + delta, 0.0)
        msgs = contact_outside(d, f, model, noise, valid, seg, (d + delta > 0) * 1e-6, delta)
        if expect is None:
            assert msgs == []
        else:
            assert len(msgs) == 1 and expect in msgs[0], msgs
    # the first sample 0.2 µm inside the model's contact: 200 nN against 0 (2000 sigma)
    model = d + 0.5e-6
    (msg,) = contact_outside(d, f, model, noise, valid, seg, np.ones_like(d), 0.5e-6)
    assert "lies 2e-07 m before" in msg and "2000 sigma" in msg


def test_no_contact_signal_fails_with_a_reason():
    from fitting._quality import check_contact_signal

    rng = np.random.default_rng(0)
    n = 200
    t = np.linspace(0, 1, 2 * n)
    sigma = 1e-11
    noise = sigma * rng.standard_normal(2 * n)
    # an approach with noise only, a retract with a constant drag offset (the QI curves)
    f = noise + np.r_[np.zeros(n), np.full(n, -14 * sigma)]
    d = np.r_[np.linspace(0, 1e-6, n), np.linspace(1e-6, 0, n)]
    curve = fitting.Curve(time=t, displacement=d, force=f, segment=np.repeat([0, 1], n),
                          segment_names=("approach", "retract"), source="qi")
    with pytest.raises(ValueError, match=r"curve 0 \(qi\): no contact in the data"):
        check_contact_signal([curve], make_spec("history"))
    # the same curve pressed into the sample: a force rise of 20 sigma at the end
    rise = np.where((np.arange(2 * n) < n) & (d > 0.5e-6), 40 * sigma * (d - 0.5e-6) / 0.5e-6,
                    0.0)
    pressed = curve.replace(force=f + rise)
    check_contact_signal([pressed], make_spec("history"))


def test_young_moduli_and_relaxed_modulus_with_errors(noisy, noisy_fit, tmp_path):
    # an independent route: the Prony series with one arm is the standard model
    # reparameterised (G_inf, G_1 = G0 - G_inf, tau); its G_inf is a fitted parameter with
    # its own Gauss-Newton error, which the delta method on the standard fit must give
    prony = _fit(noisy, rheology="prony:1")
    std = {d["name"]: d for d in noisy_fit.derived}
    other = {d["name"]: d for d in prony.derived}
    i = prony.names.index("G_inf")
    assert std["G_inf"]["value"] == pytest.approx(prony.values[i], rel=1e-5)
    assert std["G_inf"]["stderr"] == pytest.approx(prony.stderr[i], rel=2e-3)
    assert std["E_inf"]["value"] == pytest.approx(3 * prony.values[i], rel=1e-5)
    assert std["E_inf"]["stderr"] == pytest.approx(3 * prony.stderr[i], rel=2e-3)
    # the glass modulus: G0 of the standard model, G_inf + G_1 of the Prony series
    assert other["E_0"]["value"] == pytest.approx(3 * noisy_fit["G0"], rel=1e-5)
    assert other["E_0"]["stderr"] == pytest.approx(3 * noisy_fit.stderr[0], rel=2e-3)
    assert std["E0"]["value"] == 3 * noisy_fit["G0"] and std["E0"]["status"] == "ok"
    # everywhere: console, JSON, CSV
    assert "E_inf_Pa" in noisy_fit.summary() and "nu = 0.5" in noisy_fit.summary()
    paths = fitting.write_report(noisy_fit, tmp_path)
    table = json.loads(paths["json"].read_text())
    assert table["E_inf_Pa"]["derived"] is True
    assert table["E_inf_Pa"]["stderr"] == pytest.approx(std["E_inf"]["stderr"])
    with paths["csv"].open() as fh:
        rows = {r["parameter"]: r for r in csv.DictReader(fh)}
    assert rows["E1"]["derived"] == "True" and float(rows["E1"]["value"]) == pytest.approx(
        3 * noisy_fit["G1"])


def test_host_transforms_match_the_traced_ones():
    # the numpy copies of the free-vector map (starts, finish) against the traced map and
    # its forward-mode derivative; z beyond +-40 saturates the logistic

    info = fitting.parameter_info(make_spec("relaxed", "standard", contact_offset=True))
    names = [n for n, _, _ in info]
    ref = {"G0": 1e4, "G1": 5e3, "eta1": 7e3, "work_of_adhesion": 1e-3,
           "contact_offset": 1e-7}
    param = fitting.make_parameterisation(info, ref, fixed={"G1": 5e3},
                                          bounds={"G0": (1e2, 1e6), "contact_offset":
                                                  (-1e-6, 5e-7)},
                                          scales={"contact_offset": 1e-6})
    rng = np.random.default_rng(1)
    zs = np.r_[rng.normal(0, 3, (5, len(param.free))), [[40.0, -45.0, 0.1, 50.0]]]
    for z in zs:
        u = np.asarray(param.internal(jnp.asarray(z)))
        np.testing.assert_allclose(param.internal_host(z), u, rtol=1e-14, atol=1e-300)
        np.testing.assert_allclose(param.to_natural_host(u),
                                   np.asarray(param.to_natural(jnp.asarray(u))), rtol=1e-14)
        jac = jax.jacfwd(lambda zz: param.internal(zz)[jnp.asarray(param.free)])(
            jnp.asarray(z))
        np.testing.assert_allclose(param.dinternal_dz(z), np.diagonal(np.asarray(jac)),
                                   rtol=1e-12, atol=1e-300)
    us = param.internal_host(zs)
    np.testing.assert_array_equal(param.z_of(us), np.stack([param.z_of(u) for u in us]))
    assert len(names) == us.shape[1]


def test_host_prepared_batch_equals_the_device_one_and_bad_probes_always_raise(noisy):
    # fit_each prepares in numpy and transfers once a chunk: the same arrays; the probe's
    # check is remembered per profile object only when it passed
    import jax

    spec = make_spec("relaxed", "standard")
    dev = prepare_curves(noisy, spec, radius=R)
    host = prepare_curves(noisy, spec, radius=R, host=True)
    assert isinstance(host.force, np.ndarray)
    for a, b in zip(jax.tree.leaves(dev), jax.tree.leaves(host), strict=True):
        np.testing.assert_array_equal(np.asarray(a), b)
    stacked = fitting.stack_batches([host, host], 70, host=True)
    assert stacked.ts.shape == (2 * len(noisy), 70) and isinstance(stacked.ts, np.ndarray)
    bad = jc.Parabola(40.0)  # 40 m: not a probe radius
    for _ in range(2):
        with pytest.raises(ValueError, match="R"):
            prepare_curves(noisy, spec, profile=bad)


def test_a_curve_prepared_alone_is_its_row_of_a_padded_batch_and_checked_modules(noisy):
    # the per-curve preparation of a map (one row, nothing to pad, the modules built by
    # unflattening, `fitting._host`) against the general path (curves of other lengths,
    # padded) and against equinox's checked construction; the noise's median against
    # np.median
    from fitting._parameters import Parameterisation
    from fitting._prepare import CurveBatch, _median

    spec = make_spec("relaxed", "standard")
    curves = [noisy[0], dataclasses.replace(noisy[1], time=noisy[1].time[:45],
                                            displacement=noisy[1].displacement[:45],
                                            force=noisy[1].force[:45],
                                            segment=noisy[1].segment[:45])]
    joint = prepare_curves(curves, spec, radius=R, host=True)
    rows = ("ts", "drive", "indentation", "force", "lower", "upper", "segment", "index",
            "contact", "noise", "weight", "valid")
    for i, c in enumerate(curves):
        alone = prepare_curves([c], spec, radius=R, host=True)
        m = alone.ts.shape[1]
        assert m == len(c) and joint.valid[i, m:].sum() == 0
        for k in rows:
            assert getattr(alone, k).dtype == getattr(joint, k).dtype
            np.testing.assert_array_equal(getattr(alone, k)[0], getattr(joint, k)[i, :m])
        for k in ("sigma", "depth", "detaches", "stiffness"):
            assert getattr(alone, k)[0] == getattr(joint, k)[i]
        fields = {f.name: getattr(alone, f.name) for f in dataclasses.fields(CurveBatch)}
        checked = CurveBatch(**fields)
        assert jax.tree.structure(checked) == jax.tree.structure(alone)
        assert alone.n_samples == m and alone.n_curves == 1
    info = fitting._spec.parameter_info(spec)
    param = fitting.make_parameterisation(info, TRUE, fixed={"G1": 5e3}, host=True)
    checked = Parameterisation(free=param.free, log=param.log, reference=param.reference,
                               scale=param.scale, lower=param.lower, upper=param.upper)
    assert jax.tree.structure(checked) == jax.tree.structure(param)
    z = np.zeros((2, len(param.free)))
    np.testing.assert_array_equal(param.internal_host(z), checked.internal_host(z))
    rng = np.random.default_rng(0)
    for n in (5, 6, 7, 12):
        x = rng.standard_normal(n)
        assert _median(x) == float(np.median(x))
    assert np.isnan(_median(np.array([1.0, np.nan, 2.0])))


def test_tabor_parameter_reported_with_its_error_and_flagged_when_small(noisy_fit, tmp_path):
    res = noisy_fit
    mu = {d["name"]: d for d in res.derived}["tabor_mu"]
    w, g0 = res["work_of_adhesion"], res["G0"]
    # the value: Tabor's parameter with the glass modulus E* = 4 G0 (the criterion's)
    assert mu["value"] == pytest.approx(float(jc.tabor_parameter(R, w, 4 * g0)), rel=1e-12)
    assert mu["status"] == "ok" and mu["value"] > fitting._quality.TABOR_JKR_MIN
    # its error by a second route: mu ~ (w / G0)^(2/3), so var(ln mu) = (4/9) var(ln w - ln G0)
    i, k = res.names.index("G0"), res.names.index("work_of_adhesion")
    c = res.covariance
    var_log = c[k, k] / w**2 + c[i, i] / g0**2 - 2 * c[i, k] / (w * g0)
    assert mu["stderr"] == pytest.approx(mu["value"] * 2 / 3 * np.sqrt(var_log), rel=1e-6)
    assert "outside_jkr_limit" not in res.flags
    # everywhere: console, JSON, CSV
    assert "tabor_mu_1" in res.summary()
    paths = fitting.write_report(res, tmp_path)
    table = json.loads(paths["json"].read_text())
    assert table["tabor_mu_1"]["value"] == pytest.approx(mu["value"])
    assert table["tabor_mu_1"]["derived"] is True
    # a probe of atomic size makes mu small: flagged, with the numbers, outside the JKR limit
    small = dataclasses.replace(res, radius=1e-12, warnings=[], derived=[])
    fitting._quality.assess(small)
    mu_small = {d["name"]: d for d in small.derived}["tabor_mu"]["value"]
    assert mu_small == pytest.approx(mu["value"] * (1e-12 / R) ** (1 / 3), rel=1e-9)
    assert mu_small < 5 and "outside_jkr_limit" in small.flags
    assert any("Tabor" in m and f"{mu_small:.3g}" in m for m in small.warnings)
    # and on the figure, in red, as every flag (fitting._quality.FLAGS) is
    from jaxcontact_cli import plot_fit
    from jaxcontact_cli._plots import _FLAG_TEXT

    assert set(_FLAG_TEXT) == set(fitting._quality.FLAGS)
    fig = plot_fit(small)
    texts = " ".join(t.get_text() for t in fig.texts)
    assert "outside the JKR limit" in texts and "further warning" not in texts
    # ... but not where the work of adhesion is not determined (mu then not known to be small)
    status = ["not determined" if n == "work_of_adhesion" else s
              for n, s in zip(res.names, res.status, strict=True)]
    vague = dataclasses.replace(res, radius=1e-12, warnings=[], derived=[], status=status)
    fitting._quality.assess(vague)
    assert "outside_jkr_limit" not in vague.flags
    assert {d["name"]: d for d in vague.derived}["tabor_mu"]["status"] == "not determined"
    # no radius of curvature (e.g. a cone): not defined, not a number
    cone = fitting._quality.tabor_entry(res.spec, res.values, res.covariance, res.status,
                                        None, res.names)
    assert cone["status"] == "not defined" and np.isnan(cone["value"])
    # no adhesion: no entry
    p0 = np.array(res.values, dtype=float)
    p0[k] = 0.0
    assert fitting._quality.tabor_entry(res.spec, p0, res.covariance, res.status, R,
                                        res.names) is None


def test_screened_starts_are_the_lowest_chi2_points_of_the_screen():
    # `screen`: the random starts are the screened points of lowest chi2, each chi2 here
    # evaluated on its own through the public residuals (a second route: the screen
    # evaluates a chunk of problems at once, in batches of points); the first start stays
    # the data-based guess; a screened fit ends at the truth
    from fitting import _optimise

    curves = _curves(noise=0.01)
    opts = fitting.FitOptions(radius=R, n_starts=STARTS, screen=24, contact_point="none")
    pb = _optimise._problem(curves, opts, rheology="standard", contact_point="none",
                            previous=None)
    assert pb.pool.shape == (24, len(pb.param.free))
    got = _optimise._screened([pb, pb], opts)
    one = jax.jit(lambda z: jnp.sum(residuals(pb.param.natural(z), pb.data, pb.spec) ** 2))
    chi2 = np.array([float(one(z)) for z in pb.pool])
    want = pb.pool[np.argsort(chi2)[:STARTS - 1]]
    for g in got:
        np.testing.assert_array_equal(g.zs[0], pb.zs[0])
        np.testing.assert_allclose(g.zs[1:STARTS], want, rtol=0, atol=0)
    res = _fit(curves, screen=24, contact_point="none")
    assert max(_errors(res).values()) < 0.05


def test_latin_hypercube_is_stratified_and_maximin_for_few_points():
    # every column of an n-point design has one point in each of the n strata; a screen's
    # large design (one design, nothing to choose: no n^2 distance matrix, which at 8,192
    # points took 24 s and 3.7 GB) as well; for a few points the best of several designs by
    # the smallest pairwise distance, recomputed here from its definition
    from fitting._start import latin_hypercube

    for n, designs in ((8192, 1), (16, 20)):
        u = latin_hypercube(n, 7, seed=3, designs=designs)
        assert u.shape == (n, 7) and np.all((u >= 0) & (u < 1))
        for col in u.T:
            np.testing.assert_array_equal(np.sort(np.floor(col * n)), np.arange(n))
    d = lambda v: min(np.linalg.norm(v[i] - v[j]) for i in range(16)  # noqa: E731
                      for j in range(i))
    best = latin_hypercube(16, 7, seed=3, designs=20)
    assert d(best) >= d(latin_hypercube(16, 7, seed=3, designs=1)) - 1e-15
    np.testing.assert_array_equal(latin_hypercube(16, 7, seed=3, designs=20), best)


def test_screen_and_explore_options_are_checked():
    with pytest.raises(ValueError, match=r"screen must be 0 or an integer >= n_starts \(4\)"):
        fitting.FitOptions(radius=R, n_starts=4, screen=3)
    with pytest.raises(ValueError, match="screen must be an integer >= 0"):
        fitting.FitOptions(radius=R, screen=-1)
    with pytest.raises(ValueError, match="explore_steps must be an integer >= 1"):
        fitting.FitOptions(radius=R, explore_steps=0)
    o = fitting.FitOptions(radius=R, n_starts=4, screen=4, explore_steps=None)
    assert o.screen == 4 and o.explore_steps == fitting.DEFAULT_EXPLORE_STEPS
    for bad in (1, 0.5, True, "10", float("nan")):
        with pytest.raises(ValueError, match="abandon must be a number > 1 or None"):
            fitting.FitOptions(radius=R, abandon=bad)
    assert fitting.FitOptions(radius=R).abandon == fitting.DEFAULT_ABANDON
    assert fitting.FitOptions(radius=R, abandon=None).abandon is None
    assert fitting.FitOptions(radius=R, abandon=30).abandon == 30.0


@pytest.mark.parametrize("contact_point", ["none", "fit"])
def test_residual_shape_stated_without_tracing_equals_the_traced_one(contact_point):
    # the search's residual function states the shape and dtype of its residuals from the
    # data (the solver's initial state is built without tracing the model): the same as
    # jax.eval_shape of the residuals, for one curve and for two curves of different
    # lengths fitted jointly (padded), eagerly and under vmap as the pool builds its states
    from fitting import _optimise
    from fitting._least_squares import residual_struct

    curves = [_curves()[0], _curves(speeds=SPEEDS[1:2], n=N + 7)[0]]
    opts = fitting.FitOptions(radius=R, n_starts=STARTS, contact_point=contact_point)
    for group in ([curves[0]], curves):
        pb = _optimise._problem(group, opts, rheology="standard",
                                contact_point=contact_point, previous=None)
        fn = _optimise._fn(pb.spec)
        z, ctx = jnp.asarray(pb.zs[0]), (pb.param, pb.data)
        traced = jax.eval_shape(fn, z, ctx)
        assert fn.residual_struct(z, ctx) == traced
        assert traced.shape == (np.size(pb.data.force),)
        zs = jnp.asarray(pb.zs[:3])
        ctxs = jax.tree.map(lambda x: jnp.broadcast_to(x, (3,) + jnp.shape(x)), ctx)
        stated = jax.vmap(lambda zz, c, f=fn: jnp.zeros(residual_struct(f, zz, c).shape))(
            zs, ctxs)
        plain = jax.vmap(lambda zz, c, f=fn: jnp.zeros(jax.eval_shape(f, zz, c).shape))(
            zs, ctxs)
        assert stated.shape == plain.shape == (3,) + traced.shape


def test_solve_batch_calls_traced_once_after_its_only_trace(monkeypatch):
    # `traced`: called once, after the pool's program is traced and before it runs; the
    # call reuses that trace (the model's residuals are not traced again after the hook),
    # and the result is the one without the hook
    from fitting import _optimise

    opts = fitting.FitOptions(radius=R, n_starts=3, contact_point="none")
    pb = _optimise._problem(_curves()[:1], opts, rheology="standard", contact_point="none",
                            previous=None)
    stack = lambda x: jnp.stack([x] * 3)  # noqa: E731
    params, datas = jax.tree.map(stack, pb.param), jax.tree.map(stack, pb.data)
    z0s = jnp.asarray(pb.zs[:3])
    kw = dict(workers=2, max_steps=7, keep_jacobian=True)
    _optimise._solve_batch.clear_cache()
    traces, order = [], []
    from fitting import _objective

    real = _objective.predict  # the forward model, whatever the pool evaluates with it
    monkeypatch.setattr(_objective, "predict", lambda *a: (traces.append(1), real(*a))[1])
    got = fitting.solve_batch(pb.spec, params, datas, z0s, traced=lambda: order.append(
        len(traces)), **kw)
    assert order == [len(traces)] and len(traces) >= 1
    want = fitting.solve_batch(pb.spec, params, datas, z0s, **kw)
    for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(want), strict=True):
        np.testing.assert_array_equal(a, b)



def test_force_drift_needs_the_history_model():
    # the relaxed model's retract cannot tell a line from the relaxation: refused, named
    with pytest.raises(ValueError, match="force_drift needs model='history'"):
        make_spec("relaxed", force_drift=True)
    with pytest.raises(ValueError, match="force_drift needs model='history'"):
        fitting.FitOptions(radius=R, force_drift=True)
    with pytest.raises(ValueError, match="force_drift must be True or False"):
        fitting.FitOptions(radius=R, model="history", force_drift="yes")
    assert fitting.FitOptions(radius=R, model="history", force_drift=True).force_offset
