"""The assembled gantry's batched motion, byte by byte at the emulators: one Sync Write and one Sync Read
per Dynamixel bus per step and poll (never a read per servo), one read per Modbus controller where its
profile allows (several controllers asked at once where that pays), and the bus watchdog fed while a
move is under way (and firing when it is not)."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.campaign import create_campaign
from gonio.config import load_config, parse_config
from gonio.drivers.dynamixel import DynamixelCommError
from gonio.drivers.modbus import ModbusAxis, make_client
from gonio.lifecycle import run_campaign
from gonio.plan.schedule import STEP_POSE
from gonio.runner import State
from gonio.sim.emulators.dxl_packet import Inst, PacketReader
from gonio.sim.emulators.gantry import EmulatedGantry
from gonio.sim.emulators.link import SyncedVirtualClock
from gonio.sim.emulators.modbus import ModbusMotorEmulator
from gonio.wiring import build_gantry

MATERIAL = "lambert:albedo=0.5"


def _two_buses() -> dict:
    """The emulated two-arm twin with the detector arm's servos on a second bus."""
    data = load_config("emulated-two-arm-dynamixel").model_dump(mode="json")
    data["buses"]["arm2"] = dict(data["buses"]["arm"], port="emulated://arm2")
    for name in ("detector_azimuth", "detector_tilt"):
        data["axes"][name]["bus"] = "arm2"
    return data


def _packets(raw: list[bytes]):
    reader = PacketReader()
    return [p for chunk in raw for p in reader.feed(chunk)]


def test_every_poll_of_a_step_is_one_sync_read_per_bus_and_no_servo_is_read_alone(tmp_path):
    clock = SyncedVirtualClock()
    with EmulatedGantry(parse_config(_two_buses()), MATERIAL, clock=clock, any_port=True,
                        referenced=True) as emu:
        cfg = emu.config()
        gantry = build_gantry(cfg, clock=clock)
        buses = {"arm": (1, 2, 5), "arm2": (3, 4)}  # servo IDs on each bus (5: the changer)
        polls, seen, per_step = [0], {b: 0 for b in buses}, []
        read_groups = gantry._read_groups

        def counted(*a):
            polls[0] += 1
            return read_groups(*a)

        gantry._read_groups = counted
        c = create_campaign(tmp_path / "c", cfg, grid="iso:step=45", material=None, sample="s")
        kinds = c.journal.steps()["kind"]

        def on_step(runner, step):
            new = {b: _packets(emu.emulators[b].received[seen[b]:]) for b in buses}
            for b in buses:
                seen[b] = len(emu.emulators[b].received)
            per_step.append((step, polls[0], new))
            polls[0] = 0

        try:
            state, runner = run_campaign(c, gantry, on_step=on_step)
        finally:
            c.close()
        assert state == State.DONE, runner.fault
    checked = 0
    for step, n_polls, new in per_step[1:]:  # the first step also holds the connection's reads
        if kinds[step] != STEP_POSE:
            continue  # reference steps move the changer, an axis of its own
        checked += 1
        assert n_polls >= 2  # the start of the path, the end of each leg, and the reading's pose
        for bus, packets in new.items():
            insts = [p.inst for p in packets]
            assert Inst.READ not in insts and Inst.WRITE not in insts, (step, bus, insts)
            syncs = [p for p in packets if p.inst == Inst.SYNC_READ]
            assert len(syncs) == n_polls, (step, bus, len(syncs), n_polls)
            ids = tuple(i for i in buses[bus] if i != 5)
            for p in syncs:  # address 98, 38 bytes (widened by 0..3: replies paired), then the IDs
                assert p.params[:2] == bytes([98, 0]) and p.params[3] == 0 and 38 <= p.params[2] <= 41
                assert tuple(p.params[4:]) == ids
    assert checked >= 5


def test_the_watchdog_is_fed_during_a_move_and_stops_the_servos_when_nobody_talks():
    clock = SyncedVirtualClock()
    with EmulatedGantry(load_config("emulated-two-arm-dynamixel"), MATERIAL, clock=clock,
                        any_port=True, referenced=True) as emu:
        cfg = emu.config()
        assert cfg.axes["light_tilt"].watchdog_s == 0.5  # armed in the shipped config
        gantry = build_gantry(cfg, clock=clock)
        gantry.connect()
        try:
            assert gantry.feed_s == 0.25
            tilt = emu.servos["light_tilt"]
            # Fed: a 60° move (1.83 s at 45 °/s, 90 °/s²) waited out in 0.05 s slices with keep_alive.
            gantry.move_axes({"light_tilt": 60.0})
            assert emu.emulators["arm"].drain()  # a Sync Write gets no reply: let the emulator take it
            assert tilt.value(98) == 25  # armed: 25 x 20 ms
            for _ in range(60):
                clock.sleep(0.05)
                gantry.keep_alive()
            pos, moving = gantry.poll_axes()
            assert not moving and pos[1] == pytest.approx(60.0, abs=0.05)
            assert tilt.watchdog_fired_at is None and tilt.value(98) == 0  # disarmed at rest
            # Silent for 1 s mid-move: the servo stops 0.5 s after it last heard from the bus.
            gantry.move_axes({"light_tilt": 0.0})
            start = clock.now()
            clock.sleep(1.0)
            with pytest.raises(DynamixelCommError, match="bus watchdog fired.*light_tilt"):
                gantry.poll_axes()
            assert tilt.watchdog_fired_at == pytest.approx(start + 0.5)
            stopped = gantry.positions()[1]
            assert 20.0 < stopped < 59.0  # short of the goal: it stopped by itself
            clock.sleep(2.0)
            assert gantry.positions()[1] == stopped and tilt.value(98) == 0  # cleared by the driver
        finally:
            gantry.close()


