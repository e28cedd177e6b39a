import csv
import json
import os

import numpy as np
import pytest

import jaxcontact as jc
from jaxcontact_cli import main

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
    # the CSV keeps every digit; the command line compiles its own program (round-off apart)
    np.testing.assert_allclose([float(r["force_N"]) for r in rows], ref.force, rtol=1e-12, atol=0)
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
        (["--hold", "-0.01"], "--hold"),
        (["--hold", "inf"], "--hold"),
        (["--hold", "0.01", "--stiffness", "0"], "--stiffness"),
        (["--hold", "0.01", "--stiffness", "-5"], "--stiffness"),
        (["--hold", "0.01", "--approach-velocity", "0"], "--approach-velocity"),
        (["--stiffness", "5"], "--stiffness"),  # needs --hold
        (["--approach-velocity", "1e-4"], "--approach-velocity"),  # needs --hold
    ],
)
def test_simulate_bad_arguments_exit_nonzero_and_write_nothing(tmp_path, capsys, change, name):
    out = tmp_path / "c.csv"
    args = list(BASE)
    key = change[0].split("=")[0]
    if key in args:
        i = args.index(key)
        del args[i : i + 2]
    assert main(args + change + ["--duration", "0.1", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert name in err and len(err.splitlines()) == 1 and "Traceback" not in err
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------------------
# --hold: approach from first touch, hold, lift on the MDR foundation
# --------------------------------------------------------------------------------------

SOLID = dict(G0=1e6, G1=2e5, eta1=1e4)  # tau = eta1 / (G0 + G1) = 8.3 ms
HOLD_ARGS = dict(depth=4e-6, v_lift=1e-4, v_in=3e-4, hold=0.02, duration=0.1, samples=251)


def _read_csv(path):
    with open(path) as fh:
        rows = list(csv.DictReader(fh))
    header = list(rows[0])
    cols = {k: np.array([float(r[k]) for r in rows]) for k in header}
    return header, cols


def _hold_history(depth, v_lift, v_in, hold, duration, samples):
    """Drive history built here from the issue's words: the requested samples, and the
    same samples with the two corners (end of approach, end of hold) added."""
    t_out = np.linspace(0.0, duration, samples)
    t_in = depth / v_in
    knots_t = [0.0, t_in, t_in + hold, duration]
    knots_d = [0.0, depth, depth, depth - v_lift * (duration - t_in - hold)]
    t_sim = np.unique(np.concatenate([t_out, knots_t]))
    keep = np.isin(t_sim, t_out)
    return t_out, t_sim, np.interp(t_sim, knots_t, knots_d), keep


def _hold_cli(tmp_path, h, extra=()):
    out = tmp_path / "hold.csv"
    argv = BASE + [
        "--hold", str(h["hold"]), "--approach-velocity", str(h["v_in"]),
        "--duration", str(h["duration"]), "--samples", str(h["samples"]),
        "--out", str(out), "--json", *extra,
    ]
    return main(argv), out


def test_simulate_hold_matches_direct_simulate(tmp_path, capsys):
    h = HOLD_ARGS
    rc, out = _hold_cli(tmp_path, h)
    assert rc == 0
    events = json.loads(capsys.readouterr().out)
    header, cols = _read_csv(out)
    assert header == ["time_s", "displacement_m", "force_N", "contact_radius_m"]
    t_out, t_sim, d_sim, keep = _hold_history(
        h["depth"], h["v_lift"], h["v_in"], h["hold"], h["duration"], h["samples"]
    )
    assert keep.sum() == h["samples"] and len(t_sim) == h["samples"] + 2  # corners off-grid
    np.testing.assert_allclose(cols["time_s"], t_out, rtol=1e-15, atol=0)
    # time 0 is first touch: no indentation, no force, no contact there
    assert cols["time_s"][0] == 0.0 and cols["displacement_m"][0] == 0.0
    assert cols["force_N"][0] == 0.0 and cols["contact_radius_m"][0] == 0.0
    # approach at --approach-velocity, hold at --depth, lift at --velocity
    t, d = cols["time_s"], cols["displacement_m"]
    t_in, t_hold = h["depth"] / h["v_in"], h["depth"] / h["v_in"] + h["hold"]
    app, hold, lift = t <= t_in, (t > t_in) & (t <= t_hold), t > t_hold
    assert app.sum() > 10 and hold.sum() > 10 and lift.sum() > 10
    np.testing.assert_allclose(d[app], h["v_in"] * t[app], rtol=1e-12, atol=1e-22)
    np.testing.assert_allclose(d[hold], h["depth"], rtol=1e-12)
    np.testing.assert_allclose(d[lift], h["depth"] - h["v_lift"] * (t[lift] - t_hold), rtol=0,
                               atol=1e-12 * h["depth"])
    # the force is that of a direct call with the same (exact, piecewise-linear) history
    ref = jc.simulate(
        jc.StandardModel(**SOLID), jc.Parabola(1e-4), 0.05, t_sim, d_sim
    )
    F = cols["force_N"]
    np.testing.assert_allclose(F, np.asarray(ref.force)[keep], rtol=1e-9,
                               atol=1e-12 * np.abs(F).max())
    np.testing.assert_allclose(cols["contact_radius_m"], np.asarray(ref.contact_radius)[keep],
                               rtol=1e-9, atol=1e-18)
    # physics along the way: the force relaxes during the hold, the contact jumps off on
    # the lift and the events are those of the library
    assert np.all(np.diff(F[hold]) < 0)
    assert t_hold < events["jumpoff_time_s"] < h["duration"]
    np.testing.assert_allclose(events["jumpoff_time_s"], float(ref.jumpoff_time), rtol=1e-9)
    np.testing.assert_allclose(events["jumpoff_force_N"], float(ref.jumpoff_force), rtol=1e-9)
    np.testing.assert_allclose(events["max_tensile_force_N"], float(ref.max_tensile_force),
                               rtol=1e-9)
    np.testing.assert_allclose(events["jumpoff_contact_radius_m"], float(ref.jumpoff_radius),
                               rtol=1e-9)
    assert events["max_tensile_force_N"] <= F.min() < 0
    assert F[-1] == 0.0 and cols["contact_radius_m"][-1] == 0.0


def test_simulate_hold_with_stiffness_matches_compliant_simulate(tmp_path, capsys):
    # the cantilever deflects: the drive must be lifted further to pull the contact off
    h = dict(HOLD_ARGS, duration=0.25)
    k = 20.0  # N/m; the contact stiffness 8 G a0 is about 160 N/m
    rc, out = _hold_cli(tmp_path, h, ["--stiffness", str(k)])
    assert rc == 0
    events = json.loads(capsys.readouterr().out)
    _, cols = _read_csv(out)
    t_out, t_sim, z_sim, keep = _hold_history(
        h["depth"], h["v_lift"], h["v_in"], h["hold"], h["duration"], h["samples"]
    )
    ref = jc.simulate(
        jc.StandardModel(**SOLID), jc.Parabola(1e-4), 0.05, t_sim, z_sim,
        loading=jc.CompliantLoading(k),
    )
    F, d = cols["force_N"], cols["displacement_m"]
    np.testing.assert_allclose(F, np.asarray(ref.force)[keep], rtol=1e-9,
                               atol=1e-12 * np.abs(F).max())
    np.testing.assert_allclose(d, np.asarray(ref.displacement)[keep], rtol=1e-9, atol=1e-18)
    # the CSV displacement is the indentation: the cantilever balances the contact force,
    # k (z - d) = F, with the drive z following approach-hold-lift
    z = z_sim[keep]
    in_c = cols["contact_radius_m"] > 0
    np.testing.assert_allclose(k * (z - d)[in_c], F[in_c], rtol=0, atol=1e-9 * np.abs(F).max())
    # pushing, the indentation lags the drive; pulling (adhesion), it leads it
    assert np.all(np.sign(z - d)[in_c] == np.sign(F)[in_c])
    assert d.max() < 0.9 * h["depth"] and F.min() < 0
    assert h["depth"] / h["v_in"] + h["hold"] < events["jumpoff_time_s"] < h["duration"]
    np.testing.assert_allclose(events["jumpoff_time_s"], float(ref.jumpoff_time), rtol=1e-9)
    np.testing.assert_allclose(events["jumpoff_force_N"], float(ref.jumpoff_force), rtol=1e-9)
    assert F[-1] == 0.0


def test_demo_writes_png(tmp_path):
    assert main(["demo", "--out", str(tmp_path)]) == 0
    png = tmp_path / "pulloff.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_tune_xla_cpu():
    # in a fresh process: the flag is added before the backend starts, not twice, not over a
    # choice already in XLA_FLAGS, not with JAXCONTACT_XLA_TUNING=0, and results are the same
    import subprocess
    import sys

    import jaxlib

    code = (
        "import os, sys\n"
        "from fitting import tune_xla_cpu, XLA_CPU_FLAGS\n"
        "added = tune_xla_cpu()\n"
        "import jax; jax.config.update('jax_enable_x64', True)\n"
        "import jaxcontact as jc\n"
        "force = None\n"
        "if sys.argv[1:] == ['compute']:\n"
        "    sol = jc.retract(jc.StandardModel(1e4, 5e3, 7.5e3), jc.Parabola(1e-5),\n"
        "                     work_of_adhesion=5e-3, depth=1e-6, ts=[0.0, 0.5, 1.0],\n"
        "                     velocity=1e-6)\n"
        "    force = float(sol.max_tensile_force)\n"
        "else:  # the backend started all the same\n"
        "    jax.numpy.zeros(1).block_until_ready()\n"
        "again = tune_xla_cpu()\n"
        "print(repr(added), repr(again), repr(os.environ.get('XLA_FLAGS', '')),\n"
        "      repr(force))\n"
    )

    def run(*argv, **env):
        full = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS",
                                                                 "JAXCONTACT_XLA_TUNING")}
        full.update(env)
        out = subprocess.run([sys.executable, "-c", code, *argv], env=full,
                             capture_output=True, text=True, check=True)
        return [eval(x) for x in out.stdout.split()]  # noqa: S307 - our own reprs

    known = tuple(int(x) for x in jaxlib.__version__.split(".")[:2]) == (0, 10)
    added, again, flags, f_tuned = run("compute")
    from fitting import XLA_CPU_FLAGS

    assert added == (list(XLA_CPU_FLAGS) if known else [])
    assert again == []  # the backend has started
    assert all(f in flags for f in added)
    added, _, flags, f_default = run("compute", JAXCONTACT_XLA_TUNING="0")
    assert added == [] and flags == ""
    # the user's choice kept (the flags only: no model compiled for nothing)
    added, again, flags, _ = run(XLA_FLAGS="--xla_cpu_use_fusion_emitters=true")
    assert added == [] and again == [] and flags == "--xla_cpu_use_fusion_emitters=true"
    assert f_tuned == pytest.approx(f_default, rel=1e-12)


