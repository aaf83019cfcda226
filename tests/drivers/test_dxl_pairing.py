"""Replies that cannot lie, on a Dynamixel bus: the real dynamixel-sdk against the emulated bus with late,
duplicated, reordered, truncated and stale replies injected. A reply is taken only from a servo that was
asked, once, with the length asked for; a read that waits for a reply is never of a length a late reply
could have; every position is checked against what the axis can have travelled; a stop writes no goal
that comes from a reply that cannot be trusted."""

from __future__ import annotations

import dynamixel_sdk as sdk
import pytest

from gonio.drivers.dynamixel import XM430, DynamixelAxis, DynamixelBus, DynamixelCommError, DynamixelGroup
from gonio.sim.emulators.dxl_packet import Inst, PacketReader
from gonio.sim.emulators.gantry import EMULATOR_LATENCY_MS


@pytest.fixture
def bus(dxl_emu):
    # No retries, so a reply the emulator's thread is late with on a loaded host fails the read: it is
    # allowed the emulated gantry's reply time (a late fault is released by the next request, not a timer)
    b = DynamixelBus(dxl_emu.port, name="dxl0", retries=0, latency_timer_ms=EMULATOR_LATENCY_MS)
    b.connect()
    try:
        yield b
    finally:
        b.close()


@pytest.fixture
def pair(dxl_emu, clock):
    """Axes 'a' (ID 1) and 'b' (ID 2) centred on tick 2048, 90 °/s, connected."""
    bus = DynamixelBus(dxl_emu.port, name="dxl0")
    axes = [DynamixelAxis(n, bus, i, limits_deg=(-90.0, 90.0), homing_offset_ticks=2048, velocity_deg_s=90.0,
                          accel_deg_s2=180.0, watchdog_s=0.0, clock=clock) for n, i in (("a", 1), ("b", 2))]
    for a in axes:
        a.connect()
    try:
        yield axes
    finally:
        for a in axes:
            a.close()


def _room(name):
    f = XM430[name]
    return XM430.room(f.address, f.size)


def test_a_late_reply_is_discarded_where_the_sdk_alone_takes_it_for_the_next_answer(bus, dxl_emu):
    """The temperature reply comes after its request timed out, while the next one-byte read waits: the
    SDK's own read returns the temperature as that answer; the driver discards it and counts it."""
    dxl_emu.servos[1].temperature_c = 51
    port = sdk.PortHandler(dxl_emu.port)  # the SDK alone on the same line, to show what it would take
    assert port.openPort() and port.setBaudRate(1_000_000)
    ph = sdk.Protocol2PacketHandler()
    for _ in range(3):  # the SDK waits 34 ms for a reply: a loaded host can miss even the late one
        dxl_emu.faults.add("late", match=(1, Inst.READ))
        assert ph.read1ByteTxRx(port, 1, 146)[1] == sdk.COMM_RX_TIMEOUT
        value, comm, _ = ph.read1ByteTxRx(port, 1, 64)  # Torque Enable, 0
        if comm != sdk.COMM_RX_TIMEOUT:
            break
        port.clearPort()   # both replies came after the SDK gave up: start again
    port.closePort()
    assert (value, comm) == (51, sdk.COMM_SUCCESS)  # the late temperature, taken for Torque Enable

    dxl_emu.faults.add("late", match=(1, Inst.READ))
    with pytest.raises(DynamixelCommError):
        bus.read(1, XM430["present_temperature"], _room("present_temperature"))
    before = bus.discarded
    assert bus.read(1, XM430["torque_enable"], _room("torque_enable")) == 0
    assert bus.discarded == before + 1
    assert ("late", 1) in dxl_emu.faults.applied


def test_a_duplicated_reply_is_discarded(bus, dxl_emu):
    dxl_emu.servos[1].temperature_c = 44
    dxl_emu.faults.add("duplicate", match=(1, Inst.READ))
    assert bus.read(1, XM430["present_temperature"], _room("present_temperature")) == 44
    before = bus.discarded
    assert bus.read(1, XM430["torque_enable"], _room("torque_enable")) == 0
    assert bus.discarded == before + 1  # the copy was waiting, or arrived during the read


