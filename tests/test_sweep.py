"""Tests of `jaxcontact.sweep` against closed forms, `retract`, `simulate`, and itself on 4
devices and in float32. Compiled sweeps are shared through module fixtures.

The references are float64 (closed forms, `retract` and `simulate` with float64 inputs), so
every sweep compared with them asks for `precision="float64"`: the sweep's default is float32
on accelerators, and the same tolerances fail on a GPU (9e-7 against rtol 1e-12)."""

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import xarray as xr

import jaxcontact as jc
from jaxcontact._sweep import SUMMARIES

# the standard-model grid used by several tests (one compiled program)
STD = dict(G0=1e6, G1=np.array([2e5, 1e6]), eta1=1e4, work_of_adhesion=0.05, R=1e-4,
           depth=np.array([1e-6, 4e-6]), velocity=np.array([1e-6, 1e-4, 1e-2]))
RELAXED = jc.RelaxedStart(samples=400, duration_factor=1.5)


# 12 points; every standard-model sweep below runs in chunks of 16: one compiled program
CHUNK = 16


@pytest.fixture(scope="module")
def relaxed():
    return jc.sweep(STD, model=RELAXED, chunk_size=CHUNK, progress=False, precision="float64")


# ---------------------------------------------------------------------------------------
# separation work and events against the elastic JKR closed form
# ---------------------------------------------------------------------------------------


def jkr_separation_work(G, dgamma, R, d0):
    r"""$\int \max(-F, 0)\,dd$ from $d_0$ to the jump-off for an elastic half-space (E* = 4G),
    paraboloid, lifted from the touch radius $a_0 = \sqrt{R d_0}$: a pinned phase
    $F = 8Ga_0(d - a_0^2/(3R))$ down to $h(a_0)$, then the JKR front
    $F(a) = 8G(2a^3/(3R) - c a^{3/2})$, $d(a) = a^2/R - c\sqrt a$ down to the fold."""
    c = np.sqrt(np.pi * dgamma * G / 2) / G
    a0 = np.sqrt(R * d0)
    a_fold = (c * R / 4) ** (2 / 3)
    h0 = a0**2 / R - c * np.sqrt(a0)
    d_zero = a0**2 / (3 * R)  # the pinned force vanishes here
    work = 8 * G * a0 * (d_zero - h0) ** 2 / 2 if h0 < d_zero else 0.0
    a_zero = (1.5 * R * c) ** (2 / 3)  # the front force vanishes here

    def antiderivative(a):  # of 8G (c a^1.5 - 2a^3/(3R)) (2a/R - c/(2 sqrt a))
        return 8 * G * (2 * c / (3 * R) * a**3.5 - c**2 / 4 * a**2 - 4 / (15 * R**2) * a**5)

    top = min(a0, a_zero)
    if top > a_fold:
        work += antiderivative(top) - antiderivative(a_fold)
    return work


def test_elastic_jkr_closed_forms():
    G, dg, R = 1e5, 0.05, 1e-4
    depths = np.array([3e-7, 1e-6, 4e-6, 3e-5])  # pinned jump-off ... long receding front
    ds = jc.sweep({"G_inf": G, "work_of_adhesion": dg, "R": R, "depth": depths,
                   "velocity": 1e-4}, model=jc.RelaxedStart(samples=2000), progress=False,
                  precision="float64")
    assert (ds.status == int(jc.RESULTS.detached._value)).all()
    W = np.array([jkr_separation_work(G, dg, R, d) for d in depths])
    # the relaxed start's separation work is exact (closed form + Gauss in sqrt(T_b - t)):
    # measured 2e-15; the former trapezoidal rule over 2000 samples was 4e-6 .. 5e-5 off
    np.testing.assert_allclose(ds.separation_work_J.values, W, rtol=1e-12)
    # jump-off at the fold of d(a) (JKR, displacement control), or from the pinned state
    c = np.sqrt(np.pi * dg * G / 2) / G
    a0, a_fold = np.sqrt(R * depths), (c * R / 4) ** (2 / 3)
    a_j = np.minimum(a0, a_fold)
    d_j = a_j**2 / R - c * np.sqrt(a_j)
    F_j = 8 * G * (a_j * d_j - a_j**3 / (3 * R))
    np.testing.assert_allclose(ds.jumpoff_displacement_m.values, d_j, rtol=1e-12, atol=1e-20)
    np.testing.assert_allclose(ds.jumpoff_force_N.values, F_j, rtol=1e-12)
    np.testing.assert_allclose(ds.jumpoff_force_N.values[a0 > a_fold], -5 / 6 * np.pi * dg * R,
                               rtol=1e-12)
    # the largest tensile force: force control's JKR minimum where the front passes it
    a_fc = (9 * c * R / 4 / 4 * 4 / 3) ** (2 / 3)  # a g' = (3/2) c sqrt(a): a = (3cR/4)^(2/3)
    assert np.isclose(a_fc, (3 * c * R / 4) ** (2 / 3))
    passes = a0 > a_fc
    np.testing.assert_allclose(ds.max_tensile_force_N.values[passes], -1.5 * np.pi * dg * R,
                               rtol=1e-12)
    # the lift is a constant-speed lift from the depth: d_j = d0 - v t_j
    np.testing.assert_allclose(ds.jumpoff_time_s.values, (depths - d_j) / 1e-4, rtol=1e-10)


