"""A pyusb backend (``usb.backend.IBackend``) whose bus holds the fake USB devices.

>>> import usb.core, usb.backend
>>> from gonio.drivers.fake import usb as fakeusb
>>> name = fakeusb.install()
>>> be = getattr(usb.backend, name).get_backend()
>>> sorted(hex(d.idVendor) for d in usb.core.find(find_all=True, backend=be))
['0x1209', '0x2457']

:func:`install` registers a module ``usb.backend.<name>`` (with ``get_backend()`` like
pyusb's own backends), so clients that select a backend by name — e.g.
``seabreeze.use("pyseabreeze", pyusb_backend=name)`` — find the fake USB2000+ and the fake
PTP camera. Descriptors, string descriptors and standard control requests are answered,
bulk and interrupt transfers move packets (short packets end transfers) and fail the way
libusb reports failures (``USBTimeoutError``/ETIMEDOUT after the caller's timeout, EPIPE,
ENODEV), driven by each device's :class:`~gonio.drivers.fake.faults.Faults`.
"""

from __future__ import annotations

import itertools
import sys
import time
import types
from typing import Any

import usb.backend
from gonio.drivers.fake.usbdev import FakeUsbDevice, usb_error
from gonio.simulator.bench import Bench

__all__ = [
    "FakeUsbBackend",
    "RemoteServer",
    "RemoteUsbBackend",
    "connect",
    "devices",
    "install",
    "serve_remote",
    "uninstall",
]

_counter = itertools.count(1)


class _NoKernelDriver(usb.backend.IBackend):
    """A pyusb backend whose devices never have a kernel driver bound (fakes need none)."""

    def is_kernel_driver_active(self, dev_handle: Any, intf: int) -> bool:
        return False

    def detach_kernel_driver(self, dev_handle: Any, intf: int) -> None:
        pass

    def attach_kernel_driver(self, dev_handle: Any, intf: int) -> None:
        pass


class _Handle:
    def __init__(self, dev: FakeUsbDevice, generation: int) -> None:
        self.dev = dev
        self.generation = generation


class _DevRef:
    """What ``enumerate_devices`` yields: one device at one enumeration (generation)."""

    def __init__(self, dev: FakeUsbDevice) -> None:
        self.dev = dev
        self.generation = dev.generation


