"""Execute a notebook's code cells in-process: the test suite's check of `notebooks/`, and
the script that stores the notebooks executed.

The notebooks are stored *with* their outputs (text, the value of each cell's last
expression, every figure as a PNG), so that a repository page shows them rendered. The
outputs are written by this file run as a script, from the repository root::

    python tests/_notebook.py                   # every notebook
    python tests/_notebook.py 04_fitting.ipynb  # one

Each code cell's stored outputs carry the SHA-256 of the cell's source
(``metadata.jaxcontact.source_sha256``). The test of a notebook (`run_notebook`, one test
file per notebook so that pytest-xdist's `--dist loadfile` spreads them over the workers)
re-executes every cell and checks that the stored outputs belong to the current source,
that each cell draws the figures it stored, and that the stored text agrees with the text
the cell prints now (every number within a relative 2 %, since a stored number is rounded
to the digits it was printed with; the words exactly; a cell tagged ``volatile``, which
prints a timing, a date or an environment-dependent repr, by its lines' first words). The
runner also enforces the
notebooks' conventions: every figure's axes labelled with units (a `[...]` in each axis
label), and a markdown cell (the reading of the figure) right after every code cell that
draws one.
"""

from __future__ import annotations

import ast
import base64
import contextlib
import hashlib
import io
import json
import os
import re
import sys
import warnings
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

NOTEBOOK_DIR = Path(__file__).resolve().parents[1] / "notebooks"
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


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


def _source(cell) -> str:
    src = cell["source"]
    return "".join(src) if isinstance(src, list) else src


def _sha(cell) -> str:
    return hashlib.sha256(_source(cell).encode()).hexdigest()


def _lines(text: str) -> list[str]:
    return text.splitlines(keepends=True)


def _run_cell(source: str, where: str, namespace: dict) -> tuple[str, str, str | None]:
    """Execute one cell as Jupyter does: the statements, then the value of a last
    expression. Returns (stdout, warnings text, repr of the last value or None)."""
    tree = ast.parse(source, filename=where)
    last = None
    if tree.body and isinstance(tree.body[-1], ast.Expr):
        last = ast.Expression(tree.body.pop().value)
    out = io.StringIO()
    with contextlib.redirect_stdout(out), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        exec(compile(tree, where, "exec"), namespace)
        value = eval(compile(last, where, "eval"), namespace) if last is not None else None
    # a cell's warnings are part of what it shows (stored as its stderr), not test errors
    warned = "".join(f"{w.category.__name__}: {w.message}\n" for w in caught)
    shown = None
    if value is not None and not type(value).__module__.startswith("matplotlib"):
        shown = repr(value)
    return out.getvalue(), warned, shown


def _figures_png(plt) -> list[str]:
    pngs = []
    for num in plt.get_fignums():
        buf = io.BytesIO()
        plt.figure(num).savefig(buf, format="png", dpi=80, bbox_inches="tight")
        pngs.append(base64.b64encode(buf.getvalue()).decode())
    return pngs


def _outputs(stdout, warned, shown, pngs, count) -> list[dict]:
    outs = []
    if stdout:
        outs.append({"output_type": "stream", "name": "stdout", "text": _lines(stdout)})
    if warned:
        outs.append({"output_type": "stream", "name": "stderr", "text": _lines(warned)})
    for png in pngs:
        outs.append({"output_type": "display_data", "metadata": {},
                     "data": {"image/png": png, "text/plain": ["<Figure>"]}})
    if shown is not None:
        outs.append({"output_type": "execute_result", "execution_count": count,
                     "metadata": {}, "data": {"text/plain": _lines(shown)}})
    return outs


def _text_of(outputs: list[dict]) -> str:
    parts = []
    for o in outputs:
        if o["output_type"] == "stream" and o["name"] == "stdout":
            parts.append("".join(o["text"]))
        elif o["output_type"] == "execute_result":
            parts.append("".join(o["data"]["text/plain"]))
    return "".join(parts)