def test_host_threads_path_matches_the_jkr_closed_form(monkeypatch):
    # sweeps of >= 2^17 points prepare the chunks' columns ahead and scale the summaries in
    # host threads; smaller ones (every other test here) in the calling thread. The threaded
    # path forced on a small elastic sweep in two chunks, against the JKR closed forms
    from jaxcontact._sweep import _run

    monkeypatch.setattr(_run, "_THREADS_MIN_POINTS", 1)
    monkeypatch.setattr(_run, "_HOST_THREADS", 2)
    assert _run.host_threads(4) == 2
    G, dg, R = 1e5, 0.05, 1e-4
    depths = np.array([3e-7, 1e-6, 4e-6, 3e-5])
    ds = jc.sweep({"G_inf": G, "work_of_adhesion": dg, "R": R, "depth": depths,
                   "velocity": 1e-4}, model=jc.RelaxedStart(samples=2000), chunk_size=2,
                  progress=False, precision="float64")
    assert ds.attrs["chunk_size"] == 2
    assert (ds.status == int(jc.RESULTS.detached._value)).all()
    W = np.array([jkr_separation_work(G, dg, R, d) for d in depths])
    np.testing.assert_allclose(ds.separation_work_J.values, W, rtol=1e-12)
    c = np.sqrt(np.pi * dg * G / 2) / G
    a_j = np.minimum(np.sqrt(R * depths), (c * R / 4) ** (2 / 3))
    d_j = a_j**2 / R - c * np.sqrt(a_j)
    np.testing.assert_allclose(ds.jumpoff_force_N.values, 8 * G * (a_j * d_j - a_j**3 / (3 * R)),
                               rtol=1e-12)
    np.testing.assert_allclose(ds.jumpoff_time_s.values, (depths - d_j) / 1e-4, rtol=1e-10)


def test_elastic_flat_punch_kendall():
    # an elastic flat punch (E* = 4G) stays pinned to the jump-off at d_j = -c sqrt(a):
    # Kendall's pull-off force -sqrt(8 pi a^3 E* dgamma) and the work
    # int_{d_j}^0 8 G a (-d) dd = 4 G a d_j^2 = 2 pi a^2 dgamma (independent of G)
    G, dg, a = 1e5, 0.05, np.array([1e-6, 3e-5])
    ds = jc.sweep({"G_inf": G, "work_of_adhesion": dg, "punch_radius": a, "depth": 1e-7,
                   "velocity": 1e-4}, model=jc.RelaxedStart(samples=20), progress=False,
                  precision="float64")
    assert (ds.status == int(jc.RESULTS.detached._value)).all()
    np.testing.assert_allclose(ds.jumpoff_force_N.values, -np.sqrt(32 * np.pi * a**3 * G * dg),
                               rtol=1e-12)
    np.testing.assert_allclose(ds.max_tensile_force_N.values, ds.jumpoff_force_N.values,
                               rtol=1e-12)
    np.testing.assert_allclose(ds.separation_work_J.values, 2 * np.pi * a**2 * dg, rtol=1e-10)
    np.testing.assert_allclose(ds.jumpoff_contact_radius_m.values, a, rtol=1e-12)


