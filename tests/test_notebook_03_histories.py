"""Execute notebooks/03_histories.ipynb (its asserts check `simulate` against Lee-Radok,
`retract`, the glassy and quasi-static limits and displacement control)."""

from _notebook import run_notebook


def test_notebook_03_histories():
    run_notebook("03_histories.ipynb")
