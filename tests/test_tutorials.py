"""The tutorials (docs/tutorials, executed when the documentation builds) leave nothing
behind: each temporary folder they make is removed at their end (issue 32: every tutorial run
left about 50 MB in the temporary folder)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

TUTORIALS = sorted((Path(__file__).parents[1] / "docs" / "tutorials").glob("plot_*.py"))


def _call_name(node: ast.AST) -> str:
    if isinstance(node, ast.Call):
        f = node.func
        if isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name):
            return f"{f.value.id}.{f.attr}"
        if isinstance(f, ast.Name):
            return f.id
    return ""


@pytest.mark.parametrize("path", TUTORIALS, ids=lambda p: p.name)
def test_every_temporary_folder_of_a_tutorial_is_removed_at_its_end(path):
    """Each name bound to ``tempfile.mkdtemp(...)`` (possibly inside ``Path(...)``) is given
    to ``shutil.rmtree`` in the tutorial's last statements, at module level."""
    tree = ast.parse(path.read_text())
    made = set()
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1:
            calls = [n for n in ast.walk(node.value) if _call_name(n) == "tempfile.mkdtemp"]
            if calls and isinstance(node.targets[0], ast.Name):
                made.add(node.targets[0].id)
    removed = set()
    for node in tree.body[-3:]:
        if isinstance(node, ast.Expr) and _call_name(node.value) == "shutil.rmtree":
            arg = node.value.args[0]
            if isinstance(arg, ast.Name):
                removed.add(arg.id)
    assert made <= removed, f"{path.name}: {sorted(made - removed)} not removed at its end"
    src = path.read_text()
    assert "mkstemp(" not in src and "NamedTemporaryFile(" not in src.replace(
        "NamedTemporaryFile(delete=True", ""
    )


def test_the_tutorials_are_found():
    assert len(TUTORIALS) >= 4
