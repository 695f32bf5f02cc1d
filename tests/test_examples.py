"""The scripts in ``examples/`` run, use only public names, and stay short.

Each script is run as a user would run it (a fresh interpreter, an output
directory as its argument); its output is checked for the numbers it prints.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

import attopt

EXAMPLES = sorted((Path(__file__).resolve().parent.parent / "examples").glob("*.py"))
MAX_ATTOPT_LINES = 15


def _attopt_uses(tree: ast.Module) -> tuple[set[int], list[str], list[str]]:
    """Lines that use attopt (``attopt.X`` or a name imported from it), every attopt name
    used (none may be private) and the facade names used as ``attopt.X``."""
    imported: set[str] = set()
    names: list[str] = []
    facade: list[str] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("attopt"):
            imported |= {alias.asname or alias.name for alias in node.names}
            names += [f"{node.module}.{alias.name}" for alias in node.names]
    lines = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and _root(node) == "attopt":
            lines.add(node.lineno)
            names.append(node.attr)
            if isinstance(node.value, ast.Name):
                facade.append(node.attr)
        elif isinstance(node, ast.Name) and node.id in imported:
            lines.add(node.lineno)
    return lines, names, facade


def _root(node: ast.AST) -> str | None:
    while isinstance(node, ast.Attribute):
        node = node.value
    return node.id if isinstance(node, ast.Name) else None


def test_there_are_at_least_three_examples() -> None:
    assert len(EXAMPLES) >= 3


@pytest.mark.parametrize("script", EXAMPLES, ids=lambda p: p.name)
def test_example_uses_public_names_in_few_lines(script: Path) -> None:
    lines, names, facade = _attopt_uses(ast.parse(script.read_text()))
    assert 0 < len(lines) <= MAX_ATTOPT_LINES, sorted(lines)
    assert [n for n in names if any(part.startswith("_") for part in n.split("."))] == []
    assert set(facade) <= set(attopt.__all__), sorted(set(facade) - set(attopt.__all__))


@pytest.mark.parametrize("script", EXAMPLES, ids=lambda p: p.name)
def test_example_runs(script: Path, tmp_path: Path) -> None:
    done = subprocess.run(
        [sys.executable, str(script), str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "Solution(" in done.stdout or "Track(" in done.stdout
    assert "nan" not in done.stdout.lower().replace("nees", "")
    if script.name == "own_gyro_pass.py":
        figures = sorted(p.name for p in tmp_path.glob("*.png"))
        assert figures == ["fg_batch_errors.png", "mekf_errors.png", "rts_errors.png"]
        smoother = re.findall(r"RMS after 60 s \(deg\): \[([^\]]*)\]", done.stdout)[2]
        assert max(float(x) for x in smoother.split(",")) < 0.05
