"""Fitting the full-history model: approach, hold and retract; the contact point as a
fitted parameter; subsampling without bias; compliant loading; the real oocyte curve.

References: synthetic curves from `jc.simulate` with known parameters and a known contact
point; a fit of all samples (against a subsampled fit); the detection of a contact point
on a raw curve (against the true one); the spring of the compliant loading.

Compilation dominates the run time: the fits share their shapes (one `max_samples` budget
pads every subsampled curve to the same length), so few compilations serve the file.
"""

import csv
import dataclasses
import json
import pathlib
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_fitting import D0, TRUE, R
from test_fitting_models import _read_outputs, _write_csv

import fitting
import jaxcontact as jc
from fitting._objective import residuals
from jaxcontact_cli import main

DATA = pathlib.Path(__file__).parent / "data"
STARTS = 4
BUDGET = 150
RHEOLOGY = jc.StandardModel(TRUE["G0"], TRUE["G1"], TRUE["eta1"])


def _history(noise, seed, n=(300, 300, 300), v=2e-6, hold=1.0, lift=3.0e-6, pre=0.3e-6):
    """Approach from `pre` above the surface to D0, hold, lift: (t, d_true, F)."""
    na, nh, nr = n
    ta = np.linspace(0.0, (pre + D0) / v, na)
    th = ta[-1] + np.linspace(0.0, hold, nh + 1)[1:]
    tr = th[-1] + np.linspace(0.0, lift / v, nr + 1)[1:]
    t = np.concatenate([ta, th, tr])
    d = np.interp(t, [0.0, ta[-1], th[-1], tr[-1]], [-pre, D0, D0, D0 - lift])
    sol = jc.simulate(RHEOLOGY, jc.Parabola(R), TRUE["work_of_adhesion"], t, d)
    f = np.asarray(sol.force)
    assert np.isfinite(float(sol.jumpoff_time))
    rng = np.random.default_rng(seed)
    return t, d, f + noise * np.ptp(f) * rng.standard_normal(t.size), (na, nh, nr)


def _curve(t, d, f, counts, **kw):
    return fitting.Curve(time=t, displacement=d, force=f,
                         segment=np.repeat([0, 1, 2], counts),
                         segment_names=("approach", "hold", "retract"), **kw)


def _fit(curves, **kw):
    kw.setdefault("n_starts", STARTS)
    kw.setdefault("local_rounds", 1)  # the suite's time; the default's rounds: own tests
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fitting.IdentifiabilityWarning)
        warnings.simplefilter("ignore", fitting.ModelValidityWarning)
        return fitting.fit(curves, radius=R, model="history", progress=False, **kw)


DELTA = 0.12e-6  # the "detected" contact is this much late


@pytest.fixture(scope="module")
def shifted():
    t, d, f, counts = _history(0.01, 1)
    return _curve(t, d - DELTA, f, counts)


@pytest.fixture(scope="module")
def subsampled_fit(shifted):
    return _fit(shifted, contact_point="fit", max_samples=BUDGET)


def test_contact_offset_recovered(subsampled_fit):
    res = subsampled_fit
    assert res.data.ts.shape[1] == BUDGET and res.data.n_samples <= BUDGET
    assert res.n_data == 900
    assert res.names[-1] == "contact_offset" and res.units[-1] == "m"
    for k, v in dict(TRUE, contact_offset=DELTA).items():
        i = res.names.index(k)
        assert res.status[i] == "ok", (k, res.status[i])
        assert abs(res.values[i] - v) < 3.5 * res.stderr[i], (k, res.values[i], res.stderr[i])
    assert 0.6 < res.reduced_chi2 < 1.6


def test_a_coarser_search_grid_ends_on_the_fit_grid(shifted, subsampled_fit):
    """``search_cells`` below ``cells``: the search on 8 cells, its best distinct end points
    continued on the fit's 32. The result is a point of the 32-cell model (its chi2 is the
    32-cell objective at its values, evaluated anew; the 8-cell objective there differs),
    and it ends where the search on the 32 cells alone ends (the fixture: chi2 within
    1e-6, every parameter within a tenth of its standard error)."""
    coarse = _fit(shifted, contact_point="fit", max_samples=BUDGET, search_cells=8)
    one = subsampled_fit
    assert one.polish_losses is None and one.polish_steps is None
    assert one.search["cells"] == one.search["search_cells"] == 32
    assert coarse.search["cells"] == 32 and coarse.search["search_cells"] == 8
    assert coarse.spec.cells == 32
    assert 1 <= len(coarse.polish_losses) <= fitting._options.POLISHED_POINTS
    assert len(coarse.polish_steps) == len(coarse.polish_losses)
    assert coarse.chi2 == pytest.approx(np.min(coarse.polish_losses), rel=1e-10)

    def chi2(cells):
        spec = dataclasses.replace(coarse.spec, cells=cells)
        r = residuals(jnp.asarray(coarse.values), coarse.data, spec)
        return float(jnp.sum(r ** 2))

    assert chi2(32) == pytest.approx(coarse.chi2, rel=1e-9)
    assert abs(chi2(8) / chi2(32) - 1) > 1e-5  # the grids' objectives differ
    assert coarse.chi2 == pytest.approx(one.chi2, rel=1e-6)
    for i, name in enumerate(one.names):
        assert abs(coarse.values[i] - one.values[i]) < 0.1 * one.stderr[i], name
    # the report says which grid each loss is on
    table = fitting._report.result_table(coarse)
    assert table["search"]["search_cells"] == 8
    assert table["polish_losses"] == pytest.approx(list(coarse.polish_losses))


def test_surface_height_from_the_fitted_contact():
    """A raw curve in an instrument's frame of heights (h = H0 - u, heights decreasing
    toward the sample; the surface at u = 0.3 um): the contact detected on its soft onset
    lies past the surface, and the fitted contact offset moves it back. The result's
    surface height is H0 - 0.3 um within 3.5 standard errors of the offset; the detected
    contact alone (`Curve.surface_height()`, no offset) is off by more than that. Without
    a height frame (no "height at start") it is nan."""
    t, d, f, counts = _history(0.01, 3)
    h0, truth = 80e-6, 80e-6 + d[0]  # d[0] = -0.3 um: the surface 0.3 um below h0
    raw = _curve(t, d - d[0], f, counts, metadata={"height at start": h0})
    curve = fitting.preprocess(raw, baseline="constant", contact_point="detect")
    detected = curve.surface_height()
    res = _fit(curve, contact_point="fit", max_samples=BUDGET)
    height, se = res.surface_height()
    j = res.names.index("contact_offset")
    assert res.status[j] == "ok" and se == res.stderr[j] > 0
    assert abs(height - truth) < 3.5 * se, (height - truth, se)
    assert abs(detected - truth) > 3.5 * se  # the offset mattered, with its sign
    assert height == pytest.approx(detected + res.values[j], rel=0, abs=1e-15)
    assert np.isnan(curve.replace(metadata={}).surface_height())
    assert np.isnan(raw.surface_height())  # not preprocessed: no contact point
    table = fitting._report.result_table(res)
    assert table["inputs"][0]["contact"]["surface_height_m"] == pytest.approx(height)
    assert f"curve 0: height {height:.9g} m +/- {se:.3g}" in res.summary()
    # a fitted contact outside the data is no measured surface: no height
    outside = dataclasses.replace(res, flags=dict(res.flags, contact_outside_data="..."))
    assert np.isnan(outside.surface_height()).all()


def test_information_criteria_count_the_effective_samples(shifted, subsampled_fit):
    """AIC and BIC of a subsampled fit count Kish's effective samples (`n_effective`:
    (sum w)^2 / sum w^2 of the kept samples' weights), not the measured ones; without
    subsampling that is the number of samples (the usual criteria)."""
    res = subsampled_fit
    w = np.asarray(res.data.weight).ravel()
    n_eff = res.data.n_effective
    assert n_eff == pytest.approx(w.sum() ** 2 / (w * w).sum())
    assert n_eff < res.data.n_samples <= BUDGET < res.n_data == 900
    ll = n_eff * np.log(res.chi2 / res.n_data)
    k = int(np.sum(~np.asarray(res.fixed)))  # the fitted parameters, at a bound or not
    assert res.bic == pytest.approx(ll + k * np.log(n_eff))
    assert res.aic == pytest.approx(ll + 2 * k)
    full = fitting.prepare_curves(shifted, res.spec, radius=R, max_samples=900)
    assert full.n_effective == pytest.approx(900) == full.n_measured


@pytest.mark.slow  # extended: `python -m pytest -m slow` (three history fits)
def test_model_selection_on_a_subsampled_curve():
    """`rheology="auto"` on a standard-model curve of 900 samples kept as 150 (each standing
    for ~6): the weighted chi2 varies ~6 times more than a chi2 of 900 samples, so AIC/BIC
    count Kish's effective samples (`CurveBatch.n_effective`, ~120); with the 900 measured
    ones BIC gave this curve a second arm (chi2 939.6 -> 905.7, 34 for 2 parameters), with
    all 900 samples kept it does not (the reference: 928.5 -> 925.8). Without subsampling
    n_effective is the number of samples and the criteria are the usual ones."""
    t, d, f, counts = _history(0.01, 4)
    curve = fitting.preprocess(_curve(t, d, f, counts), baseline="constant",
                               contact_point="detect")
    res = _fit(curve, rheology="auto", max_samples=BUDGET)
    assert [m.rheology for m in res.model_selection] == ["standard", "prony:2", "prony:3"]
    assert res.rheology == "standard", [(m.rheology, m.chi2, m.bic)
                                        for m in res.model_selection]
    assert 0.6 * BUDGET < res.data.n_effective < BUDGET and res.n_data == 900


def test_force_drift_columns_of_the_jacobian_in_closed_form(shifted):
    """The fitted baseline F0 + s t (`force_drift`): the residuals' derivatives along F0 and
    s are sqrt(w)/sigma and sqrt(w) t/sigma per sample (closed form: the line is added to
    the model force), the material columns are those of the fit without the line, and at
    s = F0 = 0 the residuals are the plain fit's."""
    plain_spec = fitting.make_spec("history", contact_offset=True)
    spec = fitting.make_spec("history", contact_offset=True, force_drift=True)
    assert spec.force_offset  # a drift is a line: its offset comes with it
    assert [n for n, _, _ in fitting.parameter_info(spec)][-2:] == ["force_offset",
                                                                     "force_drift"]
    assert fitting.parameter_info(spec)[-1] == ("force_drift", "N_s", "offset_force_rate")
    data = fitting.prepare_curves(shifted, spec, radius=R, max_samples=BUDGET)
    p0 = jnp.array([TRUE["G0"], TRUE["G1"], TRUE["eta1"], TRUE["work_of_adhesion"], DELTA])
    p = jnp.concatenate([p0, jnp.array([2e-9, -3e-9])])  # F0 [N], s [N/s]
    J = jax.jacfwd(lambda q: residuals(q, data, spec))(p)
    J0 = jax.jacfwd(lambda q: residuals(q, data, plain_spec))(p0)
    w = np.sqrt(np.asarray(data.weight)) / np.asarray(data.noise)
    np.testing.assert_allclose(J[:, -2], w.ravel(), rtol=1e-12)
    np.testing.assert_allclose(J[:, -1], (w * np.asarray(data.ts)).ravel(), rtol=1e-12)
    np.testing.assert_allclose(J[:, :5], J0, rtol=1e-10, atol=1e-12 * np.abs(J0).max())
    r0 = residuals(p0, data, plain_spec)
    np.testing.assert_allclose(residuals(p.at[-2:].set(0.0), data, spec), r0, rtol=1e-14)


def test_force_drift_recovers_a_trend_the_constant_baseline_left(monkeypatch):
    """A drift in the force (a line rising 15 noise sigma by the end of the approach, on
    top of a baseline offset) under a constant baseline: the fit with `force_drift`
    recovers the drift and every material parameter within 3.5 standard errors, and the
    contact where the curve truly touched (the detection alone sits early: the rising
    baseline crosses the threshold first), against the free force's scatter about its
    line as the noise; without the drift the same curve is not described (chi2 > 100
    times higher in that noise). The `baseline_trend` flag (its threshold lowered
    here: this curve's free approach is short, so the trend's standard error keeps it
    below the default) names the drift fit as the remedy and is not raised for it."""
    monkeypatch.setattr(fitting._quality, "TREND_SIGMA", 1.0)
    t, d, f, counts = _history(0.01, 4)
    sigma = 0.01 * np.ptp(f)
    drift = 15 * sigma / t[counts[0] - 1]
    raw = _curve(t, d - DELTA, f + 3 * sigma + drift * t, counts)
    curve = fitting.preprocess(raw, baseline="constant", contact_point="detect")
    res = _fit(curve, contact_point="fit", max_samples=BUDGET, force_drift=True)
    assert res.names[-2:] == ["force_offset", "force_drift"] and res.units[-1] == "N_s"
    for k, v in dict(TRUE, force_drift=drift).items():
        i = res.names.index(k)
        assert res.status[i] == "ok", (k, res.status[i])
        assert abs(res.values[i] - v) < 3.5 * res.stderr[i], (k, res.values[i], res.stderr[i])
    j = res.names.index("contact_offset")
    contact = curve.contact.tip_position - res.values[j]  # the truth: -DELTA
    assert abs(contact + DELTA) < 3.5 * res.stderr[j]
    assert abs(curve.contact.tip_position + DELTA) > 3.5 * res.stderr[j]
    assert "baseline_trend" not in res.flags and "drift_not_baseline" not in res.flags
    # the drift fit's noise: the free force's scatter about its line (the constant
    # baseline's counts the trend); the two chi2 compared in that one noise
    sigma, sigma_plain = curve.contact.trend_noise, curve.contact.noise
    assert float(res.data.sigma[0]) == pytest.approx(sigma) and sigma < sigma_plain
    plain = _fit(curve, contact_point="fit", max_samples=BUDGET)
    assert float(plain.data.sigma[0]) == pytest.approx(sigma_plain)
    assert plain.chi2 * (sigma_plain / sigma) ** 2 > 100 * res.chi2
    assert "--force-drift" in plain.flags["baseline_trend"]
    table = fitting._report.result_table(res)
    assert table["force_drift"] is True and table["force_offset"] is True


