"""The two-arm gantry: geometry of the arms, round trips, nearest branch, free azimuths, collisions."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gonio.config import DEFAULT_CONFIG, load_config, parse_config
from gonio.geometry import sph_to_vec
from gonio.kinematics import (
    ARM_COLLISION,
    BEYOND_THETA_MAX,
    OCCLUSION,
    OK,
    OUT_OF_REACH,
    make_kinematics,
)
from gonio.kinematics.base import circular_distance_deg

KIN = make_kinematics(load_config())
R = np.radians
TMAX = R(KIN.theta_max_deg)


def variant(kinematics=None, axes=None):
    """config/sim.toml with some [kinematics] keys and axis keys replaced."""
    data = tomllib.loads(DEFAULT_CONFIG.read_text())
    data["kinematics"].update(kinematics or {})
    for name, keys in (axes or {}).items():
        data["axes"][name].update(keys)
    return make_kinematics(parse_config(data))


#: Neither arm can swing over the zenith: every carriage clash is final.
NO_FLIP = {"light_tilt": {"min_deg": 0.0}, "detector_tilt": {"min_deg": 0.0}}


def separation_deg(ti, pi, to, po):
    return np.degrees(np.arccos(np.clip(np.sum(sph_to_vec(ti, pi) * sph_to_vec(to, po), -1), -1, 1)))


# --- forward geometry ---------------------------------------------------------------------------------


def test_directions_of_the_arms():
    axes = np.array([[30.0, 40.0, 100.0, 70.0], [30.0, -40.0, 100.0, -70.0], [-170.0, 0.0, 190.0, 90.0]])
    wi, wo = KIN.directions(axes)
    np.testing.assert_allclose(wi, sph_to_vec(R([40, 40, 0]), R([30, 210, 0])), atol=1e-15)
    np.testing.assert_allclose(wo, sph_to_vec(R([70, 70, 90]), R([100, 280, 190])), atol=1e-15)
    ti, pi, to, po = KIN.forward(axes)
    np.testing.assert_allclose(np.degrees([ti, pi, to, po]).T,
                               [[40, 30, 70, 100], [40, 210, 70, 280], [0, 0, 90, 190]], atol=1e-12)


# --- round trips --------------------------------------------------------------------------------------

theta = st.one_of(st.just(0.0), st.just(TMAX), st.floats(0.0, TMAX))
phi = st.one_of(st.just(0.0), st.floats(-7.0, 7.0))
poses = st.lists(st.tuples(theta, phi, theta, phi), min_size=1, max_size=12)
currents = st.tuples(*(st.floats(lo, hi) for lo, hi in KIN.limits_deg))


@settings(derandomize=True, max_examples=200, deadline=None)
@given(poses=poses, current=currents)
def test_round_trip_reaches_every_unoccluded_pose(poses, current, check_round_trip):
    ti, pi, to, po = np.array(poses).T
    axes, ok = check_round_trip(KIN, ti, pi, to, po, current)
    # Carriages stay apart on every returned pose.
    assert np.all(circular_distance_deg(axes[ok, 0], axes[ok, 2]) >= KIN.arm_collision_deg - 1e-9)


@settings(derandomize=True, max_examples=100, deadline=None)
@given(poses=poses)
def test_every_branch_is_a_true_solution_within_limits(poses):
    ti, pi, to, po = np.array(poses).T
    sols = KIN.solutions(ti, pi, to, po)
    valid = ~np.isnan(sols[..., 0])
    rows = sols[valid]
    lo, hi = KIN.limits_deg.T
    assert np.all((rows >= lo) & (rows <= hi))
    idx = np.nonzero(valid)[0]
    wi, wo = KIN.directions(rows)
    np.testing.assert_allclose(wi, sph_to_vec(ti[idx], pi[idx]), atol=1e-12)
    np.testing.assert_allclose(wo, sph_to_vec(to[idx], po[idx]), atol=1e-12)
    assert np.all(circular_distance_deg(rows[:, 0], rows[:, 2]) >= KIN.arm_collision_deg - 1e-9)


@settings(derandomize=True, max_examples=100, deadline=None)
@given(poses=poses)
def test_standing_on_a_branch_inverse_stays_there(poses):
    ti, pi, to, po = np.array(poses).T
    sols = KIN.solutions(ti, pi, to, po)
    pose_idx, _ = np.nonzero(~np.isnan(sols[..., 0]))
    here = sols[~np.isnan(sols[..., 0])]
    got = KIN.inverse(ti[pose_idx], pi[pose_idx], to[pose_idx], po[pose_idx], current_deg=here)
    np.testing.assert_allclose(got, here, atol=1e-9)


# --- nearest branch -----------------------------------------------------------------------------------


def test_nearest_is_the_wrapped_azimuth():
    current = [-170.0, 20.0, 0.0, 45.0]
    sols = KIN.solutions(R(40), R(185), R(45), 0.0, current_deg=current)[0]
    light = {tuple(r) for r in np.round(sols[~np.isnan(sols[:, 0])][:, :2], 9)}
    assert {(185.0, 40.0), (-175.0, 40.0), (5.0, -40.0)} <= light
    np.testing.assert_allclose(KIN.inverse(R(40), R(185), R(45), 0.0, current_deg=current),
                               [[-175.0, 40.0, 0.0, 45.0]], atol=1e-9)


def test_nearest_is_the_flipped_arm():
    current = [0.0, -30.0, 180.0, 45.0]
    np.testing.assert_allclose(KIN.inverse(R(30), R(180), R(45), R(180), current_deg=current),
                               [[0.0, -30.0, 180.0, 45.0]], atol=1e-9)
    # From home both arms flip: a 30° tilt is quicker than half a turn of the carriage ...
    np.testing.assert_allclose(KIN.inverse(R(30), R(180), R(45), R(0)), [[0.0, -30.0, 180.0, -45.0]],
                               atol=1e-9)
    # ... but with the light carriage already near 180° the upright branch is the nearer.
    np.testing.assert_allclose(KIN.inverse(R(30), R(180), R(45), R(90), current_deg=[170.0, 0.0, 90.0, 45.0]),
                               [[180.0, 30.0, 90.0, 45.0]], atol=1e-9)


def test_nearest_weighs_time_not_degrees():
    # A slow light tilt (5°/s) makes tilt travel dominate: from tilt −20°, the flipped branch (−90°, −50°)
    # is 30° of tilt away (7 s) and the upright (90°, 50°) 70° (15 s); both carriages move 90° (2 s).
    k = variant(axes={"light_tilt": {"max_velocity_deg_s": 5.0, "max_accel_deg_s2": 5.0}})
    got = k.inverse(R(50), R(90), R(45), 0.0, current_deg=[0.0, -20.0, 0.0, 45.0])
    np.testing.assert_allclose(got, [[-90.0, -50.0, 0.0, 45.0]], atol=1e-9)
    # With the tilt up to 30° instead the upright branch is the nearer.
    got = k.inverse(R(50), R(90), R(45), 0.0, current_deg=[0.0, 30.0, 0.0, 45.0])
    np.testing.assert_allclose(got, [[90.0, 50.0, 0.0, 45.0]], atol=1e-9)


def test_nearest_is_the_slowest_axis_not_the_sum():
    # Axes move together, so a move lasts as long as its slowest axis. With a fast light carriage
    # (0.6 s for 180°), from (0°, −10°) the upright (0°, 40°) is one 50° tilt (1.61 s), the flipped
    # (180°, −40°) a 30° tilt (1.17 s) plus the half turn: longer in sum, shorter in time.
    k = variant(axes={"light_azimuth": {"max_velocity_deg_s": 1000.0, "max_accel_deg_s2": 2000.0}})
    got = k.inverse(R(40), 0.0, R(30), R(90), current_deg=[0.0, -10.0, 90.0, 30.0])[0]
    np.testing.assert_allclose([abs(got[0]), *got[1:]], [180.0, -40.0, 90.0, 30.0], atol=1e-9)  # ±180° tie


def test_ties_in_time_go_to_the_smaller_total():
    # The light's 80° tilt (2.28 s) sets the time of every branch; of the detector's two ways there,
    # (0°, 30°) tilts 40° and (180°, −30°) only 20° (both carriages move 90°).
    got = KIN.inverse(R(80), R(270), R(30), 0.0, current_deg=[-90.0, 0.0, 90.0, -10.0])
    np.testing.assert_allclose(got, [[-90.0, 80.0, 180.0, -30.0]], atol=1e-9)


# --- free azimuth -------------------------------------------------------------------------------------


def test_free_light_azimuth_stays_put_when_clear():
    got = KIN.inverse(0.0, R(123), R(45), R(90), current_deg=[37.0, 10.0, 90.0, 10.0])
    np.testing.assert_allclose(got, [[37.0, 0.0, 90.0, 45.0]], atol=1e-9)


def test_free_light_azimuth_steps_aside_from_the_detector_carriage():
    current = [5.0, 0.0, 180.0, 0.0]
    sols = KIN.solutions(0.0, 0.0, R(45), R(3), current_deg=current)[0]
    rows = {tuple(r) for r in np.round(sols[~np.isnan(sols[:, 0])], 9)}
    # Detector carriage at 3°: it comes from 180° (light − detector = −175°, the detector ahead
    # counter-clockwise), so the light gives way clockwise to −7° rather than to the nearer edge 13°
    # on the far side, which the detector could only reach by passing it; at 183° the light stays.
    assert (-7.0, 0.0, 3.0, 45.0) in rows and (5.0, 0.0, 183.0, -45.0) in rows
    assert (13.0, 0.0, 3.0, 45.0) not in rows
    np.testing.assert_allclose(KIN.inverse(0.0, 0.0, R(45), R(3), current_deg=current),
                               [[5.0, 0.0, 183.0, -45.0]], atol=1e-9)


def test_free_detector_azimuth_steps_aside_from_the_light_carriage():
    got = KIN.inverse(R(40), 0.0, 0.0, 0.0, current_deg=[0.0, 0.0, 0.0, 0.0])[0]
    # Moving the detector 10° is quicker than sending the light carriage half a turn.
    np.testing.assert_allclose(got[[0, 1, 3]], [0.0, 40.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(abs(got[2]), 10.0, atol=1e-9)


def test_both_arms_at_the_pole_offer_both_ways_out():
    k = variant(kinematics={"clearance_deg": 0.0})
    current = [30.0, 0.0, 35.0, 0.0]
    sols = k.solutions(0.0, 0.0, 0.0, 0.0, current_deg=current)[0]
    rows = {tuple(r) for r in np.round(sols[~np.isnan(sols[:, 0])], 9)}
    assert rows == {(30.0, 0.0, 40.0, 0.0), (25.0, 0.0, 35.0, 0.0)}
    # A slow detector carriage makes the light the one to give way.
    slow = variant(kinematics={"clearance_deg": 0.0},
                   axes={"detector_azimuth": {"max_velocity_deg_s": 5.0, "max_accel_deg_s2": 5.0}})
    np.testing.assert_allclose(slow.inverse(0.0, 0.0, 0.0, 0.0, current_deg=current), [[25.0, 0, 35.0, 0]])


# --- reasons ------------------------------------------------------------------------------------------


def test_flipping_an_arm_avoids_the_carriage_clash():
    axes = KIN.inverse(R(30), R(50), R(60), R(50))[0]
    assert circular_distance_deg(axes[0], axes[2]) == pytest.approx(180.0)
    assert min(axes[1], axes[3]) < 0.0


def test_arm_collision_when_no_arm_can_flip():
    k = variant(axes=NO_FLIP)
    codes = k.feasibility(R(30), R(50), R(60), R([50.0, 59.9, 60.0, 230.0, 40.1]))
    assert codes.tolist() == [ARM_COLLISION, ARM_COLLISION, OK, OK, ARM_COLLISION]
    assert np.isnan(k.inverse(R(30), R(50), R(60), R(50))).all()


def test_light_at_the_pole_collides_when_it_cannot_step_aside():
    k = variant(axes={**NO_FLIP, "light_azimuth": {"min_deg": -5.0, "max_deg": 5.0}})
    # The light carriage can only reach [−5°, 5°]: a detector carriage within (−5°, 5°) leaves it no room.
    codes = k.feasibility(0.0, 0.0, R(45), R([0.0, 4.9, 5.0, 14.0, 180.0]))
    assert codes.tolist() == [ARM_COLLISION, ARM_COLLISION, OK, OK, OK]
    np.testing.assert_allclose(k.inverse(0.0, 0.0, R(45), R([5.0, 8.0])),
                               [[-5.0, 0.0, 5.0, 45.0], [-2.0, 0.0, 8.0, 45.0]], atol=1e-9)


def test_out_of_reach_by_tilt_and_by_azimuth():
    k = variant(axes={"light_tilt": {"min_deg": -60.0, "max_deg": 60.0}})
    assert k.feasibility(R([60.0, 70.0]), 0.0, R(30), R(180))[:].tolist() == [OK, OUT_OF_REACH]
    k = variant(axes={"light_tilt": {"min_deg": 0.0}, "light_azimuth": {"min_deg": 0.0, "max_deg": 90.0}})
    assert k.feasibility(R(30), R([90.0, 180.0]), R(30), R(0)).tolist() == [OK, OUT_OF_REACH]


# --- brute force --------------------------------------------------------------------------------------


def _settings_by_direction(lo_a, hi_a, lo_t, hi_t):
    """Every integer (azimuth, tilt) in the limits, grouped by the direction it points at: θ, φ in whole
    degrees, φ = None at the pole. Built from the arm's definition, not from the kinematics code."""
    table: dict[tuple, list[float]] = {}
    for t in range(int(lo_t), int(hi_t) + 1):
        for a in range(int(lo_a), int(hi_a) + 1):
            key = (0, None) if t == 0 else (abs(t), (a + (180 if t < 0 else 0)) % 360)
            table.setdefault(key, []).append(float(a))
    return {k: np.array(v) for k, v in table.items()}


