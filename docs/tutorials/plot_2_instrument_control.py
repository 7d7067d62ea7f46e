"""
Writing instrument-control code
===============================

Code that moves motors and reads detectors is hard to test: the hardware is shared, slow and
rarely fails on demand. gonio serves fake devices that speak the real protocols — a Newport
ESP300 motion controller on a pseudo-terminal (RS-232 ASCII), an Ocean Optics USB2000+
spectrometer and a PTP camera on a fake USB bus (a pyusb backend) — all acting on one
simulated bench whose stages move with realistic speed and whose detectors see the
simulated instrument. Your code opens them exactly as it would open the real devices.

This tutorial serves the fake bench, talks to the controller with a few lines of pyserial,
drives a short scan with gonio's own drivers, then injects faults and checks that the code
recovers (or fails the way it should).
"""

# %%
# Serve the bench
# ---------------
# A :class:`~gonio.simulator.bench.Bench` laid out like the LBL instrument has a source arm,
# a sample rotation, a tilt and a sample changer; ``time_scale=200`` runs its clock 200 times
# faster than real time, so a 60° arm move takes a fraction of a second here.
# :class:`~gonio.drivers.fake.esp300.FakeESP300Server` serves the controller on a
# pseudo-terminal; :func:`gonio.drivers.fake.usb.install` puts the spectrometer and the camera
# on a fake USB bus and returns the name of its pyusb backend. (``gonio devices serve`` does
# the same from the command line for a driver running in another process.)
import time

import matplotlib.pyplot as plt
import numpy as np
import serial
from gonio.drivers.errors import DeviceError, DeviceTimeout
from gonio.drivers.esp300 import ESP300
from gonio.drivers.fake import usb as fakeusb
from gonio.drivers.fake.esp300 import FakeESP300Server
from gonio.drivers.ptp import PTPCamera
from gonio.drivers.usb2000 import USB2000Plus
from gonio.simulator.bench import Bench, default_spectrum_render

bench = Bench.for_instrument("lbl", "rolled_brass", time_scale=200.0, rng=0)
server = FakeESP300Server(bench).start()
usb_name = fakeusb.install(bench)
print("ESP300 on", server.port, "| pyusb backend", usb_name)
print("stages:", bench.positions())

# %%
# Your own driver: a few lines of pyserial
# ----------------------------------------
# The fake is a byte-level emulation of the ESP300 firmware (the manual's command syntax,
# error FIFO and codes), so any serial code works against it. Here is the smallest possible
# driver: switch motor 1 on, send an absolute move, poll "motion done", read the position and
# the error register.
with serial.Serial(server.port, timeout=1.0) as port:

    def ask(command: str) -> str:
        port.write(command.encode() + b"\r")
        return port.readline().decode().strip()

    print("version:", ask("VE?"))
    port.write(b"1MO;1PA20\r")  # motor on, move axis 1 to 20°
    while ask("1MD?") == "0":  # 0 while moving
        time.sleep(0.01)
    print("axis 1 at", ask("1TP?"), "deg; error code", ask("TE?"))

# %%
# A scan with gonio's drivers
# ---------------------------
# The drivers in :mod:`gonio.drivers` implement the typed interfaces of
# :mod:`gonio.drivers.interfaces` (``MotionController``, ``Axis``, ``Spectrometer``,
# ``Camera``); campaign code written against those interfaces runs unchanged on the real
# devices. The scan moves the source arm, waits for it, and reads a spectrum and a camera
# frame at every angle.
mc = ESP300.open(server.port, axes={"source": 1, "sample": 2, "tilt": 3}, timeout=0.5)
mc.enable()
spec = USB2000Plus.open(usb_name, timeout=0.2)  # USB transfer timeout, s
cam = PTPCamera.open(usb_name)
spec.integration_time = 0.02
cam.exposure = 0.01
wavelengths = spec.wavelengths()
arm = mc.axis("source")


def scan(angles):
    """Move, wait, read a spectrum and a frame at every angle."""
    records = []
    for a in angles:
        arm.move_to(a)
        position = arm.wait(10.0)
        counts = spec.intensities()
        image, meta = cam.capture(timeout=10.0)
        records.append({"angle": position, "counts": counts, "image": image, "meta": meta})
    return records


records = scan([0.0, 20.0, 40.0, 60.0])
for r in records:
    print(
        f"arm {r['angle']:5.1f}°: spectrum sum {r['counts'].sum():.4g} counts, "
        f"frame {r['image'].shape} {r['image'].dtype} mean {r['image'].mean():.1f} DN"
    )

