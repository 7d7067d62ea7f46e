"""Fake still camera speaking PTP (ISO 15740) over USB (still-image class 6/1/1).

Endpoints: bulk IN 0x81, bulk OUT 0x02 (512-byte packets), interrupt IN 0x83 (events).
Operations: GetDeviceInfo, OpenSession, CloseSession, GetStorageIDs, GetObjectHandles,
GetObjectInfo, GetObject (a 16-bit TIFF), DeleteObject, InitiateCapture, GetDevicePropDesc,
Get/SetDevicePropValue for ExposureTime (0x500D, u32 in 0.1 ms) and FNumber (0x5007, u16
×100). InitiateCapture answers OK at once; after the (scaled) exposure the camera posts
ObjectAdded (handle) and CaptureComplete (the capture's transaction id) on the interrupt
endpoint. Class requests: Cancel (0x64), Device Reset (0x66), Get Device Status (0x67).
The image is the bench's ``camera_render`` for the stage positions when capture starts.
The object store survives an unplug (it is the memory card), sessions do not.

References
----------
ISO 15740:2013 §10-13; USB Still Image Capture Device Definition 1.0 §5-7.
"""

from __future__ import annotations

import struct
import threading
import time
from typing import ClassVar

import numpy as np
from gonio.drivers.fake.faults import Faults
from gonio.drivers.fake.usbdev import Endpoint, FakeUsbDevice, Interface
from gonio.drivers.ptpcodes import (
    CONTAINER_COMMAND,
    CONTAINER_DATA,
    CONTAINER_EVENT,
    CONTAINER_RESPONSE,
    EV,
    FORMAT_TIFF,
    OP,
    PROP,
    RC,
    container,
    pack_array,
    pack_string,
)
from gonio.simulator.bench import Bench

__all__ = ["FakePTPCamera", "encode_tiff16"]

STORAGE_ID = 0x00010001

#: Most images the fake camera's store holds (its card); a capture beyond them is answered
#: ``Store_Full`` (0x200C, PTP: ISO 15740 response codes) until the host deletes some.
MAX_OBJECTS = 256
STORE_FULL = 0x200C
F_NUMBERS = (280, 400, 560, 800, 1100, 1600, 2200)


def encode_tiff16(img: np.ndarray) -> bytes:
    """A 16-bit TIFF of ``img`` (OpenCV's encoder)."""
    import cv2

    ok, buf = cv2.imencode(".tiff", np.ascontiguousarray(img, dtype=np.uint16))
    if not ok:
        raise ValueError("cv2.imencode('.tiff') failed for the rendered image")
    return buf.tobytes()


