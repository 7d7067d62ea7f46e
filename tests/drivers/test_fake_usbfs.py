"""The fake USB devices on an emulated usbdevfs bus, driven by real libusb-1.0 programs.

Every test starts real programs (lsusb, gphoto2, Python children on pyusb's C ``libusb1``
backend, python-seabreeze, a ctypes client on libusb-1.0) under umockdev's preload library;
their ioctls are answered in this process by the same fakes the pyusb backend uses.
"""

from __future__ import annotations

import ctypes.util
import json
import re
import shutil
import subprocess
import sys
import textwrap
import threading
import time

import numpy as np
import pytest
import usb.backend

pytest.importorskip("gi")
from gonio.drivers.fake import usb as fakeusb
from gonio.drivers.fake import usbdevfs, usbfs
from gonio.simulator.bench import Bench

try:
    usbfs.require()
except usbfs.UsbfsUnavailable as exc:  # pragma: no cover - depends on the system packages
    pytest.skip(str(exc), allow_module_level=True)
for lib in ("umockdev-preload", "usb-1.0"):
    if ctypes.util.find_library(lib) is None:  # pragma: no cover - system packages
        pytest.skip(f"lib{lib} is not installed", allow_module_level=True)


def _bench() -> Bench:
    return Bench.for_instrument("lbl", time_scale=100.0, rng=1, simulate=False)


@pytest.fixture
def rig():
    """(bus, fakes, bench, in-process twin backend name on an identical bench)."""
    bench = _bench()
    name = fakeusb.install(bench)
    twin = fakeusb.install(_bench())
    fakes = fakeusb.devices(name)
    bus = usbfs.UsbfsBus(fakes)
    yield bus, fakes, bench, twin
    bus.close()
    fakeusb.uninstall(name)
    fakeusb.uninstall(twin)


def _child(bus, tmp_path, code: str, timeout: float = 60.0, header: bool = True):
    """Run Python ``code`` (after :data:`HEADER`) on the bus; the JSON object it prints last."""
    r = bus.run(
        [sys.executable, "-P", "-c", (HEADER if header else "") + textwrap.dedent(code)],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=tmp_path,  # not the repository root: its gonio/ folder would shadow the package
    )
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


HEADER = """
import json, errno, time
import usb.core, usb.util
import usb.backend.libusb1 as libusb1
be = libusb1.get_backend()
"""

USB2000_SESSION = """
from gonio.drivers.usb2000 import USB2000Plus
s = USB2000Plus.open(backend=be)
s.integration_time = 0.02
out = {
    "serial": s.serial_number(),
    "wavelengths": s.wavelengths()[:4].tolist(),
    "nonlinearity": s.nonlinearity_coefficients(),
    "status": s.status(),
    "firmware": list(s.firmware_version()),
    "spectra": [s.raw_spectrum().tolist() for _ in range(3)],
}
s.close()
"""


# -- what a libusb program sees --------------------------------------------------------------
@pytest.mark.skipif(shutil.which("lsusb") is None, reason="lsusb (usbutils) is not installed")
def test_lsusb_lists_both_fakes_with_descriptors_and_strings(rig):
    bus, fakes, _, _ = rig
    out = bus.run(["lsusb"], capture_output=True, text=True, timeout=30).stdout
    assert re.search(r"Bus 001 Device \d{3}: ID 2457:101e Ocean Optics USB2000\+", out), out
    assert re.search(r"Bus 001 Device \d{3}: ID 1209:0001 gonio gonio simulated PTP camera", out)
    devnums = {m[1]: int(m[0]) for m in re.findall(r"Device (\d{3}): ID (\w{4})", out)}
    verbose = bus.run(["lsusb", "-v", "-d", "2457:101e"], capture_output=True, text=True).stdout
    assert "iSerial                 3 USB2+F07001" in verbose
    eps = re.findall(r"bEndpointAddress\s+(0x[0-9a-f]{2})", verbose)
    assert eps == ["0x01", "0x81", "0x02", "0x82", "0x86"]
    assert verbose.count("wMaxPacketSize     0x0200") == 5
    assert bus.stats["SUBMITURB"] > 0  # string descriptors were read through control URBs
    assert bus.devnode(fakes["usb2000plus"]) == f"/dev/bus/usb/001/{devnums['2457']:03d}"


