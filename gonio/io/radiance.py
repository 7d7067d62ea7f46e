"""Fitted Ward parameters as a Radiance material (``plastic2`` / ``metal2``).

Radiance's anisotropic materials take (Radiance reference manual, ``ray.html``, Materials)::

    mod plastic2 id            mod metal2 id
    4+ ux uy uz funcfile [transform]
    0
    6 red green blue spec urough vrough

``ux uy uz`` is the (unnormalised) direction along which ``urough`` applies; ``vrough`` applies
perpendicular to it in the surface. Radiance evaluates Ward's elliptical Gaussian
(Ward 1992, eq. 5a) with ``urough``/``vrough`` as the RMS slopes, so
``urough = alpha_x`` along the sample's x axis and ``vrough = alpha_y``.

The reflectances follow Radiance's source (``normal.c`` / ``aniso.c``): the diffuse part is
``color × (1 − spec)`` (``rdiff = 1 − rspec``, "modified by material color"); the specular
part is ``spec`` uncoloured for ``plastic2`` and ``color × spec`` for ``metal2``. Hence

- plastic2 (dielectrics): ``spec = ρs``, ``color = ρd / (1 − ρs)``;
- metal2 (metals): ``color = ρd + ρs``, ``spec = ρs / (ρd + ρs)``.

Grey fits write ``red = green = blue``; spectral (RGB) fits may pass three values.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from gonio.io.atomic import atomic_write_bytes

__all__ = [
    "MATERIAL_TYPES",
    "material_type_for",
    "parse_material",
    "ward_material",
    "ward_params",
    "write_material",
]

MATERIAL_TYPES = ("plastic2", "metal2")
_NAME = re.compile(r"^[A-Za-z0-9_.\-]+$")


def material_type_for(material_class: str) -> str:
    """``"metal2"`` for class ``"metal"``, ``"plastic2"`` for dielectrics (and others)."""
    if not isinstance(material_class, str) or not material_class:
        raise ValueError(f"material_class must be a non-empty string, got {material_class!r}")
    return "metal2" if material_class.lower().startswith("metal") else "plastic2"


def _rgb(v: float | Sequence[float], name: str) -> list[float]:
    vals = [float(v)] * 3 if isinstance(v, int | float) else [float(x) for x in v]
    if len(vals) != 3:
        raise ValueError(f"{name} must be a number or 3 values (R, G, B), got {v!r}")
    if not all(math.isfinite(x) and x >= 0 for x in vals):
        raise ValueError(f"{name} must be finite and >= 0, got {v!r}")
    return vals


def ward_material(
    params: Mapping[str, Any],
    material_type: str = "plastic2",
    name: str = "gonio_ward",
    u: Sequence[float] = (1.0, 0.0, 0.0),
    modifier: str = "void",
    comment: str | None = None,
) -> str:
    """The Radiance text of a Ward fit.

    Parameters
    ----------
    params : mapping
        ``rho_d``, ``rho_s`` (numbers, or 3 values R, G, B), ``alpha_x``, ``alpha_y``.
    material_type : {"plastic2", "metal2"}
    name : str
        Radiance identifier (no white space).
    u : 3 numbers
        Direction of ``alpha_x`` in the object's coordinates (the sample's x axis).
    modifier : str
        Radiance modifier (``void`` by default).
    comment : str, optional
        Lines written as ``#`` comments above the primitive.

    Raises
    ------
    ValueError
        Unknown type, a bad name, missing parameters, a plastic whose ``ρd/(1−ρs)`` exceeds 1,
        or roughness ≤ 0 (Radiance forbids zero roughness in ``plastic2``/``metal2``).
    """
    if material_type not in MATERIAL_TYPES:
        raise ValueError(f"material_type {material_type!r}; expected one of {MATERIAL_TYPES}")
    for label, s in (("name", name), ("modifier", modifier)):
        if not isinstance(s, str) or not _NAME.match(s):
            raise ValueError(f"{label} {s!r} must be a non-empty word without white space")
    missing = [k for k in ("rho_d", "rho_s", "alpha_x", "alpha_y") if k not in params]
    if missing:
        raise ValueError(f"params is missing {missing}; expected Ward's rho_d, rho_s, alphas")
    rd = _rgb(params["rho_d"], "rho_d")
    rs = _rgb(params["rho_s"], "rho_s")
    ax, ay = float(params["alpha_x"]), float(params["alpha_y"])
    if not (ax > 0 and ay > 0 and math.isfinite(ax) and math.isfinite(ay)):
        raise ValueError(f"alpha_x, alpha_y must be finite and > 0, got {ax!r}, {ay!r}")
    ux = [float(x) for x in u]
    if len(ux) != 3 or not any(ux) or not all(math.isfinite(x) for x in ux):
        raise ValueError(f"u must be a non-zero 3-vector, got {u!r}")
    if material_type == "plastic2":
        spec = sum(rs) / 3.0
        if max(rs) - min(rs) > 1e-12:
            raise ValueError(f"plastic2 has an uncoloured specular; rho_s {rs} must be grey")
        if spec >= 1.0:
            raise ValueError(f"plastic2 needs rho_s < 1, got {spec}")
        color = [d / (1.0 - spec) for d in rd]
    else:
        color = [d + s for d, s in zip(rd, rs)]
        tot = sum(color)
        spec = sum(rs) / tot if tot > 0 else 0.0
        if tot > 0 and max(abs(s - spec * c) for s, c in zip(rs, color)) > 1e-9:
            raise ValueError(
                f"metal2 has one spec for all channels: rho_s/(rho_d + rho_s) must be equal "
                f"in R, G, B; got rho_d {rd}, rho_s {rs}"
            )
    if max(color) > 1.0 + 1e-12:
        raise ValueError(
            f"{material_type} colour {color} exceeds 1 (rho_d {rd}, rho_s {rs}); not a "
            "physically valid Radiance material"
        )
    lines = [f"# {c}" for c in (comment or "").splitlines() if c.strip()]
    lines += [
        f"{modifier} {material_type} {name}",
        "4 {:.8g} {:.8g} {:.8g} .".format(*ux),
        "0",
        "6 {:.10g} {:.10g} {:.10g} {:.10g} {:.10g} {:.10g}".format(*color, spec, ax, ay),
    ]
    return "\n".join(lines) + "\n"


def write_material(path: str | os.PathLike, text: str) -> Path:
    """Write a material file atomically."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def parse_material(text: str) -> dict[str, Any]:
    """Parse one ``plastic2``/``metal2`` primitive: type, name, u, color, spec, urough, vrough."""
    words = []
    for line in text.splitlines():
        line = line.split("#", 1)[0]
        words += line.split()
    if len(words) < 3:
        raise ValueError("material text too short; expected 'mod type id' and arguments")
    mod, mtype, name = words[:3]
    if mtype not in MATERIAL_TYPES:
        raise ValueError(f"material type {mtype!r}; expected one of {MATERIAL_TYPES}")
    rest = words[3:]
    try:
        ns = int(rest[0])
        sargs = rest[1 : 1 + ns]
        rest = rest[1 + ns :]
        ni = int(rest[0])
        rest = rest[1 + ni :]
        nf = int(rest[0])
        fargs = [float(x) for x in rest[1 : 1 + nf]]
    except (IndexError, ValueError):
        raise ValueError("malformed argument lists in material text") from None
    if ns < 4 or nf != 6 or len(fargs) != 6:
        raise ValueError(f"{mtype} needs 4+ string and 6 real arguments, got {ns} and {nf}")
    return {
        "modifier": mod,
        "type": mtype,
        "name": name,
        "u": [float(x) for x in sargs[:3]],
        "funcfile": sargs[3],
        "color": fargs[:3],
        "spec": fargs[3],
        "urough": fargs[4],
        "vrough": fargs[5],
    }


def ward_params(material: Mapping[str, Any] | str) -> dict[str, Any]:
    """Ward's ``rho_d, rho_s, alpha_x, alpha_y`` from a parsed (or textual) material.

    The inverse of :func:`ward_material`; reflectances are per channel lists when the colour
    is not grey, floats otherwise.
    """
    m = parse_material(material) if isinstance(material, str) else material
    c, s = m["color"], m["spec"]
    rd = [x * (1.0 - s) for x in c]
    rs = [s] * 3 if m["type"] == "plastic2" else [x * s for x in c]

    def grey(v: list[float]) -> float | list[float]:
        return v[0] if max(v) - min(v) < 1e-12 else v

    return {"rho_d": grey(rd), "rho_s": grey(rs), "alpha_x": m["urough"], "alpha_y": m["vrough"]}
