"""The notebooks: each one runs in its own test file (`test_notebook_<stem>.py`, so that
pytest-xdist's `--dist loadfile` spreads them over the workers, with the figure conventions
of `_notebook.run_notebook` enforced). This file checks that every notebook has that test
file and that the README lists every notebook."""

from pathlib import Path

from _notebook import NOTEBOOK_DIR, check_stored

TESTS = Path(__file__).resolve().parent
NOTEBOOKS = sorted(NOTEBOOK_DIR.glob("*.ipynb"))


def test_every_notebook_has_a_test_that_runs_it():
    assert NOTEBOOKS
    for p in NOTEBOOKS:
        test = TESTS / f"test_notebook_{p.stem}.py"
        assert test.exists(), f"{p.name} has no test file {test.name}"
        assert f'run_notebook("{p.name}")' in test.read_text(), f"{test.name} does not run it"


def test_readme_lists_every_notebook():
    readme = (TESTS.parent / "README.md").read_text()
    missing = [p.stem for p in NOTEBOOKS if f"`{p.stem}`" not in readme]
    assert not missing, f"README.md does not list the notebooks {missing}"


def test_stored_outputs_belong_to_the_current_sources():
    # without running them (the runs of 03, 04, 05 and 06 are in the extended run, `-m slow`): a
    # notebook edited without re-storing its outputs fails here in the default run
    for p in NOTEBOOKS:
        check_stored(p.name)
