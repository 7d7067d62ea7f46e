"""The usbdevfs ioctls of emulated USB device nodes, answered from fake USB devices.

:class:`Usbdevfs` is the kernel side of ``/dev/bus/usb/BBB/DDD`` for the nodes of a
:class:`~gonio.drivers.fake.usbfs.UsbfsBus`: umockdev hands it each ioctl a program makes on
such a node (an ``UMockdev.IoctlClient``, one per open file), and it answers from the fake
(:class:`~gonio.drivers.fake.usbdev.FakeUsbDevice`), reading and writing the program's memory
through ``UMockdev.IoctlData`` (``resolve``, ``retrieve``, ``update``).

The ioctls answered are those libusb-1.0 uses on Linux: ``GET_CAPABILITIES``,
``CLAIMINTERFACE``/``RELEASEINTERFACE``/``DISCONNECT_CLAIM``, ``SETCONFIGURATION``,
``SETINTERFACE``, ``CLEAR_HALT``, ``RESET``, ``GETDRIVER``/``IOCTL`` (no kernel driver is
ever bound), ``GET_SPEED``, ``CONTROL``, and control / bulk / interrupt URBs through
``SUBMITURB``, ``DISCARDURB``, ``REAPURB`` and ``REAPURBNDELAY``; any other is ``ENOTTY``.
URBs complete as the kernel completes them: an IN URB collects packets until it is full or a
short packet arrives (``-EREMOTEIO`` under ``USBDEVFS_URB_SHORT_NOT_OK``), a discarded URB
comes back ``-ENOENT`` with the bytes it already received, a babbling packet ``-EOVERFLOW``.

The fakes' fault injection (:class:`~gonio.drivers.fake.faults.Faults`) reaches the program
as on a real bus: ``usb_pipe_errors`` stall the endpoint (the URB completes ``-EPIPE``; the
endpoint stays halted until ``CLEAR_HALT``); ``usb_timeouts`` make the device NAK (the URB
stays pending until the program's own timeout discards it); an unplug (``unplug()`` or
``disconnect_after_bytes``) completes every pending URB ``-ENODEV`` with the bytes already
received, and every later ioctl on the open file fails ``ENODEV``.

The emulated node always polls ready (it is a plain file), so libusb's event loop asks
``REAPURBNDELAY`` again at once when nothing has completed. libusb also reaps until
``EAGAIN`` after every URB it gets; that first empty reap is answered at once, but a second
empty reap in a row (the program is polling, not draining) is held up to ``reap_hold``
seconds, or until a URB completes, before ``EAGAIN``: a program waiting on a long
integration or a camera event makes about ``1 / reap_hold`` ioctls per second instead of
spinning.

A file is closed (its claims released, its URBs dropped) when umockdev marks its client
disconnected, or when the program's end of the client's socket is found hung up. The second
test is needed because umockdev never notices a program that dies while its last answer is
on the way: the failed write of that answer ends umockdev's reading of the socket without
closing it (``IoctlClient.complete_async`` in ``umockdev-ioctl.vala``, 0.17), so the client
stays "connected" for as long as the bus runs, and its claim would make every later program
fail ``EBUSY``. The kernel releases a closed file's claims at once; so does this, looking at
the sockets (see :meth:`Usbdevfs.connected`) before it grants a claim or opens a file.

Every call runs on the umockdev test bed's worker thread, except the failing of a node's
files when the bus sees the device unplugged; all state is guarded by the bus's lock.

References
----------
.. [usbdevfs] The Linux kernel, ``include/uapi/linux/usbdevice_fs.h`` (the ioctls and
   ``struct usbdevfs_urb``) and ``drivers/usb/core/devio.c`` (URB life cycle and statuses).
.. [libusb] libusb-1.0, version 1.0.26 (2022), ``libusb/os/linux_usbfs.c``: which ioctls a
   libusb program issues, and how it reads URB statuses.
.. [USB20] USB Implementers Forum, "Universal Serial Bus Specification", Revision 2.0
   (2000), §5.8 (bulk transfers: a short packet ends one) and chapter 8 (the NAK and STALL
   handshakes).
.. [umockdev] M. Pitt and contributors, "umockdev: mock hardware devices for creating unit
   tests", software, version 0.17 (2023): ``UMockdevIoctlBase``, ``UMockdevIoctlClient``,
   ``UMockdevIoctlData`` (since 0.16).
"""

