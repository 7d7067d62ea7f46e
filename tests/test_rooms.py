"""The rooms' import rules of docs/architecture.md ("The house"), checked on the source.

Every ``import`` of every module (those inside functions too) is read from the syntax tree;
an import of another room must be one the architecture's table allows. The truth-and-knowledge
rule is one of them: the laboratory's reduction (``calibration/``) may import the simulator's
optics models, never its instruments.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: source folder -> its import name (pyproject.toml's package-dir)
FOLDERS = {
    "gonio": "gonio",
    "simulator": "gonio.simulator",
    "calibration": "gonio.calibration",
    "drivers": "gonio.drivers",
}
CORE = {
    "brdf",
    "materials",
    "geometry",
    "samples",
    "colour",
    "numeric",
    "malloc",
    "_validate",
    "hints",
    "console",
    "merl",
    "__version__",
}
#: every room but the command line and the tests
ROOMS = {
    "core",
    "fit",
    "io",
    "simulator",
    "calibration",
    "drivers",
    "plots",
    "campaign",
    "diagnostics",
}
#: room -> the rooms it may import (the table's last column)
MAY = {
    "core": {"core"},
    "fit": {"core"},
    "io": {"core"},
    "simulator": {"core"},
    "calibration": {"core", "io"},
    "drivers": set(),
    "plots": {"core", "fit", "io"},
    "campaign": ROOMS - {"diagnostics"},  # "everything above" it in the table
    "diagnostics": ROOMS,
    "cli": ROOMS,
}
#: the table's named exceptions: (importing module or package prefix, imported module)
EXCEPTIONS = {
    ("gonio.samples", "gonio.io.samples_table"),  # BRDFSamples.read / .write
    ("gonio.merl", "gonio.io.merl"),  # the old public name, re-exported
    ("gonio.brdf.tabulated", "gonio.io.merl"),  # a table model reads its file
    ("gonio.brdf.measured", "gonio.io.merl"),
    ("gonio.brdf.measured", "gonio.io.mitsuba"),
    ("gonio.simulator.standard", "gonio.io.certificate"),  # the standard's certificate
    ("gonio.calibration.", "gonio.simulator.lenses"),  # the optics models, not the instruments
    ("gonio.calibration.", "gonio.simulator.optics"),
    ("gonio.drivers.fake.", "gonio.simulator"),  # the fakes' simulated bench
    ("gonio.campaign.sweep", "gonio.diagnostics"),  # the sweep's task registry
}


def _module(path: Path) -> tuple[str, bool]:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    parts[0] = FOLDERS[parts[0]]
    if parts[-1] == "__init__":
        return ".".join(parts[:-1]), True
    return ".".join(parts), False


def _imports(path: Path) -> set[str]:
    """The gonio modules ``path`` imports (relative imports resolved)."""
    name, is_pkg = _module(path)
    pkg = name if is_pkg else name.rsplit(".", 1)[0]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")[: len(pkg.split(".")) - (node.level - 1)]
                out.add(".".join(base + ([node.module] if node.module else [])))
            else:
                out.add(node.module or "")
    return {m for m in out if m == "gonio" or m.startswith("gonio.")}


def _room(module: str) -> str:
    parts = module.split(".")
    if len(parts) == 1 or parts[1] in CORE:
        return "core"
    return parts[1]


def _allowed(importer: str, imported: str) -> bool:
    a, b = _room(importer), _room(imported)
    if a == b or b in MAY[a]:
        return True
    return any(
        (importer == src or (src.endswith(".") and importer.startswith(src)))
        and (imported == dst or imported.startswith(dst + "."))
        for src, dst in EXCEPTIONS
    )


def _sources() -> list[Path]:
    return sorted(p for folder in FOLDERS for p in (ROOT / folder).rglob("*.py"))


def test_every_import_across_rooms_is_one_the_architecture_allows():
    bad = sorted(
        f"{_module(p)[0]} imports {m}"
        for p in _sources()
        for m in _imports(p)
        if not _allowed(_module(p)[0], m)
    )
    assert not bad, "\n".join(bad)


def test_the_check_sees_a_forbidden_import(tmp_path):
    """The scan finds function-level and relative imports (a rule it cannot see is no rule)."""
    assert _room("gonio.cli._common") == "cli" and _room("gonio.console") == "core"
    assert not _allowed("gonio.campaign.folder", "gonio.cli._common")
    assert not _allowed("gonio.calibration.reduce", "gonio.simulator.lbl")
    assert _allowed("gonio.calibration.reduce", "gonio.simulator.lenses")
    assert not _allowed("gonio.drivers.esp300", "gonio.simulator.bench")
    assert _allowed("gonio.drivers.fake.esp300", "gonio.simulator.bench")
    src = ROOT / "gonio" / "campaign" / "report.py"
    assert "gonio.console" in _imports(src)  # imported inside a function
    assert any(
        m.startswith("gonio.campaign") for m in _imports(ROOT / "gonio/campaign/__init__.py")
    )
    assert len(_sources()) > 150
