"""``gonio devices serve``: run the fake devices on a simulated bench until interrupted."""

from __future__ import annotations

import json
import sys

COMMAND = "devices"
HELP = "fake ESP300 / USB2000+ / PTP camera on a simulated bench (gonio devices serve)"


def add_arguments(parser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION")
    p = sub.add_parser("serve", help="start the fakes and print how to reach them")
    p.add_argument(
        "--instrument",
        choices=("lbl", "cornell"),
        default="lbl",
        help="bench layout and instrument simulator (default lbl)",
    )
    p.add_argument("--material", default=None, help="material preset of the sample")
    p.add_argument(
        "--time-scale",
        type=float,
        default=1.0,
        help="simulated seconds per real second (default 1)",
    )
    p.add_argument(
        "--tcp-port", type=int, default=0, help="TCP port of the ESP300 (default: any free port)"
    )
    p.add_argument(
        "--link", default=None, help="also keep a symlink to the ESP300 pty at this path"
    )
    p.add_argument(
        "--json",
        action="store_true",
        help="one JSON object per device per line (flushed when ready)",
    )


def _serve(args) -> int:
    import signal
    import threading

    from gonio.drivers.fake.esp300 import FakeESP300Server
    from gonio.drivers.fake.usb import devices, install, serve_remote
    from gonio.simulator.bench import Bench

    if args.time_scale <= 0:
        raise ValueError(f"--time-scale={args.time_scale!r}: expected a number > 0")
    if args.material is not None:
        from gonio import materials

        if args.material not in materials.names():
            raise ValueError(
                f"--material={args.material!r}: expected one of {', '.join(materials.names())}"
            )
    bench = Bench.for_instrument(args.instrument, args.material, time_scale=args.time_scale)
    server = FakeESP300Server(bench, tcp=args.tcp_port or True, link=args.link).start()
    name = install(bench)
    remote = serve_remote(name)
    fakes = devices(name)
    axes = {str(i): s.name for i, s in server.firmware.axes.items()}
    records = [
        {
            "device": "esp300",
            "port": server.port,
            "tcp": server.tcp_port,
            "url": server.url,
            "link": args.link,
            "axes": axes,
        },
        {
            "device": "usb2000plus",
            "backend": name,
            "usb_server": remote.address,
            "vendor": "0x2457",
            "product": "0x101e",
            "serial": fakes["usb2000plus"].serial,
        },
        {
            "device": "ptp",
            "backend": name,
            "usb_server": remote.address,
            "vendor": f"0x{fakes['ptp'].vendor:04x}",
            "product": f"0x{fakes['ptp'].product:04x}",
            "serial": fakes["ptp"].serial,
        },
    ]
    for rec in records:
        if args.json:
            print(json.dumps(rec), flush=True)
        elif rec["device"] == "esp300":
            print(f"esp300       pty {rec['port']}   tcp {rec['url']}   axes {axes}", flush=True)
        else:
            print(
                f"{rec['device']:<12} pyusb backend {name!r} in this process; from another "
                f"process: gonio.drivers.fake.usb.connect({remote.address!r})",
                flush=True,
            )
    if not args.json:
        print(
            f"bench: instrument {args.instrument}, material {args.material}, "
            f"time x{args.time_scale:g}; Ctrl-C to stop",
            flush=True,
        )
    stop = threading.Event()
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        while not stop.wait(0.5):  # Ctrl-C raises KeyboardInterrupt here; SIGTERM sets stop
            pass
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGTERM, previous)
        server.stop()
        remote.close()
    return 0


def run(args) -> int:
    if getattr(args, "action", None) != "serve":
        print(
            "usage: gonio devices serve [--instrument lbl|cornell] [--material M] [--json]",
            file=sys.stderr,
        )
        return 2
    return _serve(args)