def trapezoid_separation_work(sol):
    """$\\int\\max(-F, 0)\\,(-dd)$ of a `retract` curve by the trapezoidal rule over its
    samples in contact, closed by the jump-off (force, indentation) as the last point."""
    F, d = np.asarray(sol.force), np.asarray(sol.displacement)
    inside = F != 0
    tension = np.append(np.maximum(-F[inside], 0.0), -float(sol.jumpoff_force))
    d = np.append(d[inside], float(sol.jumpoff_displacement))
    return float(np.sum(0.5 * (tension[:-1] + tension[1:]) * -np.diff(d)))


def dense_separation_work(rheology, profile, dgamma, jumpoff_time):
    """The separation work of `retract` (v = d0 = 1) by `trapezoid_separation_work` on
    2 x 200,001 samples graded toward the jump-off (t = T (1 - (1 - x)^2)) over the whole
    lift and over its last per cent."""
    x = np.linspace(0.0, 1.0, 200_001)
    grade = 1.0 - (1.0 - x) ** 2
    T = jumpoff_time * (1 + 1e-12)
    ts = np.sort(np.concatenate([T * grade, T * (0.99 + 0.01 * grade)]))
    return trapezoid_separation_work(jc.retract(rheology, profile, work_of_adhesion=dgamma,
                                                depth=1.0, velocity=1.0, ts=ts, throw=False))


@pytest.mark.parametrize("seed", [0, 1])
def test_relaxed_separation_work_against_a_dense_sampling(seed):
    # random materials (G_inf/G_1 from 1e-3 to 10, tau from 1e-5 to 10 lift times; then
    # three-arm Prony series), weak to strong adhesion, paraboloid, cone and flat punch, in
    # the sweep's units (depth = speed = 1): the exact separation work against retract's
    # dense graded curve
    from jaxcontact._sweep._models import RelaxedStart

    rng = np.random.default_rng(seed)
    model = RelaxedStart(samples=10)
    with jc.plausibility_checks(False):
        for k in range(6):
            g0 = 10 ** rng.uniform(-0.5, 0.5)
            g1 = g0 * 10 ** rng.uniform(-3.0, 1.0)
            rheology = jc.StandardModel(G0=g0, G1=g1, eta1=(g0 + g1) * 10 ** rng.uniform(-4, 1))
            if k >= 3:  # three Maxwell arms, relaxation times spread over 4 decades
                rheology = jc.PronySeries(G_inf=1.0, G=10 ** rng.uniform(-1, 1.5, 3),
                                          tau=10 ** rng.uniform(-4, 0, 3))
            profile = [jc.Parabola(R=10 ** rng.uniform(1, 4)),
                       jc.Cone(half_angle=rng.uniform(1.0, 1.5)),
                       jc.FlatPunch(radius=10 ** rng.uniform(-1, 1))][k % 3]
            dgamma = 10 ** rng.uniform(-8, -5)
            point = model.solve(rheology, profile, {"work_of_adhesion": dgamma})
            assert int(point.status) == int(jc.RESULTS.detached._value)
            ref = dense_separation_work(rheology, profile, dgamma, float(point.jumpoff_time))
            assert float(point.separation_work) == pytest.approx(ref, rel=1e-8), (k, ref)


def test_relaxed_summaries_do_not_depend_on_the_samples(relaxed):
    # the summaries are computed without sampling the curve; `curves=True` adds the curves
    # and leaves the summaries as they are
    ds = jc.sweep(STD, model=jc.RelaxedStart(samples=50), chunk_size=CHUNK, progress=False,
                  precision="float64",
                  curves=True)
    for name in SUMMARIES:  # another compiled program: the same to round-off
        np.testing.assert_allclose(ds[name].values, relaxed[name].values, rtol=1e-14)
    assert ds.force_N.shape[-1] == 50