@pytest.mark.slow  # extended (the default run's time): test_tune_xla_cpu checks the mechanism
def test_only_fit_gets_the_xla_tuning():
    # the older code generator slows the forward models and the relaxed model's search
    # down: `simulate`, `sweep`, `demo` and a relaxed `fit` must start JAX with XLA's
    # defaults, a full-history `fit` with `fitting.XLA_CPU_FLAGS`
    import subprocess
    import sys

    import jaxlib

    from fitting import XLA_CPU_FLAGS

    code = (
        "import os, sys\n"
        "from jaxcontact_cli._main import _parse\n"
        "args = _parse(sys.argv[1:])\n"
        "print(args.command, repr(os.environ.get('XLA_FLAGS', '')))\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS",
                                                            "JAXCONTACT_XLA_TUNING")}
    forward = ["--G0", "1e4", "--G1", "5e3", "--eta1", "7.5e3", "--work-of-adhesion", "5e-3",
               "--depth", "1e-6", "--velocity", "1e-6", "--out", "x.csv"]
    cases = {"demo": ["demo"], "simulate": ["simulate", *forward, "--duration", "1"],
             "sweep": ["sweep", *forward, "--radius", "1e-5"], "fit": ["fit", "x.csv", "--out", "o"],
             "fit-history": ["fit", "x.csv", "--model", "history", "--out", "o"]}
    known = tuple(int(x) for x in jaxlib.__version__.split(".")[:2]) == (0, 10)
    for name, argv in cases.items():
        out = subprocess.run([sys.executable, "-c", code, *argv], env=env,
                             capture_output=True, text=True, check=True).stdout.split()
        assert out[0] == name.split("-")[0]
        flags = eval(out[1])  # noqa: S307 - our own repr
        expected = " ".join(XLA_CPU_FLAGS) if (name == "fit-history" and known) else ""
        assert flags == expected, (name, flags)


