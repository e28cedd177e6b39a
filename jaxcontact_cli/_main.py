"""The ``jaxcontact`` command: parser, dispatch, errors and interruption.

Exit status: 0 success; 1 the work failed (a simulation that ended in an error state, an
unexpected error); 2 bad arguments or input data (the message names the option or the
file); 3 a fit written but not converged (its best point, ``"converged": false``), or a map
with curves that did not converge or failed (``jaxcontact_cli._fit.EXIT_NOT_CONVERGED``);
130/143 interrupted by Ctrl-C/SIGTERM. Every error is one
line on stderr; ``--debug`` adds the traceback. Progress and logs go to stderr; with
``--json`` stdout carries only the JSON document.

Interruption: the command runs in a worker thread while the main thread waits, so Ctrl-C
and SIGTERM are handled at once, also while XLA compiles: the temporary outputs are removed
(outputs are only ever renamed into place when complete, see :mod:`._common`) and the
process ends without waiting for the compiler. The message says what was complete: nothing,
or (for a signal after an output was renamed into place) the outputs written.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import sys
import threading
import traceback

from ._common import UsageError, pending_cleanups, run_cleanups, written_outputs

__all__ = ["main", "console_main", "build_parser"]


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


class _Parser(argparse.ArgumentParser):
    """An `argparse.ArgumentParser` that reads every negative number as a value, not an
    option: argparse (before Python 3.13) takes ``--radius -1e-5`` for an option
    ``-1e-5`` and says "expected one argument"; the value then reaches the command's own
    range check, whose message names the option and the allowed range. A range that starts
    with a negative number (``--indentation-range -1e-7:2e-6``) is a value too. (No option
    of the command line looks like a negative number.)"""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = _NEGATIVE_NUMBER


_NEGATIVE_NUMBER = re.compile(
    r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?(:.*)?$|^-(inf|infinity|nan)(:.*)?$", re.IGNORECASE)


def build_parser() -> argparse.ArgumentParser:
    from . import _demo, _fit, _simulate, _sweep

    parser = _Parser(
        prog="jaxcontact",
        description=(
            "Adhesive contact of viscoelastic bodies (MDR, energetic detachment criterion): "
            "forward simulation, sweeps and parameter identification. SI units throughout."
        ),
    )
    from jaxcontact import __version__  # imports jax: after the signal handlers are set

    parser.add_argument("--version", action="version", version=f"jaxcontact {__version__}")
    common = _Parser(add_help=False)
    common.add_argument("--debug", action="store_true",
                        help="show the Python traceback of an error")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module in (_demo, _simulate, _sweep, _fit):
        module.add_parser(sub, common)
    return parser


def _dispatch(args: argparse.Namespace) -> int:
    name = f"jaxcontact {args.command}"
    before = pending_cleanups()
    try:
        return int(args.func(args) or 0)
    except UsageError as err:
        _log(f"{name}: error: {err}")
        return 2
    except (KeyboardInterrupt, SystemExit):
        run_cleanups()
        raise
    except ValueError as err:  # the library's validation names the parameter or the file
        if getattr(args, "debug", False):
            traceback.print_exc()
        _log(f"{name}: error: {_one_line(err)}")
        return 2
    except BaseException as err:  # noqa: BLE001 - afmformats raises BaseException subclasses
        run_cleanups()
        if getattr(args, "debug", False):
            traceback.print_exc()
        _log(f"{name}: error: {type(err).__name__}: {_one_line(err)} "
             "(run with --debug for the traceback)")
        return 1
    finally:
        run_cleanups(keep=before)  # what the command left registered: its output locks


def _one_line(err: BaseException) -> str:
    text = " ".join(str(err).split())
    return text if len(text) <= 600 else text[:597] + "..."


#: Commands that run with `fitting.XLA_CPU_FLAGS` (for the whole process), and for which
#: models: the older CPU code generator makes the full-history model's fit faster, but the
#: relaxed model's search and the forward models slower (benchmarks/results/forward.md,
#: section 3; fit_each.md, "XLA's code generator chosen per model"), so `simulate`,
#: `sweep`, `demo` and relaxed-model fits keep XLA's default (a fit's search programs
#: choose per model anyway: `fitting._xla.program_options`).
TUNED_COMMANDS = {"fit": frozenset({"history"})}


def _parse(argv) -> argparse.Namespace | int:
    from fitting import tune_xla_cpu

    parser = build_parser()  # imports jax without starting its backend
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help(sys.stderr)
        return 2
    if getattr(args, "model", None) in TUNED_COMMANDS.get(args.command, ()):
        tune_xla_cpu()
    return args


def main(argv: list[str] | None = None) -> int:
    """Run the command line in the calling thread; returns the exit status.

    For use from Python (tests, notebooks): an interruption raises `KeyboardInterrupt`
    after the temporary outputs are removed. The console script uses :func:`console_main`.
    """
    args = _parse(argv)
    if isinstance(args, int):
        return args
    return _dispatch(args)


def interrupted_message() -> str:
    """What an interruption leaves: the outputs already complete (renamed into place), or
    that nothing was written or changed."""
    done = written_outputs()
    if not done:
        return "interrupted; no output was written or changed"
    return (f"interrupted after the output was complete: wrote {', '.join(done)}; "
            "nothing else was written or changed")


class _Terminated(Exception):
    pass


_SIGNALLED: list[int] = []
_RAISE = [False]


def _on_signal(signum, frame):  # pragma: no cover - exercised in a subprocess test
    # recorded, and raised only once the imports are done: an exception raised into an
    # extension module while it initialises can crash the interpreter (SIGSEGV) or be
    # swallowed by a library's bare `except:`; the command checks the record after them
    _SIGNALLED.append(signum)
    if _RAISE[0]:
        raise _Terminated if signum == signal.SIGTERM else KeyboardInterrupt


def _interrupted(command: str, signum: int):  # pragma: no cover - subprocess tests
    run_cleanups()  # waits for an output being renamed into place
    _log(f"jaxcontact {command}: {interrupted_message()}")
    sys.stdout.flush()
    os._exit(143 if signum == signal.SIGTERM else 130)  # not waiting for a compilation


def console_main() -> None:  # pragma: no cover - exercised in subprocess tests
    """Entry point of the ``jaxcontact`` script (see the module docstring)."""
    previous = {sig: signal.signal(sig, _on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    command = sys.argv[1] if len(sys.argv) > 1 else "command"
    try:
        args = _parse(None)  # imports jax: an interruption here must not be lost either
    except (KeyboardInterrupt, _Terminated) as err:
        _interrupted(command, signal.SIGTERM if isinstance(err, _Terminated) else signal.SIGINT)
    except BaseException:
        # an extension module interrupted while it initialises raises ImportError
        if _SIGNALLED:
            _interrupted(command, _SIGNALLED[0])
        raise
    if _SIGNALLED:
        _interrupted(command, _SIGNALLED[0])
    _RAISE[0] = True  # from here the main thread only waits for the worker
    if isinstance(args, int):
        sys.exit(args)
    import jax  # imported by _parse; the command's own process computes in float64

    jax.config.update("jax_enable_x64", True)
    box: dict = {}

    def work():
        try:
            box["rc"] = _dispatch(args)
        except BaseException as err:  # noqa: BLE001 - reported by the main thread
            box["err"] = err

    worker = threading.Thread(target=work, name="jaxcontact-command", daemon=True)
    try:
        worker.start()
        while worker.is_alive():
            worker.join(0.1)
            if _SIGNALLED:
                _interrupted(args.command, _SIGNALLED[0])
        # the command is done: a signal from here on is recorded (never the default action,
        # which would end the process with -15 and no word about the complete output)
        _RAISE[0] = False
        if _SIGNALLED:
            _interrupted(args.command, _SIGNALLED[0])
    except (KeyboardInterrupt, _Terminated) as err:
        _interrupted(args.command,
                     signal.SIGTERM if isinstance(err, _Terminated) else signal.SIGINT)
    del previous  # the handlers stay until the process ends (see above)
    if "err" in box:
        err = box["err"]
        if isinstance(err, SystemExit):
            sys.exit(err.code)
        raise err
    sys.exit(box.get("rc", 1))
