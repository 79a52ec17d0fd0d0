"""The import graph of mosegpipe, read from the source with `ast` (nothing is imported).

Two rules of DESIGN.md: no module imports itself back through others (no import circles), and the
inference stages never import training/, evaluation/ or synth/. An import inside a function body
counts (a lazy import still closes a circle once it runs), and so does one under `if TYPE_CHECKING:` (it
never runs, but the two modules still lean on each other: a circle of types is a circle to untangle).
The cli folder is installed as mosegpipe.cli and is read as such.

An edge is an import the module writes: `import a.b` and `from a import b` (b a module) lead to a.b,
`from a import name` to a (a package: its __init__). Python also runs a package's __init__ before a
submodule, but that is not an edge here: every __init__ that re-exports its submodules would
otherwise be a circle.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator, Mapping
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {"mosegpipe": ROOT / "mosegpipe", "mosegpipe.cli": ROOT / "cli"}
"""Import name -> source folder of each package root read (the cli is mapped in by package-dir)."""

FORBIDDEN = ("mosegpipe.training", "mosegpipe.evaluation", "mosegpipe.studies", "mosegpipe.synth")


def module_files(packages: Mapping[str, Path]) -> dict[str, Path]:
    """Module name -> source file of every module under the package roots (a package is its __init__)."""
    modules: dict[str, Path] = {}
    for prefix, folder in packages.items():
        for path in sorted(folder.rglob("*.py")):
            parts = path.relative_to(folder).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            modules[".".join((prefix, *parts))] = path
    return modules


def _import_nodes(node: ast.AST) -> Iterator[ast.Import | ast.ImportFrom]:
    """Every import statement in `node`: function bodies and `if TYPE_CHECKING:` bodies included."""
    if isinstance(node, (ast.Import, ast.ImportFrom)):
        yield node
    else:
        for child in ast.iter_child_nodes(node):
            yield from _import_nodes(child)


def _known(name: str, modules: Mapping[str, Path]) -> str | None:
    """`name` or its nearest enclosing package among `modules` (None: outside them)."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def imports_of(name: str, path: Path, modules: Mapping[str, Path]) -> set[str]:
    """The modules among `modules` that module `name` (source `path`) imports."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str | None] = set()
    for node in _import_nodes(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            found.update(_known(alias.name, modules) for alias in node.names)
            continue
        if node.level:
            parts = package.split(".")
            base = ".".join(parts[: len(parts) - node.level + 1] + ([node.module] if node.module else []))
        else:
            base = node.module or ""
        for alias in node.names:
            sub = f"{base}.{alias.name}"
            found.add(sub if sub in modules else _known(base, modules))
    return {m for m in found if m is not None and m != name}


def import_graph(packages: Mapping[str, Path]) -> dict[str, set[str]]:
    """Module -> the modules it imports, for every module under the package roots."""
    modules = module_files(packages)
    return {name: imports_of(name, path, modules) for name, path in modules.items()}


def find_cycle(graph: Mapping[str, set[str]]) -> list[str] | None:
    """One import circle as a path that ends where it starts (`[a, b, a]`), or None when there is none.

    Depth-first from each module in name order; `done` holds the modules whose imports are known to
    lead to no circle.
    """
    done: set[str] = set()
    for root in sorted(graph):
        if root in done:
            continue
        path = [root]
        todo = [iter(sorted(graph.get(root, ())))]
        while todo:
            nxt = next(todo[-1], None)
            if nxt is None:
                done.add(path.pop())
                todo.pop()
            elif nxt in path:
                return path[path.index(nxt) :] + [nxt]
            elif nxt not in done:
                path.append(nxt)
                todo.append(iter(sorted(graph.get(nxt, ()))))
    return None


def reachable(graph: Mapping[str, set[str]], start: str) -> set[str]:
    """Every module `start` imports, directly or through others."""
    seen: set[str] = set()
    todo = [start]
    while todo:
        for nxt in graph.get(todo.pop(), ()):
            if nxt not in seen:
                seen.add(nxt)
                todo.append(nxt)
    return seen


# ---------------------------------------------------------------------------------------------
# The finder itself, on small made-up graphs and packages
# ---------------------------------------------------------------------------------------------


def test_find_cycle_names_the_circle() -> None:
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None
    assert find_cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None  # a diamond is no circle
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"b"}}) == ["b", "c", "b"]
    assert find_cycle({"x": {"x"}}) == ["x", "x"]


def test_import_graph_resolves_relative_lazy_and_package_imports(tmp_path: Path) -> None:
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    files = {
        "__init__.py": "from pkg.a import f\n",
        "a.py": "from typing import TYPE_CHECKING\nfrom . import b\nif TYPE_CHECKING:\n    from pkg import c\n"
        "def f():\n    import pkg.sub.d\n",
        "b.py": "from .sub import d\nfrom .sub.d import g\n",
        "c.py": "import os\n",
        "sub/__init__.py": "from ..a import f\n",
        "sub/d.py": "def g():\n    from pkg import b\n",
    }
    for name, text in files.items():
        (pkg / name).write_text(text)
    graph = import_graph({"pkg": pkg})
    assert graph == {
        "pkg": {"pkg.a"},
        "pkg.a": {"pkg.b", "pkg.c", "pkg.sub.d"},  # the TYPE_CHECKING import of pkg.c counts too
        "pkg.b": {"pkg.sub.d"},
        "pkg.c": set(),
        "pkg.sub": {"pkg.a"},
        "pkg.sub.d": {"pkg.b"},
    }
    assert find_cycle(graph) == ["pkg.b", "pkg.sub.d", "pkg.b"]


# ---------------------------------------------------------------------------------------------
# The rules, on mosegpipe
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    return import_graph(PACKAGES)


def test_the_graph_covers_the_package_and_the_cli(graph: dict[str, set[str]]) -> None:
    assert {"mosegpipe", "mosegpipe.pipeline.video", "mosegpipe.cli.main", "mosegpipe.studies.registry"} <= set(graph)
    assert "mosegpipe.pipeline.video" in reachable(graph, "mosegpipe.cli.main")


def test_no_import_circles(graph: dict[str, set[str]]) -> None:
    cycle = find_cycle(graph)
    assert cycle is None, f"import circle: {' -> '.join(cycle)}"


def test_inference_stages_never_import_training_evaluation_or_synth(graph: dict[str, set[str]]) -> None:
    # Every module but the training side and the CLI (whose train/eval commands load it on demand; `python -m
    # mosegpipe` is the CLI too): computed, so that a new module is held to the rule without being listed anywhere.
    stages = [m for m in graph if not m.startswith((*FORBIDDEN, "mosegpipe.cli", "mosegpipe.__main__"))]
    assert "mosegpipe.pipeline.clip" in stages and "mosegpipe.apps.outputs" in stages
    for module in stages:
        bad = sorted(m for m in reachable(graph, module) if m.startswith(FORBIDDEN))
        assert not bad, f"{module} imports {', '.join(bad)}"


def test_every_package_folder_is_installed() -> None:
    """pyproject.toml lists the packages by hand: a folder left out imports in the checkout (editable) but not
    from a wheel, the way CI installs the project."""
    import tomllib

    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(setuptools["packages"])
    folders = {
        ".".join((prefix, *init.parent.relative_to(folder).parts))
        for prefix, folder in PACKAGES.items()
        for init in folder.rglob("__init__.py")
    }
    assert folders - listed == set(), f"packages missing from pyproject.toml: {sorted(folders - listed)}"
    assert listed - folders == set(), f"pyproject.toml lists packages with no folder: {sorted(listed - folders)}"


def private_imports(folders: list[Path]) -> list[str]:
    """`file: module._name` for every `from mosegpipe... import _name` (a single leading underscore) in the folders."""
    found = []
    for folder in folders:
        for path in sorted(folder.rglob("*.py")):
            for node in _import_nodes(ast.parse(path.read_text(encoding="utf-8"), str(path))):
                if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("mosegpipe"):
                    for alias in node.names:
                        if alias.name.startswith("_") and not alias.name.startswith("__"):
                            found.append(f"{path.relative_to(folder.parent).as_posix()}: {node.module}.{alias.name}")
    return found


def test_the_finder_of_private_imports_sees_them(tmp_path: Path) -> None:
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "a.py").write_text(
        "from mosegpipe.x import _hidden, shown\nfrom mosegpipe import __version__\ndef f():\n    from mosegpipe.y import _lazy\n"
    )
    assert private_imports([tmp_path / "pkg"]) == ["pkg/a.py: mosegpipe.x._hidden", "pkg/a.py: mosegpipe.y._lazy"]


def test_no_module_imports_another_modules_private_names() -> None:
    """A name another module needs is public: `_name` stays inside its module (tests and benchmarks included)."""
    assert private_imports([ROOT / "mosegpipe", ROOT / "cli", ROOT / "tests", ROOT / "benchmarks"]) == []
