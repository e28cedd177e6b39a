"""Execute notebooks/06_bem.ipynb (its asserts check the BEM against the MDR/JKR sphere,
Hertz's elliptical contact and a second contact algorithm)."""

from _notebook import run_notebook


def test_notebook_06_bem():
    run_notebook("06_bem.ipynb")
