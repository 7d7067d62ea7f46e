"""Helpers shared by the subcommands: JSON output and table printing."""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np


def _default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"value of type {type(o).__name__} is not JSON serialisable")


def to_json(obj: Any) -> str:
    """``json.dumps`` that understands numpy scalars and arrays and paths."""
    return json.dumps(obj, indent=2, default=_default, allow_nan=False)


def write_json(path: str | os.PathLike, obj: Any) -> Path:
    """Write ``obj`` as JSON to ``path`` atomically (temporary file + rename)."""
    from gonio.io.atomic import atomic_write_bytes

    return atomic_write_bytes(path, (to_json(obj) + "\n").encode())


def add_json_option(parser) -> None:
    """The ``--json PATH`` option every result-producing subcommand has."""
    parser.add_argument("--json", metavar="PATH", help="also write the results as JSON to PATH")


def format_table(headers: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """A plain aligned text table."""
    cells = [[str(h) for h in headers]] + [[_fmt(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in cells]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def _fmt(c: Any) -> str:
    if isinstance(c, float | np.floating):
        return f"{c:.4g}"
    return str(c)
