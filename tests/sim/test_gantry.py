"""The simulated gantry: wiring from a config, target selection, stop, power-up position, close."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.clock import VirtualClock
from gonio.config import DEFAULT_CONFIG, load_config
from gonio.motion.trapezoid import move_time
from gonio.protocols import DeviceFault, Gantry
from gonio.sim import materials
from gonio.sim.axis import SimAxis
from gonio.sim.gantry import SimGantry

SAMPLE_STAGE = DEFAULT_CONFIG.parent / "sample-stage.toml"


def connected(cfg=None, material="lambert:albedo=0.8", **kwargs) -> SimGantry:
    gantry = SimGantry.from_config(cfg or load_config(), material, **kwargs)
    gantry.connect()
    return gantry


def test_from_config_wires_every_device_on_one_clock():
    cfg = load_config()
    clock = VirtualClock(start=12.0)
    gantry = SimGantry.from_config(cfg, "lambert:albedo=0.8", clock=clock)
    assert isinstance(gantry, Gantry)
    assert gantry.name == cfg.name and gantry.clock is clock
    assert tuple(gantry.axes) == gantry.kinematics.axis_names == cfg.axis_names
    assert all(isinstance(a, SimAxis) and a.name == n for n, a in gantry.axes.items())
    assert gantry.axes["detector_azimuth"].limits_deg == (-200.0, 200.0)
    assert gantry.target == "sample"
    # No I/O in the constructor: nothing is connected until connect().
    with pytest.raises(DeviceFault, match="not connected"):
        gantry.axes["light_tilt"].position_deg()
    with pytest.raises(DeviceFault, match="not connected"):
        gantry.detector.measure(0.1)
    gantry.connect()
    gantry.axes["light_tilt"].move_to(30.0)
    gantry.detector.measure(0.5)
    assert clock.now() == 12.5  # the detector integrates on the injected clock


def test_default_clock_is_a_fresh_virtual_clock():
    a, b = (SimGantry.from_config(load_config(), "lambert:albedo=0.5") for _ in range(2))
    assert isinstance(a.clock, VirtualClock) and a.clock.now() == 0.0 and a.clock is not b.clock


def test_material_may_be_a_spec_or_a_loaded_material():
    spec = "cook-torrance:d=beckmann,m=0.3,metal=gold"
    by_spec, by_object = connected(material=spec), connected(material=materials.load(spec))
    for gantry in (by_spec, by_object):
        gantry.light.set_on(True)
    axes = np.array([[0.0, 30.0, 180.0, 35.0], [0.0, 50.0, 120.0, 20.0]])
    np.testing.assert_array_equal(by_spec.detector.expected_signal(axes),
                                  by_object.detector.expected_signal(axes))
    with pytest.raises(ValueError, match="seed"):
        SimGantry.from_config(load_config(), spec, seed=-1)


def test_set_target_switches_between_sample_and_white_standard():
    gantry = connected(material="lambert:albedo=0.2")
    gantry.light.set_on(True)
    sample = gantry.detector.measure(0.1).signal
    gantry.set_target("reference")
    assert gantry.target == "reference"
    white = gantry.detector.measure(0.1).signal
    np.testing.assert_allclose(sample / white, 0.2 / load_config().reference.albedo, rtol=1e-3)
    with pytest.raises(ValueError) as err:
        gantry.set_target("dark")
    assert str(err.value) == "target: 'dark' is not one of 'sample', 'reference'"
    assert gantry.target == "reference"  # a rejected target changes nothing


def test_stop_brakes_every_axis_short_of_its_target():
    gantry = connected()
    targets = {"light_azimuth": 150.0, "light_tilt": 70.0, "detector_azimuth": -150.0, "detector_tilt": -70.0}
    for name, target in targets.items():
        gantry.axes[name].move_to(target)
    gantry.clock.sleep(1.0)
    gantry.stop()
    slowest_brake = max(a.cfg.max_velocity_deg_s / a.cfg.max_accel_deg_s2 for a in gantry.axes.values())
    gantry.clock.sleep(slowest_brake)
    for name, axis in gantry.axes.items():
        assert not axis.is_moving()
        home, target = axis.cfg.home_deg, targets[name]
        # Stopped on the way: past where it was, short of the target.
        assert min(home, target) < axis.position_deg() < max(home, target)


def test_wait_until_still_waits_exactly_as_long_as_the_slowest_axis():
    gantry = connected()
    gantry.axes["light_tilt"].move_to(60.0)
    gantry.axes["detector_azimuth"].move_to(-100.0)
    t0 = gantry.clock.now()
    gantry.wait_until_still()
    tilt, azimuth = gantry.axes["light_tilt"].cfg, gantry.axes["detector_azimuth"].cfg
    expect = max(float(move_time(60.0, tilt.max_velocity_deg_s, tilt.max_accel_deg_s2)),
                 float(move_time(280.0, azimuth.max_velocity_deg_s, azimuth.max_accel_deg_s2)))
    assert gantry.clock.now() - t0 == pytest.approx(expect, rel=1e-12)
    assert gantry.axes["light_tilt"].position_deg() == 60.0
    assert gantry.axes["detector_azimuth"].position_deg() == -100.0


def test_wait_until_still_lets_a_brake_finish():
    gantry = connected()
    gantry.axes["light_azimuth"].move_to(190.0)
    gantry.clock.sleep(1.5)
    gantry.stop()
    assert gantry.axes["light_azimuth"].is_moving()
    gantry.wait_until_still()
    assert not gantry.axes["light_azimuth"].is_moving()
    assert 0.0 < gantry.axes["light_azimuth"].position_deg() < 190.0


def test_axes_power_up_where_they_are_told_and_refuse_a_start_beyond_the_limits():
    cfg = load_config()
    start = [10.0, -20.0, 150.0, 30.0]
    gantry = connected(cfg, start_deg=start)
    assert [a.position_deg() for a in gantry.axes.values()] == start
    with pytest.raises(ValueError, match="light_tilt.*start_deg 97.0 is outside the limit"):
        SimGantry.from_config(cfg, "lambert:albedo=0.5", start_deg=[0.0, 97.0, 180.0, 0.0])
    with pytest.raises(ValueError, match="start_deg: 3 positions"):
        SimGantry.from_config(cfg, "lambert:albedo=0.5", start_deg=[0.0, 0.0, 0.0])


def test_close_closes_every_device():
    gantry = connected()
    gantry.close()
    calls = (gantry.axes["light_tilt"].is_moving, gantry.light.is_on, lambda: gantry.detector.measure(0.1))
    for call in calls:
        with pytest.raises(DeviceFault, match="not connected"):
            call()


def test_the_sample_stage_design_wires_its_own_axes():
    cfg = load_config(SAMPLE_STAGE)
    gantry = connected(cfg)
    assert tuple(gantry.axes) == cfg.axis_names
    gantry.light.set_on(True)
    assert np.all(gantry.detector.measure(0.1).signal >= 0.0)
    for axis in gantry.axes.values():
        assert axis.position_deg() == axis.cfg.home_deg


def test_constructor_rejects_axes_that_do_not_match_the_kinematics():
    gantry = SimGantry.from_config(load_config(), "lambert:albedo=0.5")
    axes = dict(gantry.axes)
    del axes["detector_tilt"]
    with pytest.raises(ValueError, match="axes: must be exactly .*; missing: detector_tilt"):
        SimGantry("x", gantry.kinematics, axes, gantry.light, gantry.detector, gantry.clock)
