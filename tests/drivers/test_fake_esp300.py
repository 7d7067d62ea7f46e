"""The ESP300 firmware emulator, served on a pty and TCP, driven by the real driver."""

from __future__ import annotations

import os
import time

import pytest
import serial
from gonio.drivers.errors import DeviceError, DeviceTimeout
from gonio.drivers.esp300 import ESP300
from gonio.drivers.fake.esp300 import ESP300Firmware, FakeESP300Server
from gonio.simulator.bench import Bench, Stage

AXES = {"a": 1, "b": 2, "c": 3}


def bench(scale: float = 200.0, **kw) -> Bench:
    return Bench(
        [Stage("a", lower=-10, upper=100, **kw), Stage("b"), Stage("c", units="mm")],
        time_scale=scale,
    )


def fw_run(fw: ESP300Firmware, line: bytes) -> bytes:
    fw.receive(line)
    return fw.step()


# -- firmware state machine (bytes in, bytes out) ---------------------------------------------
def test_firmware_queries_and_error_fifo():
    fw = ESP300Firmware(bench())
    assert fw_run(fw, b"VE?\r") == b"ESP300 Version 3.08 09/09/02\r\n"
    assert fw_run(fw, b"1TP\r\n") == b"0.00000\r\n"
    assert fw_run(fw, b"1MO?;2MO?\r") == b"0\r\n0\r\n"
    assert fw_run(fw, b"1PA5\r") == b""  # motor off: error 113
    assert fw_run(fw, b"XX\r") == b""  # unknown command: error 6
    assert fw_run(fw, b"4TP\r") == b""  # axis out of range: error 9
    assert fw_run(fw, b"TE?\r") == b"113\r\n"
    assert fw_run(fw, b"TB?\r").split(b", ")[::2] == [b"6", b"COMMAND DOES NOT EXIST\r\n"]
    assert fw_run(fw, b"TB?\r").endswith(b"AXIS NUMBER OUT OF RANGE\r\n")
    assert fw_run(fw, b"TE?\r") == b"0\r\n"
    assert fw_run(fw, b"3SN?;1SN?\r") == b"2\r\n7\r\n"


def test_firmware_split_and_joined_input():
    fw = ESP300Firmware(bench())
    fw.receive(b"1T")
    assert fw.step() == b""
    fw.receive(b"P\r\n2TP\r")
    assert fw.step() == b"0.00000\r\n0.00000\r\n"


def test_firmware_move_software_limits_and_ws_hold():
    b = bench(scale=50.0)
    fw = ESP300Firmware(b)
    fw_run(fw, b"1MO\r")
    assert fw_run(fw, b"1PA150\r") == b""
    assert fw_run(fw, b"TE?\r") == b"106\r\n"  # beyond SR: positive software limit
    fw_run(fw, b"1PA20;1WS;1MD?\r")
    assert fw.step() == b""  # held by WS while moving
    assert fw.busy()
    deadline = time.monotonic() + 2.0
    out = b""
    while not out and time.monotonic() < deadline:
        time.sleep(0.005)
        out = fw.step()
    assert out == b"1\r\n"
    assert fw_run(fw, b"1TP\r") == b"20.00000\r\n"


# -- driver over the pty and TCP --------------------------------------------------------------
@pytest.fixture
def server():
    with FakeESP300Server(bench(), tcp=True) as srv:
        yield srv


def test_pty_path_opens_with_plain_pyserial(server):
    with serial.Serial(server.port, 19200, timeout=1.0) as port:
        port.write(b"VE?\r\n")
        assert port.readline() == b"ESP300 Version 3.08 09/09/02\r\n"


def test_full_move_sequence_over_pty(server):
    esp = ESP300.open(server.port, axes=AXES, timeout=1.0)
    try:
        assert esp.version().startswith("ESP300")
        esp.enable()
        a = esp.axis("a")
        assert a.units == "deg" and esp.axis("c").units == "mm"
        a.velocity = 1  # a 30 s move, 0.15 s of the bench's 200-times clock: still moving
        assert a.velocity == 1.0  # when asked on a loaded machine (at 50: 3 ms)
        a.move_to(30)
        assert a.is_moving()
        a.velocity = 50  # (the rest quicker)
        assert a.wait(5.0) == pytest.approx(30.0)
        a.move_by(-5)
        assert a.wait(5.0) == pytest.approx(25.0)
        assert server.bench.positions()["a"] == pytest.approx(25.0)
        a.define_home(0)
        assert a.position() == 0.0
        a.move_to(10)
        a.wait(5.0)
        a.home()
        assert a.wait(5.0) == 0.0
        assert a.limits() == (-10.0, 100.0)
    finally:
        esp.close()


