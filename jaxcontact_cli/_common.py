"""What the commands share: argument errors, number validation, the model options of
``simulate`` and ``sweep`` (`add_material_arguments`), output files and folders. The command
modules (``_demo``, ``_simulate`` with its BEM part ``_simulate_bem``, ``_sweep``, ``_fit``)
stand side by side over this module and never import each other.

Output policy (all commands): nothing is written before the inputs are checked and the work
is done; files are written under a temporary name beside the target and renamed into place
(one rename per file, or one per output folder), so a reader never sees a half-written file;
an interrupted run (Ctrl-C, SIGTERM) removes its temporary files
(:func:`register_cleanup`) and leaves what was there before untouched. Output files get
the ordinary mode (0666 less the umask). An output folder is replaced only when it is
empty or holds nothing but what an earlier run listed in its manifest (`OutputFolder`),
and only one run at a time may write it (a lock file beside it).
"""

from __future__ import annotations

import dataclasses
import math
import os
import pathlib
import shutil
import tempfile
import threading
import time
from collections.abc import Callable

__all__ = [
    "UsageError",
    "add_material_arguments",
    "check_number",
    "parse_assignments",
    "parse_profile",
    "PROFILE_SHAPES",
    "profile_help",
    "atomic_write_text",
    "OutputFolder",
    "register_cleanup",
    "run_cleanups",
    "note_written",
    "written_outputs",
    "temp_beside",
    "MANIFEST",
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


def add_material_arguments(p, *, radius_required: bool = True) -> None:
    """The model options shared by the commands ``simulate`` and ``sweep``. `radius_required`: False
    where another option can give the indenter (``simulate --profile``; then checked in
    `check_args`)."""
    p.add_argument("--G0", type=float, required=True, help="glass shear modulus [Pa]")
    p.add_argument("--G1", type=float, required=True, help="Kelvin-element shear modulus [Pa]")
    p.add_argument("--eta1", type=float, required=True, help="Kelvin-element viscosity [Pa s]")
    p.add_argument("--work-of-adhesion", type=float, required=True, help="Δγ [J/m^2]")
    p.add_argument("--radius", type=float, required=radius_required,
                   help="indenter radius of curvature R [m] (a paraboloid, the sphere "
                        "at small indentation)")
    p.add_argument("--depth", type=float, required=True, help="indentation before the lift [m]")
    p.add_argument("--velocity", type=float, required=True, help="lift speed [m/s], > 0")
    p.add_argument("--hold", type=float, default=None, help="hold at --depth [s] (full history)")
    p.add_argument(
        "--approach-velocity", type=float, default=None,
        help="approach speed [m/s] with --hold (default: --velocity)",
    )
    p.add_argument(
        "--stiffness", type=float, default=None,
        help=(
            "stiffness of a compliant loading system (cantilever) [N/m], with --hold: the "
            "approach-hold-lift history is then the drive position (0 where the undeflected "
            "indenter touches) and displacement_m the indentation"
        ),
    )


def add_process_arguments(p) -> None:
    """The options of a command that several processes can share (``jax.distributed``):
    ``--coordinator HOST:PORT --num-processes N --process-id I``, or ``--distributed``
    (the cluster's environment)."""
    p.add_argument("--coordinator", default=None, metavar="HOST:PORT",
                   help="several processes: the address of process 0 (jax.distributed)")
    p.add_argument("--num-processes", type=int, default=None, help="with --coordinator")
    p.add_argument("--process-id", type=int, default=None, help="with --coordinator")
    p.add_argument("--distributed", action="store_true",
                   help="several processes, configured from the cluster's environment "
                        "(SLURM, Open MPI, ...: jax.distributed.initialize())")


def check_process_arguments(args) -> None:
    """`UsageError` naming the option for inconsistent process options."""
    given = [args.num_processes is not None, args.process_id is not None]
    if args.coordinator is not None:
        if not all(given):
            raise UsageError("argument --coordinator: needs --num-processes and --process-id")
        host, sep, port = args.coordinator.rpartition(":")
        if not sep or not host or not port.isdigit():
            raise UsageError(f"argument --coordinator: expected HOST:PORT; got "
                             f"{args.coordinator!r}")
        if args.num_processes < 1:
            raise UsageError(f"argument --num-processes: must be >= 1; got {args.num_processes}")
        if not 0 <= args.process_id < args.num_processes:
            raise UsageError(f"argument --process-id: must lie in [0, {args.num_processes - 1}]; "
                             f"got {args.process_id}")
        if args.distributed:
            raise UsageError("argument --distributed: not together with --coordinator")
    elif any(given):
        raise UsageError("argument --num-processes/--process-id: need --coordinator")


def several_processes(args) -> bool:
    """Whether the process options ask for several processes."""
    return args.coordinator is not None or bool(args.distributed)


def start_processes(args) -> int:
    """``jax.distributed.initialize`` as the process options say (before any JAX
    computation); returns this process's index (0 with one process)."""
    import jax

    if args.coordinator is not None:
        jax.distributed.initialize(coordinator_address=args.coordinator,
                                   num_processes=args.num_processes,
                                   process_id=args.process_id)
    elif args.distributed:
        jax.distributed.initialize()
    return jax.process_index()


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


@dataclasses.dataclass(frozen=True)
class ProfileShape:
    """One indenter shape of ``--profile NAME:V1[,V2][,MODE]``: its values (`values`: per
    value its letter, unit and the keywords of :func:`check_number`), optional trailing
    words (`modes`, the first the default), what it means (`help`), how it is built
    (`build(values, mode) -> profile`) and whether it is the paraboloid (whose radius
    the fit reports)."""

    values: tuple[tuple[str, str, dict], ...]
    help: str
    build: Callable
    modes: tuple[str, ...] = ()
    paraboloid: bool = False

    def form(self, name: str) -> str:
        """``name:V1,V2[,mode|mode]`` as the options write it."""
        text = f"{name}:" + ",".join(v[0] for v in self.values)
        return text + (f"[,{'|'.join(self.modes)}]" if self.modes else "")


def _jc():
    import jaxcontact as jc

    return jc


_LENGTH = {"high": 1.0}
_ANGLE = {"high": 89.9}

#: The indenters of ``--profile``, by name: adding one here adds it to the option's
#: parsing, its checks, its help and its error messages.
PROFILE_SHAPES: dict[str, ProfileShape] = {
    "sphere": ProfileShape(
        (("R", "m", _LENGTH),), "exact sphere of radius R [m]",
        lambda v, _m: _jc().Sphere(R=v[0])),
    "paraboloid": ProfileShape(
        (("R", "m", _LENGTH),), "paraboloid of radius of curvature R [m], the "
        "small-indentation sphere", lambda v, _m: _jc().Parabola(R=v[0]), paraboloid=True),
    "cone": ProfileShape(
        (("DEG", "degrees", _ANGLE),), "cone of half-opening angle DEG",
        lambda v, _m: _jc().Cone(half_angle=math.radians(v[0]))),
    "pyramid4": ProfileShape(
        (("DEG", "degrees", _ANGLE),), "regular 4-sided pyramid by its half-angle to a face "
        "(default) or an edge, as the equivalent cone",
        lambda v, m: _jc().pyramid(math.radians(v[0]), sides=4, angle=m),
        modes=("face", "edge")),
    "pyramid3": ProfileShape(
        (("DEG", "degrees", _ANGLE),), "regular 3-sided pyramid, likewise",
        lambda v, m: _jc().pyramid(math.radians(v[0]), sides=3, angle=m),
        modes=("face", "edge")),
    "flat": ProfileShape(
        (("A", "m", _LENGTH),), "flat punch of radius A [m]",
        lambda v, _m: _jc().FlatPunch(radius=v[0])),
    "power": ProfileShape(
        (("C", "m^(1-N)", {}), ("N", "1", {"low": 1.0, "low_open": False, "high": 20.0})),
        "power law f = C r^N", lambda v, _m: _jc().PowerLaw(c=v[0], n=v[1])),
}


def profile_forms() -> str:
    """The shapes as the messages list them: ``sphere:R, ..., flat:A or power:C,N``."""
    forms = [shape.form(name) for name, shape in PROFILE_SHAPES.items()]
    return ", ".join(forms[:-1]) + " or " + forms[-1]


def profile_help() -> str:
    """The help text of ``--profile``, from :data:`PROFILE_SHAPES`."""
    return "indenter: " + "; ".join(f"{shape.form(name)} ({shape.help})"
                                    for name, shape in PROFILE_SHAPES.items())


def parse_profile(spec: str | None, radius: float | None):
    """The indenter of ``--profile`` / ``--radius`` as a jaxcontact profile.

    The shapes of :data:`PROFILE_SHAPES`: ``sphere:R`` (the exact sphere of radius R [m],
    `jc.Sphere`), ``paraboloid:R`` (`jc.Parabola`, the small-indentation sphere),
    ``cone:DEG`` (half-opening angle [degrees]), ``pyramid4:DEG[,face|edge]`` and
    ``pyramid3:DEG[,face|edge]`` (`jc.pyramid`, the equivalent cone), ``flat:A`` (flat
    punch of radius A [m]), ``power:C,N`` (f = C r^N, C in m^(1-N)).
    ``--radius R`` alone is ``paraboloid:R`` (as before the exact sphere existed, so that
    earlier results are reproduced); giving both is an error (they could disagree).
    Returns ``(profile, radius_or_None)``: the radius only for the paraboloid.
    """
    if spec is None:
        if radius is None:
            raise UsageError("argument --radius/--profile: give the indenter, e.g. "
                             "--radius 5e-6 or --profile cone:35")
        check_number("--radius", radius, "m")
        if radius > 1.0:
            raise UsageError(f"argument --radius: {radius} m looks like a unit mistake "
                             "(lengths are in metres, e.g. 5e-6 for 5 µm)")
        return _jc().Parabola(R=float(radius)), float(radius)
    if radius is not None:
        raise UsageError("argument --radius: not together with --profile (use paraboloid:R "
                         "or sphere:R)")
    kind, _, rest = spec.partition(":")
    tokens = rest.split(",") if rest else []
    shape = PROFILE_SHAPES.get(kind)
    mode = shape.modes[0] if shape is not None and shape.modes else None
    if (shape is not None and shape.modes and len(tokens) == len(shape.values) + 1
            and tokens[-1].strip() in shape.modes):
        mode = tokens.pop().strip()
    try:
        vals = [float(x) for x in tokens]
    except ValueError:
        raise UsageError(f"argument --profile: bad numbers in {spec!r}") from None
    if shape is None:
        raise UsageError(f"argument --profile: unknown shape {kind!r}; use {profile_forms()}")
    n = len(shape.values)
    if len(vals) != n:
        raise UsageError(f"argument --profile: {kind} takes {n} number(s); got {spec!r}")
    for (label, unit, limits), value in zip(shape.values, vals, strict=True):
        check_number(f"--profile {kind}:{label}", value, unit, **limits)
    return shape.build(vals, mode), (vals[0] if shape.paraboloid else None)


# --------------------------------------------------------------------------------------
# cleanup of temporary outputs on interruption, and what was written
# --------------------------------------------------------------------------------------

_CLEANUPS: list[Callable[[], None]] = []
_LOCK = threading.Lock()
#: held while an output is renamed into place: an interruption waits for it (the renames
#: take microseconds), so an output is never half swapped
COMMIT_GUARD = threading.RLock()
_WRITTEN: list[str] = []


def register_cleanup(fn: Callable[[], None]) -> Callable[[], None]:
    """Run `fn` if the command is interrupted; returns a function that unregisters it."""
    with _LOCK:
        _CLEANUPS.append(fn)

    def forget() -> None:
        with _LOCK:
            if fn in _CLEANUPS:
                _CLEANUPS.remove(fn)

    return forget


def pending_cleanups() -> list[Callable[[], None]]:
    """The cleanups registered now (to run only those a command adds, see `run_cleanups`)."""
    with _LOCK:
        return list(_CLEANUPS)


def run_cleanups(keep: list[Callable[[], None]] | None = None) -> None:
    """Remove every registered temporary output and lock (on Ctrl-C / SIGTERM, and when a
    command ends), except those in `keep` (registered before the command started); waits
    for an output being renamed into place."""
    with COMMIT_GUARD:
        with _LOCK:
            fns = [f for f in _CLEANUPS if keep is None or f not in keep]
            for f in fns:
                _CLEANUPS.remove(f)
        for fn in fns:
            try:
                fn()
            except OSError:
                pass


def note_written(path) -> None:
    """Record that `path` (a file or folder) was written completely (renamed into place)."""
    with _LOCK:
        _WRITTEN.append(str(path))


def written_outputs() -> list[str]:
    """The outputs this process has written completely, in order (see `note_written`)."""
    with _LOCK:
        return list(_WRITTEN)


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


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def temp_beside(path, suffix: str = ".tmp") -> tuple[str, Callable[[], None]]:
    """A new empty temporary file beside `path` with an ordinary file's mode (0666 less the
    umask, as `open` gives; `mkstemp` alone makes it private), removed if the command is
    interrupted. Returns the temporary path and the function that unregisters its removal."""
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=suffix)
    os.close(fd)
    os.chmod(tmp, 0o666 & ~_umask())
    forget = register_cleanup(lambda: os.path.exists(tmp) and os.unlink(tmp))
    return tmp, forget


