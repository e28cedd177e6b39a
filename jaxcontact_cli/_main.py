"""The ``jaxcontact`` command: parser, dispatch, errors and interruption.

Exit status: 0 success; 1 the work failed (a fit that did not converge, a simulation that
ended in an error state, an unexpected error); 2 bad arguments or input data (the message
names the option or the file); 130/143 interrupted by Ctrl-C/SIGTERM. Every error is one
line on stderr; ``--debug`` adds the traceback. Progress and logs go to stderr; with
``--json`` stdout carries only the JSON document.

Interruption: the command runs in a worker thread while the main thread waits, so Ctrl-C
and SIGTERM are handled at once, also while XLA compiles: the temporary outputs are removed
(outputs are only ever renamed into place when complete, see :mod:`._common`) and the
process ends without waiting for the compiler.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
import traceback

from jaxcontact import __version__

from ._common import UsageError, run_cleanups

__all__ = ["main", "console_main", "build_parser"]


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def build_parser() -> argparse.ArgumentParser:
    from . import _demo, _fit, _simulate, _sweep

    parser = argparse.ArgumentParser(
        prog="jaxcontact",
        description=(
            "Adhesive contact of viscoelastic bodies (MDR, energetic detachment criterion): "
            "forward simulation, sweeps and parameter identification. SI units throughout."
        ),
    )
    parser.add_argument("--version", action="version", version=f"jaxcontact {__version__}")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--debug", action="store_true",
                        help="show the Python traceback of an error")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module in (_demo, _simulate, _sweep, _fit):
        module.add_parser(sub, common)
    return parser


def _dispatch(args: argparse.Namespace) -> int:
    name = f"jaxcontact {args.command}"
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


def _one_line(err: BaseException) -> str:
    text = " ".join(str(err).split())
    return text if len(text) <= 600 else text[:597] + "..."


def _parse(argv) -> argparse.Namespace | int:
    from fitting import tune_xla_cpu

    tune_xla_cpu()
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help(sys.stderr)
        return 2
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


class _Terminated(Exception):
    pass


def _raise_terminated(signum, frame):  # pragma: no cover - exercised in a subprocess test
    raise _Terminated


def console_main() -> None:  # pragma: no cover - exercised in subprocess tests
    """Entry point of the ``jaxcontact`` script (see the module docstring)."""
    args = _parse(None)
    if isinstance(args, int):
        sys.exit(args)
    box: dict = {}

    def work():
        try:
            box["rc"] = _dispatch(args)
        except BaseException as err:  # noqa: BLE001 - reported by the main thread
            box["err"] = err

    worker = threading.Thread(target=work, name="jaxcontact-command", daemon=True)
    previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        worker.start()
        while worker.is_alive():
            worker.join(0.1)
    except (KeyboardInterrupt, _Terminated) as err:
        run_cleanups()
        code = 143 if isinstance(err, _Terminated) else 130
        _log(f"jaxcontact {args.command}: interrupted; no output was written or changed")
        sys.stdout.flush()
        os._exit(code)  # do not wait for a compilation in the worker thread
    finally:
        signal.signal(signal.SIGTERM, previous)
    if "err" in box:
        err = box["err"]
        if isinstance(err, SystemExit):
            sys.exit(err.code)
        raise err
    sys.exit(box.get("rc", 1))
