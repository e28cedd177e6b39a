import csv
import json

import numpy as np
import pytest

import jaxcontact as jc
from jaxcontact.cli import main

BASE = [
    "simulate", "--G0", "1e6", "--G1", "2e5", "--eta1", "1e4", "--work-of-adhesion", "0.05",
    "--radius", "1e-4", "--depth", "4e-6", "--velocity", "1e-4",
]


def test_version_and_help(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert jc.__version__ in capsys.readouterr().out
    with pytest.raises(SystemExit) as e:
        main(["simulate", "--help"])
    assert e.value.code == 0


def test_simulate_csv_and_json_match_library(tmp_path, capsys):
    out = tmp_path / "curve.csv"
    rc = main(BASE + ["--duration", "0.1", "--samples", "501", "--out", str(out), "--json"])
    assert rc == 0
    captured = capsys.readouterr()
    events = json.loads(captured.out)  # stdout holds only the JSON
    with open(out) as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == ["time_s", "displacement_m", "force_N", "contact_radius_m"]
    assert len(rows) == 501
    ref = jc.retract(
        jc.StandardModel(G0=1e6, G1=2e5, eta1=1e4), jc.Parabola(R=1e-4), work_of_adhesion=0.05,
        depth=4e-6, velocity=1e-4, ts=np.linspace(0, 0.1, 501),
    )
    np.testing.assert_allclose([float(r["force_N"]) for r in rows], ref.force, rtol=1e-15, atol=0)
    np.testing.assert_allclose(events["jumpoff_time_s"], ref.jumpoff_time, rtol=1e-15)
    np.testing.assert_allclose(events["jumpoff_force_N"], -5 / 6 * np.pi * 0.3 * 1e-4, rtol=1e-12)
    assert set(events) == {
        "max_tensile_force_N", "jumpoff_force_N", "jumpoff_time_s", "jumpoff_contact_radius_m"
    }


def test_simulate_no_detachment_gives_null(tmp_path, capsys):
    out = tmp_path / "c.csv"
    assert main(BASE + ["--duration", "0.005", "--samples", "11", "--out", str(out), "--json"]) == 0
    events = json.loads(capsys.readouterr().out)
    assert events["jumpoff_time_s"] is None and events["jumpoff_force_N"] is None
    assert events["max_tensile_force_N"] is not None


@pytest.mark.parametrize(
    "change, name",
    [
        (["--G0=-1e6"], "--G0"),
        (["--G1", "0"], "--G1"),
        (["--depth", "0"], "--depth"),
        (["--eta1", "nan"], "--eta1"),
        (["--radius", "5"], "--radius"),
        (["--samples", "1"], "--samples"),
    ],
)
def test_simulate_bad_arguments_exit_nonzero_and_write_nothing(tmp_path, capsys, change, name):
    out = tmp_path / "c.csv"
    args = list(BASE)
    key = change[0].split("=")[0]
    if key in args:
        i = args.index(key)
        del args[i : i + 2]
    with pytest.raises(SystemExit) as e:
        main(args + change + ["--duration", "0.1", "--out", str(out)])
    assert e.value.code == 2
    assert name in capsys.readouterr().err
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


def test_demo_writes_png(tmp_path):
    assert main(["demo", "--out", str(tmp_path)]) == 0
    png = tmp_path / "pulloff.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