def test_tcp_and_pty_reach_the_same_stages(server):
    pty = ESP300.open(server.port, axes=AXES)
    tcp = ESP300.open(server.url, axes=AXES)
    pty.axis("b").motor_on()
    pty.axis("b").move_to(12)
    pty.axis("b").wait(5)
    assert tcp.axis("b").position() == pytest.approx(12.0)
    pty.close()
    tcp.close()


def test_query_round_trip_time_over_pty(server):
    esp = ESP300.open(server.port, axes=AXES)
    esp.axis("a").position()
    n = 50
    t0 = time.perf_counter()
    for _ in range(n):
        esp.axis("a").position()
    rtt = (time.perf_counter() - t0) / n
    esp.close()
    assert rtt < 0.05


def test_backlash_and_noise_show_in_bench_not_encoder():
    b = Bench([Stage("a", lower=-90, upper=90, backlash=0.2, noise=0.0)], time_scale=500)
    with FakeESP300Server(b, axes=["a"]) as srv:
        esp = ESP300.open(srv.port, axes={"a": 1})
        a = esp.axis("a")
        a.motor_on()
        a.move_to(10)
        assert a.wait(5) == pytest.approx(10.0)
        up = b.positions()["a"]
        a.move_to(20)
        a.wait(5)
        a.move_to(10)
        assert a.wait(5) == pytest.approx(10.0)  # the encoder sees no backlash
        down = b.positions()["a"]
        assert down - up == pytest.approx(0.2)  # approaching from above: load lags by 0.2
        esp.close()


# -- faults -----------------------------------------------------------------------------------
def test_dropped_reply_bytes_recovered_by_retry(server):
    esp = ESP300.open(server.port, axes=AXES, timeout=0.2)
    server.faults.drop_reply_bytes = 3  # loses the line terminator of the first reply
    assert esp.axis("a").position() == 0.0
    assert any("dropped" in m for m in server.faults.log)
    esp.close()


def test_corrupted_reply_bytes_recovered_by_retry(server):
    esp = ESP300.open(server.port, axes=AXES, timeout=0.3)
    server.faults.corrupt_reply_bytes = 1
    assert esp.version() == "ESP300 Version 3.08 09/09/02"
    assert esp.axis("a").position() == 0.0  # and the stream is clean afterwards
    esp.close()


def test_corrupted_command_is_reported_by_the_controller(server):
    esp = ESP300.open(server.port, axes=AXES, timeout=0.3)
    server.faults.corrupt_command_bytes = 2  # "1MO" arrives as garbage
    with pytest.raises(DeviceError) as ei:
        esp.axis("a").motor_on()
    assert ei.value.command == "1MO" and "COMMAND DOES NOT EXIST" in str(ei.value)
    esp.axis("a").motor_on()  # next attempt goes through
    assert esp.axis("a").is_motor_on()
    esp.close()


def test_delayed_reply_beyond_timeout_is_not_taken_for_the_next_answer(server):
    esp = ESP300.open(server.port, axes=AXES, timeout=0.3)
    esp.axis("a").motor_on()
    esp.axis("a").move_to(5)
    esp.axis("a").wait(5)
    server.faults.reply_delay, server.faults.delayed_replies = 0.45, 1
    assert esp.axis("a").position() == pytest.approx(5.0)
    assert esp.axis("a").is_moving() is False  # a stale "5.00000" would fail to parse here
    esp.close()


def test_delay_everything_beyond_timeout_raises_device_timeout(server):
    esp = ESP300.open(server.port, axes=AXES, timeout=0.05, retries=1)
    server.faults.reply_delay, server.faults.delayed_replies = 0.5, -1
    with pytest.raises(DeviceTimeout) as ei:
        esp.axis("a").position()
    assert ei.value.device == "ESP300" and ei.value.command == "1TP"
    server.faults.delayed_replies = 0
    esp.close()


def test_motor_fault_during_move_then_recovery(server):
    esp = ESP300.open(server.port, axes=AXES)
    a = esp.axis("a")
    a.motor_on()
    a.velocity = 1  # 90 s simulated = 0.45 s real: the fault lands mid-move
    a.move_to(90)
    time.sleep(0.02)
    server.firmware.inject_motor_fault(1)
    with pytest.raises(DeviceError) as ei:
        a.wait(5)
    assert "102" in str(ei.value.reply) and "AMPLIFIER FAULT" in str(ei.value)
    assert not a.is_motor_on()
    stopped = a.position()
    assert 0 < stopped < 90
    a.motor_on()
    a.velocity = 50
    a.move_to(40)
    assert a.wait(5) == pytest.approx(40.0)
    esp.close()


