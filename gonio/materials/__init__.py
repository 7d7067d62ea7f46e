"""Named material presets with their sources.

Each JSON file in ``data/`` maps a preset name to ``{"model": ..., "params": {...},
"source": "<seed file> <table/section>", "class": "metal" | "dielectric" | ..., "notes": ...}``.
Angles in preset files are radians only where the paper gives radians; any parameter whose
name ends in ``_deg`` is converted to radians (and renamed without the suffix) on load.

>>> from gonio import materials
>>> m = materials.get("rolled_brass")
>>> m.name, m.params["alpha_y"]
('ward', 0.16)
"""

from __future__ import annotations

import json
import math
from functools import cache
from importlib import resources
from typing import Any

from gonio.brdf import BRDF, create

__all__ = ["get", "info", "names"]


@cache
def _presets() -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for entry in sorted(resources.files(__name__).joinpath("data").iterdir(), key=str):
        if not entry.name.endswith(".json"):
            continue
        table = json.loads(entry.read_text(encoding="utf-8"))
        for name, rec in table.items():
            if name in out:
                raise RuntimeError(f"material preset {name!r} defined twice ({entry.name})")
            rec = dict(rec)
            rec["file"] = entry.name
            out[name] = rec
    return out


def names(model: str | None = None) -> list[str]:
    """Sorted preset names (optionally only those of one registered model)."""
    p = _presets()
    if model is not None:
        from gonio import brdf

        if model not in brdf.names():
            raise ValueError(
                f"unknown model {model!r}; registered models are: {', '.join(brdf.names())}"
            )
    return sorted(n for n in p if model is None or p[n]["model"] == model)


def info(name: str) -> dict[str, Any]:
    """The preset record: model, params (radians), source, class, notes."""
    p = _presets()
    if name not in p:
        raise ValueError(f"unknown material {name!r}; known materials are: {', '.join(names())}")
    rec = dict(p[name])
    rec["params"] = _to_radians(rec["params"])
    return rec


def get(name: str, **overrides: Any) -> BRDF:
    """The BRDF model of preset ``name`` (parameters may be overridden)."""
    rec = info(name)
    params = {**rec["params"], **overrides}
    return create(rec["model"], **params)


def _to_radians(params: dict[str, Any]) -> dict[str, Any]:
    out = {}
    for k, v in params.items():
        if k.endswith("_deg"):
            out[k[:-4]] = [math.radians(x) for x in v] if isinstance(v, list) else math.radians(v)
        else:
            out[k] = v
    return out