# --------------------------------------------------------------------------------------
# fit and the output policy of every command
# --------------------------------------------------------------------------------------

def _fit_csvs(tmp_path, speeds=(0.5e-6, 2e-6, 8e-6), n=60):
    """Synthetic relaxed-start retract curves as CSV files (noiseless, known parameters)."""
    import fitting  # noqa: F401 - the loader reads these files

    files = []
    rheology = jc.StandardModel(G0=10e3, G1=5e3, eta1=7.5e3)
    for k, v in enumerate(speeds):
        ts = np.linspace(0.0, 2.5e-6 / v, n)
        sol = jc.retract(rheology, jc.Parabola(10e-6), work_of_adhesion=5e-3, depth=1e-6,
                         ts=ts, velocity=v)
        path = tmp_path / f"c{k}.csv"
        np.savetxt(path, np.column_stack([ts, np.asarray(sol.displacement),
                                          np.asarray(sol.force)]),
                   delimiter=",", header="time_s,displacement_m,force_N", comments="")
        files.append(str(path))
    return files


def test_fit_csv_recovers_parameters_and_writes_strict_json(tmp_path, monkeypatch):
    monkeypatch.setenv("JAXCONTACT_CACHE", str(tmp_path / "cache"))
    files = _fit_csvs(tmp_path)
    out = tmp_path / "result"
    rc = main(["fit", *files, "--radius", "10e-6", "--model", "relaxed", "--out", str(out),
               "--quiet", "--no-figure", "--starts", "8"])
    assert rc == 0
    text = (out / "parameters.json").read_text()
    table = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-JSON constant {c}"))
    assert table["G0_Pa"]["value"] == pytest.approx(10e3, rel=0.02)
    assert table["r_squared"] > 0.999
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


