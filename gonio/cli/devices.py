"""``gonio devices serve``: run the fake devices on a simulated bench until interrupted.

Every ESP300 controller of the bench is served (``gonio.campaign.drivers.CONTROLLER_GROUPS``): for
``--instrument cornell`` the motors (arm, turntable, tilt), the accessories (polariser,
target slide, ND filter wheel) and the shutter, on three controllers, beside the USB2000+
(1024 pixels, the simulator's EEPROM wavelength calibration) and the PTP camera on one fake
USB bus; for ``lbl`` the source arm, sample rotation and tilt, and the sample changer.
The Cornell bench is ``gonio.campaign.drivers.cornell_fake_bench(material, seed, noise)``, so an
external driver script (``gonio.campaign.drivers.open_served_rig`` on the printed records, then
``run_cornell_measurements``) measures the same samples as the in-process simulation with
the same seed.

With ``--libusb`` the USB fakes are also put on an emulated Linux USB bus (umockdev's preload
library, :mod:`gonio.drivers.fake.usbfs`) that every libusb-1.0 program sees — ``lsusb``,
``gphoto2``, pyusb's ``libusb1`` backend, python-seabreeze, C programs: ``gonio devices serve
--libusb -- gphoto2 --capture-image-and-download`` runs the program on the bus and returns its
exit code; without a program the environment to start programs with is printed and the bus
is served until interrupted. ``--fault usb2000plus.usb_pipe_errors=1`` arms a fault of a fake
(:class:`gonio.drivers.fake.faults.Faults`) before anything connects.
"""

from __future__ import annotations

import argparse
import json
import sys

from gonio.cli._common import port_number

COMMAND = "devices"
HELP = "fake ESP300 / USB2000+ / PTP camera on a simulated bench (gonio devices serve)"


def add_arguments(parser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION")
    p = sub.add_parser(
        "serve",
        help="start the fakes and print how to reach them",
        description="Start the fake ESP300 motion controllers (on a pseudo-terminal and a "
        "loopback TCP port), the fake USB2000+ spectrometer and PTP camera (on a fake USB bus) "
        "on a simulated bench of the chosen instrument, print how to reach each device (one "
        "line each, or JSON), and serve them until interrupted (Ctrl-C); with --libusb and a "
        "program after '--', run that program on the emulated USB bus and return its exit code.",
        formatter_class=parser.formatter_class,
    )
    p.add_argument(
        "--instrument",
        choices=("lbl", "cornell"),
        default="lbl",
        help="bench layout and instrument simulator (default lbl)",
    )
    p.add_argument(
        "--material",
        default=None,
        help="material preset of the sample (default: the diffuse standard on lbl, a "
        "Lambertian sample on cornell)",
    )
    p.add_argument(
        "--time-scale",
        type=float,
        default=1.0,
        help="simulated seconds per real second (default 1)",
    )
    p.add_argument(
        "--tcp-port",
        type=port_number,
        default=0,
        help="TCP port of the ESP300 (default: any free port)",
    )
    p.add_argument(
        "--link", default=None, help="also keep a symlink to the ESP300 pty at this path"
    )
    p.add_argument(
        "--seed",
        type=int,
        default=0,
        help="noise seed of the simulated instrument (default 0; the in-process seed)",
    )
    p.add_argument(
        "--noise", choices=("on", "off"), default="on", help="detector noise (default on)"
    )
    p.add_argument(
        "--json",
        action="store_true",
        help="one JSON object per device per line (flushed when ready)",
    )
    p.add_argument(
        "--libusb",
        action="store_true",
        help="also put the USB fakes on an emulated usbdevfs bus for libusb-1.0 programs "
        "(needs umockdev, gir1.2-umockdev-1.0 and PyGObject: pip install 'gonio[libusb]')",
    )
    p.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="DEVICE.FAULT=N",
        help="arm a fault of a USB fake, e.g. usb2000plus.disconnect_after_bytes=5000 "
        "(repeatable; faults: see gonio.drivers.fake.faults.Faults)",
    )
    p.add_argument(
        "program",
        nargs=argparse.REMAINDER,
        help="with --libusb: a program (after --) to run on the bus; its exit code is returned",
    )