def test_the_watchdog_is_fed_with_most_of_its_period_left_for_a_host_held_up():
    """Fed between 0.05 s slices, a 60° move (1.83 s) of the shipped twin's tilt (watchdog 0.5 s) is held
    up once, 0.33 s with nothing sent (the OS not running gonio on a loaded machine: 0.1-0.8 s seen),
    at each phase of the feeding in turn: the servo still hears from gonio within its 0.5 s every time.
    Feeding once every half period (0.25 s) left the host 0.2-0.25 s: a hold-up at the wrong moment let
    the watchdog fire."""
    clock = SyncedVirtualClock()
    with EmulatedGantry(load_config("emulated-two-arm-dynamixel"), MATERIAL, clock=clock,
                        any_port=True, referenced=True) as emu:
        gantry = build_gantry(emu.config(), clock=clock)
        gantry.connect()
        tilt = emu.servos["light_tilt"]
        try:
            for phase in range(6):
                gantry.move_axes({"light_tilt": 60.0 * ((phase + 1) % 2)})
                for k in range(45):
                    clock.sleep(0.33 if k == 5 + phase else 0.05)
                    gantry.keep_alive()
                assert tilt.watchdog_fired_at is None, phase
                pos, moving = gantry.poll_axes()
                assert not moving and pos[1] == pytest.approx(60.0 * ((phase + 1) % 2), abs=0.05)
        finally:
            gantry.close()


@pytest.mark.parametrize(("profile", "transport", "requests"), [
    ("generic", "tcp", 1), ("generic", "rtu", 1),  # adjacent
    ("oriental_az_direct", "tcp", 1),  # 79 registers spanned (span_read)
    ("oriental_az_direct", "rtu", 2),  # the span's bytes cost more than a second read on the wire
    ("leadshine_pr", "tcp", 2),  # far apart, no span_read
])
def test_a_modbus_state_read_is_one_request_where_the_profile_allows_it(profile, transport, requests):
    emu = ModbusMotorEmulator(profile, clock=SyncedVirtualClock())
    url = (f"tcp://{':'.join(map(str, emu.start_tcp()))}" if transport == "tcp"
           else f"rtu://{emu.start_rtu()}?baudrate=115200")
    axis = ModbusAxis("m", make_client(url, timeout_s=2.0, retries=0), profile, limits_deg=(-180.0, 180.0),
                      velocity_deg_s=90.0, accel_deg_s2=180.0, clock=emu.clock)
    try:
        axis.connect()
        emu.set_position(axis.steps_for(36.0))  # 1000 steps (generic), exact
        before = len(emu.requests)
        pos, moving = axis.read_state()
        assert (pos, moving) == (pytest.approx(36.0, abs=0.01), False)
        assert len(emu.requests) - before == requests
        assert axis.state_in_one_read == (requests == 1)
    finally:
        axis.close()
        emu.stop()


def test_a_watchdog_too_short_for_the_runner_poll_is_refused():
    data = load_config("emulated-two-arm-dynamixel").model_dump(mode="json")
    data["axes"]["light_tilt"]["watchdog_s"] = 0.1  # poll_s is 0.05: fed only every 0.05..0.1 s
    with pytest.raises(ValueError, match=r"axes\.light_tilt\.watchdog_s: 0.1 is below 4 x runner.poll_s"):
        parse_config(data)
    data["runner"]["poll_s"] = 0.02
    assert parse_config(data).axes["light_tilt"].watchdog_s == 0.1


def test_a_manual_move_longer_than_the_watchdog_arrives():
    """``gonio gantry move`` drives the axes one by one: it too must talk to every moving servo while the
    profile runs, or the armed watchdog (0.5 s in the shipped config) stops a 1.8 s move short."""
    from gonio import manual

    clock = SyncedVirtualClock()
    with EmulatedGantry(load_config("emulated-two-arm-dynamixel"), MATERIAL, clock=clock,
                        any_port=True, referenced=True) as emu:
        cfg = emu.config()
        gantry = build_gantry(cfg, clock=clock)
        axes = manual.connect_axes(gantry)
        try:
            start = np.array([gantry.axes[n].position_deg() for n in gantry.kinematics.axis_names])
            leg = start.copy()
            leg[1] = 60.0  # light_tilt: 1.83 s at 45 °/s, 90 °/s²
            final = manual.drive(gantry, leg, cfg=cfg, clock=clock)
            assert final[1] == pytest.approx(60.0, abs=0.05)
            assert emu.servos["light_tilt"].watchdog_fired_at is None
        finally:
            manual.close_axes(axes)
