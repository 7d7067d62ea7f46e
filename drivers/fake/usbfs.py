"""The fake USB devices on an emulated Linux USB bus, for every libusb-1.0 program.

:class:`UsbfsBus` puts fake USB devices (:class:`~gonio.drivers.fake.usbdev.FakeUsbDevice`,
e.g. the fake USB2000+ and PTP camera of a bench) into a umockdev test bed: each becomes a
sysfs device (``/sys/bus/usb/devices/1-N`` with ``busnum``, ``devnum``, ``descriptors``...)
and a usbdevfs node ``/dev/bus/usb/001/NNN``. A program started with :meth:`UsbfsBus.env`
(umockdev's preload library and ``UMOCKDEV_DIR``) sees them as real devices — ``lsusb``,
gphoto2, pyusb's ``libusb1`` backend, python-seabreeze, any C program on libusb-1.0 — and
its usbdevfs ioctls are answered live in this process by the same fakes and bench as the
in-process pyusb backend (:mod:`gonio.drivers.fake.usb`).

The ioctls are answered by :class:`~gonio.drivers.fake.usbdevfs.Usbdevfs` (URBs, statuses,
faults: see there). When a fake is unplugged (its ``unplug()`` or ``disconnect_after_bytes``)
its sysfs device and node are removed with a ``remove`` uevent; when it comes back
(``reconnect_after``) it is added at a new address with an ``add`` uevent, so libusb's
hotplug list finds it again. As in the kernel, a file of the removed node that a program
still holds, or opens in that moment, stays answered (``ENODEV``): the node's ioctl
listener is kept until its address is handed out again or the bus closes (closing it at
the unplug reset a connection umockdev had not yet accepted, and the program died).
umockdev sends uevents through libudev reading the test bed, so
only a bus in a process under the preload library sends them (:func:`ensure_preloaded`, as
``gonio devices serve --libusb`` does); elsewhere a running program sees the unplug as
``ENODEV`` and a program started later finds the replugged device.

Needs umockdev >= 0.16 with its GObject typelib and PyGObject (Debian: ``umockdev``,
``gir1.2-umockdev-1.0``; ``pip install gonio[libusb]``); :func:`require` says what is
missing.

References
----------
.. [umockdev] M. Pitt and contributors, "umockdev: mock hardware devices for creating unit
   tests", software, version 0.17 (2023): ``UMockdevTestbed`` (``add_from_string``,
   ``attach_ioctl``, ``uevent``) and the preload library.
.. [sysfs] The Linux kernel, ``Documentation/ABI/stable/sysfs-bus-usb`` (the USB device
   attributes libusb and lsusb read) and ``drivers/usb/core/sysfs.c``.
"""

from __future__ import annotations

import os
import subprocess
import threading
from collections import Counter
from collections.abc import Mapping, Sequence
from typing import Any

from gonio.drivers.fake.usbdev import FakeUsbDevice
from gonio.drivers.fake.usbdevfs import Node, Usbdevfs

__all__ = ["PRELOAD", "UsbfsBus", "UsbfsUnavailable", "ensure_preloaded", "require"]

PRELOAD = "libumockdev-preload.so.0"


class UsbfsUnavailable(RuntimeError):
    """umockdev, its typelib or PyGObject is missing (the message says which and how)."""


def require() -> Any:
    """The ``UMockdev`` GObject module, or :class:`UsbfsUnavailable` saying what is missing."""
    try:
        import gi
    except ImportError:
        raise UsbfsUnavailable(
            "PyGObject is not installed: pip install 'gonio[libusb]' (building it needs the "
            "system packages libgirepository1.0-dev, libcairo2-dev and pkg-config)"
        ) from None
    try:
        gi.require_version("UMockdev", "1.0")
        from gi.repository import UMockdev
    except (ImportError, ValueError):
        raise UsbfsUnavailable(
            "the umockdev GObject typelib is missing: apt-get install umockdev "
            "gir1.2-umockdev-1.0 (umockdev >= 0.16)"
        ) from None
    if not hasattr(UMockdev, "IoctlBase"):
        raise UsbfsUnavailable("umockdev is older than 0.16 (no UMockdev.IoctlBase)")
    return UMockdev


