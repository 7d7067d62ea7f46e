"""Physics of the instruments.

Optics, sensors, the LBL imaging and Cornell three-axis gonioreflectometers, and the
simulated bench the fake devices read and change.

Light at import: the optics and lens models (numpy only) are imported eagerly; the LBL
instrument, sensor and source load on first attribute access (numba is only imported when a
capture runs).

>>> from gonio.simulator import eq3_reflection_angles
>>> t, p = eq3_reflection_angles(0.0, 0.0, 1.0, 0.05)
>>> round(float(t), 6), round(float(p), 6)
(0.099793, -1.570796)
"""

from __future__ import annotations

import importlib
from typing import Any

from gonio.simulator.lenses import LENS_MODELS, FisheyeLens, make_lens
from gonio.simulator.optics import (
    MIRRORS,
    Mirror,
    eq3_error,
    eq3_reflection_angles,
    traced_reflection_angles,
)

_LAZY = {
    "LBLInstrument": "gonio.simulator.lbl",
    "Geometry": "gonio.simulator.lbl",
    "STANDARD": "gonio.simulator.lbl",
    "WARD_BINNING": "gonio.simulator.lbl",
    "capture": "gonio.simulator.lbl",
    "default_instrument": "gonio.simulator.lbl",
    "reproduce": "gonio.simulator.lbl",
    "Sensor": "gonio.simulator.sensor",
    "Source": "gonio.simulator.source",
    "Background": "gonio.simulator.source",
}

__all__ = [
    "LENS_MODELS",
    "MIRRORS",
    "FisheyeLens",
    "Mirror",
    "eq3_error",
    "eq3_reflection_angles",
    "make_lens",
    "traced_reflection_angles",
    *sorted(_LAZY),
]


def __getattr__(name: str) -> Any:
    mod = _LAZY.get(name)
    if mod is None:
        raise AttributeError(f"module 'gonio.simulator' has no attribute {name!r}")
    value = getattr(importlib.import_module(mod), name)
    globals()[name] = value
    return value
