"""A line's start in one packet: the Sync Write of Profile Acceleration(108), Profile Velocity(112) and
Goal Position(116), 12 bytes per servo, byte for byte on the wire; and the emulated servos as the
e-Manual has them: Sync Write only to the broadcast ID, silent refusals, a goal written during a move
re-planned from the present velocity (Velocity Override), the time-based profile (Drive Mode bit 2)."""

from __future__ import annotations

import serial

from gonio.drivers.dynamixel import DynamixelAxis, DynamixelBus
from gonio.drivers.dynamixel.group import DynamixelGroup
from gonio.sim.emulators.dxl_packet import BROADCAST_ID, Inst, PacketReader, crc16, instruction_packet

TICKS_S_PER_UNIT = 0.229 * 4096 / 60.0   # Profile Velocity unit in ticks/s
BAUD = 1_000_000


def _axes(emu, clock):
    bus = DynamixelBus(emu.port)
    axes = [DynamixelAxis(f"a{i}", bus, i, limits_deg=(-170.0, 170.0), homing_offset_ticks=2048,
                          watchdog_s=0.0, clock=clock) for i in (1, 2)]
    for a in axes:
        a.connect()
    return bus, axes


def _le(v: int) -> bytes:
    return int(v).to_bytes(4, "little", signed=True)


def test_a_line_starts_with_one_sync_write_of_goal_and_profile_from_address_108(dxl_emu, clock):
    bus, (a1, a2) = _axes(dxl_emu, clock)
    try:
        group = DynamixelGroup([a1, a2])
        v1, acc1 = a1.prepare(30.0, 60.0)
        v2, acc2 = a2.prepare(12.0, 200.0)
        n = len(dxl_emu.received)
        group.start_sweeps({"a1": 90.0, "a2": -45.0})
        assert dxl_emu.wait_received(n + 1)
        assert len(dxl_emu.received) == n + 1          # one packet, and nothing answers it
        raw = dxl_emu.received[n]
        # The e-Manual's layout: address 108, length 12, then ID and 12 bytes per servo.
        units = {1: (round(60.0 * 3600 / 360 / 214.577), round(30.0 * 60 / 360 / 0.229), 2048 + 1024),
                 2: (round(200.0 * 3600 / 360 / 214.577), round(12.0 * 60 / 360 / 0.229), 2048 - 512)}
        params = bytes([108, 0, 12, 0]) + b"".join(bytes([i]) + b"".join(map(_le, u))
                                                   for i, u in units.items())
        assert raw == instruction_packet(BROADCAST_ID, Inst.SYNC_WRITE, params)
        assert raw[4] == 0xFE and raw[7] == 0x83
        assert int.from_bytes(raw[5:7], "little") == 3 + 4 + 2 * 13 == len(raw) - 7
        assert int.from_bytes(raw[-2:], "little") == crc16(raw[:-2])
        s1, s2 = dxl_emu.servos[1], dxl_emu.servos[2]
        for s, (acc, vel, goal) in ((s1, units[1]), (s2, units[2])):
            assert (s.value(108), s.value(112), s.value(116)) == (acc, vel, goal)
        # Both servos planned their moves on the packet, within one bus transfer of each other, each on
        # the profile written beside its goal (its own top speed).
        assert abs(s1.trajectory.t0 - s2.trajectory.t0) <= len(raw) * 10 / BAUD
        for s, (_acc, vel, goal) in ((s1, units[1]), (s2, units[2])):
            top = max(abs(p[2] + p[3] * p[0]) for p in s.trajectory.pieces)
            assert abs(top - vel * TICKS_S_PER_UNIT) < 1e-6 * top
            assert s.trajectory.end == goal
        assert (v1, v2) == (a1.velocity_deg_s_of(units[1][1]), a2.velocity_deg_s_of(units[2][1]))
        clock.sleep(20.0)
        assert abs(a1.position_deg() - 90.0) < 0.1 and abs(a2.position_deg() + 45.0) < 0.1
        # The campaign profile comes back after the sweep.
        a1.complete()
        assert dxl_emu.servos[1].value(112) == a1.profile_velocity
    finally:
        for a in (a1, a2):
            a.close()


def test_a_refused_target_starts_no_servo(dxl_emu, clock):
    bus, (a1, a2) = _axes(dxl_emu, clock)
    try:
        group = DynamixelGroup([a1, a2])
        a1.prepare(30.0, 60.0)
        a2.prepare(30.0, 60.0)
        n = len(dxl_emu.received)
        try:
            group.start_sweeps({"a1": 10.0, "a2": 400.0})
        except ValueError as err:
            assert "a2" in str(err) and "outside" in str(err)
        else:
            raise AssertionError("a target beyond the limit was accepted")
        assert len(dxl_emu.received) == n
    finally:
        for a in (a1, a2):
            a.close()


def _raw(emu, packet: bytes) -> bytes:
    """Send ``packet`` on the emulator's wire; what came back once it was handled."""
    n = emu.handled
    with serial.Serial(emu.port, BAUD, timeout=0) as port:
        port.write(packet)
        assert emu.wait_received(n + 1)
        return port.read(1024)


def _sync_write(address: int, length: int, blocks: dict[int, bytes], dxl_id: int = BROADCAST_ID) -> bytes:
    params = bytes([address & 0xFF, address >> 8, length & 0xFF, length >> 8])
    params += b"".join(bytes([i]) + b for i, b in blocks.items())
    return instruction_packet(dxl_id, Inst.SYNC_WRITE, params)


