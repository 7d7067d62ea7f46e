"""Ocean Optics USB2000+ spectrometer over pyusb (the OOI single-byte command protocol).

Commands: 0x01 initialise; 0x02 + u32 LE integration time (µs); 0x05 + slot: query
information (reply ``05 slot`` + 15 bytes of NUL-terminated ASCII on EP1 IN 0x81; slot 0
serial number, 1-4 wavelength polynomial, 6-13 non-linearity coefficients, 14 their order);
0x09 request spectrum (2048 pixels × u16 LE on EP2 IN 0x82 — 8 × 512-byte packets at high
speed — then the sync byte 0x69); 0xFE query status (16 bytes: pixels u16, integration time
u32, lamp, trigger mode, acquisition status, packets per spectrum, power, packet count, 2
reserved, USB speed (0x80 high / 0x00 full), reserved); 0x6B + register: read FPGA register
(``reg lo hi``; 0x04 is the firmware version).

References
----------
Ocean Optics, *USB2000+ Data Sheet* — USB command summary, EEPROM slots, status query.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np
from gonio.drivers._retry import BadReply, check_timeout, clear_halts, open_usb, reconnect, retry
from gonio.drivers.errors import DeviceError
from gonio.drivers.transport import (
    TransportDisconnected,
    TransportStall,
    TransportTimeout,
    UsbTransportProtocol,
)

__all__ = ["USB2000Plus"]

DEVICE = "USB2000+"
VENDOR, PRODUCT = 0x2457, 0x101E
EP_OUT, EP_IN_LOW, EP_IN_SPECTRUM = 0x01, 0x81, 0x82
N_PIXELS = 2048
SYNC = 0x69
T = TypeVar("T")


class USB2000Plus:
    """Driver for an Ocean Optics USB2000+ (implements the ``Spectrometer`` interface).

    Parameters
    ----------
    transport : UsbTransportProtocol
        E.g. ``UsbTransport(0x2457, 0x101E, backend=...)``; see :meth:`open`.
    timeout : float
        Seconds allowed for a query reply; a spectrum gets this plus the integration time.
    retries : int
        Extra attempts (after a timeout, a stall, a bad sync byte or a reconnect).
    initialize : bool
        Send 0x01 on construction.
    n_pixels : int or None
        Pixels per spectrum: 2048 on a USB2000+ (default). ``None`` asks the device (status
        query 0xFE on construction), for a detector of another size behind the same protocol.
    """

    device = DEVICE

    def __init__(
        self,
        transport: UsbTransportProtocol,
        *,
        timeout: float = 1.0,
        retries: int = 2,
        initialize: bool = True,
        n_pixels: int | None = N_PIXELS,
    ) -> None:
        self.transport = transport
        self.timeout = check_timeout(timeout)
        self.retries = int(retries)
        self._itime_us = 10_000  # power-up default
        self._wavelengths: np.ndarray | None = None
        if initialize:
            self.initialize()
        if n_pixels is None:
            n_pixels = self.status()["pixels"]
        if int(n_pixels) != n_pixels or not 1 <= n_pixels <= 8192:
            raise ValueError(f"n_pixels={n_pixels!r}: expected an integer 1..8192 or None")
        self.n_pixels = int(n_pixels)

    @classmethod
    def open(cls, backend: Any = None, **kwargs: Any) -> USB2000Plus:
        """Find the first USB2000+ (optionally on a named or given pyusb ``backend``)."""
        return cls(open_usb(DEVICE, VENDOR, PRODUCT, backend), **kwargs)

    # -- plumbing ---------------------------------------------------------------------------
    @property
    def _tmo_ms(self) -> int:
        return max(1, int(self.timeout * 1000))

    def _recover(self) -> None:
        """After a lost link: find the device again and restore its settings."""
        reconnect(self.transport, DEVICE)
        self.transport.write(EP_OUT, b"\x01", self._tmo_ms)
        self.transport.write(EP_OUT, struct.pack("<BI", 0x02, self._itime_us), self._tmo_ms)

    def _clear_stall(self) -> None:
        clear_halts(self.transport, (EP_OUT, EP_IN_LOW, EP_IN_SPECTRUM), self._recover)

    def _retry(self, command: str, fn: Callable[[], T]) -> T:
        return retry(
            DEVICE,
            command,
            fn,
            self.retries + 1,
            recover=self._recover,
            clear_stall=self._clear_stall,
        )

    # -- commands ---------------------------------------------------------------------------
    def initialize(self) -> None:
        """0x01: reset the spectrometer to power-up settings."""
        self._retry("0x01 initialize", lambda: self.transport.write(EP_OUT, b"\x01", self._tmo_ms))
        self._itime_us = 10_000

    @property
    def integration_time(self) -> float:
        """Integration time in seconds (1 ms … 655.35 s)."""
        return self._itime_us * 1e-6

    @integration_time.setter
    def integration_time(self, seconds: float) -> None:
        us = round(float(seconds) * 1e6)
        if not 1000 <= us <= 655_350_000:
            raise ValueError(f"integration_time={seconds!r}: expected 0.001 to 655.35 seconds")
        cmd = struct.pack("<BI", 0x02, us)
        self._retry(
            f"0x02 set integration time {us} us",
            lambda: self.transport.write(EP_OUT, cmd, self._tmo_ms),
        )
        self._itime_us = us

    def read_slot(self, slot: int) -> str:
        """0x05: the ASCII content of EEPROM slot ``slot``."""
        if not 0 <= int(slot) <= 255:
            raise ValueError(f"slot={slot!r}: expected 0..255")
        slot = int(slot)

        def once() -> str:
            self.transport.write(EP_OUT, bytes([0x05, slot]), self._tmo_ms)
            r = self.transport.read(EP_IN_LOW, 64, self._tmo_ms)
            if len(r) != 17 or r[0] != 0x05 or r[1] != slot:
                raise BadReply(r, f"expected 17 bytes starting 05 {slot:02x}")
            try:
                return r[2:].split(b"\x00")[0].decode("ascii")
            except UnicodeDecodeError as exc:
                raise BadReply(r, "slot data is not ASCII") from exc

        return self._retry(f"0x05 query slot {slot}", once)

    def serial_number(self) -> str:
        return self.read_slot(0)

    def wavelength_coefficients(self) -> list[float]:
        """Slots 1-4: λ(p) = c0 + c1 p + c2 p² + c3 p³ (nm)."""
        return [self._float_slot(i) for i in range(1, 5)]

    def nonlinearity_coefficients(self) -> list[float]:
        """Slots 6.. (order in slot 14): counts correction polynomial."""
        order = int(self._float_slot(14))
        return [self._float_slot(i) for i in range(6, 6 + order + 1)]

    def _float_slot(self, slot: int) -> float:
        for _ in range(self.retries + 1):
            text = self.read_slot(slot)
            try:
                return float(text)
            except ValueError:
                continue
        raise DeviceError(DEVICE, f"0x05 query slot {slot}", text, "slot is not a number")

    def wavelengths(self) -> np.ndarray:
        """Wavelength of each pixel (nm), from the EEPROM calibration."""
        if self._wavelengths is None:
            c = self.wavelength_coefficients()
            p = np.arange(self.n_pixels, dtype=np.float64)
            self._wavelengths = c[0] + c[1] * p + c[2] * p**2 + c[3] * p**3
        return self._wavelengths.copy()

    def status(self) -> dict[str, int]:
        """0xFE: the 16-byte status block, decoded."""

        def once() -> dict[str, int]:
            self.transport.write(EP_OUT, b"\xfe", self._tmo_ms)
            r = self.transport.read(EP_IN_LOW, 64, self._tmo_ms)
            if len(r) != 16:
                raise BadReply(r, "expected 16 status bytes")
            v = struct.unpack("<HLBBBBBBBBBB", r)
            return {
                "pixels": v[0],
                "integration_us": v[1],
                "lamp": v[2],
                "trigger_mode": v[3],
                "acquiring": v[4],
                "packets": v[5],
                "power_down": v[6],
                "packet_count": v[7],
                "usb_speed": v[10],
            }

        return self._retry("0xFE query status", once)

    def firmware_version(self) -> tuple[int, int, int]:
        """0x6B 0x04: FPGA firmware version (major, minor, patch)."""

        def once() -> tuple[int, int, int]:
            self.transport.write(EP_OUT, b"\x6b\x04", self._tmo_ms)
            r = self.transport.read(EP_IN_LOW, 64, self._tmo_ms)
            if len(r) != 3 or r[0] != 0x04:
                raise BadReply(r, "expected 3 bytes starting 04")
            d = struct.unpack("<H", r[1:])[0]
            return (d >> 12) & 0xF, (d >> 4) & 0xFF, d & 0xF

        return self._retry("0x6B read register 0x04", once)

    def raw_spectrum(self) -> np.ndarray:
        """0x09: one spectrum as raw counts (uint16, ``n_pixels``); checks the sync byte."""
        tmo = self._tmo_ms + int(self._itime_us / 1000)

        n = self.n_pixels

        def once() -> np.ndarray:
            self.transport.write(EP_OUT, b"\x09", self._tmo_ms)
            data = b""
            deadline = time.monotonic() + tmo / 1000
            while len(data) < 2 * n + 1:
                left = int(max(1, (deadline - time.monotonic()) * 1000))
                chunk = self.transport.read(EP_IN_SPECTRUM, 2 * n + 1 - len(data), left)
                if not chunk:
                    break
                data += chunk
                if len(chunk) % 512:
                    break  # short packet: end of the transfer
            if len(data) != 2 * n + 1 or data[-1] != SYNC:
                self._drain()
                raise BadReply(
                    data[-8:],
                    f"{len(data)} bytes, last {data[-1:]!r}: expected "
                    f"{2 * n + 1} bytes ending with sync byte 0x69",
                )
            return np.frombuffer(data[:-1], dtype="<u2").astype(np.uint16)

        return self._retry("0x09 request spectrum", once)

    def _drain(self) -> None:
        try:
            while self.transport.read(EP_IN_SPECTRUM, 8192, 20):
                pass
        except (TransportTimeout, TransportStall, TransportDisconnected):
            pass

    def intensities(self) -> np.ndarray:
        """Counts per pixel (float64) for one acquisition."""
        return self.raw_spectrum().astype(np.float64)

    def close(self) -> None:
        self.transport.close()
