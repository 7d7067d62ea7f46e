"""Fake Ocean Optics USB2000+ spectrometer: the OOI single-byte command protocol over USB.

Endpoints as on the real device (high-speed): EP1 OUT 0x01 (commands), EP1 IN 0x81 (query
replies), EP2 OUT 0x02, EP2 IN 0x82 (spectra), EP6 IN 0x86; all bulk, 512-byte packets.
Commands (first byte): 0x01 initialise, 0x02 integration time (u32 LE, µs), 0x03 strobe
enable, 0x05 query information (EEPROM slot; reply 17 bytes ``05 slot data[15]`` on 0x81),
0x06 write information, 0x09 request spectrum (the bench's ``n_pixels`` — 2048 on a
USB2000+ — as u16 LE in 512-byte packets on 0x82, then the one-byte sync packet 0x69), 0x0A
trigger mode, 0x6A/0x6B write/read FPGA register (``reg lo hi`` on 0x81), 0xFE query status
(16 bytes on 0x81). Unknown commands are ignored, as the firmware does.

The spectrum is what the bench's ``spectrum_render`` gives for the stage positions at the
start of the integration; it is ready ``integration time`` (simulated) after the request.

References
----------
Ocean Optics, *USB2000+ Data Sheet* (USB command summary, EEPROM slot map, status bytes);
python-seabreeze ``pyseabreeze`` (``devices.USB2000PLUS``, ``protocol.OOIProtocol``,
``features.spectrometer``/``eeprom``/``fpga``) whose unmodified client this fake serves.
"""

from __future__ import annotations

import struct
import time
from typing import ClassVar

import numpy as np
from gonio.drivers.fake.faults import Faults
from gonio.drivers.fake.usbdev import Endpoint, FakeUsbDevice, Interface
from gonio.simulator.bench import Bench

__all__ = ["FakeUSB2000Plus"]

N_PIXELS = 2048
SYNC = 0x69
IT_MIN_US, IT_MAX_US = 1000, 655_350_000


class FakeUSB2000Plus(FakeUsbDevice):
    """The firmware of a USB2000+ (vendor 0x2457, product 0x101E) on a simulated bench.

    Parameters
    ----------
    bench : Bench
    serial : str
        Serial number (EEPROM slot 0 and the USB string descriptor).
    faults : Faults, optional
    nonlinearity : sequence of float
        Coefficients stored in slots 6..13 (order in slot 14).
    """

    vendor, product, bcd_device = 0x2457, 0x101E, 0x0200
    name = "usb2000plus"
    interfaces: ClassVar[list[Interface]] = [
        Interface(
            0,
            0xFF,
            0,
            0,
            [
                Endpoint(0x01, 2, 512),
                Endpoint(0x81, 2, 512),
                Endpoint(0x02, 2, 512),
                Endpoint(0x82, 2, 512),
                Endpoint(0x86, 2, 512),
            ],
        ),
    ]
    # FPGA firmware version register 0x04: major.minor.patch = 2.5.0 (below 3: USB2000+,
    # not Flame-S, for seabreeze's model check)
    firmware_version = 0x2050

    def __init__(
        self,
        bench: Bench,
        serial: str = "USB2+F07001",
        faults: Faults | None = None,
        nonlinearity: tuple[float, ...] = (0.9507, 7.0e-6, -3.1e-10, 5.2e-15),
    ) -> None:
        self.bench = bench
        self.serial = serial
        self.strings = {1: "Ocean Optics", 2: "USB2000+", 3: serial}
        self.nonlinearity = tuple(float(c) for c in nonlinearity)
        super().__init__(faults)
        self.eeprom: dict[int, bytes] = {}
        self.on_reset()

    def on_reset(self) -> None:
        self.integration_us = 10_000
        self.trigger_mode = 0
        self.strobe = 0
        self._acq_until = 0.0
        c = self.bench.wavelength_coeffs
        slots = {0: self.serial}
        for i in range(4):
            slots[1 + i] = f"{c[i]:.6e}"
        slots[5] = "0"  # stray light constant
        for i in range(8):
            slots[6 + i] = f"{self.nonlinearity[i]:.6e}" if i < len(self.nonlinearity) else "0"
        slots[14] = str(len(self.nonlinearity) - 1)
        slots[15] = "  0 0 0 0"  # optical bench: grating, filter, slit ...
        slots[16] = "USB2000+"
        for k, v in slots.items():
            self.eeprom.setdefault(k, v.encode("ascii")[:15])
        # slot 17: bytes 4..5 hold the saturation level (u16 LE) read by seabreeze
        self.eeprom.setdefault(17, b"\x00\x00\x00\x00" + struct.pack("<H", 65535))

    @property
    def n_pixels(self) -> int:
        """Pixels per spectrum: the bench's ``n_pixels`` (2048 unless the bench says)."""
        return int(getattr(self.bench, "n_pixels", N_PIXELS))

    def _slot(self, n: int) -> bytes:
        data = self.eeprom.get(n, b"")[:15]
        return bytes([0x05, n % 0xFF]) + data + bytes(15 - len(data))

    def on_out(self, ep: int, data: bytes) -> None:
        if ep != 0x01 or not data:
            return
        cmd = data[0]
        if cmd == 0x01:  # initialise
            self.on_reset()
        elif cmd == 0x02 and len(data) >= 5:
            it = struct.unpack("<I", data[1:5])[0]
            if IT_MIN_US <= it <= IT_MAX_US:
                self.integration_us = it
        elif cmd == 0x03 and len(data) >= 3:
            self.strobe = struct.unpack("<H", data[1:3])[0]
        elif cmd == 0x05 and len(data) >= 2:
            self.queue_in(0x81, self._slot(data[1]))
        elif cmd == 0x06 and len(data) >= 2:
            self.eeprom[data[1]] = bytes(data[2:17]).split(b"\x00")[0]
        elif cmd == 0x09:
            self._request_spectrum()
        elif cmd == 0x0A and len(data) >= 3:
            self.trigger_mode = struct.unpack("<H", data[1:3])[0]
        elif cmd == 0x6B and len(data) >= 2:
            reg = data[1]
            value = self.firmware_version if reg == 0x04 else 0
            self.queue_in(0x81, struct.pack("<BH", reg, value))
        elif cmd == 0xFE:
            acquiring = 1 if time.monotonic() < self._acq_until else 0
            status = struct.pack(
                "<HLBBBBBBBBBB",
                self.n_pixels,
                self.integration_us,
                self.strobe & 1,
                self.trigger_mode,
                acquiring,
                (2 * self.n_pixels + 511) // 512,
                0,
                0,
                0,
                0,
                0x80,
                0,
            )
            self.queue_in(0x81, status)
        # anything else: ignored, like the real firmware

    def _request_spectrum(self) -> None:
        it_s = self.integration_us * 1e-6
        counts = self.bench.render_spectrum(it_s, self.n_pixels)
        ready = time.monotonic() + self.bench.clock.real_seconds(it_s)
        self._acq_until = ready
        raw = counts.astype("<u2").tobytes()
        # 8 full 512-byte packets, then the sync byte as its own (short) packet
        self.queue_in(0x82, raw, ready_at=ready, zlp=False)
        self.queue_in(0x82, bytes([SYNC]), ready_at=ready)

    def spectrum_truth(self) -> np.ndarray:
        """The noise-free counts the bench would give now (for tests)."""
        return self.bench.render_spectrum(self.integration_us * 1e-6, self.n_pixels)
