"""Scripted transports for exact-bytes driver tests (pymeasure's ``expected_protocol`` style).

Every write the driver makes and every reply the device gives is pinned in order; a write
that differs, a read with nothing scripted, or anything left over at the end fails the test.

>>> from gonio.drivers.testing import ScriptedLineTransport
>>> t = ScriptedLineTransport([(b"VE?\\r\\n", b"ESP300 Version 3.08 09/09/02\\r\\n")])
>>> t.write(b"VE?\\r\\n"); t.read_line(1.0)
b'ESP300 Version 3.08 09/09/02\\r\\n'
>>> t.assert_done()
"""

from __future__ import annotations

from collections.abc import Sequence

from gonio.drivers.transport import TransportTimeout

__all__ = ["ScriptError", "ScriptedLineTransport", "ScriptedUsbTransport"]


class ScriptError(AssertionError):
    """The driver did not follow the script."""


class _Scripted:
    """What both scripted transports share: the script, its position, reconnects, close."""

    def __init__(self, script: Sequence[tuple]) -> None:
        self.script = list(script)
        self.pos = 0
        self.reconnects = 0

    def reconnect(self) -> None:
        self.reconnects += 1

    def close(self) -> None:
        pass

    def assert_done(self) -> None:
        """Raise :class:`ScriptError` if scripted steps were left unplayed."""
        if self.pos != len(self.script):
            raise ScriptError(
                f"{len(self.script) - self.pos} scripted steps left over: "
                f"{self.script[self.pos :]!r}"
            )


class ScriptedLineTransport(_Scripted):
    """A line transport replaying ``[(expected_write, reply_or_None_or_exception), ...]``."""

    def __init__(self, script: Sequence[tuple[bytes, bytes | BaseException | None]]) -> None:
        super().__init__(script)
        self._pending = bytearray()
        self._exc: BaseException | None = None
        self.flushes = 0

    def write(self, data: bytes) -> None:
        if self.pos >= len(self.script):
            raise ScriptError(f"unexpected write {bytes(data)!r}: script exhausted")
        expected, reply = self.script[self.pos]
        if bytes(data) != expected:
            raise ScriptError(f"step {self.pos}: wrote {bytes(data)!r}, expected {expected!r}")
        self.pos += 1
        if isinstance(reply, BaseException):
            self._exc = reply
        elif reply is not None:
            self._pending += reply

    def read_line(self, timeout: float) -> bytes:
        if self._exc is not None:
            exc, self._exc = self._exc, None
            raise exc
        i = self._pending.find(b"\n")
        if i < 0:
            raise TransportTimeout(f"no scripted reply (pending {bytes(self._pending)!r})")
        line = bytes(self._pending[: i + 1])
        del self._pending[: i + 1]
        return line

    def flush_input(self) -> None:
        self.flushes += 1
        self._pending.clear()

    def assert_done(self) -> None:
        super().assert_done()
        if self._pending:
            raise ScriptError(f"unread reply bytes left over: {bytes(self._pending)!r}")


class ScriptedUsbTransport(_Scripted):
    """A USB transport replaying ``[("out", ep, bytes) | ("in", ep, bytes_or_exception), ...]``.

    ``"in"`` steps give what one ``read`` returns (a short packet ends the transfer, as on
    the bus); the driver's requested size must be at least its length.
    """

    def __init__(self, script: Sequence[tuple[str, int, object]]) -> None:
        super().__init__(script)
        self.halts_cleared: list[int] = []

    def _next(self, kind: str, ep: int) -> object:
        if self.pos >= len(self.script):
            raise ScriptError(f"unexpected {kind} on EP 0x{ep:02x}: script exhausted")
        k, e, payload = self.script[self.pos]
        if (k, e) != (kind, ep):
            raise ScriptError(
                f"step {self.pos}: {kind} on EP 0x{ep:02x}, expected {k} on EP 0x{e:02x}"
            )
        self.pos += 1
        return payload

    def write(self, ep: int, data: bytes, timeout_ms: int) -> int:
        expected = self._next("out", ep)
        if bytes(data) != expected:
            raise ScriptError(f"step {self.pos - 1}: wrote {bytes(data)!r}, expected {expected!r}")
        return len(data)

    def read(self, ep: int, size: int, timeout_ms: int) -> bytes:
        payload = self._next("in", ep)
        if isinstance(payload, BaseException):
            raise payload
        data = bytes(payload)  # type: ignore[arg-type]
        if len(data) > size:
            raise ScriptError(f"step {self.pos - 1}: read of {size} bytes but {len(data)} scripted")
        return data

    def clear_halt(self, ep: int) -> None:
        self.halts_cleared.append(ep)
