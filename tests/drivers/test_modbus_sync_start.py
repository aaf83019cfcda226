"""Several Modbus axes started together (Oriental Motor AZ, direct data operation): each move preloaded with
trigger 0, then ONE start query, byte for byte on the wire: group send to the parent (only it answers;
the children execute silently), or broadcast to unit 0 (nobody answers), or, with each unit behind its
own TCP gateway, the trigger on every connection before any reply is read. The emulated units as the
manuals have them: the group register volatile, a unit not in the group ignores the query, a trigger on
data lost at power-off trips an alarm; every failed start found by reading the status, named."""

from __future__ import annotations

import contextlib
import re
import tomllib

import pytest

from gonio.drivers.modbus import (
    ModbusAlarmError,
    ModbusAxis,
    ModbusStartGroup,
    SyncStartError,
    load_profile,
    make_client,
    parse_profile,
)
from gonio.drivers.modbus.profile import FAMILIES
from gonio.sim.emulators.modbus import DATA_ALARM, ModbusBusEmulator, ModbusMotorEmulator

AZ = "oriental_az_direct"
GEAR = 18.0
STEPS_PER_DEG = 1000 * GEAR / 360.0


def crc16_modbus(data: bytes) -> int:
    """CRC-16/MODBUS (polynomial 0xA001 reflected, initial 0xFFFF), as the serial line spec gives it."""
    crc = 0xFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def _rtu_frame(unit: int, pdu: bytes) -> bytes:
    crc = crc16_modbus(bytes([unit]) + pdu)
    return bytes([unit]) + pdu + crc.to_bytes(2, "little")  # CRC low byte first on the wire


TRIGGER_PDU = bytes([0x10, 0x00, 0x66, 0x00, 0x02, 0x04, 0, 0, 0, 1])  # trigger (0x0066) = 1, s32


def _axis(name, client, unit, clock):
    return ModbusAxis(name, client, AZ, device_id=unit, limits_deg=(-180.0, 180.0), gear_ratio=GEAR,
                      velocity_deg_s=60.0, accel_deg_s2=120.0, clock=clock)


@pytest.fixture
def line(clock):
    """Three AZ units (1, 2, 3) on one RTU line, all connected through one client."""
    units = [ModbusMotorEmulator(AZ, clock=clock, device_id=i) for i in (1, 2, 3)]
    for u in units:
        u.assume_referenced()
    bus = ModbusBusEmulator(units)
    client = make_client(f"rtu://{bus.start_rtu()}?baudrate=115200", timeout_s=2.0, retries=0)
    axes = [_axis(f"ax{i}", client, i, clock) for i in (1, 2, 3)]
    try:
        for a in axes:
            a.connect()
        yield bus, units, axes
    finally:
        client.close()
        bus.stop()


MOVES = {"ax1": (30.0, 60.0, 120.0), "ax2": (-12.0, 24.0, 48.0), "ax3": (5.0, 10.0, 20.0)}


