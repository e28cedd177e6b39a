"""Fits beyond the standard relaxed model: profile likelihoods, Prony series, compliant
loading, instrument files through the command line, and data the fit cannot use.

References: synthetic curves from the forward models (`jc.retract`, `jc.simulate`) with
known parameters; the Gauss-Newton standard error (profile curvature); a direct
`fitting.fit` with the parameter fixed (profile refits); the spring constants and
segments the instrument files carry (tests/data/README.md).

Compilation dominates the run time: curves of one family share their shapes (and so the
compiled fit) between the API and the command-line tests.
"""

import csv
import json
import logging
import pathlib
import warnings

import jax
import numpy as np
import pytest
from test_fitting import D0, STARTS, TRUE, R, _curves, _fit

import fitting
import jaxcontact as jc
from jaxcontact_cli import main
from jaxcontact_cli._fit import add_fit_arguments, load_inputs

DATA = pathlib.Path(__file__).parent / "data"


def _args(argv):
    import argparse

    return add_fit_arguments(argparse.ArgumentParser()).parse_args(argv)


def _fit_cli(argv):
    """``jaxcontact fit`` with the relaxed model unless the arguments choose one."""
    argv = list(argv)
    if "--model" not in argv:
        argv += ["--model", "relaxed"]
    return main(["fit", *argv])


def _relaxed_curves(lift, noise=0.0, seed=0, speeds=(1e-6, 4e-6), n=60, p=TRUE):
    # the synthetic relaxed-model curves of tests/test_fitting.py
    return _curves(noise=noise, seed=seed, speeds=speeds, lift=lift, p=p, n=n)


def _write_csv(path, curve, segments=False):
    header = "time_s,displacement_m,force_N"
    cols = [curve.time, curve.displacement, curve.force]
    with open(path, "w") as fh:
        fh.write(header + (",segment\n" if segments else "\n"))
        for i in range(len(curve)):
            row = ",".join(repr(float(c[i])) for c in cols)
            if segments:
                row += "," + curve.segment_names[curve.segment[i]]
            fh.write(row + "\n")