# ---------------------------------------------------------------------------------------
# labels, the relaxed model against retract, the duration
# ---------------------------------------------------------------------------------------


def test_dataset_labels(relaxed):
    ds = relaxed
    assert ds.max_tensile_force_N.dims == ("G1", "depth", "velocity")
    np.testing.assert_array_equal(ds.velocity.values, STD["velocity"])
    assert ds.velocity.attrs["units"] == "m/s" and ds.G1.attrs["units"] == "Pa"
    assert ds.eta1.attrs["units"] == "Pa s" and float(ds.eta1) == 1e4 and ds.eta1.dims == ()
    units = {"max_tensile_force_N": "N", "jumpoff_time_s": "s", "separation_work_J": "J",
             "jumpoff_displacement_m": "m"}
    for name, unit in units.items():
        assert ds[name].attrs["units"] == unit
    assert set(SUMMARIES) <= set(ds.data_vars)
    assert ds.status.dtype == np.int8
    meanings = ds.status.attrs["flag_meanings"].split()
    assert meanings[int(ds.status.attrs["flag_values"][0])] == "detached"
    assert ds.attrs["model"] == "relaxed" and ds.attrs["precision"] == "float64"


def test_relaxed_matches_retract_and_lift_reaches_jumpoff(relaxed):
    ds = relaxed
    assert (ds.status == int(jc.RESULTS.detached._value)).all()
    # the bound is exact for the relaxed start: the lift lasts duration_factor x jump-off time
    np.testing.assert_allclose(ds.jumpoff_time_s * 1.5, ds.lift_duration_s, rtol=1e-10)
    for i, j, k in [(0, 0, 0), (1, 1, 2), (0, 1, 1)]:
        p = ds.isel(G1=i, depth=j, velocity=k)
        # retract on 40,001 samples up to just before the jump-off (the events are refined
        # between samples, so they do not depend on the sampling)
        sol = jc.retract(jc.StandardModel(G0=1e6, G1=float(p.G1), eta1=1e4),
                         jc.Parabola(R=1e-4), work_of_adhesion=0.05, depth=float(p.depth),
                         velocity=float(p.velocity),
                         ts=np.linspace(0.0, float(p.lift_duration_s), 40001))
        for name, ref in [("max_tensile_force_N", sol.max_tensile_force),
                          ("jumpoff_force_N", sol.jumpoff_force),
                          ("jumpoff_time_s", sol.jumpoff_time),
                          ("jumpoff_displacement_m", sol.jumpoff_displacement)]:
            np.testing.assert_allclose(float(p[name]), float(ref), rtol=1e-9)
        # separation work against the dense trapezoid of retract's curve to its jump-off
        np.testing.assert_allclose(float(p.separation_work_J), trapezoid_separation_work(sol),
                                   rtol=1e-4)


def test_points_and_list_of_sets_match_grid(relaxed):
    g1, dep, vel = np.meshgrid(STD["G1"], STD["depth"], STD["velocity"], indexing="ij")
    cols = dict(STD, G1=g1.ravel(), depth=dep.ravel(), velocity=vel.ravel())
    ds = jc.sweep(points=cols, model=RELAXED, chunk_size=CHUNK, progress=False,
                  precision="float64")
    assert ds.max_tensile_force_N.dims == ("point",) and ds.G1.dims == ("point",)
    flat = relaxed.stack(point=("G1", "depth", "velocity"))
    for name in SUMMARIES:
        np.testing.assert_allclose(ds[name].values, flat[name].values, rtol=1e-12)
    sets = [dict(G0=1e6, G1=2e5, eta1=1e4, work_of_adhesion=0.05, R=1e-4, depth=1e-6,
                 velocity=v) for v in (1e-6, 1e-2)]
    ds2 = jc.sweep(points=sets, model=RELAXED, chunk_size=CHUNK, progress=False,
                   precision="float64")
    np.testing.assert_allclose(ds2.jumpoff_time_s.values,
                               relaxed.jumpoff_time_s.isel(G1=0, depth=0).values[[0, 2]],
                               rtol=1e-12)


