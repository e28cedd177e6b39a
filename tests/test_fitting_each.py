"""Many independent fits in batched calls (`fitting.fit_each`): force maps, failed curves.

The second method is `fitting.fit` on each curve alone: a curve fitted in a batch must end
where it ends alone. Synthetic retract curves (`jc.retract`) with known parameters at
several map points; the real force map `tests/data/force-map-2x2.jpk-force-map` through
the command line.
"""

import json
import os
import subprocess
import sys
import textwrap
import time
import warnings

import numpy as np
import pytest

import fitting
import jaxcontact as jc

R = 12e-6
D0 = 1e-6
N = 50
STARTS = 4
# three map points with different materials (a stiffer, a softer, a more adhesive one)
POINTS = [
    {"G0": 10e3, "G1": 5e3, "eta1": 7.5e3, "work_of_adhesion": 1e-3},
    {"G0": 20e3, "G1": 4e3, "eta1": 6e3, "work_of_adhesion": 1e-3},
    {"G0": 8e3, "G1": 6e3, "eta1": 9e3, "work_of_adhesion": 2e-3},
]
GRID = [(0, 0), (1, 0), (0, 1)]


def _curve(p, *, noise=0.01, seed=0, v=2e-6, grid=(0, 0)):
    rng = np.random.default_rng(seed)
    ts = np.linspace(0.0, 3e-6 / v, N)
    sol = jc.retract(jc.StandardModel(p["G0"], p["G1"], p["eta1"]), jc.Parabola(R),
                     work_of_adhesion=p["work_of_adhesion"], depth=D0, ts=ts, velocity=v)
    f = np.asarray(sol.force)
    f = f + noise * np.ptp(f) * rng.standard_normal(N)
    meta = {"grid index x": grid[0], "grid index y": grid[1],
            "position x": 1e-6 * grid[0], "position y": 1e-6 * grid[1]}
    return fitting.Curve(time=ts, displacement=np.asarray(sol.displacement), force=f,
                         segment=np.zeros(N, int), segment_names=("retract",),
                         source=f"point{grid}", metadata=meta)


def _quiet(fn, *a, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fitting.IdentifiabilityWarning)
        warnings.simplefilter("ignore", fitting.ModelValidityWarning)
        return fn(*a, **kw)


@pytest.fixture(scope="module")
def curves():
    return [_curve(p, seed=i, grid=g) for i, (p, g) in enumerate(zip(POINTS, GRID,
                                                                    strict=True))]


@pytest.fixture(scope="module")
def each(curves):
    # a failed load and a curve the relaxed model cannot use (no positive start depth)
    failed = fitting.FailedCurve("map.jpk-force-map", 3, "no contact found on the approach",
                                 {"grid index x": 1, "grid index y": 1})
    bad = fitting.Curve(time=np.linspace(0, 1, N), displacement=np.linspace(-1e-6, -2e-6, N),
                        force=np.zeros(N), segment=np.zeros(N, int),
                        segment_names=("retract",), source="bad",
                        metadata={"grid index x": 2, "grid index y": 0})
    items = [curves[0], failed, curves[1], bad, curves[2]]
    return _quiet(fitting.fit_each, items, radius=R, n_starts=STARTS, chunk=2,
                  progress=False)


def test_each_curve_ends_where_it_ends_alone(curves, each):
    # the batch (chunks of 2, the last one padded; samples padded to a common length)
    # against `fit` on each curve alone: the same optimum
    for k, c in zip((0, 2, 4), curves, strict=True):
        alone = _quiet(fitting.fit, c, radius=R, n_starts=STARTS, progress=False)
        got = each.results[k]
        assert got is not None and got.converged
        assert got.chi2 == pytest.approx(alone.chi2, rel=1e-9)
        np.testing.assert_allclose(got.values, alone.values, rtol=1e-6)
        np.testing.assert_allclose(got.stderr, alone.stderr, rtol=1e-4)


def test_fit_is_the_one_curve_case_of_fit_each(curves):
    # one pipeline: `fit` of a curve, `fit` of the same options as one FitOptions object,
    # and `fit_each` of that curve alone (one problem, one chunk: the same compiled pool)
    # (the global search alone: the suite's time; the rounds are the same code for both)
    c = curves[1]
    alone = _quiet(fitting.fit, c, radius=R, n_starts=STARTS, local_rounds=0,
                   progress=False)
    options = fitting.FitOptions(radius=R, n_starts=STARTS, local_rounds=0, progress=False)
    same = _quiet(fitting.fit, c, options=options)
    assert same.chi2 == alone.chi2
    np.testing.assert_array_equal(same.values, alone.values)
    np.testing.assert_array_equal(same.stderr, alone.stderr)
    one = _quiet(fitting.fit_each, [c], options=options)
    got = one.results[0]
    assert got.converged and got.chi2 == pytest.approx(alone.chi2, rel=1e-9)
    np.testing.assert_allclose(got.values, alone.values, rtol=1e-7)
    np.testing.assert_allclose(got.stderr, alone.stderr, rtol=1e-6)
    assert got.status == alone.status and got.n_free == alone.n_free
    # the model the fit ends at describes the curve it was made from (an independent check)
    for name, true in POINTS[1].items():
        assert abs(got[name] - true) < 4 * got.stderr[got.names.index(name)], name


