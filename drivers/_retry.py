"""Retry and recovery plumbing shared by the USB drivers (PTP camera, USB2000+).

Both drivers run each idempotent operation through :func:`retry`: a lost link is reconnected,
a stalled endpoint cleared, a timeout or a garbled reply (:class:`BadReply`) retried, and the
last failure is turned into the matching :class:`~gonio.drivers.errors.DeviceError`. What
each driver does to recover (restore its settings, reopen a session, drain an endpoint) is
passed in as callables.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any, TypeVar

from gonio.drivers.errors import DeviceDisconnected, DeviceError, DeviceTimeout
from gonio.drivers.transport import (
    TransportDisconnected,
    TransportStall,
    TransportTimeout,
    UsbTransport,
    UsbTransportProtocol,
)

__all__ = ["BadReply", "check_timeout", "clear_halts", "open_usb", "reconnect", "retry"]

T = TypeVar("T")


class BadReply(Exception):
    """A reply that arrived but does not parse; ``reply`` holds the offending bytes."""

    def __init__(self, reply: bytes, message: str) -> None:
        super().__init__(message)
        self.reply = bytes(reply)


def check_timeout(timeout: float) -> float:
    """``timeout`` as a float, or ``ValueError`` unless it is a positive number of seconds."""
    value = float(timeout)
    if value <= 0:
        raise ValueError(f"timeout={timeout!r}: expected a positive number of seconds")
    return value


def open_usb(
    device: str,
    vendor: int | None,
    product: int | None,
    backend: Any = None,
    match: Callable[[Any], bool] | None = None,
) -> UsbTransport:
    """A :class:`UsbTransport`; a device not found raises :class:`DeviceDisconnected`."""
    try:
        return UsbTransport(vendor, product, backend=backend, match=match)
    except TransportDisconnected as exc:
        raise DeviceDisconnected(device, "find", None, str(exc)) from exc


def reconnect(transport: UsbTransportProtocol, device: str) -> None:
    """``transport.reconnect()``; giving up raises :class:`DeviceDisconnected`."""
    try:
        transport.reconnect()
    except TransportDisconnected as exc:
        raise DeviceDisconnected(device, "reconnect", None, str(exc)) from exc


def clear_halts(
    transport: UsbTransportProtocol, endpoints: Iterable[int], recover: Callable[[], None]
) -> bool:
    """Clear the halt on each endpoint; on a lost link call ``recover`` and return ``False``."""
    for ep in endpoints:
        try:
            transport.clear_halt(ep)
        except TransportDisconnected:
            recover()
            return False
    return True


def retry(
    device: str,
    command: str,
    fn: Callable[[], T],
    attempts: int,
    *,
    recover: Callable[[], None],
    clear_stall: Callable[[], None],
    after_error: Callable[[], None] | None = None,
) -> T:
    """``fn()``, tried up to ``attempts`` times, recovering between attempts.

    A :class:`TransportDisconnected` calls ``recover``, a :class:`TransportStall` calls
    ``clear_stall``, and a :class:`TransportTimeout` or :class:`BadReply` calls
    ``after_error`` (if given) before the next attempt. When all attempts fail, the last
    failure is raised as :class:`DeviceTimeout` (timeout), :class:`DeviceError` with the reply
    (bad reply) or :class:`DeviceError` ("gave up"). Other exceptions are not retried. The
    loop is ``tenacity``'s (no wait between attempts: the recovery is the pause).
    """
    import tenacity

    def between(state: tenacity.RetryCallState) -> None:
        exc = state.outcome.exception() if state.outcome is not None else None
        if isinstance(exc, TransportDisconnected):
            recover()
        elif isinstance(exc, TransportStall):
            clear_stall()
        elif after_error is not None:
            after_error()

    try:
        for attempt in tenacity.Retrying(
            stop=tenacity.stop_after_attempt(max(1, int(attempts))),
            retry=tenacity.retry_if_exception_type(_RETRIED),
            after=between,
            reraise=True,
        ):
            with attempt:
                return fn()
    except TransportTimeout as last:
        raise DeviceTimeout(device, command, None, str(last)) from last
    except BadReply as last:
        raise DeviceError(device, command, last.reply, str(last)) from last
    except (TransportDisconnected, TransportStall) as last:
        raise DeviceError(device, command, None, f"gave up: {last}") from last
    raise AssertionError("unreachable")  # pragma: no cover  (tenacity returns or raises)


#: The failures :func:`retry` retries (after its recovery step).
_RETRIED = (TransportDisconnected, TransportStall, TransportTimeout, BadReply)
