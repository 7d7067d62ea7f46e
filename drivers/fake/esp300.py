"""A Newport ESP300 firmware emulator on a pseudo-terminal (and optionally loopback TCP).

:class:`ESP300Firmware` is a byte-level state machine: bytes in (commands, ``\\r`` or ``\\n``
terminated, ``;``-separated), bytes out (query replies ending ``\\r\\n``), motion on the
simulated bench's stages, a 10-deep error FIFO read by ``TE?``/``TB?`` with the manual's codes,
``WS`` holding later commands until the axis stops. :class:`FakeESP300Server` serves it on
``os.openpty()`` so any process can ``serial.Serial(path)``, and on ``127.0.0.1:<port>`` for
``serial.serial_for_url("socket://127.0.0.1:<port>")``.

References
----------
Newport, *ESP300 Motion Controller/Driver User's Manual*, ch. 3 (command syntax, command
set, error codes).
"""

from __future__ import annotations

import contextlib
import os
import re
import select
import socket
import threading
import time
import tty
from collections import deque
from collections.abc import Sequence

from gonio.drivers.fake.faults import Faults
from gonio.simulator.bench import Bench, Stage, StageFault

__all__ = ["ERROR_MESSAGES", "ESP300Firmware", "FakeESP300Server"]

VERSION = "ESP300 Version 3.08 09/09/02"

#: Listen backlog of the TCP port: connections beyond the one served are accepted and
#: refused with :data:`BUSY_REPLY`, never left unanswered in a full backlog.
_BACKLOG = 64

#: The line a TCP client gets (then the socket closes) while another client is served: the
#: controller has one host port; a second host is refused explicitly, not silently dropped.
BUSY_REPLY = b"ESP300 fake: busy, another client is connected\r\n"

#: General errors (code) and axis errors (100·axis + code) of the ESP300 manual.
ERROR_MESSAGES = {
    0: "NO ERROR DETECTED",
    6: "COMMAND DOES NOT EXIST",
    7: "PARAMETER OUT OF RANGE",
    9: "AXIS NUMBER OUT OF RANGE",
    37: "AXIS NUMBER MISSING",
    38: "COMMAND PARAMETER MISSING",
}
AXIS_ERRORS = {
    1: "PARAMETER OUT OF RANGE",
    2: "AMPLIFIER FAULT DETECTED",
    4: "POSITIVE HARDWARE LIMIT DETECTED",
    5: "NEGATIVE HARDWARE LIMIT DETECTED",
    6: "POSITIVE SOFTWARE LIMIT DETECTED",
    7: "NEGATIVE SOFTWARE LIMIT DETECTED",
    10: "MAXIMUM VELOCITY EXCEEDED",
    11: "MAXIMUM ACCELERATION EXCEEDED",
    13: "MOTOR NOT ENABLED",
    20: "HOMING ABORTED",
}
#: Longest command line the fake buffers before its terminator (bytes; a real command line is
#: under 80): a longer one is discarded with error 6, so a host that never sends ``\r`` cannot
#: grow the buffer (or the time each search for a terminator takes) without bound.
MAX_LINE = 1024

#: Most commands queued (behind a ``WS`` wait, say); beyond it a command is dropped (error 6).
MAX_QUEUE = 1024

_CMD = re.compile(r"^\s*(\d*)\s*([A-Za-z]{2})\s*(\?|[-+]?[0-9.]*(?:[eE][-+]?\d+)?)\s*$")
_AXIS_CMDS = {
    "PA",
    "PR",
    "TP",
    "MD",
    "MO",
    "MF",
    "OR",
    "DH",
    "VA",
    "AC",
    "SL",
    "SR",
    "ID",
    "SN",
    "ST",
}
_UNIT_CODE = {"deg": 7, "mm": 2, "um": 3, "rad": 9}


def message(code: int) -> str:
    """The manual's text for an error code."""
    if code >= 100:
        return AXIS_ERRORS.get(code % 100, "UNKNOWN AXIS ERROR")
    return ERROR_MESSAGES.get(code, "UNKNOWN ERROR")


