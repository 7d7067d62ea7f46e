"""Hardware interfaces and real-protocol drivers (ESP300, USB2000+, PTP camera).

Campaign code programs against the protocols in :mod:`gonio.drivers.interfaces`
(:class:`Axis`, :class:`MotionController`, :class:`Camera`, :class:`Spectrometer`). The
drivers speak the devices' own protocols through a transport object:

- :class:`gonio.drivers.esp300.ESP300` — Newport ESP300 (ASCII over RS-232, pyserial);
- :class:`gonio.drivers.usb2000.USB2000Plus` — Ocean Optics USB2000+ (OOI protocol, pyusb);
- :class:`gonio.drivers.ptp.PTPCamera` — a PTP / ISO 15740 still camera (pyusb).

Fakes of all three on a simulated bench live in :mod:`gonio.drivers.fake`.
"""

from gonio.drivers.errors import DeviceDisconnected, DeviceError, DeviceTimeout
from gonio.drivers.interfaces import Axis, Camera, MotionController, Spectrometer

__all__ = [
    "Axis",
    "Camera",
    "DeviceDisconnected",
    "DeviceError",
    "DeviceTimeout",
    "MotionController",
    "Spectrometer",
]
