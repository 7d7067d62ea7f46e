"""Round-trip times of the drivers against the fakes.

Run: ``python benchmarks/bench_drivers.py [--n 200]``. Prints (and with ``--json PATH``
writes) the median and 95th percentile of: one ESP300 query (``1TP``) over the pty and over
loopback TCP, one USB2000+ spectrum (1 ms integration, time scale 1) over the in-process fake
pyusb backend and through seabreeze, and one PTP capture (10 ms exposure) including the
TIFF download.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time


def _stats(samples: list[float]) -> dict[str, float]:
    s = sorted(samples)
    return {
        "n": len(s),
        "median_ms": 1e3 * statistics.median(s),
        "p95_ms": 1e3 * s[int(0.95 * (len(s) - 1))],
        "min_ms": 1e3 * s[0],
    }


def _time(fn, n: int) -> dict[str, float]:
    fn()  # warm up
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return _stats(out)


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=200, help="repetitions per measurement")
    p.add_argument("--json", default=None, help="also write the results here")
    args = p.parse_args(argv)

    from gonio.drivers.esp300 import ESP300
    from gonio.drivers.fake import usb as fakeusb
    from gonio.drivers.fake.esp300 import FakeESP300Server
    from gonio.drivers.ptp import PTPCamera
    from gonio.drivers.usb2000 import USB2000Plus
    from gonio.simulator.bench import Bench

    bench = Bench.for_instrument("lbl", time_scale=1.0, simulate=False)
    res: dict[str, dict] = {}
    with FakeESP300Server(bench, tcp=True) as srv:
        pty = ESP300.open(srv.port, axes={"source": 1})
        tcp = ESP300.open(srv.url, axes={"source": 1})
        res["esp300_query_pty"] = _time(lambda: pty.axis("source").position(), args.n)
        res["esp300_query_tcp"] = _time(lambda: tcp.axis("source").position(), args.n)
        pty.close()
        tcp.close()
    name = fakeusb.install(bench)
    spec = USB2000Plus.open(name)
    spec.integration_time = 0.001
    res["usb2000_spectrum_1ms"] = _time(spec.intensities, args.n)
    spec.close()
    try:
        import seabreeze

        seabreeze.use("pyseabreeze", pyusb_backend=name)
        from seabreeze.spectrometers import Spectrometer

        sb = Spectrometer.from_first_available()
        sb.integration_time_micros(1000)
        res["seabreeze_spectrum_1ms"] = _time(sb.intensities, args.n)
        sb.close()
    except ImportError:
        pass
    cam = PTPCamera.open(name)
    cam.exposure = 0.01
    res["ptp_capture_10ms"] = _time(lambda: cam.capture(timeout=10), max(10, args.n // 10))
    cam.close()
    for k, v in res.items():
        print(f"{k:<26} median {v['median_ms']:8.3f} ms   p95 {v['p95_ms']:8.3f} ms   (n={v['n']})")
    if args.json:
        from gonio.io.atomic import atomic_write_bytes

        atomic_write_bytes(args.json, (json.dumps(res, indent=2) + "\n").encode())
    return res


if __name__ == "__main__":
    main()
