"""The notebooks: each one with its own test file runs there (`test_notebook_<stem>.py`,
so that pytest-xdist's `--dist loadfile` spreads them over the workers, with the figure
conventions of `_notebook.run_notebook` enforced); this file runs the others (written before
those conventions, checked only for running) and checks that the README lists every
notebook."""

from pathlib import Path

import pytest
from _notebook import NOTEBOOK_DIR, run_notebook

TESTS = Path(__file__).resolve().parent
NOTEBOOKS = sorted(NOTEBOOK_DIR.glob("*.ipynb"))
OTHERS = [p for p in NOTEBOOKS if not (TESTS / f"test_notebook_{p.stem}.py").exists()]


@pytest.mark.parametrize("path", OTHERS, ids=[p.name for p in OTHERS])
def test_notebook_runs(path):
    run_notebook(path.name, conventions=False)


def test_readme_lists_every_notebook():
    readme = (TESTS.parent / "README.md").read_text()
    missing = [p.stem for p in NOTEBOOKS if f"`{p.stem}`" not in readme]
    assert not missing, f"README.md does not list the notebooks {missing}"