def test_group_send_is_one_query_to_the_parent_executed_by_every_child(line, clock):
    bus, units, axes = line
    group = ModbusStartGroup.for_axes(axes)            # one line, profiles with group send
    assert group.mode == "group"
    n_req, n_rep = len(bus.requests), len(bus.replies)
    goals = group.start(MOVES)
    requests, replies = bus.requests[n_req:], bus.replies[n_rep:]
    # Three preloads (block at 0x0058, trigger 0), each to its own unit, while no unit is in a group.
    for i, raw in enumerate(requests[:3], start=1):
        assert raw[:2] == bytes([i, 0x10]) and raw[2:4] == b"\x00\x58" and raw[-6:-2] == b"\0\0\0\0"
    # The group joined: each unit's Group register (0x0030) written (parent -1, children 1) and read back
    # in one Read/Write Multiple Registers (function 23: read 2 at 0x0030, write 2 at 0x0030), each
    # answered with the value written.
    joins = requests[3:6]
    assert [(r[0], r[1], r[2:4], r[4:6], r[6:8], r[8:10], r[11:15]) for r in joins] == [
        (u, 0x17, b"\x00\x30", b"\x00\x02", b"\x00\x30", b"\x00\x02", v)
        for u, v in ((1, b"\xff\xff\xff\xff"), (2, b"\0\0\0\1"), (3, b"\0\0\0\1"))]
    assert [r[3:7] for r in replies[3:6]] == [b"\xff\xff\xff\xff", b"\0\0\0\1", b"\0\0\0\1"]
    # Then ONE start: the trigger to the parent, its CRC the serial line's.
    start = requests[6]
    assert start == _rtu_frame(1, TRIGGER_PDU)
    assert int.from_bytes(start[-2:], "little") == crc16_modbus(start[:-2])
    # Only the parent answered it (the reply that follows the query, from unit 1, echoing address and
    # count), and nobody else answered anything it was not asked: one reply per request addressed.
    assert replies[6] == _rtu_frame(1, bytes([0x10, 0x00, 0x66, 0x00, 0x02]))
    assert len(replies) == len(requests)
    # The group left: -1 written to the parent's Group register (a Write Multiple Registers to the parent,
    # which every child executes too), then each child's read (-1 already: nothing more written).
    assert requests[7] == _rtu_frame(1, bytes([0x10, 0x00, 0x30, 0x00, 0x02, 0x04, 0xFF, 0xFF, 0xFF, 0xFF]))
    assert requests[8:10] == [_rtu_frame(u, bytes([0x03, 0x00, 0x30, 0x00, 0x02])) for u in (2, 3)]
    # Every unit started on that one query (its index on the line), each with its own profile.
    index = n_req + 6
    assert [u.starts[-1][1] for u in units] == [index] * 3
    assert len({u.starts[-1][0] for u in units}) == 1
    for u, (name, (deg, v, a)) in zip(units, MOVES.items(), strict=True):
        assert goals[name] == round(deg * STEPS_PER_DEG)
        _t0, _start, goal, vel, acc = u.plan
        assert goal == goals[name] and vel == round(v * STEPS_PER_DEG) and acc == round(a * STEPS_PER_DEG)
    # The group left right after: a later write to the parent is the parent's alone.
    assert [u.group_id for u in units] == [-1, -1, -1]
    clock.sleep(10.0)
    for a, (deg, _v, _acc) in zip(axes, MOVES.values(), strict=True):
        assert abs(a.position_deg() - deg) < 0.05


def test_while_grouped_a_write_to_the_parent_is_every_childs_and_the_group_is_volatile(line, clock):
    bus, units, axes = line
    group = ModbusStartGroup(axes, "group")
    group.join()
    assert [u.group_id for u in units] == [-1, 1, 1]   # the children name the parent's address
    n = len(bus.replies)
    axes[0].preload(40.0)                              # a block write to the parent ...
    assert len(bus.replies) == n + 1                   # ... answered by the parent alone ...
    # ... and held by every child too (each unit's target register read from it), none moving (trigger 0).
    assert [a.goal_steps() for a in axes] == [round(40.0 * STEPS_PER_DEG)] * 3
    assert not any(u.starts for u in units)
    units[2].power_cycle()                             # the group is lost at power-off
    assert units[2].group_id == -1
    group.leave()
    assert [u.group_id for u in units] == [-1, -1, -1]


def test_a_child_that_missed_the_parents_leave_is_written_itself(line, monkeypatch):
    """The leave's write to the parent reaches a child that does not execute it (a frame it did not take):
    its Group register still reads the parent's address, so it is written -1 itself and read back."""
    bus, units, axes = line
    group = ModbusStartGroup(axes, "group")
    group.join()
    monkeypatch.setattr(units[2], "execute_silently", lambda address, values: None)
    n = len(bus.requests)
    group.leave()
    assert [u.group_id for u in units] == [-1, -1, -1]
    assert [(r[0], r[1]) for r in bus.requests[n:]] == [(1, 0x10), (2, 0x03), (3, 0x03), (3, 0x17)]


def test_a_unit_without_function_23_joins_by_a_write_and_a_read(line):
    """A unit that answers function 23 with exception 1 (illegal function: it wrote nothing) joins by a
    Write Multiple Registers and a read, from then on."""
    bus, units, axes = line
    units[1].fail_next(1)
    group = ModbusStartGroup(axes, "group")
    n = len(bus.requests)
    group.join()
    assert [u.group_id for u in units] == [-1, 1, 1]
    assert [(r[0], r[1]) for r in bus.requests[n:]] == [(1, 0x17), (2, 0x17), (2, 0x10), (2, 0x03), (3, 0x17)]
    assert axes[1].write_read_refused and not axes[0].write_read_refused


