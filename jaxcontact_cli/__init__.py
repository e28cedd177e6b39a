"""jaxcontact_cli: the command line and the plots of jaxcontact (the top layer).

It imports the forward model (:mod:`jaxcontact`) and the identification (:mod:`fitting`);
nothing imports it. ``jaxcontact demo | simulate | fit`` (see ``jaxcontact
--help``); :func:`plot_fit` draws a `fitting.FitResult`.
"""

from ._main import build_parser as build_parser
from ._main import console_main as console_main
from ._main import main as main
from ._plots import plot_fit as plot_fit

__all__ = ["main", "console_main", "build_parser", "plot_fit"]
