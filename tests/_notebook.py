"""Execute a notebook's code cells in-process, as the test suite's check of `notebooks/`.

Each notebook has its own test file (`test_notebook_*.py`), so that pytest-xdist's
`--dist loadfile` spreads the notebooks over the workers. The runner also enforces the
notebooks' conventions: stored without outputs, every figure's axes labelled with units
(a `[...]` in each axis label), and a markdown cell (the reading of the figure) right after
every code cell that draws one.
"""

import json
import os
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

NOTEBOOK_DIR = Path(__file__).resolve().parents[1] / "notebooks"


def _check_figures(plt, where):
    for num in plt.get_fignums():
        fig = plt.figure(num)
        for ax in fig.axes:
            if not ax.get_visible() or not ax.axison:
                continue
            labels = [ax.get_xlabel(), ax.get_ylabel()]
            if hasattr(ax, "get_zlabel"):
                labels.append(ax.get_zlabel())
            for axis, label in zip("xyz", labels, strict=False):
                is_colorbar = ax.get_label() == "<colorbar>"
                if is_colorbar and axis == "x":
                    continue
                assert "[" in label and "]" in label, (
                    f"{where}: figure {num} has a {axis} axis without a label with units "
                    f"({label!r})"
                )


def run_notebook(name: str, *, conventions: bool = True) -> None:
    """Run every code cell of `notebooks/<name>` in one namespace, from `notebooks/`.

    `conventions=False` skips the figure checks (units on every axis, a reading after every
    figure), for notebooks written before them."""
    import matplotlib.pyplot as plt

    path = NOTEBOOK_DIR / name
    nb = json.loads(path.read_text())
    cells = nb["cells"]
    code = [c for c in cells if c["cell_type"] == "code"]
    assert code, f"{name} has no code cells"
    for c in code:
        assert not c.get("outputs") and c.get("execution_count") is None, (
            f"{name}: store notebooks without outputs (cell {c.get('id')})"
        )
    namespace = {"__name__": "__notebook__"}
    cwd = os.getcwd()
    os.chdir(NOTEBOOK_DIR)
    plt.close("all")
    try:
        for i, cell in enumerate(cells):
            if cell["cell_type"] != "code":
                continue
            where = f"{name} cell {cell.get('id', i)}"
            exec(compile("".join(cell["source"]), where, "exec"), namespace)
            if plt.get_fignums() and conventions:
                _check_figures(plt, where)
                following = cells[i + 1]["cell_type"] if i + 1 < len(cells) else None
                assert following == "markdown", (
                    f"{where} draws a figure; a markdown cell reading it must follow"
                )
            plt.close("all")
    finally:
        os.chdir(cwd)
        plt.close("all")
