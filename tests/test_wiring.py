"""Config schema of mixed gantries, the wiring of emulated devices, and ``gonio gantry`` manual control."""

from __future__ import annotations

import time

import pytest

from gonio.cli import main
from gonio.clock import WallClock
from gonio.config import ConfigError, load_config, parse_config, relocate
from gonio.gantry import AssembledGantry
from gonio.sim.emulators.gantry import EmulatedGantry
from gonio.sim.emulators.link import SyncedVirtualClock
from gonio.wiring import build_gantry

TWIN = "emulated-two-arm-dynamixel"


def _data(name=TWIN):
    return load_config(name).model_dump(mode="json")


@pytest.mark.parametrize(("edit", "message"), [
    (lambda d: d["axes"]["light_tilt"].update(bus="nowhere"),
     "axes.light_tilt.bus: no [buses.nowhere] section"),
    (lambda d: d["buses"].update(arm={"driver": "modbus", "url": "tcp://127.0.0.1:1"}),
     "axes.light_azimuth.bus: a 'dynamixel' device cannot be on bus 'arm', a 'modbus' bus"),
    (lambda d: d["axes"]["light_tilt"].update(id=1),
     "axes.light_tilt: bus 'arm' id 1 is also axes.light_azimuth"),
    (lambda d: d["axes"]["light_tilt"].update(profile="leadshine_pr"),
     "profile: not a setting of a 'dynamixel' axis"),
    (lambda d: (d["target"].update(axis=None), d["axes"].pop("changer")),
     "target.axis: a real detector needs an axis"),
    (lambda d: d["detector"]["sim"].update(aperture_samples=1), "greater than or equal to 2"),
    (lambda d: d["light"].update(radiance=5.0), "light.radiance: unknown key"),
])
def test_config_errors_name_the_field(edit, message):
    data = _data()
    edit(data)
    with pytest.raises(ConfigError, match=message.replace("[", r"\[").replace("]", r"\]")):
        parse_config(data, "x.toml")


def test_twins_differ_only_in_where_buses_are_reached():
    for real, twin in (("two-arm-dynamixel", TWIN), ("sample-stage-modbus", "emulated-sample-stage-modbus")):
        a, b = load_config(real), load_config(twin)
        assert a != b
        assert relocate(a, b) == b


def test_devices_on_one_bus_share_one_bus_object():
    g = build_gantry(load_config(TWIN))
    assert isinstance(g, AssembledGantry) and isinstance(g.clock, WallClock)
    buses = {id(a.bus) for a in g.all_axes.values()}
    assert len(buses) == 1


def _emulated(tmp_path, clock):
    data = _data()
    for axis in data["axes"].values():
        axis.update(gear_ratio=1.0, max_velocity_deg_s=250.0, max_accel_deg_s2=5000.0)
    data["runner"].update(poll_s=0.005)
    with EmulatedGantry(parse_config(data), clock=clock, any_port=True, referenced=True) as emu:
        path = tmp_path / "gantry.toml"
        path.write_text(emu.config_toml())
        yield emu, str(path)


@pytest.fixture
def emulated(tmp_path):
    """The two-arm twin emulated on the wall clock with fast motion; its config file with the ptys."""
    yield from _emulated(tmp_path, WallClock())


@pytest.fixture
def emulated_virtual(tmp_path, monkeypatch):
    """As :func:`emulated` on a synced virtual clock that is also the CLI's wall clock (the gantry commands
    run in this process; where the test is not about the servos moving in real time)."""
    clock = SyncedVirtualClock()
    monkeypatch.setattr("gonio.wiring.WallClock", lambda: clock)
    yield from _emulated(tmp_path, clock)


def _ticks(emu):
    return {n: s.value(132) for n, s in emu.servos.items()}