def _same_text(stored: str, now: str, *, numbers: bool = True) -> str | None:
    """None if `now` reads as `stored` (words equal, numbers within 2 %), else a reason.
    Not `numbers` (a cell tagged ``volatile``: it prints timings, dates or an object's
    environment-dependent repr): the same number of lines, each starting with the same
    word."""
    if not numbers:
        first = [line.split()[:1] for line in stored.splitlines()]
        if first != [line.split()[:1] for line in now.splitlines()]:
            return f"stored:\n{stored}\nnow:\n{now}"
        return None
    words_s, words_n = _NUMBER.split(stored), _NUMBER.split(now)
    nums_s, nums_n = _NUMBER.findall(stored), _NUMBER.findall(now)
    if [w.split() for w in words_s] != [w.split() for w in words_n] or len(nums_s) != len(nums_n):
        return f"stored:\n{stored}\nnow:\n{now}"
    for a, b in zip(nums_s, nums_n, strict=True):
        x, y = float(a), float(b)
        if abs(x - y) > 0.02 * max(abs(x), abs(y)) and abs(x - y) > 1e-12:
            return f"{a} stored, {b} now:\nstored:\n{stored}\nnow:\n{now}"
    return None


def check_stored(name: str) -> None:
    """Every code cell of `notebooks/<name>` carries stored outputs made from its current
    source (the SHA-256 of the source recorded when they were stored), without running it."""
    cells = json.loads((NOTEBOOK_DIR / name).read_text())["cells"]
    code = [c for c in cells if c["cell_type"] == "code"]
    assert code, f"{name} has no code cells"
    for c in code:
        stored_sha = c.get("metadata", {}).get("jaxcontact", {}).get("source_sha256")
        assert stored_sha == _sha(c), (
            f"{name} cell {c.get('id')}: its stored outputs are not those of its source; "
            f"run `python tests/_notebook.py {name}`")
        assert c.get("outputs") is not None, f"{name} cell {c.get('id')}: no stored outputs"


def run_notebook(name: str, *, conventions: bool = True, write: bool = False) -> None:
    """Run every code cell of `notebooks/<name>` in one namespace, from `notebooks/`.

    Checks the stored outputs against the run (see the module docstring); `write=True`
    stores the run's outputs instead. `conventions=False` skips the figure checks (units
    on every axis, a reading after every figure), for notebooks written before them."""
    import matplotlib.pyplot as plt

    path = NOTEBOOK_DIR / name
    nb = json.loads(path.read_text())
    cells = nb["cells"]
    code = [c for c in cells if c["cell_type"] == "code"]
    assert code, f"{name} has no code cells"
    if not write:
        check_stored(name)
    namespace = {"__name__": "__notebook__"}
    cwd = os.getcwd()
    os.chdir(NOTEBOOK_DIR)
    plt.close("all")
    count = 0
    try:
        for i, cell in enumerate(cells):
            if cell["cell_type"] != "code":
                continue
            count += 1
            where = f"{name} cell {cell.get('id', i)}"
            stdout, warned, shown = _run_cell(_source(cell), where, namespace)
            if plt.get_fignums() and conventions:
                _check_figures(plt, where)
                following = cells[i + 1]["cell_type"] if i + 1 < len(cells) else None
                assert following == "markdown", (
                    f"{where} draws a figure; a markdown cell reading it must follow"
                )
            if write:
                outs = _outputs(stdout, warned, shown, _figures_png(plt), count)
                cell["outputs"] = outs
                cell["execution_count"] = count
                cell.setdefault("metadata", {})["jaxcontact"] = {"source_sha256": _sha(cell)}
            else:
                stored = cell.get("outputs", [])
                n_fig = sum(o["output_type"] == "display_data" for o in stored)
                assert n_fig == len(plt.get_fignums()), (
                    f"{where}: stored {n_fig} figure(s), draws {len(plt.get_fignums())}; "
                    f"run `python tests/_notebook.py {name}`")
                volatile = "volatile" in cell.get("metadata", {}).get("tags", [])
                differs = _same_text(_text_of(stored), stdout + (shown or ""),
                                     numbers=not volatile)
                assert differs is None, f"{where}: the stored text differs from the run: {differs}"
            plt.close("all")
    finally:
        os.chdir(cwd)
        plt.close("all")
    if write:
        text = json.dumps(nb, indent=1, ensure_ascii=False) + "\n"
        tmp = path.with_name(f".{path.name}.tmp")
        tmp.write_text(text)
        os.replace(tmp, path)


if __name__ == "__main__":
    # the test suite's JAX settings (float64, strict rank promotion, XLA flags)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import conftest  # noqa: F401

    names = sys.argv[1:] or sorted(p.name for p in NOTEBOOK_DIR.glob("*.ipynb"))
    for n in names:
        print(f"executing {n}", file=sys.stderr, flush=True)
        run_notebook(n, write=True)