def test_pyusb_libusb1_drives_usb2000_exactly_like_the_in_process_backend(rig, tmp_path):
    bus, _, _, twin = rig
    got = _child(bus, tmp_path, USB2000_SESSION + "print(json.dumps(out))")
    ns: dict = {"be": getattr(usb.backend, twin).get_backend()}
    exec(USB2000_SESSION, ns)  # the same session on the in-process pyusb backend
    want = json.loads(json.dumps(ns["out"]))
    assert got == want
    assert got["serial"] == "USB2+F07001" and len(got["spectra"][0]) == 2048
    assert bus.stats["urbs reaped"] == bus.stats["urbs completed"] > 10


PTP_SESSION = """
from gonio.drivers.ptp import PTPCamera
import hashlib
cam = PTPCamera.open(backend=be)
info = cam.device_info()
cam.open_session()
cam.exposure = 0.02
cam.f_number = 5.6
img, meta = cam.capture(timeout=20)
out = {
    "model": info["model"], "serial": info["serial_number"], "ops": info["operations"],
    "exposure": cam.exposure, "f_number": cam.f_number,
    "shape": list(img.shape), "sha": hashlib.sha256(img.tobytes()).hexdigest(),
    "size": meta["size"], "handles_left": cam.object_handles(),
}
cam.close_session()
cam.close()
"""


def test_pyusb_libusb1_drives_ptp_camera_exactly_like_the_in_process_backend(rig, tmp_path):
    bus, _, _, twin = rig
    got = _child(bus, tmp_path, PTP_SESSION + "print(json.dumps(out))")
    ns: dict = {"be": getattr(usb.backend, twin).get_backend()}
    exec(PTP_SESSION, ns)  # the same session on the in-process pyusb backend
    assert got == json.loads(json.dumps(ns["out"]))
    assert got["model"] == "gonio simulated PTP camera" and got["handles_left"] == []
    assert bus.stats["packets in"] > got["size"] // 512  # the TIFF came through bulk IN


@pytest.mark.skipif(shutil.which("gphoto2") is None, reason="gphoto2 is not installed")
def test_gphoto2_detects_summarises_sets_f_number_and_captures_the_rendered_image(rig, tmp_path):
    import cv2

    bus, fakes, _, twin = rig
    cam = fakes["ptp"]
    run = {"capture_output": True, "text": True, "timeout": 60, "cwd": tmp_path}
    detect = bus.run(["gphoto2", "--auto-detect"], **run)
    assert re.search(rf"USB PTP Class Camera\s+usb:001,{bus.address(cam):03d}", detect.stdout)
    summary = bus.run(["gphoto2", "--summary"], **run)
    assert summary.returncode == 0, summary.stderr
    assert "Model: gonio simulated PTP camera" in summary.stdout
    assert "Serial Number: GONIO-CAM-0001" in summary.stdout
    assert "Enumeration [280,400,560,800,1100,1600,2200] value: f/8 (800)" in summary.stdout
    setf = bus.run(["gphoto2", "--set-config", "f-number=5.6"], **run)  # SetDevicePropValue
    assert setf.returncode == 0 and cam.f_number == 560, setf.stderr[-2000:]
    shot = bus.run(["gphoto2", "--capture-image-and-download", "--filename", "shot.tif"], **run)
    assert shot.returncode == 0, shot.stderr[-2000:]
    img = cv2.imread(str(tmp_path / "shot.tif"), cv2.IMREAD_UNCHANGED)
    # the twin bench renders the same frame for the same state: exposure 0.01 s, f/5.6
    twin_bench = fakeusb.devices(twin)["ptp"].bench
    want, _ = twin_bench.render_image(cam.exposure * 1e-4, 5.6)
    assert img.dtype == np.uint16 and np.array_equal(img, want)
    assert not np.array_equal(img, twin_bench.render_image(cam.exposure * 1e-4, 8.0)[0])
    assert cam.objects == {}  # gphoto2 deleted it after the download


