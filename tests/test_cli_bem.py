"""``jaxcontact simulate --method bem``: the same options, CSV and events as the MDR
``simulate``, checked against the library call.

The runs use 32 cells and 80 samples with the standard model: the compiled programs of
`tests/test_bem.py`'s viscoelastic runs (the extent and all values are traced).
"""

import csv
import json

import numpy as np
import pytest

import jaxcontact as jc
from jaxcontact_cli import main
from jaxcontact_cli._simulate_bem import EXTENT_FACTOR, hertz_semi_major

SOLID = dict(G0=1e6, G1=5e5, eta1=1.5e6)  # tau = eta1 / (G0 + G1) = 1 s
R, DEPTH, DGAMMA = 1e-3, 1e-6, 0.01
SAMPLES = 80
DURATION = 79 / 16  # samples every 1/16 s exactly: the corners below fall on samples
BASE = [
    "simulate", "--method", "bem", "--grid", "32", "--G0", "1e6", "--G1", "5e5", "--eta1",
    "1.5e6", "--work-of-adhesion", str(DGAMMA), "--depth", str(DEPTH),
    "--duration", str(DURATION), "--samples", str(SAMPLES), "--json",
]
HEADER = ["time_s", "displacement_m", "force_N", "contact_radius_m"]


def _read(path):
    with open(path) as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == HEADER and len(rows) == SAMPLES
    return {k: np.array([float(r[k]) for r in rows]) for k in HEADER}


def _check_against(cols, events, ref):
    for key, field in (("time_s", "ts"), ("displacement_m", "displacement"),
                       ("force_N", "force"), ("contact_radius_m", "contact_radius")):
        np.testing.assert_allclose(cols[key], np.asarray(getattr(ref, field)), rtol=1e-12,
                                   atol=1e-12 * np.abs(cols[key]).max())
    assert set(events) == {"max_tensile_force_N", "jumpoff_force_N", "jumpoff_time_s",
                           "jumpoff_contact_radius_m"}
    for key, field in (("max_tensile_force_N", "max_tensile_force"),
                       ("jumpoff_force_N", "jumpoff_force"), ("jumpoff_time_s", "jumpoff_time"),
                       ("jumpoff_contact_radius_m", "jumpoff_radius")):
        value = float(getattr(ref, field))
        if events[key] is None:  # JSON null for an event that did not happen
            assert np.isnan(value), key
        else:
            np.testing.assert_allclose(events[key], value, rtol=1e-12)


def _run(tmp_path, capsys, extra):
    out = tmp_path / "bem.csv"
    assert main(BASE + ["--out", str(out), *extra]) == 0
    return _read(out), json.loads(capsys.readouterr().out)


def test_relaxed_start_matches_library(tmp_path, capsys):
    v = DEPTH
    cols, events = _run(tmp_path, capsys, ["--radius", str(R), "--velocity", str(v)])
    ts = np.linspace(0.0, DURATION, SAMPLES)
    # the default square: EXTENT_FACTOR x the Hertz radius at --depth
    grid = jc.BEMGrid(32, EXTENT_FACTOR * np.sqrt(R * DEPTH))
    ref = jc.bem_simulate(jc.StandardModel(**SOLID), jc.Parabola(R), DGAMMA, ts,
                          DEPTH - v * ts, grid=grid, relaxed_depth=DEPTH)
    assert bool(ref.detached) and 0 < events["jumpoff_time_s"] < DURATION
    _check_against(cols, events, ref)
    # and close to the MDR command (the same options without --method bem)
    mdr = tmp_path / "mdr.csv"
    argv = [a for a in BASE if a not in ("--method", "bem", "--grid", "32")]
    assert main(argv + ["--radius", str(R), "--velocity", str(v), "--out", str(mdr)]) == 0
    ev_mdr = json.loads(capsys.readouterr().out)
    assert events["max_tensile_force_N"] == pytest.approx(ev_mdr["max_tensile_force_N"],
                                                          rel=0.15)
    assert events["jumpoff_time_s"] == pytest.approx(ev_mdr["jumpoff_time_s"], rel=0.1)


