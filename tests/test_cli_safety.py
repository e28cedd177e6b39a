"""The command line's output safety: never delete what jaxcontact did not write, one run per
output at a time, ordinary file modes, and a clear word when a signal comes after the
output is complete (issue 25, items 11 and 12)."""

import json
import os
import pathlib
import signal
import stat
import subprocess
import sys

import pytest

from jaxcontact_cli import main
from jaxcontact_cli._common import MANIFEST, OutputFolder, UsageError

ROOT = pathlib.Path(__file__).resolve().parents[1]
IBW = str(ROOT / "tests" / "data" / "sin-force-distance.ibw")


def _user_folder(path: pathlib.Path) -> dict:
    """A user's folder that holds a file named like an output (the issue's example)."""
    (path / "raw").mkdir(parents=True)
    (path / ".git").mkdir()
    (path / "parameters.json").write_text('{"lr": 0.1}')
    (path / "raw" / "experiment1.csv").write_text("x\n")
    (path / ".git" / "HEAD").write_text("ref: refs/heads/main\n")
    return _snapshot(path)


def _snapshot(path: pathlib.Path) -> dict:
    return {str(p.relative_to(path)): p.read_bytes() if p.is_file() else None
            for p in sorted(path.rglob("*"))}


@pytest.mark.parametrize("command", [
    ["fit", IBW, "--radius", "40e-6", "--starts", "2", "--no-figure"],
    ["demo"],
])
def test_out_never_replaces_a_folder_with_files_we_did_not_write(tmp_path, capsys, command):
    # formerly any folder holding parameters.json (pulloff.csv for demo) counted as an
    # earlier output and was replaced whole: raw/ and .git/ were deleted, rc 0
    user = tmp_path / "u"
    before = _user_folder(user)
    if command[0] == "demo":
        (user / "pulloff.csv").write_text("mine")
        before = _snapshot(user)
    rc = main([*command, "--out", str(user)])
    err = capsys.readouterr().err
    assert rc == 2
    assert "--out" in err and "raw" in err and ".git" in err and "did not write" in err
    assert _snapshot(user) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["u"]  # no lock, no staging left


def _write(folder: OutputFolder, **files) -> pathlib.Path:
    stage = folder.stage()
    for name, text in files.items():
        (stage / name.replace("_", ".")).write_text(text)
    return folder.commit()


def test_output_folder_replaces_only_its_own_earlier_output(tmp_path):
    out = tmp_path / "run"
    _write(OutputFolder("--out", out, command="t"), a_txt="1", b_png="old figure")
    listed = json.loads((out / MANIFEST).read_text())
    assert listed["files"] == ["a.txt", "b.png"] and listed["written_by"] == "jaxcontact"
    _write(OutputFolder("--out", out, command="t"), a_txt="2")  # our own output: replaced
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "a.txt"]  # no stale b.png
    assert (out / "a.txt").read_text() == "2"
    third = OutputFolder("--out", out, command="t")
    (third.stage() / "a.txt").write_text("3")
    third.discard()  # a failed run changes nothing and leaves nothing
    assert (out / "a.txt").read_text() == "2"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
    # a file the user added to an earlier output makes it theirs: refused, nothing deleted
    (out / "notes.txt").write_text("mine")
    with pytest.raises(UsageError, match="notes.txt"):
        OutputFolder("--out", out, command="t")
    # a listed name that is now a folder is not ours either
    (out / "notes.txt").unlink()
    (out / "a.txt").unlink()
    (out / "a.txt").mkdir()
    (out / "a.txt" / "data.csv").write_text("mine")
    with pytest.raises(UsageError, match="a.txt"):
        OutputFolder("--out", out, command="t")
    assert (out / "a.txt" / "data.csv").read_text() == "mine"
    # an empty folder may be used; a manifest that is not ours does not count
    empty = tmp_path / "empty"
    empty.mkdir()
    _write(OutputFolder("--out", empty, command="t"), a_txt="1")
    forged = tmp_path / "forged"
    forged.mkdir()
    (forged / MANIFEST).write_text('{"files": ["x.csv"]}')
    (forged / "x.csv").write_text("mine")
    with pytest.raises(UsageError, match="x.csv"):
        OutputFolder("--out", forged, command="t")


