"""The fake USB device model's non-blocking side: poll_in, transfer_fault, accept_out."""

from __future__ import annotations

import errno
import time

import pytest
import usb.core
from gonio.drivers.fake.ptp import FakePTPCamera
from gonio.drivers.fake.usb2000 import FakeUSB2000Plus
from gonio.simulator.bench import Bench


@pytest.fixture
def cam():
    return FakePTPCamera(Bench.for_instrument("lbl", time_scale=100.0, rng=1, simulate=False))


def test_poll_in_takes_ready_packets_and_tells_when_the_next_one_is_due(cam):
    assert cam.poll_in(0x81, 512) == (None, None)  # nothing queued
    data = bytes(range(200)) * 3  # 600 bytes: one full packet and a short one
    cam.queue_in(0x81, data)
    assert cam.poll_in(0x81, 4096) == (data[:512], None)
    assert cam.poll_in(0x81, 4096) == (data[512:], None)
    assert cam.poll_in(0x81, 4096) == (None, None)
    due = time.monotonic() + 5.0
    cam.queue_in(0x81, bytes(600), ready_at=due)
    pkt, at = cam.poll_in(0x81, 512)
    assert pkt is None and at == pytest.approx(due)  # not yet: when it will be


def test_poll_in_overflow_consumes_the_packet_and_unplug_cuts_it(cam):
    cam.queue_in(0x81, bytes(100))
    with pytest.raises(usb.core.USBError) as ei:
        cam.poll_in(0x81, 64)
    assert ei.value.errno == errno.EOVERFLOW
    assert cam.poll_in(0x81, 64) == (None, None)  # babble is gone, as on the bus
    cam.faults.disconnect_after_bytes = 700
    cam.queue_in(0x81, bytes(1024), zlp=False)
    assert cam.poll_in(0x81, 4096) == (bytes(512), None) and cam.present
    pkt, _ = cam.poll_in(0x81, 4096)
    assert pkt == bytes(188) and not cam.present  # 700 bytes in all, then unplugged
    with pytest.raises(usb.core.USBError) as ei:
        cam.poll_in(0x81, 4096)
    assert ei.value.errno == errno.ENODEV


def test_transfer_fault_order_and_halt_until_cleared():
    spec = FakeUSB2000Plus(Bench.for_instrument("lbl", rng=1, simulate=False))
    spec.faults.usb_timeouts, spec.faults.usb_pipe_errors = 1, 1
    assert spec.transfer_fault(0x01) == "timeout"
    assert spec.transfer_fault(0x01) == "pipe"
    assert spec.transfer_fault(0x01) == "pipe"  # halted until clear_halt
    assert spec.transfer_fault(0x81) is None  # other endpoints still work
    spec._halted.discard(0x01)
    assert spec.transfer_fault(0x01) is None
    assert spec.accept_out(0x01, b"\x05\x00") == 2  # query slot 0: the serial number
    assert spec.poll_in(0x81, 512)[0][:13] == b"\x05\x00USB2+F07001"
    spec.unplug()
    assert spec.transfer_fault(0x01) == "nodev"
