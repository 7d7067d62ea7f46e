"""Exact bytes of every ESP300 driver command against a scripted transport."""

from __future__ import annotations

import pytest
from gonio.drivers.errors import DeviceDisconnected, DeviceError, DeviceTimeout
from gonio.drivers.esp300 import ESP300, format_number
from gonio.drivers.testing import ScriptedLineTransport, ScriptError
from gonio.drivers.transport import TransportDisconnected

OK = (b"TB?\r\n", b"0, 1234, NO ERROR DETECTED\r\n")


def make(script, **kw):
    t = ScriptedLineTransport(script)
    kw.setdefault("units", {"1": "deg", "2": "deg", "3": "mm"})
    return ESP300(t, **kw), t


@pytest.mark.parametrize(
    ("call", "script", "result"),
    [
        (
            lambda e: e.version(),
            [(b"VE?\r\n", b"ESP300 Version 3.08 09/09/02\r\n")],
            "ESP300 Version 3.08 09/09/02",
        ),
        (lambda e: e.error_code(), [(b"TE?\r\n", b"0\r\n")], 0),
        (
            lambda e: e.error(),
            [(b"TB?\r\n", b"108, 5678, MOTOR / STAGE NOT CONNECTED\r\n")],
            (108, 5678, "MOTOR / STAGE NOT CONNECTED"),
        ),
        (lambda e: e.axis("1").position(), [(b"1TP\r\n", b"12.34500\r\n")], 12.345),
        (lambda e: e.axis("2").is_moving(), [(b"2MD?\r\n", b"0\r\n")], True),
        (lambda e: e.axis("2").is_moving(), [(b"2MD?\r\n", b"1\r\n")], False),
        (lambda e: e.axis("3").is_motor_on(), [(b"3MO?\r\n", b"1\r\n")], True),
        (
            lambda e: e.axis("1").limits(),
            [(b"1SL?\r\n", b"-5.00000\r\n"), (b"1SR?\r\n", b"95.00000\r\n")],
            (-5.0, 95.0),
        ),
        (lambda e: e.axis("1").velocity, [(b"1VA?\r\n", b"10.00000\r\n")], 10.0),
        (lambda e: e.axis("1").acceleration, [(b"1AC?\r\n", b"40.00000\r\n")], 40.0),
        (
            lambda e: e.axis("1").identify(),
            [(b"1ID?\r\n", b"URS100BPP, B11111\r\n")],
            "URS100BPP, B11111",
        ),
    ],
)
def test_queries(call, script, result):
    esp, t = make(script)
    assert call(esp) == result
    t.assert_done()


@pytest.mark.parametrize(
    ("call", "sent"),
    [
        (lambda e: e.axis("1").move_to(10.0), b"1PA10\r\n"),
        (lambda e: e.axis("2").move_to(-12.5), b"2PA-12.5\r\n"),
        (lambda e: e.axis("3").move_by(0.125), b"3PR0.125\r\n"),
        (lambda e: e.axis("1").motor_on(), b"1MO\r\n"),
        (lambda e: e.axis("1").motor_off(), b"1MF\r\n"),
        (lambda e: e.axis("1").home(), b"1OR\r\n"),
        (lambda e: e.axis("1").define_home(), b"1DH0\r\n"),
        (lambda e: e.axis("2").define_home(3.5), b"2DH3.5\r\n"),
        (lambda e: setattr(e.axis("1"), "velocity", 20), b"1VA20\r\n"),
        (lambda e: setattr(e.axis("1"), "acceleration", 80.25), b"1AC80.25\r\n"),
        (lambda e: e.axis("1").stop(), b"1ST\r\n"),
    ],
)
def test_commands_then_error_check(call, sent):
    esp, t = make([(sent, None), OK])
    call(esp)
    t.assert_done()


def test_set_limits_sends_sl_and_sr():
    esp, t = make([(b"1SL-10\r\n", None), OK, (b"1SR170\r\n", None), OK])
    esp.axis("1").set_limits(-10, 170)
    t.assert_done()