def test_the_emulator_applies_a_sync_write_as_the_emanual_says(dxl_emu):
    s1, s2, s3 = (dxl_emu.servos[i] for i in (1, 2, 3))
    s1.write(64, b"\x01")
    # A servo named in the packet applies its bytes; one not named ignores it; nobody answers.
    assert _raw(dxl_emu, _sync_write(116, 4, {1: _le(1000), 3: _le(3000)})) == b""
    assert (s1.value(116), s3.value(116)) == (1000, 3000)
    assert s1.trajectory.end == 1000 and s3.trajectory.end == s3.value(132)   # torque off on 3: no move
    assert s2.value(116) == s2.value(132)        # untouched: still its power-up goal
    # Not to the broadcast ID: no servo takes it, not even the one it names.
    assert _raw(dxl_emu, _sync_write(116, 4, {1: _le(1500)}, dxl_id=1)) == b""
    assert s1.value(116) == 1000
    # An EEPROM item while torque is on: refused, silently (there is no status packet to carry it).
    assert _raw(dxl_emu, _sync_write(11, 1, {1: b"\x04", 2: b"\x04"})) == b""
    assert (s1.value(11), s2.value(11)) == (3, 4)    # torque off on 2: its EEPROM took it
    # Data that do not divide into whole entries: dropped.
    short = instruction_packet(BROADCAST_ID, Inst.SYNC_WRITE, bytes([116, 0, 4, 0, 1]) + _le(500)[:3])
    assert _raw(dxl_emu, short) == b""
    assert s1.value(116) == 1000
    packets = PacketReader().feed(b"".join(dxl_emu.received[-4:]))
    assert [(p.inst, p.crc_ok) for p in packets] == [(Inst.SYNC_WRITE, True)] * 4


def test_a_goal_written_during_a_move_replans_from_the_present_velocity(clock, dxl_emu):
    s = dxl_emu.servos[1]
    assert s.write(11, b"\x04") == 0                      # extended position mode: room to run
    s.write(64, b"\x01")
    assert s.write(108, _le(50) + _le(100) + _le(2048 + 8000)) == 0   # 50 accel units, 100 speed units
    clock.sleep(2.0)                                       # cruising
    v_before = s.value(128)
    assert v_before == 100 and s.value(122) == 1
    x = s.value(132)
    s.write(116, _le(x + 3000))                           # a new goal, same direction, mid-move
    assert s.trajectory.t0 == clock.now()
    assert abs(s.value(128) - v_before) <= 1              # no restart from rest: velocity continuous
    planned = s.trajectory
    assert planned.end == x + 3000
    s.write(112, _le(40))                                  # a profile alone does not re-plan the move
    assert s.trajectory is planned
    clock.sleep(0.01)
    s.write(116, _le(x + 3000))                           # the same goal with the new top speed: slows
    clock.sleep(3.0)
    assert abs(s.value(128) - 40) <= 1
    # A goal behind the servo: it brakes through zero (never a jump), then comes back.
    s.write(116, _le(x))
    v = [s.value(128)]
    for _ in range(40):
        clock.sleep(0.01)
        v.append(s.value(128))
    steps = [abs(b - a) for a, b in zip(v, v[1:], strict=False)]
    assert max(steps) <= 50 * 214.577 / 0.229 / 60 * 0.01 + 1 and min(v) < 0 < v[0]
    clock.sleep(30.0)
    assert s.value(132) == x and s.value(122) == 0


def test_time_based_profiles_make_servos_of_any_distance_arrive_together(clock, dxl_emu):
    s1, s2 = dxl_emu.servos[1], dxl_emu.servos[2]
    for s in (s1, s2):
        assert s.write(10, b"\x04") == 0                   # Drive Mode bit 2, torque off (EEPROM)
        s.write(64, b"\x01")
    start = {s: s.value(132) for s in (s1, s2)}
    t0 = clock.now()
    # 1.5 s in all, 0.4 s ramps (ms), different distances and directions, one packet.
    _raw(dxl_emu, _sync_write(108, 12, {1: _le(400) + _le(1500) + _le(start[s1] + 1500),
                                        2: _le(400) + _le(1500) + _le(start[s2] - 700)}))
    assert s1.trajectory.t0 == s2.trajectory.t0
    t_mid = s1.trajectory.t0 + 0.75
    clock.sleep(t_mid - clock.now())
    # Symmetric profile: both halfway at half time, same fraction of their travel all along.
    assert abs(s1.value(132) - (start[s1] + 750)) <= 1 and abs(s2.value(132) - (start[s2] - 350)) <= 1
    clock.sleep(s1.trajectory.t0 + 1.5 - clock.now() - 1e-3)
    assert s1.value(122) == 1 and s2.value(122) == 1
    clock.sleep(2e-3)
    assert (s1.value(132), s2.value(132)) == (start[s1] + 1500, start[s2] - 700)
    assert s1.value(122) == 0 and s2.value(122) == 0
    assert clock.now() - t0 >= 1.5
    # A ramp longer than half the time is clipped to it (e-Manual: at most 50 % of Profile Velocity).
    s1.write(108, _le(900) + _le(1000) + _le(start[s1]))
    assert abs(s1.trajectory.pieces[0][0] - 0.5) < 1e-12 and abs(s1.trajectory.duration - 1.0) < 1e-12