def _parse_faults(specs: list[str]) -> list[tuple[str, str, float]]:
    """``--fault DEVICE.FAULT=VALUE`` settings as (device, fault, value), checked."""
    import dataclasses

    from gonio.drivers.fake.faults import Faults

    names = {f.name for f in dataclasses.fields(Faults) if not f.name.startswith("_")} - {"log"}
    out = []
    for spec in specs:
        target, _, value = spec.partition("=")
        dev, _, fault = target.partition(".")
        if dev not in ("usb2000plus", "ptp") or fault not in names or not value:
            raise ValueError(
                f"--fault={spec!r}: expected DEVICE.FAULT=VALUE with DEVICE usb2000plus or ptp "
                f"and FAULT one of {sorted(names)}"
            )
        try:
            number = float(value) if fault in ("reply_delay", "reconnect_after") else int(value)
        except ValueError:
            raise ValueError(f"--fault={spec!r}: {value!r} is not a number") from None
        if number < 0 and not (fault == "delayed_replies" and number == -1):
            raise ValueError(f"--fault={spec!r}: expected a value >= 0")
        out.append((dev, fault, number))
    return out


def _serve(args) -> int:
    """Start the fakes on a bench, print how to reach them, serve until stopped (or the
    program ends); every server, bus and thread started is stopped on the way out."""
    from gonio.drivers.fake.usb import devices

    faults, command = _check_serve_args(args)
    bench = _make_bench(args)
    servers, records, name, remote = _start_servers(bench, args)
    fakes = devices(name)
    for dev, fault, number in faults:
        setattr(fakes[dev].faults, fault, number)
    bus = None
    if args.libusb:
        from gonio.drivers.fake.usbfs import UsbfsBus

        try:
            bus = UsbfsBus(fakes)
        except BaseException:
            for srv in servers:
                srv.stop()
            remote.close()
            raise
        records.append(bus.record(fakes))
    records += _usb_and_bench_records(args, bench, fakes, name, remote.address)
    return _serve_until_stopped(args, command, records, servers, remote, bus, name)


def _check_serve_args(args) -> tuple[list[tuple[str, str, float]], list[str]]:
    """``serve``'s options checked: the faults to arm and the program to run (may be empty).

    With ``--libusb`` this re-executes the command under umockdev's preload library.
    """
    if args.time_scale <= 0:
        raise ValueError(f"--time-scale={args.time_scale!r}: expected a number > 0")
    if args.seed < 0:
        raise ValueError(f"--seed={args.seed!r}: expected an integer >= 0")
    if args.material is not None:
        from gonio import materials

        if args.material not in materials.names():
            raise ValueError(
                f"--material={args.material!r}: expected one of {', '.join(materials.names())}"
            )
    faults = _parse_faults(args.fault)
    command = args.program[1:] if args.program[:1] == ["--"] else args.program
    if command and not args.libusb:
        raise ValueError(f"{' '.join(command)!r}: a program to run needs --libusb")
    if args.libusb:
        from gonio.drivers.fake.usbfs import UsbfsUnavailable, ensure_preloaded

        try:
            ensure_preloaded()  # re-executes this command under umockdev's preload library
        except UsbfsUnavailable as exc:
            raise ValueError(f"--libusb: {exc}") from None
    return faults, command


def _sample_label(args) -> str:
    """What the bench's sample is: ``--material``, else what the instrument puts there."""
    if args.material is not None:
        return args.material
    return "standard (no --material)" if args.instrument == "lbl" else "lambert (no --material)"


def _make_bench(args):
    """The simulated bench of ``--instrument`` with the sample, seed, noise and time scale."""
    from gonio.campaign.drivers import cornell_fake_bench
    from gonio.simulator.bench import Bench

    noise = args.noise == "on"
    if args.instrument == "cornell":
        bench, _inst = cornell_fake_bench(
            args.material, seed=args.seed, noise=noise, time_scale=args.time_scale
        )
        return bench
    return Bench.for_instrument(
        args.instrument, args.material, time_scale=args.time_scale, rng=args.seed, noise=noise
    )


