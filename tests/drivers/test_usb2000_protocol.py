"""Exact bytes of every USB2000+ driver command against a scripted USB transport."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from gonio.drivers.errors import DeviceError, DeviceTimeout
from gonio.drivers.testing import ScriptedUsbTransport
from gonio.drivers.transport import TransportDisconnected, TransportStall, TransportTimeout
from gonio.drivers.usb2000 import USB2000Plus


def slot(n: int, text: str) -> bytes:
    data = text.encode()
    return bytes([0x05, n]) + data + bytes(15 - len(data))


def spectrum_packets(counts: np.ndarray) -> list[tuple[str, int, bytes]]:
    raw = counts.astype("<u2").tobytes()
    return [("in", 0x82, raw + b"\x69")]


def make(script, **kw):
    t = ScriptedUsbTransport([("out", 0x01, b"\x01"), *script])
    return USB2000Plus(t, **kw), t


def test_initialize_sends_0x01():
    s, t = make([])
    t.assert_done()
    assert s.integration_time == pytest.approx(0.01)


def test_set_integration_time_is_u32_little_endian_microseconds():
    s, t = make([("out", 0x01, b"\x02\x20\xa1\x07\x00")])  # 500000 us
    s.integration_time = 0.5
    assert s.integration_time == 0.5
    t.assert_done()


def test_read_slot_and_serial_number():
    s, t = make([("out", 0x01, b"\x05\x00"), ("in", 0x81, slot(0, "USB2+F07001"))])
    assert s.serial_number() == "USB2+F07001"
    t.assert_done()


def test_wavelengths_from_slots_1_to_4():
    coeffs = ["3.397000e+02", "3.825000e-01", "-1.710000e-05", "-1.100000e-09"]
    script = []
    for i, c in enumerate(coeffs, start=1):
        script += [("out", 0x01, bytes([0x05, i])), ("in", 0x81, slot(i, c))]
    s, t = make(script)
    w = s.wavelengths()
    p = np.arange(2048.0)
    np.testing.assert_allclose(w, 339.7 + 0.3825 * p - 1.71e-5 * p**2 - 1.1e-9 * p**3)
    s.wavelengths()  # cached: no more traffic
    t.assert_done()


def test_nonlinearity_coefficients_order_in_slot_14():
    script = [("out", 0x01, b"\x05\x0e"), ("in", 0x81, slot(14, "1"))]
    script += [
        ("out", 0x01, b"\x05\x06"),
        ("in", 0x81, slot(6, "9.5e-01")),
        ("out", 0x01, b"\x05\x07"),
        ("in", 0x81, slot(7, "7e-06")),
    ]
    s, t = make(script)
    assert s.nonlinearity_coefficients() == [0.95, 7e-6]
    t.assert_done()


def test_status_block():
    status = struct.pack("<HLBBBBBBBBBB", 2048, 10000, 0, 0, 0, 8, 0, 0, 0, 0, 0x80, 0)
    s, t = make([("out", 0x01, b"\xfe"), ("in", 0x81, status)])
    st = s.status()
    assert st["pixels"] == 2048 and st["integration_us"] == 10000 and st["usb_speed"] == 0x80
    t.assert_done()


def test_firmware_version_register():
    s, t = make([("out", 0x01, b"\x6b\x04"), ("in", 0x81, b"\x04\x50\x20")])
    assert s.firmware_version() == (2, 5, 0)
    t.assert_done()


def test_request_spectrum_reads_4097_bytes_with_sync():
    counts = (np.arange(2048) * 7 % 65536).astype(np.uint16)
    s, t = make([("out", 0x01, b"\x09"), *spectrum_packets(counts)])
    np.testing.assert_array_equal(s.raw_spectrum(), counts)
    t.assert_done()


def test_bad_sync_byte_is_retried():
    counts = np.full(2048, 1000, np.uint16)
    raw = counts.astype("<u2").tobytes()
    s, t = make(
        [
            ("out", 0x01, b"\x09"),
            ("in", 0x82, raw + b"\xe9"),
            ("in", 0x82, TransportTimeout("drained")),
            ("out", 0x01, b"\x09"),
            ("in", 0x82, raw + b"\x69"),
        ]
    )
    np.testing.assert_array_equal(s.intensities(), counts.astype(float))
    t.assert_done()


def test_timeouts_exhaust_retries_into_device_timeout():
    s, t = make([("out", 0x01, b"\x05\x00"), ("in", 0x81, TransportTimeout("t"))] * 3, retries=2)
    with pytest.raises(DeviceTimeout) as ei:
        s.serial_number()
    assert ei.value.device == "USB2000+" and "0x05" in ei.value.command
    t.assert_done()


def test_pipe_error_clears_halts_and_retries():
    s, t = make(
        [
            ("out", 0x01, b"\x05\x00"),
            ("in", 0x81, TransportStall("pipe")),
            ("out", 0x01, b"\x05\x00"),
            ("in", 0x81, slot(0, "X1")),
        ]
    )
    assert s.serial_number() == "X1"
    assert t.halts_cleared == [0x01, 0x81, 0x82]
    t.assert_done()


def test_disconnect_reconnects_restores_settings_and_retries():
    s, t = make(
        [
            ("out", 0x01, b"\x02\x20\xa1\x07\x00"),
            ("out", 0x01, b"\x05\x00"),
            ("in", 0x81, TransportDisconnected("gone")),
            ("out", 0x01, b"\x01"),
            ("out", 0x01, b"\x02\x20\xa1\x07\x00"),
            ("out", 0x01, b"\x05\x00"),
            ("in", 0x81, slot(0, "X2")),
        ]
    )
    s.integration_time = 0.5
    assert s.serial_number() == "X2"
    assert t.reconnects == 1
    t.assert_done()


def test_wrong_reply_raises_device_error_with_reply():
    bad = bytes([0x05, 0x03]) + bytes(15)
    s, t = make([("out", 0x01, b"\x05\x00"), ("in", 0x81, bad)] * 3)
    with pytest.raises(DeviceError) as ei:
        s.serial_number()
    assert ei.value.reply == bad
    t.assert_done()


def test_integration_time_range_checked():
    s, _ = make([])
    with pytest.raises(ValueError, match="integration_time"):
        s.integration_time = 1e-4
