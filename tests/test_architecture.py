"""The direction of imports is the architecture.

Layers, bottom to top: ``jaxcontact`` (forward model) → ``fitting`` (identification) →
``jaxcontact_cli`` (command line and plots). A module may import its own package and the
packages below it, never one above, not even lazily inside a function; and the modules of
the project form no import cycle. The imports are read with `ast` from the source files
(every ``import``/``from`` statement anywhere in a module, so lazy imports count).
"""

from __future__ import annotations

import ast
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[1]
LAYERS = ["jaxcontact", "fitting", "jaxcontact_cli"]


def _module_name(path: pathlib.Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _modules() -> dict[str, pathlib.Path]:
    out = {}
    for pkg in LAYERS:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            out[_module_name(path)] = path
    return out


def _imports(name: str, path: pathlib.Path, known: set[str]) -> set[str]:
    """Project modules imported by module `name` (resolved relative imports)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    is_pkg = path.name == "__init__.py"
    package = name if is_pkg else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            # `from pkg import sub` imports the submodule; `from mod import name` the module
            targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in known else mod
                       for a in node.names]
        for t in targets:
            # the longest known module that `t` names (a name imported from a module
            # counts as that module)
            while t and t not in known:
                t = t.rpartition(".")[0]
            if t and t != name:
                found.add(t)
    return found


def _graph():
    mods = _modules()
    known = set(mods)
    return {m: _imports(m, p, known) for m, p in mods.items()}


def test_layers_import_only_downward():
    rank = {pkg: i for i, pkg in enumerate(LAYERS)}
    bad = []
    for mod, deps in _graph().items():
        r = rank[mod.split(".")[0]]
        for d in deps:
            if rank[d.split(".")[0]] > r:
                bad.append(f"{mod} imports {d}")
    assert not bad, "imports against the layering:\n" + "\n".join(sorted(bad))


def test_no_import_cycles_between_modules():
    graph = _graph()
    # a package's __init__ re-exports its private modules; an edge from a private module to
    # its own package's __init__ is a cycle as well, so every edge counts
    state: dict[str, int] = {}
    cycles = []

    def visit(m, stack):
        state[m] = 1
        stack.append(m)
        for d in sorted(graph.get(m, ())):
            if state.get(d) == 1:
                cycles.append(" -> ".join(stack[stack.index(d):] + [d]))
            elif d not in state:
                visit(d, stack)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [])
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


def test_the_walk_sees_lazy_imports(tmp_path):
    # the checker itself: an import inside a function is found
    src = tmp_path / "m.py"
    src.write_text("def f():\n    import fitting._optimise\n    from . import other\n")
    deps = _imports("jaxcontact.m", src, {"fitting", "fitting._optimise", "jaxcontact.other"})
    assert deps == {"fitting._optimise", "jaxcontact.other"}


def test_fit_each_reaches_the_shared_pipeline_through_public_internal_names():
    # `fit` and `fit_each` run one pipeline (fitting._optimise.identify); the batched
    # front end imports no private helper of the modules behind it (it imported six)
    tree = ast.parse((ROOT / "fitting" / "_batch.py").read_text())
    private = [(node.module, a.name) for node in ast.walk(tree)
               if isinstance(node, ast.ImportFrom) and node.level == 1
               for a in node.names if a.name.startswith("_")]
    assert private == []


def _commands() -> set[str]:
    """The command modules of the command line: those that define `add_parser`."""
    out = set()
    for name, path in _modules().items():
        if not name.startswith("jaxcontact_cli."):
            continue
        tree = ast.parse(path.read_text(), filename=str(path))
        if any(isinstance(n, ast.FunctionDef) and n.name == "add_parser" for n in tree.body):
            out.add(name)
    return out


def test_commands_stand_side_by_side():
    # `simulate`, `sweep`, `fit`, `demo` share what they share through `_common` (and their
    # own parts, e.g. `_simulate_bem`): no command reaches another through its imports
    graph = _graph()
    commands = _commands()
    assert {"jaxcontact_cli._simulate", "jaxcontact_cli._sweep"} <= commands
    bad = []
    for c in sorted(commands):
        seen, todo = set(), [c]
        while todo:
            for d in graph.get(todo.pop(), ()):
                if d not in seen:
                    seen.add(d)
                    todo.append(d)
        bad += [f"{c} reaches {d}" for d in sorted(seen & commands - {c})]
    assert not bad, "commands importing commands:\n" + "\n".join(bad)