def test_seabreeze_pyseabreeze_on_libusb1_reads_the_spectrum(rig, tmp_path):
    pytest.importorskip("seabreeze")
    bus, _, bench, _ = rig
    got = _child(
        bus,
        tmp_path,
        """
        import json, seabreeze
        seabreeze.use("pyseabreeze")  # pyusb's default backend: libusb1
        from seabreeze.spectrometers import Spectrometer
        s = Spectrometer.from_first_available()
        s.integration_time_micros(20000)
        print(json.dumps({"model": s.model, "serial": s.serial_number,
                          "wl": s.wavelengths().tolist(), "counts": s.intensities().tolist()}))
        s.close()
        """,
    )
    assert (got["model"], got["serial"]) == ("USB2000PLUS", "USB2+F07001")
    np.testing.assert_allclose(got["wl"], bench.wavelengths(2048), rtol=1e-6)
    np.testing.assert_array_equal(got["counts"], bench.render_spectrum(0.02).astype(float))


# -- faults, as a libusb program sees them ---------------------------------------------------
def test_stall_is_epipe_until_clear_halt_and_timeout_is_the_clients_own(rig, tmp_path):
    bus, fakes, _, _ = rig
    fakes["usb2000plus"].faults.usb_timeouts = 1  # the next transfer: the device NAKs
    fakes["usb2000plus"].faults.usb_pipe_errors = 1  # the one after: a stall
    got = _child(
        bus,
        tmp_path,
        """
        d = usb.core.find(idVendor=0x2457, backend=be)
        d.set_configuration()
        out = {}
        t0 = time.monotonic()
        try:
            d.write(0x01, b"\\xfe", timeout=300)
        except usb.core.USBTimeoutError as e:
            out["timeout"] = [e.errno, time.monotonic() - t0]
        for _ in range(2):
            try:
                d.write(0x01, b"\\xfe", timeout=500)  # stalled, then still halted
            except usb.core.USBError as e:
                out.setdefault("stall", []).append(e.errno)
        d.clear_halt(0x01)
        d.set_interface_altsetting(0, 0)
        d.reset()  # USBDEVFS_RESET; libusb claims the interface again afterwards
        d.write(0x01, b"\\xfe", timeout=500)
        out["status_len"] = len(d.read(0x81, 512, timeout=500))  # a short packet ends it
        try:
            d.read(0x81, 64, timeout=200)  # nothing queued: the client's own timeout
        except usb.core.USBTimeoutError as e:
            out["read_timeout"] = e.errno
        d.write(0x01, b"\\xfe", timeout=500)
        try:
            d.read(0x81, 8, timeout=500)  # 16 bytes into 8
        except usb.core.USBError as e:
            out["overflow"] = e.errno
        print(json.dumps(out))
        """,
    )
    assert got["timeout"][0] == errno_("ETIMEDOUT") and 0.29 <= got["timeout"][1] < 2
    assert got["stall"] == [errno_("EPIPE")] * 2
    assert got["status_len"] == 16
    assert got["read_timeout"] == errno_("ETIMEDOUT")
    assert got["overflow"] == errno_("EOVERFLOW")
    assert bus.stats["urbs discarded"] == 2  # the two timed-out URBs, discarded by libusb
    assert fakes["usb2000plus"].faults.log == ["usb_timeouts", "usb_pipe_errors"]
    assert bus.stats["RESET"] == 1 and bus.stats["SETINTERFACE"] == 1


def errno_(name: str) -> int:
    import errno

    return getattr(errno, name)


