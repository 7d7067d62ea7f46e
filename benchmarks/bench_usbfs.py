"""The fakes on the emulated usbdevfs bus: spectra per second and the cost of waiting.

Run: ``python benchmarks/bench_usbfs.py [--n 200] [--rounds 2]``. Needs umockdev, its
typelib and PyGObject (``gonio.drivers.fake.usbfs``). Prints, measured in the same run:

- spectra per second through gonio's ``USB2000Plus`` driver (1 ms integration at time
  scale 1000), in-process on the fake pyusb backend and in a child process on pyusb's C
  ``libusb1`` backend through the bridge, alternated A B A B; the bridge process's own CPU
  seconds per spectrum and the URB / ioctl counts;
- a client waiting 2 s on the camera's interrupt endpoint (nothing comes) and one waiting
  for a 2 s integration: wall time, the client's CPU, the bridge's CPU and the number of
  ``REAPURBNDELAY`` calls, with the default ``reap_hold`` and with ``reap_hold=0`` (every
  empty reap answered at once: libusb spins, as on an emulated node that always polls ready).

Nothing is asserted; the numbers are for the notes.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time

from gonio.io.atomic import atomic_write_bytes

SPECTRA = """
import json, resource, sys, time
import usb.backend.libusb1 as libusb1
from gonio.drivers.usb2000 import USB2000Plus
s = USB2000Plus.open(backend=libusb1.get_backend())
s.integration_time = 0.001
s.raw_spectrum()
n = int(sys.argv[1])
r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
for _ in range(n):
    s.raw_spectrum()
t1, r1 = time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF)
cpu = r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime
print(json.dumps({"per_s": n / (t1 - t0), "client_cpu_per_spectrum_ms": 1e3 * cpu / n}))
"""

WAIT = """
import json, resource, sys, time
import usb.core, usb.backend.libusb1 as libusb1
be = libusb1.get_backend()
what = sys.argv[1]
r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
if what == "event":
    d = usb.core.find(idVendor=0x1209, backend=be)
    d.set_configuration()
    try:
        d.read(0x83, 64, timeout=2000)
    except usb.core.USBTimeoutError:
        pass
else:
    from gonio.drivers.usb2000 import USB2000Plus
    s = USB2000Plus.open(backend=be)
    s.integration_time = 2.0
    r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    s.raw_spectrum()
t1, r1 = time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF)
cpu = r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime
print(json.dumps({"wall_s": t1 - t0, "client_cpu_s": cpu}))
"""


def _child(bus, code: str, *args: str) -> dict:
    r = bus.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=300)
    if r.returncode != 0:
        raise RuntimeError(r.stderr[-2000:])
    return json.loads(r.stdout.strip().splitlines()[-1])


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def spectra(n: int, rounds: int) -> list[dict]:
    import usb.backend
    from gonio.drivers.fake import usb as fakeusb
    from gonio.drivers.fake.usbfs import UsbfsBus
    from gonio.drivers.usb2000 import USB2000Plus
    from gonio.simulator.bench import Bench

    bench = Bench.for_instrument("lbl", time_scale=1000.0, rng=1, simulate=False)
    name = fakeusb.install(bench)
    out = []
    with UsbfsBus(fakeusb.devices(name)) as bus:
        local = USB2000Plus.open(backend=getattr(usb.backend, name).get_backend())
        local.integration_time = 0.001
        local.raw_spectrum()
        for k in range(rounds):
            t0 = time.perf_counter()
            for _ in range(n):
                local.raw_spectrum()
            a = n / (time.perf_counter() - t0)
            before, c0 = dict(bus.stats), _cpu()
            b = _child(bus, SPECTRA, str(n))
            bridge_cpu = _cpu() - c0
            delta = {k2: bus.stats[k2] - before.get(k2, 0) for k2 in bus.stats}
            out.append(
                {
                    "round": k + 1,
                    "in_process_per_s": round(a, 1),
                    "bridge_per_s": round(b["per_s"], 1),
                    "ratio_bridge_over_in_process": round(b["per_s"] / a, 3),
                    "client_cpu_per_spectrum_ms": round(b["client_cpu_per_spectrum_ms"], 3),
                    "bridge_cpu_per_spectrum_ms": round(1e3 * bridge_cpu / (n + 1), 3),
                    "urbs_per_spectrum": round(delta.get("urbs reaped", 0) / (n + 1), 2),
                    "ioctls_per_spectrum": round(
                        sum(v for k2, v in delta.items() if k2.isupper()) / (n + 1), 2
                    ),
                }
            )
        local.close()
    fakeusb.uninstall(name)
    return out


def waiting() -> list[dict]:
    from gonio.drivers.fake import usb as fakeusb
    from gonio.drivers.fake.usbfs import UsbfsBus
    from gonio.simulator.bench import Bench

    out = []
    for hold in (0.01, 0.0):
        for what in ("event", "integration"):
            bench = Bench.for_instrument("lbl", time_scale=1.0, rng=1, simulate=False)
            name = fakeusb.install(bench)
            with UsbfsBus(fakeusb.devices(name), reap_hold=hold) as bus:
                c0 = _cpu()
                r = _child(bus, WAIT, what)
                out.append(
                    {
                        "wait": what,
                        "reap_hold_s": hold,
                        "wall_s": round(r["wall_s"], 3),
                        "client_cpu_s": round(r["client_cpu_s"], 3),
                        "bridge_cpu_s_whole_child": round(_cpu() - c0, 3),
                        "REAPURBNDELAY": bus.stats["REAPURBNDELAY"],
                    }
                )
            fakeusb.uninstall(name)
    return out


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=200, help="spectra per round")
    p.add_argument("--rounds", type=int, default=2, help="A B rounds")
    p.add_argument("--json", default=None, help="also write the results here")
    args = p.parse_args(argv)
    res = {"spectra": spectra(args.n, args.rounds), "waiting": waiting()}
    for section, rows in res.items():
        print(f"== {section}")
        for row in rows:
            print("  " + "  ".join(f"{k}={v}" for k, v in row.items()))
    if args.json:
        atomic_write_bytes(args.json, json.dumps(res, indent=2).encode())
    return res


if __name__ == "__main__":
    main()
