"""Referencing (``gonio gantry reference``) against emulators that power up as hardware does: the ring
carriages' servos report their position within one turn (the ring angle modulo 90°), mechanical stops at
the ends of their travel, Modbus controllers that lose their origin. Moves are refused until the axes
are referenced, with nothing written; a reference finds the true angles, survives a restart of gonio and
not a power cycle, and the journal records it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gonio import manual
from gonio.campaign import create_campaign
from gonio.cli import main
from gonio.clock import WallClock
from gonio.config import load_config, parse_config
from gonio.drivers.modbus import ModbusAxis, make_client
from gonio.lifecycle import run_campaign
from gonio.protocols import DeviceFault, NotReferencedFault
from gonio.reference import reference_axes, unreferenced
from gonio.sim.emulators.dxl_packet import Inst, PacketReader
from gonio.sim.emulators.gantry import EmulatedGantry
from gonio.sim.emulators.link import SyncedVirtualClock
from gonio.sim.emulators.modbus import ModbusMotorEmulator
from gonio.store import JOURNAL_NAME
from gonio.wiring import build_gantry

TWIN = "emulated-two-arm-dynamixel"
#: Instructions that change a servo (anything but ping and reads).
WRITES = {Inst.WRITE, Inst.REG_WRITE, Inst.ACTION, Inst.REBOOT, Inst.SYNC_WRITE}


def writes(emu, since: int = 0) -> list[int]:
    """The write instructions the emulated bus received since packet ``since``."""
    reader = PacketReader()
    packets = [p for raw in emu.emulators["arm"].received[since:] for p in reader.feed(raw)]
    return [p.inst for p in packets if p.inst in WRITES]


def ring_gap(axes_deg: dict) -> float:
    """How far apart the two carriages are around the ring (°)."""
    d = (axes_deg["light_azimuth"] - axes_deg["detector_azimuth"]) % 360.0
    return min(d, 360.0 - d)


class WatchedClock(SyncedVirtualClock):
    """The emulators' synced virtual clock that calls ``watch()`` after every advance (the commands wait in
    slices of runner.poll_s, 5 ms here: the carriages are looked at every 0.6° of a 120 °/s move)."""

    def __init__(self):
        super().__init__()
        self.watch = lambda: None

    def sleep(self, seconds: float) -> None:
        super().sleep(seconds)
        self.watch()


@pytest.fixture
def fast_twin(tmp_path, monkeypatch, request):
    """The two-arm twin with quicker moves (2:1 ring pinions, so 120 °/s on the ring is within the servos'
    velocity limit, and the approach at that speed): its emulators, powered up as hardware does (a
    carriage's angle known modulo 180°), the config file that reaches them, and their clock (a
    :class:`WatchedClock`), which is the CLI's wall clock here: the commands run in this process and do
    not wait for the motion (gonio gantry reference on the wall clock: test_run_emulated_scpi). The bus
    watchdogs are off unless the test asks for a period (indirect parametrization)."""
    data = load_config(TWIN).model_dump(mode="json")
    for name, axis in data["axes"].items():
        if axis.get("reference") == "hard_stop":
            axis.update(gear_ratio=2.0, max_velocity_deg_s=120.0, max_accel_deg_s2=2400.0,
                        reference_velocity_deg_s=120.0)
        elif name != "changer":
            axis.update(max_velocity_deg_s=120.0, max_accel_deg_s2=2400.0)
    data["runner"].update(poll_s=0.005)
    for axis in data["axes"].values():
        axis["watchdog_s"] = getattr(request, "param", 0.0)
    clock = WatchedClock()
    with EmulatedGantry(parse_config(data), clock=clock, any_port=True) as emu:
        path = tmp_path / "gantry.toml"
        path.write_text(emu.config_toml())
        monkeypatch.setattr("gonio.wiring.WallClock", lambda: clock)
        yield emu, str(path), clock


def test_home_is_refused_on_an_unreferenced_gantry_with_nothing_written(fast_twin, capsys):
    emu, path, _ = fast_twin
    truth = emu.axes_deg()
    for action in (["home"], ["jog", "--axis", "light_tilt", "--by", "5"], ["move", "--axes", "0,10,180,0"]):
        n = len(emu.emulators["arm"].received)
        assert main(["gantry", *action, "--config", path]) == 2
        (line,) = capsys.readouterr().err.strip().splitlines()
        assert "light_azimuth" in line and "detector_azimuth" in line and "gonio gantry reference" in line
        assert writes(emu, n) == []
    assert emu.axes_deg() == truth


def _assert_referenced_at_the_true_angles(emu, path: str, capsys) -> None:
    """`gonio gantry status` reads every axis at its true angle (the emulators' shafts) within 0.5°, each
    referenced (or needing no reference)."""
    assert main(["gantry", "status", "--config", path, "--json"]) == 0
    after = {a["axis"]: a for a in json.loads(capsys.readouterr().out)["axes"]}
    truth = emu.axes_deg()
    for name, a in after.items():
        assert a["position_deg"] == pytest.approx(truth[name], abs=0.5), name
        assert a["referenced"] in (True, None)


def test_reference_finds_the_true_angles_then_home_drives_there_and_the_carriages_keep_apart(fast_twin,
                                                                                           capsys):
    """The detector carriage really stands at 180° and reads 0°; after `gonio gantry reference` every axis
    reads its true angle within 0.5°, `gonio gantry home` works, and the carriages never came within
    arm_collision_deg of each other on the way (the emulators' true shafts, watched throughout)."""
    emu, path, clock = fast_twin
    assert main(["gantry", "status", "--config", path, "--json"]) == 0
    before = {a["axis"]: a for a in json.loads(capsys.readouterr().out)["axes"]}
    assert before["detector_azimuth"]["position_deg"] == pytest.approx(0.0, abs=0.1)
    assert before["detector_azimuth"]["referenced"] is False and before["light_tilt"]["referenced"] is None
    gaps: list[float] = []
    clock.watch = lambda: gaps.append(ring_gap(emu.axes_deg()))   # the emulators' true shafts
    assert main(["gantry", "reference", "--config", path]) == 0
    out = capsys.readouterr().out
    assert "light_azimuth: referenced (hard_stop" in out and "detector_azimuth: referenced" in out
    assert "-0.00°" not in out   # a stop found a hair short of its place read "-0.00° from -200°"
    _assert_referenced_at_the_true_angles(emu, path, capsys)
    assert main(["gantry", "home", "--config", path]) == 0
    assert len(gaps) > 100   # looked at throughout
    home = emu.axes_deg()
    assert home["light_azimuth"] == pytest.approx(0.0, abs=0.1)
    assert home["detector_azimuth"] == pytest.approx(180.0, abs=0.1)
    assert min(gaps) >= load_config(TWIN).kinematics.arm_collision_deg, min(gaps)


@pytest.mark.parametrize("fast_twin", [0.5], indirect=True)   # the shipped bus watchdog
def test_a_reference_held_up_past_the_bus_watchdog_starts_the_approach_again(fast_twin, capsys):
    """Mid-approach this host is held up for 1 s (a loaded machine): both carriages' bus watchdogs (0.5 s)
    fire and stop them short of the stop. That is not the stop: the reference says what happened, clears
    the watchdogs, approaches again and finds the true angles (before, the stopped servo passed for one
    stalled against its stop and the goal written then was refused: goal locked by the watchdog)."""
    emu, path, clock = fast_twin
    sleeps = []

    def held_up():
        sleeps.append(clock.now())
        if len(sleeps) == 40:   # 0.2 s into the approach: the carriages at speed, far from the stop
            SyncedVirtualClock.sleep(clock, 1.0)

    clock.watch = held_up
    assert main(["gantry", "reference", "--config", path]) == 0
    out = capsys.readouterr().out
    assert "bus watchdog fired" in out and "the approach starts again (1 of 3)" in out, out
    assert any(s.watchdog_fired_at is not None for s in emu.servos.values())
    _assert_referenced_at_the_true_angles(emu, path, capsys)


def _virtual_twin(**kw):
    clock = SyncedVirtualClock()
    return EmulatedGantry(load_config(TWIN), clock=clock, any_port=True, **kw), clock


def test_a_reference_survives_a_restart_of_gonio_but_not_a_power_cycle():
    emu, clock = _virtual_twin()
    with emu:
        cfg = emu.config()
        g = build_gantry(cfg, clock=clock)
        axes = manual.connect_axes(g)
        assert unreferenced(axes) == ["light_azimuth", "detector_azimuth"]
        with pytest.raises(NotReferencedFault, match="gonio gantry reference"):
            g.axes["detector_azimuth"].move_to(170.0)
        reference_axes(g, cfg, out=lambda line: None)
        assert unreferenced(axes) == []
        manual.close_axes(axes)
        g2 = build_gantry(cfg, clock=clock)  # another gonio process: the servos kept their marker
        axes = manual.connect_axes(g2)
        truth = emu.axes_deg()
        assert unreferenced(axes) == []
        assert axes["detector_azimuth"].position_deg() == pytest.approx(truth["detector_azimuth"], abs=0.1)
        manual.close_axes(axes)
        servo = emu.servos["detector_azimuth"]
        servo.power_off()
        servo.power_on()  # its RAM back at power-up values: the marker and the turn count are gone
        g3 = build_gantry(cfg, clock=clock)
        axes = manual.connect_axes(g3)
        assert unreferenced(axes) == ["detector_azimuth"]
        assert axes["detector_azimuth"].position_deg() != pytest.approx(truth["detector_azimuth"], abs=1.0)
        manual.close_axes(axes)


def test_a_stall_away_from_the_configured_stop_is_refused_and_leaves_the_axis_unreferenced():
    """The light carriage's stop is 40° inside where the config says: the stall lands between turns of
    the servo's encoder that the config allows (more than a quarter turn off), so the reference is
    refused, naming the way out, and nothing is referenced."""
    data = load_config(TWIN).model_dump(mode="json")
    clock = SyncedVirtualClock()
    with EmulatedGantry(parse_config(data), clock=clock, any_port=True) as emu:
        servo = emu.servos["light_azimuth"]
        lo, hi = servo.stops_ticks
        servo.stops_ticks = (lo + 40.0 * 4096 * 4 / 360, hi)
        cfg = emu.config()
        g = build_gantry(cfg, clock=clock)
        axes = manual.connect_axes(g)
        try:
            with pytest.raises(DeviceFault, match="homing_offset_ticks"):
                reference_axes(g, cfg, ["light_azimuth"], out=lambda line: None)
            assert "light_azimuth" in unreferenced(axes)
            assert emu.servos["light_azimuth"].value(11) == 4  # back in extended position mode
        finally:
            manual.close_axes(axes)


def test_a_campaign_journals_the_references_and_refuses_to_start_without_them(tmp_path, capsys):
    emu, clock = _virtual_twin()
    with emu:
        cfg = emu.config()
        c = create_campaign(tmp_path / "c", cfg, grid="iso:step=45", material=None, sample="s")
        try:
            with pytest.raises(NotReferencedFault, match="not referenced"):
                run_campaign(c, build_gantry(cfg, clock=clock))
            assert c.journal.done_count() == 0
            g = build_gantry(cfg, clock=clock)
            axes = manual.connect_axes(g)
            reference_axes(g, cfg, out=lambda line: None)
            manual.close_axes(axes)
            state, runner = run_campaign(c, build_gantry(cfg, clock=clock))
            assert state == "done", runner.fault
            events = c.journal.events()
        finally:
            c.close()
    kinds = [e["kind"] for e in events]
    refused = next(e for e in events if e["kind"] == "fault")
    assert "not started" in refused["message"] and "gonio gantry reference" in refused["message"]
    ref = [e for e in events if e["kind"] == "reference"]
    assert "NOT referenced" in ref[0]["message"]
    assert "light_azimuth referenced (hard_stop)" in ref[-1]["message"]
    assert "detector_azimuth referenced (hard_stop)" in ref[-1]["message"]
    assert kinds.count("fault") == 1


def test_gonio_run_on_an_unreferenced_gantry_is_refused_with_nothing_written(tmp_path, capsys):
    emu, _clock = _virtual_twin()
    with emu:
        path = tmp_path / "gantry.toml"
        path.write_text(emu.config_toml())
        n = len(emu.emulators["arm"].received)
        out = tmp_path / "run"
        assert main(["run", "--config", str(path), "--grid", "iso:step=45", "--out", str(out),
                     "--sample", "s"]) == 2
        (line,) = capsys.readouterr().err.strip().splitlines()
        assert "not referenced" in line and "gonio gantry reference" in line
        assert not out.exists() and writes(emu, n) == []
        assert not (tmp_path / "run" / JOURNAL_NAME).exists()


@pytest.mark.parametrize(("edit", "field"), [
    (lambda a: a.update(reference_deg=-250.0),
     "axes.light_azimuth: reference_deg: -250 is outside the axis limit"),
    (lambda a: a.update(reference="origin"), "reference: 'origin' is not a method of a dynamixel axis"),
    (lambda a: a.update(reference_velocity_deg_s=90.0), "reference_velocity_deg_s: 90 is above max_velocity"),
])
def test_a_bad_reference_setting_is_one_line_naming_the_file_and_field(tmp_path, capsys, edit, field):
    data = load_config(TWIN).model_dump(mode="json", exclude_defaults=True)
    edit(data["axes"]["light_azimuth"])
    from gonio.sim.emulators.gantry import to_toml

    path = tmp_path / "bad.toml"
    path.write_text(to_toml(data))
    assert main(["gantry", "status", "--config", str(path)]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert str(path) in line and field in line, line


def test_hard_stop_needs_current_based_position_mode(tmp_path):
    data = load_config(TWIN).model_dump(mode="json")
    data["axes"]["light_azimuth"]["family"] = "XL430"
    with pytest.raises(ValueError, match="'hard_stop' needs current-based position mode, which the XL430"):
        parse_config(data)


def test_an_incremental_modbus_drive_is_referenced_by_its_origin_and_loses_it_at_power_off():
    """A Leadshine closed-loop stepper (incremental): it counts from where it powered up, so the axis is
    refused until its homing ran; then it reads true positions; a power cycle loses the origin again."""
    clock = SyncedVirtualClock()
    emu = ModbusMotorEmulator("leadshine_pr", clock=clock)
    emu.home_steps = 0.0
    emu.set_position(2500)  # the shaft at 90° (10000 steps per turn): the drive counts 2500 from there
    emu.power_cycle()
    url = f"rtu://{emu.start_rtu()}?baudrate=115200"
    axis = ModbusAxis("stage", make_client(url, timeout_s=0.2, retries=0), "leadshine_pr",
                      limits_deg=(-180.0, 180.0), velocity_deg_s=90.0, accel_deg_s2=180.0, clock=clock)
    try:
        axis.connect()
        assert axis.reference_method == "origin" and not axis.referenced()
        assert axis.position_deg() == 0.0  # it says 0° where it stands at 90°
        n = len(emu.requests)
        with pytest.raises(NotReferencedFault, match="no origin set"):
            axis.move_to(10.0)
        assert len(emu.requests) == n  # refused before anything was sent
        axis.reference_origin(timeout_s=30.0, poll_s=0.05)
        assert axis.referenced() and axis.position_deg() == pytest.approx(0.0)
        assert emu.position_steps_f() == pytest.approx(0.0)  # at the home sensor
        axis.move_to(45.0)
        for _ in range(100):
            clock.sleep(0.05)
            if not axis.is_moving():
                break
        assert axis.position_deg() == pytest.approx(45.0) and emu.position_steps_f() == pytest.approx(1250.0)
        emu.power_cycle()
        axis.is_moving()
        assert not axis.referenced()
        with pytest.raises(NotReferencedFault):
            axis.move_to(0.0)
    finally:
        axis.close()
        emu.stop()


def test_the_emulated_sample_stage_needs_its_changer_referenced_and_gonio_gantry_reference_does_it(capsys):
    clock = SyncedVirtualClock()
    with EmulatedGantry(load_config("emulated-sample-stage-modbus"), clock=clock, any_port=True) as emu:
        cfg = emu.config()
        g = build_gantry(cfg, clock=clock)
        axes = manual.connect_axes(g)
        try:
            assert unreferenced(axes) == ["changer"]
            found = reference_axes(g, cfg, out=lambda line: None)
            assert found == {"changer": 0.0} and unreferenced(axes) == []
            assert np.isclose(axes["changer"].position_deg(), emu.axes_deg()["changer"])
        finally:
            manual.close_axes(axes)


def test_gonio_gantry_reference_axis_names_one_axis_and_refuses_others(tmp_path, capsys):
    with EmulatedGantry(load_config("emulated-sample-stage-modbus"), clock=WallClock(), any_port=True) as emu:
        path = tmp_path / "gantry.toml"
        path.write_text(emu.config_toml())
        assert main(["gantry", "reference", "--config", str(path), "--axis", "nowhere"]) == 2
        assert "--axis: 'nowhere' is not one of" in capsys.readouterr().err
        assert main(["gantry", "reference", "--config", str(path), "--axis", "sample_tilt"]) == 2
        (line,) = capsys.readouterr().err.strip().splitlines()
        assert "'sample_tilt' needs no reference" in line and "changer" in line
        assert not emu.motors["changer"].referenced
        assert main(["gantry", "reference", "--config", str(path), "--axis", "changer"]) == 0
        assert "changer: referenced (origin)" in capsys.readouterr().out
        assert emu.motors["changer"].referenced