@pytest.mark.parametrize(
    "extra, needle",
    [
        (["--radius", "-1"], "--radius"),
        (["--radius", "1e-5", "--rheology", "prony:x"], "--rheology"),
        (["--radius", "1e-5", "--spring-constant", "1", "--model", "relaxed"],
         "--spring-constant"),
        (["--radius", "1e-5", "--units", "force=furlong"], "--units"),
        (["--radius", "1e-5", "--sensitivity", "5e-8"], "--sensitivity"),
        (["--radius", "1e-5", "--sample-rate", "-5"], "--sample-rate"),
        (["--radius", "1e-5", "--sample-rate", "100"], "sample_rate"),
        (["--radius", "1e-5", "--profile", "cone:30"], "--radius"),
        (["--profile", "cone:95"], "--profile"),
        (["--profile", "blob:1"], "--profile"),
        (["--radius", "1e-5", "--fix", "G0"], "--fix"),
        (["--radius", "1e-5", "--bounds", "G0=5:1"], "--bounds"),
        (["--radius", "1e-5", "--initial", "G0=nan"], "--initial"),
        (["--radius", "1e-5", "--starts", "0"], "--starts"),
        (["--radius", "1e-5", "--max-steps", "0"], "--max-steps"),
        (["--radius", "1e-5", "--screen", "-1"], "--screen"),
        (["--radius", "1e-5", "--starts", "4", "--screen", "3"], "--screen"),
        (["--radius", "1e-5", "--screen", "8"], "screen must be 0 or an integer >= n_starts"),
        (["--radius", "1e-5", "--explore-steps", "0"], "--explore-steps"),
        (["--radius", "1e-5", "--abandon", "1"], "--abandon: must be a number > 1"),
        (["--radius", "1e-5", "--abandon", "nan"], "--abandon"),
        (["--radius", "1e-5", "--search-cells", "40"],
         "--search-cells: must be an integer in [2, --cells = 32]; got 40"),
        (["--radius", "1e-5", "--cells", "8", "--search-cells", "1"], "--search-cells"),
        (["--radius", "1e-5", "--streams", "0"], "--streams: must be an integer >= 1"),
        (["--radius", "1e-5", "--out", ""], "--out"),
        (["--radius", "1e-5", "--coordinator", "h:1"], "--coordinator"),
        (["--radius", "1e-5", "--process-id", "1"], "--num-processes/--process-id"),
    ],
)
def test_fit_bad_input_one_line_error_and_no_files(tmp_path, capsys, extra, needle):
    files = _fit_csvs(tmp_path, speeds=(8e-6,), n=20)
    out = tmp_path / "out"
    argv = ["fit", *files, *extra]
    if "--out" not in extra:
        argv += ["--out", str(out)]
    rc = main(argv + ["--quiet"])
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and "Traceback" not in err and len(err.splitlines()) == 1
    assert not out.exists()


