"""Tests of ``jaxcontact sweep``: the issue's example (scaled down) against the library, the
error messages, the outputs, and two processes on loopback against one."""

import os
import socket
import subprocess
import sys

import numpy as np
import pytest
import xarray as xr

import jaxcontact as jc
from jaxcontact_cli import main
from jaxcontact_cli._sweep import parse_range

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# the example of issue 13, with fewer points and samples (and the model and chunks of
# tests/test_sweep.py, whose compiled program it shares when both run in one process)
ARGS = ["sweep", "--G0", "1e6", "--G1", "1e5:1e6:2:log", "--eta1", "1e4",
        "--work-of-adhesion", "0.05", "--radius", "1e-2", "--depth", "1e-4",
        "--velocity", "1e-5:1e-1:3:log", "--duration-factor", "1.5", "--samples", "400",
        "--chunk-size", "16"]


@pytest.fixture(scope="module")
def example(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sweep")
    out = folder / "s.nc"
    rc = main(ARGS + ["--out", str(out)])
    assert rc == 0
    return out


def test_example_writes_netcdf_and_plot_matching_the_library(example, capsys):
    ds = xr.load_dataset(example, engine="h5netcdf")
    assert (example.with_suffix(".png")).stat().st_size > 1000
    assert not [p for p in os.listdir(example.parent) if p.startswith(".")]  # no temporaries
    assert ds.max_tensile_force_N.dims == ("G1", "velocity")
    np.testing.assert_allclose(ds.G1.values, [1e5, 1e6])
    np.testing.assert_allclose(ds.velocity.values, [1e-5, 1e-3, 1e-1])
    assert ds.velocity.attrs["units"] == "m/s" and float(ds.R) == 1e-2
    ref = jc.sweep(dict(G0=1e6, G1=[1e5, 1e6], eta1=1e4, work_of_adhesion=0.05, R=1e-2,
                        depth=1e-4, velocity=[1e-5, 1e-3, 1e-1]),
                   model=jc.RelaxedStart(samples=400, duration_factor=1.5), chunk_size=16,
                   progress=False)
    for name in jc._sweep.SUMMARIES:
        np.testing.assert_allclose(ds[name].values, ref[name].values, rtol=1e-13)
    assert (ds.status == int(jc.RESULTS.detached._value)).all()
    assert os.stat(example).st_mode & 0o044  # an ordinary file, readable by others


def test_parse_range():
    assert parse_range("--x", "2.5", "m") == ([2.5], False)
    values, log = parse_range("--x", "1e-5:1e-1:5:log", "m")
    np.testing.assert_allclose(values, [1e-5, 1e-4, 1e-3, 1e-2, 1e-1], rtol=1e-14)
    assert log
    assert parse_range("--x", "0:1:3", "s", allow_zero=True) == ([0.0, 0.5, 1.0], False)


@pytest.mark.parametrize(
    "change, option",
    [
        (["--G1", "1e5:1e6"], "--G1"),
        (["--G1", "1e5:1e6:x"], "--G1"),
        (["--velocity=-1:1:3:log"], "--velocity"),
        (["--velocity", "0:1e-3:3"], "--velocity"),
        (["--depth", "1e-4:2e-2:2"], "--depth"),
        (["--hold", "1"], "--hold"),
        (["--model", "history"], "--hold"),
        (["--stiffness", "10"], "--stiffness"),
        (["--duration-factor", "1"], "--duration-factor"),
        (["--work-rtol", "0"], "--work-rtol"),
        (["--coordinator", "localhost:1234"], "--coordinator"),
        (["--coordinator", "nohost", "--num-processes", "2", "--process-id", "0"],
         "--coordinator"),
        (["--coordinator", "h:1", "--num-processes", "2", "--process-id", "2"], "--process-id"),
        (["--plot-x", "eta1"], "--plot-x"),
        (["--out-ignored"], None),
    ],
)
def test_errors_name_the_option_and_write_nothing(tmp_path, capsys, change, option):
    out = tmp_path / "s.nc"
    out.write_text("old")
    if option is None:  # argparse: an unknown option
        with pytest.raises(SystemExit) as e:
            main(ARGS + ["--out", str(out)] + change)
        assert e.value.code == 2
        return
    rc = main(ARGS + ["--out", str(out)] + change)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and option in err[0], err
    assert out.read_text() == "old" and sorted(os.listdir(tmp_path)) == ["s.nc"]


def test_out_must_be_netcdf(tmp_path, capsys):
    assert main(ARGS + ["--out", str(tmp_path / "s.csv")]) == 2
    assert "--out" in capsys.readouterr().err
    assert os.listdir(tmp_path) == []


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_two_processes_match_one(example, tmp_path):
    out = tmp_path / "two.nc"
    port = _free_port()
    env = dict(os.environ, PYTHONPATH=ROOT, JAX_PLATFORMS="cpu")
    procs = [
        subprocess.Popen(
            [sys.executable, "-m", "jaxcontact_cli"] + ARGS
            + ["--out", str(out), "--no-plot", "--cpu-devices", "1",
               "--coordinator", f"127.0.0.1:{port}", "--num-processes", "2",
               "--process-id", str(i)],
            env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for i in range(2)
    ]
    outs = [p.communicate(timeout=1800) for p in procs]  # a hang's limit, not a speed
    for p, (_, err) in zip(procs, outs, strict=True):
        assert p.returncode == 0, err[-3000:]
    two = xr.load_dataset(out, engine="h5netcdf")
    one = xr.load_dataset(example, engine="h5netcdf")
    assert two.attrs["processes"] == 2 and two.attrs["devices"] == 2
    assert one.attrs["processes"] == 1
    for name in list(jc._sweep.SUMMARIES) + ["status"]:
        np.testing.assert_allclose(two[name].values, one[name].values, rtol=1e-13)
    assert sorted(os.listdir(tmp_path)) == ["two.nc"]  # written once, by process 0


def test_history_undersampled_work_is_reported(tmp_path, capsys):
    # 16 samples (10 in the lift): fewer than 8 under tension, so the separation work
    # is withheld (NaN, status undersampled) and the command says so
    out = tmp_path / "h.nc"
    rc = main(["sweep", "--model", "history", "--G0", "1e6", "--G1", "2e5", "--eta1", "1e4",
               "--work-of-adhesion", "0.05", "--radius", "1e-4", "--depth", "3e-6",
               "--velocity", "1e-6", "--hold", "50", "--samples", "16", "--cells", "16",
               "--no-plot", "--out", str(out)])
    assert rc == 0
    assert "undersampled" in capsys.readouterr().err
    ds = xr.load_dataset(out, engine="h5netcdf")
    assert int(ds.separation_work_status) == 1 and np.isnan(ds.separation_work_J)
    assert ds.separation_work_status.attrs["work_rtol"] == 0.01