def test_a_drift_that_takes_up_a_force_in_contact_is_flagged():
    """A force the model does not have, in contact only (a creep rising 80 noise sigma from
    the contact to the end; nothing before it): the fitted drift takes it up and the fit
    looks fine (reduced chi2 about 1), but the drift is not the free force's own slope
    before contact (about 0), so the fit is flagged `drift_not_baseline`."""
    t, d, f, counts = _history(0.01, 4)
    sigma = 0.01 * np.ptp(f)
    tc = t[np.argmax(d > 0)]
    creep = 80 * sigma * np.clip((t - tc) / (t[-1] - tc), 0.0, None)
    raw = _curve(t, d - DELTA, f + creep, counts)
    curve = fitting.preprocess(raw, baseline="constant", contact_point="detect")
    res = _fit(curve, contact_point="fit", max_samples=BUDGET, force_drift=True)
    assert res.reduced_chi2 < 2.0  # the misfit is hidden in the line
    cp = curve.contact
    assert abs(cp.trend_slope) < 3 * cp.trend_slope_error  # no drift before contact
    msg = res.flags["drift_not_baseline"]
    assert msg.startswith("curve 0: the fitted force drift") and "not a baseline" in msg
    j = res.names.index("force_drift")
    assert abs(res.values[j] - cp.trend_slope) > 5 * np.hypot(res.stderr[j],
                                                              cp.trend_slope_error)


@pytest.mark.slow  # extended: `python -m pytest -m slow` (the default run's time)
def test_subsampling_does_not_bias_the_history_fit(shifted, subsampled_fit):
    """All 900 samples against 150 kept ones (each standing for its neighbours): the same
    optimum within the subsample's standard errors (the old interpolating resampling to
    150 samples per segment was off by 2-3 %, 4 of its own standard errors)."""
    full = _fit(shifted, contact_point="fit", max_samples=900)
    sub = subsampled_fit
    for i, k in enumerate(full.names):
        assert abs(sub.values[i] - full.values[i]) < 3 * sub.stderr[i], k
        assert sub.stderr[i] >= 0.9 * full.stderr[i], k


def test_soft_onset_detection_and_fitted_contact_point(subsampled_fit):
    """A raw curve with a Hertz-like (soft) onset, a force baseline and noise: the
    threshold detection finds the contact late (the force rises slowly); fitting the
    offset recovers the true contact point."""
    t, d, f, counts = _history(0.01, 2, pre=0.6e-6)
    base = 3e-10
    raw = _curve(t, d + 0.6e-6, f + base, counts)  # base position from the first sample
    pre = fitting.preprocess(raw, baseline="constant", contact_point="detect")
    late = pre.contact.height - 0.6e-6  # detected minus true contact (base positions)
    assert late > 0.01e-6  # the soft onset is detected late
    res = _fit(pre, contact_point="fit", max_samples=BUDGET)
    i = res.names.index("contact_offset")
    assert abs(res.values[i] - late) < 3.5 * res.stderr[i], (res.values[i], late)
    assert res.stderr[i] < 0.5 * late