def test_each_recovers_every_point_within_its_errors(each):
    # an independent check: the parameters the curves were made with
    for k, p in zip((0, 2, 4), POINTS, strict=True):
        res = each.results[k]
        for name, true in p.items():
            assert abs(res[name] - true) < 4 * res.stderr[res.names.index(name)], (k, name)


def test_failures_are_isolated_and_named(each):
    assert each.results[1] is None and "no contact found" in each.errors[1]
    # a curve with zero force: no contact in the data (before: a confusing start-depth error)
    assert each.results[3] is None and "no contact in the data" in each.errors[3]
    assert each.n_failed == 2 and each.n_converged == 3
    assert all(each.errors[k] is None for k in (0, 2, 4))
    text = each.summary()
    assert "curve 1 (x 1, y 1): failed" in text and "curve 3 (x 2, y 0): failed" in text


def test_dataset_is_labelled_and_round_trips(each, tmp_path):
    ds = each.to_dataset()
    assert ds.sizes["curve"] == 5
    assert list(ds["grid_x"].values) == [0, 1, 1, 2, 0]
    assert ds["G0_Pa"].attrs["units"] == "Pa"
    np.testing.assert_allclose(ds["G0_Pa"].values[[0, 2, 4]], each.values()[[0, 2, 4], 0])
    assert np.isnan(ds["G0_Pa"].values[1]) and ds["G0_Pa_status"].values[1] == "failed"
    assert ds["error"].values[3] != "" and ds["error"].values[0] == ""
    assert ds.attrs["failed"] == 2
    # positions only where every curve has them (the failed load has no position)
    assert "position_x" not in ds.coords
    path = tmp_path / "map.nc"
    ds.to_netcdf(path, engine="h5netcdf")
    import xarray as xr

    back = xr.load_dataset(path, engine="h5netcdf")
    np.testing.assert_allclose(back["G0_Pa"].values, ds["G0_Pa"].values)
    grid = each.grid()
    assert grid["G0_Pa"].dims == ("grid_y", "grid_x")
    assert grid["G0_Pa"].sel(grid_x=1, grid_y=0).item() == pytest.approx(each.values()[2, 0])
    assert np.isnan(grid["G0_Pa"].sel(grid_x=1, grid_y=1).item())


def test_map_outputs_keep_flags_warnings_and_settings(each, tmp_path):
    paths = fitting.write_each_report(each, tmp_path)
    import csv

    with paths["csv"].open() as fh:
        rows = list(csv.DictReader(fh))
    assert [r["status"] for r in rows] == ["ok", "failed", "ok", "failed", "ok"]
    for k in (0, 2, 4):
        assert float(rows[k]["radius_m"]) == R and rows[k]["profile"] == "Parabola"
        assert rows[k]["contact_point"] == "fixed" and rows[k]["convergence"] == "converged"
        # the retract's quality, and R² of the retract = R² of the whole (one segment)
        assert float(rows[k]["r_squared_retract"]) == pytest.approx(
            float(rows[k]["r_squared"]), rel=1e-12)
        assert float(rows[k]["max_residual_retract"]) > 1.0
        # Young's moduli beside the shear moduli (E = 3G), with errors
        assert float(rows[k]["E0_Pa"]) == pytest.approx(3 * float(rows[k]["G0_Pa"]))
        assert float(rows[k]["E0_Pa_stderr"]) == pytest.approx(
            3 * float(rows[k]["G0_Pa_stderr"]))
        assert float(rows[k]["E_inf_Pa_stderr"]) > 0
        # Tabor's parameter of each point (glass modulus, z0 = 0.3 nm): deep in the JKR limit
        assert float(rows[k]["tabor_mu_1"]) == pytest.approx(float(jc.tabor_parameter(
            R, float(rows[k]["work_of_adhesion_J_m2"]), 4 * float(rows[k]["G0_Pa"]))))
        assert float(rows[k]["tabor_mu_1"]) > 5 and float(rows[k]["tabor_mu_1_stderr"]) > 0
        # synthetic curves have no frame of heights: no surface height, not a false one
        assert rows[k]["surface_height_m"] == rows[k]["surface_height_m_stderr"] == ""
    table = json.loads(paths["json"].read_text())
    assert table["settings"]["radius_m"] == R and table["settings"]["model"] == "relaxed"
    # the search's settings, as given (n_starts) and the defaults otherwise
    assert table["settings"]["search"] == {
        "n_starts": STARTS, "screen": fitting.DEFAULT_SCREEN,
        "local_rounds": fitting.DEFAULT_LOCAL_ROUNDS, "max_steps": 200,
        "explore_steps": 200, "abandon": fitting.DEFAULT_ABANDON, "optimiser": "lm",
        "rtol": 1e-8, "seed": 0}
    assert table["ok"] == 3 and table["flagged"] == 0
    import xarray as xr

    ds = xr.load_dataset(paths["netcdf"], engine="h5netcdf")
    assert ds.attrs["radius_m"] == R and ds.attrs["contact_point"] == "fixed"
    assert json.loads(ds.attrs["search"])["n_starts"] == STARTS
    assert list(ds["status"].values) == [r["status"] for r in rows]
    assert ds["E_inf_Pa"].values[0] == pytest.approx(float(rows[0]["E_inf_Pa"]))
    # the console: a status beside every median, the warnings once by kind
    text = each.summary()
    assert "3 ok, 0 flagged" in text and "2 failed" in text
    g0 = [r["G0_Pa"] for r in each.results if r is not None]
    assert f"{np.median(g0):12.5g}   (ok 3)" in text