from __future__ import annotations

import array
import errno
import logging
import os
import select
import socket
import struct
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import usb.core
from gonio.drivers.fake.usb import FakeUsbBackend, _Handle
from gonio.drivers.fake.usbdev import FakeUsbDevice

__all__ = ["Node", "Usbdevfs"]

_log = logging.getLogger(__name__)

# -- usbdevfs ABI (x86-64 / aarch64 layout: 8-byte pointers) -----------------------------------


def _ioc(direction: int, nr: int, size: int) -> int:
    return (direction << 30) | (size << 16) | (ord("U") << 8) | nr


_W, _R = 1, 2
URB_SIZE = 56  # struct usbdevfs_urb without iso descriptors
REQ = {
    _ioc(_R | _W, 0, 24): "CONTROL",
    _ioc(_R, 4, 8): "SETINTERFACE",
    _ioc(_R, 5, 4): "SETCONFIGURATION",
    _ioc(_W, 8, 260): "GETDRIVER",
    _ioc(_R, 10, URB_SIZE): "SUBMITURB",
    _ioc(0, 11, 0): "DISCARDURB",
    _ioc(_W, 12, 8): "REAPURB",
    _ioc(_W, 13, 8): "REAPURBNDELAY",
    _ioc(_R, 15, 4): "CLAIMINTERFACE",
    _ioc(_R, 16, 4): "RELEASEINTERFACE",
    _ioc(_R | _W, 18, 16): "IOCTL",
    _ioc(0, 20, 0): "RESET",
    _ioc(_R, 21, 4): "CLEAR_HALT",
    _ioc(_R, 26, 4): "GET_CAPABILITIES",
    _ioc(_R, 27, 264): "DISCONNECT_CLAIM",
    _ioc(0, 31, 0): "GET_SPEED",
}
URB_TYPE_CONTROL, URB_TYPE_BULK, URB_TYPE_INTERRUPT = 2, 3, 1
URB_SHORT_NOT_OK = 0x01
# ZERO_PACKET | BULK_CONTINUATION | NO_PACKET_SIZE_LIM | REAP_AFTER_DISCONNECT: libusb then
# submits each bulk transfer as one URB and reaps the URBs a disconnect completed
CAPABILITIES = 0x01 | 0x02 | 0x04 | 0x10
USB_SPEED_HIGH = 3
IDLE_POLL = 0.05  # s between looks at an empty IN queue (packets queued from outside)


# -- a node, its open files and their URBs ----------------------------------------------------
@dataclass
class Node:
    """One enumeration of a fake: sysfs path, device node, address, generation."""

    dev: FakeUsbDevice
    generation: int
    devnum: int
    syspath: str
    devnode: str
    handler: Any = None
    gone: bool = False
    socket: str = ""  # the path of umockdev's socket for devnode (its clients connect there)


@dataclass
class _Urb:
    addr: int  # the URB's address in the client
    type: int
    ep: int
    flags: int
    capacity: int  # buffer_length (for control: setup packet included)
    data: bytearray = field(default_factory=bytearray)  # IN: received so far
    status: int = 0
    actual: int = 0


@dataclass
class _Fd:
    """One open ``/dev/bus/usb/...`` file of a client: its device and URBs."""

    node: Node
    client: Any  # the UMockdev.IoctlClient (hashed by its GObject address)
    pending: dict[int, _Urb] = field(default_factory=dict)
    done: deque[_Urb] = field(default_factory=deque)
    held: tuple[Any, float | None] | None = None  # a reap waiting: (client, deadline)
    drained: bool = False  # the last reap found nothing: the program is polling, not draining
    claimed: set[int] = field(default_factory=set)