@pytest.mark.parametrize(("model", "curves"), [(jc.RelaxedStart(samples=500), False),
                                             (jc.RelaxedStart(samples=500), True),
                                             # extended (the default run's time): the
                                             # history model's compilation, ~17 s
                                             pytest.param(jc.ApproachHoldLift(samples=200,
                                                                              cells=16), False,
                                                          marks=pytest.mark.slow)])
def test_default_cpu_chunk_fits_the_models_budget(model, curves):
    # the default chunk on a CPU device follows the model's `cpu_chunk_budget` through an
    # upper estimate of the bytes per curve: XLA's own account of the compiled chunk
    # (arguments + outputs + temporaries) must stay within the budget, and not be far below
    import jax

    from jaxcontact._sweep._parameters import _ProfileFamily, _StandardFamily
    from jaxcontact._sweep._run import _compiled, chunk_size_for

    devices = tuple(jax.devices("cpu")[:1])  # a CPU device also where the default is a GPU
    chunk = chunk_size_for(model, 1, 8, curves, 10**7, 1, devices=devices)
    names = tuple(sorted(["G0", "G1", "eta1", "work_of_adhesion", "velocity", "R", "depth",
                          *(["hold", "approach_velocity"] if model.name == "history" else [])]))
    fn, sharding = _compiled(model, _StandardFamily(), _ProfileFamily("R"), names, curves,
                             devices, "float64")
    cols = jax.ShapeDtypeStruct((chunk, len(names)), np.float64, sharding=sharding)
    mem = fn.lower(cols).compile().memory_analysis()
    used = mem.argument_size_in_bytes + mem.output_size_in_bytes + mem.temp_size_in_bytes
    assert used <= model.cpu_chunk_budget(curves)
    assert used >= 0.2 * model.cpu_chunk_budget(curves)


def _forty_points(relaxed):
    """40 points of the module's grid (its 12 repeated) in chunks of 16: three chunks, the
    last one padded; `(flat grid, indices, sweep)`."""
    flat = relaxed.stack(point=("G1", "depth", "velocity"))
    reps = np.resize(np.arange(12), 40)
    cols = dict(STD, G1=flat.G1.values[reps], depth=flat.depth.values[reps],
                velocity=flat.velocity.values[reps])
    return flat, reps, jc.sweep(points=cols, model=RELAXED, chunk_size=CHUNK,
                                progress=False, precision="float64")


def test_chunks_give_the_same_result(relaxed):
    flat, reps, ds = _forty_points(relaxed)
    assert ds.attrs["chunk_size"] == CHUNK
    for name in SUMMARIES:
        np.testing.assert_array_equal(ds[name].values, flat[name].values[reps])


def test_dataset_is_built_once_while_the_first_chunk_runs(relaxed, monkeypatch):
    # the dataset (coordinates, attributes, empty summaries) is built once, right after the
    # first chunk is dispatched, and the results are written into it in place: three chunks
    # give the same values as the module's sweep (checked against retract and closed forms)
    from jaxcontact._sweep import _sweep

    calls = []
    run = _sweep.run_points

    def spy(*args, while_running, **kw):
        def hook():
            calls.append(len(calls))
            while_running()

        return run(*args, while_running=hook, **kw)

    monkeypatch.setattr(_sweep, "run_points", spy)
    flat, reps, ds = _forty_points(relaxed)
    assert calls == [0]
    assert ds.attrs["chunk_size"] == CHUNK and ds.attrs["devices"] == relaxed.attrs["devices"]
    for name in [*SUMMARIES, "status", "separation_work_error_J", "separation_work_status"]:
        np.testing.assert_array_equal(ds[name].values, flat[name].values[reps])


