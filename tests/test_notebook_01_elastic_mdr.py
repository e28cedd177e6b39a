"""Execute notebooks/01_elastic_mdr.ipynb (its asserts check the MDR against closed forms)."""

from _notebook import run_notebook


def test_notebook_01_elastic_mdr():
    run_notebook("01_elastic_mdr.ipynb")