def test_enable_disable_every_axis():
    esp, t = make(
        [
            (b"1MO\r\n", None),
            OK,
            (b"2MO\r\n", None),
            OK,
            (b"3MO\r\n", None),
            OK,
            (b"1MF\r\n", None),
            OK,
            (b"2MF\r\n", None),
            OK,
            (b"3MF\r\n", None),
            OK,
        ]
    )
    esp.enable()
    esp.disable()
    t.assert_done()


def test_wait_uses_ws_then_md_then_reads_position():
    esp, t = make([(b"1WS\r\n", None), (b"1MD?\r\n", b"1\r\n"), OK, (b"1TP\r\n", b"45.00000\r\n")])
    assert esp.axis("1").wait(timeout=1.0) == 45.0
    t.assert_done()


def test_units_queried_with_sn_when_not_given():
    t = ScriptedLineTransport([(b"1SN?\r\n", b"7\r\n"), (b"3SN?\r\n", b"2\r\n")])
    esp = ESP300(t)
    assert esp.axis("1").units == "deg"
    assert esp.axis("1").units == "deg"  # cached: no second query
    assert esp.axis("3").units == "mm"
    t.assert_done()


def test_controller_error_raises_device_error_naming_command_and_reply():
    esp, t = make(
        [(b"1PA200\r\n", None), (b"TB?\r\n", b"106, 99, POSITIVE SOFTWARE LIMIT DETECTED\r\n")]
    )
    with pytest.raises(DeviceError) as ei:
        esp.axis("1").move_to(200)
    err = ei.value
    assert err.device == "ESP300" and err.command == "1PA200"
    assert "106" in str(err.reply) and "POSITIVE SOFTWARE LIMIT" in str(err)
    t.assert_done()


def test_garbled_reply_is_retried_after_flushing_input():
    esp, t = make([(b"1TP\r\n", b"1\xb2.0\r\n"), (b"1TP\r\n", b"12.00000\r\n")])
    assert esp.axis("1").position() == 12.0
    assert t.flushes == 1
    t.assert_done()


def test_timeout_is_retried_then_raises_device_timeout():
    esp, t = make([(b"1TP\r\n", None)] * 3)
    with pytest.raises(DeviceTimeout) as ei:
        esp.axis("1").position()
    assert ei.value.command == "1TP"
    t.assert_done()


def test_disconnect_reconnects_and_resends_idempotent_query():
    esp, t = make([(b"1TP\r\n", TransportDisconnected("gone")), (b"1TP\r\n", b"3.00000\r\n")])
    assert esp.axis("1").position() == 3.0
    assert t.reconnects == 1
    t.assert_done()


def test_relative_move_is_not_resent_after_disconnect():
    t = ScriptedLineTransport([(b"1PR5\r\n", None)])

    def write(data, _orig=t.write):
        _orig(data)
        raise TransportDisconnected("cable pulled")

    t.write = write  # type: ignore[method-assign]
    esp = ESP300(t, units={"1": "deg"}, axes={"1": 1})
    with pytest.raises(DeviceDisconnected) as ei:
        esp.axis("1").move_by(5)
    assert "not resending" in str(ei.value)
    assert t.reconnects == 1
    t.assert_done()


def test_scripted_transport_catches_leftovers_and_wrong_bytes():
    esp, t = make([(b"VE?\r\n", b"ESP300\r\n"), (b"TE?\r\n", b"0\r\n")])
    esp.version()
    with pytest.raises(ScriptError):
        t.assert_done()
    with pytest.raises(ScriptError):
        esp.axis("1").position()


def test_bad_arguments_raise_value_error():
    esp, _ = make([])
    with pytest.raises(ValueError, match="axes"):
        ESP300(ScriptedLineTransport([]), axes={"x": 4})
    with pytest.raises(ValueError, match="name"):
        esp.axis("nope")
    with pytest.raises(ValueError, match="value"):
        format_number(float("nan"))
    with pytest.raises(ValueError, match="low"):
        esp.axis("1").set_limits(5, 1)


def test_format_number():
    assert format_number(0.0) == "0"
    assert format_number(-0.0000001) == "0"
    assert format_number(1e-6) == "0.000001"
    assert format_number(123456.5) == "123456.5"