# %%
# The figure shows what the scan read: the spectra, the camera frame at 40° (the LBL
# simulator's view of the sample through the dome) and the spectrum's total against the arm
# angle beside cos θ. On the LBL bench the spectrometer is a simple stand-in — a
# tungsten-halogen lamp's Planck spectrum reflected by a grey Lambertian sample, plus a
# constant dark offset (:func:`~gonio.simulator.bench.default_spectrum_render`) — so its
# total above the dark offset follows cos θ; the dark spectrum is the stand-in's reading with
# the source at grazing incidence. The Cornell bench's spectrometer is the Cornell
# instrument simulator.
dark = default_spectrum_render({"source": 90.0}, spec.integration_time, wavelengths)
print(f"dark offset: {dark.mean():.0f} counts per pixel")
fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
for r in records:
    axes[0].plot(wavelengths, r["counts"], lw=0.8, label=f"{r['angle']:.0f}°")
axes[0].set(xlabel="wavelength (nm)", ylabel="counts", title="USB2000+ spectra")
axes[0].legend(title="source arm", fontsize=8)
im = axes[1].imshow(np.log10(np.maximum(records[2]["image"], 1)), cmap="magma")
axes[1].set_title("PTP camera frame, arm at 40°")
axes[1].axis("off")
fig.colorbar(im, ax=axes[1], label="log10 DN", shrink=0.8)
angles = np.array([r["angle"] for r in records])
totals = np.array([(r["counts"] - dark).sum() for r in records])
fine = np.linspace(0.0, 60.0, 61)
axes[2].plot(angles, totals / totals[0], "o", label="(spectrum − dark) total / at 0°")
axes[2].plot(fine, np.cos(np.radians(fine)), "k:", label="cos θ")
axes[2].set(xlabel="source arm (deg)", ylabel="relative signal", title="signal against angle")
axes[2].legend(fontsize=8)
fig.tight_layout()

# %%
# Inject faults and check the code recovers
# -----------------------------------------
# Every fake owns a :class:`~gonio.drivers.fake.faults.Faults` object; arming a counter
# makes the next bytes or transfers go wrong, once. gonio's drivers retry what a real device
# can get wrong transiently: corrupted reply bytes (the reply fails to parse and the query is
# repeated), a USB transfer that times out, a stalled endpoint (the halt is cleared).
fakes = fakeusb.devices(usb_name)
server.faults.corrupt_reply_bytes = 2
print("position through corrupted bytes:", arm.position(), server.faults.log[-2:])
fakes["usb2000plus"].faults.usb_timeouts = 1
print("serial number through a USB timeout:", spec.serial_number())
fakes["ptp"].faults.usb_pipe_errors = 1
frame, _ = cam.capture(timeout=10.0)
print("frame through a stalled endpoint:", frame.shape, fakes["ptp"].faults.log[-1:])

# %%
# The same scan with a fault armed before every step gives the same positions:
faulty = iter(
    [
        lambda: setattr(server.faults, "corrupt_reply_bytes", 2),
        lambda: setattr(fakes["usb2000plus"].faults, "usb_timeouts", 1),
        lambda: setattr(fakes["ptp"].faults, "usb_pipe_errors", 1),
        lambda: setattr(server.faults, "drop_reply_bytes", 3),
    ]
)
again = []
for a in [0.0, 20.0, 40.0, 60.0]:
    next(faulty)()
    again.extend(scan([a]))
print("positions:", [r["angle"] for r in again], "== clean scan:",
      [r["angle"] for r in again] == [r["angle"] for r in records])  # fmt: skip

# %%
# Faults that persist are not hidden: they surface as typed exceptions your code must
# handle. A controller that stops answering raises
# :class:`~gonio.drivers.errors.DeviceTimeout` naming the device and the command; a motor
# stalled against a hardware limit raises :class:`~gonio.drivers.errors.DeviceError` with the
# controller's own error message, and the axis stays where it stopped.
server.faults.reply_delay, server.faults.delayed_replies = 0.8, -1  # every reply late
try:
    arm.position()
except DeviceTimeout as exc:
    print(f"DeviceTimeout: device {exc.device}, command {exc.command}")
server.faults.delayed_replies = 0
print("answering again:", arm.position())

server.firmware.inject_stall(1, 30.0)  # axis 1 will stall at 30°
try:
    arm.move_to(0.0)
    arm.wait(10.0)
except DeviceError as exc:
    print("DeviceError:", exc)
print("arm stopped at", arm.position())

# %%
# Close the devices, stop the server and remove the fake bus.
spec.close()
cam.close()
mc.close()
server.stop()
fakeusb.uninstall(usb_name)