def test_discarded_urb_returns_the_packets_it_already_took(rig, tmp_path):
    """A C-level client (ctypes on libusb-1.0): libusb_bulk_transfer's ``transferred``."""
    bus, fakes, _, _ = rig
    cam = fakes["ptp"]
    cam.queue_in(0x81, bytes(range(256)) * 4, zlp=False)  # 2 full packets, no end yet
    got = _child(
        bus,
        tmp_path,
        """
        import ctypes, ctypes.util, json
        lib = ctypes.CDLL(ctypes.util.find_library("usb-1.0"))
        lib.libusb_open_device_with_vid_pid.restype = ctypes.c_void_p
        lib.libusb_init(None)
        h = ctypes.c_void_p(lib.libusb_open_device_with_vid_pid(None, 0x1209, 0x0001))
        assert lib.libusb_claim_interface(h, 0) == 0
        buf = (ctypes.c_ubyte * 4096)()
        n = ctypes.c_int(0)
        rc = lib.libusb_bulk_transfer(h, 0x81, buf, 4096, ctypes.byref(n), 300)
        rc2 = lib.libusb_bulk_transfer(h, 0x81, buf, 4096, ctypes.byref(ctypes.c_int()), 100)
        print(json.dumps({"rc": rc, "n": n.value, "data": bytes(buf[: n.value]).hex(),
                          "rc2": rc2}))
        lib.libusb_release_interface(h, 0)
        lib.libusb_close(h)
        """,
    )
    assert got["rc"] == -7 and got["n"] == 1024  # LIBUSB_ERROR_TIMEOUT, with the bytes
    assert bytes.fromhex(got["data"]) == bytes(range(256)) * 4
    assert got["rc2"] == -7  # nothing was put back or left behind
    assert cam.poll_in(0x81, 512) == (None, None)


def test_disconnect_mid_transfer_is_enodev_and_replug_is_found_at_a_new_address(rig, tmp_path):
    bus, fakes, _, _ = rig
    spec = fakes["usb2000plus"]
    old = bus.address(spec)
    spec.faults.disconnect_after_bytes = 1000  # two packets and a bit of the spectrum
    spec.faults.reconnect_after = 0.2
    got = _child(
        bus,
        tmp_path,
        """
        d = usb.core.find(idVendor=0x2457, backend=be)
        d.set_configuration()
        d.write(0x01, b"\\x09")
        out = {}
        try:
            d.read(0x82, 4097, timeout=2000)
        except usb.core.USBError as e:
            out["read"] = e.errno
        try:
            d.write(0x01, b"\\x09", timeout=500)
        except usb.core.USBError as e:
            out["write"] = e.errno
        print(json.dumps(out))
        """,
    )
    assert got == {"read": errno_("ENODEV"), "write": errno_("ENODEV")}
    deadline = time.monotonic() + 5  # the bus follows the plug state every plug_poll s
    while bus.address(spec) in (None, old) and time.monotonic() < deadline:
        time.sleep(0.01)
    new = bus.address(spec)
    assert new not in (None, old) and bus.devnode(spec) == f"/dev/bus/usb/001/{new:03d}"
    assert (bus.stats["unplugged"], bus.stats["plugged"]) == (1, 3)
    again = _child(
        bus,
        tmp_path,
        """
        from gonio.drivers.usb2000 import USB2000Plus
        s = USB2000Plus.open(backend=be)
        print(json.dumps({"address": usb.core.find(idVendor=0x2457, backend=be).address,
                          "n": len(s.raw_spectrum())}))
        """,
    )
    assert again == {"address": new, "n": 2048}


def test_waiting_client_costs_a_bounded_number_of_ioctls(rig, tmp_path):
    """The node always polls ready: a client waiting 1 s on the camera's interrupt endpoint
    makes at most about 1 / reap_hold empty reaps, not a busy loop."""
    bus, _, _, _ = rig
    got = _child(
        bus,
        tmp_path,
        """
        import resource
        d = usb.core.find(idVendor=0x1209, backend=be)
        d.set_configuration()
        r0 = resource.getrusage(resource.RUSAGE_SELF)
        t0 = time.monotonic()
        try:
            d.read(0x83, 64, timeout=1000)
        except usb.core.USBTimeoutError:
            pass
        r1 = resource.getrusage(resource.RUSAGE_SELF)
        cpu = r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime
        print(json.dumps({"wall": time.monotonic() - t0, "cpu": cpu}))
        """,
    )
    assert 0.99 <= got["wall"] < 2.0
    reaps = bus.stats["REAPURBNDELAY"]
    assert 10 <= reaps <= 1.0 / bus.reap_hold * 1.5, reaps
    assert got["cpu"] < 0.5 * got["wall"], got