def test_a_child_that_dropped_out_of_the_group_ignores_the_query_and_is_named(line, clock, monkeypatch):
    bus, units, axes = line
    group = ModbusStartGroup(axes, "group")
    join = group.join

    def join_then_power_cut():                         # ax3's power cut between the join and the start
        join()
        units[2].power_cycle()

    monkeypatch.setattr(group, "join", join_then_power_cut)
    with pytest.raises(SyncStartError) as err:
        group.start(MOVES)
    assert set(err.value.failed) == {"ax3"}
    assert "not in the group" in err.value.failed["ax3"]
    assert not units[2].starts and units[2].alarm_code == 0   # it executed nothing
    # The two that started were stopped: a coordinated move does not go on with an axis missing.
    assert not units[0].moving() and not units[1].moving()
    monkeypatch.setattr(group, "join", join)
    group.start(MOVES)
    assert units[2].starts


def test_an_alarm_and_data_lost_at_power_off_are_found_by_the_status_read(line, clock):
    bus, units, axes = line
    group = ModbusStartGroup(axes, "group")
    units[1].raise_alarm(0x30)
    with pytest.raises(SyncStartError) as err:
        group.start({"ax1": (10.0, None, None), "ax3": (10.0, None, None)})
    # ax2, told to stay where it is, stood in alarm: the status read after the query finds it, and names
    # it with its alarm code; the two that started are stopped.
    assert set(err.value.failed) == {"ax2"} and "controller alarm 0x0030" in err.value.failed["ax2"]
    assert not units[0].moving() and not units[2].moving()
    axes[1].clear_fault()
    # A unit power cycled between its preload and the trigger holds no data any more: the trigger trips
    # its operation data alarm instead of a move, and the start check names it.
    goals = {n: a.preload(*MOVES[n]) for n, a in group.axes.items()}
    units[0].power_cycle()
    before = len(units[0].starts)
    axes[0].write_words(0x0066, [0, 1], what="trigger")
    assert units[0].alarm_code == DATA_ALARM and len(units[0].starts) == before
    with pytest.raises(ModbusAlarmError, match="^ax1: controller alarm 0x0070"):
        axes[0].start_state(goals["ax1"])


def test_broadcast_is_one_query_to_unit_0_that_nobody_answers(line, clock):
    bus, units, axes = line
    group = ModbusStartGroup(axes, "broadcast")
    n_req, n_rep = len(bus.requests), len(bus.replies)
    t0 = clock.now()
    group.start(MOVES)
    # The line left silent for the turnaround before the first status read: every start is checked after
    # it (on the axes' clock).
    assert clock.now() - t0 >= group.turnaround_s
    start = bus.requests[n_req + 3]
    assert start == _rtu_frame(0, TRIGGER_PDU)
    assert bus.broadcasts == 1
    # The replies after the three preload replies answer the status reads, not the broadcast.
    assert all(r[0] != 0 for r in bus.replies[n_rep:])
    assert [u.starts[-1][1] for u in units] == [n_req + 3] * 3


def test_group_start_refused_where_the_manual_gives_none(clock):
    emu = ModbusMotorEmulator("generic", clock=clock)
    try:
        client = make_client(f"tcp://{':'.join(map(str, emu.start_tcp()))}", timeout_s=0.1, retries=0)
        a = ModbusAxis("stage", client, "generic", limits_deg=(-180.0, 180.0), clock=clock)
        with pytest.raises(ValueError, match=r"^modbus start group: axis 'stage': profile 'generic' has no "
                                             r"\[sync_start\]"):
            ModbusStartGroup([a], "group")
        with pytest.raises(ValueError, match="no \\[sync_start\\]"):
            a.preload(10.0)
    finally:
        emu.stop()
    assert load_profile("leadshine_pr").sync_start is None
    az = load_profile(AZ).sync_start
    assert (az.trigger, az.hold, az.start, az.group_register, az.broadcast) == \
        ("trigger", 0, 1, "group_id", True)
    assert "group_id" in load_profile(AZ).secondary
    # A [sync_start] table that names what the profile does not have is refused, naming the field.
    data = tomllib.loads(FAMILIES[AZ].extra["profile"].read_text())
    for key, bad, msg in (("hold", 1, "sync_start.hold 1 must be an integer other than the trigger"),
                          ("group_register", "nope", "sync_start.group_register 'nope' is not defined"),
                          ("broadcast", "yes", "sync_start.broadcast 'yes' is not one of true, false")):
        with pytest.raises(ValueError, match=f"^modbus profile az: {msg}"):
            parse_profile({**data, "sync_start": {**data["sync_start"], key: bad}}, "az")