class FakeUsbBackend(_NoKernelDriver):
    """pyusb backend over a list of :class:`FakeUsbDevice`."""

    def __init__(self, fakes: list[FakeUsbDevice]) -> None:
        self.fakes = list(fakes)

    # -- helpers ---------------------------------------------------------------------------
    @staticmethod
    def _live(ref: Any) -> FakeUsbDevice:
        dev = ref.dev
        dev.check_plugged()
        if not dev.present or dev.generation != ref.generation:
            raise usb_error("nodev")
        return dev

    # -- enumeration and descriptors -------------------------------------------------------
    def enumerate_devices(self):
        for d in self.fakes:
            d.check_plugged()
            if d.present:
                yield _DevRef(d)

    def get_parent(self, dev: Any) -> None:
        return None

    def get_device_descriptor(self, dev: Any) -> Any:
        return dev.dev.device_descriptor()

    def get_configuration_descriptor(self, dev: Any, config: int) -> Any:
        if config != 0:
            raise IndexError(f"configuration {config} does not exist")
        return dev.dev.config_descriptor()

    def get_interface_descriptor(self, dev: Any, intf: int, alt: int, config: int) -> Any:
        if config != 0 or alt != 0 or not 0 <= intf < len(dev.dev.interfaces):
            raise IndexError(f"interface ({intf}, {alt}) does not exist")
        return dev.dev.interface_descriptor(intf)

    def get_endpoint_descriptor(self, dev: Any, ep: int, intf: int, alt: int, config: int) -> Any:
        eps = dev.dev.interfaces[intf].endpoints
        if not 0 <= ep < len(eps):
            raise IndexError(f"endpoint {ep} does not exist")
        return eps[ep].descriptor()

    # -- handles and configuration ---------------------------------------------------------
    def open_device(self, dev: Any) -> _Handle:
        d = self._live(dev)
        return _Handle(d, dev.generation)

    def close_device(self, dev_handle: _Handle) -> None:
        pass

    def set_configuration(self, dev_handle: _Handle, config_value: int) -> None:
        d = self._live(dev_handle)
        if config_value not in (0, 1):
            raise usb_error("inval")
        d.configuration = config_value

    def get_configuration(self, dev_handle: _Handle) -> int:
        return self._live(dev_handle).configuration

    def set_interface_altsetting(self, dev_handle: _Handle, intf: int, altsetting: int) -> None:
        self._live(dev_handle)
        if altsetting != 0:
            raise usb_error("inval")

    def claim_interface(self, dev_handle: _Handle, intf: int) -> None:
        self._live(dev_handle)

    def release_interface(self, dev_handle: _Handle, intf: int) -> None:
        pass

    # -- transfers --------------------------------------------------------------------------
    def _check_ep(self, d: FakeUsbDevice, ep: int) -> None:
        if d.configuration == 0:
            raise usb_error("inval")  # not configured: endpoints are not there yet
        if ep not in d.endpoints:
            raise usb_error("inval")

    def bulk_write(self, dev_handle: _Handle, ep: int, intf: int, data: Any, timeout: int) -> int:
        d = self._live(dev_handle)
        self._check_ep(d, ep)
        return d.bulk_out(ep, bytes(data), timeout)

    intr_write = bulk_write

    def bulk_read(self, dev_handle: _Handle, ep: int, intf: int, buff: Any, timeout: int) -> int:
        d = self._live(dev_handle)
        self._check_ep(d, ep)
        size = len(buff) * buff.itemsize
        data = d.bulk_in(ep, size, timeout)
        buff[: len(data)] = type(buff)(buff.typecode, data)
        return len(data)

    intr_read = bulk_read

    def ctrl_transfer(
        self,
        dev_handle: _Handle,
        bmRequestType: int,
        bRequest: int,
        wValue: int,
        wIndex: int,
        data: Any,
        timeout: int,
    ) -> int:
        d = self._live(dev_handle)
        direction_in = bool(bmRequestType & 0x80)
        rtype = (bmRequestType >> 5) & 3
        if rtype == 0 and bRequest == 6 and direction_in:  # GET_DESCRIPTOR
            raw = d.raw_descriptor(wValue >> 8, wValue & 0xFF, wIndex)
            n = min(len(raw), len(data))
            data[:n] = type(data)(data.typecode, raw[:n])
            return n
        if rtype == 0 and bRequest == 8 and direction_in:  # GET_CONFIGURATION
            data[0] = d.configuration
            return 1
        if rtype == 0 and bRequest == 9:  # SET_CONFIGURATION
            d.configuration = wValue
            return 0
        if rtype == 0 and bRequest == 0 and direction_in:  # GET_STATUS
            data[:2] = type(data)(data.typecode, b"\x00\x00")
            return 2
        if rtype == 0 and bRequest == 1 and (bmRequestType & 3) == 2:  # CLEAR_FEATURE halt
            d._halted.discard(wIndex)
            return 0
        handler = getattr(d, "class_request", None)
        if handler is not None:
            return handler(bmRequestType, bRequest, wValue, wIndex, data, timeout)
        raise usb_error("pipe")

    def clear_halt(self, dev_handle: _Handle, ep: int) -> None:
        d = self._live(dev_handle)
        d._halted.discard(ep)

    def reset_device(self, dev_handle: _Handle) -> None:
        d = self._live(dev_handle)
        d._reset_queues()  # the configuration survives a port reset (the host restores it)
        d.on_reset()
        time.sleep(0.001)


