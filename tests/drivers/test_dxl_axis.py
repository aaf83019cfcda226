"""The Dynamixel driver run through the real dynamixel-sdk against the emulated bus: units, limits,
EEPROM, group moves and reads, and what the driver does for each injected fault."""

from __future__ import annotations

import threading

import pytest

from gonio.drivers.dynamixel import (
    XM430,
    DynamixelAxis,
    DynamixelBus,
    DynamixelCommError,
    DynamixelGroup,
    DynamixelHardwareError,
    DynamixelStatusError,
    HardwareError,
    PacketError,
)
from gonio.motion.trapezoid import position_at
from gonio.protocols import Axis, DeviceFault
from gonio.sim.emulators.dxl_packet import Inst


@pytest.fixture
def rig(dxl_emu, clock):
    """A bus with axes 'a' (ID 1) and 'b' (ID 2) centred on tick 2048, connected; closed at the end. Five
    retries: the emulator is a thread of this process, and on a loaded host its reply can miss the SDK's
    ~34 ms packet time-out several times (at load 6 on 2 cores, four times in a row: "There is no status
    packet!" at connect); tests of the retries themselves set their own or count from bus.retries."""
    bus = DynamixelBus(dxl_emu.port, name="dxl0", retries=5)
    a = DynamixelAxis("a", bus, 1, limits_deg=(-90.0, 90.0), homing_offset_ticks=2048,
                      velocity_deg_s=90.0, accel_deg_s2=180.0, watchdog_s=0.2, clock=clock)
    b = DynamixelAxis("b", bus, 2, limits_deg=(-90.0, 90.0), homing_offset_ticks=2048, clock=clock)
    a.connect()
    b.connect()
    try:
        yield bus, a, b
    finally:
        a.close()
        b.close()


def settle(clock, axis, step_s=0.05, max_steps=400):
    for _ in range(max_steps):
        if not axis.is_moving():
            return
        clock.sleep(step_s)
    raise AssertionError("axis never stopped")


def test_satisfies_axis_protocol_and_does_no_io_in_constructor():
    bus = DynamixelBus("/nonexistent/port")
    axis = DynamixelAxis("a", bus, 1, limits_deg=(0.0, 90.0))
    assert isinstance(axis, Axis)
    assert not bus.is_open


def test_units_gear_direction_offset():
    bus = DynamixelBus("/nonexistent/port")
    axis = DynamixelAxis("a", bus, 1, limits_deg=(-40.0, 40.0), gear_ratio=2.0, direction=-1,
                         homing_offset_ticks=2048, velocity_deg_s=90.0, accel_deg_s2=180.0)
    assert axis.check_target(10.0) == 2048 - round(10 * 4096 * 2 / 360)
    # 90 °/s on the axis is 30 rev/min on the servo: 30 / 0.229 = 131 units; 180 °/s² -> 3600 rev/min².
    assert axis.profile_velocity == 131
    assert axis.profile_acceleration == round(3600 / 214.577)
    with pytest.raises(ValueError, match=r"axis 'a': target 41.0° is outside the limit \[-40°, 40°\]"):
        axis.check_target(41.0)
    with pytest.raises(ValueError, match="outside the position mode range"):
        DynamixelAxis("w", bus, 1, limits_deg=(-10.0, 10.0))  # ticks -114..114 are not in 0..4095
    with pytest.raises(ValueError, match="accel_deg_s2"):
        DynamixelAxis("w", bus, 1, limits_deg=(0.0, 10.0), accel_deg_s2=1e9)


def test_connect_configures_servo(rig, dxl_emu):
    _bus, a, _b = rig
    servo = dxl_emu.servos[1]
    assert a.model_name == "XM430-W350"
    assert servo.value(11) == 3  # position mode
    assert (servo.value(52), servo.value(48)) == (1024, 3072)  # limits ±90° around 2048
    assert (servo.value(112), servo.value(108)) == (a.profile_velocity, a.profile_acceleration)
    assert servo.value(64) == 1
    assert a.torque()


def test_wrong_model_is_refused(dxl_emu):
    axis = DynamixelAxis("x", DynamixelBus(dxl_emu.port), 3, limits_deg=(0.0, 90.0), family="XM430")
    with pytest.raises(DeviceFault, match=r"servo 3 is model 1060, not a XM430"):
        axis.connect()


def test_eeprom_locked_while_torque_on(rig):
    bus, a, _b = rig
    with pytest.raises(DynamixelStatusError) as err:
        bus.write(1, XM430["operating_mode"], 4)
    assert err.value.error == PacketError.ACCESS and not err.value.transient