def test_stall_at_hardware_limit_is_reported(server):
    esp = ESP300.open(server.port, axes=AXES)
    a = esp.axis("a")
    a.motor_on()
    server.firmware.inject_stall(1, 42.0)
    a.move_to(80)
    with pytest.raises(DeviceError) as ei:
        a.wait(5)
    assert "104" in str(ei.value.reply) and "POSITIVE HARDWARE LIMIT" in str(ei.value)
    assert a.position() == pytest.approx(42.0)
    esp.close()


def test_wait_timeout_stops_the_axis():
    with FakeESP300Server(bench(scale=1.0)) as srv:
        esp = ESP300.open(srv.port, axes=AXES, timeout=0.5)
        a = esp.axis("a")
        a.motor_on()
        a.velocity = 1.0
        a.move_to(90)
        t0 = time.monotonic()
        with pytest.raises(DeviceTimeout) as ei:
            a.wait(0.2)
        assert time.monotonic() - t0 < 1.5
        assert "still moving" in str(ei.value)
        p = a.position()
        time.sleep(0.1)
        assert a.position() == p  # ST stopped it
        esp.close()


def test_disconnect_mid_reply_over_tcp_reconnects(server):
    esp = ESP300.open(server.url, axes=AXES, timeout=0.3)
    server.faults.disconnect_after_bytes = 4
    assert esp.version() == "ESP300 Version 3.08 09/09/02"
    assert server.disconnects == 1
    esp.close()


def test_disconnect_mid_reply_over_pty_reconnects_by_link(tmp_path):
    link = str(tmp_path / "esp300")
    with FakeESP300Server(bench(), link=link) as srv:
        esp = ESP300.open(link, axes=AXES, timeout=0.3)
        first = srv.port
        srv.faults.disconnect_after_bytes = 3
        srv.faults.reconnect_after = 0.05
        time.sleep(0.01)
        assert esp.axis("a").position() == 0.0
        assert srv.disconnects == 1 and os.path.realpath(link) == srv.port
        assert srv.port == first or os.path.exists(srv.port)
        esp.close()


# -- TCP clients: per-connection state, explicit refusal (issue 15 item 8) --------------------
def _ask(sock, cmd: bytes, timeout: float = 2.0) -> bytes:

    sock.settimeout(timeout)
    sock.sendall(cmd)
    buf = b""
    try:
        while not buf.endswith(b"\r\n"):
            chunk = sock.recv(200)
            if not chunk:
                break
            buf += chunk
    except TimeoutError:
        pass
    return buf


def _wait_for(cond, timeout: float = 2.0) -> None:
    t0 = time.monotonic()
    while not cond() and time.monotonic() - t0 < timeout:
        time.sleep(0.01)


def test_tcp_client_state_does_not_leak_to_the_next_client():
    import socket

    with FakeESP300Server(bench(), tcp=True) as srv:
        a = socket.create_connection(("127.0.0.1", srv.tcp_port))
        a.sendall(b"1P")  # disconnect mid-line
        _wait_for(lambda: srv._client is not None)
        a.close()
        _wait_for(lambda: srv._client is None)
        b = socket.create_connection(("127.0.0.1", srv.tcp_port))
        assert _ask(b, b"VE?\r") == b"ESP300 Version 3.08 09/09/02\r\n"
        b.close()
        a = socket.create_connection(("127.0.0.1", srv.tcp_port))
        a.sendall(b"WS1e12\r")  # a wait that would hold the queue for ever
        _wait_for(lambda: srv.tcp_firmware._hold is not None)
        a.close()
        _wait_for(lambda: srv._client is None)
        b = socket.create_connection(("127.0.0.1", srv.tcp_port))
        t0 = time.monotonic()
        assert _ask(b, b"VE?\r") == b"ESP300 Version 3.08 09/09/02\r\n"
        assert time.monotonic() - t0 < 1.0
        b.close()