def _waiter(bus, tmp_path) -> subprocess.Popen:
    """A program on the bus that claims the interface, prints "waiting" and waits 20 s for
    an event."""
    return subprocess.Popen(
        [sys.executable, "-P", "-c", HEADER + WAIT_FOR_EVENT.format(timeout=20000)],
        env=bus.env(),
        stdout=subprocess.PIPE,
        text=True,
        cwd=tmp_path,
    )


def test_a_program_killed_while_waiting_leaves_no_claim_behind(rig, tmp_path):
    """Ctrl-C on a program blocked in a reap: its interface claim must not outlive it."""
    bus = rig[0]
    waiter = _waiter(bus, tmp_path)
    try:
        assert waiter.stdout.readline().strip() == "waiting"
        time.sleep(0.1)
    finally:
        waiter.kill()
        waiter.wait()
    got = _child(bus, tmp_path, WAIT_FOR_EVENT.format(timeout=200) + "print(json.dumps(out))")
    assert got == {"timeout": errno_("ETIMEDOUT")}  # it claimed the interface: no EBUSY
    assert bus.stats["files forgotten"] >= 1


def test_a_program_killed_before_its_answer_leaves_no_claim_behind(rig, tmp_path, monkeypatch):
    """A program dies between an ioctl and its answer (a kill at the wrong moment, as seen
    about once in 20 runs of the test above): umockdev never marks that client disconnected, so
    only the look at its socket frees the claim. The kill is put into that moment here."""
    bus = rig[0]
    fs = bus.usbdevfs
    waiter = _waiter(bus, tmp_path)
    armed, killed = threading.Event(), threading.Event()
    real_reap = fs._reap

    def kill_then_reap(fd, client, block):
        if armed.is_set() and not killed.is_set():
            waiter.kill()
            waiter.wait()
            killed.set()
            fd.drained = False  # so this reap is answered at once, into the dead socket
        real_reap(fd, client, block)

    monkeypatch.setattr(fs, "_reap", kill_then_reap)
    try:
        assert waiter.stdout.readline().strip() == "waiting"
        armed.set()
        assert killed.wait(10)
    finally:
        if waiter.poll() is None:
            waiter.kill()
            waiter.wait()
    got = _child(bus, tmp_path, WAIT_FOR_EVENT.format(timeout=200) + "print(json.dumps(out))")
    assert got == {"timeout": errno_("ETIMEDOUT")}  # it claimed the interface: no EBUSY
    assert bus.stats["files forgotten"] >= 1


def test_a_file_opened_as_its_device_goes_away_is_answered_enodev(rig, tmp_path):
    """A program opens the node in the moment its device is unplugged. The kernel's open
    file stays valid and its ioctls fail ENODEV; the node's listener must not be closed
    under a connection umockdev has not yet accepted (the program died with "Error
    communicating with ioctl socket, errno: 104", CI's failure). Holding the bus's lock
    stops umockdev's worker at the first open's client-connected, so the second open waits
    in the listener's backlog while the device goes (as the bus's watch removes it)."""
    bus, fakes, _, _ = rig
    spec = fakes["usb2000plus"]
    code = f"""
        import ctypes, errno, json, os, sys
        libc = ctypes.CDLL(None, use_errno=True)  # the preloaded ioctl() comes first
        libc.ioctl.argtypes = [ctypes.c_int, ctypes.c_ulong, ctypes.c_void_p]
        CAPS = (2 << 30) | (4 << 16) | (ord("U") << 8) | 26
        files = [os.open({bus.devnode(spec)!r}, os.O_RDWR) for _ in range(2)]
        print("opened", flush=True)
        sys.stdin.readline()
        out = []
        for fd in files:
            caps = ctypes.c_uint(0)
            r = libc.ioctl(fd, CAPS, ctypes.byref(caps))
            out.append(errno.errorcode[ctypes.get_errno()] if r < 0 else r)
        print(json.dumps(out), flush=True)
        """
    prog = subprocess.Popen(
        [sys.executable, "-P", "-c", textwrap.dedent(code)],
        env=bus.env(), stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True, cwd=tmp_path,
    )  # fmt: skip
    try:
        with bus._lock:
            assert prog.stdout.readline().strip() == "opened"
            spec.unplug()
            bus._unplug_node(bus.fakes.index(spec))  # what the watch does, now
        out, err = prog.communicate("\n", timeout=30)
    finally:
        if prog.poll() is None:
            prog.kill()
            prog.wait()
    assert prog.returncode == 0, err[-3000:]
    assert json.loads(out.strip().splitlines()[-1]) == ["ENODEV", "ENODEV"]
    assert bus.devnode(spec) is None