def test_fit_csv_and_figure_of_a_history_fit(subsampled_fit, tmp_path):
    from jaxcontact_cli import plot_fit

    paths = fitting.write_report(subsampled_fit, tmp_path)
    with paths["samples"].open() as fh:
        rows = list(csv.DictReader(fh))
    assert {r["segment"] for r in rows} == {"approach", "hold", "retract"}
    assert sum(float(r["weight"]) for r in rows) == pytest.approx(900)
    fig_path = tmp_path / "fit.png"
    plot_fit(subsampled_fit, fig_path)
    assert fig_path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_quality_per_segment_and_the_weighting_of_r_squared(subsampled_fit, tmp_path):
    # 150 kept samples standing for 900: the headline R² weights each by its count, the
    # unweighted one counts it once; both and the per-segment values from fit.csv alone
    res = subsampled_fit
    paths = fitting.write_report(res, tmp_path)
    with paths["samples"].open() as fh:
        rows = list(csv.DictReader(fh))

    def r2(rs, weighted):
        f = np.array([float(r["force_N"]) for r in rs])
        m = np.array([float(r["model_force_N"]) for r in rs])
        w = np.array([float(r["weight"]) for r in rs]) if weighted else np.ones(len(rs))
        mean = np.sum(w * f) / np.sum(w)
        return 1 - np.sum(w * (m - f) ** 2) / np.sum(w * (f - mean) ** 2)

    assert res.r_squared == pytest.approx(r2(rows, True), rel=1e-10)
    assert res.r_squared_unweighted == pytest.approx(r2(rows, False), rel=1e-10)
    assert abs(res.r_squared - res.r_squared_unweighted) > 1e-6  # the weights matter here
    table = json.loads(paths["json"].read_text())
    assert [s["segment"] for s in table["segments"]] == ["approach", "hold", "retract"]
    for s in table["segments"]:
        part = [r for r in rows if r["segment"] == s["segment"]]
        w = np.array([float(r["weight"]) for r in part])
        e = np.array([float(r["residual"]) for r in part])
        assert s["reduced_chi2"] == pytest.approx(np.sum(w * e**2) / np.sum(w), rel=1e-10)
        assert s["max_residual"] == pytest.approx(np.max(np.abs(e)), rel=1e-12)
        assert s["r_squared"] == pytest.approx(r2(part, True), rel=1e-10)
        assert s["n_measured"] == pytest.approx(np.sum(w))
        assert s["described"] and s["reduced_chi2"] < 2
    # the fitted contact lies inside the data (the offset is recovered): no flag
    assert table["status"] == "ok" and table["flags"] == {}
    text = res.summary()
    assert "[[segments]]" in text and "hold" in text and "unweighted" in text


def test_oocyte_history_fit():
    """The real oocyte curve (approach, 30 s hold, retract); R = 40 um is an assumption
    (the file has no probe radius). The global search and the contact point fitted by
    default; every sample counts, so the adhesive tail is followed."""
    pytest.importorskip("afmformats")
    curve = fitting.load_afm(DATA / "oocyte-stress-relaxation-cell1-0008.jpk-force")[0]
    res = _fit(curve, max_samples=BUDGET)
    assert res.spec.contact_offset  # instrument file: the contact point is fitted
    assert res.r_squared > 0.95 and res.r_squared_contact > 0.95
    # the model's contact radius far exceeds 0.3 R: the fit says so
    assert any("contact radius reaches" in w for w in res.warnings)


@pytest.mark.slow
def test_oocyte_default_search_reaches_brute_force():
    """The issue's acceptance on the shipped curve: the default search (16 starts and
    its local rounds) ends at least as low as a brute-force search of 64 other starts
    (another seed) without local rounds. Before the local rounds the default ended 1.8 %
    above the best known chi2 at R = 10 um (a ladder of optima in the contact offset)."""
    pytest.importorskip("afmformats")
    curve = fitting.load_afm(DATA / "oocyte-stress-relaxation-cell1-0008.jpk-force")[0]
    default = _fit(curve, n_starts=None, local_rounds=fitting.DEFAULT_LOCAL_ROUNDS)
    brute = _fit(curve, n_starts=64, seed=1, local_rounds=0)
    assert default.chi2 <= brute.chi2 * (1 + 1e-6)
    assert default.r_squared >= brute.r_squared - 1e-5


# --------------------------------------------------------------------------------------
# Compliant loading (history model, cantilever of 0.5 N/m)
# --------------------------------------------------------------------------------------

K = 0.5
CELLS = 16


