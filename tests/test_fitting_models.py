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

import jax
import numpy as np
import pytest
from test_fitting import D0, TRUE, R, _curves

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
    """parameters.json (parsed) and parameters.csv (rows as dicts); both must parse."""
    table = json.loads((out / "parameters.json").read_text())
    with (out / "parameters.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    return table, rows


# --------------------------------------------------------------------------------------
# Profile likelihood (two relaxed curves, 1 % noise; every curve detaches)
# --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def noisy_fit():
    curves = _relaxed_curves(4.5e-6, noise=0.01, seed=3)
    return fitting.fit(curves, radius=R, initial=TRUE, n_starts=1, progress=False)


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
    # standard errors; within 15 % (measured 0.95-0.98). (The profile of the work of
    # adhesion is not quadratic: below the optimum the ramp switches off the samples the
    # earlier model jump-off passes, and it rises about half as fast.)
    np.testing.assert_allclose(dchi[[1, 3]], 1.0, rtol=0.15)
    np.testing.assert_allclose(dchi[[0, 4]], 4.0, rtol=0.15)
    # the profiled parameter is held at its value, the others are refitted
    np.testing.assert_allclose(prof["others"][:, i], v + offsets * s, rtol=1e-12)
    # a direct fit with the parameter fixed finds the same other parameters and chi2
    direct = fitting.fit(res.curves, radius=R, initial=res.as_dict(),
                         fixed={name: float(v + s)}, n_starts=1, progress=False)
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


def test_no_detachment_names_the_work_of_adhesion():
    # lifts of 1.2 um from 1 um: the contact holds (jump-off after 3.7 and 2.1 um of lift)
    curves = _relaxed_curves(1.2e-6)
    for c in curves:
        assert c.force[-1] == np.min(c.force) < 0  # still loaded, most tensile at the end
    # Before: from a low guess the fit sat on the lower bound of the work of adhesion (0.39
    # of the truth) with a 0.1 % standard error and no warning. Now the message names it
    # and why; its standard error is infinite, the moduli (which the pinned contact
    # determines) are kept.
    with pytest.warns(fitting.IdentifiabilityWarning,
                      match=r"work_of_adhesion is not determined by the data: no curve "
                            r"detaches") as caught:
        res = fitting.fit(curves, radius=R, initial={k: v / 3 for k, v in TRUE.items()},
                          n_starts=1, progress=False)
    assert len(caught) == 1, [str(w.message) for w in caught]
    i = res.names.index("work_of_adhesion")
    assert res.stderr[i] == np.inf and np.all(np.isnan(res.covariance[i]))
    assert any("no curve detaches" in w for w in res.warnings)
    for k in ("G0", "G1", "eta1"):
        assert res[k] == pytest.approx(TRUE[k], rel=0.01), k
        assert np.isfinite(res.stderr[res.names.index(k)])
    # the message depends on the free work of adhesion and on no curve detaching
    from fitting._objective import make_spec, prepare_curves
    from fitting._uncertainty import detachment_message

    names = list(TRUE)
    assert detachment_message(res.data, names, [0, 1, 2]) is None
    assert "no curve detaches" in detachment_message(res.data, names, [0, 1, 2, 3])
    both = prepare_curves([*curves, _relaxed_curves(4.5e-6, speeds=(4e-6,))[0]], make_spec(),
                          radius=R)
    assert detachment_message(both, names, [0, 1, 2, 3]) is None


def test_early_model_jumpoff_is_penalised():
    """A curve that ends attached gets a one-sided jump-off residual."""
    from fitting._objective import make_spec, prepare_curves, residuals_natural

    spec = make_spec()
    detaching = _relaxed_curves(4.5e-6, speeds=(4e-6,))[0]
    holding = _relaxed_curves(1.2e-6, speeds=(4e-6,))[0]
    data = prepare_curves([detaching, holding], spec, radius=R)
    np.testing.assert_array_equal(np.asarray(data.has_jump), [1.0, 0.0])
    np.testing.assert_array_equal(np.asarray(data.attached_end), [0.0, 1.0])
    truth = np.array([TRUE[k] for k in ("G0", "G1", "eta1", "work_of_adhesion")])
    r = np.asarray(residuals_natural(truth, data, spec))
    assert r[-1] == 0.0  # the true model holds beyond the end of the second curve
    weak = truth * np.array([1, 1, 1, 0.3])
    sol = jc.retract(jc.StandardModel(*truth[:3]), jc.Parabola(R),
                     work_of_adhesion=weak[3], depth=D0, ts=holding.time, velocity=4e-6)
    jd = float(sol.jumpoff_displacement)
    assert jd > holding.displacement[-1]  # this model detaches inside the second curve
    r_weak = np.asarray(residuals_natural(weak, data, spec))
    expected = (jd - holding.displacement[-1]) / float(data.jump_sigma[1])
    assert r_weak[-1] == pytest.approx(expected, rel=1e-9)


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
# Prony series (relaxed model, two arms, three lift speeds)
# --------------------------------------------------------------------------------------

PRONY = {"G_inf": 4e3, "G_1": 6e3, "G_2": 3e3, "tau_1": 0.05, "tau_2": 2.0,
         "work_of_adhesion": 5e-3}


@pytest.fixture(scope="module")
def prony_curves():
    # relaxation times 40x apart; lifts of 4 um last 8 s, 2 s and 0.5 s (jump-off after
    # 3.7, 2.8 and 2.3 um): the slow lift sees tau_2, the fast one tau_1
    rheology = jc.PronySeries(PRONY["G_inf"], np.array([PRONY["G_1"], PRONY["G_2"]]),
                              np.array([PRONY["tau_1"], PRONY["tau_2"]]))
    out = []
    for v in (0.5e-6, 2e-6, 8e-6):
        ts = np.linspace(0.0, 4e-6 / v, 100)
        sol = jc.retract(rheology, jc.Parabola(R), work_of_adhesion=PRONY["work_of_adhesion"],
                         depth=D0, ts=ts, velocity=v)
        assert np.isfinite(float(sol.jumpoff_time))
        out.append(fitting.Curve(time=ts, displacement=np.asarray(sol.displacement),
                                 force=np.asarray(sol.force), segment=np.zeros(100, int),
                                 segment_names=("retract",)))
    return out


def test_prony_fit_recovers_parameters(prony_curves):
    spec = fitting.make_spec("relaxed", "prony:2")
    guess = fitting.initial_guess(prony_curves, spec, jc.Parabola(R))
    # the data-derived guess is well off (G_1 and tau_2 by a factor 2)
    assert max(abs(np.log(guess[k] / v)) for k, v in PRONY.items()) > np.log(1.9)
    res = fitting.fit(prony_curves, radius=R, rheology="prony:2", n_starts=1, progress=False)
    assert res.names == list(PRONY)
    assert res.columns == ["G_inf_Pa", "G_1_Pa", "G_2_Pa", "tau_1_s", "tau_2_s",
                           "work_of_adhesion_J_m2"]
    err = {k: abs(res[k] / v - 1) for k, v in PRONY.items()}
    assert max(err.values()) < 0.02, err
    # noiseless: the moduli and times to much better than the work of adhesion, whose
    # optimum the event residuals shift by ~0.6 %
    assert max(err[k] for k in PRONY if k != "work_of_adhesion") < 1e-3, err
    assert res.converged and np.all(np.isfinite(res.stderr))


def test_cli_prony(prony_curves, tmp_path, monkeypatch):
    monkeypatch.setenv("JAXCONTACT_CACHE", str(tmp_path / "cache"))
    files = []
    for k, c in enumerate(prony_curves):
        files.append(str(tmp_path / f"prony{k}.csv"))
        _write_csv(files[-1], c)
    out = tmp_path / "result"
    code = _fit_cli([*files, "--radius", str(R), "--rheology", "prony:2",
                                  "--starts", "1", "--no-figure", "--quiet", "--out",
                                  str(out)])
    assert code == 0
    table, rows = _read_outputs(out)
    assert table["rheology"] == "prony:2" and table["model"] == "relaxed"
    for k, v in PRONY.items():
        unit = {"G": "Pa", "t": "s", "w": "J_m2"}[k[0]]
        assert table[f"{k}_{unit}"]["value"] == pytest.approx(v, rel=0.02), k
    assert [r["parameter"] for r in rows] == list(PRONY)
    assert table["loading"] == {"type": "displacement", "spring_constant_N_m": None}
    assert len(table["inputs"]) == 3 and table["r_squared"] > 0.9


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
    return fitting.Curve(time=ts, displacement=d, force=f,
                         segment=np.repeat([0, 1, 2], [15, 20, 70]),
                         segment_names=("approach", "hold", "retract"))


def test_compliant_history_fit_recovers_parameters(compliant_curve):
    spec = fitting.make_spec("history", compliant=True, cells=CELLS)
    guess = fitting.initial_guess([compliant_curve], spec, jc.Parabola(R))
    assert abs(np.log(guess["work_of_adhesion"] / TRUE["work_of_adhesion"])) > np.log(2)
    res = fitting.fit(compliant_curve, radius=R, model="history", spring_constant=K,
                      cells=CELLS, n_starts=1, progress=False)
    assert res.spec.compliant and float(res.data.stiffness[0]) == K
    err = {k: abs(res[k] / v - 1) for k, v in TRUE.items()}
    # the jump-off is known to the drive step (50 nm) only; measured errors 1e-7 for the
    # moduli and 1e-3 for the work of adhesion
    assert max(err.values()) < 0.02, err
    assert res.converged and res.r_squared > 0.9999


def test_cli_spring_constant(compliant_curve, tmp_path, monkeypatch):
    monkeypatch.setenv("JAXCONTACT_CACHE", str(tmp_path / "cache"))
    path = tmp_path / "compliant.csv"
    _write_csv(path, compliant_curve, segments=True)
    out = tmp_path / "result"
    argv = [str(path), "--radius", str(R), "--model", "history", "--spring-constant", str(K),
            "--cells", str(CELLS), "--starts", "1", "--no-figure", "--quiet", "--out",
            str(out)]
    assert _fit_cli(argv) == 0
    table, rows = _read_outputs(out)
    assert table["model"] == "history"
    assert table["loading"] == {"type": "compliant", "spring_constant_N_m": [K]}
    assert table["inputs"][0]["segments"] == ["approach", "hold", "retract"]
    for k, v in TRUE.items():
        unit = {"G0": "Pa", "G1": "Pa", "eta1": "Pa_s", "work_of_adhesion": "J_m2"}[k]
        assert table[f"{k}_{unit}"]["value"] == pytest.approx(v, rel=0.02), k
    assert {r["parameter"] for r in rows} == set(TRUE)


# --------------------------------------------------------------------------------------
# Instrument files through the command line
# --------------------------------------------------------------------------------------


def test_cli_ibw_relaxed(tmp_path, monkeypatch, capsys):
    """Asylum force-distance file: spring constant and segments from the file."""
    pytest.importorskip("afmformats")
    monkeypatch.setenv("JAXCONTACT_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "ibw"
    code = _fit_cli([str(DATA / "sin-force-distance.ibw"), "--radius", str(R),
                                  "--max-samples", "60", "--starts", "1", "--out",
                                  str(out)])
    assert code == 0
    stdout = capsys.readouterr().out
    table, rows = _read_outputs(out)
    (inp,) = table["inputs"]
    assert inp["spring_constant_N_m"] == pytest.approx(1.1841, rel=1e-4)
    assert inp["segments"] == ["approach", "retract"]
    assert inp["source"].endswith("sin-force-distance.ibw")
    assert table["loading"]["type"] == "displacement"
    assert 0.9 < table["r_squared"] <= 1.0
    assert f"r_squared = {table['r_squared']:.6f}" in stdout
    for r in rows:
        assert float(r["value"]) > 0 and float(r["stderr"]) > 0
    png = (out / "fit.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 1000


def test_cli_jpk_inputs():
    """JPK stress-relaxation file: four segments and the spring constant of the file;
    --spring-constant overrides it and rescales the force."""
    pytest.importorskip("afmformats")
    path = str(DATA / "oocyte-stress-relaxation-cell1-0008.jpk-force")
    base = ["--radius", "40e-6", "--out", "unused", "--model", "history"]
    (c,) = load_inputs(_args([path, *base]))
    assert c.segment_names == ("rest", "approach", "hold", "retract")
    assert c.spring_constant == pytest.approx(1.0677, rel=1e-4)
    (c2,) = load_inputs(_args([path, *base, "--spring-constant", "2.0"]))
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
