"""Execute notebooks/04_fitting.ipynb (its asserts check the recovery of known parameters,
the standard errors against a profile likelihood, the nested model choice and the
identifiability report)."""

from _notebook import run_notebook


def test_notebook_04_fitting():
    run_notebook("04_fitting.ipynb")
