"""The posterior by NUTS (`fitting.sample`): against the truth and the linearised errors,
its diagnostics against known cases, the netCDF groups, the command line.

One small synthetic relaxed problem (2 retract curves x 40 samples, 2 chains x 150 draws)
serves the default-run tests: one compilation of the fit and one of the sampler (about 50 s
of CPU on the 2-core machine, nearly all compilation; the command-line test reuses both).
The posterior band and the figures are a slow test.
"""

import json
import warnings

import numpy as np
import pytest

import fitting
import jaxcontact as jc
from fitting._posterior import diagnostics, identifiability

pytest.importorskip("numpyro")

R = 12e-6
D0 = 1e-6
TRUE = {"G0": 10e3, "G1": 5e3, "eta1": 7.5e3, "work_of_adhesion": 1e-3}
SPEEDS = (0.5e-6, 4e-6)
N = 40
DRAWS, CHAINS = 150, 2


def _curves(noise=0.01, seed=3, lift=3e-6, n=N, speeds=SPEEDS):
    rng = np.random.default_rng(seed)
    out = []
    for v in speeds:
        ts = np.linspace(0.0, lift / v, n)
        sol = jc.retract(jc.StandardModel(TRUE["G0"], TRUE["G1"], TRUE["eta1"]), jc.Parabola(R),
                         work_of_adhesion=TRUE["work_of_adhesion"], depth=D0, ts=ts, velocity=v)
        f = np.asarray(sol.force) + noise * np.ptp(sol.force) * rng.standard_normal(n)
        out.append(fitting.Curve(time=ts, displacement=np.asarray(sol.displacement), force=f,
                                 segment=np.zeros(n, int), segment_names=("retract",)))
    return out


def _fit(curves, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fitting.IdentifiabilityWarning)
        warnings.simplefilter("ignore", fitting.ModelValidityWarning)
        return fitting.fit(curves, radius=R, progress=False, n_starts=2, local_rounds=0, **kw)


@pytest.fixture(scope="module")
def fit_result():
    return _fit(_curves())


@pytest.fixture(scope="module")
def posterior(fit_result):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fitting.PosteriorWarning)  # 300 draws: ESS < 400
        return fitting.sample(fit_result, draws=DRAWS, chains=CHAINS, seed=1, predictive=False)


def test_posterior_agrees_with_truth_and_linearised_errors(fit_result, posterior):
    post = posterior
    assert post.names == ["G0", "G1", "eta1", "work_of_adhesion", "noise_scale_1",
                          "noise_scale_2"]
    assert post["G0"].shape == (CHAINS, DRAWS)
    assert post.divergences == 0
    for name, true in TRUE.items():
        r = post.row(name)
        # the truth within 4 posterior sd of the mean (1 % noise: a fraction of a per cent)
        assert abs(r["mean"] - true) < 4 * r["sd"], (name, r, true)
        # the posterior sd against the Gauss-Newton error of the fit (a second method)
        i = fit_result.names.index(name)
        assert 0.5 < r["sd"] / fit_result.stderr[i] < 2.0, (name, r["sd"], fit_result.stderr[i])
        assert r["q05"] < r["median"] < r["q95"]
        assert r["identifiability"] == "determined"
        assert r["r_hat"] < 1.1 and r["ess_bulk"] > 50
    # each curve's noise scale: near the rms of its normalised residuals at the optimum
    # (a second estimate of the same quantity; 40 samples: ~11 % uncertainty)
    res = fit_result.normalised_residuals
    valid = np.asarray(fit_result.data.valid) > 0
    for c in range(2):
        ns = post.row(f"noise_scale_{c + 1}")
        rms = np.sqrt(np.mean(res[c][valid[c]] ** 2))
        assert 0.6 < ns["mean"] < 1.6
        assert abs(ns["mean"] - rms) < 3 * ns["sd"], (c, ns, rms)
    assert post.predictive is None
    assert "NUTS (numpyro)" in post.summary() and "determined" in post.summary()


