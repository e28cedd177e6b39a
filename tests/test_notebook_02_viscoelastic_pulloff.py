"""Execute notebooks/02_viscoelastic_pulloff.ipynb (its asserts check `retract` against the
corrected eq. (24)-(25), the ODE, the stiffness limits and the slow JKR limit)."""

from _notebook import run_notebook


def test_notebook_02_viscoelastic_pulloff():
    run_notebook("02_viscoelastic_pulloff.ipynb")
