"""Reliability of the command line and the fitting outputs: bad inputs and faults, as a user
meets them, and what each gives.

Each case runs ``python -m jaxcontact_cli ...`` in a fresh process (as a user does) in a
scratch folder, and records the exit status, whether the message names what is wrong,
whether a Python traceback reached the user, and whether files the user had are intact and
no partial output was left. The companion of `benchmarks/fuzz_forward.py` (the library);
the test suite checks a fixed subset (`tests/test_cli*.py`, `tests/test_input_errors.py`).

    python benchmarks/fuzz_cli.py [--out docs/reliability-cli.md]
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"
ROWS: list[tuple[str, str, str, str]] = []


def _env(tmp: Path) -> dict:
    env = {**os.environ, "JAXCONTACT_CACHE": str(tmp / "cache")}
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def _cli(tmp: Path, *argv, timeout=1200):
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-m", "jaxcontact_cli", *map(str, argv)],
                         capture_output=True, text=True, cwd=tmp, env=_env(tmp),
                         timeout=timeout)
    return out.returncode, out.stdout, out.stderr, time.perf_counter() - t0


def _csv(path: Path, t, d, f):
    np.savetxt(path, np.column_stack([t, d, f]), delimiter=",",
               header="time_s,displacement_m,force_N", comments="")
    return path


def _good_curve(tmp: Path, name="good.csv", n=60):
    import jaxcontact as jc

    ts = np.linspace(0.0, 1.25, n)
    sol = jc.retract(jc.StandardModel(G0=10e3, G1=5e3, eta1=7.5e3), jc.Parabola(10e-6),
                     work_of_adhesion=5e-3, depth=1e-6, ts=ts, velocity=2e-6)
    return _csv(tmp / name, ts, np.asarray(sol.displacement), np.asarray(sol.force))


def _snapshot(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file() and "cache" not in p.parts}


def case(area, tried, run, *, expect_rc, names=(), keep=None, out=None, tmp):
    """Run one case; `names`: words the message must contain; `keep`: a folder whose files
    must be unchanged; `out`: an output folder that must not exist afterwards."""
    before = _snapshot(keep) if keep else None
    rc, so, se, dt = run()
    msg = (so + se).strip().splitlines()
    last = next((line for line in reversed(msg) if "error" in line.lower()), msg[-1] if msg
                else "")
    checks = [f"exit {rc}" + ("" if rc in expect_rc else f" (expected {sorted(expect_rc)})")]
    checks.append("no traceback" if "Traceback" not in so + se else "TRACEBACK")
    if names:
        hit = all(n.lower() in (so + se).lower() for n in names)
        checks.append("message names " + "/".join(names) if hit else "message does NOT name "
                      + "/".join(names))
    if keep is not None:
        checks.append("user files intact" if _snapshot(keep) == before else "USER FILES CHANGED")
    if out is not None:
        checks.append("no output left" if not Path(out).exists() else "OUTPUT LEFT")
    leftovers = [p.name for p in tmp.iterdir() if p.name.startswith(".")]
    if leftovers:
        checks.append(f"HIDDEN FILES LEFT {leftovers}")
    bad = ("TRACEBACK", "CHANGED", "does NOT name", "LEFT", "(expected")
    ok = not any(m in c for c in checks for m in bad)
    ROWS.append((area, tried, "; ".join(checks), "ok" if ok else "FAIL"))
    print(f"| {area} | {tried} | {'; '.join(checks)} | {'ok' if ok else 'FAIL'} |  "
          f"({dt:.1f} s) {last[:140]}", flush=True)
    return ok


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "docs" / "reliability-cli.md"))
    args = ap.parse_args(argv)
    t_start = time.perf_counter()
    base = Path(tempfile.mkdtemp(prefix="jc-fuzz-cli-"))

    def fresh(name):
        d = base / name
        d.mkdir()
        return d

    # ---- argument errors (before any work) ---------------------------------------------
    t = fresh("args")
    good = _good_curve(t)
    for tried, extra, names in [
        ("--radius -1e-5", ["--radius", "-1e-5"], ["--radius"]),
        ("--radius 5 (mm as m)", ["--radius", "5"], ["--radius", "unit"]),
        ("--radius nan", ["--radius", "nan"], ["--radius"]),
        ("--profile cone:95", ["--profile", "cone:95"], ["cone"]),
        ("--profile sphere:R and --radius", ["--profile", "sphere:1e-5", "--radius", "1e-5"],
         ["--radius"]),
        ("--starts 0", ["--radius", "1e-5", "--starts", "0"], ["--starts"]),
        ("--fix unknown=1", ["--radius", "1e-5", "--fix", "unknown=1"], ["unknown"]),
        ("--bounds eta1=10:1", ["--radius", "1e-5", "--bounds", "eta1=10:1"], ["eta1"]),
        ("--max-samples 1", ["--radius", "1e-5", "--max-samples", "1"], ["--max-samples"]),
        ("--rheology prony:0", ["--radius", "1e-5", "--rheology", "prony:0"], ["--rheology"]),
        ("--indentation-range 2:1", ["--radius", "1e-5", "--indentation-range", "2:1"],
         ["--indentation-range"]),
    ]:
        out = t / "o"
        case("fit: arguments", tried,
             lambda extra=extra, out=out: _cli(t, "fit", good, *extra, "--out", out),
             expect_rc={2}, names=names, out=out, tmp=t)

    # ---- input files -------------------------------------------------------------------
    t = fresh("files")
    (t / "empty.csv").write_text("")
    (t / "header.csv").write_text("time_s,displacement_m,force_N\n")
    nanf = _good_curve(t, "nan.csv")
    text = nanf.read_text().splitlines()
    text[5] = "nan,nan,nan"
    nanf.write_text("\n".join(text) + "\n")
    (t / "words.csv").write_text("a,b,c\nx,y,z\n")
    for tried, fname, names in [
        ("a missing file", "missing.csv", ["missing.csv"]),
        ("an empty file", "empty.csv", ["empty.csv"]),
        ("a header without rows", "header.csv", ["header.csv"]),
        ("a row of NaN", "nan.csv", ["nan.csv"]),
        ("a table of words", "words.csv", ["words.csv"]),
    ]:
        out = t / "o"
        case("fit: input files", tried,
             lambda fname=fname, out=out: _cli(t, "fit", t / fname, "--radius", "1e-5",
                                               "--out", out, "--quiet"),
             expect_rc={2}, names=names, out=out, tmp=t)

    # ---- degenerate data (the fit runs, or refuses, with a reason) ---------------------
    t = fresh("data")
    n = 60
    ts = np.linspace(0, 1, n)
    d = np.linspace(1e-6, -1e-6, n)
    _csv(t / "zero.csv", ts, d, np.zeros(n))
    _csv(t / "const.csv", ts, d, np.full(n, 1e-9))
    short = _good_curve(t, "short.csv", n=5)
    for tried, path, rcs in [
            ("a zero-force curve: refused (no contact)", t / "zero.csv", {2}),
            ("a constant-force curve: refused, or written as not converged (exit 3)",
             t / "const.csv", {2, 3}),
            ("a noiseless 5-sample curve of the model itself: the three moduli exact, the "
             "work of adhesion reported not determined (no jump-off)", short, {0, 3})]:
        out = t / f"o-{path.stem}"
        case("fit: degenerate data", tried,
             lambda path=path, out=out: _cli(t, "fit", path, "--radius", "1e-5", "--out", out,
                                             "--quiet", "--no-figure", "--starts", "2"),
             expect_rc=rcs, tmp=t)
    qi = DATA / "qi-2x2-2020.02.07.jpk-qi-data"
    out = t / "q"
    case("fit: degenerate data", "QI map, curves without contact (--contact-point none)",
         lambda: _cli(t, "fit", qi, "--radius", "10e-6", "--contact-point", "none", "--out",
                      out, "--quiet", "--no-figure", "--starts", "2"),
         expect_rc={1, 2}, names=["no contact"], tmp=t)

    # ---- output folders ----------------------------------------------------------------
    t = fresh("outputs")
    good = _good_curve(t)
    user = t / "u"
    (user / "raw").mkdir(parents=True)
    (user / ".git").mkdir()
    (user / "parameters.json").write_text('{"lr": 0.1}')
    (user / "raw" / "experiment1.csv").write_text("x\n")
    case("fit: --out", "a folder of the user's holding a parameters.json, raw/ and .git/",
         lambda: _cli(t, "fit", good, "--radius", "1e-5", "--out", user, "--quiet",
                      "--no-figure", "--starts", "2"),
         expect_rc={2}, names=["--out"], keep=user, tmp=t)
    (t / "afile").write_text("mine")
    case("fit: --out", "an existing file",
         lambda: _cli(t, "fit", good, "--radius", "1e-5", "--out", t / "afile", "--quiet"),
         expect_rc={2}, names=["--out"], tmp=t)
    locked = t / "locked"
    procs = []
    for _ in range(2):
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "jaxcontact_cli", "fit", str(good), "--radius", "1e-5",
             "--out", str(locked), "--quiet", "--no-figure", "--starts", "2"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=t, env=_env(t)))
        time.sleep(1.0)
    res = [p.communicate(timeout=1200) for p in procs]
    rcs = sorted(p.returncode for p in procs)
    tb = any("Traceback" in so + se for so, se in res)
    ok = rcs == [0, 2] and not tb and (locked / "parameters.json").exists()
    ROWS.append(("fit: --out", "two fits into the same --out at once",
                 f"exit codes {rcs}; " + ("no traceback" if not tb else "TRACEBACK")
                 + "; one result written, the other refused", "ok" if ok else "FAIL"))
    print(ROWS[-1], flush=True)

    # ---- interruption ------------------------------------------------------------------
    for sig, code in ((signal.SIGINT, 130), (signal.SIGTERM, 143)):
        out = t / f"int{code}"
        p = subprocess.Popen(
            [sys.executable, "-m", "jaxcontact_cli", "fit", str(good), "--radius", "1e-5",
             "--out", str(out), "--starts", "4", "--no-figure"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=t, env=_env(t))
        seen = ""
        while True:  # the fit's first progress line: imports done, the fit under way
            line = p.stderr.readline()
            seen += line
            if not line or line.startswith("[fit"):
                break
        p.send_signal(sig)
        so, se = p.communicate(timeout=1200)
        se = seen + se
        left = out.exists() or [q.name for q in t.iterdir() if q.name.startswith(".")]
        ok = p.returncode == code and "Traceback" not in se and not left
        ROWS.append(("fit: interruption", f"{signal.Signals(sig).name} during the fit",
                     f"exit {p.returncode}; " + ("no traceback" if "Traceback" not in se
                                                 else "TRACEBACK")
                     + ("; no output left" if not left else f"; LEFT {left}"),
                     "ok" if ok else "FAIL"))
        print(ROWS[-1], flush=True)

    # ---- the other commands ------------------------------------------------------------
    t = fresh("other")
    for tried, argv, names in [
        ("simulate --G0 -1", ["simulate", "--G0", "-1", "--G1", "1e5", "--eta1", "1e4",
                              "--work-of-adhesion", "0.05", "--radius", "1e-4", "--depth",
                              "4e-6", "--velocity", "1e-4", "--out", "s.csv"], ["--G0"]),
        ("simulate --depth 4000 (µm as m)", ["simulate", "--G0", "1e6", "--G1", "1e5",
                                             "--eta1", "1e4", "--work-of-adhesion", "0.05",
                                             "--radius", "1e-4", "--depth", "4000",
                                             "--velocity", "1e-4", "--out", "s.csv"],
         ["depth"]),
        ("sweep --velocity 1:0:4", ["sweep", "--G0", "1e6", "--G1", "1e5", "--eta1", "1e4",
                                    "--work-of-adhesion", "0.05", "--radius", "1e-2",
                                    "--depth", "1e-4", "--velocity", "1:0:4", "--out",
                                    "s.nc"], ["--velocity"]),
    ]:
        case(argv[0], tried, lambda argv=argv: _cli(t, *argv), expect_rc={2}, names=names,
             out=t / "s.csv", tmp=t)

    import jax

    head = (f"Produced by `python benchmarks/fuzz_cli.py` on {datetime.date.today()}, "
            f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, jax "
            f"{jax.__version__}, in {(time.perf_counter() - t_start) / 60:.1f} min. Each case "
            "runs `python -m jaxcontact_cli` in a fresh process in a scratch folder.")
    n_ok = sum(r[3] == "ok" for r in ROWS)
    lines = ["# Reliability of the command line and the fitting outputs", "", head, "",
             f"{n_ok} of {len(ROWS)} cases as expected.", "",
             "| command | what was tried | what it gives | verdict |", "| --- | --- | --- | --- |"]
    lines += [f"| {a} | {b} | {c} | {d} |" for a, b, c, d in ROWS]
    Path(args.out).write_text("\n".join(lines) + "\n")
    print(f"{n_ok} of {len(ROWS)} as expected; written {args.out}")
    return 0 if n_ok == len(ROWS) else 1


if __name__ == "__main__":
    sys.exit(main())