def test_step_size_adapted_per_chain_and_fixed_after_warmup(posterior):
    """The recorded step size: one per chain, constant over the kept draws (the warm-up's
    dual averaging ends with it), and the draws' mean acceptance statistic near the
    target it was adapted for (dual averaging's aim; 150 draws: within 0.15)."""
    step = posterior.sample_stats["step_size"]
    assert step.shape == (CHAINS, DRAWS)
    assert np.all(step > 0) and np.all(step == step[:, :1])
    target = posterior.settings["target_accept"]
    accept = posterior.sample_stats["acceptance_rate"].mean(axis=1)
    assert np.all(np.abs(accept - target) < 0.15), (accept, target)
    assert posterior.sample_stats["n_steps"].max() < 2 ** posterior.settings["max_tree_depth"]


def test_max_draws_continues_every_chain_from_its_last_state(fit_result, posterior):
    """`max_draws`: 2 x 150 draws have bulk ESS < 400, so the chains continue for one more
    block of 150 (a third does not fit in 375). The first block is the run without
    `max_draws` to the bit; the continued draws keep the warm-up's step size (no second
    adaptation) and the acceptance statistic it was adapted for; the summary's diagnostics
    are those of all 300 draws."""
    assert posterior.settings["draws_run"] == DRAWS and posterior.settings["extensions"] == 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fitting.PosteriorWarning)
        post = fitting.sample(fit_result, draws=DRAWS, chains=CHAINS, seed=1,
                              predictive=False, max_draws=2 * DRAWS + DRAWS // 2)
    assert post.settings["draws_run"] == 2 * DRAWS and post.settings["extensions"] == 1
    assert post.draws == 2 * DRAWS and post["G0"].shape == (CHAINS, 2 * DRAWS)
    for name in posterior.names:
        np.testing.assert_array_equal(post[name][:, :DRAWS], posterior[name])
    step = post.sample_stats["step_size"]
    np.testing.assert_array_equal(step, np.repeat(posterior.sample_stats["step_size"][:, :1],
                                                  2 * DRAWS, axis=1))
    accept = post.sample_stats["acceptance_rate"][:, DRAWS:].mean(axis=1)
    assert np.all(np.abs(accept - post.settings["target_accept"]) < 0.15), accept
    # the continued draws are new draws of the same posterior: not a copy of the first
    # block, and their means within the first block's spread
    for name in TRUE:
        first, more = post[name][:, :DRAWS], post[name][:, DRAWS:]
        assert not np.array_equal(first, more)
        assert abs(more.mean() - first.mean()) < 0.5 * first.std(), name
    k = post.names.index("G0")
    assert post.row("G0")["r_hat"] == diagnostics(post.internal[..., k])[0]


@pytest.mark.slow
def test_continued_chains_equal_one_longer_run(fit_result, posterior):
    """A chain continued for a second block of draws is the chain run for both blocks at
    once (the same transitions from the same state and random key): within round-off."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fitting.PosteriorWarning)
        cont = fitting.sample(fit_result, draws=DRAWS, chains=CHAINS, seed=1,
                              predictive=False, max_draws=2 * DRAWS)
        once = fitting.sample(fit_result, draws=2 * DRAWS, warmup=DRAWS, chains=CHAINS,
                              seed=1, predictive=False)
    assert cont.settings["extensions"] == 1
    for name in posterior.names:
        np.testing.assert_allclose(cont[name], once[name], rtol=1e-9)


def test_an_informative_prior_moves_the_posterior_as_gaussians_combine(fit_result):
    """A narrow prior on G0 (centre 5 % above the fit, sd 0.2 % in ln G0): the posterior
    means of all parameters move as the product of the fit's linearised Gaussian (in
    ln p) and the prior predicts: mean = u + (C^-1 + P)^-1 P (mu - u). The same compiled
    sampler (the prior's numbers are arguments)."""
    names = list(TRUE)
    idx = [fit_result.names.index(n) for n in names]
    u = np.log(fit_result.values[idx])
    C = fit_result.covariance[np.ix_(idx, idx)] / np.outer(fit_result.values[idx],
                                                             fit_result.values[idx])
    width = 0.002
    centre = fit_result["G0"] * 1.05
    P = np.zeros((4, 4))
    P[0, 0] = 1.0 / width**2
    mu = u.copy()
    mu[0] = np.log(centre)
    cov_post = np.linalg.inv(np.linalg.inv(C) + P)
    expect = u + cov_post @ P @ (mu - u)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fitting.PosteriorWarning)
        post = fitting.sample(fit_result, draws=DRAWS, chains=CHAINS, seed=3, predictive=False,
                              prior={"G0": (centre, width)})
    assert post.prior["G0"].startswith("normal of ln(G0)")
    for j, n in enumerate(names):
        got = np.log(post[n]).mean()
        sd = np.sqrt(cov_post[j, j])
        assert abs(got - expect[j]) < 0.3 * sd + 0.15 * abs(expect[j] - u[j]), \
            (n, got, expect[j], u[j], sd)
    # G0 moved by most of the way to the prior's centre (the data's sd is ~1 %)
    assert np.log(post["G0"]).mean() - u[0] > 0.8 * (mu[0] - u[0]) * C[0, 0] / (C[0, 0] + width**2)