def test_an_address_handed_out_again_gets_a_new_listener(rig, tmp_path):
    """A removed node's listener is kept (above) until its address comes round again: 130
    replugs (the kernel's round robin over 2..127) reuse every address, and the device
    answers at the last one."""
    bus, fakes, _, _ = rig
    spec = fakes["usb2000plus"]
    k = bus.fakes.index(spec)
    seen = set()
    with bus._lock:
        for _ in range(130):
            bus._unplug_node(k)
            bus._plug(k)
            seen.add(bus.address(spec))
    assert len(seen) == 125  # 2..127 less the camera's address
    assert len(bus._gone) == 124  # every other address a removed node's, none twice
    got = _child(
        bus,
        tmp_path,
        """
        d = usb.core.find(idVendor=0x2457, backend=be)
        print(json.dumps([d.address, usb.util.get_string(d, d.iSerialNumber)]))
        """,
    )
    assert got == [bus.address(spec), "USB2+F07001"]


WAIT_FOR_EVENT = """
d = usb.core.find(idVendor=0x1209, backend=be)
d.set_configuration()
print("waiting", flush=True)
out = {{}}
try:
    d.read(0x83, 64, timeout={timeout})
except usb.core.USBTimeoutError as e:
    out["timeout"] = e.errno
"""