def ensure_preloaded() -> None:
    """Run this process under umockdev's preload library, re-executing it if it is not.

    A bus in such a process also sends the hotplug uevents (``remove`` / ``add``) a running
    libusb program needs to see an unplug and a replug; elsewhere it works without them.
    """
    require()
    if PRELOAD in os.environ.get("LD_PRELOAD", "").split():
        return
    import ctypes.util
    import sys

    if ctypes.util.find_library("umockdev-preload") is None:
        raise UsbfsUnavailable(f"{PRELOAD} is missing: apt-get install umockdev")
    pre = os.environ.get("LD_PRELOAD", "")
    env = dict(os.environ, LD_PRELOAD=f"{PRELOAD} {pre}".strip())
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(sys.executable, sys.orig_argv, env)


def _sysfs_record(dev: FakeUsbDevice, bus: int, devnum: int, port: int) -> str:
    """A umockdev device record of ``dev`` as the kernel shows it in sysfs."""
    d = dev.device_descriptor()
    c = dev.config_descriptor()
    raw = dev.raw_descriptor(1, 0, 0) + dev.raw_descriptor(2, 0, 0)
    node = f"bus/usb/{bus:03d}/{devnum:03d}"
    ifaces = ":" + "".join(f"{i.cls:02x}{i.subclass:02x}{i.protocol:02x}:" for i in dev.interfaces)
    props = {
        "DEVNAME": "/" + "dev/" + node,
        "DEVTYPE": "usb_device",
        "SUBSYSTEM": "usb",
        "DRIVER": "usb",
        "BUSNUM": f"{bus:03d}",
        "DEVNUM": f"{devnum:03d}",
        "MAJOR": "189",
        "MINOR": str((bus - 1) * 128 + devnum - 1),
        "PRODUCT": f"{d.idVendor:x}/{d.idProduct:x}/{d.bcdDevice:x}",
        "TYPE": f"{d.bDeviceClass}/{d.bDeviceSubClass}/{d.bDeviceProtocol}",
        "ID_BUS": "usb",
        "ID_VENDOR_ID": f"{d.idVendor:04x}",
        "ID_MODEL_ID": f"{d.idProduct:04x}",
        "ID_USB_INTERFACES": ifaces,
    }
    # sysfs text attributes end in a newline (libusb's parsers and lsusb rely on it)
    attrs = {
        "busnum": bus,
        "devnum": devnum,
        "devpath": port,
        "speed": 480,
        "idVendor": f"{d.idVendor:04x}",
        "idProduct": f"{d.idProduct:04x}",
        "bcdDevice": f"{d.bcdDevice:04x}",
        "bDeviceClass": f"{d.bDeviceClass:02x}",
        "bMaxPacketSize0": 64,
        "bNumConfigurations": 1,
        "bNumInterfaces": f"{c.bNumInterfaces:2d}",
        "bConfigurationValue": dev.configuration or "",
        "bmAttributes": f"{c.bmAttributes:02x}",
        "bMaxPower": f"{2 * c.bMaxPower}mA",
        "version": " 2.00",
        "authorized": 1,
        "manufacturer": dev.strings.get(dev.manufacturer_index, ""),
        "product": dev.strings.get(dev.product_index, ""),
        "serial": dev.strings.get(dev.serial_index, ""),
    }
    lines = [f"P: /devices/usb{bus}/{bus}-{port}", f"N: {node}"]
    lines += [f"E: {k}={v}" for k, v in props.items()]
    lines += [f"A: {k}={v}\\n" for k, v in attrs.items()]
    lines.append(f"H: descriptors={raw.hex().upper()}")
    return "\n".join(lines) + "\n"