def test_move_follows_the_trapezoid(rig, clock, dxl_emu):
    _bus, a, _b = rig
    a.move_to(45.0)
    assert dxl_emu.servos[1].value(98) == 10  # watchdog armed: 0.2 s in 20 ms units
    clock.sleep(0.15)
    v_ticks = a.profile_velocity * 0.229 * 4096 / 60
    acc_ticks = a.profile_acceleration * 214.577 * 4096 / 3600
    expected = round(position_at(0.15, 2048.0, 2048.0 + 512, v_ticks, acc_ticks))
    assert a.position_deg() == pytest.approx((expected - 2048) * 360 / 4096)
    assert a.is_moving()
    settle(clock, a)
    assert a.position_deg() == 45.0
    assert dxl_emu.servos[1].value(98) == 0  # disarmed at rest


def test_extended_mode_reads_signed_positions(dxl_emu, clock):
    bus = DynamixelBus(dxl_emu.port)
    axis = DynamixelAxis("spin", bus, 2, limits_deg=(-720.0, 720.0), operating_mode="extended",
                         velocity_deg_s=270.0, accel_deg_s2=2000.0, clock=clock)
    axis.connect()
    try:
        assert not axis.referenced()
        with pytest.raises(DeviceFault, match="not referenced.*gonio gantry reference"):
            axis.move_to(10.0)
        # The shaft reads 180° within its turn; an index at 530° says which turn: 540°, 10° past the mark.
        assert axis.reference_index(530.0) == pytest.approx(10.0, abs=360 / 4096)
        assert axis.referenced() and axis.position_deg() == pytest.approx(540.0)
        assert axis.reference_info()["correction_ticks"] == 4096
        assert dxl_emu.servos[2].value(11) == 4
        axis.move_to(-700.0)
        settle(clock, axis, step_s=0.05)
        assert axis.position_deg() == pytest.approx(-700.0, abs=0.05)
    finally:
        axis.close()


def test_servo_limit_refuses_goal_beyond_it(rig):
    bus, _a, _b = rig
    with pytest.raises(DynamixelStatusError) as err:
        bus.write(1, XM430["goal_position"], 3500)  # servo limit is 3072
    assert err.value.error == PacketError.DATA_LIMIT


def test_group_uses_one_sync_write_and_one_sync_read_per_step(rig, dxl_emu, clock):
    _bus, a, b = rig
    group = DynamixelGroup([a, b])
    group.move_to({"a": 10.0, "b": -10.0})  # arms the watchdog (one sync write) then the goals
    clock.sleep(0.05)
    group.read()  # answered: every packet before it has been handled
    n = len(dxl_emu.received)
    group.move_to({"a": 20.0, "b": -20.0})
    state = group.read()
    assert dxl_emu.wait_received(n + 2)
    insts = [p[7] for p in dxl_emu.received[n:]]
    assert insts == [Inst.SYNC_WRITE, Inst.SYNC_READ]
    assert set(state) == {"a", "b"} and state["a"].moving
    for _ in range(100):
        clock.sleep(0.05)
        state = group.read()
        if not any(s.moving for s in state.values()):
            break
    assert state["a"].position_deg == pytest.approx(20.0, abs=0.05)
    assert state["b"].position_deg == pytest.approx(-20.0, abs=0.05)


def test_group_refuses_all_when_one_target_is_out_of_range(rig, dxl_emu):
    _bus, a, b = rig
    n = len(dxl_emu.received)
    with pytest.raises(ValueError, match="axis 'b': target 95.0°"):
        DynamixelGroup([a, b]).move_to({"a": 10.0, "b": 95.0})
    assert len(dxl_emu.received) == n


def test_silent_servo_in_sync_read_is_an_error_never_zero(rig, dxl_emu):
    bus, a, b = rig
    dxl_emu.faults.add("drop", match=(2, Inst.SYNC_READ), times=bus.retries + 1)  # every attempt
    with pytest.raises(DynamixelCommError, match="servo 2 did not answer") as err:
        DynamixelGroup([a, b]).read()
    assert err.value.transient and err.value.dxl_id == 2


def test_dropped_reply_is_retried(rig, dxl_emu):
    _bus, a, _b = rig
    dxl_emu.faults.add("drop", match=1)
    assert a.position_deg() == 0.0
    assert dxl_emu.faults.applied == [("drop", 1)]


@pytest.mark.parametrize("kind", ["corrupt", "truncate"])
def test_bad_reply_retried_then_typed_error(rig, dxl_emu, kind):
    bus, a, _b = rig
    dxl_emu.faults.add(kind, match=1)
    assert a.position_deg() == 0.0  # one bad reply: the retry gets a good one
    dxl_emu.faults.add(kind, match=1, times=bus.retries + 1)  # every attempt
    with pytest.raises(DynamixelCommError) as err:
        a.position_deg()
    assert err.value.transient and "servo 1" in str(err.value)


