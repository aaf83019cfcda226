"""The table-driven Modbus axis through the real pymodbus client against the emulated controller (pymodbus
server on 127.0.0.1 TCP and RTU over a pty): request bytes per profile, moves, and each injected fault."""

from __future__ import annotations

import tomllib
from importlib import resources

import pytest

from gonio.drivers.modbus import (
    PROFILES,
    ModbusAlarmError,
    ModbusAxis,
    ModbusCommError,
    ModbusExceptionError,
    load_profile,
    make_client,
    parse_profile,
)
from gonio.protocols import Axis
from gonio.sim.emulators.modbus import ModbusMotorEmulator


@pytest.fixture(params=["tcp", "rtu"])
def transport(request):
    return request.param


def _start(emu, transport):
    if transport == "tcp":
        host, port = emu.start_tcp()
        return f"tcp://{host}:{port}"
    return f"rtu://{emu.start_rtu()}?baudrate=115200"


#: The reply time-out of a test that waits one out (a dropped, truncated, late reply; a lost link): short,
#: since the test's run time includes it.
EXPIRES_S = 0.1


@pytest.fixture
def reply_timeout_s():
    """The client's reply time-out where the test waits for none to expire: a margin over what a loaded
    host holds back an in-process emulator's reply (its server thread waits for a core and then for the
    interpreter lock: 0.2 s seen at load 2-3); it costs nothing, since no reply is waited out. A test
    that waits one out sets it to :data:`EXPIRES_S` (``pytest.mark.parametrize``)."""
    return 2.0


@pytest.fixture
def motor(clock, transport, reply_timeout_s):
    """(emulator, axis) for the generic profile on either transport; both stopped at the end."""
    emu = ModbusMotorEmulator("generic", clock=clock)
    url = _start(emu, transport)
    axis = ModbusAxis("stage", make_client(url, timeout_s=reply_timeout_s, retries=0), "generic",
                      limits_deg=(-180.0, 180.0), velocity_deg_s=90.0, accel_deg_s2=180.0, clock=clock)
    try:
        axis.connect()
        yield emu, axis
    finally:
        axis.close()
        emu.stop()
    assert emu.error is None, f"the emulator's thread died of {emu.error!r}"


def test_profiles_load_and_validate():
    for name in PROFILES:
        p = load_profile(name)
        assert p.move_block[0] in p.registers
    assert load_profile("oriental_az_direct").block_start == 0x0058
    assert load_profile("leadshine_pr").block_start == 0x6200
    assert "status" in load_profile("leadshine_pr").secondary
    # Every name a shipped profile marks as secondary is one of its fields; a misspelt one is refused.
    for name in PROFILES:
        p = load_profile(name)
        assert set(p.secondary) <= set(p.registers) | {"status bits", "stop", "alarm_reset", "move",
                                                        "word_order", "steps_per_rev", "velocity_unit",
                                                        "accel_unit", "span_read", "write_read",
                                                        "origin", "absolute"}
    typo = tomllib.loads(resources.files("gonio.drivers.modbus").joinpath(
        "profiles/leadshine_pr.toml").read_text())
    typo["secondary"] = ["staus"]
    with pytest.raises(ValueError, match=r"secondary names 'staus': not a register"):
        parse_profile(typo)
    bad = {"registers": {"status": {"address": 1, "type": "u8"}}}
    with pytest.raises(ValueError, match=r"registers.status.type 'u8' is not one of"):
        parse_profile(bad)


def test_word_order_and_sign():
    reg = load_profile("generic")["target_position"]
    assert reg.encode(-2, "big") == [0xFFFF, 0xFFFE]
    assert reg.encode(0x12345, "little") == [0x2345, 0x0001]
    assert reg.decode([0xFFFF, 0xFFFE], "big") == -2
    with pytest.raises(ValueError, match="outside"):
        reg.encode(1 << 31, "big")


def test_constructor_does_no_io_and_satisfies_axis():
    axis = ModbusAxis("s", make_client("tcp://127.0.0.1:1"), "generic", limits_deg=(0.0, 90.0))
    assert isinstance(axis, Axis)
    with pytest.raises(ValueError, match=r"axis 's': target 91.0° is outside the limit \[0°, 90°\]"):
        axis.steps_for(91.0)


