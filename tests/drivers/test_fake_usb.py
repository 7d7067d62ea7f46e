"""The fake USB bus as a pyusb backend: descriptors, seabreeze, drivers, faults."""

from __future__ import annotations

import errno
import time

import numpy as np
import pytest
import usb.backend
import usb.core
import usb.util
from gonio.drivers.errors import DeviceError, DeviceTimeout
from gonio.drivers.fake import usb as fakeusb
from gonio.drivers.ptp import PTPCamera
from gonio.drivers.usb2000 import USB2000Plus
from gonio.simulator.bench import Bench


@pytest.fixture
def bus():
    b = Bench.for_instrument("lbl", time_scale=100.0, rng=1, simulate=False)
    name = fakeusb.install(b)
    yield name, b, fakeusb.devices(name)
    fakeusb.uninstall(name)


def backend(name):
    return getattr(usb.backend, name).get_backend()


# -- enumeration and descriptors -------------------------------------------------------------
def test_find_lists_both_devices(bus):
    name, _, _ = bus
    devs = list(usb.core.find(find_all=True, backend=backend(name)))
    ids = sorted((d.idVendor, d.idProduct) for d in devs)
    assert ids == [(0x1209, 0x0001), (0x2457, 0x101E)]


def test_usb2000_descriptors_and_strings(bus):
    name, _, _ = bus
    d = usb.core.find(idVendor=0x2457, idProduct=0x101E, backend=backend(name))
    assert (d.manufacturer, d.product, d.serial_number) == (
        "Ocean Optics",
        "USB2000+",
        "USB2+F07001",
    )
    assert d.langids == (0x0409,)
    d.set_configuration()
    cfg = d.get_active_configuration()
    eps = {
        e.bEndpointAddress: (usb.util.endpoint_type(e.bmAttributes), e.wMaxPacketSize)
        for e in cfg[(0, 0)]
    }
    assert eps == {0x01: (2, 512), 0x81: (2, 512), 0x02: (2, 512), 0x82: (2, 512), 0x86: (2, 512)}
    raw = d.ctrl_transfer(0x80, 6, 0x0100, 0, 18)
    assert bytes(raw[:2]) == b"\x12\x01" and bytes(raw[8:12]) == b"\x57\x24\x1e\x10"
    raw = d.ctrl_transfer(0x80, 6, 0x0200, 0, 255)
    assert len(raw) == 9 + 9 + 5 * 7 and raw[2] == len(raw)


def test_ptp_interface_is_still_image_class(bus):
    name, _, _ = bus
    d = usb.core.find(idVendor=0x1209, backend=backend(name))
    d.set_configuration()
    intf = d.get_active_configuration()[(0, 0)]
    assert (intf.bInterfaceClass, intf.bInterfaceSubClass, intf.bInterfaceProtocol) == (6, 1, 1)
    types = {e.bEndpointAddress: usb.util.endpoint_type(e.bmAttributes) for e in intf}
    assert types == {0x81: 2, 0x02: 2, 0x83: 3}


def test_configured_once_enumerated_and_unconfigurable(bus):
    name, _, _ = bus
    d = usb.core.find(idVendor=0x2457, backend=backend(name))
    assert d.get_active_configuration().bConfigurationValue == 1
    assert d.write(0x01, b"\x01") == 1
    d.set_configuration(0)  # unconfigured: the endpoints are gone
    with pytest.raises(usb.core.USBError):
        d.write(0x01, b"\x01")
    d.set_configuration(1)
    d.reset()
    assert d.write(0x01, b"\x01") == 1


def test_transfer_of_whole_packets_ends_with_zero_length_packet(bus):
    name, _, fakes = bus
    cam = fakes["ptp"]
    d = usb.core.find(idVendor=0x1209, backend=backend(name))
    cam.queue_in(0x81, bytes(range(256)) * 4)  # 1024 bytes = 2 full packets, then a ZLP
    cam.queue_in(0x81, b"next")
    assert len(d.read(0x81, 4096, timeout=200)) == 1024  # the ZLP ends the transfer
    assert bytes(d.read(0x81, 4096, timeout=200)) == b"next"
    cam.queue_in(0x81, bytes(100))
    with pytest.raises(usb.core.USBError) as ei:  # a packet bigger than the buffer
        d.read(0x81, 64, timeout=200)
    assert ei.value.errno == errno.EOVERFLOW


def test_interrupt_read_without_event_times_out_after_callers_timeout(bus):
    name, _, _ = bus
    d = usb.core.find(idVendor=0x1209, backend=backend(name))
    d.set_configuration()
    t0 = time.monotonic()
    with pytest.raises(usb.core.USBTimeoutError) as ei:
        d.read(0x83, 64, timeout=150)
    elapsed = time.monotonic() - t0
    assert ei.value.errno == errno.ETIMEDOUT
    assert 0.14 <= elapsed < 1.0