def atomic_write_text(path, text: str) -> None:
    """Write `text` to `path` through a temporary file in the same folder and one rename
    (the file gets the ordinary mode, 0666 less the umask)."""
    path = pathlib.Path(path)
    tmp, forget = temp_beside(path)
    try:
        with open(tmp, "w", newline="") as fh:
            fh.write(text)
        with COMMIT_GUARD:
            os.replace(tmp, path)
            note_written(path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
        forget()


#: The file in every output folder that lists the files jaxcontact wrote there.
MANIFEST = ".jaxcontact-manifest.json"


def _listed_files(folder: pathlib.Path) -> set[str] | None:
    """The names `folder`'s manifest lists as written by jaxcontact (None: no valid one)."""
    import json

    try:
        doc = json.loads((folder / MANIFEST).read_text())
    except (OSError, ValueError):
        return None
    files = doc.get("files") if isinstance(doc, dict) else None
    if (not isinstance(doc, dict) or doc.get("written_by") != "jaxcontact"
            or not isinstance(files, list) or not all(isinstance(f, str) for f in files)):
        return None
    return {f for f in files if f and "/" not in f and f not in (".", "..")}


def foreign_entries(folder: pathlib.Path) -> list[str]:
    """The entries of an existing folder that jaxcontact did not write: every entry when it
    holds no manifest, else those the manifest does not list (a listed name that is now a
    folder counts as foreign too). Empty: the folder may be replaced."""
    entries = sorted(e.name for e in folder.iterdir())
    listed = _listed_files(folder)
    if listed is None:
        return entries
    return [e for e in entries
            if e != MANIFEST and (e not in listed or (folder / e).is_dir()
                                  and not (folder / e).is_symlink())]


def _pid_alive(pid: int) -> bool:
    if os.name != "posix":  # pragma: no cover - os.kill(pid, 0) is no probe there
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


class _WriteLock:
    """An exclusive lock on an output path: the file ``.NAME.lock`` beside it, created with
    ``O_EXCL`` and holding the owner's pid and host. A lock whose process is gone (same
    host) is stale and taken over; one of a live process is refused (`UsageError`)."""

    def __init__(self, option: str, target: pathlib.Path):
        self.path = target.with_name(f".{target.name}.lock")
        self._forget = None
        import socket

        me = f"{os.getpid()} {socket.gethostname()}\n"
        for _ in range(3):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                if self._stale(socket.gethostname()):
                    try:
                        os.unlink(self.path)
                    except FileNotFoundError:
                        pass
                    continue
                raise UsageError(
                    f"argument {option}: {target} is being written by another jaxcontact run "
                    f"({self._owner()}); wait for it to finish or choose another folder (if no "
                    f"such run exists, remove {self.path})") from None
            except OSError as exc:
                raise UsageError(f"argument {option}: cannot create the lock file {self.path} "
                                 f"({exc.strerror})") from None
            with os.fdopen(fd, "w") as fh:
                fh.write(me)
            self._forget = register_cleanup(self.release)
            return
        raise UsageError(f"argument {option}: cannot take the lock {self.path} (it keeps "
                         "reappearing: another run is starting)")

    def _read(self) -> tuple[int | None, str | None, float]:
        try:
            text = self.path.read_text()
            age = time.time() - self.path.stat().st_mtime
        except OSError:
            return None, None, 0.0
        parts = text.split()
        try:
            return int(parts[0]), (parts[1] if len(parts) > 1 else None), age
        except (IndexError, ValueError):
            return None, None, age

    def _owner(self) -> str:
        pid, host, _ = self._read()
        return f"pid {pid} on {host}" if pid is not None else f"lock file {self.path}"

    def _stale(self, host: str) -> bool:
        pid, owner_host, age = self._read()
        if pid is None:  # empty or garbled: a run that is just writing it, unless old
            return age > 60.0
        if owner_host not in (None, host):  # another machine (shared file system): unknown
            return False
        return not _pid_alive(pid)

    def release(self) -> None:
        if self._forget is not None:
            self._forget()
            self._forget = None
            try:
                os.unlink(self.path)
            except FileNotFoundError:
                pass


class OutputFolder:
    """An output folder written all at once: every file or none, no stale files, and never
    a file that jaxcontact did not write deleted.

    Checked at construction (before any work): the option must name a folder we may create
    or replace, and no other run may be writing it (a lock file ``.NAME.lock`` beside it,
    see `_WriteLock`; released when the output is committed or discarded, or the command
    ends). A folder that exists must be empty or an earlier jaxcontact output whose every
    entry its manifest (`MANIFEST`, written with the outputs) lists; anything else (a
    user's ``raw/`` or ``.git/``, or an output of an older version without a manifest) is
    refused rather than mixed with or deleted. :meth:`stage` returns a fresh temporary
    folder beside the target; :meth:`commit` writes the manifest of what is in it and swaps
    it in (the previous output's listed files are removed only after the new one is in
    place); :meth:`discard` removes the staging folder. Interruptions remove it too.
    """

    def __init__(self, option: str, path, *, command: str):
        if path is None or str(path).strip() == "":
            raise UsageError(f"argument {option}: give a folder name")
        self.option = option
        self.path = pathlib.Path(path)
        self.command = command
        if self.path.exists() and not self.path.is_dir():
            raise UsageError(f"argument {option}: {self.path} exists and is not a folder")
        _check_writable_dir(option, self.path.resolve().parent)
        self._tmp: pathlib.Path | None = None
        self._forget = None
        self._committed = False
        parent = self.path.resolve().parent
        self._made = []  # the folders made for the lock, deepest first: removed unless used
        probe = parent
        while not probe.exists():
            self._made.append(probe)
            probe = probe.parent
        parent.mkdir(parents=True, exist_ok=True)
        try:
            self._lock = _WriteLock(option, self.path.resolve())
        except UsageError:
            self._unmake()
            raise
        self._forget_unmake = register_cleanup(self._unmake)
        try:
            self._check_replaceable("")
        except UsageError:
            self._done()
            raise

    def _unmake(self) -> None:
        """Remove the (empty) folders made for this output, unless it was written."""
        if self._committed:
            return
        for folder in self._made:
            try:
                folder.rmdir()
            except OSError:
                break

    def _check_replaceable(self, when: str) -> None:
        if not self.path.is_dir():
            if self.path.exists() or self.path.is_symlink():
                raise UsageError(f"argument {self.option}: {self.path} exists and is not a "
                                 f"folder{when}")
            return
        foreign = foreign_entries(self.path)
        if foreign:
            shown = ", ".join(foreign[:5]) + (f" and {len(foreign) - 5} more"
                                              if len(foreign) > 5 else "")
            older = ("" if _listed_files(self.path) is not None else
                     f" (it has no {MANIFEST}: an output written before jaxcontact kept "
                     "manifests is not recognised either; remove it yourself if it is one)")
            raise UsageError(
                f"argument {self.option}: {self.path} holds entries jaxcontact did not write "
                f"({shown}){when}; an output folder is replaced whole, so it must be new, "
                f"empty or an earlier jaxcontact output (every entry listed in its "
                f"{MANIFEST}){older}; choose a new folder")

    def stage(self) -> pathlib.Path:
        parent = self.path.resolve().parent
        parent.mkdir(parents=True, exist_ok=True)
        self._tmp = pathlib.Path(tempfile.mkdtemp(prefix=f".{self.path.name}.tmp-",
                                                  dir=parent))
        tmp = self._tmp
        os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes it private; outputs are ordinary
        self._forget = register_cleanup(lambda: shutil.rmtree(tmp, ignore_errors=True))
        return tmp

    def commit(self) -> pathlib.Path:
        """Write the manifest of the staged files and rename the staging folder into place.
        Raises `UsageError` (and replaces nothing) if entries that jaxcontact did not write
        appeared in the target during the run."""
        import json

        from jaxcontact import __version__

        assert self._tmp is not None, "stage() first"
        files = sorted(e.name for e in self._tmp.iterdir() if e.name != MANIFEST)
        doc = {"written_by": "jaxcontact", "command": self.command, "version": __version__,
               "files": files}
        (self._tmp / MANIFEST).write_text(json.dumps(doc, indent=1) + "\n")
        target = self.path.resolve()
        with COMMIT_GUARD:
            self._check_replaceable(" (they appeared while this run worked; nothing was "
                                    "replaced)")
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
            note_written(self.path)
            self._committed = True
            self._done()
        if old is not None:
            self._remove_old(old)
        return self.path

    @staticmethod
    def _remove_old(old: pathlib.Path) -> None:
        """Remove the previous output: only the files its manifest lists, then the folder
        (left in place, as a hidden folder beside the output, if anything else is in it)."""
        listed = _listed_files(old) or set()
        for name in listed | {MANIFEST}:
            p = old / name
            if p.is_symlink() or p.is_file():
                try:
                    p.unlink()
                except OSError:
                    pass
        try:
            old.rmdir()
        except OSError:
            pass

    def discard(self) -> None:
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
        self._done()

    def _done(self) -> None:
        if self._forget is not None:
            self._forget()
        self._tmp = None
        self._forget = None
        self._lock.release()
        self._forget_unmake()
        self._unmake()
