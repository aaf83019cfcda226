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


@pytest.fixture
def motor(clock, transport):
    """(emulator, axis) for the generic profile on either transport; both stopped at the end."""
    emu = ModbusMotorEmulator("generic", clock=clock)
    url = _start(emu, transport)
    axis = ModbusAxis("stage", make_client(url, timeout_s=0.1, retries=0), "generic",
                      limits_deg=(-180.0, 180.0), velocity_deg_s=90.0, accel_deg_s2=180.0, clock=clock)
    try:
        axis.connect()
        yield emu, axis
    finally:
        axis.close()
        emu.stop()


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
                                                        "accel_unit"}
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
    # AZ direct data: data no. 0, type 1 (absolute), 250 steps, 250 Hz, 500 Hz/s ×2, 100.0 %, trigger 1.
    ("oriental_az_direct", "01 10 00 58 00 10 20 00 00 00 00 00 00 00 01 00 00 00 FA 00 00 00 FA "
                           "00 00 01 F4 00 00 01 F4 00 00 03 E8 00 00 00 01"),
    # Leadshine PR0: mode 1, 2500 pulses, 15 rpm, 33333 ms per 1000 rpm (30 rpm/s) ×2, delay 0, trigger 0x10.
    ("leadshine_pr", "01 10 62 00 00 08 10 00 01 00 00 09 C4 00 0F 82 35 82 35 00 00 00 10"),
])
def test_move_request_bytes_per_profile(clock, profile, request_hex):
    emu = ModbusMotorEmulator(profile, clock=clock)
    url = f"rtu://{emu.start_rtu()}?baudrate=115200"
    axis = ModbusAxis("s", make_client(url, timeout_s=0.2, retries=0), profile, limits_deg=(-180.0, 180.0),
                      velocity_deg_s=90.0, accel_deg_s2=180.0, clock=clock)
    try:
        axis.connect()
        n = len(emu.requests)
        axis.move_to(90.0)
        frame = emu.requests[n]
        assert frame[:-2] == bytes.fromhex(request_hex)  # RTU: the CRC follows
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


def test_tcp_disconnect_then_reconnect(clock):
    emu = ModbusMotorEmulator("generic", clock=clock)
    url = _start(emu, "tcp")
    axis = ModbusAxis("s", make_client(url, timeout_s=0.2, retries=0), "generic", limits_deg=(0.0, 90.0),
                      clock=clock)
    try:
        axis.connect()
        emu.faults.add("disconnect")
        try:
            axis.position_deg()  # the server drops the connection instead of answering
        except ModbusCommError as exc:
            assert exc.transient
        assert emu.faults.applied == [("disconnect", 3)]
        assert axis.position_deg() == 0.0  # reconnected
    finally:
        axis.close()
        emu.stop()


def test_rtu_cable_pulled_then_replugged(clock):
    """RTU over a pty that closes under the client: every call fails as a transient 'connection lost'
    naming the port while it is gone; after a replug the next call reconnects and reads."""
    emu = ModbusMotorEmulator("generic", clock=clock)
    url = _start(emu, "rtu")
    axis = ModbusAxis("s", make_client(url, timeout_s=0.1, retries=0), "generic", limits_deg=(0.0, 90.0),
                      clock=clock)
    try:
        axis.connect()
        emu.faults.add("disconnect")
        for _ in range(2):
            with pytest.raises(ModbusCommError, match=r"connection lost .*ttyMB") as err:
                axis.position_deg()
            assert err.value.transient
        emu.replug()
        assert axis.position_deg() == 0.0
        assert [kind for kind, _ in emu.faults.applied] == ["disconnect"]
    finally:
        axis.close()
        emu.stop()
