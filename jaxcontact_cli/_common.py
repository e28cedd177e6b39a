"""What every command shares: argument errors, number validation, output files and folders.

Output policy (all commands): nothing is written before the inputs are checked and the work
is done; files are written under a temporary name beside the target and renamed into place
(one rename per file, or one per output folder), so a reader never sees a half-written file;
an interrupted run (Ctrl-C, SIGTERM) removes its temporary files
(:func:`register_cleanup`) and leaves what was there before untouched.
"""

from __future__ import annotations

import math
import os
import pathlib
import shutil
import tempfile
import threading
from collections.abc import Callable

__all__ = [
    "UsageError",
    "check_number",
    "parse_assignments",
    "parse_profile",
    "atomic_write_text",
    "OutputFolder",
    "register_cleanup",
    "run_cleanups",
]


class UsageError(Exception):
    """A bad command-line argument (exit status 2); the message names the argument."""


# --------------------------------------------------------------------------------------
# numbers
# --------------------------------------------------------------------------------------


def check_number(name: str, value, unit: str, *, low: float = 0.0, low_open: bool = True,
                 high: float = math.inf) -> None:
    """Raise `UsageError` unless `value` is a finite number in the stated interval.

    `None` passes (an option not given). The message names the option, the interval and the
    unit, e.g. ``argument --G0: must be a finite number in (0, inf) [Pa]; got -1.0``.
    """
    if value is None:
        return
    ok = isinstance(value, int | float) and math.isfinite(value)
    ok = ok and (value > low if low_open else value >= low) and value <= high
    if not ok:
        left = "(" if low_open else "["
        right = "]" if math.isfinite(high) else ")"
        hi = f"{high:g}" if math.isfinite(high) else "inf"
        raise UsageError(f"argument {name}: must be a finite number in {left}{low:g}, {hi}"
                         f"{right} [{unit}]; got {value}")


def parse_assignments(option: str, items, *, ranges: bool = False) -> dict:
    """``NAME=VALUE`` (or ``NAME=LO:HI`` with `ranges`) strings into a dict of floats."""
    out: dict = {}
    for item in items or ():
        name, sep, rhs = item.partition("=")
        name = name.strip()
        if not sep or not name:
            form = "NAME=LO:HI" if ranges else "NAME=VALUE"
            raise UsageError(f"argument {option}: expected {form}; got {item!r}")
        try:
            if ranges:
                lo, sep2, hi = rhs.partition(":")
                if not sep2:
                    raise ValueError
                value = (float(lo), float(hi))
                if not all(math.isfinite(v) for v in value) or not value[0] < value[1]:
                    raise UsageError(f"argument {option}: {name}: need finite LO < HI; "
                                     f"got {rhs!r}")
            else:
                value = float(rhs)
                if not math.isfinite(value):
                    raise UsageError(f"argument {option}: {name}: must be finite; got {rhs!r}")
        except ValueError:
            form = "LO:HI" if ranges else "a number"
            raise UsageError(f"argument {option}: {name}: expected {form}; got {rhs!r}") from None
        if name in out:
            raise UsageError(f"argument {option}: {name} given twice")
        out[name] = value
    return out