def test_late_reply_is_not_taken_for_the_next_answer(rig, dxl_emu):
    bus, _a, _b = rig
    bus.retries = 0
    dxl_emu.faults.add("delay", match=(1, Inst.READ), delay_s=0.08)  # SDK waits ~34 ms
    with pytest.raises(DynamixelCommError):
        bus.read(1, XM430["present_temperature"])
    assert dxl_emu.wait_received(len(dxl_emu.received))  # the late reply is now in the input buffer
    assert bus.read(1, XM430["model_number"]) == 1020  # not the late temperature reply


def test_the_bus_latency_timer_sets_how_long_a_reply_is_waited_for(dxl_emu):
    """A reply 70 ms late misses the SDK's time-out (2 x 16 ms latency + 2 ms + the bytes: ~34 ms) and is
    taken where the bus allows a 100 ms latency timer (~202 ms); the emulated gantry's config allows 50."""
    for latency, taken in ((16.0, False), (100.0, True)):
        bus = DynamixelBus(dxl_emu.port, name="dxl0", retries=0, latency_timer_ms=latency)
        bus.connect()
        try:
            dxl_emu.faults.add("delay", match=(1, Inst.READ), delay_s=0.07)
            if taken:
                assert bus.read(1, XM430["model_number"]) == 1020
            else:
                with pytest.raises(DynamixelCommError, match="servo 1"):
                    bus.read(1, XM430["model_number"])
                assert dxl_emu.wait_received(len(dxl_emu.received))
        finally:
            bus.close()
    for bad in (0.0, -1.0, float("nan"), 501.0):
        with pytest.raises(ValueError, match="latency_timer_ms"):
            DynamixelBus(dxl_emu.port, name="dxl0", latency_timer_ms=bad)


def test_hardware_error_latches_and_only_clear_fault_reboots(rig, dxl_emu, clock):
    _bus, a, b = rig
    a.move_to(30.0)
    clock.sleep(0.1)
    dxl_emu.servos[1].inject_hardware_error(int(HardwareError.OVERLOAD | HardwareError.OVERHEATING))
    with pytest.raises(DynamixelHardwareError) as err:
        a.is_moving()
    assert not err.value.transient
    assert err.value.flags == HardwareError.OVERLOAD | HardwareError.OVERHEATING
    assert a.fault() == "servo 1 hardware error: overheating + overload (Shutdown acts on it: torque is off)"
    with pytest.raises(DynamixelHardwareError, match="latched"):
        a.move_to(0.0)
    assert dxl_emu.servos[1].reboots == 0
    a.clear_fault()
    assert dxl_emu.servos[1].reboots == 1
    assert a.fault() is None and a.torque()
    a.move_to(0.0)
    settle(clock, a)
    assert a.position_deg() == 0.0


def test_hardware_error_seen_by_group_read(rig, dxl_emu):
    _bus, a, b = rig
    dxl_emu.servos[2].inject_hardware_error(int(HardwareError.OVERLOAD))
    with pytest.raises(DynamixelHardwareError, match="overload") as err:
        DynamixelGroup([a, b]).read()
    assert not err.value.transient and "torque is off" in str(err.value)
    assert b.fault() is not None and a.fault() is None


def test_a_hardware_error_the_shutdown_setting_ignores_is_a_warning_and_the_servo_goes_on(rig, dxl_emu,
                                                                                          clock):
    """Input voltage is not in the default Shutdown (0x34): the servo keeps its torque and its move; the
    driver reports a warning once, moves on, and says what the servo did."""
    _bus, a, b = rig
    servo = dxl_emu.servos[2]
    assert servo.value(63) == 0x34
    group = DynamixelGroup([a, b])
    group.move_to({"b": 20.0})
    servo.inject_hardware_error(int(HardwareError.INPUT_VOLTAGE))
    assert servo.value(64) == 1  # torque stays on: the servo did not act on it
    group.read()
    assert b.fault() is None
    (warning,) = b.warnings()
    assert "input voltage" in warning and "keeps its torque" in warning and "torque off" not in warning
    for _ in range(100):
        clock.sleep(0.05)
        if not group.read()["b"].moving:
            break
    assert b.position_deg() == pytest.approx(20.0, abs=0.05) and b.warnings() == []
    servo.inject_hardware_error(int(HardwareError.OVERHEATING))  # in Shutdown: torque goes off
    clock.sleep(1.0)  # the alert bit stays up: Hardware Error Status is read again after 1 s
    with pytest.raises(DynamixelHardwareError, match="overheating.*torque is off"):
        group.read()


def test_bus_watchdog_stops_servo_when_gonio_goes_quiet(rig, dxl_emu, clock):
    _bus, a, _b = rig
    a.move_to(80.0)
    clock.sleep(0.5)  # no traffic for longer than 0.2 s: the servo stops by itself
    with pytest.raises(DynamixelCommError, match="bus watchdog fired") as err:
        a.is_moving()
    assert err.value.transient
    stopped = a.position_deg()
    assert 0.0 < stopped < 80.0
    clock.sleep(1.0)
    assert a.position_deg() == stopped
    a.move_to(80.0)  # the watchdog error was cleared: goals are accepted again
    settle(clock, a)
    assert a.position_deg() == pytest.approx(80.0, abs=0.05)