def test_netcdf_groups_json_and_csv(posterior, tmp_path):
    xr = pytest.importorskip("xarray")
    path = tmp_path / "posterior.nc"
    posterior.to_netcdf(path)
    with xr.open_dataset(path, group="posterior", engine="h5netcdf") as ds:
        assert set(ds.data_vars) == set(posterior.names)
        assert ds["G0"].dims == ("chain", "draw")
        np.testing.assert_array_equal(ds["G0"].values, posterior["G0"])
        assert ds["eta1"].attrs["units"] == "Pa_s"
    with xr.open_dataset(path, group="sample_stats", engine="h5netcdf") as ds:
        assert {"diverging", "lp", "acceptance_rate", "tree_depth", "energy",
                "step_size"} <= set(ds)
        assert int(ds["diverging"].sum()) == posterior.divergences
    with xr.open_dataset(path, group="observed_data", engine="h5netcdf") as ds:
        f = ds["force"].values
        assert f.shape == (2, N)
        np.testing.assert_allclose(f[0], posterior.fit.curves[0].force)
    doc = json.loads(posterior.to_json())
    assert [p["name"] for p in doc["parameters"]] == posterior.names
    assert doc["chains"] == CHAINS and doc["draws"] == DRAWS
    lines = posterior.to_csv().splitlines()
    assert lines[0].startswith("name,unit,mean,sd,q05,median,q95,r_hat,ess_bulk,ess_tail")
    assert len(lines) == 1 + len(posterior.names)


def test_bad_arguments_name_the_argument(fit_result):
    for kw, needle in (({"draws": 0}, "draws"), ({"chains": 0}, "chains"),
                       ({"target_accept": 1.5}, "target_accept"),
                       ({"max_draws": 100}, "max_draws must be an integer >= 1000"),
                       ({"prior": {"G9": "uniform"}}, "prior: unknown parameter"),
                       ({"prior": {"G0": (-1.0, 1.0)}}, "prior for 'G0'"),
                       ({"prior": {"G0": "wide"}}, "prior for 'G0'"),
                       ({"prior": {"noise_scale": "uniform"}}, "noise_scale"),
                       ({"prior": "flat"}, "prior must be")):
        with pytest.raises(ValueError, match=needle):
            fitting.sample(fit_result, **kw)
    with pytest.raises(ValueError, match="fit must be a FitResult"):
        fitting.sample({"G0": 1.0})


def test_diagnostics_on_known_draws():
    rng = np.random.default_rng(0)
    iid = rng.standard_normal((4, 1000))
    rhat, bulk, tail = diagnostics(iid)
    assert rhat < 1.01
    assert 3000 < bulk < 5000 and 2500 < tail < 5500  # independent draws: ESS ~ 4000
    # chains that disagree (means 1 sd apart): R-hat far above 1.01
    apart = iid + np.arange(4)[:, None]
    assert diagnostics(apart)[0] > 1.3
    # an AR(1) chain with rho = 0.9: ESS ~ N (1 - rho) / (1 + rho) = 4000 / 19 ~ 210
    x = np.zeros((4, 1000))
    e = rng.standard_normal((4, 1000))
    for t in range(1, 1000):
        x[:, t] = 0.9 * x[:, t - 1] + np.sqrt(1 - 0.81) * e[:, t]
    assert 120 < diagnostics(x)[1] < 330


