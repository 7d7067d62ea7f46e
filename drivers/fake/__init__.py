"""Fake devices speaking the real protocols on top of a simulated bench.

- :mod:`gonio.drivers.fake.esp300` — ESP300 firmware emulator served on a pty / TCP;
- :mod:`gonio.drivers.fake.usb` — a pyusb backend with a fake USB2000+
  (:mod:`~gonio.drivers.fake.usb2000`) and a fake PTP camera (:mod:`~gonio.drivers.fake.ptp`);
  ``install(bench) -> name`` registers it as ``usb.backend.<name>``;
- :mod:`gonio.drivers.fake.usbfs` — the same USB fakes on an emulated Linux USB bus
  (umockdev) for every libusb-1.0 program, their usbdevfs ioctls answered by
  :mod:`~gonio.drivers.fake.usbdevfs` (``gonio devices serve --libusb -- PROGRAM``);
- :mod:`gonio.drivers.fake.faults` — fault injection shared by all fakes.

The bench is :class:`gonio.simulator.bench.Bench`.
"""