def test_map_figure_draws_young_moduli_with_units(each, monkeypatch):
    from jaxcontact_cli._plots import plot_map

    fig = plot_map(each)
    axes = {ax.get_title(): ax for ax in fig.axes if ax.get_title()}
    assert set(axes) >= {"E0 [Pa] = 3 G0", "E1 [Pa] = 3 G1", "eta1 [Pa s]",
                         "work_of_adhesion [J/m²]", "R² in contact"}
    # curves without a frame of heights: no topography panel (not a false relief)
    assert np.isnan(each.surface_heights()[0]).all()
    assert not any(t.startswith("surface height") for t in axes)
    assert "surface height" not in each.summary()
    # with heights (as a JPK or Asylum map has them): their panel, above the lowest, in µm,
    # each at its grid point
    heights = np.array([5e-6, 7e-6, 6.5e-6, np.nan, np.nan])[:len(each.results)]
    monkeypatch.setattr(each, "surface_heights", lambda: (heights, heights * 1e-3))
    fig2 = plot_map(each)
    assert "relief 2e-06 m over 3 curve(s)" in each.summary()  # the console says it too
    panel = next(ax for ax in fig2.axes if ax.get_title().startswith("surface height"))
    img2 = panel.images[0].get_array()
    for h, m in zip(heights, each.metadata, strict=True):
        if np.isfinite(h):
            assert img2[m["grid index y"], m["grid index x"]] == pytest.approx(
                (h - 5e-6) * 1e6)
    img = axes["E0 [Pa] = 3 G0"].images[0].get_array()
    j = each.names.index("G0")
    for r, m in zip(each.results, each.metadata, strict=True):
        if r is not None:  # the grid point's pixel holds E0 = 3 G0 of its fit
            assert img[m["grid index y"], m["grid index x"]] == pytest.approx(3 * r.values[j])
    import matplotlib.pyplot as plt

    plt.close(fig)
    plt.close(fig2)


def _with_approach(c, k=6):
    """`c` with a measured approach of `k` samples straight into the lift (no hold): the
    relaxed model's assumption is contradicted, and each fit warns so."""
    t_app = c.time[0] - (c.time[1] - c.time[0]) * np.arange(k, 0, -1)
    return fitting.Curve(
        time=np.r_[t_app, c.time],
        displacement=np.r_[np.linspace(0.0, c.displacement[0], k + 1)[:-1], c.displacement],
        force=np.r_[np.linspace(0.0, c.force[0], k + 1)[:-1], c.force],
        segment=np.r_[np.zeros(k, int), np.ones(len(c), int)],
        segment_names=("approach", "retract"), source=c.source, metadata=c.metadata)


def test_fit_each_warns_once_per_kind_and_keeps_each_curves_warning(curves, tmp_path):
    # per-curve warnings are not repeated for every curve: one warning with the count; each
    # curve keeps its own in the map outputs
    unheld = [_with_approach(c) for c in curves]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        each = fitting.fit_each(unheld, radius=R, n_starts=STARTS, chunk=2, progress=False)
    hold = [w for w in caught if "an approach and no hold" in str(w.message)]
    assert len(hold) == 1 and str(hold[0].message).startswith("3 of 3 fitted curves"), hold
    assert hold[0].filename == __file__  # attributed to the caller's line
    paths = fitting.write_each_report(each, tmp_path)
    import csv

    with paths["csv"].open() as fh:
        rows = list(csv.DictReader(fh))
    assert all("an approach and no hold" in r["warnings"] for r in rows)
    table = json.loads(paths["json"].read_text())
    (kind,) = [w for w in table["warnings"] if "hold" in w["kind"]]
    assert kind["curves"] == 3
    assert "3x: the relaxed model assumes" in each.summary()


