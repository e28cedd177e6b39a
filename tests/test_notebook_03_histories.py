"""Execute notebooks/03_histories.ipynb (its asserts check `simulate` against Lee-Radok,
`retract`, the glassy and quasi-static limits and displacement control)."""

import pytest
from _notebook import run_notebook


@pytest.mark.slow  # extended (~30 s): `python -m pytest -m slow`; its stored outputs'
# sources are checked in the default run (test_notebooks.py); the physics it checks is
# also in the module's own tests
def test_notebook_03_histories():
    run_notebook("03_histories.ipynb")
