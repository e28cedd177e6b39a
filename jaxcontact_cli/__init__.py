"""jaxcontact_cli: the command line and the plots of jaxcontact (the top layer).

It imports the forward model (:mod:`jaxcontact`) and the identification (:mod:`fitting`);
nothing imports it. ``jaxcontact demo | simulate | fit`` (see ``jaxcontact
--help``).
"""

from ._main import build_parser as build_parser
from ._main import console_main as console_main
from ._main import main as main

__all__ = ["main", "console_main", "build_parser"]