def test_bad_options_are_named(curves):
    with pytest.raises(ValueError, match="rheology: 'auto'"):
        fitting.fit_each(curves, radius=R, rheology="auto")
    with pytest.raises(ValueError, match="chunk"):
        fitting.fit_each(curves, radius=R, chunk=0)
    with pytest.raises(ValueError, match="none could be loaded"):
        fitting.fit_each([fitting.FailedCurve("f", 0, "why")], radius=R)
    with pytest.raises(ValueError, match="local_rounds"):
        fitting.fit_each(curves, radius=R, local_rounds=-1)


@pytest.mark.slow  # extended: `python -m pytest -m slow` (the default run's time)
def test_force_map_file_through_the_command_line(tmp_path, capsys):
    from jaxcontact_cli import main

    out = tmp_path / "map"
    rc = main(["fit", "tests/data/force-map-2x2.jpk-force-map", "--radius", "10e-6",
               "--model", "relaxed", "--starts", "4", "--quiet", "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    names = sorted(p.name for p in out.iterdir())
    assert names == [".jaxcontact-manifest.json", "map.csv", "map.nc", "map.png",
                     "parameters.json"]  # the manifest lists what the run wrote
    assert json.loads((out / names[0]).read_text())["files"] == names[1:]
    summary = json.loads((out / "parameters.json").read_text())
    assert summary["curves"] == 4 and summary["failed"] == 0
    import xarray as xr

    ds = xr.load_dataset(out / "map.nc", engine="h5netcdf")
    assert sorted(ds["grid_x"].values.tolist()) == [0, 0, 9, 9]
    assert np.all(ds["r_squared_contact"].values > 0.8)
    rows = (out / "map.csv").read_text().splitlines()
    assert rows[0].startswith("curve,source,grid_x,grid_y") and len(rows) == 5
    # the topography: each point's surface height in the strain gauge's frame
    heights = ds["surface_height_m"].values
    assert np.all(np.isfinite(heights)) and len(set(heights.tolist())) == 4
    curves = fitting.load_afm("tests/data/force-map-2x2.jpk-force-map")
    for c, h, d in zip(curves, heights, ds["contact_offset_m"].values, strict=True):
        assert h == pytest.approx(c.metadata["height at start"] - c.contact.tip_position + d,
                                  rel=1e-12)


def test_force_map_with_no_usable_curve_is_one_line(tmp_path, capsys):
    from jaxcontact_cli import main

    rc = main(["fit", "tests/data/qi-2x2-2020.02.07.jpk-qi-data", "--radius", "10e-6",
               "--model", "relaxed", "--out", str(tmp_path / "qi")])
    err = capsys.readouterr().err
    assert rc == 2 and "no contact found" in err and "Traceback" not in err
    assert not (tmp_path / "qi").exists()


FOUR_DEVICES = textwrap.dedent(
    """
    import json, warnings, jax
    jax.config.update("jax_enable_x64", True)
    import fitting
    from tests.test_fitting_each import POINTS, GRID, R, STARTS, _curve
    curves = [_curve(p, seed=i, grid=g) for i, (p, g) in enumerate(zip(POINTS, GRID))]
    warnings.simplefilter("ignore")
    res = fitting.fit_each(curves, radius=R, n_starts=STARTS, chunk=2, progress=False)
    print(json.dumps(dict(n=len(jax.devices()), chi2=[r.chi2 for r in res.results],
                          values=[list(map(float, r.values)) for r in res.results])))
    """
)


@pytest.mark.slow
def test_four_devices_match_one(curves):
    # the chunks spread over 4 virtual CPU devices (solve_batch: one pool per device)
    # end where one device ends
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=4",
               JAX_PLATFORMS="cpu", PYTHONPATH=os.getcwd())
    out = subprocess.run([sys.executable, "-c", FOUR_DEVICES], env=env, capture_output=True,
                         text=True, timeout=600, cwd=os.path.dirname(os.path.dirname(__file__)))
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["n"] == 4
    one = _quiet(fitting.fit_each, curves, radius=R, n_starts=STARTS, chunk=2,
                 progress=False)
    for k, r in enumerate(one.results):
        assert got["chi2"][k] == pytest.approx(r.chi2, rel=1e-9)
        np.testing.assert_allclose(got["values"][k], r.values, rtol=1e-6)


def test_batched_finish_equals_the_per_curve_finish(curves):
    # the finish of a chunk is one compiled call over its curves (the model at the optimum,
    # the derived quantities and Tabor's parameter with their gradients) and one check of
    # the probe's validity: each curve's numbers equal those computed for it alone, with
    # statuses kept per curve; here a chunk of a curve whose eta1 the data do not determine
    # (a lift 1,000 times slower than the relaxation: the creep is over before it starts)
    # beside a determined one, and a failed curve beside them
    import jax.numpy as jnp

    from fitting._objective import predict
    from fitting._quality import tabor_entry
    from fitting._uncertainty import derived_quantities

    slow = _curve(POINTS[0], v=2e-9, seed=7, grid=(2, 2))
    failed = fitting.FailedCurve("map.jpk-force-map", 5, "no contact found on the approach")
    res = _quiet(fitting.fit_each, [slow, curves[0], failed], radius=R, n_starts=STARTS,
                 chunk=2, progress=False)
    assert res.results[2] is None and "no contact found" in res.errors[2]
    eta = res.names.index("eta1")
    assert res.results[0].status[eta] == "not determined"
    assert res.results[1].status[eta] == "ok"
    for r in res.results[:2]:
        derived = {d["name"]: d for d in r.derived}
        alone = derived_quantities(r.spec, r.values, r.covariance, r.status)
        alone.append(tabor_entry(r.spec, r.values, r.covariance, r.status, r.radius, r.names))
        assert sorted(derived) == sorted(d["name"] for d in alone)
        for d in alone:
            got = derived[d["name"]]
            assert got["status"] == d["status"], d["name"]
            np.testing.assert_allclose([got["value"], got["stderr"]],
                                       [d["value"], d["stderr"]], rtol=1e-12)
        model = np.asarray(predict(r.spec, jnp.asarray(r.values), r.data).force)
        np.testing.assert_allclose(r.model_force, np.where(np.isfinite(model), model, 0.0),
                                   rtol=1e-12, atol=1e-12 * np.max(np.abs(model)))
        # R^2 and the segments' quality (computed for the chunk at once), by hand per curve
        d = r.data
        valid = np.asarray(d.valid) > 0
        for mask, got in ((valid, r.r_squared), (r.in_contact, r.r_squared_contact)):
            f, w, fm = (np.asarray(x)[mask] for x in (d.force, d.weight, r.model_force))
            mean = np.sum(w * f) / np.sum(w)
            want = 1 - np.sum(w * (fm - f) ** 2) / np.sum(w * (f - mean) ** 2)
            assert got == pytest.approx(want, rel=1e-12)
        for q in r.segments:
            m = valid & (np.asarray(d.segment) == fitting._prepare.SEGMENTS.index(q.segment))
            e = ((np.asarray(r.fitted_force) - np.asarray(d.force)) / np.asarray(d.noise))[m]
            w = np.asarray(d.weight)[m]
            assert q.n_kept == m.sum() and q.max_residual == pytest.approx(np.max(np.abs(e)))
            assert q.reduced_chi2 == pytest.approx(np.sum(w * e**2) / np.sum(w), rel=1e-12)
    # eta1 not determined: the relaxation time it enters is not determined either
    assert {d["name"]: d for d in res.results[0].derived}["tau"]["status"] == "not determined"
    assert {d["name"]: d for d in res.results[1].derived}["tau"]["status"] == "ok"


def test_compiled_fit_programs_hold_no_host_callback(curves):
    """JAX's persistent compilation cache (``jaxcontact fit`` keeps one) does not store a
    program with a host callback, and a GPU stops at each one: the search's pool and the
    finish's call of a chunk have none. (The derived quantities and Tabor's parameter built
    rheologies whose guarded methods put a run-time check, a callback, into the finish: it
    was compiled again in every run of the README's main job.)"""
    from fitting import _optimise as O

    opts = fitting.FitOptions(radius=R, progress=False)
    pb = O._problem([curves[0]], opts, rheology="standard", contact_point="fixed",
                    previous=None)
    # with the model (the finish evaluates it where the search's solver does not carry it)
    args, kw = O._chunk_inputs([pb], [pb.param.internal_host(pb.zs[0])], 1, opts,
                               model=True)
    assert kw["tabor"] is not None  # Tabor's parameter is part of this finish
    finish = O._evaluate_chunk.lower(*args, **kw).as_text()
    n = len(pb.zs)
    pool = O._solve_batch.lower(
        pb.spec, O._stack([pb.param], n), O._stack([pb.data], n), pb.zs,
        np.full(n, 20, np.int32), np.full(n, np.inf), workers=2, rtol=1e-8, atol=1e-9, gtol=1e-8, max_steps=20,
        optimiser="lm", keep_jacobian=True).as_text()
    for text in (finish, pool):
        assert "stablehlo" in text and "callback" not in text


def test_the_reported_model_is_the_searchs_own_evaluation(each):
    """The forces and contact radius a fit reports come from the search's evaluation at its
    optimum (Levenberg-Marquardt carries them; the finish does not compile or evaluate the
    model again): the reported fitted force gives the reported chi2, and the full model
    solution, evaluated anew on first access, agrees with them to round-off."""
    from fitting import _optimise as O

    opts = fitting.FitOptions(radius=R, progress=False)
    assert O._carries_model(opts) and not O._carries_model(opts.replace(optimiser="lbfgs"))
    done = [r for r in each.results if r is not None]
    assert done
    for r in done:
        d = r.data
        res = np.sqrt(d.weight) * (r.fitted_force - d.force) / d.noise
        assert np.sum(res * res) == pytest.approx(r.chi2, rel=1e-12)
        sol = r.model_solution  # the forward model at the optimum, evaluated on access
        assert r.model_solution is sol  # once
        np.testing.assert_allclose(r.model_contact_radius, sol.contact_radius, rtol=1e-9,
                                   atol=1e-12 * R)
        force = np.where(np.isfinite(sol.force), sol.force, 0.0)
        np.testing.assert_allclose(r.model_force, force, rtol=1e-9,
                                   atol=1e-12 * np.max(np.abs(force)))


def test_finish_compiled_in_the_background_serves_the_call():
    """The finish's program is compiled in a thread during the search and the call after
    it runs that executable: traced once, in the caller's precision. (`fit` turns 64-bit
    types on for its own thread only; the thread traced in float32 wherever a Python
    scalar entered, so the call traced and compiled the whole finish again.)"""
    import jax
    import jax.numpy as jnp

    from fitting._optimise import _Background

    traces = []

    @jax.jit
    def f(x, radius):
        traces.append(radius.dtype)
        return x * radius

    x = np.ones(3)
    before = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", False)  # as in a process that did not switch it on
    try:
        with jax.enable_x64(True):
            bg = _Background(f, x, 2.5)
            bg.start()
            out = bg.call(x, 2.5)
            assert out.dtype == jnp.float64 and traces == [jnp.float64]
            np.testing.assert_array_equal(out, 2.5 * x)
            # other argument types than compiled for: the function itself
            assert bg.call(np.ones(4), 2.5).shape == (4,) and len(traces) == 2
    finally:
        jax.config.update("jax_enable_x64", before)


def test_chunks_searched_at_once_end_where_one_stream_ends(curves):
    # three chunks of one curve, searched one after the other and three at once (host
    # threads, `BatchOptions.streams`), in a process whose 64-bit types are off (fit_each
    # turns them on for its own thread; its search threads must carry that): the same
    # optima, start for start, to the last bit
    import jax

    before = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", False)
    try:
        one, three = (_quiet(fitting.fit_each, curves, radius=R, n_starts=STARTS,
                             local_rounds=1, chunk=1, streams=k, progress=False)
                      for k in (1, 3))
    finally:
        jax.config.update("jax_enable_x64", before)
    for a, b in zip(one.results, three.results, strict=True):
        assert a.chi2 == b.chi2
        np.testing.assert_array_equal(a.values, b.values)
        np.testing.assert_array_equal(a.start_losses, b.start_losses)
        np.testing.assert_array_equal(a.start_steps, b.start_steps)
    # and where each curve ends alone (the first curve; the others: above)
    alone = _quiet(fitting.fit, curves[0], radius=R, n_starts=STARTS, local_rounds=1,
                   progress=False)
    assert three.results[0].chi2 == pytest.approx(alone.chi2, rel=1e-9)


def test_a_chunks_padding_costs_no_step(curves, monkeypatch):
    # three curves in chunks of two: the second chunk is padded with a copy of its curve
    # (one compiled shape); every Levenberg-Marquardt step the pool runs belongs to a real
    # curve's start (before: the copy ran its own search and rounds)
    import jax

    from fitting import _optimise

    ran, real = [], _optimise.solve_batch

    def counting(*args, **kw):
        out = real(*args, **kw)
        ran.append(int(np.sum(jax.device_get(out.steps))))
        return out

    monkeypatch.setattr(_optimise, "solve_batch", counting)
    padded = _quiet(fitting.fit_each, curves, radius=R, n_starts=STARTS, local_rounds=1,
                    chunk=2, streams=1, progress=False)
    assert len(ran) >= 2
    assert sum(ran) == sum(int(np.sum(r.start_steps)) for r in padded.results)
    monkeypatch.undo()
    whole = _quiet(fitting.fit_each, curves, radius=R, n_starts=STARTS, local_rounds=1,
                   chunk=3, progress=False)
    for a, b in zip(padded.results, whole.results, strict=True):
        assert a.chi2 == pytest.approx(b.chi2, rel=1e-9)


def test_streams_take_in_order_raise_per_chunk_and_stop_when_closed():
    """`_Streams`: results in chunk order whatever order the threads end in; the first
    chunk's search runs alone until it says its program is compiled; an error is raised
    by the `take` of its chunk; at most 2 × streams chunks run ahead of the one taken;
    after `close` no chunk starts; the threads carry the caller's 64-bit setting."""
    import threading

    import jax
    import jax.numpy as jnp

    from fitting._optimise import _Streams

    started, lock = [], threading.Lock()
    gate = threading.Event()

    def search(k, searched):
        with lock:
            started.append(k)
        if k == 0:
            assert started == [0]  # alone until compiled
            searched()
        if k == 5:
            raise ArithmeticError("chunk 5 failed")
        if k == 1:
            gate.wait(10)  # chunk 1 ends after the others it may overtake
        return k, bool(jax.config.jax_enable_x64), jnp.asarray(1.0).dtype

    before = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", False)
    try:
        with jax.enable_x64(True):
            streams = _Streams(search, 12, 2)
            assert streams.take(0) == (0, True, jnp.float64)
            # chunk 1 holds one thread; the other runs ahead to at most 2 x 2 chunks
            # waiting (0 taken: chunks 1-4 may start; 5 may not before 1 is taken)
            deadline = time.monotonic() + 10
            while len(started) < 5 and time.monotonic() < deadline:
                time.sleep(0.01)
            time.sleep(0.1)
            assert sorted(started) == [0, 1, 2, 3, 4]
            gate.set()
            assert [streams.take(k)[0] for k in (1, 2, 3, 4)] == [1, 2, 3, 4]
            with pytest.raises(ArithmeticError, match="chunk 5 failed"):
                streams.take(5)
            assert streams.take(6) == (6, True, jnp.float64)
            streams.close()
            time.sleep(0.2)
            assert max(started) <= 6 + 2 * 2  # nothing started after close
            n = len(started)
            time.sleep(0.2)
            assert len(started) == n
        # one stream: each chunk searched in the calling thread when taken
        calls = []
        serial = _Streams(lambda k, searched: calls.append(k) or k, 3, 1)
        assert calls == [] and [serial.take(k) for k in range(3)] == [0, 1, 2]
    finally:
        jax.config.update("jax_enable_x64", before)


def _free_port() -> int:
    """A free TCP port on this machine (the coordinator of two JAX processes)."""
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


TWO_PROCESSES = textwrap.dedent(
    """
    import json, sys, warnings, jax
    jax.config.update("jax_enable_x64", True)
    jax.distributed.initialize(coordinator_address=sys.argv[1], num_processes=2,
                               process_id=int(sys.argv[2]))
    import fitting
    from tests.test_fitting_each import POINTS, GRID, R, STARTS, _curve
    curves = [_curve(p, seed=i, grid=g) for i, (p, g) in enumerate(zip(POINTS, GRID))]
    failed = fitting.FailedCurve("map", 3, "no contact found on the approach")
    warnings.simplefilter("ignore")
    res = fitting.fit_each(curves[:2] + [failed] + curves[2:], radius=R, n_starts=STARTS,
                           chunk=2, progress=False)
    print(json.dumps(dict(rank=jax.process_index(), errors=res.errors,
                          chi2=[r.chi2 if r else None for r in res.results],
                          values=[list(map(float, r.values)) if r else None
                                  for r in res.results])))
    """
)


@pytest.mark.slow
def test_two_processes_match_one(curves):
    # after jax.distributed.initialize two processes share the curves (each fits every
    # second one), and each returns every curve's result: the same as one process, the
    # failed curve in its place
    port = _free_port()
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = dict(os.environ, JAX_PLATFORMS="cpu", PYTHONPATH=root)
    procs = [subprocess.Popen([sys.executable, "-c", TWO_PROCESSES, f"127.0.0.1:{port}",
                               str(i)], env=env, cwd=root, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for i in range(2)]
    outs = [p.communicate(timeout=600) for p in procs]
    for p, (_, err) in zip(procs, outs, strict=True):
        assert p.returncode == 0, err[-3000:]
    got = [json.loads(o.strip().splitlines()[-1]) for o, _ in outs]
    assert [g["rank"] for g in got] == [0, 1]
    assert got[0]["chi2"] == got[1]["chi2"] and got[0]["values"] == got[1]["values"]
    assert got[0]["errors"][2] == "no contact found on the approach"
    assert got[0]["chi2"][2] is None
    one = _quiet(fitting.fit_each, curves, radius=R, n_starts=STARTS, chunk=2,
                 progress=False)
    for k, r in zip((0, 1, 3), one.results, strict=True):
        assert got[0]["chi2"][k] == pytest.approx(r.chi2, rel=1e-9)
        np.testing.assert_allclose(got[0]["values"][k], r.values, rtol=1e-6)


@pytest.mark.slow
def test_force_map_shared_by_two_processes_through_the_command_line(tmp_path):
    # `jaxcontact fit MAP --coordinator ...` in two processes: process 0 writes the output
    # folder (the others nothing), and its map equals the one-process map of the same file
    import xarray as xr

    port = _free_port()
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = dict(os.environ, JAX_PLATFORMS="cpu", PYTHONPATH=root, JAXCONTACT_NO_CACHE="1")
    args = [sys.executable, "-m", "jaxcontact_cli", "fit",
            os.path.join(root, "tests", "data", "force-map-2x2.jpk-force-map"),
            "--radius", "10e-6", "--starts", "4", "--no-figure", "--quiet"]
    procs = [subprocess.Popen(args + ["--out", str(tmp_path / "two"), "--coordinator",
                                      f"127.0.0.1:{port}", "--num-processes", "2",
                                      "--process-id", str(i)],
                              env=env, cwd=str(tmp_path), stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for i in range(2)]
    outs = [p.communicate(timeout=900) for p in procs]
    codes = [p.returncode for p in procs]
    assert codes[0] == codes[1] and codes[0] in (0, 3), outs[0][1][-3000:]
    one = subprocess.run(args + ["--out", str(tmp_path / "one")], env=env, cwd=str(tmp_path),
                         capture_output=True, text=True, timeout=900)
    assert one.returncode == codes[0], one.stderr[-3000:]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["one", "two"]
    a = xr.load_dataset(tmp_path / "two" / "map.nc", engine="h5netcdf")
    b = xr.load_dataset(tmp_path / "one" / "map.nc", engine="h5netcdf")
    # two processes search their 2 curves each in chunks of 1 (a CPU map of fewer chunks
    # than streams is split over the streams: `BatchOptions.chunk_for`), one process its 4
    # in chunks of 2, padded to other lengths: other compiled shapes, so other round-off.
    # A start stops where an accepted step lowers chi2 by less than rtol = 1e-8 of it (a
    # rule on its last step, not a bound on its distance to the optimum: measured 3.9e-8
    # apart on one curve), so the two end in the same optimum to a few rtol, and the
    # parameters there agree to a small fraction of their standard errors: a chi2 a
    # relative 4e-8 above the optimum (4e-8 x chi2_red x n_data in chi2) is a step of
    # sqrt(2 x 4e-8 x n_data) ~ 0.007 standard errors along the weakest direction
    # (measured: 0.003 for G0 on that curve)
    np.testing.assert_allclose(a["reduced_chi2"].values, b["reduced_chi2"].values, rtol=1e-6)
    for name in ("G0_Pa", "G1_Pa", "work_of_adhesion_J_m2"):
        err = b[f"{name}_stderr"].values
        assert np.all(np.isfinite(err)), name
        assert np.all(np.abs(a[name].values - b[name].values) <= 2e-2 * err), name
    assert a["grid_x"].values.tolist() == b["grid_x"].values.tolist()


def test_distinct_best_end_points():
    """The end points continued after a coarser search (`fitting._optimise.distinct_best`):
    the best first, one per optimum (chi2 equal within the relative tolerance), finite only,
    at most k."""
    from fitting._optimise import distinct_best

    chi2 = np.array([5.0, 1.0, 1.0 + 1e-9, np.nan, 3.0, 1.0 + 1e-3, np.inf, 3.0 * (1 + 1e-8)])
    assert distinct_best(chi2, 3).tolist() == [1, 5, 4]
    assert distinct_best(chi2, 10).tolist() == [1, 5, 4, 0]
    assert distinct_best(chi2, 1).tolist() == [1]
    assert distinct_best(chi2, 3, rtol=1e-12).tolist() == [1, 2, 5]
    assert distinct_best(np.array([np.nan, np.inf]), 3).tolist() == []


def test_far_starts_of_the_local_rounds_are_abandoned_without_losing_an_optimum(curves):
    """The default search abandons a local round's start whose chi2 is still above
    `abandon` x the best known after 5 steps (`fitting.FitOptions.abandon`). Against the
    same search without it (`abandon=None`, a second run of the curves): every curve ends
    at the same optimum (chi2 to 1e-9, parameters to 1e-6), in fewer steps; a lower factor
    abandons more. The starts' losses stay reported, each abandoned one above its bound."""
    kw = dict(radius=R, progress=False, chunk=3)
    full = _quiet(fitting.fit_each, curves, abandon=None, **kw)
    cut = _quiet(fitting.fit_each, curves, **kw)
    low = _quiet(fitting.fit_each, curves, abandon=3.0, **kw)
    steps = [sum(int(np.sum(r.start_steps)) for r in e.results) for e in (full, cut, low)]
    assert steps[0] > steps[1] >= steps[2]
    for a, b in zip(full.results, cut.results, strict=True):
        assert b.chi2 == pytest.approx(a.chi2, rel=1e-9)
        np.testing.assert_allclose(b.values, a.values, rtol=1e-6)
        assert len(b.start_losses) == len(a.start_losses)
        assert b.search["abandon"] == fitting.DEFAULT_ABANDON
        assert a.search["abandon"] is None
