"""``python -m jaxcontact_cli`` runs the ``jaxcontact`` command."""

from ._main import console_main

console_main()