def test_spectrum_arrives_as_full_packets_then_sync_packet(bus):
    name, _, _ = bus
    d = usb.core.find(idVendor=0x2457, backend=backend(name))
    d.set_configuration()
    d.write(0x01, b"\x09")
    first = d.read(0x82, 512, timeout=1000)
    assert len(first) == 512
    rest = d.read(0x82, 3584, timeout=1000)  # exactly the 7 remaining full packets
    assert len(rest) == 3584
    sync = d.read(0x82, 512, timeout=1000)  # the one-byte short packet
    assert bytes(sync) == b"\x69"
    d.write(0x01, b"\x09")
    whole = d.read(0x82, 8192, timeout=1000)  # a big read ends at the short sync packet
    assert len(whole) == 4097 and whole[-1] == 0x69


# -- seabreeze, unchanged ----------------------------------------------------------------------
def test_seabreeze_pyseabreeze_against_the_fake(bus):
    name, b, fakes = bus
    seabreeze = pytest.importorskip("seabreeze")
    seabreeze.use("pyseabreeze", pyusb_backend=name)
    from seabreeze.spectrometers import Spectrometer, list_devices

    assert [d.serial_number for d in list_devices()] == ["USB2+F07001"]
    spec = Spectrometer.from_first_available()
    try:
        assert spec.model == "USB2000PLUS" and spec.serial_number == "USB2+F07001"
        spec.integration_time_micros(20000)
        assert fakes["usb2000plus"].integration_us == 20000
        np.testing.assert_allclose(spec.wavelengths(), b.wavelengths(2048), rtol=1e-6)
        counts = spec.intensities()
        np.testing.assert_array_equal(counts, b.render_spectrum(0.02).astype(float))
        corrected = spec.intensities(correct_nonlinearity=True)
        assert corrected.shape == (2048,) and not np.array_equal(corrected, counts)
    finally:
        spec.close()


# -- our drivers over the backend --------------------------------------------------------------
def test_usb2000_driver_round_trip(bus):
    name, b, _ = bus
    s = USB2000Plus.open(name)
    assert s.serial_number() == "USB2+F07001"
    assert s.firmware_version() == (2, 5, 0)
    assert s.status()["usb_speed"] == 0x80
    s.integration_time = 0.05
    np.testing.assert_allclose(s.wavelengths(), b.wavelengths(2048), rtol=1e-6)
    np.testing.assert_array_equal(s.intensities(), b.render_spectrum(0.05).astype(float))
    s.close()


def test_ptp_driver_capture_round_trip(bus):
    name, b, _ = bus
    cam = PTPCamera.open(name)
    info = cam.device_info()
    assert 0x100E in info["operations"] and 0x400D in info["events"]
    cam.exposure = 0.02
    cam.f_number = 4.0
    img, meta = cam.capture(timeout=5)
    expect, _ = b.render_image(0.02, 4.0)
    np.testing.assert_array_equal(img, expect)
    assert meta["width"] == img.shape[1] and meta["bit_depth"] == 16
    assert cam.object_handles() == []  # deleted after download
    with pytest.raises(DeviceError) as ei:
        cam.f_number = 3.3  # not a stop the camera has
    assert "InvalidDevicePropValue" in str(ei.value)
    cam.close()


# -- faults ------------------------------------------------------------------------------------
def test_usb_timeout_is_retried(bus):
    name, _, fakes = bus
    s = USB2000Plus.open(name, timeout=0.1)
    fakes["usb2000plus"].faults.usb_timeouts = 1
    t0 = time.monotonic()
    assert s.serial_number() == "USB2+F07001"
    assert time.monotonic() - t0 >= 0.1  # the failed transfer took the caller's timeout
    fakes["usb2000plus"].faults.usb_timeouts = 5
    with pytest.raises(DeviceTimeout) as ei:
        s.serial_number()
    assert ei.value.device == "USB2000+" and "0x05" in ei.value.command
    fakes["usb2000plus"].faults.usb_timeouts = 0
    s.close()


def test_pipe_error_clears_halt_and_recovers(bus):
    name, _, fakes = bus
    s = USB2000Plus.open(name)
    fakes["usb2000plus"].faults.usb_pipe_errors = 1
    s.integration_time = 0.01
    assert fakes["usb2000plus"].integration_us == 10000
    cam = PTPCamera.open(name)
    fakes["ptp"].faults.usb_pipe_errors = 1
    assert cam.f_number == 8.0
    s.close()
    cam.close()


def test_dropped_spectrum_bytes_detected_and_retried(bus):
    name, b, fakes = bus
    s = USB2000Plus.open(name)
    fakes["usb2000plus"].faults.drop_reply_bytes = 1
    np.testing.assert_array_equal(s.raw_spectrum(), b.render_spectrum(0.01))
    assert any("dropped" in m for m in fakes["usb2000plus"].faults.log)
    s.close()


