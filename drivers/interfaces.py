"""Small typed interfaces that campaign code programs against.

Campaign code uses only these protocols; the ESP300, USB2000+ and PTP drivers implement them,
and so can any other device (or a pure-Python stand-in). Positions are in the axis' native
``units`` (``"deg"`` for the rotation stages, ``"mm"`` for linear ones); convert with
``math.radians`` at the campaign boundary. Times are seconds.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol, runtime_checkable

import numpy as np

__all__ = ["Axis", "Camera", "MotionController", "Spectrometer"]


@runtime_checkable
class Axis(Protocol):
    """One motorised axis."""

    name: str
    units: str

    def move_to(self, position: float) -> None:
        """Start an absolute move (returns at once; use :meth:`wait`)."""

    def move_by(self, delta: float) -> None:
        """Start a relative move."""

    def position(self) -> float:
        """The current (encoder) position."""

    def is_moving(self) -> bool:
        """True while a move is in progress."""

    def wait(self, timeout: float = 60.0) -> float:
        """Block until the axis stops (``DeviceTimeout`` after ``timeout`` s); the position."""

    def home(self) -> None:
        """Search the home switch and zero the position there."""

    def limits(self) -> tuple[float, float]:
        """Software travel limits ``(low, high)``."""


@runtime_checkable
class MotionController(Protocol):
    """A controller owning named axes."""

    @property
    def axes(self) -> Mapping[str, Axis]: ...

    def axis(self, name: str) -> Axis: ...

    def enable(self) -> None:
        """Power every motor."""

    def disable(self) -> None:
        """Switch every motor off."""

    def close(self) -> None: ...


@runtime_checkable
class Camera(Protocol):
    """A still camera: set exposure and f-number, capture one raw frame."""

    exposure: float  # seconds
    f_number: float

    def capture(self, timeout: float = 30.0) -> tuple[np.ndarray, dict[str, Any]]:
        """One raw frame (uint16, H×W) and its metadata."""

    def close(self) -> None: ...


@runtime_checkable
class Spectrometer(Protocol):
    """A grating spectrometer with a linear detector."""

    integration_time: float  # seconds

    def wavelengths(self) -> np.ndarray:
        """Wavelength of every pixel (nm)."""

    def intensities(self) -> np.ndarray:
        """Counts of every pixel for one acquisition."""

    def close(self) -> None: ...