def _start_servers(bench, args) -> tuple[list, list[dict], str, object]:
    """One fake ESP300 server per controller of the bench and the fake USB bus served to
    other processes: (servers, their records, the pyusb backend's name, the USB server).

    If any of them fails to start, the servers already started are stopped.
    """
    from gonio.campaign.drivers import CONTROLLER_GROUPS
    from gonio.drivers.fake.esp300 import FakeESP300Server
    from gonio.drivers.fake.usb import install, serve_remote

    servers = []
    records = []
    try:
        for k, (role, group) in enumerate(CONTROLLER_GROUPS[args.instrument]):
            link = None
            if args.link:
                link = args.link if k == 0 else f"{args.link}{k + 1}"
            tcp = (args.tcp_port or True) if k == 0 else True
            srv = FakeESP300Server(bench, tcp=tcp, link=link, axes=list(group)).start()
            servers.append(srv)
            records.append(
                {
                    "device": "esp300",
                    "controller": role,
                    "port": srv.port,
                    "tcp": srv.tcp_port,
                    "url": srv.url,
                    "link": link,
                    "axes": {str(i): s.name for i, s in srv.firmware.axes.items()},
                }
            )
        name = install(bench)
        remote = serve_remote(name)
    except BaseException:
        for srv in servers:
            srv.stop()
        raise
    return servers, records, name, remote


def _usb_and_bench_records(args, bench, fakes: dict, name: str, usb_server: str) -> list[dict]:
    """The printed records of the USB2000+, the PTP camera and the bench."""
    return [
        {
            "device": "usb2000plus",
            "backend": name,
            "usb_server": usb_server,
            "vendor": "0x2457",
            "product": "0x101e",
            "serial": fakes["usb2000plus"].serial,
            "n_pixels": int(bench.n_pixels),
        },
        {
            "device": "ptp",
            "backend": name,
            "usb_server": usb_server,
            "vendor": f"0x{fakes['ptp'].vendor:04x}",
            "product": f"0x{fakes['ptp'].product:04x}",
            "serial": fakes["ptp"].serial,
        },
        {
            "device": "bench",
            "instrument": args.instrument,
            "material": _sample_label(args),
            "seed": int(args.seed),
            "noise": args.noise == "on",
            "time_scale": float(args.time_scale),
            "stages": list(bench.stages),
        },
    ]


def _serve_until_stopped(args, command, records, servers, remote, bus, name: str) -> int:
    """Print the records, then serve until SIGINT/SIGTERM (or run ``command`` on the libusb
    bus and return its exit code); stop the bus, the servers and the USB server."""
    import signal
    import threading

    stop = threading.Event()
    # SIGINT (Ctrl-C) and SIGTERM both stop the server, through handlers installed before the
    # records are printed (a client may signal as soon as it has read them). SIGINT needs its
    # own handler: a process started in the background by a non-interactive shell (`gonio
    # devices serve &` in a script) inherits SIGINT *ignored* and gets no KeyboardInterrupt
    previous = {sig: signal.signal(sig, lambda *_: stop.set())
                for sig in (signal.SIGINT, signal.SIGTERM)}  # fmt: skip
    out = sys.stderr if command else sys.stdout  # the program's own output stays clean
    rc = 0
    try:
        for rec in records:
            print(_describe(rec, args, name, remote.address), file=out, flush=True)
        if bus is not None and command:
            rc = bus.run_until(command, stop)
        else:
            while not stop.wait(0.5):
                pass
    except KeyboardInterrupt:
        pass
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if bus is not None:
            bus.close()
        for srv in servers:
            srv.stop()
        remote.close()
    return rc


def _describe(rec: dict, args, name: str, usb_server: str) -> str:
    """One printed line for a record (its JSON with ``--json``)."""
    if args.json:
        return json.dumps(rec)
    if rec["device"] == "esp300":
        return (
            f"esp300 ({rec['controller']})  pty {rec['port']}   tcp {rec['url']}   "
            f"axes {rec['axes']}"
        )
    if rec["device"] == "bench":
        return (
            f"bench: instrument {args.instrument}, material {_sample_label(args)}, seed "
            f"{args.seed}, noise {args.noise}, time x{args.time_scale:g}; Ctrl-C to stop"
        )
    if rec["device"] == "libusb":
        nodes = ", ".join(f"{k} {v}" for k, v in rec["nodes"].items())
        return f"libusb bus: {nodes}; programs run with: {rec['env']}"
    return (
        f"{rec['device']:<12} pyusb backend {name!r} in this process; from another "
        f"process: gonio.drivers.fake.usb.connect({usb_server!r})"
    )


def run(args) -> int:
    if getattr(args, "action", None) != "serve":
        print(
            "usage: gonio devices serve [--instrument lbl|cornell] [--material M] [--seed N]"
            " [--noise on|off] [--json] [--fault DEVICE.FAULT=N] [--libusb [-- PROGRAM ...]]",
            file=sys.stderr,
        )
        return 2
    return _serve(args)
