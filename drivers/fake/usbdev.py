"""USB device model shared by the fake USB2000+ and the fake PTP camera.

A :class:`FakeUsbDevice` has standard descriptors (device, configuration, interface,
endpoint, string), answers standard control requests on endpoint 0, and moves data in
packets: IN endpoints hold queues of packets (each at most ``wMaxPacketSize``; a short
packet ends a transfer, as on the bus), OUT transfers are handed to the firmware's
:meth:`FakeUsbDevice.on_out`. Faults (:class:`~gonio.drivers.fake.faults.Faults`) turn
transfers into timeouts (after the caller's timeout), pipe errors (the endpoint halts until
``clear_halt``) or an unplug part-way through a reply.
"""

from __future__ import annotations

import abc
import errno
import itertools
import struct
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import ClassVar

import usb.core
from gonio.drivers.fake.faults import Faults

__all__ = ["Endpoint", "FakeUsbDevice", "Interface", "usb_error"]

_addresses = itertools.count(2)

LIBUSB = {  # libusb error code, errno, text (as pyusb's libusb1 backend reports them)
    "timeout": (-7, errno.ETIMEDOUT, "Operation timed out"),
    "pipe": (-9, errno.EPIPE, "Pipe error"),
    "nodev": (-4, errno.ENODEV, "No such device (it may have been disconnected)"),
    "overflow": (-8, errno.EOVERFLOW, "Overflow"),
    "inval": (-2, errno.EINVAL, "Invalid parameter"),
}


#: Most packets an IN endpoint holds for the host (128 Ki packets: 64 MiB of 512-byte bulk
#: packets, a 4096 x 4096 16-bit image twice over). While one holds more, the device NAKs
#: every OUT transfer (the host's write times out) and its firmware sees no new command: a
#: host that writes commands and never reads the replies cannot grow the queues without bound.
MAX_QUEUED_PACKETS = 1 << 17


def usb_error(kind: str) -> usb.core.USBError:
    """The exception pyusb's libusb1 backend raises for ``kind``."""
    code, err, text = LIBUSB[kind]
    if kind == "timeout":
        return usb.core.USBTimeoutError(text, code, err)
    return usb.core.USBError(text, code, err)


@dataclass
class Endpoint:
    address: int
    attributes: int  # 2 bulk, 3 interrupt
    max_packet: int
    interval: int = 0

    def descriptor(self) -> _Desc:
        return _Desc(
            bLength=7,
            bDescriptorType=5,
            bEndpointAddress=self.address,
            bmAttributes=self.attributes,
            wMaxPacketSize=self.max_packet,
            bInterval=self.interval,
            bRefresh=0,
            bSynchAddress=0,
            extra_descriptors=[],
        )


@dataclass
class Interface:
    number: int
    cls: int
    subclass: int
    protocol: int
    endpoints: list[Endpoint] = field(default_factory=list)
    string_index: int = 0


class _Desc:
    def __init__(self, **kw: object) -> None:
        self.__dict__.update(kw)


