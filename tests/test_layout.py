"""The layout of the code: inference never loads training, evaluation or data generation, and every
file and function is small enough to hold in one's head (issue 39, item 4)."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_FILE_LINES = 600
MAX_FUNCTION_LINES = 80
"""A function's lines from its `def` to its end; a CLI command's from its docstring (its signature is
the option declarations)."""

FORBIDDEN = ("mosegpipe.training", "mosegpipe.evaluation", "mosegpipe.studies", "mosegpipe.synth")


@pytest.mark.slow
def test_inference_loads_no_training_evaluation_or_synth() -> None:
    # One fresh interpreter for all of them: the check is about the union of what they import.
    sys.path.insert(0, str(ROOT / "tests"))
    from test_imports import PACKAGES, module_files

    # Every module but the training side and the CLI (`python -m mosegpipe` included), computed from the source (a
    # new one is held to it too).
    cli = ("mosegpipe.cli", "mosegpipe.__main__")
    inference = sorted(m for m in module_files(PACKAGES) if not m.startswith((*FORBIDDEN, *cli)))
    code = (
        f"import sys, importlib; [importlib.import_module(m) for m in {inference!r}]; "
        f"print('\\n'.join(m for m in sorted(sys.modules) if m.startswith({FORBIDDEN!r})))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == [], f"importing the inference modules loads {out}"


def _sources() -> list[Path]:
    return sorted([*(ROOT / "mosegpipe").rglob("*.py"), *(ROOT / "cli").rglob("*.py")])


def test_no_file_over_the_limit() -> None:
    sizes = {p.relative_to(ROOT).as_posix(): len(p.read_text(encoding="utf-8").splitlines()) for p in _sources()}
    assert {p: n for p, n in sizes.items() if n > MAX_FILE_LINES} == {}


def test_no_function_over_the_limit() -> None:
    long = {}
    for path in _sources():
        cli = path.is_relative_to(ROOT / "cli")
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                start = node.body[0].lineno if cli else node.lineno
                if node.end_lineno is not None and node.end_lineno - start + 1 > MAX_FUNCTION_LINES:
                    long[f"{path.relative_to(ROOT).as_posix()}:{node.lineno} {node.name}"] = node.end_lineno - start + 1
    assert long == {}