def test_disconnect_then_reconnect(rig, dxl_emu):
    bus, a, _b = rig
    dxl_emu.unplug()
    with pytest.raises(DeviceFault) as err:
        a.position_deg()
    assert err.value.transient
    dxl_emu.replug()
    assert a.position_deg() == 0.0
    assert bus.reconnects >= 1


def test_disconnect_mid_reply_then_reconnect(rig, dxl_emu):
    bus, a, _b = rig
    dxl_emu.faults.add("disconnect", match=1)
    with pytest.raises(DeviceFault) as err:
        a.position_deg()
    assert err.value.transient
    dxl_emu.replug()
    assert a.position_deg() == 0.0


def test_stop_from_another_thread_holds_position(rig, clock, dxl_emu):
    _bus, a, _b = rig
    a.move_to(80.0)
    clock.sleep(0.2)
    t = threading.Thread(target=a.stop)
    t.start()
    t.join(5.0)
    held = dxl_emu.servos[1].value(116)
    assert held == dxl_emu.servos[1].value(132)
    settle(clock, a)
    assert a.position_deg() == pytest.approx((held - 2048) * 360 / 4096)


def test_reg_write_applies_on_action(rig, dxl_emu, clock):
    bus, a, _b = rig
    bus.reg_write(1, XM430["goal_position"], 2048 + 100)
    clock.sleep(1.0)
    assert dxl_emu.servos[1].value(132) == 2048
    bus.action()
    assert dxl_emu.wait_received(len(dxl_emu.received))
    for _ in range(100):
        clock.sleep(0.05)
        if a.position_deg() == pytest.approx(100 * 360 / 4096):
            break
    assert a.position_deg() == pytest.approx(100 * 360 / 4096)


def test_telemetry(rig, dxl_emu):
    _bus, a, _b = rig
    dxl_emu.servos[1].temperature_c = 51
    dxl_emu.servos[1].voltage_dv = 118
    assert a.temperature_c() == 51.0
    assert a.voltage_v() == pytest.approx(11.8)
    assert a.current_a() == pytest.approx(3 * 0.00269)
    xl = DynamixelAxis("xl", a.bus, 3, limits_deg=(0.0, 90.0), family="XL430", clock=a.clock)
    with pytest.raises(DeviceFault, match="report load, not current"):
        xl.current_a()


def test_a_sweep_runs_at_the_quantised_profile_and_the_campaign_profile_comes_back(rig, dxl_emu, clock):
    """On-the-fly scanning: the sweep writes the profile in whole units and returns the speed the servo
    runs at (not the one asked); the emulated shaft moves at exactly that speed; stamped reads give the
    positions with their times; the campaign's profile is written back after, and before a later move
    if a sweep left its own."""
    _bus, a, b = rig
    group = DynamixelGroup([a, b])
    servo = dxl_emu.servos[1]
    v, acc = a.sweep(80.0, 33.3, 150.0)
    assert (servo.value(112), servo.value(108)) == (24, 7)  # 33.3 °/s and 150 °/s² in profile units
    assert v == pytest.approx(24 * 0.229 * 6.0) and v != 33.3
    assert acc == pytest.approx(7 * 214.577 / 10.0) and acc != 150.0
    assert servo.value(98) == 10  # the watchdog armed, as for any move
    reads = []
    for _ in range(8):  # reads every 0.15 s keep the 0.2 s watchdog fed
        clock.sleep(0.15)
        reads.append(group.read_stamped(clock))
    (t1, s1), (t2, s2) = reads[1], reads[-1]  # past the run-up (v / acc = 0.22 s)
    assert (t1, t2) == pytest.approx((0.3, 1.2))  # the virtual clock stands still during a transaction
    speed = (s2["a"].position_deg - s1["a"].position_deg) / (t2 - t1)
    assert speed == pytest.approx(v, abs=2 * 360 / 4096 / 0.9)  # two reads, each within a tick
    assert abs(speed - 33.3) > 0.2
    a.restore_profile()
    assert (servo.value(112), servo.value(108)) == (a.profile_velocity, a.profile_acceleration)
    settle(clock, a)
    a.sweep(0.0, 20.0, 100.0)  # a restore that could not be written: the next move restores first
    settle(clock, a)
    group.move_to({"a": 10.0})
    assert (servo.value(112), servo.value(108)) == (a.profile_velocity, a.profile_acceleration)
    with pytest.raises(ValueError, match="outside the limit"):
        a.sweep(120.0, 20.0, 100.0)