@pytest.fixture(scope="module")
def compliant_curve():
    # approach at 4 um/s to 1 um (15 samples), hold 2 s (20), lift 3.5 um at 4 um/s (70);
    # the contact stays pinned and jumps off at a drive position of -1.97 um
    v = 4e-6
    ta = np.linspace(0.0, D0 / v, 15)
    th = np.linspace(D0 / v, D0 / v + 2.0, 21)[1:]
    tr = th[-1] + np.linspace(0.0, 3.5e-6 / v, 71)[1:]
    ts = np.concatenate([ta, th, tr])
    z = np.concatenate([ta * v, np.full(20, D0), D0 - (tr - th[-1]) * v])
    sol = jc.simulate(jc.StandardModel(TRUE["G0"], TRUE["G1"], TRUE["eta1"]), jc.Parabola(R),
                      TRUE["work_of_adhesion"], ts, z, loading=jc.CompliantLoading(K),
                      grid=jc.FoundationGrid(cells=CELLS))
    d, f = np.asarray(sol.displacement), np.asarray(sol.force)
    # the spring: k (z - d) = F, and the jump-off lies inside the lift
    np.testing.assert_allclose(K * (z - d), f, atol=1e-12 * np.abs(f).max())
    assert np.isfinite(float(sol.jumpoff_time)) and f[-1] == 0.0
    # the instrument measures the drive z and the force; the indentation d = z - F/k
    # carries the force noise
    noisy = f + 0.005 * np.ptp(f) * np.random.default_rng(3).standard_normal(f.size)
    return fitting.Curve(time=ts, displacement=z - noisy / K, force=noisy,
                         segment=np.repeat([0, 1, 2], [15, 20, 70]),
                         segment_names=("approach", "hold", "retract"))


def test_compliant_data_drive_the_base(shifted):
    """The compliant model is driven by the base position z = d + F/k (the spring's
    measured deflection added back), with the spring constant per curve (the fit itself:
    the slow test below). Every 15th sample of the module's simulated curve: 20 per
    segment (a new curve length would compile `simulate` once more for nothing)."""
    t, d, f = (np.asarray(x)[::15] for x in (shifted.time, shifted.displacement,
                                             shifted.force))
    counts = np.bincount(np.asarray(shifted.segment)[::15])
    assert list(counts) == [20, 20, 20]
    curve = _curve(t, d, f, counts)
    spec = fitting.make_spec("history", compliant=True, cells=CELLS)
    data = fitting.prepare_curves(curve, spec, radius=R, spring_constant=K)
    np.testing.assert_allclose(np.asarray(data.drive)[0, :60], d + f / K, rtol=0,
                               atol=1e-15)
    assert float(data.stiffness[0]) == K
    with pytest.raises(ValueError, match="spring constant"):
        fitting.prepare_curves(curve, spec, radius=R)


@pytest.mark.slow
def test_compliant_history_fit_from_the_command_line(compliant_curve, tmp_path, monkeypatch):
    """A compliant (cantilever) history curve with 0.5 % noise written as CSV and fitted by
    `jaxcontact fit --spring-constant`: the spring reaches the model (loading record in
    parameters.json) and the true parameters lie within 4 of the reported standard errors
    (one fit serves the command line and the recovery check: compilation dominates)."""
    monkeypatch.setenv("JAXCONTACT_CACHE", str(tmp_path / "cache"))
    path = tmp_path / "compliant.csv"
    _write_csv(path, compliant_curve, segments=True)
    out = tmp_path / "result"
    argv = [str(path), "--radius", str(R), "--model", "history", "--spring-constant", str(K),
            "--cells", str(CELLS), "--starts", str(STARTS), "--no-figure", "--quiet", "--out",
            str(out)]
    assert main(["fit", *argv]) == 0
    table, rows = _read_outputs(out)
    assert table["model"] == "history"
    assert table["loading"] == {"type": "compliant", "spring_constant_N_m": [K]}
    assert table["inputs"][0]["segments"] == ["approach", "hold", "retract"]
    for k, v in TRUE.items():
        unit = {"G0": "Pa", "G1": "Pa", "eta1": "Pa_s", "work_of_adhesion": "J_m2"}[k]
        entry = table[f"{k}_{unit}"]
        assert entry["status"] == "ok", (k, entry)
        assert abs(entry["value"] - v) < 4 * entry["stderr"], (k, entry, v)
        assert entry["stderr"] < 0.1 * v, (k, entry)
    assert {r["parameter"] for r in rows} == set(TRUE)
    assert table["converged"] and table["r_squared"] > 0.99
