"""Fault injection shared by the fake devices.

Every fake owns a :class:`Faults`; tests (or ``gonio devices serve`` users) set its counters
and the fake applies them to the next bytes or transfers: dropped or corrupted bytes in either
direction, delayed replies, USB timeouts and pipe errors (stalls), and a disconnect in the
middle of a reply. Counters count down as they fire, so a fault is one-shot unless re-armed.
Device-specific faults (a motor amplifier fault, a stall at a limit) are methods of the fakes.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

__all__ = ["Faults"]


@dataclass
class Faults:
    """Armed faults (all off by default).

    Attributes
    ----------
    drop_reply_bytes, corrupt_reply_bytes : int
        Drop / corrupt (XOR 0x80) the next n bytes the device sends.
    drop_command_bytes, corrupt_command_bytes : int
        Drop / corrupt the next n bytes the device receives.
    reply_delay : float
        Real seconds added before each of the next ``delayed_replies`` replies
        (``delayed_replies=-1``: every reply).
    usb_timeouts, usb_pipe_errors : int
        The next n USB transfers time out (ETIMEDOUT, after the caller's timeout) / stall
        (EPIPE) instead of moving data.
    disconnect_after_bytes : int or None
        Unplug after this many more reply bytes (0: at once, i.e. before a reply).
    reconnect_after : float
        Real seconds until an unplugged device comes back.
    """

    drop_reply_bytes: int = 0
    corrupt_reply_bytes: int = 0
    drop_command_bytes: int = 0
    corrupt_command_bytes: int = 0
    reply_delay: float = 0.0
    delayed_replies: int = 0
    usb_timeouts: int = 0
    usb_pipe_errors: int = 0
    disconnect_after_bytes: int | None = None
    reconnect_after: float = 0.05
    log: list[str] = field(default_factory=list)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def _mangle(self, data: bytes, drop_attr: str, corrupt_attr: str, what: str) -> bytes:
        with self._lock:
            out = bytearray()
            for b in data:
                if getattr(self, drop_attr) > 0:
                    setattr(self, drop_attr, getattr(self, drop_attr) - 1)
                    self.log.append(f"dropped {what} byte {b:#04x}")
                    continue
                if getattr(self, corrupt_attr) > 0:
                    setattr(self, corrupt_attr, getattr(self, corrupt_attr) - 1)
                    self.log.append(f"corrupted {what} byte {b:#04x}")
                    b ^= 0x80
                out.append(b)
            return bytes(out)

    def filter_reply(self, data: bytes) -> bytes:
        """Apply reply-side drop/corrupt faults to bytes the device is about to send."""
        if not (self.drop_reply_bytes or self.corrupt_reply_bytes):
            return data
        return self._mangle(data, "drop_reply_bytes", "corrupt_reply_bytes", "reply")

    def filter_command(self, data: bytes) -> bytes:
        """Apply command-side faults to bytes the device received."""
        if not (self.drop_command_bytes or self.corrupt_command_bytes):
            return data
        return self._mangle(data, "drop_command_bytes", "corrupt_command_bytes", "command")

    def take_delay(self) -> float:
        """Seconds to hold the next reply (and count it down)."""
        with self._lock:
            if self.reply_delay <= 0 or self.delayed_replies == 0:
                return 0.0
            if self.delayed_replies > 0:
                self.delayed_replies -= 1
            self.log.append(f"delayed reply by {self.reply_delay:g} s")
            return self.reply_delay

    def take(self, attr: str) -> bool:
        """Consume one count of ``usb_timeouts`` / ``usb_pipe_errors``; True if it fired."""
        with self._lock:
            n = getattr(self, attr)
            if n > 0:
                setattr(self, attr, n - 1)
                self.log.append(attr)
                return True
            return False

    def split_for_disconnect(self, data: bytes) -> tuple[bytes, bool]:
        """``(bytes to send, unplug_after)`` under ``disconnect_after_bytes``."""
        with self._lock:
            n = self.disconnect_after_bytes
            if n is None:
                return data, False
            if len(data) < n:
                self.disconnect_after_bytes = n - len(data)
                return data, False
            self.disconnect_after_bytes = None
            self.log.append(f"disconnect after {n} of {len(data)} bytes")
            return data[:n], True