def test_bad_point_is_isolated(relaxed):
    # eta1 = 1e-320 Pa s underflows to a zero relaxation time in the point's units: that point
    # is invalid; its neighbours in the same chunk are unaffected
    # (1e-320 Pa s is no plausible viscosity: the eager check names it unless switched off)
    pts = dict(STD, G1=2e5, depth=1e-6, velocity=1e-6, eta1=[1e4, 1e-320, 1e4])
    with pytest.raises(ValueError, match=r"`eta1` lies outside the plausible range"):
        jc.sweep(points=pts, model=RELAXED, chunk_size=CHUNK, progress=False, precision="float64")
    with jc.plausibility_checks(False):
        ds = jc.sweep(points=pts, model=RELAXED, chunk_size=CHUNK, progress=False,
                      precision="float64")
    assert list(ds.status.values) == [int(jc.RESULTS.detached._value),
                                      int(jc.RESULTS.invalid_input._value),
                                      int(jc.RESULTS.detached._value)]
    for name in SUMMARIES:
        assert np.isnan(ds[name].values[1])
        np.testing.assert_allclose(ds[name].values[[0, 2]],
                                   relaxed[name].isel(G1=0, depth=0, velocity=0).values,
                                   rtol=1e-12)


def test_on_error_status_flags_bad_points_and_keeps_going(relaxed):
    # a map with unphysical points: the default refuses it naming the parameter; with
    # on_error="status" each bad point is flagged (status, parameter, reason) and the others
    # equal the same points swept alone
    G0 = [1e6, -1.0, 1e6, 1e6, np.nan]
    eta1 = [1e4, 1e4, 1e-320, 1e4, 1e4]  # 1e-320 Pa s: positive, but no plausible viscosity
    pts = dict(STD, G1=2e5, depth=1e-6, velocity=1e-6, G0=G0, eta1=eta1)
    with pytest.raises(ValueError, match=r"`G0` must lie in \(0, inf\) \[Pa\]"):
        jc.sweep(points=pts, model=RELAXED, chunk_size=CHUNK, progress=False)
    ds = jc.sweep(points=pts, model=RELAXED, chunk_size=CHUNK, progress=False,
                  precision="float64", on_error="status")
    ok, bad = [0, 3], [1, 2, 4]
    detached, invalid = int(jc.RESULTS.detached._value), int(jc.RESULTS.invalid_input._value)
    assert list(ds.status.values) == [detached, invalid, invalid, detached, invalid]
    meanings = ds.invalid_parameter.attrs["flag_meanings"].split()
    assert [meanings[c] for c in ds.invalid_parameter.values] == ["none", "G0", "eta1",
                                                                  "none", "G0"]
    reasons = ds.invalid_reason.attrs["flag_meanings"].split()
    assert [reasons[c] for c in ds.invalid_reason.values] == [
        "valid", "below_its_allowed_range", "outside_its_plausible_range", "valid",
        "not_finite"]
    alone = relaxed.isel(G1=0, depth=0, velocity=0)
    for name in SUMMARIES:
        assert np.isnan(ds[name].values[bad]).all()
        np.testing.assert_allclose(ds[name].values[ok], alone[name].values, rtol=1e-12)
    # on a grid a bad coordinate flags its slice; a bad fixed value spoils every point
    grid = dict(STD, velocity=np.array([1e-6, -1e-4, 1e-2]))
    dg = jc.sweep(grid, model=RELAXED, chunk_size=CHUNK, progress=False, on_error="status",
                  precision="float64")
    assert (dg.status.isel(velocity=1) == invalid).all()
    assert np.isnan(dg.jumpoff_force_N.isel(velocity=1)).all()
    for name in SUMMARIES:
        np.testing.assert_allclose(dg[name].isel(velocity=[0, 2]).values,
                                   relaxed[name].isel(velocity=[0, 2]).values, rtol=1e-12)
    with pytest.raises(ValueError, match="`G0` must lie in"):
        jc.sweep(dict(STD, G0=-1.0), model=RELAXED, progress=False, on_error="status")
    with pytest.raises(ValueError, match="on_error"):
        jc.sweep(STD, model=RELAXED, progress=False, on_error="ignore")


def test_netcdf_round_trip(relaxed, tmp_path):
    path = tmp_path / "s.nc"
    relaxed.to_netcdf(path, engine="h5netcdf")
    back = xr.load_dataset(path, engine="h5netcdf")
    xr.testing.assert_identical(back, relaxed)


# ---------------------------------------------------------------------------------------
# the full history
# ---------------------------------------------------------------------------------------

HISTORY = jc.ApproachHoldLift(samples=480, duration_factor=1.05, cells=64)