def test_move_waits_for_moving_bit_and_reaches_target(motor, clock):
    emu, axis = motor
    axis.move_to(90.0)
    assert axis.is_moving()  # the move had started when move_to returned
    clock.sleep(0.5)
    assert 0.0 < axis.position_deg() < 90.0
    clock.sleep(5.0)
    assert not axis.is_moving()
    assert axis.position_deg() == 90.0
    assert emu.position_steps() == 2500


@pytest.mark.parametrize("profile, request_hex", [
    # FC16 at 0x0100, 9 registers: target 2500 steps, 2500 steps/s, 5000 steps/s² (twice), trigger 1.
    ("generic", "01 10 01 00 00 09 12 00 00 09 C4 00 00 09 C4 00 00 13 88 00 00 13 88 00 01"),
    # AZ direct data: data no. 0, type 1 (absolute), 250 steps, 250 Hz, 500 Hz/s ×2, 100.0 %, trigger 1,
    # written with function 23 that reads the status (0x007F, 1 register) back; over RTU the status and
    # the position (0x00CC) are not read in one span: its 150 extra bytes cost more than a second read.
    ("oriental_az_direct", "01 17 00 7F 00 01 00 58 00 10 20 00 00 00 00 00 00 00 01 00 00 00 FA 00 00 00 FA "
                           "00 00 01 F4 00 00 01 F4 00 00 03 E8 00 00 00 01"),
    # Leadshine PR0: mode 1, 2500 pulses, 15 rpm, 33333 ms per 1000 rpm (30 rpm/s) ×2, delay 0, trigger 0x10.
    ("leadshine_pr", "01 10 62 00 00 08 10 00 01 00 00 09 C4 00 0F 82 35 82 35 00 00 00 10"),
])
def test_move_request_bytes_per_profile(clock, profile, request_hex):
    emu = ModbusMotorEmulator(profile, clock=clock)
    emu.assume_referenced()  # the Leadshine drive is incremental: an axis on it moves once referenced
    url = f"rtu://{emu.start_rtu()}?baudrate=115200"
    axis = ModbusAxis("s", make_client(url, timeout_s=2.0, retries=0), profile, limits_deg=(-180.0, 180.0),
                      velocity_deg_s=90.0, accel_deg_s2=180.0, clock=clock)
    try:
        axis.connect()
        n = len(emu.requests)
        axis.move_to(90.0)
        frame = emu.requests[n]
        assert frame[:-2] == bytes.fromhex(request_hex)  # RTU: the CRC follows
        assert len(emu.requests) - n == 1 + (not axis.profile.write_read)  # the start check's read
        assert axis.is_moving()
    finally:
        axis.close()
        emu.stop()


def test_exception_response_is_typed_with_its_code(motor):
    emu, axis = motor
    emu.fail_next(2)
    with pytest.raises(ModbusExceptionError) as err:
        axis.position_deg()
    assert err.value.code == 2 and not err.value.transient
    emu.fail_next(6)  # device busy: may be retried
    with pytest.raises(ModbusExceptionError) as err:
        axis.position_deg()
    assert err.value.code == 6 and err.value.transient
    assert axis.position_deg() == 0.0


def test_alarm_latches_stops_motor_and_resets_on_request(motor, clock):
    emu, axis = motor
    axis.move_to(90.0)
    clock.sleep(0.5)
    emu.raise_alarm(0x30)
    with pytest.raises(ModbusAlarmError) as err:
        axis.is_moving()
    assert err.value.alarm_code == 0x30 and not err.value.transient
    assert axis.fault() == "controller alarm 0x0030"
    stopped = axis.position_deg()
    with pytest.raises(ModbusAlarmError, match="latched"):
        axis.move_to(0.0)
    clock.sleep(1.0)
    assert axis.position_deg() == stopped
    axis.clear_fault()
    assert axis.fault() is None and emu.alarm_code == 0


@pytest.mark.parametrize("kind", ["drop", "corrupt", "truncate"])
@pytest.mark.parametrize("reply_timeout_s", [EXPIRES_S])
def test_bad_reply_is_a_transient_error_and_the_next_call_works(motor, kind, transport):
    if kind == "corrupt" and transport == "tcp":
        pytest.skip("Modbus TCP frames carry no checksum: a flipped data byte cannot be detected")
    emu, axis = motor
    emu.faults.add(kind)
    with pytest.raises(ModbusCommError) as err:
        axis.position_deg()
    assert err.value.transient
    assert axis.position_deg() == 0.0


