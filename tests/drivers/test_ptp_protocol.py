"""Exact bytes of the PTP camera driver's transactions against a scripted USB transport."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from gonio.drivers.errors import DeviceTimeout
from gonio.drivers.ptp import PTPCamera, PTPError
from gonio.drivers.testing import ScriptedUsbTransport
from gonio.drivers.transport import TransportTimeout


def _container(kind: int, code: int, tid: int, params: tuple[int, ...]) -> bytes:
    """A PTP container of ``kind`` (1 command, 3 response, 4 event) with 32-bit params."""
    return struct.pack("<IHHI", 12 + 4 * len(params), kind, code, tid) + b"".join(
        struct.pack("<I", p) for p in params
    )


def cmd(code: int, tid: int, *params: int) -> bytes:
    return _container(1, code, tid, params)


def data(code: int, tid: int, payload: bytes) -> bytes:
    return struct.pack("<IHHI", 12 + len(payload), 2, code, tid) + payload


def resp(code: int, tid: int, *params: int) -> bytes:
    return _container(3, code, tid, params)


def event(code: int, tid: int, *params: int) -> bytes:
    return _container(4, code, tid, params)


def get_prop(tid: int, prop: int, value: bytes) -> list:
    """GetDevicePropValue of ``prop``: command, the camera's data phase, OK."""
    return [
        ("out", 0x02, cmd(0x1015, tid, prop)),
        ("in", 0x81, data(0x1015, tid, value)),
        ("in", 0x81, resp(0x2001, tid)),
    ]


def set_prop(tid: int, prop: int, value: bytes, code: int = 0x2001) -> list:
    """SetDevicePropValue of ``prop``: command, the host's data phase, response ``code``."""
    return [
        ("out", 0x02, cmd(0x1016, tid, prop)),
        ("out", 0x02, data(0x1016, tid, value)),
        ("in", 0x81, resp(code, tid)),
    ]


#: Capture at exposure 100 (0.01 s) and f-number 800 (f/8): both read, then InitiateCapture.
CAPTURE_START = [
    *get_prop(2, 0x500D, b"\x64\0\0\0"),
    *get_prop(3, 0x5007, b"\x20\x03"),
    ("out", 0x02, cmd(0x100E, 4, 0, 0)),
    ("in", 0x81, resp(0x2001, 4)),
]


OPEN = [
    ("out", 0x02, bytes.fromhex("10000000 0100 0210 01000000 01000000")),
    ("in", 0x81, bytes.fromhex("0c000000 0300 0120 01000000")),
]


def make(script, **kw):
    t = ScriptedUsbTransport([*OPEN, *script])
    return PTPCamera(t, **kw), t


def test_open_session_bytes():
    cam, t = make([])
    assert cam.session_open
    t.assert_done()


def test_open_session_when_already_open_closes_and_reopens():
    t = ScriptedUsbTransport(
        [
            ("out", 0x02, cmd(0x1002, 1, 1)),
            ("in", 0x81, resp(0x201E, 1, 1)),
            ("out", 0x02, cmd(0x1003, 2)),
            ("in", 0x81, resp(0x2001, 2)),
            ("out", 0x02, cmd(0x1002, 3, 1)),
            ("in", 0x81, resp(0x2001, 3)),
        ]
    )
    PTPCamera(t)
    t.assert_done()


def test_get_device_info_decodes_dataset():
    def s(x: str) -> bytes:
        return bytes([len(x) + 1]) + (x + "\0").encode("utf-16-le") if x else b"\0"

    def arr(v):
        return struct.pack("<I", len(v)) + b"".join(struct.pack("<H", i) for i in v)

    payload = (
        struct.pack("<HIH", 100, 0, 0)
        + s("")
        + struct.pack("<H", 0)
        + arr([0x1001, 0x1002])
        + arr([0x4002])
        + arr([0x500D])
        + arr([0x380D])
        + arr([0x380D])
        + s("Maker")
        + s("Model")
        + s("1.0")
        + s("SN1")
    )
    cam, t = make(
        [
            ("out", 0x02, cmd(0x1001, 2)),
            ("in", 0x81, data(0x1001, 2, payload)),
            ("in", 0x81, resp(0x2001, 2)),
        ]
    )
    info = cam.device_info()
    assert info["operations"] == [0x1001, 0x1002] and info["model"] == "Model"
    assert info["serial_number"] == "SN1" and info["standard_version"] == 100
    t.assert_done()