@pytest.fixture(scope="module")
def history():
    grid = dict(STD, depth=4e-6, hold=np.array([0.0, 0.02, 0.5]))
    return jc.sweep(grid, model=HISTORY, chunk_size=CHUNK, progress=False,
                    precision="float64", curves=True)


def test_history_detaches_within_the_bound(history):
    assert (history.status == int(jc.RESULTS.detached._value)).all()
    # the bound of the jump-off time is an upper bound: t_j <= T_b = lift / factor
    assert (history.jumpoff_time_s <= history.lift_duration_s / 1.05 * (1 + 1e-12)).all()
    assert history.approach_velocity.dims == ("velocity",)
    # the curves: time 0 is the start of the lift, the indentation is the protocol
    t, d = history.time_s.isel(G1=0, velocity=1, hold=1), history.displacement_m.isel(
        G1=0, velocity=1, hold=1)
    lift = t.values >= 0
    np.testing.assert_allclose(d.values[lift], 4e-6 - 1e-4 * t.values[lift], rtol=1e-12,
                               atol=1e-20)
    np.testing.assert_allclose(d.values[~lift].max(), 4e-6, rtol=1e-12)


def test_history_after_long_hold_is_relaxed(history, relaxed):
    # hold 0.5 s = 60 relaxation times (tau <= 8.3 ms): the relaxed start
    long = history.isel(hold=2)
    ref = relaxed.sel(depth=4e-6)
    for name in ("max_tensile_force_N", "jumpoff_force_N", "jumpoff_time_s",
                 "jumpoff_displacement_m"):
        np.testing.assert_allclose(long[name].values, ref[name].values, rtol=1e-9)
    # the separation work to the quadrature error of each (different samplings)
    np.testing.assert_allclose(long.separation_work_J.values, ref.separation_work_J.values,
                               rtol=2e-4)
    # a short hold leaves the material stiffer: the contact needs a longer lift
    assert (history.jumpoff_time_s.isel(hold=0) >= long.jumpoff_time_s * (1 - 1e-12)).all()


# ---------------------------------------------------------------------------------------
# float32 and devices
# ---------------------------------------------------------------------------------------


def test_history_separation_work_within_tolerance_or_undersampled():
    # the history's separation work after a long hold against the relaxed start's exact one:
    # at 100 samples each point's work is within the model's work_rtol of it, or withheld as
    # `undersampled` (depth = R: the tension spans a few lift samples); never a wrong number
    # with status OK
    g = dict(G0=1e6, G1=2e5, eta1=1e4, work_of_adhesion=0.05, R=1e-4,
             depth=np.array([3e-6, 1e-4]), velocity=1e-6)
    exact = jc.sweep(g, model=jc.RelaxedStart(), progress=False)
    assert (exact.separation_work_status == 0).all()
    assert (exact.separation_work_error_J == 0).all()
    model = jc.ApproachHoldLift(samples=100, cells=16)
    ds = jc.sweep(dict(g, hold=50.0), model=model, progress=False)
    assert (ds.status == int(jc.RESULTS.detached._value)).all()
    assert list(ds.separation_work_status.values) == [0, 1]  # converged, undersampled
    w, ref = ds.separation_work_J.values, exact.separation_work_J.values
    assert abs(w[0] / ref[0] - 1) <= model.work_rtol
    assert np.isnan(w[1])
    # the estimate is not far below the true error where it is given
    assert abs(w[0] - ref[0]) <= 3 * ds.separation_work_error_J.values[0]