def test_hold_and_stiffness_match_library(tmp_path, capsys):
    v_in, hold, v = DEPTH / 1.0, 0.5, DEPTH  # corners at t = 1 s and 1.5 s: samples
    ts = np.linspace(0.0, DURATION, SAMPLES)
    d = np.where(ts <= 1.0, v_in * ts, np.where(ts <= 1.5, DEPTH, DEPTH - v * (ts - 1.5)))
    common = ["--radius", str(R), "--velocity", str(v), "--hold", str(hold),
              "--approach-velocity", str(v_in)]
    grid = jc.BEMGrid(32, EXTENT_FACTOR * np.sqrt(R * DEPTH))
    cols, events = _run(tmp_path, capsys, common)
    ref = jc.bem_simulate(jc.StandardModel(**SOLID), jc.Parabola(R), DGAMMA, ts, d, grid=grid)
    _check_against(cols, events, ref)
    assert cols["force_N"][0] == 0.0 and bool(ref.detached)
    hold_rows = (ts > 1.0) & (ts <= 1.5)
    assert np.all(np.diff(cols["force_N"][hold_rows]) < 0)  # relaxation during the hold
    # a cantilever of stiffness k: the history is the drive position, displacement_m the
    # indentation, k (z - d) = F in contact
    k = 1000.0
    cols, events = _run(tmp_path, capsys, common + ["--stiffness", str(k)])
    ref = jc.bem_simulate(jc.StandardModel(**SOLID), jc.Parabola(R), DGAMMA, ts, d, grid=grid,
                          loading=jc.CompliantLoading(k))
    _check_against(cols, events, ref)
    assert bool(ref.detached)
    inside = cols["contact_radius_m"] > 0
    np.testing.assert_allclose(k * (d - cols["displacement_m"])[inside],
                               cols["force_N"][inside], rtol=0,
                               atol=1e-8 * np.abs(cols["force_N"]).max())


def test_ellipsoid_profile_matches_library(tmp_path, capsys):
    rx, ry, extent = 2e-3, 0.5e-3, 2e-4
    v = DEPTH
    cols, events = _run(tmp_path, capsys, ["--profile", f"ellipsoid:{rx},{ry}", "--extent",
                                           str(extent), "--velocity", str(v)])
    ts = np.linspace(0.0, DURATION, SAMPLES)
    grid = jc.BEMGrid(32, extent)
    ref = jc.bem_simulate(jc.StandardModel(**SOLID), jc.ellipsoid_heights(grid, rx, ry), DGAMMA,
                          ts, DEPTH - v * ts, grid=grid, relaxed_depth=DEPTH)
    _check_against(cols, events, ref)


def test_hertz_semi_major_axis_against_bem():
    # the default extent of an ellipsoid: the Hertz ellipse, checked by a non-adhesive BEM
    # solve (64 cells; the contact is then measured to one cell)
    rx, ry, d = 4e-3, 1e-3, 1e-6
    a = hertz_semi_major(rx, ry, d)
    assert np.sqrt(rx * d) < a < np.sqrt(2 * rx * d)
    assert hertz_semi_major(1e-3, 1e-3, d) == pytest.approx(np.sqrt(1e-3 * d), rel=1e-14)
    assert hertz_semi_major(ry, rx, d) == a
    grid = jc.BEMGrid(64, 2.4 * a)
    _, _, p = jc.bem_contact(jc.ellipsoid_heights(grid, rx, ry), d, grid=grid,
                             effective_modulus=1e6)
    x, _ = grid.coordinates()
    x_max = float(np.max(np.abs(np.asarray(x))[np.asarray(p) > 0]))
    assert x_max == pytest.approx(a, abs=float(grid.cell_size))


@pytest.mark.parametrize(
    "change, name",
    [
        (["--grid", "4"], "--grid"),
        (["--grid", "abc"], "--grid"),
        (["--grid", "1e9"], "--grid"),
        (["--extent", "0"], "--extent"),
        (["--extent", "5"], "--extent"),
        (["--extent", "nan"], "--extent"),
        (["--profile", "ellipsoid:1e-3"], "--profile"),
        (["--profile", "ellipsoid:1e-3,-1e-3"], "--profile"),
        (["--profile", "ellipsoid:1e-3,x"], "--profile"),
        (["--profile", "cone:30"], "--profile"),
        (["--profile", "ellipsoid:1e-3,1e-3", "--radius", "1e-3"], "--radius"),
        (["--method", "fem"], "--method"),
        (["--method", "mdr"], "--grid"),  # --grid only with bem
        (["--radius", None], "--radius"),  # no indenter
        (["--extent", "1e-5"], "--extent"),  # the contact reaches the edge (runs, then fails)
    ],
)
def test_bad_values_one_line_error_and_no_file(tmp_path, capsys, change, name):
    out = tmp_path / "c.csv"
    argv = BASE + ["--radius", str(R), "--velocity", "5e-7"]
    for opt in change[::2]:
        if opt in argv:
            i = argv.index(opt)
            del argv[i : i + 2]
    extra = [x for pair in zip(change[::2], change[1::2], strict=True) for x in pair
             if pair[1] is not None]
    assert main(argv + extra + ["--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert name in err and len(err.splitlines()) == 1 and "Traceback" not in err
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []
