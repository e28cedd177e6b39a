"""Warnings that point to the caller's line, not into the library."""

from __future__ import annotations

import sys
import warnings

__all__ = ["warn_at_caller"]


def warn_at_caller(message: str, category: type[Warning]) -> None:
    """`warnings.warn` attributed to the first frame outside the library (the ``fitting``
    and ``jaxcontact`` packages: the user's call of :func:`fitting.fit`, say, which passes
    through jaxcontact's `float64_scope` wrapper), however deep in them it is issued.
    Python's default filter then shows each message once per calling line (a warning
    attributed to a library line is shown once for all callers, and its location says
    nothing to the user)."""
    level, frame = 2, sys._getframe(1)  # stacklevel 2: the frame that called us
    library = ("fitting", "jaxcontact")
    while frame is not None and frame.f_globals.get("__name__", "").split(".")[0] in library:
        frame = frame.f_back
        level += 1
    warnings.warn(message, category, stacklevel=level)