class FakePTPCamera(FakeUsbDevice):
    """The firmware of a PTP still camera on a simulated bench.

    Parameters
    ----------
    bench : Bench
    faults : Faults, optional
    readout : float
        Simulated seconds of sensor readout after the exposure.
    """

    vendor, product, bcd_device = 0x1209, 0x0001, 0x0100  # pid.codes test id: not a real camera
    name = "ptp"
    interfaces: ClassVar[list[Interface]] = [
        Interface(
            0,
            6,
            1,
            1,
            [
                Endpoint(0x81, 2, 512),
                Endpoint(0x02, 2, 512),
                Endpoint(0x83, 3, 64, interval=8),
            ],
        )
    ]

    def __init__(
        self,
        bench: Bench,
        faults: Faults | None = None,
        readout: float = 0.05,
        serial: str = "GONIO-CAM-0001",
    ) -> None:
        self.bench = bench
        self.readout = float(readout)
        self.serial = serial
        self.strings = {1: "gonio", 2: "gonio simulated PTP camera", 3: serial}
        super().__init__(faults)
        self.objects: dict[int, tuple[bytes, dict]] = {}
        self._next_handle = 1
        self._lock = threading.RLock()
        self.exposure = 100  # 0.01 s in units of 0.1 ms
        self.f_number = 800
        self.on_reset()

    def on_reset(self) -> None:
        self.session = 0
        self._pending: tuple[int, int, list[int]] | None = None  # waiting for a data phase

    # -- bulk OUT ---------------------------------------------------------------------------
    def on_out(self, ep: int, data: bytes) -> None:
        if ep != 0x02:
            return
        if len(data) < 12:
            return  # a runt: dropped like a real device would (no response)
        length, ctype, code, tid = struct.unpack_from("<IHHI", data)
        if length != len(data):
            self._respond(RC["IncompleteTransfer"], tid)
            self._pending = None
            return
        payload = data[12:]
        if ctype == CONTAINER_DATA and self._pending is not None:
            op, ptid, params = self._pending
            self._pending = None
            if tid != ptid or code != op:
                self._respond(RC["InvalidTransactionID"], tid)
                return
            self._set_prop(params, payload, tid)
            return
        if ctype != CONTAINER_COMMAND:
            return
        params = [struct.unpack_from("<I", payload, 4 * i)[0] for i in range(len(payload) // 4)]
        self._command(code, tid, params)

    def _respond(self, rc: int, tid: int, params: tuple[int, ...] = ()) -> None:
        self.queue_in(0x81, container(CONTAINER_RESPONSE, rc, tid, params))

    def _data(self, op: int, tid: int, payload: bytes) -> None:
        self.queue_in(0x81, container(CONTAINER_DATA, op, tid, payload=payload))

    def _command(self, op: int, tid: int, p: list[int]) -> None:
        with self._lock:
            if op == OP["GetDeviceInfo"]:
                self._data(op, tid, self._device_info())
                return self._respond(RC["OK"], tid)
            if op == OP["OpenSession"]:
                if not p or p[0] == 0:
                    return self._respond(RC["InvalidParameter"], tid)
                if self.session:
                    return self._respond(RC["SessionAlreadyOpen"], tid, (self.session,))
                self.session = p[0]
                return self._respond(RC["OK"], tid)
            if op not in (OP["GetDeviceInfo"], OP["OpenSession"]) and not self.session:
                return self._respond(RC["SessionNotOpen"], tid)
            if op == OP["CloseSession"]:
                self.session = 0
                return self._respond(RC["OK"], tid)
            if op == OP["GetStorageIDs"]:
                self._data(op, tid, pack_array("I", [STORAGE_ID]))
                return self._respond(RC["OK"], tid)
            if op == OP["GetObjectHandles"]:
                if p and p[0] not in (0xFFFFFFFF, STORAGE_ID):
                    return self._respond(RC["InvalidStorageID"], tid)
                fmt = p[1] if len(p) > 1 else 0
                handles = [h for h in sorted(self.objects) if fmt in (0, FORMAT_TIFF)]
                self._data(op, tid, pack_array("I", handles))
                return self._respond(RC["OK"], tid)
            if op in (OP["GetObjectInfo"], OP["GetObject"], OP["DeleteObject"]):
                h = p[0] if p else 0
                if op == OP["DeleteObject"] and h == 0xFFFFFFFF:
                    self.objects.clear()
                    return self._respond(RC["OK"], tid)
                if h not in self.objects:
                    return self._respond(RC["InvalidObjectHandle"], tid)
                blob, info = self.objects[h]
                if op == OP["GetObjectInfo"]:
                    self._data(op, tid, self._object_info(blob, info))
                elif op == OP["GetObject"]:
                    self._data(op, tid, blob)
                else:
                    del self.objects[h]
                return self._respond(RC["OK"], tid)
            if op == OP["InitiateCapture"]:
                if p and p[0] not in (0, STORAGE_ID):
                    return self._respond(RC["InvalidStorageID"], tid)
                if p and len(p) > 1 and p[1] not in (0, FORMAT_TIFF):
                    return self._respond(RC["ParameterNotSupported"], tid)
                if len(self.objects) >= MAX_OBJECTS:
                    return self._respond(STORE_FULL, tid)
                self._capture(tid)
                return self._respond(RC["OK"], tid)
            if op == OP["GetDevicePropValue"]:
                prop = p[0] if p else 0
                if prop == PROP["ExposureTime"]:
                    self._data(op, tid, struct.pack("<I", self.exposure))
                elif prop == PROP["FNumber"]:
                    self._data(op, tid, struct.pack("<H", self.f_number))
                else:
                    return self._respond(RC["DevicePropNotSupported"], tid)
                return self._respond(RC["OK"], tid)
            if op == OP["GetDevicePropDesc"]:
                prop = p[0] if p else 0
                if prop == PROP["ExposureTime"]:
                    desc = struct.pack("<HHBIIB", prop, 0x0006, 1, 100, self.exposure, 1)
                    desc += struct.pack("<III", 1, 3_000_000, 1)  # range form: min max step
                elif prop == PROP["FNumber"]:
                    desc = struct.pack("<HHBHHB", prop, 0x0004, 1, 800, self.f_number, 2)
                    desc += struct.pack("<H", len(F_NUMBERS)) + b"".join(
                        struct.pack("<H", f) for f in F_NUMBERS
                    )
                else:
                    return self._respond(RC["DevicePropNotSupported"], tid)
                self._data(op, tid, desc)
                return self._respond(RC["OK"], tid)
            if op == OP["SetDevicePropValue"]:
                if not p or p[0] not in PROP.values():
                    return self._respond(RC["DevicePropNotSupported"], tid)
                self._pending = (op, tid, p)
                return None
            return self._respond(RC["OperationNotSupported"], tid)

    def _set_prop(self, params: list[int], payload: bytes, tid: int) -> None:
        prop = params[0]
        if prop == PROP["ExposureTime"]:
            if len(payload) != 4:
                return self._respond(RC["InvalidDevicePropValue"], tid)
            v = struct.unpack("<I", payload)[0]
            if not 1 <= v <= 3_000_000:
                return self._respond(RC["InvalidDevicePropValue"], tid)
            self.exposure = v
        else:
            if len(payload) != 2:
                return self._respond(RC["InvalidDevicePropValue"], tid)
            v = struct.unpack("<H", payload)[0]
            if v not in F_NUMBERS:
                return self._respond(RC["InvalidDevicePropValue"], tid)
            self.f_number = v
        return self._respond(RC["OK"], tid)

    # -- datasets ---------------------------------------------------------------------------
    def _device_info(self) -> bytes:
        out = struct.pack("<HIH", 100, 0, 0) + pack_string("") + struct.pack("<H", 0)
        out += pack_array("H", sorted(OP.values()))
        out += pack_array("H", sorted(EV.values()))
        out += pack_array("H", sorted(PROP.values()))
        out += pack_array("H", [FORMAT_TIFF]) + pack_array("H", [FORMAT_TIFF])
        for s in ("gonio", "gonio simulated PTP camera", "1.0", self.serial):
            out += pack_string(s)
        return out

    def _object_info(self, blob: bytes, info: dict) -> bytes:
        h, w = info["height"], info["width"]
        out = struct.pack(
            "<IHHIHIIIIIIIHII",
            STORAGE_ID,
            FORMAT_TIFF,
            0,
            len(blob),
            0,
            0,
            0,
            0,
            w,
            h,
            16,
            0,
            0,
            0,
            info["sequence"],
        )
        for s in (info["filename"], info["date"], info["date"], ""):
            out += pack_string(s)
        return out

    # -- capture ----------------------------------------------------------------------------
    def _capture(self, tid: int) -> None:
        exposure_s = self.exposure * 1e-4
        f_number = self.f_number / 100.0
        img, _meta = self.bench.render_image(exposure_s, f_number)
        blob = encode_tiff16(img)
        handle = self._next_handle
        self._next_handle += 1
        date = time.strftime("%Y%m%dT%H%M%S", time.gmtime())
        self.objects[handle] = (
            blob,
            {
                "height": int(img.shape[0]),
                "width": int(img.shape[1]),
                "sequence": handle,
                "filename": f"IMG_{handle:04d}.TIF",
                "date": date,
            },
        )
        ready = time.monotonic() + self.bench.clock.real_seconds(exposure_s + self.readout)
        self.queue_in(
            0x83, container(CONTAINER_EVENT, EV["ObjectAdded"], tid, (handle,)), ready_at=ready
        )
        self.queue_in(
            0x83, container(CONTAINER_EVENT, EV["CaptureComplete"], tid, (tid,)), ready_at=ready
        )

    # -- class-specific control requests ----------------------------------------------------
    def class_request(self, bm: int, req: int, value: int, index: int, data, timeout: int) -> int:
        if req == 0x67 and bm & 0x80:  # Get Device Status
            st = struct.pack("<HH", 4, RC["OK"])
            n = min(len(st), len(data))
            data[:n] = type(data)(data.typecode, st[:n])
            return n
        if req == 0x66:  # Device Reset
            self.on_reset()
            self._reset_queues()
            return 0
        if req == 0x64:  # Cancel
            self._pending = None
            self._reset_queues()
            return 0
        from gonio.drivers.fake.usbdev import usb_error

        raise usb_error("pipe")