def test_concurrent_tcp_clients_are_served_or_refused_explicitly():
    import socket

    from gonio.drivers.fake.esp300 import BUSY_REPLY

    with FakeESP300Server(bench(), tcp=True) as srv:
        first = socket.create_connection(("127.0.0.1", srv.tcp_port))
        assert _ask(first, b"VE?\r").startswith(b"ESP300")
        others = [socket.create_connection(("127.0.0.1", srv.tcp_port)) for _ in range(40)]
        replies = [_ask(s, b"VE?\r") for s in others]
        assert replies == [BUSY_REPLY] * 40 and srv.refused == 40
        assert _ask(first, b"VE?\r").startswith(b"ESP300")  # the served client keeps its link
        for s in [first, *others]:
            s.close()


def test_link_over_an_existing_file_is_refused_and_the_file_kept(tmp_path):
    victim = tmp_path / "precious.txt"
    victim.write_text("keep me\n")
    with pytest.raises(ValueError, match="exists and is not a symlink"):
        FakeESP300Server(bench(), link=str(victim)).start()
    assert victim.read_text() == "keep me\n" and not victim.is_symlink()


def test_stop_removes_only_its_own_link(tmp_path):
    link = tmp_path / "esp"
    srv = FakeESP300Server(bench(), link=str(link)).start()
    os.unlink(link)
    os.symlink("/dev/null", link)  # someone else's link now
    srv.stop()
    assert os.readlink(link) == "/dev/null"


def test_tcp_port_in_use_names_the_port():
    import socket

    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen(1)
    port = busy.getsockname()[1]
    try:
        with pytest.raises(OSError, match=f"cannot listen on 127.0.0.1:{port}"):
            FakeESP300Server(bench(), tcp=port).start()
    finally:
        busy.close()
    with pytest.raises(ValueError, match=r"\[0, 65535\]"):
        FakeESP300Server(bench(), tcp=70000).start()


# -- issue 30, 6-7: any input, bounded buffers, a server that keeps serving --------------------
def test_a_5000_digit_axis_number_is_an_error_and_the_server_keeps_serving():
    import socket

    with FakeESP300Server(bench(), tcp=True) as srv:
        a = socket.create_connection(("127.0.0.1", srv.tcp_port))
        a.sendall(b"9" * 5000 + b"TP?\r")
        assert _ask(a, b"TE?\r") == b"6\r\n"  # the line answered: longer than MAX_LINE
        a.sendall(b"9" * 500 + b"TP?\r")
        assert _ask(a, b"TE?\r") == b"9\r\n"  # the command answered: axis out of range
        assert _ask(a, b"VE?\r").startswith(b"ESP300")
        a.close()
        b = socket.create_connection(("127.0.0.1", srv.tcp_port))
        assert _ask(b, b"1TP?\r").strip()  # and on a new connection
        b.close()


def test_an_exception_in_one_command_answers_it_and_serving_goes_on(monkeypatch):
    import socket

    with FakeESP300Server(bench(), tcp=True) as srv:
        real = ESP300Firmware._axis_command

        def broken(self, mn, *a):
            if mn == "ID":
                raise RuntimeError("firmware bug")
            return real(self, mn, *a)

        monkeypatch.setattr(ESP300Firmware, "_axis_command", broken)
        a = socket.create_connection(("127.0.0.1", srv.tcp_port))
        a.sendall(b"1ID?\r")
        assert _ask(a, b"TE?\r") == b"6\r\n"
        assert _ask(a, b"VE?\r").startswith(b"ESP300")
        a.close()


def test_the_input_buffer_is_bounded_on_a_line_without_a_terminator():
    from gonio.drivers.fake.esp300 import MAX_LINE, MAX_QUEUE

    fw = ESP300Firmware(bench())
    for _ in range(200):
        fw.receive(b"x" * 1000)  # 200 kB, no terminator
        assert len(fw._inbuf) <= MAX_LINE
    assert fw_run(fw, b"\rTE?\r") == b"6\r\n"  # the over-long line: error 6
    assert fw_run(fw, b"VE?\r").startswith(b"ESP300")
    fw.receive(b"WS1e12\r" + b"VE?;" * 5000 + b"\r")
    assert len(fw._queue) <= MAX_QUEUE


def test_a_line_in_one_byte_chunks_reads_as_one_chunk():
    """(Each chunk is searched for a terminator from where the last search ended.)"""
    fw = ESP300Firmware(bench())
    for b in b"1TP?;2TP?":
        fw.receive(bytes([b]))
    assert fw.step() == b""
    fw.receive(b"\r")
    assert fw_run(fw, b"") == fw_run(ESP300Firmware(bench()), b"1TP?;2TP?\r")