def test_spectrometer_unplugged_mid_spectrum_reconnects(bus):
    name, b, fakes = bus
    s = USB2000Plus.open(name)
    s.integration_time = 0.02
    old_address = fakes["usb2000plus"].address
    fakes["usb2000plus"].faults.disconnect_after_bytes = 1000
    np.testing.assert_array_equal(s.raw_spectrum(), b.render_spectrum(0.02))
    assert fakes["usb2000plus"].address != old_address  # re-enumerated
    assert fakes["usb2000plus"].integration_us == 20000  # driver restored its setting
    s.close()


def test_camera_unplugged_during_get_object_loses_no_image(bus):
    name, b, fakes = bus
    cam = PTPCamera.open(name)
    cam.exposure = 0.01
    # arm the unplug for the first GetObject only (2 KiB into the image)
    orig = fakes["ptp"].on_out
    armed = [True]

    def arm(ep, data, _orig=orig):
        if armed[0] and len(data) >= 8 and data[6:8] == b"\x09\x10":  # GetObject
            armed[0] = False
            fakes["ptp"].faults.disconnect_after_bytes = 2048
        _orig(ep, data)

    fakes["ptp"].on_out = arm
    img, _ = cam.capture(timeout=5)
    expect, _ = b.render_image(0.01, 8.0)
    np.testing.assert_array_equal(img, expect)
    assert any("disconnect" in m for m in fakes["ptp"].faults.log)
    cam.close()


def test_device_gone_for_good_raises_device_disconnected(bus):
    name, _, fakes = bus
    s = USB2000Plus.open(name)
    s.transport.reconnect_timeout = 0.1
    fakes["usb2000plus"].faults.reconnect_after = 60.0
    fakes["usb2000plus"].unplug()
    with pytest.raises(DeviceError) as ei:
        s.serial_number()
    assert ei.value.device == "USB2000+" and "no USB device" in str(ei.value)


def test_fake_camera_shows_the_lbl_simulator_capture():
    """With the LBL simulator wired in, the PTP camera returns its capture for the stages."""
    pytest.importorskip("gonio.simulator.lbl")
    b = Bench.for_instrument("lbl", "standard", time_scale=1000.0, noise=False)
    name = fakeusb.install(b)
    try:
        src = b.stage("source")
        src.motor_on = True
        src.move_to(30.0, b.now() - 100.0)  # long finished
        cam = PTPCamera.open(name)
        cam.exposure, cam.f_number = 0.01, 4.0
        img, meta = cam.capture(timeout=30)
        expect, truth = b.render_image(0.01, 4.0)
        np.testing.assert_array_equal(img, expect)
        assert truth["instrument"] == "lbl" and truth["theta_i"] == pytest.approx(np.radians(30))
        assert img.shape == (480, 640) and meta["width"] == 640
        cam.close()
    finally:
        fakeusb.uninstall(name)


def test_delayed_reply_beyond_timeout_then_stale_reply_rejected(bus):
    name, b, fakes = bus
    s = USB2000Plus.open(name, timeout=0.1)
    fakes["usb2000plus"].faults.reply_delay = 0.15
    fakes["usb2000plus"].faults.delayed_replies = 1
    assert s.serial_number() == "USB2+F07001"
    # the second (undelayed) slot-0 reply is still queued: the next query must not take it
    np.testing.assert_allclose(s.wavelengths(), b.wavelengths(2048), rtol=1e-6)
    s.close()


def test_ptp_corrupted_container_and_timeouts_recovered(bus):
    name, _, fakes = bus
    cam = PTPCamera.open(name, timeout=0.2)
    fakes["ptp"].faults.corrupt_reply_bytes = 1  # the length field of the next container
    assert cam.exposure == pytest.approx(0.01)
    assert any("corrupted" in m for m in fakes["ptp"].faults.log)
    fakes["ptp"].faults.usb_timeouts = 1
    assert cam.f_number == 8.0
    fakes["ptp"].faults.usb_timeouts = 10
    with pytest.raises(DeviceTimeout) as ei:
        cam.object_handles()
    assert ei.value.device == "PTP camera" and ei.value.command == "GetObjectHandles"
    fakes["ptp"].faults.usb_timeouts = 0
    assert cam.object_handles() == []
    cam.close()