def test_exposure_and_fnumber_get_set():
    cam, t = make(
        [
            *set_prop(2, 0x500D, b"\xf4\x01\0\0"),
            *get_prop(3, 0x500D, b"\xf4\x01\0\0"),
            *set_prop(4, 0x5007, b"\x30\x02"),
            *get_prop(5, 0x5007, b"\x30\x02"),
        ]
    )
    cam.exposure = 0.05
    assert cam.exposure == pytest.approx(0.05)
    cam.f_number = 5.6
    assert cam.f_number == pytest.approx(5.6)
    t.assert_done()


def test_invalid_prop_value_raises_ptp_error():
    cam, t = make(set_prop(2, 0x5007, b"\xe8\x03", code=0x201C))
    with pytest.raises(PTPError) as ei:
        cam.f_number = 10.0
    assert ei.value.code == 0x201C and "InvalidDevicePropValue" in str(ei.value)
    t.assert_done()


def test_capture_sequence_bytes():
    import cv2

    img = (np.arange(12 * 16).reshape(12, 16) * 300).astype(np.uint16)
    _, buf = cv2.imencode(".tiff", img)
    blob = buf.tobytes()

    def st(x: str) -> bytes:
        return bytes([len(x) + 1]) + (x + "\0").encode("utf-16-le") if x else b"\0"

    info = (
        struct.pack(
            "<IHHIHIIIIIIIHII", 0x10001, 0x380D, 0, len(blob), 0, 0, 0, 0, 16, 12, 16, 0, 0, 0, 1
        )
        + st("IMG_0001.TIF")
        + st("20260101T000000") * 2
        + st("")
    )
    cam, t = make(
        [
            *CAPTURE_START,
            ("in", 0x83, TransportTimeout("no event yet")),
            ("in", 0x83, event(0x4002, 4, 1)),
            ("in", 0x83, event(0x400D, 4, 4)),
            ("out", 0x02, cmd(0x1008, 5, 1)),
            ("in", 0x81, data(0x1008, 5, info)),
            ("in", 0x81, resp(0x2001, 5)),
            ("out", 0x02, cmd(0x1009, 6, 1)),
        ]
    )
    # the data phase: first packet, then the rest (ends with a short packet or a ZLP)
    big = data(0x1009, 6, blob)
    t.script += [("in", 0x81, big[:512])]
    if len(big) > 512:
        t.script += [("in", 0x81, big[512:])]
    if len(big) % 512 == 0:
        t.script += [("in", 0x81, b"")]
    t.script += [
        ("in", 0x81, resp(0x2001, 6)),
        ("out", 0x02, cmd(0x100B, 7, 1)),
        ("in", 0x81, resp(0x2001, 7)),
    ]
    out, meta = cam.capture(timeout=1.0)
    np.testing.assert_array_equal(out, img)
    assert meta["filename"] == "IMG_0001.TIF" and meta["exposure_s"] == pytest.approx(0.01)
    assert meta["f_number"] == 8.0 and meta["width"] == 16 and meta["height"] == 12
    t.assert_done()


def test_object_handles_and_delete():
    cam, t = make(
        [
            ("out", 0x02, cmd(0x1007, 2, 0xFFFFFFFF, 0, 0)),
            ("in", 0x81, data(0x1007, 2, struct.pack("<III", 2, 5, 9))),
            ("in", 0x81, resp(0x2001, 2)),
            ("out", 0x02, cmd(0x100B, 3, 5)),
            ("in", 0x81, resp(0x2001, 3)),
            ("out", 0x02, cmd(0x1003, 4)),
            ("in", 0x81, resp(0x2001, 4)),
        ]
    )
    assert cam.object_handles() == [5, 9]
    cam.delete_object(5)
    cam.close()
    t.assert_done()


def test_capture_without_events_times_out_clearly():
    cam, t = make(CAPTURE_START)

    def read(ep, size, timeout_ms, _orig=t.read):
        if ep == 0x83:
            import time

            time.sleep(timeout_ms / 1000)
            raise TransportTimeout("no event")
        return _orig(ep, size, timeout_ms)

    t.read = read  # type: ignore[method-assign]
    with pytest.raises(DeviceTimeout) as ei:
        cam.capture(timeout=0.1)
    assert ei.value.command == "InitiateCapture" and "CaptureComplete" in str(ei.value)
    t.assert_done()