def _read_outputs(out):
    """parameters.json (parsed) and the fitted parameters' rows of parameters.csv (dicts;
    the derived quantities' rows follow them); both must parse."""
    table = json.loads((out / "parameters.json").read_text())
    with (out / "parameters.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    fitted = [r for r in rows if r["derived"] == "False"]
    assert rows[:len(fitted)] == fitted  # the derived rows come last
    return table, fitted


# --------------------------------------------------------------------------------------
# Profile likelihood (two relaxed curves, 1 % noise; every curve detaches)
# --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def noisy_fit():
    curves = _relaxed_curves(3e-6, noise=0.01, seed=3, speeds=(0.5e-6, 2e-6, 8e-6))
    return _fit(curves, initial=TRUE)


def test_profile_likelihood_curvature_and_refits(noisy_fit, caplog):
    res = noisy_fit
    assert res.converged and 0.6 < res.reduced_chi2 < 1.5
    name = "eta1"
    i = res.names.index(name)
    v, s = res.values[i], res.stderr[i]
    offsets = np.array([-2.0, -1.0, 0.0, 1.0, 2.0])
    prof = fitting.profile_likelihood(res, "eta1_Pa_s", v + offsets * s)
    dchi = prof["delta_chi2"] / res.reduced_chi2
    assert np.all(prof["converged"])
    # ~0 at the optimum (the refit from the optimum stays there) ...
    assert abs(dchi[2]) < 1e-6
    # ... and increasing on both sides
    assert dchi[0] > dchi[1] > dchi[2] and dchi[4] > dchi[3] > dchi[2]
    # curvature: (delta/sigma)^2 for a locally linear model, i.e. 1 at one and 4 at two
    # standard errors; within 15 %
    np.testing.assert_allclose(dchi[[1, 3]], 1.0, rtol=0.15)
    np.testing.assert_allclose(dchi[[0, 4]], 4.0, rtol=0.15)
    # the profiled parameter is held at its value, the others are refitted
    np.testing.assert_allclose(prof["others"][:, i], v + offsets * s, rtol=1e-12)
    # a direct fit with the parameter fixed finds the same other parameters and chi2
    direct = _fit(res.curves, initial=res.as_dict(), fixed={name: float(v + s)})
    np.testing.assert_allclose(prof["others"][3], direct.values, rtol=1e-5)
    np.testing.assert_allclose(prof["chi2"][3], direct.chi2, rtol=1e-6)
    # one compilation serves other values (same count): no new compile on a second call
    with caplog.at_level(logging.WARNING, logger="jax"), jax.log_compiles():
        again = fitting.profile_likelihood(res, name, v + 0.5 * offsets * s)
    compiled = [r.getMessage() for r in caplog.records if "Compiling" in r.getMessage()]
    assert not any("profile" in m or "solve" in m for m in compiled), compiled
    assert np.all(np.diff(again["delta_chi2"][2:]) > 0)


def test_profile_likelihood_bad_input(noisy_fit):
    with pytest.raises(ValueError, match="name: .*unknown parameter 'tau'"):
        fitting.profile_likelihood(noisy_fit, "tau", [1.0])
    with pytest.raises(ValueError, match="values of 'eta1' must be finite and > 0"):
        fitting.profile_likelihood(noisy_fit, "eta1", [1e3, -1.0])
    with pytest.raises(ValueError, match="values of 'eta1' must be finite and > 0"):
        fitting.profile_likelihood(noisy_fit, "eta1", [np.nan])
    with pytest.raises(ValueError, match="values must be a non-empty 1-D array"):
        fitting.profile_likelihood(noisy_fit, "eta1", [])


# --------------------------------------------------------------------------------------
# Data the fit cannot use: no detachment, NaN
# --------------------------------------------------------------------------------------


def test_no_detachment_is_not_a_confident_work_of_adhesion():
    # lifts of 0.6 um from 1 um: the contact stays pinned and holds; the force in the
    # pinned phase does not depend on the work of adhesion, so the data bound it only from
    # below: it must be reported as not determined (or at its bound), never with a small
    # error bar, and the moduli (which the pinned contact determines) are kept
    curves = _relaxed_curves(0.6e-6, speeds=(0.5e-6, 2e-6, 8e-6))
    for c in curves:
        assert c.force[-1] == np.min(c.force) < 0  # still loaded, most tensile at the end
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = fitting.fit(curves, radius=R, n_starts=STARTS, progress=False)
    i = res.names.index("work_of_adhesion")
    assert res.status[i] != "ok"
    assert not (np.isfinite(res.stderr[i]) and res.stderr[i] < 0.5 * res.values[i])
    msgs = [str(w.message) for w in caught if issubclass(w.category,
                                                         fitting.IdentifiabilityWarning)]
    assert any(m.startswith("work_of_adhesion ") and "ends still pulling" in m
               and "only from below" in m for m in msgs) or res.status[i].startswith("at "), msgs
    for k in ("G0", "G1", "eta1"):
        assert res[k] == pytest.approx(TRUE[k], rel=0.01), k
        assert res.status[res.names.index(k)] == "ok"


def test_how_a_retract_ends_and_what_it_bounds_of_the_work_of_adhesion():
    # constructed retracts (sigma 1): what the data say of the work of adhesion when no
    # curve jumps off, from the force alone
    from fitting._prepare import retract_end
    from fitting._uncertainty import adhesion_note

    t = np.linspace(0.0, 1.0, 200)
    dip = -40.0 * np.sin(np.pi * np.clip(t / 0.5, 0, 1))  # a tensile dip back to 0 at t 0.5
    jump = np.where(t < 0.4, -40.0 * t / 0.4, 0.0)  # pulls harder, then lets go at once
    held = -40.0 * t  # still pulling when the lift ends
    free = 2.0 * np.sin(40 * t)  # never below -3 sigma
    assert retract_end(jump, 1.0) == "jump-off"
    assert retract_end(dip, 1.0) == "gradual"
    assert retract_end(held, 1.0) == "held"
    assert retract_end(free, 1.0) == "no adhesion"
    assert retract_end(held, 1.0, jumps=True) == "jump-off"  # the preparation's finding
    # the tail is the last tenth, weighted by the measured samples each kept one stands for
    tail = np.r_[dip[:180], np.full(20, -5.0)]
    assert retract_end(tail, 1.0) == "held"
    assert retract_end(tail, 10.0) == "gradual"
    ends = np.r_[dip[:180], np.full(10, -10.0), np.zeros(10)]  # the last tenth: -5 a sample
    assert retract_end(ends, 1.0, jumps=False) == "held"
    # ... but the free samples stand for 100 measured ones each: -0.1 a measured sample
    w = np.r_[np.ones(190), np.full(10, 100.0)]
    assert retract_end(ends, 1.0, w, jumps=False) == "gradual"
    assert retract_end(np.array([]), 1.0) == "no retract"
    assert adhesion_note(["jump-off", "held"]) == "" and adhesion_note([]) == ""
    assert adhesion_note(["no retract"]) == ""
    assert "only from above" in adhesion_note(["no adhesion", "no retract"])
    assert "only from below" in adhesion_note(["held", "gradual", "no adhesion"])
    assert "only from above" in adhesion_note(["no adhesion", "no adhesion"])
    assert "returns gradually" in adhesion_note(["gradual", "no adhesion"])


def test_nan_data_rejected(tmp_path, capsys):
    c = _relaxed_curves(4.5e-6, speeds=(4e-6,), n=20)[0]
    force = c.force.copy()
    force[7] = np.nan
    with pytest.raises(ValueError, match=r"force has a non-finite value \(nan\) at sample 7"):
        fitting.Curve(time=c.time, displacement=c.displacement, force=force)
    path = tmp_path / "nan.csv"
    _write_csv(path, c)
    lines = path.read_text().splitlines()
    parts = lines[8].split(",")
    lines[8] = ",".join([parts[0], parts[1], "nan"])
    path.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    code = _fit_cli([str(path), "--radius", str(R), "--out", str(out),
                                  "--quiet"])
    err = capsys.readouterr().err
    assert code != 0 and err.count("nan.csv") == 1, err
    assert "column 'force_N' has a non-finite value ('nan') at data row 8" in err, err
    assert not out.exists()


# --------------------------------------------------------------------------------------
# Prony series, nested models, model choice (relaxed model, three lift speeds)
# --------------------------------------------------------------------------------------

PRONY = {"G_inf": 4e3, "G_1": 6e3, "G_2": 3e3, "tau_1": 0.05, "tau_2": 2.0,
         "work_of_adhesion": 5e-3}


def _prony_curves(noise=0.0, seed=0):
    # relaxation times 40x apart; lifts of 4 um last 8 s, 2 s and 0.5 s: the slow lift sees
    # tau_2, the fast one tau_1
    rheology = jc.PronySeries(PRONY["G_inf"], np.array([PRONY["G_1"], PRONY["G_2"]]),
                              np.array([PRONY["tau_1"], PRONY["tau_2"]]))
    rng = np.random.default_rng(seed)
    out = []
    for v in (0.5e-6, 2e-6, 8e-6):
        ts = np.linspace(0.0, 4e-6 / v, 60)
        sol = jc.retract(rheology, jc.Parabola(R), work_of_adhesion=PRONY["work_of_adhesion"],
                         depth=D0, ts=ts, velocity=v)
        assert np.isfinite(float(sol.jumpoff_time))
        f = np.asarray(sol.force)
        out.append(fitting.Curve(time=ts, displacement=np.asarray(sol.displacement),
                                 force=f + noise * np.ptp(f) * rng.standard_normal(60),
                                 segment=np.zeros(60, int), segment_names=("retract",)))
    return out


@pytest.fixture(scope="module")
def prony_curves():
    return _prony_curves(noise=0.005, seed=11)


@pytest.fixture(scope="module")
def auto_fit(prony_curves):
    return _fit(prony_curves, rheology="auto")


def test_auto_chooses_the_true_model_and_nested_fits_never_get_worse(auto_fit):
    res = auto_fit
    names = [m.rheology for m in res.model_selection]
    assert names == ["standard", "prony:2", "prony:3"]
    chi2 = {m.rheology: m.chi2 for m in res.model_selection}
    # each richer model contains the simpler one and starts from its optimum (an arm split
    # in two): never worse than the model it contains, to round-off
    assert chi2["prony:2"] <= chi2["standard"] * (1 + 1e-9)
    assert chi2["prony:3"] <= chi2["prony:2"] * (1 + 1e-9)
    # two arms generated the data: BIC picks prony:2 (prony:3 gains less than its penalty)
    assert res.rheology == "prony:2" and [m.chosen for m in res.model_selection] == [
        False, True, False]
    bic = {m.rheology: m.bic for m in res.model_selection}
    assert bic["prony:2"] < bic["standard"] - 10
    assert "model selection" in str(res)


def test_one_relaxation_time_richer_models_end_at_the_standard_fit():
    # data of the standard model (one relaxation time) with 1 % noise: the second arm has
    # nothing to explain, so prony:2 can at best match the standard fit, and the nested
    # start (the standard optimum as two equal arms) must let it; BIC keeps the standard
    curves = _relaxed_curves(3e-6, noise=0.01, seed=3, speeds=(0.5e-6, 2e-6, 8e-6))
    res = _fit(curves, rheology="auto")
    chi2 = {m.rheology: m.chi2 for m in res.model_selection}
    assert chi2["prony:2"] <= chi2["standard"] * (1 + 1e-9)
    assert chi2["prony:3"] <= chi2["prony:2"] * (1 + 1e-9)
    assert res.rheology == "standard"


def test_nested_start_is_the_simpler_model():
    # among the nested starts of prony:2 and prony:3 from a standard optimum, one has the
    # same relaxation modulus G(t) (jaxcontact's own rheologies), so the same loss
    spec1 = fitting._spec.make_spec("relaxed", "standard")
    # scales: relaxation times from 1 ms to 1000 s (the other scales are not used)
    scales = fitting._start.DataScales(1e4, 1e4, 1.0, 1e-3, 1e3, 10.0, 1e-3, 1e-6, 1e-9)
    ts = np.geomspace(1e-4, 1e2, 13)
    g_std = jc.StandardModel(TRUE["G0"], TRUE["G1"], TRUE["eta1"]).relaxation(ts)
    for arms in (2, 3):
        spec = fitting._spec.make_spec("relaxed", f"prony:{arms}")
        starts = fitting._start.nested_starts(spec, spec1, TRUE, scales)
        assert len(starts) > 1 and all(q["work_of_adhesion"] == TRUE["work_of_adhesion"]
                                       for q in starts)
        errors = []
        for q in starts:
            g = jc.PronySeries(q["G_inf"], np.array([q[f"G_{k + 1}"] for k in range(arms)]),
                               np.array([q[f"tau_{k + 1}"] for k in range(arms)]))
            errors.append(float(np.max(np.abs(g.relaxation(ts) / g_std - 1))))
        assert min(errors) < 1e-14, errors


def test_prony_fit_recovers_parameters(auto_fit, prony_curves):
    res = auto_fit
    assert res.names == list(PRONY)
    assert res.columns == ["G_inf_Pa", "G_1_Pa", "G_2_Pa", "tau_1_s", "tau_2_s",
                           "work_of_adhesion_J_m2"]
    for k, v in PRONY.items():
        i = res.names.index(k)
        assert abs(res[k] - v) < 4 * res.stderr[i], (k, res[k], res.stderr[i])
    # a direct prony:2 fit (which runs the nested chain standard -> prony:2) agrees
    direct = _fit(prony_curves, rheology="prony:2")
    assert direct.chi2 == pytest.approx(res.chi2, rel=1e-6)


def test_cli_prony(prony_curves, tmp_path, monkeypatch):
    monkeypatch.setenv("JAXCONTACT_CACHE", str(tmp_path / "cache"))
    files = []
    for k, c in enumerate(prony_curves):
        files.append(str(tmp_path / f"prony{k}.csv"))
        _write_csv(files[-1], c)
    out = tmp_path / "result"
    code = _fit_cli([*files, "--radius", str(R), "--rheology", "prony:2",
                     "--starts", str(STARTS), "--no-figure", "--quiet", "--out", str(out)])
    assert code == 0
    table, rows = _read_outputs(out)
    assert table["rheology"] == "prony:2" and table["model"] == "relaxed"
    for k, v in PRONY.items():
        unit = {"G": "Pa", "t": "s", "w": "J_m2"}[k[0]]
        assert table[f"{k}_{unit}"]["value"] == pytest.approx(v, rel=0.1), k
    assert [r["parameter"] for r in rows] == list(PRONY)
    assert table["loading"] == {"type": "displacement", "spring_constant_N_m": None}
    assert len(table["inputs"]) == 3 and table["r_squared"] > 0.99
    assert (out / "fit.csv").is_file()


# --------------------------------------------------------------------------------------
# Instrument files through the command line
# --------------------------------------------------------------------------------------


@pytest.mark.slow
def test_cli_ibw_relaxed(tmp_path, monkeypatch, capsys):
    """Asylum force-distance file: spring constant and segments from the file."""
    pytest.importorskip("afmformats")
    monkeypatch.setenv("JAXCONTACT_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "ibw"
    code = _fit_cli([str(DATA / "sin-force-distance.ibw"), "--radius", str(R),
                     "--max-samples", "60", "--starts", str(STARTS), "--out", str(out)])
    assert code in (0, 3)  # 3: written, but not converged
    stdout = capsys.readouterr().out
    table, rows = _read_outputs(out)
    (inp,) = table["inputs"]
    assert inp["spring_constant_N_m"] == pytest.approx(1.1841, rel=1e-4)
    assert inp["segments"] == ["approach", "retract"]
    assert inp["source"].endswith("sin-force-distance.ibw")
    assert table["loading"]["type"] == "displacement"
    assert table["converged"] == (code == 0)
    assert 0.9 < table["r_squared"] <= 1.0
    assert f"R^2 (all)          {table['r_squared']:.5f}" in stdout
    # the contact point of an instrument file is fitted by default
    assert table["contact_point"] == "fit" and "contact_offset_m" in table
    for r in rows:
        assert r["status"] in ("ok", "not determined", "at lower bound", "at upper bound")
        assert r["stderr"] == "" or float(r["stderr"]) > 0
    png = (out / "fit.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 1000


def test_cli_jpk_inputs():
    """JPK stress-relaxation file: four segments and the spring constant of the file;
    --spring-constant overrides it and rescales the force."""
    pytest.importorskip("afmformats")
    path = str(DATA / "oocyte-stress-relaxation-cell1-0008.jpk-force")
    base = ["--radius", "40e-6", "--out", "unused", "--model", "history"]
    (c,), _ = load_inputs(_args([path, *base]))
    assert c.segment_names == ("rest", "approach", "hold", "retract")
    assert c.spring_constant == pytest.approx(1.0677, rel=1e-4)
    (c2,), _ = load_inputs(_args([path, *base, "--spring-constant", "2.0"]))
    assert c2.spring_constant == 2.0
    # the raw deflection force scales with k; the baseline is removed the same way
    i = int(np.argmax(c.force))
    assert c2.force[i] == pytest.approx(c.force[i] * 2.0 / c.spring_constant, rel=1e-6)


@pytest.mark.parametrize(
    "extra, needle",
    [
        (["--cells", "1", "--model", "history"], "--cells"),
        (["--max-samples", "1"], "--max-samples"),
    ],
)
def test_cli_bad_options(tmp_path, capsys, extra, needle):
    path = tmp_path / "c.csv"
    _write_csv(path, _relaxed_curves(4.5e-6, speeds=(4e-6,), n=20)[0])
    out = tmp_path / "out"
    code = _fit_cli([str(path), "--radius", str(R), *extra, "--out", str(out),
                                  "--quiet"])
    assert code != 0 and needle in capsys.readouterr().err
    assert not out.exists()


def test_levenberg_marquardt_follows_the_valley_of_an_almost_elastic_arm():
    # the valley that made nested prony:2 fits of real curves run to their step limit: an
    # arm whose relaxation time is far beyond the curve (here 20x) acts as a spring beside
    # G_inf, so the data fix G_inf + G_2 (and a slight slope) and the two moduli trade off
    # along a narrow valley, curved in the log coordinates the fit uses. The relaxation
    # modulus is linear in the moduli: the optimum is the truth exactly (noise-free data).
    import jax.numpy as jnp

    from fitting._least_squares import LevenbergMarquardt, run_starts

    t = jnp.linspace(0.0, 1.0, 50)
    decay = jnp.exp(-t / 20.0)
    data = 1.0 + 3.0 * decay  # G_inf = 1, G_2 = 3 [units of the data]

    def fn(z, ctx):  # z: log G_inf, log G_2; sigma = 1e-4
        return (jnp.exp(z[0]) + jnp.exp(z[1]) * decay - data) / 1e-4

    # starts at the two ends of the valley (the sum nearly right, the split wrong)
    z0 = jnp.log(jnp.array([[3.9, 0.1], [0.05, 3.95]]))
    # plain Levenberg-Marquardt (the default) crawls: 125 and 86 steps; with geodesic
    # acceleration and a bounded step it converges within 60 (45 and 37)
    s = run_starts(LevenbergMarquardt(max_steps=60, geodesic=True, max_step=4.0), fn, z0,
                   None)
    assert np.all(np.asarray(s.converged)), np.asarray(s.steps)
    np.testing.assert_allclose(np.exp(np.asarray(s.z)), [[1.0, 3.0], [1.0, 3.0]], rtol=1e-7)
    # plain: converged, but each start after more than 61 steps, so not with max_steps=60
    # (the step limit only ends the loop, at steps = 61 unless converged there; the
    # iterates are the same: one compiled loop instead of a second with max_steps=60)
    plain = run_starts(LevenbergMarquardt(max_steps=200), fn, z0, None)
    assert np.all(np.asarray(plain.converged)) and np.all(np.asarray(plain.steps) > 61)


def test_prony_relaxation_times_bounded_by_the_curve_and_nested_starts_inside():
    # an arm slower than the curve is a spring beside G_inf (G_k (1 - exp(-t/tau_k)) ~
    # G_k t / tau_k over it): the default upper bound of tau_k is the duration of the
    # longest curve (8 s here: 4 um lifted at 0.5 um/s), not 10x it; every start lies
    # inside the bounds, away from the flat ends of the logistic; a nested start from a
    # simpler optimum with a relaxation time beyond them widens them to contain it exactly
    import types

    from fitting._optimise import _problem

    curves = _prony_curves()
    longest = max(float(c.time[-1] - c.time[0]) for c in curves)
    options = fitting.FitOptions(profile=jc.Parabola(R), model="relaxed", rheology="prony:2",
                                 contact_point="none", n_starts=8, seed=0)
    opts = dict(contact_point="none")
    pb = _problem(curves, options, rheology="prony:2", previous=None, **opts)
    t_idx = [pb.names.index("tau_1"), pb.names.index("tau_2")]
    upper = np.exp(np.asarray(pb.param.upper)[t_idx])
    np.testing.assert_allclose(upper, [longest, longest], rtol=1e-12)
    assert np.max(np.abs(pb.zs)) < 10  # no start in the saturated logistic
    # the standard optimum with tau = eta1 / (G0 + G1) = 3 T, as prony:2's split start
    std = {"G0": 9e3, "G1": 3e3, "eta1": 3 * longest * 12e3, "work_of_adhesion": 5e-3}
    previous = types.SimpleNamespace(spec=fitting._spec.make_spec("relaxed", "standard"),
                                     as_dict=lambda: dict(std))
    pb = _problem(curves, options, rheology="prony:2", previous=previous, **opts)
    nat = np.asarray(jax.vmap(pb.param.natural)(jax.numpy.asarray(pb.zs)))
    split = nat[np.argmin(np.abs(nat[:, t_idx[0]] / (3 * longest) - 1))]
    np.testing.assert_allclose(split[t_idx], [3 * longest] * 2, rtol=1e-9)
    # G_inf = G0 G1 / (G0 + G1) and the two arms share G0 - G_inf (the standard model)
    np.testing.assert_allclose(split[:3], [2.25e3, 3.375e3, 3.375e3], rtol=1e-9)
    assert np.max(np.abs(pb.zs)) < 10
    upper = np.exp(np.asarray(pb.param.upper)[t_idx])
    assert upper[0] == upper[1] > 3 * longest  # one bound: the arms stay interchangeable
    # a standard fit elastic in effect (tau = 1e-15 s, far below two sampling intervals)
    std["eta1"] = 1e-15 * 12e3
    pb = _problem(curves, options, rheology="prony:2", previous=previous, **opts)
    nat = np.asarray(jax.vmap(pb.param.natural)(jax.numpy.asarray(pb.zs)))
    split = nat[np.argmin(np.abs(np.log(nat[:, t_idx[0]] / 1e-15)))]
    np.testing.assert_allclose(split[t_idx], [1e-15] * 2, rtol=1e-9)
    np.testing.assert_allclose(split[:3], [2.25e3, 3.375e3, 3.375e3], rtol=1e-9)
    assert np.max(np.abs(pb.zs)) < 10
