"""Execute notebooks/04_fitting.ipynb (its asserts check the recovery of known parameters,
the standard errors against a profile likelihood, the nested model choice and the
identifiability report)."""

import pytest
from _notebook import run_notebook


@pytest.mark.slow  # extended (~2 min): `python -m pytest -m slow`; its stored outputs'
# sources are checked in the default run (test_notebooks.py)
def test_notebook_04_fitting():
    run_notebook("04_fitting.ipynb")