@contextlib.contextmanager
def _gateways(clock, n: int = 3, *, timeout_s: float = 2.0, line=None):
    """``n`` AZ units (unit 1 each), each behind its own TCP gateway, and a connected axis on each
    (ax1..axN): (units, axes); every unit watched on ``line`` (a StartLine) when given."""
    units = [ModbusMotorEmulator(AZ, clock=clock, device_id=1) for _ in range(n)]
    axes = []
    try:
        for i, u in enumerate(units, start=1):
            u.assume_referenced()
            u.start_line = line
            host, port = u.start_tcp()
            client = make_client(f"tcp://{host}:{port}", timeout_s=timeout_s, retries=0)
            axes.append(_axis(f"ax{i}", client, 1, clock))
            axes[-1].connect()
        yield units, axes
    finally:
        for a in axes:
            a.close()
        for u in units:
            u.stop()


def test_separate_tcp_gateways_get_the_trigger_back_to_back(clock):
    with _gateways(clock) as (units, axes):
        with pytest.raises(ValueError, match="same bus"):
            ModbusStartGroup(axes, "group")
        group = ModbusStartGroup.for_axes(axes)
        assert group.mode == "back_to_back"
        counts = [len(u.requests) for u in units]
        group.start(MOVES)
        for u, n in zip(units, counts, strict=True):
            preload, trigger = u.requests[n], u.requests[n + 1]
            assert preload[7] == 0x10 and preload[8:10] == b"\x00\x58"
            assert trigger[2:4] == b"\0\0" and trigger[6:] == bytes([1]) + TRIGGER_PDU  # MBAP, unit 1
            assert u.starts[-1][1] == n + 1
        clock.sleep(10.0)
        for a, (deg, _v, _acc) in zip(axes, MOVES.values(), strict=True):
            assert abs(a.position_deg() - deg) < 0.05
        # A connection on which the unit raised an alarm: the others stopped, that one named.
        units[1].raise_alarm(0x42)
        with pytest.raises(SyncStartError) as err:
            group.start({"ax1": (0.0, None, None), "ax2": (0.0, None, None)})
        assert set(err.value.failed) == {"ax2"} and not units[0].moving()


def test_the_shipped_emulated_sample_stage_starts_its_detector_axes_back_to_back():
    """emulated-sample-stage-modbus puts each AZ driver behind its own TCP gateway: no query reaches two,
    so the group its axes make is back_to_back; both detector axes start on their trigger frames, each
    moving at its own preloaded speed, and arrive."""
    from gonio.config import load_config
    from gonio.sim.emulators.gantry import EmulatedGantry
    from gonio.sim.emulators.link import SyncedVirtualClock
    from gonio.wiring import build_gantry

    clock = SyncedVirtualClock()
    with EmulatedGantry(load_config("emulated-sample-stage-modbus"), "lambert:albedo=0.5", clock=clock,
                        any_port=True, referenced=True) as emu:
        gantry = build_gantry(emu.config(), clock=clock)
        gantry.connect()
        try:
            names = ("detector_azimuth", "detector_tilt")
            group = ModbusStartGroup.for_axes([gantry.axes[n] for n in names])
            assert group.mode == "back_to_back"
            counts = {n: len(emu.motors[n].requests) for n in names}
            group.start({"detector_azimuth": (20.0, 10.0, 40.0), "detector_tilt": (-10.0, 5.0, 20.0)})
            for n in names:
                m = emu.motors[n]
                assert m.requests[counts[n] + 1][7:] == TRIGGER_PDU   # the preload, then the trigger
                assert m.starts[-1][1] == counts[n] + 1
            t_start = {n: emu.motors[n].starts[-1][0] for n in names}
            for n, v, a in (("detector_azimuth", 10.0, 40.0), ("detector_tilt", 5.0, 20.0)):
                steps_per_deg = gantry.axes[n].steps_per_deg
                assert emu.motors[n].plan[3:] == (round(v * steps_per_deg), round(a * steps_per_deg))
            clock.sleep(30.0)
            for n, deg in (("detector_azimuth", 20.0), ("detector_tilt", -10.0)):
                assert abs(gantry.axes[n].position_deg() - deg) < 0.05
            assert t_start["detector_azimuth"] == t_start["detector_tilt"]  # one instant of the gantry clock
        finally:
            gantry.close()