def test_fake_spectrometer_shows_the_cornell_simulator_spectrum():
    """With the Cornell simulator wired in, the USB2000+ returns its counts for the stages."""
    pytest.importorskip("gonio.simulator.cornell")
    b = Bench.for_instrument("cornell", time_scale=1000.0, noise=False)
    name = fakeusb.install(b)
    try:
        s = USB2000Plus.open(name, n_pixels=None)
        assert s.n_pixels == b.n_pixels == 1024  # learnt from the status query
        np.testing.assert_allclose(s.wavelengths(), b.wavelengths(), rtol=1e-6)
        s.integration_time = 0.1
        at_zero = s.raw_spectrum()
        np.testing.assert_array_equal(at_zero, b.render_spectrum(0.1))
        arm = b.stage("arm")
        arm.motor_on = True
        arm.move_to(40.0, b.now() - 100.0)
        at_40 = s.raw_spectrum()
        np.testing.assert_array_equal(at_40, b.render_spectrum(0.1))
        assert at_40.astype(float).sum() != at_zero.astype(float).sum()
        s.close()
    finally:
        fakeusb.uninstall(name)


# -- the JSON server's bounded resources (issue 15 items 5 and 8) -----------------------------
def _raw_call(f, op, *args):
    import json

    f.write(json.dumps({"op": op, "args": list(args)}).encode() + b"\n")
    f.flush()
    return json.loads(f.readline())


def test_remote_server_refuses_huge_reads_before_allocating(bus):
    import socket

    name, _, _ = bus
    srv = fakeusb.serve_remote(name)
    try:
        host, port = srv.address.split(":")
        with socket.create_connection((host, int(port))) as s:
            f = s.makefile("rwb")
            key = _raw_call(f, "enumerate_devices")["ok"][0]
            _raw_call(f, "open_device", key)
            r = _raw_call(f, "bulk_read", key, 0x81, 0, 2**40, 100)
            assert r["error"]["msg"].startswith("ValueError: bulk_read length 1099511627776")
            assert str(fakeusb.MAX_TRANSFER) in r["error"]["msg"]
            assert _raw_call(f, "get_device_descriptor", key)["ok"]["idVendor"] > 0
    finally:
        srv.close()


def _wait_until(condition, timeout: float = 10.0) -> None:
    """Poll ``condition`` every 10 ms until it holds or ``timeout`` seconds pass."""
    deadline = time.monotonic() + timeout
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.01)


def test_remote_server_bounds_its_client_threads(bus):
    import json
    import socket
    import threading

    name, _, _ = bus
    srv = fakeusb.serve_remote(name)
    host, port = srv.address.split(":")

    def clients() -> int:  # this server's client threads (others' threads come and go)
        return sum(t.name == f"fake-usb-client {srv.address}" for t in threading.enumerate())

    socks = [socket.create_connection((host, int(port))) for _ in range(fakeusb.MAX_CLIENTS)]
    try:
        # the server starts one thread per accepted client: wait for them (a fixed 0.2 s
        # sleep saw 15 of 16 on a loaded machine), then check it never starts more
        _wait_until(lambda: clients() >= fakeusb.MAX_CLIENTS)
        assert clients() == fakeusb.MAX_CLIENTS
        extra = [socket.create_connection((host, int(port))) for _ in range(10)]
        for s in extra:
            s.settimeout(2.0)
            reply = json.loads(s.makefile("rb").readline())
            assert reply["error"]["msg"].startswith("busy:")
            s.close()
        assert clients() == fakeusb.MAX_CLIENTS and srv.refused == 10
    finally:
        for s in socks:
            s.close()
        srv.close()
    _wait_until(lambda: clients() == 0)
    assert clients() == 0


# -- issue 30, 6: bounded queues and object store -----------------------------------------------
def test_replies_never_read_fill_no_more_than_the_queue_bound(bus, monkeypatch):
    from gonio.drivers.fake import usbdev

    monkeypatch.setattr(usbdev, "MAX_QUEUED_PACKETS", 8)
    name, _, fakes = bus
    d = usb.core.find(idVendor=0x2457, idProduct=0x101E, backend=backend(name))
    d.set_configuration()
    with pytest.raises(usb.core.USBTimeoutError):
        for _ in range(100):  # "query information" commands; their replies never read
            d.write(0x01, b"\x05\x00", timeout=100)
    assert max(len(q) for q in fakes["usb2000plus"]._in.values()) <= 8 + 2
    while True:  # the host reads the replies: the device takes commands again
        try:
            d.read(0x81, 512, timeout=50)
        except usb.core.USBTimeoutError:
            break
    assert d.write(0x01, b"\x05\x00", timeout=100) == 2


def test_the_cameras_store_is_bounded(bus, monkeypatch):
    from gonio.drivers.fake import ptp

    monkeypatch.setattr(ptp, "MAX_OBJECTS", 2)
    name, _, fakes = bus
    cam = PTPCamera.open(name)
    cam.exposure = 0.001
    for _ in range(2):
        cam.capture(timeout=5, delete=False)
    assert len(fakes["ptp"].objects) == 2
    with pytest.raises(DeviceError):
        cam.capture(timeout=5, delete=False)
    assert len(fakes["ptp"].objects) == 2
    cam.close()