def parse_profile(spec: str | None, radius: float | None):
    """The indenter of ``--profile`` / ``--radius`` as a jaxcontact profile.

    ``sphere:R`` (the exact sphere of radius R [m], `jc.Sphere`), ``paraboloid:R``
    (paraboloid of radius of curvature R [m], the small-indentation sphere, `jc.Parabola`),
    ``cone:DEG`` (half-opening angle [degrees]), ``pyramid4:DEG[,face|edge]`` and
    ``pyramid3:DEG[,face|edge]`` (regular 4- or 3-sided pyramid by its half-angle [degrees]
    to a face (default) or an edge, as the equivalent cone, `jc.pyramid`), ``flat:A`` (flat
    punch of radius A [m]), ``power:C,N`` (f = C r^N, C in m^(1-N)).
    ``--radius R`` alone is ``paraboloid:R`` (as before the exact sphere existed, so that
    earlier results are reproduced); giving both is an error (they could disagree).
    Returns ``(profile, radius_or_None)``: the radius only for the paraboloid.
    """
    import jaxcontact as jc

    shapes = ("sphere:R, paraboloid:R, cone:DEG, pyramid4:DEG[,face|edge], "
              "pyramid3:DEG[,face|edge], flat:A or power:C,N")
    if spec is None:
        if radius is None:
            raise UsageError("argument --radius/--profile: give the indenter, e.g. "
                             "--radius 5e-6 or --profile cone:35")
        check_number("--radius", radius, "m")
        if radius > 1.0:
            raise UsageError(f"argument --radius: {radius} m looks like a unit mistake "
                             "(lengths are in metres, e.g. 5e-6 for 5 µm)")
        return jc.Parabola(R=float(radius)), float(radius)
    if radius is not None:
        raise UsageError("argument --radius: not together with --profile (use paraboloid:R "
                         "or sphere:R)")
    kind, _, rest = spec.partition(":")
    tokens = rest.split(",") if rest else []
    angle = "face"
    if kind in ("pyramid3", "pyramid4") and len(tokens) == 2 and tokens[1].strip() in (
            "face", "edge"):
        angle = tokens.pop().strip()
    try:
        vals = [float(x) for x in tokens]
    except ValueError:
        raise UsageError(f"argument --profile: bad numbers in {spec!r}") from None
    want = {"sphere": 1, "paraboloid": 1, "cone": 1, "pyramid3": 1, "pyramid4": 1, "flat": 1,
            "power": 2}
    if kind not in want:
        raise UsageError(f"argument --profile: unknown shape {kind!r}; use {shapes}")
    if len(vals) != want[kind]:
        raise UsageError(f"argument --profile: {kind} takes {want[kind]} number(s); got {spec!r}")
    if kind == "sphere":
        check_number("--profile sphere:R", vals[0], "m", high=1.0)
        return jc.Sphere(R=vals[0]), None
    if kind == "paraboloid":
        check_number("--profile paraboloid:R", vals[0], "m", high=1.0)
        return jc.Parabola(R=vals[0]), vals[0]
    if kind == "cone":
        check_number("--profile cone:DEG", vals[0], "degrees", high=89.9)
        return jc.Cone(half_angle=math.radians(vals[0])), None
    if kind in ("pyramid3", "pyramid4"):
        check_number(f"--profile {kind}:DEG", vals[0], "degrees", high=89.9)
        return jc.pyramid(math.radians(vals[0]), sides=int(kind[-1]), angle=angle), None
    if kind == "flat":
        check_number("--profile flat:A", vals[0], "m", high=1.0)
        return jc.FlatPunch(radius=vals[0]), None
    check_number("--profile power:C", vals[0], "m^(1-N)")
    check_number("--profile power:N", vals[1], "1", low=1.0, low_open=False, high=20.0)
    return jc.PowerLaw(c=vals[0], n=vals[1]), None


# --------------------------------------------------------------------------------------
# cleanup of temporary outputs on interruption
# --------------------------------------------------------------------------------------

_CLEANUPS: list[Callable[[], None]] = []
_LOCK = threading.Lock()


def register_cleanup(fn: Callable[[], None]) -> Callable[[], None]:
    """Run `fn` if the command is interrupted; returns a function that unregisters it."""
    with _LOCK:
        _CLEANUPS.append(fn)

    def forget() -> None:
        with _LOCK:
            if fn in _CLEANUPS:
                _CLEANUPS.remove(fn)

    return forget


def run_cleanups() -> None:
    """Remove every registered temporary output (called on Ctrl-C / SIGTERM)."""
    with _LOCK:
        fns = list(_CLEANUPS)
        _CLEANUPS.clear()
    for fn in fns:
        try:
            fn()
        except OSError:
            pass


