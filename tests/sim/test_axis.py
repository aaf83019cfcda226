"""The simulated axis: trapezoidal moves on the virtual clock, limits, encoder counts, stop, faults."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gonio.clock import VirtualClock
from gonio.config import AxisConfig, AxisSimConfig, load_config
from gonio.motion.trapezoid import move_time, position_at
from gonio.protocols import Axis, DeviceFault
from gonio.sim.axis import SimAxis

TILT = load_config().axes["light_tilt"]  # [-90°, 90°], 45 °/s, 90 °/s²


def make_axis(cfg: AxisConfig = TILT, name: str = "light_tilt") -> tuple[SimAxis, VirtualClock]:
    clock = VirtualClock()
    axis = SimAxis(name, cfg, clock)
    axis.connect()
    return axis, clock


def advance_to(clock: VirtualClock, t_s: float) -> None:
    clock.sleep(t_s - clock.now())


def test_satisfies_the_axis_protocol_and_starts_at_home():
    cfg = load_config().axes["detector_azimuth"]
    axis, _ = make_axis(cfg, "detector_azimuth")
    assert isinstance(axis, Axis)
    assert axis.limits_deg == (cfg.min_deg, cfg.max_deg)
    assert axis.position_deg() == cfg.home_deg == 180.0
    assert not axis.is_moving()


@pytest.mark.parametrize("target", [60.0, -2.0, 45.0**2 / 90.0])  # cruise, triangle, just at v_max
def test_move_follows_the_trapezoid_and_arrives_exactly_at_move_time(target):
    axis, clock = make_axis()
    v, a = TILT.max_velocity_deg_s, TILT.max_accel_deg_s2
    total = float(move_time(target, v, a))
    axis.move_to(target)  # returns at once: no virtual time passes
    assert clock.now() == 0.0 and axis.is_moving()
    for frac in (0.1, 0.25, 0.5, 0.8, 0.99):
        advance_to(clock, frac * total)
        assert axis.position_deg() == pytest.approx(float(position_at(frac * total, 0.0, target, v, a)),
                                                   abs=1e-12)
        assert axis.is_moving()
        if frac == 0.5:  # the profile is symmetric: half-way in time is half-way in distance
            assert axis.position_deg() == pytest.approx(0.5 * target, abs=1e-12)
    advance_to(clock, total - 1e-6)
    assert axis.is_moving() and axis.position_deg() != target
    advance_to(clock, total)
    assert not axis.is_moving()
    assert axis.position_deg() == target
    assert axis.arrival_time_s() == total


def test_cruise_speed_is_the_configured_maximum():
    axis, clock = make_axis()
    axis.move_to(80.0)  # 80° at 45 °/s and 90 °/s²: cruises from 0.5 s to 1.78 s
    advance_to(clock, 1.0)
    x0 = axis.position_deg()
    advance_to(clock, 1.2)
    assert (axis.position_deg() - x0) / 0.2 == pytest.approx(TILT.max_velocity_deg_s, rel=1e-12)


def test_a_new_move_starts_from_where_the_last_one_ended():
    axis, clock = make_axis()
    axis.move_to(30.0)
    clock.sleep(10.0)
    axis.move_to(-20.0)
    t0 = clock.now()
    clock.sleep(0.7)
    v, a = TILT.max_velocity_deg_s, TILT.max_accel_deg_s2
    assert axis.position_deg() == pytest.approx(float(position_at(clock.now() - t0, 30.0, -20.0, v, a)))


def test_an_arrived_axis_sits_exactly_on_its_target():
    axis, clock = make_axis()
    # For each of these steps start + (target − start) misses target by an ulp: arrival must not.
    for target in (-82.6, 10.1, -87.0, 46.4, 56.9, -28.0):
        axis.move_to(target)
        clock.sleep(10.0)
        assert axis.position_deg() == target


def test_move_while_moving_is_refused():
    axis, clock = make_axis()
    axis.move_to(60.0)
    clock.sleep(0.3)
    with pytest.raises(RuntimeError, match="light_tilt.*while still moving"):
        axis.move_to(10.0)


def test_target_outside_the_limits_is_rejected_with_the_allowed_range():
    axis, clock = make_axis()
    with pytest.raises(ValueError) as err:
        axis.move_to(97.0)
    assert str(err.value) == "axis 'light_tilt': target 97.0° is outside the limit [-90°, 90°]"
    with pytest.raises(ValueError, match=r"outside the limit \[-90°, 90°\]"):
        axis.move_to(-90.5)
    with pytest.raises(ValueError, match="light_tilt"):
        axis.move_to(math.nan)
    assert not axis.is_moving() and axis.position_deg() == 0.0
    axis.move_to(90.0)  # the limit itself is allowed
    clock.sleep(10.0)
    assert axis.position_deg() == 90.0


def test_encoder_resolution_quantizes_the_settled_and_reported_position():
    res = 360.0 / 4096  # a 12-bit servo encoder
    cfg = TILT.model_copy(update={"sim": AxisSimConfig(resolution_deg=res)})
    axis, clock = make_axis(cfg)
    axis.move_to(10.0)
    clock.sleep(0.3)  # mid-move: the shaft is between counts, the encoder reports a count
    assert axis.true_position_deg() % res != pytest.approx(0.0, abs=1e-9)
    assert axis.position_deg() / res == pytest.approx(round(axis.position_deg() / res), abs=1e-9)
    assert abs(axis.position_deg() - axis.true_position_deg()) <= res / 2 + 1e-12
    clock.sleep(10.0)
    settled = axis.position_deg()
    assert settled != 10.0  # commanded and actual differ, as on a real servo
    assert abs(settled - 10.0) <= res / 2
    assert settled == pytest.approx(round(10.0 / res) * res, abs=1e-12)
    assert axis.true_position_deg() == settled


def test_a_limit_off_the_encoder_grid_settles_one_count_inside():
    cfg = TILT.model_copy(update={"sim": AxisSimConfig(resolution_deg=0.7)})  # 90 / 0.7 = 128.57 counts
    axis, clock = make_axis(cfg)
    axis.move_to(90.0)
    clock.sleep(10.0)
    assert axis.position_deg() == pytest.approx(128 * 0.7)
    assert axis.position_deg() <= 90.0


def test_stop_brakes_at_full_deceleration_and_holds():
    axis, clock = make_axis()
    v, a = TILT.max_velocity_deg_s, TILT.max_accel_deg_s2
    axis.move_to(80.0)
    advance_to(clock, 1.0)  # cruising at v_max
    x_stop = axis.position_deg()
    axis.stop()
    assert axis.is_moving()  # a servo cannot halt instantly
    clock.sleep(0.5 * v / a)
    # Half-way through the brake: x0 + v·τ − a·τ²/2.
    tau = 0.5 * v / a
    assert axis.position_deg() == pytest.approx(x_stop + v * tau - 0.5 * a * tau**2, abs=1e-12)
    clock.sleep(0.5 * v / a)
    assert not axis.is_moving()
    rest = axis.position_deg()
    assert rest == pytest.approx(x_stop + v * v / (2 * a), abs=1e-12)
    assert rest < 80.0
    clock.sleep(100.0)
    assert axis.position_deg() == rest
    axis.move_to(0.0)  # usable again once at rest
    clock.sleep(10.0)
    assert axis.position_deg() == 0.0


def test_stop_during_acceleration_and_at_rest():
    axis, clock = make_axis()
    a = TILT.max_accel_deg_s2
    axis.move_to(-60.0)
    clock.sleep(0.2)  # still accelerating: speed a·t
    x0, v0 = axis.position_deg(), a * 0.2
    axis.stop()
    clock.sleep(1.0)
    assert axis.position_deg() == pytest.approx(x0 - v0 * v0 / (2 * a), abs=1e-12)
    axis.stop()  # at rest: nothing happens
    assert not axis.is_moving() and axis.position_deg() == pytest.approx(x0 - v0 * v0 / (2 * a))


def test_timeout_fault_is_transient_and_does_not_move_the_axis():
    axis, clock = make_axis()
    axis.fail_next("timeout", times=2)
    for _ in range(2):
        with pytest.raises(DeviceFault) as err:
            axis.move_to(30.0)
        assert err.value.transient and err.value.device == "light_tilt"
        assert not axis.is_moving() and axis.position_deg() == 0.0
    axis.move_to(30.0)  # the third attempt goes through
    clock.sleep(10.0)
    assert axis.position_deg() == 30.0


def test_hardware_fault_latches_until_cleared_or_reconnected():
    axis, clock = make_axis()
    axis.fail_next("hardware")
    with pytest.raises(DeviceFault) as err:
        axis.move_to(30.0)
    assert not err.value.transient
    assert "overload" in str(err.value) and axis.fault() is not None
    with pytest.raises(DeviceFault, match="latched") as err:
        axis.move_to(30.0)  # no more injected faults, but the error bit is still set
    assert not err.value.transient
    assert axis.position_deg() == 0.0
    axis.clear_fault()
    axis.move_to(30.0)
    clock.sleep(10.0)
    assert axis.position_deg() == 30.0

    axis.fail_next("hardware")
    with pytest.raises(DeviceFault):
        axis.move_to(0.0)
    axis.close()
    axis.connect()  # a power cycle clears the error bit too
    assert axis.fault() is None
    axis.move_to(0.0)
    clock.sleep(10.0)
    assert axis.position_deg() == 0.0


def test_stall_stops_short_without_an_error():
    axis, clock = make_axis()
    axis.fail_next("stall")
    axis.move_to(60.0)
    total = float(move_time(60.0, TILT.max_velocity_deg_s, TILT.max_accel_deg_s2))
    clock.sleep(0.25 * total)
    assert axis.is_moving()
    clock.sleep(100.0)
    assert not axis.is_moving()
    assert axis.position_deg() == pytest.approx(30.0, abs=1e-12)  # blocked half-way
    assert abs(axis.position_deg() - 60.0) > load_config().runner.position_tolerance_deg
    axis.move_to(60.0)  # one stall only
    clock.sleep(100.0)
    assert axis.position_deg() == 60.0


def test_fault_injection_arguments_are_checked():
    axis, _ = make_axis()
    with pytest.raises(ValueError, match="'overheat' is not one of timeout, hardware, stall"):
        axis.fail_next("overheat")
    with pytest.raises(ValueError, match="times must be an integer >= 1"):
        axis.fail_next("timeout", times=0)


def test_methods_need_a_connection():
    clock = VirtualClock()
    axis = SimAxis("light_tilt", TILT, clock)
    for call in (lambda: axis.move_to(1.0), axis.position_deg, axis.is_moving, axis.stop):
        with pytest.raises(DeviceFault, match="not connected"):
            call()
    axis.connect()
    axis.move_to(40.0)
    clock.sleep(0.3)
    axis.close()  # brakes to a halt, then disconnects
    with pytest.raises(DeviceFault, match="not connected"):
        axis.position_deg()
    clock.sleep(10.0)
    axis.connect()
    assert not axis.is_moving()
    assert 0.0 < axis.position_deg() < 40.0
    assert np.isfinite(axis.position_deg())
