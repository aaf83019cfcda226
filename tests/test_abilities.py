"""Declared abilities (gonio.protocols): what each shipped device declares, the fly check that asks the
declarations (a detector that cannot read on the fly is refused, whatever it is), and every device's
describe() journaled when a campaign connects."""

from __future__ import annotations

import numpy as np
import pytest

from gonio import protocols as P
from gonio.campaign import create_campaign
from gonio.config import load_config
from gonio.fly.units import check_fly_gantry
from gonio.gantry import abilities
from gonio.lifecycle import Request, plan_request, run_campaign
from gonio.protocols import Reading
from gonio.runner import State
from gonio.sim.emulators.gantry import EMULATOR_LATENCY_MS, EmulatedGantry
from gonio.sim.emulators.link import SyncedVirtualClock
from gonio.wiring import build_gantry

TWIN = "emulated-two-arm-dynamixel"
MATERIAL = "lambert:albedo=0.5"


def _declared(device) -> set[str]:
    names = ["Describes", "Referencing", "ChecksTarget", "Flyable", "ReadsState", "SharesConnection",
             "TimesRoundTrip", "Warns", "CountsLink", "HoldsAtGoal", "JoinsGroup", "ReportsDeviceUnits",
             "ReferencesIndex", "SeeksStop", "ReferencesOrigin", "Follows", "SwitchesTarget", "ReadsOnTheFly"]
    return {n for n in names if isinstance(device, getattr(P, n))}


def test_each_shipped_device_declares_what_it_can():
    twin = build_gantry(load_config(TWIN))             # Dynamixel servos, a changer, serial instruments
    servo = twin.axes["detector_azimuth"]
    assert {"Describes", "Referencing", "ChecksTarget", "Flyable", "JoinsGroup", "HoldsAtGoal", "Warns",
            "CountsLink", "ReportsDeviceUnits", "Follows"} <= _declared(servo)
    assert "ReadsOnTheFly" in _declared(twin.detector) and "Describes" in _declared(twin.light)
    modbus = build_gantry(load_config("sample-stage-modbus"))
    motor = next(iter(modbus.axes.values()))
    assert {"Describes", "ChecksTarget", "ReadsState", "SharesConnection", "TimesRoundTrip", "CountsLink",
            "ReportsDeviceUnits"} <= _declared(motor)
    assert "Flyable" not in _declared(motor) and "JoinsGroup" not in _declared(motor)
    sim = build_gantry(load_config("sim"), MATERIAL)
    assert _declared(sim.axes["light_tilt"]) == {"Describes"}
    assert {"ReadsOnTheFly", "SwitchesTarget", "Describes"} <= _declared(sim.detector)
    can = abilities(sim)
    assert can.renders_fly is sim and can.batched is None and can.flies is None
    can = abilities(twin)
    assert can.batched is twin and can.flies is twin and can.keep_alive is twin and can.renders_fly is None
    assert twin.can_sweep("detector_azimuth")
    assert not modbus.can_sweep(next(iter(modbus.axes)))


class _Camera:
    """A real camera's driver as it would be written: it measures a frame on request, and declares no
    reading on the fly."""

    name, channels = "detector", ("R", "G", "B")

    def connect(self):
        pass

    def close(self):
        pass

    def measure(self, exposure_s, frames=1, *, key=None):
        return Reading(np.zeros(3), np.zeros(3), exposure_s, frames)


def test_a_detector_that_cannot_read_on_the_fly_is_refused_not_only_the_simulated_camera():
    cfg = load_config(TWIN)
    planned = plan_request(cfg, Request("iso:step=30,order=fly", sample="gold"))
    gantry = build_gantry(cfg)
    check_fly_gantry(gantry, cfg, planned.fly)          # servos that fly, a power meter: it can
    gantry.detector = _Camera()
    assert isinstance(gantry.detector, P.Detector) and not isinstance(gantry.detector, P.ReadsOnTheFly)
    with pytest.raises(ValueError, match="cannot read while the axes sweep"):
        check_fly_gantry(gantry, cfg, planned.fly)


def test_every_device_describes_itself_into_the_journal_at_connect(tmp_path):
    clock = SyncedVirtualClock()
    with EmulatedGantry(load_config(TWIN), MATERIAL, clock=clock, any_port=True, referenced=True) as emu:
        cfg = emu.config()
        # the servos' emulator is a thread of a loaded host: its replies are allowed a longer latency
        shipped = load_config(TWIN).buses["arm"].latency_timer_ms
        assert cfg.buses["arm"].latency_timer_ms == EMULATOR_LATENCY_MS > shipped
        c = create_campaign(tmp_path / "c", cfg, grid="iso:step=45,theta_max=45", material=None, sample="x")
        try:
            state, runner = run_campaign(c, build_gantry(cfg, clock=clock))
            assert state == State.DONE, runner.fault
            devices, events = c.meta["devices"], c.journal.events()
        finally:
            c.close()
    # every axis (the changer's too), the lamp and the meter
    assert set(devices) == {*cfg.axes, "light", "detector"}
    servo = devices["detector_azimuth"]
    assert servo["driver"] == "dynamixel" and servo["identity"] == "XM430-W350"
    assert servo["firmware"] == 45              # the emulated servo's Firmware Version, from its Ping
    assert servo["units"] == "ticks" and servo["settings"]["id"] == cfg.axes["detector_azimuth"].id
    assert devices["detector"]["identity"] == emu.meter.idn
    (line,) = [e["message"] for e in events if e["kind"] == "devices"]
    assert "detector_azimuth: dynamixel 'XM430-W350' firmware 45" in line