def test_identifiability_words():
    rng = np.random.default_rng(1)
    assert identifiability(rng.normal(0.0, 0.1, 4000), -5.0, 5.0) == "determined"
    # piled against the lower bound: the data give only an upper limit
    assert identifiability(-5.0 + rng.exponential(0.3, 4000), -5.0, 5.0) == \
        "bounded from above only"
    assert identifiability(5.0 - rng.exponential(0.3, 4000), -5.0, 5.0) == \
        "bounded from below only"
    assert identifiability(rng.uniform(-5.0, 5.0, 4000), -5.0, 5.0) == "not determined"
    # wide but inside the bounds: not determined (sd above the fit's limit 0.5)
    assert identifiability(rng.normal(0.0, 1.0, 4000), -20.0, 20.0) == "not determined"


def test_cli_posterior_writes_listed_files(tmp_path, fit_result, capsys):
    """`jaxcontact fit --posterior` on the tests' curves as CSV files: the posterior files,
    all listed in the manifest (the same shapes as the library test: one compilation)."""
    from jaxcontact_cli import main
    from jaxcontact_cli._common import MANIFEST

    files = _as_csv_files(fit_result.curves, tmp_path)
    out = tmp_path / "out"
    rc = main(["fit", *files, "--radius", str(R), "--starts", "2", "--posterior",
               "--draws", str(DRAWS), "--chains", str(CHAINS), "--quiet", "--no-figure",
               "--out", str(out)])
    assert rc == 0
    names = {p.name for p in out.iterdir()}
    assert {"posterior.nc", "posterior.json", "posterior.csv", "parameters.json"} <= names
    listed = set(json.loads((out / MANIFEST).read_text())["files"])
    assert listed == names - {MANIFEST}
    assert {"posterior.nc", "posterior.json", "posterior.csv"} <= listed
    doc = json.loads((out / "posterior.json").read_text())
    assert {p["name"] for p in doc["parameters"]} >= set(TRUE)
    # bad option values: a one-line usage error, nothing written
    rc = main(["fit", *files, "--radius", str(R), "--posterior", "--draws", "3",
               "--out", str(tmp_path / "bad")])
    assert rc == 2 and not (tmp_path / "bad").exists()
    assert "--draws" in capsys.readouterr().err
    rc = main(["fit", *files, "--radius", str(R), "--posterior", "--draws", "50",
               "--max-draws", "20", "--out", str(tmp_path / "bad")])
    assert rc == 2 and not (tmp_path / "bad").exists()
    assert "--max-draws: must be an integer >= --draws (50); got 20" in capsys.readouterr().err


@pytest.mark.slow
def test_cli_figures_and_posterior_band(tmp_path, fit_result):
    """With figures: corner.png and fit.png (with the band) are written and listed; the
    band of the model force brackets the fitted model curve."""
    from jaxcontact_cli import main
    from jaxcontact_cli._common import MANIFEST

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fitting.PosteriorWarning)
        post = fitting.sample(fit_result, draws=DRAWS, chains=CHAINS, seed=2)
    lo, mid, hi = post.predictive
    valid = np.asarray(fit_result.data.valid) > 0
    fm = np.asarray(fit_result.model_force)
    inside = (lo[valid] - 1e-12 <= fm[valid]) & (fm[valid] <= hi[valid] + 1e-12)
    assert inside.mean() > 0.8
    files = _as_csv_files(fit_result.curves, tmp_path)
    out = tmp_path / "out"
    assert main(["fit", *files, "--radius", str(R), "--starts", "2", "--posterior",
                 "--draws", str(DRAWS), "--chains", str(CHAINS), "--quiet",
                 "--out", str(out)]) == 0
    listed = set(json.loads((out / MANIFEST).read_text())["files"])
    assert {"corner.png", "fit.png", "posterior.nc"} <= listed
    assert (out / "corner.png").stat().st_size > 10_000


def _as_csv_files(curves, folder) -> list[str]:
    """The curves as CSV files (time, displacement, force) for the command line."""
    files = []
    for i, c in enumerate(curves):
        p = folder / f"c{i}.csv"
        np.savetxt(p, np.column_stack([c.time, c.displacement, c.force]), delimiter=",",
                   header="time_s,displacement_m,force_N", comments="")
        files.append(str(p))
    return files
