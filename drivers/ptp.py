"""A still camera speaking PTP (ISO 15740) over USB via pyusb (still-image class 6/1/1).

Transactions follow the USB still-image transport: a command container on the bulk OUT
endpoint, an optional data phase (device → host, or host → device for
SetDevicePropValue), then a response container on bulk IN; events (ObjectAdded 0x4002,
CaptureComplete 0x400D) arrive on the interrupt endpoint. A data container longer than one
packet ends with a short packet, or with a zero-length packet when its length is a multiple
of ``wMaxPacketSize``.

Operations: GetDeviceInfo 0x1001, OpenSession 0x1002, CloseSession 0x1003, GetStorageIDs
0x1004, GetObjectHandles 0x1007, GetObjectInfo 0x1008, GetObject 0x1009, DeleteObject
0x100B, InitiateCapture 0x100E, GetDevicePropValue 0x1015, SetDevicePropValue 0x1016 for
ExposureTime 0x500D (u32, units of 0.1 ms) and FNumber 0x5007 (u16, f-number × 100).

References
----------
ISO 15740:2013 §5, §10-13; USB Still Image Capture Device Definition 1.0 §7.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np
from gonio.drivers._retry import (
    BadReply,
    check_timeout,
    clear_halts,
    open_usb,
    reconnect,
    retry,
)
from gonio.drivers.errors import DeviceError, DeviceTimeout
from gonio.drivers.ptpcodes import (
    CONTAINER_COMMAND,
    CONTAINER_DATA,
    CONTAINER_EVENT,
    CONTAINER_RESPONSE,
    EV,
    OP,
    OP_NAMES,
    PROP,
    RC,
    RC_NAMES,
    container,
    unpack_array,
    unpack_string,
)
from gonio.drivers.transport import (
    TransportDisconnected,
    TransportStall,
    TransportTimeout,
    UsbTransportProtocol,
)

__all__ = ["PTPCamera", "PTPError"]

DEVICE = "PTP camera"
EP_IN, EP_OUT, EP_EVENT = 0x81, 0x02, 0x83
PACKET = 512
T = TypeVar("T")


class PTPError(DeviceError):
    """The camera answered with a response code other than OK."""

    def __init__(self, command: str, code: int) -> None:
        self.code = code
        super().__init__(
            DEVICE,
            command,
            f"0x{code:04X} {RC_NAMES.get(code, '?')}",
            f"response {RC_NAMES.get(code, hex(code))}",
        )


def _is_still_image(dev: Any) -> bool:
    try:
        return any(i.bInterfaceClass == 6 for cfg in dev for i in cfg)
    except Exception:
        return False


class PTPCamera:
    """Driver for a PTP still camera (implements the ``Camera`` interface).

    Parameters
    ----------
    transport : UsbTransportProtocol
        E.g. ``UsbTransport(None, None, backend=..., match=...)``; see :meth:`open`.
    timeout : float
        Seconds allowed per transfer.
    retries : int
        Extra attempts for idempotent operations after a timeout, stall or reconnect.
    session_id : int
        The id sent with OpenSession.
    """

    device = DEVICE

    def __init__(
        self,
        transport: UsbTransportProtocol,
        *,
        timeout: float = 2.0,
        retries: int = 2,
        session_id: int = 1,
        open_session: bool = True,
    ) -> None:
        self.transport = transport
        self.timeout = check_timeout(timeout)
        self.retries = int(retries)
        self.session_id = int(session_id)
        self._tid = 0
        self.session_open = False
        if open_session:
            self.open_session()

    @classmethod
    def open(cls, backend: Any = None, **kwargs: Any) -> PTPCamera:
        """The first still-image-class device on the (named or given) pyusb ``backend``."""
        return cls(open_usb(DEVICE, None, None, backend, match=_is_still_image), **kwargs)

    # -- transport level --------------------------------------------------------------------
    @property
    def _tmo(self) -> int:
        return max(1, int(self.timeout * 1000))

    def _next_tid(self) -> int:
        self._tid = (self._tid + 1) & 0xFFFFFFFF or 1
        return self._tid

    def _read_container(self, what: str) -> tuple[int, int, int, bytes]:
        first = self.transport.read(EP_IN, PACKET, self._tmo)
        if len(first) < 12:
            raise BadReply(first, f"{what}: runt container of {len(first)} bytes")
        length, ctype, code, tid = struct.unpack_from("<IHHI", first)
        if ctype not in (CONTAINER_DATA, CONTAINER_RESPONSE) or length < 12:
            raise BadReply(first[:12], f"{what}: bad container header")
        data = bytearray(first)
        while len(data) < length:
            if len(data) % PACKET:
                raise BadReply(
                    bytes(data[:12]), f"{what}: short packet after {len(data)} of {length} bytes"
                )
            want = length - len(data)
            want += (-want) % PACKET
            chunk = self.transport.read(EP_IN, want, self._tmo)
            if not chunk:
                break
            data += chunk
        if len(data) != length:
            raise BadReply(bytes(data[:12]), f"{what}: {len(data)} bytes, header says {length}")
        if length % PACKET == 0 and length > 0:
            try:  # the zero-length packet that ends a transfer of whole packets
                self.transport.read(EP_IN, PACKET, 50)
            except TransportTimeout:
                pass
        return ctype, code, tid, bytes(data[12:])

    def transaction(
        self, op: int, params: tuple[int, ...] = (), data_out: bytes | None = None
    ) -> tuple[bytes | None, tuple[int, ...]]:
        """One PTP transaction: ``(data-in payload or None, response parameters)``.

        Raises :class:`PTPError` for a response code other than OK.
        """
        name = f"{OP_NAMES.get(op, hex(op))}{tuple(params) if params else ''}"
        tid = self._next_tid()
        self.transport.write(EP_OUT, container(CONTAINER_COMMAND, op, tid, params), self._tmo)
        if data_out is not None:
            self.transport.write(
                EP_OUT, container(CONTAINER_DATA, op, tid, payload=data_out), self._tmo
            )
        payload = None
        ctype, code, rtid, body = self._read_container(name)
        if ctype == CONTAINER_DATA:
            if code != op or rtid != tid:
                raise BadReply(
                    body[:8],
                    f"{name}: data for 0x{code:04X}/tid {rtid}, expected 0x{op:04X}/tid {tid}",
                )
            payload = body
            ctype, code, rtid, body = self._read_container(name)
        if ctype != CONTAINER_RESPONSE or rtid != tid:
            raise BadReply(body[:8], f"{name}: expected the response to tid {tid}")
        if code != RC["OK"]:
            raise PTPError(name, code)
        rparams = tuple(struct.unpack_from("<I", body, 4 * i)[0] for i in range(len(body) // 4))
        return payload, rparams

    def _recover(self) -> None:
        reconnect(self.transport, DEVICE)
        was_open, self.session_open = self.session_open, False
        if was_open:
            self.open_session()

    def _retry(self, command: str, fn: Callable[[], T], idempotent: bool = True) -> T:
        return retry(
            DEVICE,
            command,
            fn,
            self.retries + 1 if idempotent else 1,
            recover=self._recover,
            clear_stall=self._clear_stall,
            after_error=self._drain,
        )

    def _clear_stall(self) -> None:
        if clear_halts(self.transport, (EP_IN, EP_OUT), self._recover):
            self._drain()

    def _drain(self) -> None:
        try:
            while True:
                self.transport.read(EP_IN, 1 << 16, 20)
        except (TransportTimeout, TransportStall, TransportDisconnected):
            pass

    # -- operations -------------------------------------------------------------------------
    def device_info(self) -> dict[str, Any]:
        """GetDeviceInfo: the DeviceInfo dataset, decoded."""
        data, _ = self._retry("GetDeviceInfo", lambda: self.transaction(OP["GetDeviceInfo"]))
        assert data is not None
        std, vext, vver = struct.unpack_from("<HIH", data)
        off = 8
        vdesc, off = unpack_string(data, off)
        (mode,) = struct.unpack_from("<H", data, off)
        off += 2
        ops, off = unpack_array("H", data, off)
        events, off = unpack_array("H", data, off)
        props, off = unpack_array("H", data, off)
        cap, off = unpack_array("H", data, off)
        img, off = unpack_array("H", data, off)
        strings = []
        for _ in range(4):
            s, off = unpack_string(data, off)
            strings.append(s)
        return {
            "standard_version": std,
            "vendor_extension_id": vext,
            "vendor_extension_version": vver,
            "vendor_extension_desc": vdesc,
            "functional_mode": mode,
            "operations": ops,
            "events": events,
            "properties": props,
            "capture_formats": cap,
            "image_formats": img,
            "manufacturer": strings[0],
            "model": strings[1],
            "device_version": strings[2],
            "serial_number": strings[3],
        }

    def open_session(self) -> None:
        """OpenSession (a session already open on the camera is closed and reopened)."""
        try:
            self.transaction(OP["OpenSession"], (self.session_id,))
        except PTPError as exc:
            if exc.code != RC["SessionAlreadyOpen"]:
                raise
            self.transaction(OP["CloseSession"])
            self.transaction(OP["OpenSession"], (self.session_id,))
        self.session_open = True

    def close_session(self) -> None:
        """CloseSession."""
        if self.session_open:
            self.transaction(OP["CloseSession"])
            self.session_open = False

    def get_prop(self, prop: int, fmt: str) -> int:
        """GetDevicePropValue."""
        data, _ = self._retry(
            f"GetDevicePropValue(0x{prop:04X})",
            lambda: self.transaction(OP["GetDevicePropValue"], (prop,)),
        )
        size = struct.calcsize("<" + fmt)
        if data is None or len(data) != size:
            raise DeviceError(
                DEVICE, f"GetDevicePropValue(0x{prop:04X})", data, f"expected {size} bytes"
            )
        return struct.unpack("<" + fmt, data)[0]

    def set_prop(self, prop: int, fmt: str, value: int) -> None:
        """SetDevicePropValue (idempotent, so retried)."""
        payload = struct.pack("<" + fmt, value)
        self._retry(
            f"SetDevicePropValue(0x{prop:04X}, {value})",
            lambda: self.transaction(OP["SetDevicePropValue"], (prop,), payload),
        )

    @property
    def exposure(self) -> float:
        """Exposure time in seconds (ExposureTime 0x500D, units of 0.1 ms)."""
        return self.get_prop(PROP["ExposureTime"], "I") * 1e-4

    @exposure.setter
    def exposure(self, seconds: float) -> None:
        v = round(float(seconds) * 1e4)
        if v < 1:
            raise ValueError(f"exposure={seconds!r}: expected at least 0.0001 s")
        self.set_prop(PROP["ExposureTime"], "I", v)

    @property
    def f_number(self) -> float:
        """F-number (FNumber 0x5007, f-number × 100)."""
        return self.get_prop(PROP["FNumber"], "H") / 100.0

    @f_number.setter
    def f_number(self, value: float) -> None:
        v = round(float(value) * 100)
        if not 0 < v < 65536:
            raise ValueError(f"f_number={value!r}: expected a positive f-number")
        self.set_prop(PROP["FNumber"], "H", v)

    def object_handles(self) -> list[int]:
        """GetObjectHandles (all storages, all formats)."""
        data, _ = self._retry(
            "GetObjectHandles", lambda: self.transaction(OP["GetObjectHandles"], (0xFFFFFFFF, 0, 0))
        )
        return unpack_array("I", data or b"\0\0\0\0", 0)[0]

    def object_info(self, handle: int) -> dict[str, Any]:
        """GetObjectInfo, decoded."""
        data, _ = self._retry(
            f"GetObjectInfo({handle})", lambda: self.transaction(OP["GetObjectInfo"], (handle,))
        )
        assert data is not None
        v = struct.unpack_from("<IHHIHIIIIIIIHII", data)
        off = struct.calcsize("<IHHIHIIIIIIIHII")
        names = (
            "storage_id",
            "format",
            "protection",
            "size",
            "thumb_format",
            "thumb_size",
            "thumb_width",
            "thumb_height",
            "width",
            "height",
            "bit_depth",
            "parent",
            "association_type",
            "association_desc",
            "sequence",
        )
        info = dict(zip(names, v))
        for key in ("filename", "capture_date", "modification_date", "keywords"):
            info[key], off = unpack_string(data, off)
        return info

    def get_object(self, handle: int) -> bytes:
        """GetObject: the object's bytes."""
        data, _ = self._retry(
            f"GetObject({handle})", lambda: self.transaction(OP["GetObject"], (handle,))
        )
        return data or b""

    def delete_object(self, handle: int) -> None:
        """DeleteObject."""
        try:
            self._retry(
                f"DeleteObject({handle})", lambda: self.transaction(OP["DeleteObject"], (handle,))
            )
        except PTPError as exc:
            if exc.code != RC["InvalidObjectHandle"]:  # already gone after a retried delete
                raise

    def initiate_capture(self) -> int:
        """InitiateCapture; returns its transaction id (not retried: it takes a picture)."""
        self._retry(
            "InitiateCapture",
            lambda: self.transaction(OP["InitiateCapture"], (0, 0)),
            idempotent=False,
        )
        return self._tid

    def wait_event(self, timeout: float) -> tuple[int, int, tuple[int, ...]]:
        """One event from the interrupt endpoint: ``(code, transaction id, params)``."""
        data = self.transport.read(EP_EVENT, 64, max(1, int(timeout * 1000)))
        if len(data) < 12:
            raise BadReply(data, "runt event container")
        length, ctype, code, tid = struct.unpack_from("<IHHI", data)
        if ctype != CONTAINER_EVENT or length != len(data):
            raise BadReply(data, "bad event container")
        params = tuple(
            struct.unpack_from("<I", data, 12 + 4 * i)[0] for i in range((len(data) - 12) // 4)
        )
        return code, tid, params

    def capture(self, timeout: float = 30.0, delete: bool = True) -> tuple[np.ndarray, dict]:
        """InitiateCapture, wait for ObjectAdded and CaptureComplete, fetch and decode the TIFF.

        Returns the uint16 image and metadata (exposure, f-number, object info).
        """
        import cv2

        exposure, f_number = self.exposure, self.f_number
        tid = self.initiate_capture()
        deadline = time.monotonic() + float(timeout)
        handle = None
        complete = False
        while not complete:
            left = deadline - time.monotonic()
            if left <= 0:
                raise DeviceTimeout(
                    DEVICE,
                    "InitiateCapture",
                    None,
                    f"no CaptureComplete within {timeout:g} s "
                    f"(ObjectAdded {'seen' if handle else 'not seen'})",
                )
            try:
                code, etid, params = self.wait_event(min(left, 1.0))  # poll in slices
            except TransportTimeout:
                continue
            except TransportDisconnected:
                self._recover()
                continue
            except BadReply:
                continue
            if code == EV["ObjectAdded"] and params:
                handle = params[0]
            elif code == EV["CaptureComplete"] and (etid == tid or (params and params[0] == tid)):
                complete = True
        if handle is None:  # event lost: look in the store
            handles = self.object_handles()
            if not handles:
                raise DeviceError(DEVICE, "InitiateCapture", None, "capture produced no object")
            handle = handles[-1]
        info = self.object_info(handle)
        blob = self.get_object(handle)
        img = cv2.imdecode(np.frombuffer(blob, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
        if img is None or img.dtype != np.uint16:
            raise DeviceError(
                DEVICE, f"GetObject({handle})", blob[:16], "object is not a 16-bit image"
            )
        if len(blob) != info["size"]:
            raise DeviceError(
                DEVICE,
                f"GetObject({handle})",
                len(blob),
                f"object size {len(blob)} != ObjectInfo size {info['size']}",
            )
        if delete:
            self.delete_object(handle)
        meta = {"exposure_s": exposure, "f_number": f_number, "handle": handle, **info}
        return img, meta

    def close(self) -> None:
        try:
            self.close_session()
        except (DeviceError, TransportDisconnected, TransportTimeout, TransportStall):
            pass
        self.transport.close()