class ESP300Firmware:
    """The controller's command interpreter, bound to bench stages.

    Parameters
    ----------
    bench : Bench
        The simulated bench; axes 1..3 drive ``axes`` (default: its first three stages).
    axes : sequence of str, optional
        Stage names for axes 1, 2, 3.
    faults : Faults, optional
        Fault switches (also reachable as ``.faults``).
    max_velocity, max_acceleration : float
        Limits of ``VA`` / ``AC`` (axis error 10 / 11 beyond them).
    """

    def __init__(
        self,
        bench: Bench,
        axes: Sequence[str] | None = None,
        faults: Faults | None = None,
        *,
        max_velocity: float = 200.0,
        max_acceleration: float = 2000.0,
    ) -> None:
        names = list(axes) if axes is not None else list(bench.stages)[:3]
        if not 1 <= len(names) <= 3:
            raise ValueError(f"axes={names!r}: expected 1 to 3 stage names")
        self.bench = bench
        self.axes = {i + 1: bench.stage(n) for i, n in enumerate(names)}
        self.soft = {i: [s.lower, s.upper] for i, s in self.axes.items()}
        self.faults = faults or Faults()
        self.max_velocity = float(max_velocity)
        self.max_acceleration = float(max_acceleration)
        self.errors: deque[tuple[int, int]] = deque(maxlen=10)
        self._inbuf = bytearray()
        self._queue: deque[str] = deque()
        self._hold: dict | None = None
        self._homing: set[int] = set()
        self._limit_armed: set[int] = set()
        self.lock = threading.RLock()

    # -- byte interface ---------------------------------------------------------------------
    def receive(self, data: bytes) -> None:
        """Bytes from the host (terminator ``\\r`` or ``\\n``; ``;`` separates commands)."""
        data = self.faults.filter_command(bytes(data))
        with self.lock:
            start = len(self._inbuf)  # (the old bytes hold no terminator: searched from here)
            self._inbuf += data
            while True:
                idx = [i for i in (self._inbuf.find(b"\r", start),
                                   self._inbuf.find(b"\n", start)) if i >= 0]  # fmt: skip
                start = 0
                if not idx:
                    break
                i = min(idx)
                line = bytes(self._inbuf[:i])
                del self._inbuf[: i + 1]
                if len(line) > MAX_LINE:
                    self._error(6)
                elif line.strip():
                    text = line.decode("latin-1")
                    for c in text.split(";"):
                        if not c.strip():
                            continue
                        if len(self._queue) >= MAX_QUEUE:
                            self._error(6)
                            break
                        self._queue.append(c)
            if len(self._inbuf) > MAX_LINE:  # no terminator in sight: the line is dropped
                self._inbuf.clear()
                self._error(6)

    def step(self) -> bytes:
        """Advance: finish homing, report limit stalls, run queued commands; the reply bytes."""
        out = []
        with self.lock:
            self._events()
            while self._queue:
                if self._hold is not None and not self._release_hold():
                    # stop/abort still act while WS holds the queue
                    for c in list(self._queue):
                        m = _CMD.match(c)
                        if m and m.group(2).upper() in ("ST", "AB"):
                            self._queue.remove(c)
                            out.append(self._execute_safely(c))
                    break
                out.append(self._execute_safely(self._queue.popleft()))
        return "".join(o for o in out if o).encode("ascii")

    def busy(self) -> bool:
        """True while commands wait (``WS``) or a move or homing is in progress."""
        t = self.bench.now()
        with self.lock:
            return (
                bool(self._queue)
                or any(s.is_moving(t) for s in self.axes.values())
                or bool(self._homing)
            )

    def reset_link(self) -> None:
        """Forget the host link's state: a partial line, queued commands and a ``WS`` wait.

        Called when a TCP client connects or goes away, so one client's unfinished bytes are
        never glued to the next client's first command and a ``WS`` wait does not outlive
        the client that sent it. The axes (motion, positions) and the error queue are the
        controller's and are kept.
        """
        with self.lock:
            self._inbuf.clear()
            self._queue.clear()
            self._hold = None

    # -- internals --------------------------------------------------------------------------
    def _error(self, code: int) -> None:
        self.errors.append((code, int(self.bench.now() * 1000) % 10**9))

    def _events(self) -> None:
        t = self.bench.now()
        for n, s in self.axes.items():
            if s.is_moving(t):
                continue
            if n in self._homing:
                self._homing.discard(n)
                s.define_position(0.0, t)
            if n in self._limit_armed and s.limit_hit():
                self._limit_armed.discard(n)
                self._error(100 * n + (4 if s.limit_hit() == "+" else 5))

    def _release_hold(self) -> bool:
        h = self._hold
        t = self.bench.now()
        if any(self.axes[n].is_moving(t) for n in h["axes"]):
            return False
        if h["stopped"] is None:
            h["stopped"] = t
        if t - h["stopped"] < h["delay"]:
            return False
        self._hold = None
        return True

    def _execute_safely(self, cmd: str) -> str:
        """:meth:`_execute`, any failure of it an error of this command (``TE?`` reports
        error 6), so that one bad command never stops the controller's serving thread."""
        try:
            return self._execute(cmd)
        except Exception:
            self._error(6)
            return ""

    def _execute(self, cmd: str) -> str:
        """One command: its reply text, or ``""`` (an error is queued for ``TE?``/``TB?``)."""
        m = _CMD.match(cmd)
        if not m:
            self._error(6)
            return ""
        ax_s, mn, arg = m.group(1), m.group(2).upper(), m.group(3)
        query = arg == "?"
        value: float | None = None
        if arg and not query:
            try:
                value = float(arg)
            except ValueError:
                self._error(7)
                return ""
        if len(ax_s) > 3:  # (an axis number of thousands of digits is no axis)
            self._error(9)
            return ""
        axis = int(ax_s) if ax_s else None
        t = self.bench.now()
        reply = self._controller_command(mn, axis, query, value, t)
        if reply is not None:
            return reply
        if mn not in _AXIS_CMDS:
            self._error(6)
            return ""
        if axis is None:
            self._error(37)
            return ""
        if axis not in self.axes:
            self._error(9)
            return ""
        return self._axis_command(mn, axis, self.axes[axis], query, value, t)

    def _controller_command(
        self, mn: str, axis: int | None, query: bool, value: float | None, t: float
    ) -> str | None:
        """A controller-wide command's reply (``VE?``, ``TE?``, ``TB?``, ``AB``, ``WS``), or
        ``None`` when ``mn`` is not one."""
        if mn == "VE" and query:
            return VERSION + "\r\n"
        if mn == "TE" and query:
            code = self.errors.popleft()[0] if self.errors else 0
            return f"{code}\r\n"
        if mn == "TB" and query:
            code, ts = self.errors.popleft() if self.errors else (0, int(t * 1000) % 10**9)
            return f"{code}, {ts}, {message(code)}\r\n"
        if mn == "AB":
            for s in self.axes.values():
                s.stop(t)
            self._homing.clear()
            return ""
        if mn == "WS":
            axes = [axis] if axis else list(self.axes)
            if axis and axis not in self.axes:
                self._error(9)
                return ""
            self._hold = {"axes": axes, "delay": (value or 0.0) / 1000.0, "stopped": None}
            return ""
        return None

    def _axis_command(
        self, mn: str, axis: int, s: Stage, query: bool, value: float | None, t: float
    ) -> str:
        """An axis command's reply (status, motor power, identification, parameters, moves)."""
        fmt = "{:.5f}\r\n".format
        if mn == "TP":
            return fmt(s.motor_position(t))
        if mn == "MD" and query:
            return "0\r\n" if (s.is_moving(t) or axis in self._homing) else "1\r\n"
        if mn == "MO":
            if query:
                return "1\r\n" if s.motor_on else "0\r\n"
            s.fault = None
            s.motor_on = True
            return ""
        if mn == "MF":
            s.stop(t)
            s.motor_on = False
            return ""
        if mn == "ST":
            s.stop(t)
            self._homing.discard(axis)
            return ""
        if mn == "SN" and query:
            return f"{_UNIT_CODE.get(s.units, 0)}\r\n"
        if mn == "ID" and query:
            model = "URS100BPP" if s.units == "deg" else "UTM100PP1HL"
            return f"{model}, B{10000 + axis * 1111}\r\n"
        if mn in ("VA", "AC", "SL", "SR"):
            return self._parameter(mn, axis, s, query, value)
        if mn == "DH":
            s.define_position(value or 0.0, t)
            return ""
        if mn == "OR":
            if not s.motor_on:
                self._error(100 * axis + 13)
                return ""
            try:
                s.move_to(s.home, t)
            except StageFault:
                self._error(100 * axis + 20)
                return ""
            self._homing.add(axis)
            return ""
        if mn in ("PA", "PR"):
            return self._move(mn, axis, s, value, t)
        self._error(6)
        return ""

    def _parameter(self, mn: str, axis: int, s: Stage, query: bool, value: float | None) -> str:
        """``VA``/``AC``/``SL``/``SR``: query or set velocity, acceleration, soft limits."""
        if query:
            v = {
                "VA": s.speed,
                "AC": s.acceleration,
                "SL": self.soft[axis][0],
                "SR": self.soft[axis][1],
            }[mn]
            return f"{v:.5f}\r\n"
        if value is None:
            self._error(38)
            return ""
        if mn == "VA":
            if not 0 < value <= self.max_velocity:
                self._error(100 * axis + 10)
            else:
                s.speed = value
        elif mn == "AC":
            if not 0 < value <= self.max_acceleration:
                self._error(100 * axis + 11)
            else:
                s.acceleration = value
        elif mn == "SL":
            self.soft[axis][0] = value
        else:
            self.soft[axis][1] = value
        return ""

    def _move(self, mn: str, axis: int, s: Stage, value: float | None, t: float) -> str:
        """``PA``/``PR``: an absolute or relative move, refused outside the soft limits, on a
        faulted axis or with the motor off."""
        if value is None:
            self._error(38)
            return ""
        if s.is_moving(t):
            start = s.motor_position(t)
            target_base = s._move.end if s._move is not None else start
        else:
            target_base = s.motor_position(t)
        target = value if mn == "PA" else target_base + value
        lo, hi = self.soft[axis]
        if target > hi:
            self._error(100 * axis + 6)
            return ""
        if target < lo:
            self._error(100 * axis + 7)
            return ""
        if s.fault:
            self._error(100 * axis + 2)
            return ""
        if not s.motor_on:
            self._error(100 * axis + 13)
            return ""
        s.move_to(target, t)
        self._limit_armed.add(axis)
        return ""

    # -- device-specific faults -------------------------------------------------------------
    def inject_motor_fault(self, axis: int) -> None:
        """Amplifier fault on ``axis``: it stops, the motor turns off, error ``x02`` queued."""
        with self.lock:
            s = self.axes[axis]
            s.stop(self.bench.now())
            s.fault = "amplifier fault"
            s.motor_on = False
            self._homing.discard(axis)
            self._error(100 * axis + 2)

    def inject_stall(self, axis: int, position: float) -> None:
        """An obstacle: the next move of ``axis`` across ``position`` stops at it (limit)."""
        with self.lock:
            s = self.axes[axis]
            p = s.motor_position(self.bench.now())
            if position >= p:
                s.upper = float(position)
            else:
                s.lower = float(position)