def test_fit_missing_or_junk_file(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["fit", str(tmp_path / "nope.csv"), "--radius", "1e-5", "--out",
                 str(out)]) == 2
    assert "FILE" in capsys.readouterr().err
    junk = tmp_path / "junk.jpk-force"
    junk.write_bytes(b"\x00\x01not a force curve" * 7)
    rc = main(["fit", str(junk), "--radius", "1e-5", "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "junk.jpk-force" in err and "Traceback" not in err
    assert not out.exists()


def test_output_folder_checked_before_work(tmp_path, capsys):
    files = _fit_csvs(tmp_path, speeds=(8e-6,), n=20)
    foreign = tmp_path / "notes"
    foreign.mkdir()
    (foreign / "mine.txt").write_text("keep me")
    rc = main(["fit", *files, "--radius", "1e-5", "--out", str(foreign), "--quiet"])
    assert rc == 2 and "--out" in capsys.readouterr().err
    assert [p.name for p in foreign.iterdir()] == ["mine.txt"]
    a_file = tmp_path / "file"
    a_file.write_text("x")
    assert main(["fit", *files, "--radius", "1e-5", "--out", str(a_file), "--quiet"]) == 2
    if os.geteuid() != 0:  # root may write anywhere
        locked = tmp_path / "locked"
        locked.mkdir()
        locked.chmod(0o500)
        rc = main(["fit", *files, "--radius", "1e-5", "--out", str(locked / "o"), "--quiet"])
        assert rc == 2 and "cannot write" in capsys.readouterr().err


def _catches(status_path, signum):
    """Whether the process of `/proc/PID/status` has a handler for `signum` (SigCgt)."""
    try:
        with open(status_path) as fh:
            line = next(x for x in fh if x.startswith("SigCgt:"))
    except (OSError, StopIteration):  # the process has ended
        return True
    return bool(int(line.split()[1], 16) >> (signum - 1) & 1)


def test_interrupt_during_imports_is_not_lost(tmp_path):
    # SIGINT while jax is being imported (before the command runs): recorded, and the
    # command stops with 130 after the imports; formerly a library swallowed it and the
    # fit ran to the end (exit 0), or the interpreter crashed (exit 139)
    import signal
    import subprocess
    import sys
    import time

    files = _fit_csvs(tmp_path, speeds=(8e-6,), n=20)
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-m", "jaxcontact_cli", "fit", *files, "--radius", "1e-5",
         "--model", "relaxed", "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "JAXCONTACT_CACHE": str(tmp_path / "cache")})
    # interrupt once the command's handlers are set (it catches SIGTERM, which Python by
    # itself does not: /proc's SigCgt mask), however slow the machine; a fixed 0.3 s sent
    # the signal into Python's own start-up on a busy machine (exit 1). The command
    # imports jax right after setting them, so the signal arrives during the imports.
    status = f"/proc/{proc.pid}/status"
    if os.path.exists(status):
        while proc.poll() is None and not _catches(status, signal.SIGTERM):
            time.sleep(0.001)
    else:  # no /proc: the start-up as measured on an idle machine
        time.sleep(0.3)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=600)  # a hang's limit: imports on a busy machine
    assert proc.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    assert not out.exists()


def _first_progress_line(proc, *, deadline_s):
    """Read `proc`'s stderr until the fit's first progress line ("[fit ...]"); returns what
    was read. Fails (killing the process) if none comes within `deadline_s`."""
    import select
    import time

    seen = ""
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        ready, _, _ = select.select([proc.stderr], [], [], 1.0)
        if ready:
            line = proc.stderr.readline()
            if not line:  # the process ended before its fit began
                break
            seen += line
            if line.startswith("[fit"):
                return seen
    proc.kill()
    raise AssertionError(f"no progress line from the fit; stderr so far:\n{seen}")


def test_interrupt_leaves_no_files(tmp_path):
    # SIGINT and SIGTERM during a real fit (compilation or optimisation): exit 130/143
    # promptly, no output folder, no hidden temporary folder
    import signal
    import subprocess
    import sys

    files = _fit_csvs(tmp_path, speeds=(8e-6,), n=20)
    for sig, code in ((signal.SIGINT, 130), (signal.SIGTERM, 143)):
        out = tmp_path / f"out{code}"
        proc = subprocess.Popen(
            [sys.executable, "-m", "jaxcontact_cli", "fit", *files, "--radius", "1e-5",
             "--model", "relaxed", "--out", str(out)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            env={**os.environ, "JAXCONTACT_CACHE": str(tmp_path / "cache")})
        # wait for the fit's first progress line (imports done, the fit under way), however
        # slow the machine, then interrupt; the exit code (130/143, not 0) shows that the fit
        # was stopped, not run to its end, without timing anything
        first = _first_progress_line(proc, deadline_s=600)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=600)
        err = first + err
        assert proc.returncode == code, err
        assert "interrupted" in err and "Traceback" not in err
        assert not out.exists()
        assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_fit_that_does_not_converge_writes_its_best_point(tmp_path, capsys):
    # one iteration per start: no start can converge; the best point is written with the
    # reason and what to try, and the exit status is the documented 3. One curve, and a
    # map of chunks of one: the map's fits are that fit's compiled pool (and 20 samples,
    # the shape of the curves above: one compilation of each program for the test)
    from jaxcontact_cli._fit import EXIT_NOT_CONVERGED

    files = _fit_csvs(tmp_path, n=20)
    out = tmp_path / "result"
    rc = main(["fit", files[0], "--radius", "10e-6", "--model", "relaxed", "--out", str(out),
               "--quiet", "--no-figure", "--starts", "2", "--max-steps", "1",
               "--abandon", "inf"])
    err = capsys.readouterr().err
    assert rc == EXIT_NOT_CONVERGED == 3, err
    assert "did not converge" in err and "--max-steps 2" in err
    table = json.loads((out / "parameters.json").read_text())
    assert table["converged"] is False and table["status"] == "flagged"
    conv = table["convergence"]
    assert "step limit (max_steps 1)" in conv["reason"] and conv["max_steps"] == 1
    assert any("max_steps=2" in a for a in conv["advice"])
    assert "not_converged" in table["flags"] and table["G0_Pa"]["value"] > 0
    assert table["search"]["n_starts"] == 2 and table["search"]["max_steps"] == 1
    assert table["search"]["explore_steps"] == 1  # at most max_steps
    assert table["search"]["abandon"] is None  # --abandon inf: no start abandoned
    # a map keeps such curves as flagged, not failed
    out = tmp_path / "map"
    rc = main(["fit", *files[:2], "--each", "--radius", "10e-6", "--model", "relaxed",
               "--out", str(out), "--quiet", "--no-figure", "--starts", "2",
               "--max-steps", "1", "--chunk", "1"])
    assert rc == 3, capsys.readouterr().err
    with (out / "map.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [r["status"] for r in rows] == ["flagged", "flagged"]
    assert all("not_converged" in r["flags"] and "step limit" in r["convergence"]
               and float(r["G0_Pa"]) > 0 and r["error"] == "" for r in rows)


def test_fit_help_documents_the_exit_status(capsys):
    with pytest.raises(SystemExit):
        main(["fit", "--help"])
    text = capsys.readouterr().out
    assert "exit status" in text and "3  written, but the fit did not converge" in text
    assert "--max-steps" in text


def test_curves_without_contact_fail_with_the_reason(tmp_path, capsys):
    # the QI curves read with --contact-point none: the approach is noise, the retract a
    # drag offset; they used to be "4 converged" with R² 0.33-0.42
    pytest.importorskip("afmformats")
    out = tmp_path / "q"
    rc = main(["fit", "tests/data/qi-2x2-2020.02.07.jpk-qi-data", "--radius", "10e-6",
               "--contact-point", "none", "--quiet", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("no contact in the data") == 4, err
    assert "on the approach and hold the force never stays above 5 sigma" in err
    assert not out.exists()