def test_files_added_during_the_run_stop_the_commit(tmp_path):
    out = tmp_path / "run"
    _write(OutputFolder("--out", out, command="t"), a_txt="1")
    folder = OutputFolder("--out", out, command="t")
    (folder.stage() / "a.txt").write_text("2")
    (out / "raw.csv").write_text("the user's data, saved while the fit ran")
    with pytest.raises(UsageError, match="raw.csv.*appeared"):
        folder.commit()
    folder.discard()
    assert (out / "raw.csv").exists() and (out / "a.txt").read_text() == "1"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_one_run_at_a_time_per_output_folder(tmp_path, capsys):
    out = tmp_path / "run"
    first = OutputFolder("--out", out, command="t")
    lock = tmp_path / ".run.lock"
    assert lock.read_text().split()[0] == str(os.getpid())
    # a second run (here the demo command) is refused before any work, naming the owner
    assert main(["demo", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and "another jaxcontact run" in err and f"pid {os.getpid()}" in err
    with pytest.raises(UsageError, match="another jaxcontact run"):
        OutputFolder("--out", out, command="t")
    _write(first, a_txt="1")
    assert not lock.exists()  # released with the commit
    # a lock left by a process that is gone is stale: taken over
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    lock.write_text(f"{dead.stdout.strip()} {os.uname().nodename}\n")
    second = OutputFolder("--out", out, command="t")
    assert lock.read_text().split()[0] == str(os.getpid())
    second.discard()
    assert not lock.exists()


def test_lock_released_when_the_command_fails_after_the_folder_check(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,displacement_m,force_N\n0,0,nope\n")
    for out in (tmp_path / "o", tmp_path / "new" / "deeper" / "o"):
        assert main(["fit", str(bad), "--radius", "1e-5", "--out", str(out), "--quiet"]) == 2
        assert "bad.csv" in capsys.readouterr().err
        # no lock left, and no folder made for it (the parents of a new --out)
        assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.csv"]


_SIGNAL_AFTER_COMMIT = """
import os, signal, sys, time
out, wait = sys.argv[1], float(sys.argv[2])
sys.argv = ["jaxcontact", "demo", "--out", out]
import jaxcontact_cli._main as m
from jaxcontact_cli._common import OutputFolder

def dispatch(args):
    folder = OutputFolder("--out", args.out, command="demo")
    (folder.stage() / "pulloff.csv").write_text("1")
    folder.commit()
    os.kill(os.getpid(), signal.SIGTERM)  # just after the output is complete
    time.sleep(wait)
    return 0

m._dispatch = dispatch
m.console_main()
"""


@pytest.mark.parametrize("wait", [0.0, 2.0])
def test_signal_after_the_output_is_complete_says_so(tmp_path, wait):
    # formerly: "interrupted; no output was written or changed" although the output was
    # complete, or (a signal after the command returned) exit -15 with no message
    out = tmp_path / "o"
    proc = subprocess.run([sys.executable, "-c", _SIGNAL_AFTER_COMMIT, str(out), str(wait)],
                          capture_output=True, text=True, timeout=600,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 128 + signal.SIGTERM, (proc.returncode, proc.stderr)
    assert f"wrote {out}" in proc.stderr and "complete" in proc.stderr, proc.stderr
    assert "no output was written" not in proc.stderr
    assert (out / "pulloff.csv").read_text() == "1"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o"]


def _ordinary(path) -> int:
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def test_every_output_file_has_the_ordinary_mode(tmp_path, capsys):
    # `simulate` wrote its CSV with mode 0600 (a private temporary file renamed into place)
    old = os.umask(0o022)
    try:
        csv = tmp_path / "c.csv"
        assert main(["simulate", "--G0", "1e6", "--G1", "2e5", "--eta1", "1e4",
                     "--work-of-adhesion", "0.05", "--radius", "1e-4", "--depth", "4e-6",
                     "--velocity", "1e-4", "--duration", "0.005", "--samples", "11",
                     "--out", str(csv)]) == 0
        nc = tmp_path / "s.nc"
        assert main(["sweep", "--G0", "1e6", "--G1", "2e5", "--eta1", "1e4",
                     "--work-of-adhesion", "0.05", "--radius", "1e-4", "--depth", "4e-6",
                     "--velocity", "1e-5:1e-4:2:log", "--model", "relaxed", "--out", str(nc),
                     "--plot", str(tmp_path / "s.png")]) == 0
        folder = OutputFolder("--out", tmp_path / "f", command="t")
        _write(folder, a_txt="1")
        files = [csv, nc, tmp_path / "s.png", tmp_path / "f" / "a.txt",
                 tmp_path / "f" / MANIFEST]
        modes = {p.name: oct(stat.S_IMODE(p.stat().st_mode)) for p in files}
        assert modes == {p.name: oct(_ordinary(p)) for p in files}
        assert oct(stat.S_IMODE((tmp_path / "f").stat().st_mode)) == oct(0o755)
    finally:
        os.umask(old)


_HOLDER = """
import sys, time
from jaxcontact_cli._common import OutputFolder
folder = OutputFolder("--out", sys.argv[1], command="fit")
print("locked", flush=True)
time.sleep(120)
"""


def test_a_second_process_is_refused_and_a_killed_ones_lock_is_taken_over(tmp_path, capsys):
    # two fits into the same --out at once both said "written" and one result was lost
    out = tmp_path / "o"
    holder = subprocess.Popen([sys.executable, "-c", _HOLDER, str(out)], text=True,
                              stdout=subprocess.PIPE, env={**os.environ,
                                                           "PYTHONPATH": str(ROOT)})
    try:
        assert holder.stdout.readline().strip() == "locked"
        assert main(["demo", "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert f"pid {holder.pid}" in err and "another jaxcontact run" in err
    finally:
        holder.kill()  # SIGKILL: no cleanup runs, the lock file stays behind
        holder.wait()
        holder.stdout.close()
    assert (tmp_path / ".o.lock").exists()
    folder = OutputFolder("--out", out, command="demo")  # stale: its process is gone
    _write(folder, pulloff_csv="1")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o"]
