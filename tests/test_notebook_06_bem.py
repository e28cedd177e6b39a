"""Execute notebooks/06_bem.ipynb (its asserts check the BEM against the MDR/JKR sphere,
Hertz's elliptical contact and a second contact algorithm)."""

import pytest
from _notebook import run_notebook


@pytest.mark.slow  # extended (~30 s): `python -m pytest -m slow`; its stored outputs'
# sources are checked in the default run (test_notebooks.py); the physics it checks is
# also in the module's own tests
def test_notebook_06_bem():
    run_notebook("06_bem.ipynb")
