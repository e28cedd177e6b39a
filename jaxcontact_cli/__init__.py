"""jaxcontact_cli: the command line and the plots of jaxcontact (the top layer).

It imports the forward model (:mod:`jaxcontact`) and the identification (:mod:`fitting`);
nothing imports it. ``jaxcontact demo | simulate | fit`` (see ``jaxcontact
--help``); :func:`plot_fit` draws a `fitting.FitResult`, :func:`plot_map` a
`fitting.FitEachResult`.
"""

from ._main import build_parser as build_parser
from ._main import console_main as console_main
from ._main import main as main

__all__ = ["main", "console_main", "build_parser", "plot_fit", "plot_map"]


def __getattr__(name):
    # the figures import numpy and matplotlib only when asked for: the console script sets
    # its signal handlers before any heavy import (an interruption is never swallowed)
    if name in ("plot_fit", "plot_map"):
        from . import _plots

        return getattr(_plots, name)
    raise AttributeError(f"module 'jaxcontact_cli' has no attribute {name!r}")