class FakeESP300Server:
    """Serve an :class:`ESP300Firmware` on a pty (and optionally loopback TCP) in a thread.

    Parameters
    ----------
    bench : Bench, optional
        Default: ``Bench.for_instrument("lbl")``.
    tcp : bool or int
        Also listen on 127.0.0.1 (an int picks the port; ``True`` any free port).
    link : str, optional
        Keep a symlink to the current pty here; after a simulated unplug the fake comes back
        on a new pty and the link is updated, so clients can reconnect by the link path. An
        existing path that is not a symlink is refused (``ValueError``), never replaced, and
        on :meth:`stop` the link is removed only while it still points at this server's pty.
    axes : sequence of str, optional
        Stage names for axes 1..3.
    faults : Faults, optional

    Use as a context manager or call :meth:`start` / :meth:`stop`. ``port`` is the pty path,
    ``tcp_port`` the TCP port, ``firmware`` the emulator.
    """

    def __init__(
        self,
        bench: Bench | None = None,
        *,
        tcp: bool | int = False,
        link: str | None = None,
        axes: Sequence[str] | None = None,
        faults: Faults | None = None,
    ) -> None:
        self.bench = bench or Bench.for_instrument("lbl")
        self.faults = faults or Faults()
        self.firmware = ESP300Firmware(self.bench, axes, self.faults)
        self.tcp_firmware = ESP300Firmware(self.bench, axes, self.faults)
        self.link = link
        self._want_tcp = tcp
        self.port: str | None = None
        self.tcp_port: int | None = None
        self._master = self._slave = -1
        self._lsock: socket.socket | None = None
        self._client: socket.socket | None = None
        self._pending: list[tuple[float, str, bytes, bool]] = []
        self._down_until = 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.disconnects = 0
        self.refused = 0  # TCP connections refused while another client was served
        self._ptys: set[str] = set()

    # -- lifecycle --------------------------------------------------------------------------
    def start(self) -> FakeESP300Server:
        if self.link and os.path.lexists(self.link) and not os.path.islink(self.link):
            raise ValueError(f"link={self.link!r} exists and is not a symlink; not replacing it")
        if self._want_tcp is not False:
            port = 0 if self._want_tcp is True else int(self._want_tcp)
            if not 0 <= port <= 65535:
                raise ValueError(f"tcp={self._want_tcp!r}: a port must be in [0, 65535]")
            self._lsock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            self._lsock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                self._lsock.bind(("127.0.0.1", port))
            except OSError as exc:
                self._lsock.close()
                self._lsock = None
                msg = f"cannot listen on 127.0.0.1:{port}: {exc.strerror}"
                raise OSError(exc.errno, msg) from None
            self._lsock.listen(_BACKLOG)
            self.tcp_port = self._lsock.getsockname()[1]
        self._open_pty()
        self._thread = threading.Thread(target=self._run, name="fake-esp300", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self._close_pty()
        for s in (self._client, self._lsock):
            if s is not None:
                with contextlib.suppress(OSError):
                    s.close()
        if self.link and self._owns_link():
            with contextlib.suppress(OSError):
                os.unlink(self.link)

    def _owns_link(self) -> bool:
        """Whether ``link`` is still the symlink this server made (to one of its ptys)."""
        try:
            return os.path.islink(self.link) and os.readlink(self.link) in self._ptys
        except OSError:
            return False

    def __enter__(self) -> FakeESP300Server:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def url(self) -> str:
        """``socket://127.0.0.1:<port>`` for pyserial (TCP must be on)."""
        if self.tcp_port is None:
            raise ValueError("tcp=False: this server has no TCP port")
        return f"socket://127.0.0.1:{self.tcp_port}"

    def _open_pty(self) -> None:
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo or CR/LF mangling before the client configures it
        os.set_blocking(self._master, False)  # nobody reading: replies are lost, not blocking
        self.port = os.ttyname(self._slave)
        self._ptys.add(self.port)
        if self.link:
            tmp = f"{self.link}.tmp{os.getpid()}"
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
            os.symlink(self.port, tmp)
            os.replace(tmp, self.link)

    def _close_pty(self) -> None:
        for fd in (self._master, self._slave):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = -1

    def unplug(self) -> None:
        """Simulate pulling the cable: drop the pty / TCP client; back after ``reconnect_after``."""
        self.disconnects += 1
        self._close_pty()
        self._drop_client()
        self._pending.clear()
        self._down_until = time.monotonic() + self.faults.reconnect_after

    # -- TCP clients ------------------------------------------------------------------------
    def _accept(self) -> None:
        """Serve a new connection, or refuse it explicitly while another client is served."""
        try:
            conn, _ = self._lsock.accept()
        except OSError:
            return
        if time.monotonic() < self._down_until:
            conn.close()
            return
        if self._client is not None and self._client_alive():
            self.refused += 1
            with contextlib.suppress(OSError):
                conn.sendall(BUSY_REPLY)
            conn.close()
            return
        self._drop_client()
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._client = conn

    def _client_alive(self) -> bool:
        """Whether the served client's socket is still open (peek, without consuming)."""
        try:
            return bool(self._client.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT))
        except BlockingIOError:
            return True
        except OSError:
            return False

    def _drop_client(self) -> None:
        """Close the TCP client and forget its link state and undelivered replies."""
        if self._client is not None:
            with contextlib.suppress(OSError):
                self._client.close()
            self._client = None
        self.tcp_firmware.reset_link()
        self._pending = [p for p in self._pending if p[1] != "tcp"]

    # -- loop -------------------------------------------------------------------------------
    def _send(self, channel: str, data: bytes) -> None:
        try:
            if channel == "pty" and self._master >= 0:
                os.write(self._master, data)  # a full buffer raises BlockingIOError: dropped
            elif channel == "tcp" and self._client is not None:
                self._client.sendall(data)
        except OSError:
            pass

    def _queue_reply(self, channel: str, out: bytes) -> None:
        if not out:
            return
        delay = self.faults.take_delay()
        out = self.faults.filter_reply(out)
        out, unplug = self.faults.split_for_disconnect(out)
        self._pending.append((time.monotonic() + delay, channel, out, unplug))

    def _run(self) -> None:
        """Serve until stopped; an error in one round drops that round's link state (the TCP
        client is disconnected, the terminal's partial line forgotten), never the thread."""
        while not self._stop.is_set():
            try:
                self._serve_once()
            except Exception:
                self._drop_client()
                self.firmware.reset_link()

    def _serve_once(self) -> None:
        """One round: read what arrived, run the firmware, send the replies that are due."""
        now = time.monotonic()
        if self._master < 0 and now >= self._down_until:
            self._open_pty()
        fds: list = []
        if self._master >= 0:
            fds.append(self._master)
        if self._client is not None:  # before the listener: a client's EOF is seen first
            fds.append(self._client)
        if self._lsock is not None:
            fds.append(self._lsock)
        busy = self.firmware.busy() or self.tcp_firmware.busy() or bool(self._pending)
        try:
            readable, _, _ = select.select(fds, [], [], 0.002 if busy else 0.02)
        except (OSError, ValueError):
            readable = []
        for fd in readable:
            if fd is self._lsock:
                self._accept()
            elif fd is self._client:
                try:
                    data = self._client.recv(4096)
                except OSError:
                    data = b""
                if not data:
                    self._drop_client()
                else:
                    self.tcp_firmware.receive(data)
            elif fd == self._master:
                try:
                    data = os.read(self._master, 4096)
                except OSError:
                    data = b""
                if data:
                    self.firmware.receive(data)
        self._queue_reply("pty", self.firmware.step())
        self._queue_reply("tcp", self.tcp_firmware.step())
        now = time.monotonic()
        keep = []
        for item in self._pending:
            due, channel, data, unplug = item
            if due <= now:
                self._send(channel, data)
                if unplug:
                    self.unplug()
                    keep = []
                    break
            else:
                keep.append(item)
        self._pending = keep if self._master >= 0 or self._client else []