def _brute_force_code(k, light, detector, ti, pi, to, po):
    if max(ti, to) > k.theta_max_deg:
        return BEYOND_THETA_MAX
    if separation_deg(R(ti), R(pi), R(to), R(po)) < k.clearance_deg - 1e-9:
        return OCCLUSION
    az_l = light.get((0, None) if ti == 0 else (ti, pi % 360))
    az_d = detector.get((0, None) if to == 0 else (to, po % 360))
    if az_l is None or az_d is None:
        return OUT_OF_REACH
    gap = circular_distance_deg(az_l[:, None], az_d[None, :])
    return OK if np.any(gap >= k.arm_collision_deg) else ARM_COLLISION


def test_reason_counts_match_brute_force():
    k = variant(axes={"light_tilt": {"min_deg": 0.0}, "detector_tilt": {"min_deg": 0.0, "max_deg": 70.0}})
    (lo_la, hi_la), (lo_lt, hi_lt), (lo_da, hi_da), (lo_dt, hi_dt) = k.limits_deg
    light = _settings_by_direction(lo_la, hi_la, lo_lt, hi_lt)
    detector = _settings_by_direction(lo_da, hi_da, lo_dt, hi_dt)
    thetas, phis = [0, 20, 50, 75, 85], [0, 5, 90, 180, 270]
    grid = np.array([(a, b, c, d) for a in thetas for b in phis for c in thetas for d in phis], dtype=float)
    expected = np.array([_brute_force_code(k, light, detector, *pose) for pose in grid])
    codes = k.feasibility(*R(grid.T))
    np.testing.assert_array_equal(codes, expected)
    counts = np.bincount(codes, minlength=5)
    assert np.all(counts > 0), counts
    assert counts.sum() == len(grid)