def test_stop_holds_position(motor, clock):
    emu, axis = motor
    axis.move_to(90.0)
    clock.sleep(0.5)
    axis.stop()
    held = axis.position_deg()
    clock.sleep(2.0)
    assert axis.position_deg() == held and not axis.is_moving()


@pytest.mark.parametrize("transport", ["tcp"])
@pytest.mark.parametrize("reply_timeout_s", [EXPIRES_S])
def test_tcp_disconnect_then_reconnect(motor):
    emu, axis = motor
    emu.faults.add("disconnect")
    try:
        axis.position_deg()  # the server drops the connection instead of answering
    except ModbusCommError as exc:
        assert exc.transient
    assert emu.faults.applied == [("disconnect", 3)]
    assert axis.position_deg() == 0.0  # reconnected


@pytest.mark.parametrize("transport", ["rtu"])
@pytest.mark.parametrize("reply_timeout_s", [EXPIRES_S])
def test_rtu_cable_pulled_then_replugged(motor):
    """RTU over a pty that closes under the client: every call fails as a transient 'connection lost'
    naming the port while it is gone; after a replug the next call reconnects and reads."""
    emu, axis = motor
    emu.faults.add("disconnect")
    for _ in range(2):
        with pytest.raises(ModbusCommError, match=r"connection lost .*ttyMB") as err:
            axis.position_deg()
        assert err.value.transient
    emu.replug()
    assert axis.position_deg() == 0.0
    assert [kind for kind, _ in emu.faults.applied] == ["disconnect"]


def test_span_read_and_write_read_flags_are_validated():
    data = tomllib.loads(resources.files("gonio.drivers.modbus").joinpath(
        "profiles/leadshine_pr.toml").read_text())
    data["span_read"] = "yes"
    with pytest.raises(ValueError, match=r"span_read 'yes' is not one of true, false"):
        parse_profile(data)
    data["span_read"] = True  # status 0x1003, position 0x602A: far more than one read may ask for
    with pytest.raises(ValueError, match=r"span_read: status \(0x1003\) and actual_position \(0x602a\) "
                                         r"span 20521 registers, more than one read may ask for \(125\)"):
        parse_profile(data)
    p = load_profile("oriental_az_direct")
    assert (p.span_read, p.write_read, p.state_block) == (True, True, (0x007F, 0x4F))
    assert load_profile("generic").state_block == (0x0110, 3)  # adjacent: always one read
    assert load_profile("leadshine_pr").state_block is None


@pytest.fixture
def az(clock, reply_timeout_s):
    """(emulator, axis): an Oriental AZ profile over TCP, 36:1 (100 steps per degree)."""
    emu = ModbusMotorEmulator("oriental_az_direct", clock=clock)
    host, port = emu.start_tcp()
    axis = ModbusAxis("tilt", make_client(f"tcp://{host}:{port}", timeout_s=reply_timeout_s, retries=0),
                      "oriental_az_direct", limits_deg=(-175.0, 175.0), gear_ratio=36.0, velocity_deg_s=45.0,
                      accel_deg_s2=90.0, clock=clock)
    try:
        yield emu, axis
    finally:
        axis.close()
        emu.stop()


def _pdus(emu, since):
    """The request PDUs (function code onwards) the TCP emulator got since index ``since``; each
    frame's unit id (MBAP byte 6) must be 1."""
    frames = emu.requests[since:]
    assert all(f[6] == 1 for f in frames)
    return [f[7:] for f in frames]


def test_one_read_spans_status_and_position_on_the_wire_and_decodes_both(az, clock):
    emu, axis = az
    axis.connect()
    emu.set_position(-17000)  # -170°: 0xFFFF 0xBD98 across the two words, high word first
    n = len(emu.requests)
    assert axis.read_state() == (-170.0, False)
    # FC3 from 0x007F (status) through 0x00CD (the position's low word): 79 registers, one request.
    assert _pdus(emu, n) == [bytes.fromhex("03 00 7F 00 4F")]
    n = len(emu.requests)
    axis.move_to(0.0)
    # One request for the move and its start check: FC23 reading the same span, writing the block at
    # 0x0058 (16 registers: target 0, 4500 Hz, 9000 Hz/s twice...).
    (pdu,) = _pdus(emu, n)
    assert pdu[:10] == bytes.fromhex("17 00 7F 00 4F 00 58 00 10 20")
    assert pdu[10:] == b"".join(w.to_bytes(2, "big") for w in (0, 0, 0, 1, 0, 0, 0, 4500, 0, 9000, 0, 9000,
                                                                0, 1000, 0, 1))
    clock.sleep(1.0)
    pos, moving = axis.read_state()
    assert moving and -170.0 < pos < 0.0 and pos == emu.position_steps() / 100.0
    emu.raise_alarm(0x30)  # the span carries the status word: the alarm bit raises, code read after it
    with pytest.raises(ModbusAlarmError) as err:
        axis.read_state()
    assert err.value.alarm_code == 0x30 and err.value.device == "tilt"
    assert _pdus(emu, len(emu.requests) - 2) == [bytes.fromhex("03 00 7F 00 4F"),
                                                  bytes.fromhex("03 00 81 00 01")]