def install(bench: Bench | None = None, *, name: str | None = None) -> str:
    """Register a fake bus as ``usb.backend.<name>`` and return ``name``.

    The bus holds a fake USB2000+ and a fake PTP camera on ``bench`` (default:
    ``Bench.for_instrument("lbl")``). ``usb.backend.<name>.get_backend()`` returns the
    backend; ``usb.backend.<name>.fakes`` maps ``"usb2000plus"``/``"ptp"`` to the fake
    devices (for fault injection).
    """
    from gonio.drivers.fake.ptp import FakePTPCamera
    from gonio.drivers.fake.usb2000 import FakeUSB2000Plus

    bench = bench or Bench.for_instrument("lbl")
    name = name or f"gonio_fake{next(_counter)}"
    if not name.isidentifier():
        raise ValueError(f"name={name!r}: expected a Python identifier")
    modname = f"usb.backend.{name}"
    if modname in sys.modules:
        raise ValueError(f"name={name!r}: a pyusb backend of that name is already installed")
    fakes = {"usb2000plus": FakeUSB2000Plus(bench), "ptp": FakePTPCamera(bench)}
    mod = types.ModuleType(modname, f"gonio fake USB bus (bench {bench!r})")
    cls = type("FakeUsbBackend", (FakeUsbBackend,), {"__module__": modname})
    backend = cls(list(fakes.values()))
    mod.get_backend = lambda find_library=None: backend  # type: ignore[attr-defined]
    mod.fakes = fakes  # type: ignore[attr-defined]
    mod.bench = bench  # type: ignore[attr-defined]
    mod.FakeUsbBackend = cls  # type: ignore[attr-defined]
    sys.modules[modname] = mod
    setattr(usb.backend, name, mod)
    return name


def devices(name: str) -> dict[str, FakeUsbDevice]:
    """The fake devices of the bus installed as ``name``."""
    try:
        return sys.modules[f"usb.backend.{name}"].fakes
    except KeyError:
        raise ValueError(f"name={name!r}: no fake pyusb backend of that name") from None


def uninstall(name: str) -> None:
    """Remove the backend module ``usb.backend.<name>``."""
    sys.modules.pop(f"usb.backend.{name}", None)
    if hasattr(usb.backend, name):
        delattr(usb.backend, name)


# ---------------------------------------------------------------------------------------------
# reaching a fake bus from another process (``gonio devices serve``)
# ---------------------------------------------------------------------------------------------
def _desc_dict(d: Any) -> dict:
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(d).items()}


#: Longest transfer a client may ask for (bytes): Linux usbfs's default memory limit for
#: all of a process's in-flight transfers (``usbfs_memory_mb`` = 16), so no real host sends
#: more; a longer read or write is refused before any buffer is allocated.
MAX_TRANSFER = 16 * 2**20

#: Longest request line (a base64 payload of :data:`MAX_TRANSFER` bytes plus the envelope).
MAX_REQUEST_LINE = 4 * MAX_TRANSFER // 3 + 4096

#: Most clients (connections) served at once; one more is answered with an error and closed.
MAX_CLIENTS = 16


def _transfer_length(v: Any, what: str) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= MAX_TRANSFER:
        raise ValueError(f"{what} length {v!r}: expected an integer in [0, {MAX_TRANSFER}]")
    return v