@pytest.mark.parametrize(("args", "message"), [
    (["--axes", "0,95,180,0"], "axis 'light_tilt': target 95° is outside the limit [-90°, 90°]"),
    (["--axes", "0,0,3,0"], "no collision-free path"),
    (["--theta-i", "30", "--phi-i", "0", "--theta-o", "31", "--phi-o", "0"], "occlusion"),
    (["--theta-i", "85", "--phi-i", "0", "--theta-o", "30", "--phi-o", "180"], "beyond_theta_max"),
    # NaN said in the degrees it was given (it read "NaN or inf is not an angle; give finite radians")
    (["--theta-i", "nan", "--phi-i", "0", "--theta-o", "30", "--phi-o", "180"],
     "--theta-i: must be a finite number of degrees, got nan"),
    (["--axes", "0,nan,0,0"], "--axes: axis light_tilt: must be a finite number of degrees, got nan"),
])
def test_gantry_move_refuses_before_anything_moves(emulated_virtual, capsys, args, message):
    emu, path = emulated_virtual
    before = _ticks(emu)
    assert main(["gantry", "move", "--config", path, *args]) == 2
    assert message in capsys.readouterr().err
    assert _ticks(emu) == before
    assert all(not s._moving() for s in emu.servos.values())


def test_gantry_jog_by_an_infinite_step_is_refused_in_degrees(emulated_virtual, capsys):
    emu, path = emulated_virtual
    before = _ticks(emu)
    assert main(["gantry", "jog", "--config", path, "--axis", "light_tilt", "--by", "inf"]) == 2
    assert "--by: must be a finite number of degrees, got inf" in capsys.readouterr().err
    assert _ticks(emu) == before


def test_gantry_move_and_status(emulated, capsys):
    emu, path = emulated
    assert main(["gantry", "move", "--config", path, "--theta-i", "30", "--phi-i", "0", "--theta-o", "30",
                 "--phi-o", "180"]) == 0
    assert abs(emu.axes_deg()["light_tilt"] - 30.0) < 0.1
    capsys.readouterr()
    assert main(["gantry", "status", "--config", path, "--json"]) == 0
    import json

    status = json.loads(capsys.readouterr().out)
    tilt = next(a for a in status["axes"] if a["axis"] == "light_tilt")
    assert tilt["units"] == "ticks" and tilt["target_units"] == 2048 + round(30 * 4096 / 360)
    assert abs(tilt["position_deg"] - 30.0) < 0.1


def test_gantry_home_from_a_pose_read_back_a_tick_inside_the_carriages_clearance(emulated_virtual, capsys):
    """Carriages sent exactly arm_collision_deg = 10° apart stop on the nearest encoder ticks: the light
    rounds up and the detector down (0.0686° closer than 10°, each axis within its 0.05° tolerance).
    From that read-back no path was clear, not even home; it may be left, not approached."""
    emu, path = emulated_virtual
    light = 1877.6 * 360 / 4096                                  # 0.6 of a tick: rounds up
    assert main(["gantry", "move", "--config", path, "--axes", f"{light},0,{light + 10},0"]) == 0
    at = emu.axes_deg()
    assert 9.9 < at["detector_azimuth"] - at["light_azimuth"] < 10.0
    capsys.readouterr()
    assert main(["gantry", "move", "--config", path, "--axes", f"{light + 1},0,{light + 10},0"]) == 2
    assert "no collision-free path" in capsys.readouterr().err     # closer still: refused
    assert main(["gantry", "home", "--config", path]) == 0
    assert abs(emu.axes_deg()["light_azimuth"]) < 0.1 and abs(emu.axes_deg()["detector_azimuth"] - 180) < 0.1


def test_gantry_stop_stops_every_axis_on_every_bus(emulated, capsys):
    emu, path = emulated
    g = build_gantry(load_config(path))
    for axis in g.all_axes.values():
        axis.connect()
    try:
        g.axes["light_azimuth"].move_to(150.0)
        g.axes["detector_tilt"].move_to(80.0)
        g.changer.axis.move_to(90.0)
        assert sum(s._moving() for s in emu.servos.values()) == 3
        assert main(["gantry", "stop", "--config", path]) == 0
        assert "stopped 5 axes" in capsys.readouterr().out
        for _ in range(200):  # each servo brakes from where it was; bounded wait on the wall clock
            if not any(s._moving() for s in emu.servos.values()):
                break
            time.sleep(0.01)
        assert not any(s._moving() for s in emu.servos.values())
        assert emu.axes_deg()["light_azimuth"] < 150.0 - 1.0  # stopped short, well before the target
    finally:
        for axis in g.all_axes.values():
            axis.close()
