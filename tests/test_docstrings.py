"""Docstrings the documentation build can read: no cross-reference split across lines, no
stray substitution.

Sphinx's autosummary takes a docstring's first sentence, up to the first ". ", as the
summary in the API tables; a role such as ``:attr:`gonio.campaign.plan.Plan.`` broken after
a dot at the end of a line becomes ``Plan. bracket_min_signal_dn`` there, an unterminated
role, and the build (warnings as errors) fails. Checked on the source, in a few milliseconds,
so the test suite catches it before the documentation build does. Likewise ``|error|``
outside a literal is a reStructuredText substitution reference, undefined, an error.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("gonio", "simulator", "calibration", "drivers")
#: a role whose target is not closed on the same line
SPLIT_ROLE = re.compile(r":(?:func|meth|attr|class|mod|data|obj|exc):`[^`]*$")
#: ``|name|`` outside double back-quotes: a substitution reference
SUBSTITUTION = re.compile(r"(?<![|`\w])\|[A-Za-z_][\w.]*\|(?![|`\w])")


def split_roles(source: str, name: str = "<source>") -> list[str]:
    """``name:line`` of every docstring line that opens a role without closing it."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        body = node.body
        if not (body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)):
            continue
        doc = body[0].value.value
        if not isinstance(doc, str):
            continue
        for k, line in enumerate(doc.splitlines()):
            if SPLIT_ROLE.search(line) or SUBSTITUTION.search(re.sub(r"``.*?``", "", line)):
                found.append(f"{name}:{body[0].lineno + k}")
    return found


def test_no_docstring_splits_a_cross_reference_across_lines():
    found = []
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            found += split_roles(path.read_text(encoding="utf-8"), str(path.relative_to(ROOT)))
    assert found == [], f"roles split across lines or substitutions (see module): {found}"


def test_the_check_sees_a_split_role():
    source = '"""Summary (:attr:`gonio.campaign.plan.Plan.\nbracket_min_signal_dn`)."""\n'
    assert split_roles(source) == ["<source>:1"]
    assert split_roles('"""Summary (:attr:`gonio.campaign.plan.Plan.x`)."""\n') == []


def test_the_check_sees_a_substitution():
    assert split_roles('"""Summary.\n\nError |error| / U 1.2."""\n') == ["<source>:3"]
    assert split_roles('"""Summary.\n\nError ``|error| / U`` 1.2."""\n') == []