class UsbfsBus:
    """Fake USB devices on an emulated usbdevfs bus; programs run under :meth:`env`.

    Parameters
    ----------
    fakes : sequence or mapping of FakeUsbDevice
        The devices (a mapping's values), e.g. ``gonio.drivers.fake.usb.devices(name)``.
    bus : int
        USB bus number (1..127).
    reap_hold : float
        Seconds an empty ``REAPURBNDELAY`` is held before ``EAGAIN`` (see the module
        docstring), 0..0.1.
    plug_poll : float
        Seconds between checks of the fakes' plug state (unplug / replug), 0.001..1.

    Examples
    --------
    >>> with UsbfsBus(fakeusb.devices(fakeusb.install(bench))) as bus:  # doctest: +SKIP
    ...     subprocess.run(["lsusb"], env=bus.env())
    """

    def __init__(
        self,
        fakes: Sequence[FakeUsbDevice] | Mapping[str, FakeUsbDevice],
        *,
        bus: int = 1,
        reap_hold: float = 0.01,
        plug_poll: float = 0.02,
    ) -> None:
        if not 1 <= int(bus) <= 127:
            raise ValueError(f"bus={bus!r}: expected an integer 1..127")
        if not 0.0 <= reap_hold <= 0.1:
            raise ValueError(f"reap_hold={reap_hold!r}: expected 0..0.1 s")
        if not 0.001 <= plug_poll <= 1.0:
            raise ValueError(f"plug_poll={plug_poll!r}: expected 0.001..1 s")
        devs = list(fakes.values()) if isinstance(fakes, Mapping) else list(fakes)
        if not devs:
            raise ValueError("fakes=[]: expected at least one fake USB device")
        self._umockdev = require()
        self.fakes = devs
        self.bus = int(bus)
        self.plug_poll = float(plug_poll)
        self.stats: Counter[str] = Counter()
        self._lock = threading.RLock()
        self.usbdevfs = Usbdevfs(
            devs,
            reap_hold=reap_hold,
            plug_poll=plug_poll,
            lock=self._lock,
            stats=self.stats,
            set_attribute=self._set_attribute,
        )
        self._nodes: dict[int, Node] = {}  # index in fakes -> current node
        self._gone: dict[str, Node] = {}  # devnode -> removed node whose listener is kept
        self._devnum = 1  # the last address handed out (the kernel's round robin)
        self._stop = threading.Event()
        self._testbed = self._umockdev.Testbed.new()
        self.hotplug = bool(self._umockdev.in_mock_environment())  # after: it stats /sys
        self._root = self._testbed.get_root_dir()
        for k, dev in enumerate(devs):
            dev.check_plugged()
            if dev.present:  # an unplugged fake is added when it comes back
                self._plug(k)
        self._monitor = threading.Thread(target=self._watch, name="usbfs-plug", daemon=True)
        self._monitor.start()

    # -- running programs ---------------------------------------------------------------------
    def env(self, base: Mapping[str, str] | None = None) -> dict[str, str]:
        """``base`` (default ``os.environ``) plus the preload library and ``UMOCKDEV_DIR``."""
        env = dict(os.environ if base is None else base)
        pre = env.get("LD_PRELOAD", "")
        env["LD_PRELOAD"] = f"{PRELOAD} {pre}".strip() if PRELOAD not in pre else pre
        env["UMOCKDEV_DIR"] = self._root
        return env

    def run(self, argv: Sequence[str], **kwargs: Any) -> subprocess.CompletedProcess:
        """``subprocess.run(argv, env=self.env(), **kwargs)``."""
        kwargs["env"] = self.env(kwargs.get("env"))
        return subprocess.run(list(argv), **kwargs)

    def run_until(self, argv: Sequence[str], stop: threading.Event) -> int:
        """Run ``argv`` on the bus until it exits (its exit code; 128 + N for signal N) or
        ``stop`` is set (then it is terminated)."""
        try:
            proc = subprocess.Popen(list(argv), env=self.env())
        except OSError as exc:
            raise ValueError(f"{' '.join(argv)!r}: cannot start it: {exc}") from None
        try:
            while proc.poll() is None:
                if stop.wait(0.1):
                    proc.terminate()
                    break
            try:
                rc = proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                rc = proc.wait()
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        return 128 - rc if rc < 0 else rc

    def record(self, names: Mapping[str, FakeUsbDevice]) -> dict[str, Any]:
        """What ``gonio devices serve --libusb`` prints: nodes, environment, hotplug."""
        env = self.env({})
        return {
            "device": "libusb",
            "nodes": {k: self.devnode(dev) for k, dev in names.items()},
            "env": f"LD_PRELOAD={env['LD_PRELOAD']} UMOCKDEV_DIR={env['UMOCKDEV_DIR']}",
            "umockdev_dir": self._root,
            "hotplug": self.hotplug,
        }

    def devnode(self, fake: FakeUsbDevice) -> str | None:
        """The device node of ``fake`` now (None while it is unplugged)."""
        node = self._node_of(fake)
        return None if node is None else node.devnode

    def address(self, fake: FakeUsbDevice) -> int | None:
        """The bus address (``devnum``) of ``fake`` now (None while it is unplugged)."""
        node = self._node_of(fake)
        return None if node is None else node.devnum

    def _node_of(self, fake: FakeUsbDevice) -> Node | None:
        with self._lock:
            node = self._nodes.get(self.fakes.index(fake))
            return None if node is None or node.gone else node

    @property
    def reap_hold(self) -> float:
        """Seconds a repeated empty ``REAPURBNDELAY`` is held (see :mod:`.usbdevfs`)."""
        return self.usbdevfs.reap_hold

    def close(self) -> None:
        """Stop answering, remove the devices and the test bed."""
        self._stop.set()
        self._monitor.join(timeout=2)
        with self._lock:
            self.usbdevfs.closed = True
            for k in list(self._nodes):
                self._unplug_node(k)
            for devnode in list(self._gone):
                self._detach(devnode)
            self._testbed = None

    def __enter__(self) -> UsbfsBus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- plug state ---------------------------------------------------------------------------
    def _plug(self, k: int) -> None:
        dev = self.fakes[k]
        devnum = self._next_address()
        port = k + 1
        syspath = f"/sys/devices/usb{self.bus}/{self.bus}-{port}"
        node = Node(
            dev, dev.generation, devnum, syspath, f"/dev/bus/usb/{self.bus:03d}/{devnum:03d}"
        )
        node.socket = os.path.join(self._root, "ioctl", node.devnode.lstrip("/"))
        self._detach(node.devnode)  # a removed node's listener at this address, if any
        self._testbed.add_from_string(_sysfs_record(dev, self.bus, devnum, port))
        node.handler = _make_handler(self._umockdev, self.usbdevfs, node)
        self._testbed.attach_ioctl(node.devnode, node.handler)
        self._uevent(syspath, "add")
        self._nodes[k] = node
        self.stats["plugged"] += 1

    def _next_address(self) -> int:
        """The next free address 2..127, round robin as the kernel assigns them (so a
        replugged device comes back at a new address)."""
        used = {n.devnum for n in self._nodes.values()}
        for _ in range(126):
            self._devnum = self._devnum % 127 + 1
            if self._devnum >= 2 and self._devnum not in used:
                return self._devnum
        raise RuntimeError("no free USB address on the bus (126 devices)")

    def _set_attribute(self, syspath: str, name: str, text: str) -> None:
        if self._testbed is not None:
            self._testbed.set_attribute(syspath, name, text)

    def _uevent(self, syspath: str, action: str) -> None:
        """Tell the programs' udev monitors (libusb hotplug). umockdev sends uevents through
        libudev reading the test bed, so only a process under the preload library can."""
        if self.hotplug:
            self._testbed.uevent(syspath, action)
            self.stats[f"uevent {action}"] += 1

    def _unplug_node(self, k: int) -> None:
        node = self._nodes.pop(k, None)
        if node is None:
            return
        node.gone = True
        self.usbdevfs.fail_node(node)
        if self._testbed is not None:
            self._testbed.remove_device(node.syspath)  # it sends the "remove" uevent
            if self.hotplug:
                self.stats["uevent remove"] += 1
            self._gone[node.devnode] = node  # its open files stay answered (ENODEV)
        self.stats["unplugged"] += 1

    def _detach(self, devnode: str) -> None:
        """Stop listening at a removed node's address (its open files are answered on)."""
        if self._gone.pop(devnode, None) is not None:
            self._testbed.detach_ioctl(devnode)

    def _watch(self) -> None:
        """Follow the fakes' plug state: remove unplugged devices, add replugged ones."""
        while not self._stop.wait(self.plug_poll):
            with self._lock:
                for k, dev in enumerate(self.fakes):
                    node = self._nodes.get(k)
                    if node is not None and (not dev.present or dev.generation != node.generation):
                        self._unplug_node(k)
                        node = None
                    if node is None:
                        dev.check_plugged()
                        if dev.present:
                            self._plug(k)


def _make_handler(umockdev: Any, usbdevfs: Usbdevfs, node: Node) -> Any:
    """An ``UMockdev.IoctlBase`` answering ``node``'s ioctls through ``usbdevfs``."""

    class Handler(umockdev.IoctlBase):
        def do_handle_ioctl(self, client: Any) -> bool:
            return usbdevfs.handle(node, client)

        def do_client_connected(self, client: Any) -> None:
            usbdevfs.connected(node, client)

    return Handler()