class RemoteServer:
    """Serve the backend ``name`` on 127.0.0.1 so other processes can :func:`connect` to it.

    One JSON request per line (``{"op": ..., "args": [...]}``, bytes in base64); one JSON
    reply per line (``{"ok": result}`` or ``{"error": {...}}``). ``address`` is
    ``"127.0.0.1:<port>"``. Resources are bounded: at most :data:`MAX_CLIENTS` connections
    (threads) at once, requests of at most :data:`MAX_REQUEST_LINE` bytes and transfers of
    at most :data:`MAX_TRANSFER` bytes; beyond them the client gets an error reply.
    """

    def __init__(self, name: str, port: int = 0) -> None:
        import socket
        import threading

        self._slots = threading.BoundedSemaphore(MAX_CLIENTS)
        self.refused = 0
        self.backend = getattr(usb.backend, name).get_backend()
        self._refs: dict[str, Any] = {}
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._sock.bind(("127.0.0.1", int(port)))
        self._sock.listen(8)
        self.address = f"127.0.0.1:{self._sock.getsockname()[1]}"
        self._closed = False
        threading.Thread(target=self._accept, name="fake-usb-server", daemon=True).start()

    def _accept(self) -> None:
        import threading

        while not self._closed:
            try:
                conn, _ = self._sock.accept()
            except OSError:
                return
            if not self._slots.acquire(blocking=False):
                self.refused += 1
                self._refuse(conn, f"busy: {MAX_CLIENTS} clients are connected")
                continue
            threading.Thread(target=self._serve_client, args=(conn,), daemon=True,
                             name=f"fake-usb-client {self.address}").start()  # fmt: skip

    @staticmethod
    def _refuse(conn: Any, msg: str) -> None:
        import json

        try:
            conn.sendall(json.dumps({"error": {"type": "other", "msg": msg}}).encode() + b"\n")
        except OSError:
            pass
        conn.close()

    def _serve_client(self, conn: Any) -> None:
        try:
            self._client(conn)
        finally:
            self._slots.release()
            try:
                conn.close()
            except OSError:
                pass

    def _ref(self, key: str) -> Any:
        try:
            return self._refs[key]
        except KeyError:
            raise usb_error("nodev") from None

    def _call(self, op: str, a: list) -> Any:
        """Run one backend operation of a request; its JSON-able result (bytes as base64)."""
        import array
        import base64

        be = self.backend
        if op == "enumerate_devices":
            out = []
            for ref in be.enumerate_devices():
                key = f"{be.fakes.index(ref.dev)}:{ref.generation}"
                self._refs[key] = ref
                out.append(key)
            res: Any = out
        elif op == "get_device_descriptor":
            res = _desc_dict(be.get_device_descriptor(self._ref(a[0])))
        elif op == "get_configuration_descriptor":
            res = _desc_dict(be.get_configuration_descriptor(self._ref(a[0]), a[1]))
        elif op == "get_interface_descriptor":
            res = _desc_dict(be.get_interface_descriptor(self._ref(a[0]), *a[1:]))
        elif op == "get_endpoint_descriptor":
            res = _desc_dict(be.get_endpoint_descriptor(self._ref(a[0]), *a[1:]))
        elif op in ("bulk_write", "intr_write"):
            res = getattr(be, op)(self._ref(a[0]), a[1], a[2], base64.b64decode(a[3]), a[4])
        elif op in ("bulk_read", "intr_read"):
            buff = array.array("B", bytes(_transfer_length(a[3], op)))
            n = getattr(be, op)(self._ref(a[0]), a[1], a[2], buff, a[4])
            res = base64.b64encode(buff[:n].tobytes()).decode()
        elif op == "ctrl_transfer":
            h, bm, req_, val, idx, payload, tmo = a
            if bm & 0x80:
                buff = array.array("B", bytes(_transfer_length(payload, op)))
                n = be.ctrl_transfer(self._ref(h), bm, req_, val, idx, buff, tmo)
                res = base64.b64encode(buff[:n].tobytes()).decode()
            else:
                buff = array.array("B", base64.b64decode(payload))
                res = be.ctrl_transfer(self._ref(h), bm, req_, val, idx, buff, tmo)
        elif op in (
            "open_device",
            "set_configuration",
            "get_configuration",
            "set_interface_altsetting",
            "claim_interface",
            "release_interface",
            "clear_halt",
            "reset_device",
        ):
            r = getattr(be, op)(self._ref(a[0]), *a[1:])
            res = a[0] if op == "open_device" else r
        else:
            raise ValueError(f"op={op!r}: not a backend operation")
        return res

    def _client(self, conn: Any) -> None:
        """Answer one client's requests (a JSON line each) until it hangs up."""
        import json
        import socket

        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        f = conn.makefile("rwb")
        while True:
            try:
                line = f.readline(MAX_REQUEST_LINE + 1)
            except OSError:
                return
            if not line:
                return
            if len(line) > MAX_REQUEST_LINE:
                self._refuse(conn, f"request longer than {MAX_REQUEST_LINE} bytes")
                return
            try:
                req = json.loads(line)
                op, a = req["op"], req.get("args", [])
                reply = {"ok": self._call(op, a)}
            except usb.core.USBError as exc:
                reply = {
                    "error": {
                        "type": "usb",
                        "msg": exc.strerror,
                        "code": exc.backend_error_code,
                        "errno": exc.errno,
                    }
                }
            except IndexError as exc:
                reply = {"error": {"type": "index", "msg": str(exc)}}
            except Exception as exc:
                reply = {"error": {"type": "other", "msg": f"{type(exc).__name__}: {exc}"}}
            try:
                f.write(json.dumps(reply).encode() + b"\n")
                f.flush()
            except OSError:
                return

    def close(self) -> None:
        self._closed = True
        try:
            self._sock.close()
        except OSError:
            pass


