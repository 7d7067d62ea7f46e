"""Errors raised by the device drivers."""

from __future__ import annotations

__all__ = ["DeviceDisconnected", "DeviceError", "DeviceTimeout"]


class DeviceError(RuntimeError):
    """A device did not do what it was asked.

    Parameters
    ----------
    device : str
        Which device (``"ESP300"``, ``"USB2000+"``, ``"PTP camera"``).
    command : str
        The command that failed, as sent (e.g. ``"1PA10"`` or ``"0x09 request spectrum"``).
    reply : object
        What the device answered (bytes, text or a decoded code); ``None`` if nothing.
    message : str
        What went wrong.
    """

    def __init__(self, device: str, command: str, reply: object, message: str) -> None:
        self.device = device
        self.command = command
        self.reply = reply
        self.message = message
        super().__init__(f"{device}: command {command!r} failed: {message} (reply: {reply!r})")


class DeviceTimeout(DeviceError):
    """No (complete) reply within the timeout."""


class DeviceDisconnected(DeviceError):
    """The device went away and could not be reconnected."""