# -- the command line ------------------------------------------------------------------------
def test_devices_serve_libusb_runs_a_program_that_sees_unplug_and_replug(tmp_path):
    """``gonio devices serve --libusb -- PROGRAM``: the bridge re-executes itself under the
    preload library, so the running program's libusb gets the remove / add uevents and the
    driver's own reconnect finds the replugged device at its new address."""
    child = HEADER + textwrap.dedent(
        """
        from gonio.drivers.usb2000 import USB2000Plus
        s = USB2000Plus.open(backend=be)
        first = usb.core.find(idVendor=0x2457, backend=be).address
        n = len(s.raw_spectrum())          # disconnected mid-spectrum: the driver reconnects
        second = usb.core.find(idVendor=0x2457, backend=be).address
        print(json.dumps({"first": first, "second": second, "n": n}))
        """
    )
    r = subprocess.run(
        [sys.executable, "-P", "-c", "import sys; from gonio.cli import main; sys.exit(main())",
         "devices", "serve", "--libusb", "--time-scale", "100", "--json",
         "--fault", "usb2000plus.disconnect_after_bytes=1000",
         "--fault", "usb2000plus.reconnect_after=0.2",
         "--", sys.executable, "-P", "-c", child],
        capture_output=True, text=True, timeout=120, cwd=tmp_path,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    got = json.loads(r.stdout.strip().splitlines()[-1])
    assert got["n"] == 2048 and got["second"] != got["first"]
    recs = [json.loads(line) for line in r.stderr.splitlines() if line.startswith("{")]
    lib = next(rec for rec in recs if rec["device"] == "libusb")
    assert lib["hotplug"] is True and lib["nodes"]["usb2000plus"].startswith("/dev/bus/usb/001/")


def test_devices_serve_rejects_a_program_without_libusb_and_bad_faults(tmp_path):
    from gonio.cli import main

    assert main(["devices", "serve", "--", "true"]) == 2
    assert main(["devices", "serve", "--fault", "usb2000plus.nonsense=1"]) == 2
    assert main(["devices", "serve", "--fault", "ptp.usb_timeouts=-3"]) == 2


def test_raw_usbdevfs_ioctls_statuses_and_blocking_reap(rig, tmp_path):
    """A client without libusb: the usbdevfs ioctls by hand (libc ioctl, ctypes structs)."""
    bus, fakes, _, _ = rig
    cam = fakes["ptp"]
    cam.queue_in(0x81, bytes(range(200)) * 3)  # 600 bytes: ends in a short packet
    got = _child(
        bus,
        tmp_path,
        f"""
        import ctypes, errno, json, os
        libc = ctypes.CDLL(None, use_errno=True)  # the preloaded ioctl() comes first
        libc.ioctl.argtypes = [ctypes.c_int, ctypes.c_ulong, ctypes.c_void_p]
        def ioctl(fd, req, arg):
            if libc.ioctl(fd, req, arg) < 0:
                raise OSError(ctypes.get_errno(), "ioctl")
        class Urb(ctypes.Structure):
            _fields_ = [("type", ctypes.c_ubyte), ("endpoint", ctypes.c_ubyte),
                        ("status", ctypes.c_int), ("flags", ctypes.c_uint),
                        ("buffer", ctypes.c_void_p), ("buffer_length", ctypes.c_int),
                        ("actual_length", ctypes.c_int), ("start_frame", ctypes.c_int),
                        ("number_of_packets", ctypes.c_int), ("error_count", ctypes.c_int),
                        ("signr", ctypes.c_uint), ("usercontext", ctypes.c_void_p)]
        def ioc(d, nr, size):
            return (d << 30) | (size << 16) | (ord("U") << 8) | nr
        SUBMIT, DISCARD = ioc(2, 10, ctypes.sizeof(Urb)), ioc(0, 11, 0)
        REAP, REAPNDELAY, CLAIM, CAPS = ioc(1, 12, 8), ioc(1, 13, 8), ioc(2, 15, 4), ioc(2, 26, 4)
        fd = os.open({bus.devnode(cam)!r}, os.O_RDWR)
        out = {{"sizeof_urb": ctypes.sizeof(Urb)}}
        caps = ctypes.c_uint(0)
        ioctl(fd, CAPS, ctypes.byref(caps))
        out["caps"] = caps.value
        ioctl(fd, CLAIM, ctypes.byref(ctypes.c_uint(0)))
        buf = (ctypes.c_ubyte * 4096)()
        def submit(flags=0):
            u = Urb(type=3, endpoint=0x81, flags=flags, buffer=ctypes.addressof(buf),
                    buffer_length=4096)
            ioctl(fd, SUBMIT, ctypes.byref(u))
            return u
        def reap(req):
            p = ctypes.c_void_p(0)
            try:
                ioctl(fd, req, ctypes.byref(p))
            except OSError as e:
                return errno.errorcode[e.errno]
            return p.value
        u = submit(flags=1)  # USBDEVFS_URB_SHORT_NOT_OK
        out["reaped_is_urb"] = reap(REAP) == ctypes.addressof(u)  # blocking reap
        out["short"] = [u.status, u.actual_length, bytes(buf[: u.actual_length]).hex()]
        out["empty"] = [reap(REAPNDELAY), reap(REAPNDELAY)]
        v = submit()
        ioctl(fd, DISCARD, ctypes.addressof(v))
        out["discarded_is_urb"] = reap(REAP) == ctypes.addressof(v)
        out["discarded"] = [v.status, v.actual_length]
        try:
            ioctl(fd, DISCARD, ctypes.addressof(v))
        except OSError as e:
            out["discard_again"] = errno.errorcode[e.errno]
        try:
            ioctl(fd, ioc(0, 99, 0), None)
        except OSError as e:
            out["unknown"] = errno.errorcode[e.errno]
        submit()  # left pending: the program exits without discarding it
        print(json.dumps(out), flush=True)
        os._exit(0)
        """,
        header=False,
    )
    assert got["sizeof_urb"] == usbdevfs.URB_SIZE
    assert got["caps"] == usbdevfs.CAPABILITIES
    assert got["reaped_is_urb"] and got["discarded_is_urb"]
    data = bytes(range(200)) * 3
    assert got["short"] == [-errno_("EREMOTEIO"), 600, data.hex()]
    assert got["empty"] == ["EAGAIN", "EAGAIN"]
    assert got["discarded"] == [-errno_("ENOENT"), 0]
    assert got["discard_again"] == "EINVAL" and got["unknown"] == "ENOTTY"
    cam.queue_in(0x81, b"after")  # the dead program's URB must not take it
    time.sleep(3 * usbdevfs.IDLE_POLL)
    assert cam.poll_in(0x81, 512) == (b"after", None)