def serve_remote(name: str, port: int = 0) -> RemoteServer:
    """Make the installed fake bus ``name`` reachable from other processes."""
    return RemoteServer(name, port)


class _RemoteRef:
    def __init__(self, key: str) -> None:
        self.key = key


class _Remote:
    def __init__(self, address: str) -> None:
        import threading

        host, _, port = address.rpartition(":")
        if not host or not port.isdigit():
            raise ValueError(f"address={address!r}: expected 'host:port'")
        self.addr = (host, int(port))
        self._local = threading.local()

    def call(self, op: str, *args: Any) -> Any:
        import json
        import socket

        f = getattr(self._local, "f", None)
        if f is None:
            s = socket.create_connection(self.addr, timeout=None)
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            f = self._local.f = s.makefile("rwb")
        f.write(json.dumps({"op": op, "args": list(args)}).encode() + b"\n")
        f.flush()
        line = f.readline()
        if not line:
            self._local.f = None
            raise usb_error("nodev")
        reply = json.loads(line)
        if "ok" in reply:
            return reply["ok"]
        err = reply["error"]
        if err["type"] == "usb":
            cls = usb.core.USBTimeoutError if err["code"] == -7 else usb.core.USBError
            raise cls(err["msg"], err["code"], err["errno"])
        if err["type"] == "index":
            raise IndexError(err["msg"])
        raise RuntimeError(err["msg"])