# --------------------------------------------------------------------------------------
# files and folders
# --------------------------------------------------------------------------------------


def check_output_file(option: str, path) -> pathlib.Path:
    """Check before any work that `path` can be written as a file; returns it as a Path."""
    if path is None or str(path).strip() == "":
        raise UsageError(f"argument {option}: give a file name")
    p = pathlib.Path(path)
    if p.is_dir():
        raise UsageError(f"argument {option}: {p} is a folder; give a file name")
    _check_writable_dir(option, p.resolve().parent)
    return p


def _check_writable_dir(option: str, parent: pathlib.Path) -> None:
    probe = parent
    while not probe.exists():  # the first existing ancestor must let us create the rest
        probe = probe.parent
    if not probe.is_dir():
        raise UsageError(f"argument {option}: {probe} is not a folder")
    try:
        fd, tmp = tempfile.mkstemp(dir=probe, prefix=".jaxcontact-probe-")
        os.close(fd)
        os.unlink(tmp)
    except OSError as exc:
        raise UsageError(f"argument {option}: cannot write in {probe} ({exc.strerror})") from None


def atomic_write_text(path, text: str) -> None:
    """Write `text` to `path` through a temporary file in the same folder and one rename."""
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    forget = register_cleanup(lambda: os.path.exists(tmp) and os.unlink(tmp))
    try:
        with os.fdopen(fd, "w", newline="") as fh:
            fh.write(text)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
        forget()


class OutputFolder:
    """An output folder written all at once: every file or none, no stale files.

    Checked at construction (before any work): the option must name a folder we may create
    or replace. A folder that exists must be empty or an earlier output of the same command
    (it holds `marker`); anything else is refused rather than mixed with or deleted.
    :meth:`stage` returns a fresh temporary folder beside the target; :meth:`commit` swaps
    it in (the previous output is removed only after the new one is in place);
    :meth:`discard` removes the staging folder. Interruptions remove it too.
    """

    def __init__(self, option: str, path, *, marker: str):
        if path is None or str(path).strip() == "":
            raise UsageError(f"argument {option}: give a folder name")
        self.option = option
        self.path = pathlib.Path(path)
        self.marker = marker
        if self.path.exists():
            if not self.path.is_dir():
                raise UsageError(f"argument {option}: {self.path} exists and is not a folder")
            entries = [e.name for e in self.path.iterdir()]
            if entries and marker not in entries:
                raise UsageError(
                    f"argument {option}: {self.path} is not empty and holds no {marker} from an "
                    "earlier run; choose a new folder (it would be replaced)")
        _check_writable_dir(option, self.path.resolve().parent)
        self._tmp: pathlib.Path | None = None
        self._forget = None

    def stage(self) -> pathlib.Path:
        parent = self.path.resolve().parent
        parent.mkdir(parents=True, exist_ok=True)
        self._tmp = pathlib.Path(tempfile.mkdtemp(prefix=f".{self.path.name}.tmp-",
                                                  dir=parent))
        tmp = self._tmp
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)  # mkdtemp makes it private; outputs are ordinary folders
        self._forget = register_cleanup(lambda: shutil.rmtree(tmp, ignore_errors=True))
        return tmp

    def commit(self) -> pathlib.Path:
        assert self._tmp is not None, "stage() first"
        target = self.path.resolve()
        old = None
        if target.exists():
            old = target.with_name(f".{target.name}.old-{os.getpid()}")
            os.replace(target, old)
        try:
            os.replace(self._tmp, target)
        except OSError:
            if old is not None:
                os.replace(old, target)
            raise
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        self._done()
        return self.path

    def discard(self) -> None:
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
        self._done()

    def _done(self) -> None:
        if self._forget is not None:
            self._forget()
        self._tmp = None
        self._forget = None
