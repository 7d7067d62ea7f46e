"""Transports the drivers talk through: a serial line (pyserial) and a USB device (pyusb).

Drivers take a transport object rather than opening ports themselves, so tests can hand them
a scripted transport (:mod:`gonio.drivers.testing`) and users can hand them anything with
the same few methods. Transports raise the three exceptions below; drivers turn them into
:class:`~gonio.drivers.errors.DeviceError` with the device, command and reply named.
"""

from __future__ import annotations

import errno
import time
from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

__all__ = [
    "LineTransport",
    "SerialTransport",
    "TransportDisconnected",
    "TransportStall",
    "TransportTimeout",
    "UsbTransport",
    "UsbTransportProtocol",
]


try:  # a vanished pty makes pyserial's tcdrain raise termios.error (not an OSError)
    import termios

    _TERMIOS_ERRORS: tuple[type[BaseException], ...] = (termios.error,)
except ImportError:  # pragma: no cover - not POSIX
    _TERMIOS_ERRORS = ()


class TransportTimeout(TimeoutError):
    """Nothing (or not enough) arrived in time."""


class TransportDisconnected(ConnectionError):
    """The port or device went away."""


class TransportStall(OSError):
    """A USB endpoint stalled (pipe error)."""


def _reopen(open_: Callable[[], None], timeout: float) -> None:
    """Call ``open_`` until it no longer raises TransportDisconnected, for ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            open_()
            return
        except TransportDisconnected:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.02)


@runtime_checkable
class LineTransport(Protocol):
    """What a line-oriented (RS-232 style) driver needs."""

    def write(self, data: bytes) -> None: ...

    def read_line(self, timeout: float) -> bytes: ...

    def flush_input(self) -> None: ...

    def reconnect(self) -> None: ...

    def close(self) -> None: ...


class SerialTransport:
    """A pyserial port (``/dev/ttyUSB0``, a pty path, or a URL like ``socket://127.0.0.1:4000``).

    Parameters
    ----------
    url : str
        Device path or any pyserial URL (``serial.serial_for_url``).
    baudrate : int
        19200 is the ESP300 factory setting (8 data bits, no parity, 1 stop bit).
    rtscts : bool
        Hardware handshake (the ESP300 uses RTS/CTS on a real cable).
    terminator : bytes
        The last byte of every reply line.
    """

    def __init__(
        self,
        url: str,
        *,
        baudrate: int = 19200,
        rtscts: bool = False,
        terminator: bytes = b"\n",
        reconnect_timeout: float = 2.0,
    ) -> None:
        self.url = str(url)
        self.reconnect_timeout = float(reconnect_timeout)
        self.baudrate = int(baudrate)
        self.rtscts = bool(rtscts)
        self.terminator = bytes(terminator)
        self._port: Any = None
        self._rx = bytearray()  # bytes read past the last returned line
        self._open()

    def _open(self) -> None:
        import serial

        try:
            self._port = serial.serial_for_url(
                self.url, baudrate=self.baudrate, rtscts=self.rtscts, timeout=0.1
            )
        except (serial.SerialException, OSError) as exc:
            raise TransportDisconnected(f"cannot open {self.url}: {exc}") from exc

    def write(self, data: bytes) -> None:
        import serial

        if self._port is None:
            raise TransportDisconnected(f"{self.url} is closed")
        try:
            self._port.write(data)
            self._port.flush()
        except (serial.SerialException, OSError, *_TERMIOS_ERRORS) as exc:
            raise TransportDisconnected(f"write to {self.url} failed: {exc}") from exc

    def read_line(self, timeout: float) -> bytes:
        """Read up to and including the terminator, or raise :class:`TransportTimeout`."""
        import serial

        if self._port is None:
            raise TransportDisconnected(f"{self.url} is closed")
        deadline = time.monotonic() + float(timeout)
        buf = self._rx
        term = self.terminator
        try:
            while True:
                end = buf.find(term)
                if end >= 0:  # a whole line is buffered: return it, keep the rest
                    line = bytes(buf[: end + len(term)])
                    del buf[: end + len(term)]
                    return line
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TransportTimeout(
                        f"no complete line from {self.url} within {timeout:g} s: {bytes(buf)!r}"
                    )
                # read what has arrived in one call (at least one byte, waiting up to the
                # deadline): pyserial's read_until costs one read() per byte
                t = 0.25 if left > 0.25 else left
                if self._port.timeout != t:  # setting it reconfigures the port (tcsetattr)
                    self._port.timeout = t
                buf += self._port.read(max(1, self._port.in_waiting))
        except TransportTimeout:
            raise
        except (serial.SerialException, OSError, *_TERMIOS_ERRORS) as exc:
            raise TransportDisconnected(f"read from {self.url} failed: {exc}") from exc

    def flush_input(self) -> None:
        if self._port is not None:
            try:
                time.sleep(0.01)
                self._port.reset_input_buffer()
            except Exception:
                pass
        self._rx.clear()

    def reconnect(self) -> None:
        """Close and reopen the port, trying until ``reconnect_timeout`` s have passed."""
        self.close()
        _reopen(self._open, self.reconnect_timeout)

    def close(self) -> None:
        self._rx.clear()
        if self._port is not None:
            try:
                self._port.close()
            finally:
                self._port = None


@runtime_checkable
class UsbTransportProtocol(Protocol):
    """What a USB driver needs: bulk/interrupt transfers by endpoint address."""

    def write(self, ep: int, data: bytes, timeout_ms: int) -> int: ...

    def read(self, ep: int, size: int, timeout_ms: int) -> bytes: ...

    def clear_halt(self, ep: int) -> None: ...

    def reconnect(self) -> None: ...

    def close(self) -> None: ...


def _map_usb_error(exc: Exception, what: str) -> Exception:
    import usb.core

    if isinstance(exc, usb.core.USBTimeoutError) or getattr(exc, "errno", None) == errno.ETIMEDOUT:
        return TransportTimeout(f"{what}: {exc}")
    if getattr(exc, "errno", None) == errno.EPIPE:
        return TransportStall(f"{what}: {exc}")
    if getattr(exc, "errno", None) in (errno.ENODEV, errno.EIO, errno.ENOENT):
        return TransportDisconnected(f"{what}: {exc}")
    return TransportDisconnected(f"{what}: {exc}")


class UsbTransport:
    """A pyusb device found by vendor/product id (and optionally serial number or class).

    Parameters
    ----------
    vendor, product : int
        USB ids.
    backend : pyusb backend or str, optional
        A backend object, or the name of a module under ``usb.backend`` (e.g. the name
        :func:`gonio.drivers.fake.usb.install` returns). Default: pyusb's choice.
    match : callable, optional
        Extra predicate on the ``usb.core.Device``.
    reconnect_timeout : float
        How long :meth:`reconnect` keeps looking for the device.
    """

    def __init__(
        self,
        vendor: int | None,
        product: int | None,
        *,
        backend: Any = None,
        match: Callable[[Any], bool] | None = None,
        reconnect_timeout: float = 2.0,
    ) -> None:
        self.vendor = vendor
        self.product = product
        self.backend = backend
        self.match = match
        self.reconnect_timeout = float(reconnect_timeout)
        self.device: Any = None
        self._open()

    def _backend(self) -> Any:
        if isinstance(self.backend, str):
            import importlib

            return importlib.import_module(f"usb.backend.{self.backend}").get_backend()
        return self.backend

    def _find(self) -> Any:
        import usb.core

        kw: dict[str, Any] = {}
        if self.vendor is not None:
            kw["idVendor"] = self.vendor
        if self.product is not None:
            kw["idProduct"] = self.product
        return usb.core.find(backend=self._backend(), custom_match=self.match, **kw)

    def _open(self) -> None:
        import usb.core

        dev = self._find()
        if dev is None:
            ids = f"{self.vendor or 0:04x}:{self.product or 0:04x}"
            raise TransportDisconnected(f"no USB device {ids} found")
        try:
            dev.set_configuration()
        except usb.core.USBError as exc:
            raise _map_usb_error(exc, "set_configuration") from exc
        self.device = dev

    def _call(self, what: str, fn: Callable[[Any], Any]) -> Any:
        """``fn(device)``, with pyusb errors mapped to the transport exceptions."""
        import usb.core

        if self.device is None:
            raise TransportDisconnected("device closed")
        try:
            return fn(self.device)
        except usb.core.USBError as exc:
            raise _map_usb_error(exc, what) from exc

    def write(self, ep: int, data: bytes, timeout_ms: int) -> int:
        return int(
            self._call(f"write EP 0x{ep:02x}", lambda d: d.write(ep, data, timeout=int(timeout_ms)))
        )

    def read(self, ep: int, size: int, timeout_ms: int) -> bytes:
        return bytes(
            self._call(f"read EP 0x{ep:02x}", lambda d: d.read(ep, size, timeout=int(timeout_ms)))
        )

    def ctrl_transfer(
        self,
        bm_request_type: int,
        b_request: int,
        w_value: int = 0,
        w_index: int = 0,
        data_or_length: Any = None,
        timeout_ms: int = 1000,
    ) -> Any:
        return self._call(
            f"control request 0x{b_request:02x}",
            lambda d: d.ctrl_transfer(
                bm_request_type, b_request, w_value, w_index, data_or_length, timeout=timeout_ms
            ),
        )

    def clear_halt(self, ep: int) -> None:
        self._call(f"clear_halt EP 0x{ep:02x}", lambda d: d.clear_halt(ep))

    def reconnect(self) -> None:
        """Drop the handle and look for the device again until ``reconnect_timeout``."""
        self.close()
        _reopen(self._open, self.reconnect_timeout)

    def close(self) -> None:
        if self.device is not None:
            import usb.util

            try:
                usb.util.dispose_resources(self.device)
            except Exception:
                pass
            self.device = None