@pytest.mark.parametrize("kind", ["reorder", "late"])
def test_sync_read_takes_each_servo_once_in_any_order_and_never_an_earlier_reply(bus, dxl_emu, kind):
    """Servo 1's reply comes after servo 2's (reorder), or servo 2's after its Sync Read gave up, at the
    start of the next (late): replies are paired by servo and length, so each servo's own block is
    returned."""
    dxl_emu.servos[1].temperature_c, dxl_emu.servos[2].temperature_c = 31, 62
    room = XM430.room(144, 3)
    dxl_emu.faults.add(kind, match=(1 if kind == "reorder" else 2, Inst.SYNC_READ))
    if kind == "late":
        with pytest.raises(DynamixelCommError, match="servo 2 did not answer"):
            bus.sync_read(144, 3, [1, 2], room)
    got = bus.sync_read(144, 3, [1, 2], room)
    assert (got[1][2], got[2][2]) == (31, 62)
    assert bus.discarded >= (1 if kind == "late" else 0)


def test_reads_are_widened_only_into_defined_addresses_and_never_repeat_a_length(bus, dxl_emu):
    n = len(dxl_emu.received)
    for _ in range(6):
        bus.read_block(1, 98, 38, XM430.room(98, 38))
    reader = PacketReader()
    reads = [p for raw in dxl_emu.received[n:] for p in reader.feed(raw) if p.inst == Inst.READ]
    spans = [(int.from_bytes(p.params[:2], "little"), int.from_bytes(p.params[2:], "little")) for p in reads]
    assert len(spans) == 6 and all(a == 98 and 38 <= length <= 41 for a, length in spans)
    lengths = [length for _, length in spans]
    assert all(lengths[i] not in lengths[max(0, i - 3):i] for i in range(len(lengths)))
    assert all(set(range(a, a + length)) <= XM430.defined | set(range(99, 100)) for a, length in spans)


def test_a_truncated_reply_is_retried(dxl_emu, clock):
    b = DynamixelBus(dxl_emu.port, retries=1)
    b.connect()
    try:
        dxl_emu.faults.add("truncate", match=(2, Inst.READ))
        assert b.read(2, XM430["model_number"]) == 1020
        assert b.counts["corrupt"] == 1
    finally:
        b.close()


def _truth_deg(servo) -> float:
    return (servo.value(132) - 2048) * 360 / 4096


def test_a_stale_position_of_the_right_length_is_never_used(pair, dxl_emu, clock):
    """Mid-move, replies of the right length carrying an earlier sample of the same request (what no
    pairing by ID, instruction and length can tell apart) are refused by the servo's Realtime Tick, read
    again, and the position returned is where the servo is."""
    a, b = pair
    group = DynamixelGroup([a, b])
    group.move_to({"a": 60.0})
    servo = dxl_emu.servos[1]
    for k in range(20):
        clock.sleep(0.05)
        if k >= 5 and k % 2:
            dxl_emu.faults.add("stale", match=(1, Inst.SYNC_READ))
        got = group.read()["a"].position_deg
        assert abs(got - _truth_deg(servo)) <= 360 / 4096
    assert [k for k, _ in dxl_emu.faults.applied].count("stale") == 8
    assert a.guard.rejected >= 5  # the first replies of a widening have no earlier one to repeat


@pytest.mark.parametrize("quiet_s", [0.0, 0.3])
def test_a_stop_never_writes_a_goal_from_a_stale_reply(pair, dxl_emu, clock, quiet_s):
    """The stop's fresh read comes back stale (the sample of four reads before: 0.2 s, some 18° back at
    90 °/s; or, after a quiet 0.3 s, one the axis could have come back to, which only the servo's
    Realtime Tick shows is old): the goal the stop writes is where the servo truly is."""
    a, _b = pair
    a.move_to(80.0)
    for _ in range(12):
        clock.sleep(0.05)
        a.is_moving()
    clock.sleep(quiet_s)
    servo = dxl_emu.servos[1]
    dxl_emu.faults.add("stale", match=(1, Inst.READ))
    a.stop()
    assert ("stale", 1) in dxl_emu.faults.applied
    assert abs((servo.value(116) - 2048) * 360 / 4096 - _truth_deg(servo)) <= 360 / 4096


def test_a_stop_with_no_trustworthy_position_writes_no_goal(pair, dxl_emu, clock):
    """Every read the stop makes is stale: no goal is written at all; the servo goes on to the goal it
    had (checked before it was given), and the stop says so."""
    a, _b = pair
    a.move_to(80.0)
    for _ in range(12):
        clock.sleep(0.05)
        a.is_moving()
    servo = dxl_emu.servos[1]
    goal_before = servo.value(116)
    dxl_emu.faults.add("stale", match=(1, Inst.READ), times=3)
    n = len(dxl_emu.received)
    with pytest.raises(DynamixelCommError, match="no goal written.*an earlier reply"):
        a.stop()
    assert [p for p in dxl_emu.received[n:] if p[7] == Inst.WRITE] == []
    assert servo.value(116) == goal_before