def test_float32_against_float64():
    # physical scales from an AFM cell measurement (nN, 100 nm) to a mm gel contact
    grid = dict(G0=np.array([1e3, 1e9]), G1=1e5, eta1=1e4, work_of_adhesion=np.array([1e-4, 0.1]),
                R=np.array([1e-6, 1e-2]), depth=1e-7, velocity=np.array([1e-7, 1e-3]))
    d64 = jc.sweep(grid, model=RELAXED, precision="float64", chunk_size=CHUNK, progress=False)
    d32 = jc.sweep(grid, model=RELAXED, precision="float32", chunk_size=CHUNK, progress=False)
    assert (d32.status == d64.status).all() and (d64.status == 0).all()
    for name in ("max_tensile_force_N", "jumpoff_force_N", "jumpoff_time_s",
                 "separation_work_J", "jumpoff_contact_radius_m", "lift_duration_s"):
        rel = np.abs(d32[name].values / d64[name].values - 1)
        assert rel.max() < 5e-6, (name, rel.max())  # separation work: 1.2e-6 measured
    # the jump-off indentation may cross 0: relative to max(|d_j|, depth)
    d_j = d64.jumpoff_displacement_m
    err = np.abs(d32.jumpoff_displacement_m - d_j) / np.maximum(np.abs(d_j), 1e-7)
    assert float(err.max()) < 5e-6


FOUR_DEVICES = textwrap.dedent(
    """
    import json, numpy as np, jax
    import jaxcontact as jc
    from tests.test_sweep import STD, RELAXED
    ds = jc.sweep(STD, model=RELAXED, chunk_size=16, progress=False, precision="float64")
    print(json.dumps(dict(devices=ds.attrs["devices"], chunk=ds.attrs["chunk_size"],
        n=len(jax.devices()),
        values={k: ds[k].values.ravel().tolist() for k in ds.data_vars})))
    """
)


def test_four_devices_match_one(relaxed):
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=4",
               JAX_PLATFORMS="cpu", PYTHONPATH=os.getcwd())
    out = subprocess.run([sys.executable, "-c", FOUR_DEVICES], env=env, capture_output=True,
                         text=True, timeout=1800, cwd=os.path.dirname(os.path.dirname(__file__)))
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["n"] == 4 and got["devices"] == 4 and got["chunk"] % 4 == 0
    assert relaxed.attrs["devices"] == 1
    for name, values in got["values"].items():
        np.testing.assert_allclose(values, relaxed[name].values.ravel(), rtol=1e-13)


# ---------------------------------------------------------------------------------------
# errors
# ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "change, match",
    [
        (dict(G0=-1.0), "`G0` must lie in"),
        (dict(velocity=[1e-3, np.nan]), r"`velocity` .*entry 1"),
        (dict(hold=1.0), "not used by this model"),
        (dict(tau_1=1.0), "mix two material families"),
        (dict(half_angle=1.0), "exactly one indenter"),
        (dict(speed=1.0), "unknown sweep parameter 'speed'"),
        (dict(depth=np.ones((2, 2))), "scalar or a 1-D array"),
        (dict(depth=[]), "empty"),
    ],
)
def test_bad_parameters_name_the_parameter(change, match):
    with pytest.raises(ValueError, match=match):
        jc.sweep(dict(STD, **change), model=RELAXED, progress=False)


def test_bad_options():
    with pytest.raises(ValueError, match="missing sweep parameter"):
        jc.sweep({k: v for k, v in STD.items() if k != "velocity"}, progress=False)
    with pytest.raises(ValueError, match="standard model needs"):
        jc.sweep({k: v for k, v in STD.items() if k != "eta1"}, progress=False)
    with pytest.raises(ValueError, match="hold"):
        jc.sweep(STD, model=HISTORY, progress=False)
    with pytest.raises(ValueError, match="exactly one of"):
        jc.sweep(STD, points=STD, progress=False)
    with pytest.raises(ValueError, match="equal lengths"):
        jc.sweep(points=dict(STD, G1=[1e5, 2e5, 3e5]), progress=False)
    with pytest.raises(ValueError, match="duration_factor"):
        jc.RelaxedStart(duration_factor=1.0)
    with pytest.raises(ValueError, match="samples"):
        jc.ApproachHoldLift(samples=4)
    with pytest.raises(ValueError, match="precision"):
        jc.sweep(STD, precision="float16", progress=False)
    with pytest.raises(TypeError, match="model"):
        jc.sweep(STD, model="relaxed", progress=False)

    # a protocol without `solve` is refused when it is built, not when a sweep runs it
    class Incomplete(jc.AbstractSweepModel):
        def floats_per_curve(self, arms, curves):
            return 8

    with pytest.raises(TypeError, match="abstract"):
        Incomplete()