class RemoteUsbBackend(_NoKernelDriver):
    """pyusb backend forwarding every call to a :class:`RemoteServer`."""

    def __init__(self, address: str) -> None:
        self.remote = _Remote(address)

    def enumerate_devices(self):
        for key in self.remote.call("enumerate_devices"):
            yield _RemoteRef(key)

    def get_device_descriptor(self, dev: Any) -> Any:
        d = types.SimpleNamespace(**self.remote.call("get_device_descriptor", dev.key))
        d.port_numbers = tuple(d.port_numbers)
        return d

    def get_configuration_descriptor(self, dev: Any, config: int) -> Any:
        return types.SimpleNamespace(
            **self.remote.call("get_configuration_descriptor", dev.key, config)
        )

    def get_interface_descriptor(self, dev: Any, intf: int, alt: int, config: int) -> Any:
        return types.SimpleNamespace(
            **self.remote.call("get_interface_descriptor", dev.key, intf, alt, config)
        )

    def get_endpoint_descriptor(self, dev: Any, ep: int, intf: int, alt: int, config: int) -> Any:
        return types.SimpleNamespace(
            **self.remote.call("get_endpoint_descriptor", dev.key, ep, intf, alt, config)
        )

    def open_device(self, dev: Any) -> Any:
        return _RemoteRef(self.remote.call("open_device", dev.key))

    def close_device(self, dev_handle: Any) -> None:
        pass

    def set_configuration(self, h: Any, config_value: int) -> None:
        self.remote.call("set_configuration", h.key, config_value)

    def get_configuration(self, h: Any) -> int:
        return self.remote.call("get_configuration", h.key)

    def set_interface_altsetting(self, h: Any, intf: int, alt: int) -> None:
        self.remote.call("set_interface_altsetting", h.key, intf, alt)

    def claim_interface(self, h: Any, intf: int) -> None:
        self.remote.call("claim_interface", h.key, intf)

    def release_interface(self, h: Any, intf: int) -> None:
        self.remote.call("release_interface", h.key, intf)

    def bulk_write(self, h: Any, ep: int, intf: int, data: Any, timeout: int) -> int:
        import base64

        return self.remote.call(
            "bulk_write", h.key, ep, intf, base64.b64encode(bytes(data)).decode(), timeout
        )

    def intr_write(self, h: Any, ep: int, intf: int, data: Any, timeout: int) -> int:
        return self.bulk_write(h, ep, intf, data, timeout)

    def _read(self, op: str, h: Any, ep: int, intf: int, buff: Any, timeout: int) -> int:
        import base64

        data = base64.b64decode(
            self.remote.call(op, h.key, ep, intf, len(buff) * buff.itemsize, timeout)
        )
        buff[: len(data)] = type(buff)(buff.typecode, data)
        return len(data)

    def bulk_read(self, h: Any, ep: int, intf: int, buff: Any, timeout: int) -> int:
        return self._read("bulk_read", h, ep, intf, buff, timeout)

    def intr_read(self, h: Any, ep: int, intf: int, buff: Any, timeout: int) -> int:
        return self._read("intr_read", h, ep, intf, buff, timeout)

    def ctrl_transfer(
        self,
        h: Any,
        bmRequestType: int,
        bRequest: int,
        wValue: int,
        wIndex: int,
        data: Any,
        timeout: int,
    ) -> Any:
        import base64

        if bmRequestType & 0x80:
            raw = base64.b64decode(
                self.remote.call(
                    "ctrl_transfer",
                    h.key,
                    bmRequestType,
                    bRequest,
                    wValue,
                    wIndex,
                    len(data),
                    timeout,
                )
            )
            data[: len(raw)] = type(data)(data.typecode, raw)
            return len(raw)
        payload = base64.b64encode(bytes(data) if data is not None else b"").decode()
        return self.remote.call(
            "ctrl_transfer", h.key, bmRequestType, bRequest, wValue, wIndex, payload, timeout
        )

    def clear_halt(self, h: Any, ep: int) -> None:
        self.remote.call("clear_halt", h.key, ep)

    def reset_device(self, h: Any) -> None:
        self.remote.call("reset_device", h.key)


def connect(address: str, *, name: str | None = None) -> str:
    """Register ``usb.backend.<name>`` forwarding to a fake bus served at ``address``.

    ``address`` is the ``usb_server`` printed by ``gonio devices serve``; returns ``name``,
    usable exactly like the one :func:`install` returns.
    """
    name = name or f"gonio_remote{next(_counter)}"
    modname = f"usb.backend.{name}"
    if modname in sys.modules:
        raise ValueError(f"name={name!r}: a pyusb backend of that name is already installed")
    mod = types.ModuleType(modname, f"gonio fake USB bus at {address}")
    cls = type("RemoteUsbBackend", (RemoteUsbBackend,), {"__module__": modname})
    backend = cls(address)
    mod.get_backend = lambda find_library=None: backend  # type: ignore[attr-defined]
    sys.modules[modname] = mod
    setattr(usb.backend, name, mod)
    return name