def test_a_unit_that_refuses_the_span_is_read_in_two_from_then_on(az, clock):
    emu, axis = az
    emu.refuse_gaps = True  # exception 2 for a read touching a register the profile does not name
    n = len(emu.requests)
    axis.connect()  # tries the span once, then reads the status alone
    assert axis.span_refused and axis.state_block is None and not axis.state_in_one_read
    assert _pdus(emu, n) == [bytes.fromhex("03 00 7F 00 4F"), bytes.fromhex("03 00 7F 00 01")]
    emu.set_position(12345)
    n = len(emu.requests)
    assert axis.read_state() == (123.45, False)
    axis.move_to(-10.0)  # FC23 reads the status alone
    assert _pdus(emu, n)[:2] == [bytes.fromhex("03 00 7F 00 01"), bytes.fromhex("03 00 CC 00 02")]
    assert _pdus(emu, n)[2][:10] == bytes.fromhex("17 00 7F 00 01 00 58 00 10 20")
    assert len(emu.requests) == n + 3 and axis.is_moving()


def test_a_unit_without_function_23_gets_the_block_by_function_16(az, clock):
    emu, axis = az
    axis.connect()
    emu.fail_next(1)  # illegal function: the unit does not do 23 (and wrote nothing)
    n = len(emu.requests)
    axis.move_to(10.0)
    assert axis.write_read_refused and axis.is_moving()
    assert [p[:1] for p in _pdus(emu, n)] == [b"\x17", b"\x10", b"\x03", b"\x03"]  # 23, 16, start, is_moving
    clock.sleep(10.0)
    n = len(emu.requests)
    axis.move_to(0.0)  # not asked again
    assert [p[:1] for p in _pdus(emu, n)] == [b"\x10", b"\x03"]
    emu.fail_next(3)  # any other exception to function 23 is the move's failure, as before
    axis.write_read_refused = False
    with pytest.raises(ModbusExceptionError, match=r"tilt: write move block at 0x0058 and read 79 at 0x007f "
                                                   r"\(function 23\): exception response, code 3"):
        axis.move_to(5.0)


@pytest.mark.parametrize("reply_timeout_s", [EXPIRES_S])
def test_a_late_reply_is_never_taken_for_another_request(motor, transport):
    """A status read's reply comes after its time-out, just before the reply to the next request (a stop).
    TCP: pymodbus skips it by its transaction id. RTU: pymodbus takes it (the first frame from the unit);
    the driver sees it is a read's reply, not the write's, discards it, and asks again."""
    emu, axis = motor
    emu.faults.add("late", match=3)
    with pytest.raises(ModbusCommError, match="No response"):
        axis.is_moving()
    axis.stop()
    assert ("late", 3) in emu.faults.applied and emu.deferred.pending() == 0
    assert axis.discarded == (1 if transport == "rtu" else 0)  # the stray frame
    assert axis.position_deg() == 0.0 and not axis.is_moving()


def test_a_stale_rtu_position_is_not_used(motor, clock):
    """On RTU nothing tells an earlier reply to the same read from this one: mid-move, the position read
    returns the sample of 0.4 s before (some 30° back), older than the last good read (the state, read
    since) and farther from it than the axis can have travelled: read again, the true position returned."""
    emu, axis = motor
    if emu.address is not None:
        pytest.skip("on TCP an earlier reply carries an earlier transaction id: pymodbus skips it")
    axis.move_to(170.0)
    clock.sleep(0.2)
    axis.position_deg()  # the earlier sample, kept by the emulator for this read
    clock.sleep(0.4)
    axis.read_state()  # the last good read: another request
    emu.faults.add("stale", match=3)
    got = axis.position_deg()
    assert got == pytest.approx(axis.deg_of_steps(emu.position_steps()), abs=0.05)
    assert axis.guard.rejected == 1