class FakeUsbDevice(abc.ABC):
    """Base class: descriptors, packet queues, faults, plug state.

    Subclasses set ``vendor``, ``product``, ``bcd_device``, ``strings`` (index → text),
    ``interfaces`` and implement :meth:`on_out` and optionally :meth:`on_reset`.
    """

    vendor = 0
    product = 0
    bcd_device = 0x0100
    device_class = 0
    manufacturer_index, product_index, serial_index = 1, 2, 3
    strings: ClassVar[dict[int, str]] = {}
    interfaces: ClassVar[list[Interface]] = []
    max_power_ma = 500
    name = "usb device"

    def __init__(self, faults: Faults | None = None, bus: int = 1) -> None:
        self.faults = faults or Faults()
        self.bus = bus
        self.address = next(_addresses)
        self.generation = 0
        self.configuration = 1  # the host configures a device as soon as it is enumerated
        self.present = True
        self._back_at = 0.0
        self._cond = threading.Condition()
        self._in: dict[int, deque[tuple[float, bytes]]] = {}
        self._halted: set[int] = set()
        self.endpoints = {ep.address: ep for i in self.interfaces for ep in i.endpoints}
        for ep in self.endpoints.values():
            if ep.address & 0x80:
                self._in[ep.address] = deque()

    # -- plug state -------------------------------------------------------------------------
    def check_plugged(self) -> None:
        """Come back after an unplug once ``reconnect_after`` has passed."""
        if not self.present and time.monotonic() >= self._back_at:
            self.present = True
            self.address = next(_addresses)  # re-enumerated at a new address
            self.generation += 1
            self.configuration = 1
            self._reset_queues()
            self.on_reset()

    def unplug(self) -> None:
        with self._cond:
            self.present = False
            self._back_at = time.monotonic() + self.faults.reconnect_after
            self._reset_queues()
            self._cond.notify_all()

    def _reset_queues(self) -> None:
        for q in self._in.values():
            q.clear()
        self._halted.clear()

    def on_reset(self) -> None:  # noqa: B027 - optional hook, nothing to reset by default
        """Firmware state after power-up / bus reset."""

    # -- descriptors ------------------------------------------------------------------------
    def device_descriptor(self) -> _Desc:
        return _Desc(
            bLength=18,
            bDescriptorType=1,
            bcdUSB=0x0200,
            bDeviceClass=self.device_class,
            bDeviceSubClass=0,
            bDeviceProtocol=0,
            bMaxPacketSize0=64,
            idVendor=self.vendor,
            idProduct=self.product,
            bcdDevice=self.bcd_device,
            iManufacturer=self.manufacturer_index,
            iProduct=self.product_index,
            iSerialNumber=self.serial_index,
            bNumConfigurations=1,
            address=self.address,
            bus=self.bus,
            port_number=self.address % 8 + 1,
            port_numbers=(self.address % 8 + 1,),
            speed=3,  # 3 = high speed (480 Mbit/s)
        )

    def config_descriptor(self) -> _Desc:
        total = 9 + sum(9 + 7 * len(i.endpoints) for i in self.interfaces)
        return _Desc(
            bLength=9,
            bDescriptorType=2,
            wTotalLength=total,
            bNumInterfaces=len(self.interfaces),
            bConfigurationValue=1,
            iConfiguration=0,
            bmAttributes=0x80,
            bMaxPower=self.max_power_ma // 2,
            extra_descriptors=[],
        )

    def interface_descriptor(self, intf: int) -> _Desc:
        i = self.interfaces[intf]
        return _Desc(
            bLength=9,
            bDescriptorType=4,
            bInterfaceNumber=i.number,
            bAlternateSetting=0,
            bNumEndpoints=len(i.endpoints),
            bInterfaceClass=i.cls,
            bInterfaceSubClass=i.subclass,
            bInterfaceProtocol=i.protocol,
            iInterface=i.string_index,
            extra_descriptors=[],
        )

    def raw_descriptor(self, dtype: int, index: int, langid: int) -> bytes:
        """Bytes of a GET_DESCRIPTOR answer (device, configuration, string)."""
        if dtype == 1:
            d = self.device_descriptor()
            return struct.pack(
                "<BBHBBBBHHHBBBB",
                18,
                1,
                d.bcdUSB,
                d.bDeviceClass,
                0,
                0,
                64,
                d.idVendor,
                d.idProduct,
                d.bcdDevice,
                d.iManufacturer,
                d.iProduct,
                d.iSerialNumber,
                1,
            )
        if dtype == 2:
            c = self.config_descriptor()
            out = struct.pack(
                "<BBHBBBBB", 9, 2, c.wTotalLength, c.bNumInterfaces, 1, 0, 0x80, c.bMaxPower
            )
            for k, i in enumerate(self.interfaces):
                out += struct.pack(
                    "<BBBBBBBBB",
                    9,
                    4,
                    i.number,
                    0,
                    len(i.endpoints),
                    i.cls,
                    i.subclass,
                    i.protocol,
                    i.string_index,
                )
                del k
                for ep in i.endpoints:
                    out += struct.pack(
                        "<BBBBHB", 7, 5, ep.address, ep.attributes, ep.max_packet, ep.interval
                    )
            return out
        if dtype == 3:
            if index == 0:
                return struct.pack("<BBH", 4, 3, 0x0409)
            text = self.strings.get(index)
            if text is None:
                raise usb_error("pipe")
            enc = text.encode("utf-16-le")
            return bytes([2 + len(enc), 3]) + enc
        raise usb_error("pipe")

    # -- data path --------------------------------------------------------------------------
    def queue_in(
        self, ep: int, data: bytes, ready_at: float | None = None, zlp: bool = True
    ) -> None:
        """Queue one IN transfer on ``ep``: split into packets; a zero-length packet follows
        when the length is a non-zero multiple of ``wMaxPacketSize`` and ``zlp`` is set."""
        ready = time.monotonic() if ready_at is None else ready_at
        ready += self.faults.take_delay()
        data = self.faults.filter_reply(bytes(data))
        mp = self.endpoints[ep].max_packet
        packets = [data[i : i + mp] for i in range(0, len(data), mp)] or [b""]
        if zlp and data and len(data) % mp == 0:
            packets.append(b"")
        with self._cond:
            for p in packets:
                self._in[ep].append((ready, p))
            self._cond.notify_all()

    @abc.abstractmethod
    def on_out(self, ep: int, data: bytes) -> None:
        """Firmware: handle one OUT transfer."""

    def transfer_fault(self, ep: int) -> str | None:
        """The fault the next transfer on ``ep`` meets, consuming its count: ``"nodev"``
        (unplugged), ``"timeout"`` (the device NAKs until the host gives up), ``"pipe"`` (a
        stall; the endpoint stays halted until ``clear_halt``), or None."""
        if not self.present:
            return "nodev"
        if self.faults.take("usb_timeouts"):
            return "timeout"
        if ep in self._halted:
            return "pipe"
        if self.faults.take("usb_pipe_errors"):
            self._halted.add(ep)
            return "pipe"
        return None

    def _fault_transfer(self, ep: int, timeout_ms: int) -> None:
        """Raise the fault a bulk transfer on ``ep`` meets (a timeout after ``timeout_ms``)."""
        kind = self.transfer_fault(ep)
        if kind == "timeout":
            time.sleep(max(timeout_ms, 1) / 1000.0)
        if kind is not None:
            raise usb_error(kind)

    def bulk_out(self, ep: int, data: bytes, timeout_ms: int) -> int:
        self._fault_transfer(ep, timeout_ms)
        return self.accept_out(ep, data)

    def accept_out(self, ep: int, data: bytes) -> int:
        """Hand one OUT transfer that met no transfer fault to the firmware; its length (a
        ``timeout`` error, the OUT NAKed, while replies fill :data:`MAX_QUEUED_PACKETS`)."""
        with self._cond:
            if any(len(q) >= MAX_QUEUED_PACKETS for q in self._in.values()):
                raise usb_error("timeout")
        data = self.faults.filter_command(bytes(data))
        self.on_out(ep, data)
        return len(data)

    def poll_in(self, ep: int, room: int) -> tuple[bytes | None, float | None]:
        """Take the next packet of ``ep`` without waiting.

        Returns ``(packet, None)`` when the head packet is ready (it leaves the queue; under
        ``disconnect_after_bytes`` it may be cut short and the device unplugged after it:
        check :attr:`present`), else ``(None, ready_at)`` with the monotonic time the head
        packet becomes ready, or ``(None, None)`` when nothing is queued. Raises the
        ``nodev`` error when unplugged and ``overflow`` (the packet is consumed, as babble
        is on the bus) when the packet is longer than ``room``.
        """
        with self._cond:
            if not self.present:
                raise usb_error("nodev")
            q = self._in[ep]
            if not q:
                return None, None
            now = time.monotonic()
            if q[0][0] > now:
                return None, q[0][0]
            _, pkt = q.popleft()
            if len(pkt) > room:
                raise usb_error("overflow")
            keep, unplug = self.faults.split_for_disconnect(pkt)
            if unplug:
                self.present = False
                self._back_at = now + self.faults.reconnect_after
                self._reset_queues()
                self._cond.notify_all()
            return keep, None

    def bulk_in(self, ep: int, size: int, timeout_ms: int) -> bytes:
        """Collect packets until ``size`` bytes, a short packet, or the timeout."""
        self._fault_transfer(ep, timeout_ms)
        mp = self.endpoints[ep].max_packet
        deadline = None if timeout_ms == 0 else time.monotonic() + timeout_ms / 1000.0
        out = bytearray()
        with self._cond:
            while True:
                pkt, ready_at = self.poll_in(ep, size - len(out))
                if pkt is not None:
                    out += pkt
                    if not self.present:
                        raise usb_error("nodev")
                    if len(pkt) < mp or len(out) >= size:
                        return bytes(out)
                    continue
                now = time.monotonic()
                wait = 0.05 if ready_at is None else max(ready_at - now, 0.0)
                if deadline is not None:
                    if now >= deadline:
                        raise usb_error("timeout")
                    wait = min(wait, deadline - now)
                self._cond.wait(wait)
