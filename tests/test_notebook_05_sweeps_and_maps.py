"""Execute notebooks/05_sweeps_and_maps.ipynb (its asserts check the sweep's pull-off force
against the closed form at every point, sweep points against direct `retract` calls,
float32 against float64, the netCDF round trip, and a force map fitted curve by curve
with every curve converged)."""

import pytest
from _notebook import run_notebook


@pytest.mark.slow  # extended (~2 min): `python -m pytest -m slow`; its stored outputs'
# sources are checked in the default run (test_notebooks.py)
def test_notebook_05_sweeps_and_maps():
    run_notebook("05_sweeps_and_maps.ipynb")
