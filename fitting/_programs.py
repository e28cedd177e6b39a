"""An on-disk cache of traced programs (:func:`cached`): the one home of keeping a traced
search across processes.

JAX's persistent compilation cache (``jax_compilation_cache_dir``, which ``jaxcontact
fit`` turns on) keeps the XLA executables of a run, but every process still traces the
Python that produces the program before it can look one up: for the full-history model's
search that is the largest part of a repeated ``jaxcontact fit`` of the README's main job
after the search itself (``benchmarks/results/fit_each.md``, "A cold fit" and "Repeated
runs"). :func:`cached` keeps the traced and lowered
program instead (``jax.export``: StableHLO, serialised with ``flatbuffers``), keyed by
everything the trace depends on: the program's name and static options, the structure,
shapes and dtypes of its arguments, the versions of jax and jaxlib, the source of the
``jaxcontact`` and ``fitting`` packages (a changed file is a new key: no stale program),
the backend and its device kind, 64-bit mode, ``XLA_FLAGS`` and whether branches
no lane takes are skipped (``jaxcontact._sharding.LANE_BRANCHES``). A later process with the
same key deserialises it (milliseconds) and JAX compiles it, or finds its executable in
the persistent cache. The results are those of the traced program, to the bit (the same
StableHLO; ``tests/test_fitting_each.py``).

Off unless :func:`enable` names a folder (the command line does, beside the compilation
cache); off as well without ``flatbuffers``. Files are written whole or not at all (a
temporary file renamed into place); one that cannot be read is traced again and
replaced.
"""

from __future__ import annotations

import functools
import hashlib
import os
import pathlib
import tempfile
import threading
from collections.abc import Callable

import jax

from jaxcontact import _sharding

__all__ = ["cached", "enable"]

_DIR: pathlib.Path | None = None
_LOADED: dict[tuple, Callable] = {}  # this process's programs, by file and XLA options
_LOCK = threading.Lock()  # one thread loads or traces a program; the others then find it


def enable(path) -> bool:
    """Keep traced programs in the folder `path` (made if need be); `None`: off. Returns
    whether the cache is on (it needs ``flatbuffers``, the serialisation of
    ``jax.export``)."""
    global _DIR
    _LOADED.clear()
    if path is None:
        _DIR = None
        return False
    try:
        import flatbuffers  # noqa: F401 - jax.export's serialisation needs it
    except ImportError:
        _DIR = None
        return False
    path = pathlib.Path(path)
    path.mkdir(parents=True, exist_ok=True)
    _DIR = path
    return True


@functools.lru_cache(maxsize=1)
def _source_hash() -> str:
    """SHA-256 of the Python source of the packages a traced program comes from."""
    import jaxcontact

    h = hashlib.sha256()
    for pkg in (pathlib.Path(jaxcontact.__file__).parent, pathlib.Path(__file__).parent):
        for f in sorted(pkg.rglob("*.py")):
            h.update(str(f.relative_to(pkg.parent)).encode())
            h.update(f.read_bytes())
    return h.hexdigest()


def _key(name: str, treedef, leaves, static: dict) -> str:
    import jaxlib

    device = jax.devices()[0]
    parts = [name, jax.__version__, jaxlib.__version__, _source_hash(), str(treedef),
             repr([str(jax.typeof(x)) for x in leaves]), repr(sorted(static.items())),
             jax.default_backend(), getattr(device, "device_kind", ""),
             str(jax.config.jax_enable_x64), os.environ.get("XLA_FLAGS", ""),
             f"lane_branches={_sharding.LANE_BRANCHES}"]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:32]


def cached(name: str, fn: Callable, args: tuple, static: dict, *,
           flatten_out: Callable, unflatten_out: Callable,
           compiler_options: dict | None = None) -> Callable | None:
    """`None` when the cache is off; else a function of no arguments that returns
    `fn(*args, **static)` (`fn` jitted with `static` as its static keywords) through the
    traced program kept on disk: loaded when its key (module docstring) is there, else
    traced and written now. `flatten_out(out)` gives the outputs as a tuple of arrays (or
    `None`), `unflatten_out(tuple)` the outputs back (the cache keeps no Python types).
    `compiler_options`: XLA's options for compiling the program (those `fn` compiles with;
    :func:`fitting._xla.program_options`)."""
    if _DIR is None:
        return None
    leaves, treedef = jax.tree.flatten(args)
    path = _DIR / f"{name}-{_key(name, treedef, leaves, static)}.jaxexport"
    options = tuple(sorted((compiler_options or {}).items()))
    with _LOCK:  # (threads searching chunks at once: one trace, one program)
        run = _LOADED.get((path, options))
        if run is None:
            run = _load(name, fn, path, options, treedef, leaves, static, flatten_out)
    return lambda: unflatten_out(run(*leaves))


def _load(name, fn, path, options, treedef, leaves, static, flatten_out) -> Callable:
    """The program of `path` (loaded, or traced and written), jitted with `options`."""
    exported = None
    if path.exists():
        try:
            exported = jax.export.deserialize(bytearray(path.read_bytes()))
        except Exception:  # noqa: BLE001 - a damaged file: traced again and replaced
            exported = None
    if exported is None:
        def flat(*xs):
            return flatten_out(fn(*jax.tree.unflatten(treedef, xs), **static))

        exported = jax.export.export(jax.jit(flat))(*leaves)
        try:
            fd, tmp = tempfile.mkstemp(dir=_DIR, prefix=f".{name}-", suffix=".tmp")
            with os.fdopen(fd, "wb") as fh:
                fh.write(exported.serialize())
            os.replace(tmp, path)
        except OSError:  # a read-only or full disk: the cache is an optimisation only
            try:
                os.unlink(tmp)
            except (OSError, UnboundLocalError):
                pass
    run = _LOADED[path, options] = jax.jit(exported.call,
                                           compiler_options=dict(options) or None)
    return run