def test_the_start_line_sees_a_driver_that_waits_for_a_reply_before_the_next_trigger(clock):
    """The emulators' :class:`StartLine` is what the campaign tests rely on: a trigger answered while
    another preloaded unit has not received its own is counted late (here a driver triggering one
    connection and reading its reply first); the group's back_to_back start is not."""
    from gonio.sim.emulators.modbus import StartLine

    line = StartLine(wait_s=0.05)
    with _gateways(clock, 2, line=line) as (_units, axes):
        for a in axes:
            a.preload(10.0)
        axes[0].write_words(0x0066, [0, 1], what="trigger, its reply awaited")  # the other still armed
        axes[1].write_words(0x0066, [0, 1], what="trigger")
        assert (line.late, line.starts) == (1, 2)
        ModbusStartGroup.for_axes(axes).start({"ax1": (20.0, None, None), "ax2": (-20.0, None, None)})
        assert (line.late, line.starts) == (1, 4)


def test_a_trigger_reply_lost_behind_one_gateway_stops_every_axis_of_the_start(clock):
    """back_to_back: the second unit goes silent after its preload; its trigger's reply never comes. Who
    started cannot be trusted: every axis of the start is stopped, then the comm error names that axis."""
    from gonio.drivers.modbus import ModbusCommError

    with _gateways(clock, timeout_s=0.2) as (units, axes):
        preload = axes[1].preload

        def preload_then_hang(*a, **k):
            steps = preload(*a, **k)
            units[1].go_silent()
            return steps

        axes[1].preload = preload_then_hang
        with pytest.raises(ModbusCommError, match="ax2: start trigger: no reply"):
            ModbusStartGroup.for_axes(axes).start(MOVES)
        assert all(len(u.starts) == 1 for u in units)  # every trigger reached its unit ...
        assert not units[0].moving() and not units[2].moving()  # ... and those that answer were stopped


@pytest.mark.parametrize(("axis", "mode", "why"), [
    ("changer", "group", "profile 'generic' has no [sync_start]"),
    ("sample_tilt", "sometimes", "Input should be 'auto', 'off', 'group', 'broadcast' or 'back_to_back'"),
])
def test_a_start_mode_the_profile_cannot_do_is_refused_naming_the_field(axis, mode, why):
    from gonio.config import ConfigError, load_config, parse_config

    data = load_config("emulated-sample-stage-modbus").model_dump(mode="json")
    data["axes"][axis]["sync_start"] = mode
    with pytest.raises(ConfigError, match=f"axes.{axis}[:.] ?sync_start.*{re.escape(why)}"):
        parse_config(data)


def test_a_start_mode_the_links_do_not_allow_fails_the_connect_in_one_line_and_closes_the_devices():
    """``sync_start = "group"`` on AZ units each behind its own gateway: no other axis shares a line, so
    the connect refuses, naming the axis and what to write instead; every device is closed."""
    from gonio.config import load_config, parse_config
    from gonio.sim.emulators.gantry import EmulatedGantry
    from gonio.sim.emulators.link import SyncedVirtualClock
    from gonio.wiring import build_gantry

    data = load_config("emulated-sample-stage-modbus").model_dump(mode="json")
    data["axes"]["sample_tilt"]["sync_start"] = "group"
    clock = SyncedVirtualClock()
    with EmulatedGantry(parse_config(data), "lambert:albedo=0.5", clock=clock, any_port=True,
                        referenced=True) as emu:
        gantry = build_gantry(emu.config(), clock=clock)
        with pytest.raises(ValueError, match="axis 'sample_tilt': sync_start 'group' starts it with other "
                           "axes, but no other axis naming that mode shares its line"):
            gantry.connect()
        assert not any(a.client.is_socket_open() for a in gantry.axes.values())


def test_a_group_a_crashed_process_left_standing_is_left_when_the_gantry_makes_its_start_group(line):
    """Units 2 and 3 still children of unit 1 (gonio died between a join and its leave): while that
    stands, a move of unit 1 alone would move them too. Making the start group at connect (what the
    gantry does) leaves it first: each unit individual again, read back."""
    from gonio.gantry import start_groups

    _bus, units, axes = line
    ModbusStartGroup(axes, "group").join()
    assert [u.group_id for u in units] == [-1, 1, 1]
    (group,) = start_groups(axes)
    assert group.mode == "group" and [u.group_id for u in units] == [-1, -1, -1]
    axes[0].move_to(10.0)  # a stop-and-go move of the parent now moves the parent alone
    assert units[0].moving() and not units[1].moving() and not units[2].moving()