class Usbdevfs:
    """The usbdevfs side of a bus's nodes (see the module docstring).

    Parameters
    ----------
    fakes : sequence of FakeUsbDevice
        The devices on the bus.
    reap_hold, plug_poll : float
        Seconds an empty repeated ``REAPURBNDELAY`` is held; seconds between looks at the
        plug state while a blocking ``REAPURB`` waits.
    lock : threading.RLock
        The bus's lock (the bus changes plug state under it).
    stats : collections.Counter
        Counts of ioctls by name and of URBs, packets and bytes.
    set_attribute : callable
        ``set_attribute(syspath, name, text)``: write a sysfs attribute of a node.
    """

    def __init__(
        self,
        fakes: Sequence[FakeUsbDevice],
        *,
        reap_hold: float,
        plug_poll: float,
        lock: threading.RLock,
        stats: Counter[str],
        set_attribute: Callable[[str, str, str], None],
    ) -> None:
        self.reap_hold = float(reap_hold)
        self.plug_poll = float(plug_poll)
        self.stats = stats
        self.closed = False
        self._lock = lock
        self._set_attribute = set_attribute
        self._backend = FakeUsbBackend(list(fakes))
        self._fds: dict[Any, _Fd] = {}  # IoctlClient -> open file (kept alive while open)
        self._sockets: dict[Any, tuple[int, int]] = {}  # IoctlClient -> its socket (fd, inode)
        self._ep_queue: dict[tuple[int, int], deque[tuple[_Fd, _Urb]]] = {}
        self._ctx: Any = None  # the test bed's worker main context (ioctls run there)
        self._tick: Any = None
        self._tick_at = 0.0

    def fail_node(self, node: Node) -> None:
        """``node``'s device went away: its files' pending URBs complete ``-ENODEV``."""
        for fd in list(self._fds.values()):
            if fd.node is node:
                self._fail_fd(fd)

    def connected(self, node: Node, client: Any) -> None:
        """A program opened ``node``: note the socket umockdev accepted for ``client``.

        umockdev's listener for a node accepts one connection and announces its client
        (``client-connected``) before it accepts the next, so the one accepted socket bound to
        ``node.socket`` that belongs to no earlier client is this client's.
        """
        with self._lock:
            live = {k: v for k, v in self._sockets.items() if _inode(v[0]) == v[1]}
            self._sockets = live
            taken = {ino for _, ino in live.values()}
            for n, ino in _accepted(node.socket):
                if ino not in taken:
                    live[client] = (n, ino)
                    return

    def handle(self, node: Node, client: Any) -> bool:
        """Answer one ioctl of ``client`` on ``node`` (now, or later for a waiting reap)."""
        request = client.get_request()
        name = REQ.get(request)
        with self._lock:
            self.stats[name or f"unknown 0x{request:08x}"] += 1
            if self.closed:
                client.complete(-1, errno.ENODEV)
                return True
            from gi.repository import GLib

            if self._ctx is None:
                self._ctx = GLib.MainContext.get_thread_default()
            fd = self._fds.get(client)
            if fd is None:
                self._sweep()
                fd = self._fds[client] = _Fd(node, client)
            if name is None:
                client.complete(-1, errno.ENOTTY)
                return True
            if name in ("REAPURB", "REAPURBNDELAY"):
                self._reap(fd, client, block=name == "REAPURB")
                return True
            if fd.node.gone or not self._live(fd.node):
                client.complete(-1, errno.ENODEV)
                return True
            try:
                res = getattr(self, "_" + name.lower())(fd, client)
            except usb.core.USBError as exc:
                res, err = -1, exc.errno or errno.EIO
            except _Errno as exc:
                res, err = -1, exc.errno
            except GLib.Error:  # the program went away while we read its memory
                self._forget(client)
                return True
            except Exception:  # a bug here must not leave the program hanging in ioctl()
                _log.exception("usbdevfs %s on %s", name, node.devnode)
                res, err = -1, errno.EIO
            else:
                err = 0
            client.complete(res, err)
            self._schedule()
            return True

    def _live(self, node: Node) -> bool:
        return node.dev.present and node.dev.generation == node.generation

    def _handle(self, fd: _Fd) -> _Handle:
        return _Handle(fd.node.dev, fd.node.generation)

    # simple requests: each returns the ioctl's result or raises _Errno / USBError
    def _get_capabilities(self, fd: _Fd, client: Any) -> int:
        client.get_arg().resolve(0, 4).update(0, struct.pack("<I", CAPABILITIES))
        return 0

    def _get_speed(self, fd: _Fd, client: Any) -> int:
        return USB_SPEED_HIGH

    def _interface_arg(self, fd: _Fd, client: Any) -> int:
        n = _u32(client.get_arg().resolve(0, 4))
        if n not in {i.number for i in fd.node.dev.interfaces}:
            raise _Errno(errno.EINVAL)
        return n

    def _claiminterface(self, fd: _Fd, client: Any) -> int:
        n = self._interface_arg(fd, client)
        self._sweep()
        for other in self._fds.values():
            if other is not fd and other.node is fd.node and n in other.claimed:
                raise _Errno(errno.EBUSY)
        fd.claimed.add(n)
        return 0

    _disconnect_claim = _claiminterface  # no kernel driver to detach: a plain claim

    def _releaseinterface(self, fd: _Fd, client: Any) -> int:
        n = self._interface_arg(fd, client)
        if n not in fd.claimed:
            raise _Errno(errno.EINVAL)
        fd.claimed.discard(n)
        return 0

    def _getdriver(self, fd: _Fd, client: Any) -> int:
        raise _Errno(errno.ENODATA)  # no kernel driver bound to any interface

    def _ioctl(self, fd: _Fd, client: Any) -> int:
        raise _Errno(errno.ENODATA)  # USBDEVFS_DISCONNECT / CONNECT: no driver to (re)bind

    def _setconfiguration(self, fd: _Fd, client: Any) -> int:
        value = struct.unpack("<i", bytes(client.get_arg().resolve(0, 4).retrieve()))[0]
        if value not in (-1, 0, 1):
            raise _Errno(errno.EINVAL)
        if fd.claimed and value != fd.node.dev.configuration:
            raise _Errno(errno.EBUSY)
        self._backend.set_configuration(self._handle(fd), max(value, 0))
        self._set_config_attr(fd.node, value)
        return 0

    def _setinterface(self, fd: _Fd, client: Any) -> int:
        intf, alt = struct.unpack("<II", bytes(client.get_arg().resolve(0, 8).retrieve()))
        self._backend.set_interface_altsetting(self._handle(fd), intf, alt)
        return 0

    def _clear_halt(self, fd: _Fd, client: Any) -> int:
        ep = _u32(client.get_arg().resolve(0, 4)) & 0xFF
        if ep not in fd.node.dev.endpoints:
            raise _Errno(errno.ENOENT)
        self._backend.clear_halt(self._handle(fd), ep)
        return 0

    def _reset(self, fd: _Fd, client: Any) -> int:
        self._backend.reset_device(self._handle(fd))
        return 0

    def _control(self, fd: _Fd, client: Any) -> int:
        """``USBDEVFS_CONTROL``: a synchronous control transfer."""
        arg = client.get_arg().resolve(0, 24)
        bm, req, value, index, length, _tmo = struct.unpack_from("<BBHHHI", bytes(arg.retrieve()))
        if bm & 0x80:
            data, n = self._control_in(fd, bm, req, value, index, length)
            if n:
                arg.resolve(16, n).update(0, data[:n])
            return n
        payload = bytes(arg.resolve(16, length).retrieve()) if length else b""
        return self._control_out(fd, bm, req, value, index, payload)

    def _control_in(self, fd: _Fd, bm: int, req: int, value: int, index: int, length: int):
        buf = array.array("B", bytes(length))
        n = self._backend.ctrl_transfer(self._handle(fd), bm, req, value, index, buf, 1000)
        self.stats["control"] += 1
        return buf.tobytes(), int(n)

    def _control_out(self, fd: _Fd, bm: int, req: int, value: int, index: int, payload: bytes):
        buf = array.array("B", payload)
        n = self._backend.ctrl_transfer(self._handle(fd), bm, req, value, index, buf, 1000)
        self.stats["control"] += 1
        if (bm & 0x60) == 0 and req == 9:  # SET_CONFIGURATION through ep0
            self._set_config_attr(fd.node, value)
        return len(payload) if n is None else int(n)

    def _set_config_attr(self, node: Node, value: int) -> None:
        """sysfs ``bConfigurationValue``: where libusb reads the active configuration."""
        text = f"{value}\n" if value > 0 else "\n"
        self._set_attribute(node.syspath, "bConfigurationValue", text)

    # -- URBs -----------------------------------------------------------------------------------
    def _submiturb(self, fd: _Fd, client: Any) -> int:
        arg = client.get_arg()
        raw = arg.resolve(0, URB_SIZE)
        typ, ep, _st, flags, _buf, length = struct.unpack_from(
            "<BBxxiIxxxxQi", bytes(raw.retrieve())
        )
        addr = raw.client_addr
        dev = fd.node.dev
        urb = _Urb(addr, typ, ep, flags, max(length, 0))
        self.stats["urbs submitted"] += 1
        if addr in fd.pending:
            raise _Errno(errno.EINVAL)
        if typ == URB_TYPE_CONTROL:
            if length < 8:
                raise _Errno(errno.EINVAL)
            buf = raw.resolve(16, length)
            self._complete_control(fd, urb, bytes(buf.retrieve()))
            return 0
        if typ not in (URB_TYPE_BULK, URB_TYPE_INTERRUPT):
            raise _Errno(errno.EINVAL)  # isochronous: none of the fakes has such an endpoint
        if ep not in dev.endpoints or dev.configuration == 0:
            raise _Errno(errno.ENOENT)
        fault = dev.transfer_fault(ep)
        if fault == "nodev":
            raise _Errno(errno.ENODEV)
        if fault == "pipe":
            urb.status = -errno.EPIPE
            self._finish(fd, urb)
            return 0
        fd.pending[addr] = urb
        if fault == "timeout":
            return 0  # the device NAKs: pending until the program discards it
        if ep & 0x80:
            self._ep_queue.setdefault((id(dev), ep), deque()).append((fd, urb))
            self._pump()
            return 0
        data = bytes(raw.resolve(16, length).retrieve()) if length > 0 else b""
        del fd.pending[addr]
        try:
            dev.accept_out(ep, data)
        except usb.core.USBError:  # the device NAKs (its replies fill its queues)
            urb.status = -errno.ETIMEDOUT
            self._finish(fd, urb)
            return 0
        self.stats["bytes out"] += len(data)
        self._finish(fd, urb, actual=len(data))
        self._pump()  # the firmware may have queued an answer for a waiting IN URB
        return 0

    def _complete_control(self, fd: _Fd, urb: _Urb, buf: bytes) -> None:
        bm, req, value, index, length = struct.unpack_from("<BBHHH", buf)
        try:
            if bm & 0x80:
                data, n = self._control_in(fd, bm, req, value, index, min(length, urb.capacity - 8))
                urb.data = bytearray(data[:n])
                actual = n
            else:
                actual = self._control_out(fd, bm, req, value, index, buf[8 : 8 + length])
        except usb.core.USBError as exc:
            urb.status = -(exc.errno or errno.EPIPE)
            actual = 0
        self._finish(fd, urb, actual=actual)

    def _finish(self, fd: _Fd, urb: _Urb, actual: int | None = None) -> None:
        """Move ``urb`` to the completed queue (and answer a waiting reap)."""
        fd.pending.pop(urb.addr, None)
        urb.actual = len(urb.data) if actual is None else actual
        if (
            urb.status == 0
            and urb.flags & URB_SHORT_NOT_OK
            and urb.ep & 0x80
            and urb.type != URB_TYPE_CONTROL
            and urb.actual < urb.capacity
        ):
            urb.status = -errno.EREMOTEIO
        fd.done.append(urb)
        self.stats["urbs completed"] += 1
        if fd.held is not None:
            client, _ = fd.held
            fd.held = None
            self._deliver(fd, client)

    def _pump(self) -> float | None:
        """Move ready packets into waiting IN URBs; the next time a packet becomes ready."""
        next_at: float | None = None
        for queue in list(self._ep_queue.values()):
            while queue:
                fd, urb = queue[0]
                if fd.pending.get(urb.addr) is not urb or not fd.client.get_connected():
                    queue.popleft()  # discarded, failed, or its program closed the file
                    continue
                at = self._fill(fd, urb)
                if at is None and urb.addr not in fd.pending:
                    queue.popleft()
                    continue
                if at is not None:
                    next_at = at if next_at is None else min(next_at, at)
                break
        return next_at

    def _fill(self, fd: _Fd, urb: _Urb) -> float | None:
        """Collect packets for one IN URB; its next packet's ready time while it waits."""
        dev = fd.node.dev
        mp = dev.endpoints[urb.ep].max_packet
        cap = urb.capacity
        while True:
            try:
                pkt, ready_at = dev.poll_in(urb.ep, cap - len(urb.data))
            except usb.core.USBError as exc:
                urb.status = -(exc.errno or errno.EIO)
                self._finish(fd, urb)
                return None
            if pkt is None:
                return ready_at if ready_at is not None else time.monotonic() + IDLE_POLL
            urb.data += pkt
            self.stats["packets in"] += 1
            self.stats["bytes in"] += len(pkt)
            if not dev.present:
                urb.status = -errno.ENODEV
                self._finish(fd, urb)
                return None
            if len(pkt) < mp or len(urb.data) >= cap:
                self._finish(fd, urb)
                return None

    def _discardurb(self, fd: _Fd, client: Any) -> int:
        addr = struct.unpack("<Q", bytes(client.get_arg().retrieve()))[0]
        urb = fd.pending.get(addr)
        if urb is None:
            raise _Errno(errno.EINVAL)  # already completed (or never submitted)
        urb.status = -errno.ENOENT  # killed: what was received so far stays in the URB
        self.stats["urbs discarded"] += 1
        self._finish(fd, urb)
        return 0

    def _fail_fd(self, fd: _Fd) -> None:
        """The device went away: every pending URB of ``fd`` completes ``-ENODEV``."""
        for urb in list(fd.pending.values()):
            urb.status = -errno.ENODEV
            self._finish(fd, urb)
        if fd.held is not None:
            client, _ = fd.held
            fd.held = None
            self._deliver(fd, client)

    def _reap(self, fd: _Fd, client: Any, block: bool) -> None:
        """``REAPURB`` / ``REAPURBNDELAY``: a completed URB now, or ENODEV, or EAGAIN now or
        after ``reap_hold`` (see the module docstring); a blocking reap waits for a URB."""
        gone = fd.node.gone or not self._live(fd.node)
        if gone and fd.pending:
            self._fail_fd(fd)
        if fd.done or gone:
            self._deliver(fd, client)
            return
        if not block and (self.reap_hold == 0 or not fd.drained):
            fd.drained = True  # libusb reaps until EAGAIN after each URB: answer that at once
            client.complete(-1, errno.EAGAIN)
            return
        deadline = None if block else time.monotonic() + self.reap_hold
        fd.held = (client, deadline)
        self._schedule()

    def _deliver(self, fd: _Fd, client: Any) -> None:
        """Answer a reap: the oldest completed URB, or ENODEV / EAGAIN.

        Every answer first reads the program's pointer slot: a program killed while its reap
        was held fails that read, and its file is forgotten (with its claims) instead of
        being answered — umockdev would not notice, as nothing reads its socket meanwhile.
        """
        from gi.repository import GLib

        try:
            slot = client.get_arg().resolve(0, 8)
        except GLib.Error:
            self._forget(client)
            return
        if not fd.done:
            gone = fd.node.gone or not self._live(fd.node)
            client.complete(-1, errno.ENODEV if gone else errno.EAGAIN)
            return
        urb = fd.done.popleft()
        fd.drained = False
        slot.update(0, struct.pack("<Q", urb.addr))
        raw = slot.resolve(0, URB_SIZE)
        raw.update(4, struct.pack("<i", urb.status))
        raw.update(28, struct.pack("<i", urb.actual))
        if urb.data and (urb.ep & 0x80 or urb.type == URB_TYPE_CONTROL):
            off = 8 if urb.type == URB_TYPE_CONTROL else 0
            raw.resolve(16, off + len(urb.data)).update(off, bytes(urb.data))
        self.stats["urbs reaped"] += 1
        client.complete(0, 0)

    # -- timing: one GLib timeout on the worker context drives IN URBs and held reaps ----------
    def _schedule(self) -> None:
        """(Re)arm the tick for the earliest packet or held-reap deadline."""
        if self._ctx is None:
            return
        wake = self._next_wake()
        if wake is None:
            return
        from gi.repository import GLib

        if self._tick is not None:
            if self._tick_at <= wake:
                return  # the armed tick comes first anyway
            self._tick.destroy()
        ms = max(0, int((wake - time.monotonic()) * 1000 + 0.999))
        self._tick, self._tick_at = GLib.Timeout(ms), wake
        self._tick.set_callback(self._on_tick)
        self._tick.attach(self._ctx)

    def _next_wake(self) -> float | None:
        """The earliest of: a packet becoming ready, a held reap's deadline, and (for a
        blocking reap) the next look at the plug state."""
        times = [self._pump()]
        for fd in self._fds.values():
            if fd.held is not None:
                times.append(fd.held[1] or time.monotonic() + self.plug_poll)
        return min((t for t in times if t is not None), default=None)

    def _on_tick(self, *_: Any) -> bool:
        """Move packets, fail the files of unplugged devices, answer expired held reaps."""
        with self._lock:
            self._tick = None
            try:
                now = time.monotonic()
                for fd in list(self._fds.values()):
                    if fd.held is not None and not self._live(fd.node):
                        self._fail_fd(fd)
                self._pump()
                for fd in list(self._fds.values()):
                    if fd.held is not None and fd.held[1] is not None and fd.held[1] <= now:
                        client, _ = fd.held
                        fd.held = None
                        self._deliver(fd, client)
            except Exception:  # keep ticking: other programs' URBs depend on it
                _log.exception("usbdevfs tick")
            finally:
                self._schedule()
        return False

    def _sweep(self) -> None:
        """Forget the files the programs closed (their claims and URBs go with them)."""
        for client in [c for c in self._fds if not c.get_connected() or self._hung_up(c)]:
            self._forget(client)

    def _hung_up(self, client: Any) -> bool:
        """Whether the program's end of ``client``'s socket is closed (see the module
        docstring); False for a client whose socket is not known."""
        known = self._sockets.get(client)
        if known is None:
            return False
        n, ino = known
        if _inode(n) != ino:
            return True  # umockdev closed it (and the number may already be reused)
        p = select.poll()
        p.register(n, select.POLLRDHUP)
        return any(ev & (select.POLLRDHUP | select.POLLHUP | select.POLLERR) for _, ev in p.poll(0))

    def _forget(self, client: Any) -> None:
        fd = self._fds.pop(client, None)
        if fd is not None:
            fd.pending.clear()  # its queued IN URBs are skipped by _pump
            fd.held = None
            self.stats["files forgotten"] += 1


class _Errno(Exception):
    def __init__(self, err: int) -> None:
        super().__init__(os.strerror(err))
        self.errno = err


def _inode(n: int) -> int | None:
    """The inode of this process's file descriptor ``n`` (None if it is not open)."""
    try:
        return os.fstat(n).st_ino
    except OSError:
        return None


def _accepted(path: str) -> list[tuple[int, int]]:
    """(fd, inode) of this process's accepted (not listening) Unix sockets bound to ``path``."""
    out = []
    for name in os.listdir("/proc/self/fd"):
        try:
            if not os.readlink(f"/proc/self/fd/{name}").startswith("socket:"):
                continue
            with socket.fromfd(int(name), socket.AF_UNIX, socket.SOCK_STREAM) as s:
                if s.getsockname() != path or s.getsockopt(socket.SOL_SOCKET, socket.SO_ACCEPTCONN):
                    continue
                out.append((int(name), os.fstat(s.fileno()).st_ino))
        except OSError:
            continue  # closed meanwhile, or not a Unix socket
    return out


def _u32(data: Any) -> int:
    return struct.unpack("<I", bytes(data.retrieve())[:4])[0]
