"""Newport ESP300 three-axis motion controller over RS-232 (pyserial).

The ESP300 speaks ASCII: each command is an optional axis number, a two-letter mnemonic and
an optional parameter or ``?`` (``1PA10.5``, ``2TP``, ``3MD?``, ``VE?``), several may share a
line separated by ``;``, and a line ends with a terminator (this driver sends ``\\r\\n``).
Queries answer one line ending ``\\r\\n``; commands answer nothing, and errors go to a
10-deep FIFO read with ``TE?`` (code) or ``TB?`` (``"code, timestamp, MESSAGE"``). Axis
errors are coded ``100·axis + n`` (e.g. 104 "POSITIVE HARDWARE LIMIT DETECTED" on axis 1).

Commands used: ``PA`` ``PR`` ``TP`` ``MD?`` ``MO`` ``MF`` ``MO?`` ``OR`` ``DH`` ``VA``/``VA?``
``AC``/``AC?`` ``SL``/``SL?`` ``SR``/``SR?`` ``WS`` ``ST`` ``SN?`` ``TE?`` ``TB?`` ``VE?``
``ID?``.

References
----------
Newport, *ESP300 Motion Controller/Driver User's Manual*, ch. 3 (remote mode command syntax,
command reference, error messages); the axis/general error tables follow that chapter.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from typing import Any, TypeVar

from gonio.drivers._retry import check_timeout
from gonio.drivers.errors import DeviceDisconnected, DeviceError, DeviceTimeout
from gonio.drivers.transport import (
    LineTransport,
    SerialTransport,
    TransportDisconnected,
    TransportTimeout,
)

__all__ = ["ESP300", "UNIT_CODES", "ESP300Axis", "format_number"]

DEVICE = "ESP300"
T = TypeVar("T")

#: ``SN`` unit codes of the ESP300 (manual, command SN).
UNIT_CODES = {
    0: "count",
    1: "step",
    2: "mm",
    3: "um",
    4: "in",
    5: "mil",
    6: "uin",
    7: "deg",
    8: "grad",
    9: "rad",
    10: "mrad",
    11: "urad",
}


def format_number(x: float) -> str:
    """A parameter as the ESP300 takes it: plain decimal, up to 6 decimals, no exponent.

    >>> format_number(10.0), format_number(-12.5), format_number(0.1234567)
    ('10', '-12.5', '0.123457')
    """
    x = float(x)
    if x != x or x in (float("inf"), float("-inf")):
        raise ValueError(f"value={x!r}: expected a finite number")
    s = f"{x:.6f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def _parse_float(s: str) -> float:
    return float(s)


def _parse_bool(s: str) -> bool:
    if s not in ("0", "1"):
        raise ValueError(f"expected 0 or 1, got {s!r}")
    return s == "1"


class ESP300:
    """Driver for a Newport ESP300.

    Parameters
    ----------
    transport : LineTransport
        E.g. ``SerialTransport("/dev/ttyUSB0")`` or a pty path from ``gonio devices serve``.
    axes : mapping of str to int
        Axis names → controller axis numbers (1-3). Default ``{"1": 1, "2": 2, "3": 3}``.
    units : mapping of str to str, optional
        Units per axis name; queried with ``SN?`` on first use when not given.
    timeout : float
        Seconds to wait for any one reply.
    retries : int
        Extra attempts for idempotent queries and commands after a timeout, a garbled reply
        or a reconnect.
    """

    device = DEVICE

    def __init__(
        self,
        transport: LineTransport,
        *,
        axes: Mapping[str, int] | None = None,
        units: Mapping[str, str] | None = None,
        timeout: float = 2.0,
        retries: int = 2,
    ) -> None:
        self.transport = transport
        self.timeout = check_timeout(timeout)
        self.retries = int(retries)
        axes = dict(axes) if axes is not None else {"1": 1, "2": 2, "3": 3}
        for name, num in axes.items():
            if int(num) not in (1, 2, 3):
                raise ValueError(f"axes[{name!r}]={num!r}: expected axis number 1, 2 or 3")
        units = dict(units or {})
        self._axes = {n: ESP300Axis(self, n, int(k), units.get(n)) for n, k in axes.items()}
        self._dirty = False

    @classmethod
    def open(
        cls, port: str, *, baudrate: int = 19200, rtscts: bool = True, **kwargs: Any
    ) -> ESP300:
        """Open a serial port (path or pyserial URL) and return the driver.

        The ESP300's RS-232 settings: 19200 baud, 8 data bits, no parity, 1 stop bit,
        RTS/CTS hardware handshake (ignored by pseudo-terminals and TCP URLs).
        """
        try:
            transport = SerialTransport(port, baudrate=baudrate, rtscts=rtscts)
        except TransportDisconnected as exc:
            raise DeviceDisconnected(DEVICE, "open", None, str(exc)) from exc
        return cls(transport, **kwargs)

    # -- low level ------------------------------------------------------------------------
    def _write(self, command: str) -> None:
        if self._dirty:
            self.transport.flush_input()
            self._dirty = False
        self.transport.write(command.encode("ascii") + b"\r\n")

    def _attempts(
        self, command: str, fn: Callable[[], T], idempotent: bool, retries: int | None = None
    ) -> T:
        last: BaseException | None = None
        reply: object = None
        n = (self.retries if retries is None else int(retries)) + 1 if idempotent else 1
        for attempt in range(n):
            try:
                return fn()
            except TransportDisconnected as exc:
                last = exc
                try:
                    self.transport.reconnect()
                except TransportDisconnected as exc2:
                    raise DeviceDisconnected(DEVICE, command, None, str(exc2)) from exc2
                if not idempotent:
                    raise DeviceDisconnected(
                        DEVICE,
                        command,
                        None,
                        f"link lost ({exc}); reconnected but not resending a relative command",
                    ) from exc
            except TransportTimeout as exc:
                last = exc
                if attempt + 1 < n:
                    self._drain_late()
                else:
                    self._dirty = True
            except (UnicodeDecodeError, ValueError) as exc:
                last, self._dirty = exc, True
                reply = getattr(exc, "reply", reply)
        if isinstance(last, TransportTimeout):
            raise DeviceTimeout(DEVICE, command, reply, str(last)) from last
        raise DeviceError(DEVICE, command, reply, f"bad reply: {last}") from last

    def _drain_late(self) -> None:
        """After a timeout, give a late reply one more ``timeout`` to arrive, and discard it.

        ASCII replies carry no sequence number, so a reply that comes late would otherwise be
        taken as the answer to the next query.
        """
        try:
            self.transport.read_line(self.timeout)
        except (TransportTimeout, TransportDisconnected):
            pass
        self.transport.flush_input()

    def query(
        self,
        command: str,
        parse: Callable[[str], T] = str,  # type: ignore[assignment]
        *,
        timeout: float | None = None,
        retries: int | None = None,
    ) -> T:
        """Send a query and return its parsed reply (retried on timeout or a garbled reply)."""
        tmo = self.timeout if timeout is None else float(timeout)

        def once() -> T:
            self._write(command)
            raw = self.transport.read_line(tmo)
            try:
                text = raw.decode("ascii").strip()
                if not text or any(not (32 <= ord(c) < 127) for c in text):
                    raise ValueError(f"garbled reply {raw!r}")
                return parse(text)
            except (UnicodeDecodeError, ValueError) as exc:
                err = ValueError(f"cannot parse reply {raw!r} to {command!r}: {exc}")
                err.reply = raw  # type: ignore[attr-defined]
                raise err from exc

        return self._attempts(command, once, idempotent=True, retries=retries)

    def command(self, command: str, *, idempotent: bool = True, check: bool = True) -> None:
        """Send a command (no reply), then read the error buffer with ``TB?``."""
        self._attempts(command, lambda: self._write(command), idempotent)
        if check:
            self.check_error(command)

    def error(self) -> tuple[int, int, str]:
        """``TB?``: the oldest error as ``(code, timestamp, message)``; code 0 = none."""

        def parse(s: str) -> tuple[int, int, str]:
            parts = [p.strip() for p in s.split(",", 2)]
            if len(parts) != 3:
                raise ValueError(f"expected 'code, timestamp, message', got {s!r}")
            return int(parts[0]), int(parts[1]), parts[2]

        return self.query("TB?", parse)

    def error_code(self) -> int:
        """``TE?``: the oldest error code (0 = none)."""
        return self.query("TE?", int)

    def check_error(self, command: str) -> None:
        code, _, msg = self.error()
        if code != 0:
            raise DeviceError(DEVICE, command, f"{code}, {msg}", f"controller error {code}: {msg}")

    def version(self) -> str:
        """``VE?``: firmware version string."""
        return self.query("VE?")

    # -- MotionController -----------------------------------------------------------------
    @property
    def axes(self) -> dict[str, ESP300Axis]:
        return dict(self._axes)

    def axis(self, name: str) -> ESP300Axis:
        try:
            return self._axes[name]
        except KeyError:
            raise ValueError(f"name={name!r}: expected one of {sorted(self._axes)}") from None

    def enable(self) -> None:
        """``MO`` on every axis."""
        for ax in self._axes.values():
            ax.motor_on()

    def disable(self) -> None:
        """``MF`` on every axis."""
        for ax in self._axes.values():
            ax.motor_off()

    def close(self) -> None:
        self.transport.close()


class ESP300Axis:
    """One axis of an :class:`ESP300` (implements :class:`~gonio.drivers.interfaces.Axis`)."""

    def __init__(self, ctl: ESP300, name: str, number: int, units: str | None) -> None:
        self.ctl = ctl
        self.name = name
        self.number = number
        self._units = units

    def _c(self, mnemonic: str, arg: str = "") -> str:
        return f"{self.number}{mnemonic}{arg}"

    @property
    def units(self) -> str:
        """Units of the axis (``SN?`` on first use unless given to the controller)."""
        if self._units is None:
            code = self.ctl.query(self._c("SN?"), int)
            self._units = UNIT_CODES.get(code, f"unit{code}")
        return self._units

    # motion
    def move_to(self, position: float) -> None:
        """``PA``: absolute move."""
        self.ctl.command(self._c("PA", format_number(position)))

    def move_by(self, delta: float) -> None:
        """``PR``: relative move (never resent after a lost link)."""
        self.ctl.command(self._c("PR", format_number(delta)), idempotent=False)

    def position(self) -> float:
        """``TP``: actual position."""
        return self.ctl.query(self._c("TP"), _parse_float)

    def is_moving(self) -> bool:
        """``MD?`` reads 0 while moving."""
        return not self.ctl.query(self._c("MD?"), _parse_bool)

    def wait(self, timeout: float = 60.0) -> float:
        """``WS`` then ``MD?``: block until the axis stops; check errors; the position.

        The controller holds the ``MD?`` reply until the motion is done, so one round trip
        covers the wait; the read is bounded by ``timeout``.
        """
        deadline = time.monotonic() + float(timeout)
        self.ctl.command(self._c("WS"), check=False)
        while True:
            left = deadline - time.monotonic()
            try:
                if left > 0 and self.ctl.query(
                    self._c("MD?"), _parse_bool, timeout=max(left, 0.05), retries=0
                ):
                    break
            except DeviceTimeout:
                pass
            if deadline - time.monotonic() <= 0:
                self.stop()
                raise DeviceTimeout(
                    DEVICE,
                    self._c("WS"),
                    None,
                    f"axis {self.name} still moving after {timeout:g} s",
                )
            time.sleep(0.005)
        self.ctl.check_error(self._c("WS"))
        return self.position()

    def stop(self) -> None:
        """``ST``: decelerate to a stop."""
        self.ctl.command(self._c("ST"))

    def home(self) -> None:
        """``OR``: search the home switch; the position reads 0 there."""
        self.ctl.command(self._c("OR"), idempotent=False)

    def define_home(self, position: float = 0.0) -> None:
        """``DH``: call the current position ``position``."""
        self.ctl.command(self._c("DH", format_number(position)))

    # motor power
    def motor_on(self) -> None:
        self.ctl.command(self._c("MO"))

    def motor_off(self) -> None:
        self.ctl.command(self._c("MF"))

    def is_motor_on(self) -> bool:
        return self.ctl.query(self._c("MO?"), _parse_bool)

    # parameters
    def limits(self) -> tuple[float, float]:
        """``SL?``, ``SR?``: software travel limits."""
        return (
            self.ctl.query(self._c("SL?"), _parse_float),
            self.ctl.query(self._c("SR?"), _parse_float),
        )

    def set_limits(self, low: float, high: float) -> None:
        if not float(low) < float(high):
            raise ValueError(f"low={low!r}, high={high!r}: expected low < high")
        self.ctl.command(self._c("SL", format_number(low)))
        self.ctl.command(self._c("SR", format_number(high)))

    def _set_positive(self, name: str, code: str, value: float) -> None:
        """Send ``code`` with ``value``, which must be > 0 (``name`` is for the error)."""
        if not float(value) > 0:
            raise ValueError(f"{name}={value!r}: expected > 0")
        self.ctl.command(self._c(code, format_number(value)))

    @property
    def velocity(self) -> float:
        return self.ctl.query(self._c("VA?"), _parse_float)

    @velocity.setter
    def velocity(self, value: float) -> None:
        self._set_positive("velocity", "VA", value)

    @property
    def acceleration(self) -> float:
        return self.ctl.query(self._c("AC?"), _parse_float)

    @acceleration.setter
    def acceleration(self, value: float) -> None:
        self._set_positive("acceleration", "AC", value)

    def identify(self) -> str:
        """``ID?``: stage model and serial number."""
        return self.ctl.query(self._c("ID?"))
