"""The sample-stage gantry: frames and signs, round trips, nearest branch, the support collision."""

from __future__ import annotations

import tomllib

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from gonio.config import DEFAULT_CONFIG, load_config, parse_config
from gonio.geometry import sph_to_vec, vec_to_sph
from gonio.kinematics import (
    ARM_COLLISION,
    BEYOND_THETA_MAX,
    OCCLUSION,
    OK,
    OUT_OF_REACH,
    SampleStage,
    make_kinematics,
)
from gonio.kinematics.base import arm_vector

PATH = DEFAULT_CONFIG.parent / "sample-stage.toml"
KIN = make_kinematics(load_config(PATH))
R = np.radians
TMAX = R(KIN.theta_max_deg)
MINUS_Y = np.array([0.0, -1.0, 0.0])


def variant(kinematics=None, axes=None):
    """config/sample-stage.toml with some [kinematics] keys and axis keys replaced."""
    data = tomllib.loads(PATH.read_text())
    data["kinematics"].update(kinematics or {})
    for name, keys in (axes or {}).items():
        data["axes"][name].update(keys)
    return make_kinematics(parse_config(data))


def lab_from_sample(rotation_deg, tilt_deg):
    """Explicit matrices (..., 3, 3) of v_lab = R_y(tilt) R_z(rotation) v_sample."""
    r, t = np.broadcast_arrays(R(np.asarray(rotation_deg, float)), R(np.asarray(tilt_deg, float)))
    zero, one = np.zeros_like(r), np.ones_like(r)
    rz = np.stack([np.cos(r), -np.sin(r), zero, np.sin(r), np.cos(r), zero, zero, zero, one], -1)
    ry = np.stack([np.cos(t), zero, np.sin(t), zero, one, zero, -np.sin(t), zero, np.cos(t)], -1)
    return ry.reshape(r.shape + (3, 3)) @ rz.reshape(r.shape + (3, 3))


def angle_deg(u, v):
    return np.degrees(np.arccos(np.clip(np.sum(u * v, -1), -1.0, 1.0)))


def detector_lab(axes):
    return arm_vector(axes[..., 2], axes[..., 3])


# --- frames and signs ---------------------------------------------------------------------------------


def test_directions_follow_the_documented_frames():
    axes = np.array([[30.0, 20.0, 0.0, 60.0], [30.0, -20.0, 200.0, -100.0], [-170.0, 0.0, 45.0, 0.0]])
    wi, wo = KIN.directions(axes)
    m = lab_from_sample(axes[:, 0], axes[:, 1])
    # The light is lab +z; the detector's lab direction is its arm's; both seen from the sample.
    np.testing.assert_allclose(wi, np.einsum("nji,j->ni", m, [0.0, 0.0, 1.0]), atol=1e-15)
    np.testing.assert_allclose(wo, np.einsum("nji,nj->ni", m, detector_lab(axes)), atol=1e-15)


def test_signs_of_rotation_and_tilt():
    # A positive tilt tips the sample normal toward lab +x.
    normal = lab_from_sample(0.0, 20.0) @ [0.0, 0.0, 1.0]
    np.testing.assert_allclose(normal, sph_to_vec(R(20), 0.0), atol=1e-15)
    axes = np.array([[30.0, 20.0, 0.0, 0.0], [30.0, -20.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]])
    ti, pi, _, _ = KIN.forward(axes)
    # θi = |tilt|; φi = 180° − rotation for a positive tilt, −rotation for a negative one.
    np.testing.assert_allclose(np.degrees(ti), [20.0, 20.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(np.degrees(pi), [150.0, 330.0, 0.0], atol=1e-12)


def test_specular_in_the_tilt_plane():
    # Light 30° off the normal on the −x side: the tilt is +30° and the mirror direction is 60° from
    # the light in the lab, toward +x.
    np.testing.assert_allclose(KIN.inverse(R(30), np.pi, R(30), 0.0), [[0.0, 30.0, 0.0, 60.0]], atol=1e-9)


# --- round trips --------------------------------------------------------------------------------------

theta = st.one_of(st.just(0.0), st.just(TMAX), st.floats(0.0, TMAX))
phi = st.one_of(st.just(0.0), st.just(1.5 * np.pi), st.floats(-7.0, 7.0))
poses = st.lists(st.tuples(theta, phi, theta, phi), min_size=1, max_size=12)
currents = st.tuples(*(st.floats(lo, hi) for lo, hi in KIN.limits_deg))


@settings(derandomize=True, max_examples=200, deadline=None)
@given(poses=poses, current=currents)
def test_round_trip_reaches_every_unoccluded_pose(poses, current, check_round_trip):
    ti, pi, to, po = np.array(poses).T
    axes, ok = check_round_trip(KIN, ti, pi, to, po, current)
    # The detector keeps clear of the tilt-stage support on every returned pose.
    assert np.all(angle_deg(detector_lab(axes[ok]), MINUS_Y) >= KIN.arm_collision_deg - 1e-9)


@settings(derandomize=True, max_examples=100, deadline=None)
@given(poses=poses)
def test_every_branch_is_a_true_solution_and_inverse_stays_on_it(poses):
    ti, pi, to, po = np.array(poses).T
    sols = KIN.solutions(ti, pi, to, po)
    valid = ~np.isnan(sols[..., 0])
    idx, _ = np.nonzero(valid)
    rows = sols[valid]
    lo, hi = KIN.limits_deg.T
    assert np.all((rows >= lo) & (rows <= hi))
    wi, wo = KIN.directions(rows)
    np.testing.assert_allclose(wi, sph_to_vec(ti[idx], pi[idx]), atol=1e-12)
    np.testing.assert_allclose(wo, sph_to_vec(to[idx], po[idx]), atol=1e-12)
    got = KIN.inverse(ti[idx], pi[idx], to[idx], po[idx], current_deg=rows)
    np.testing.assert_allclose(got, rows, atol=1e-9)


# --- nearest branch -----------------------------------------------------------------------------------


def test_nearest_is_the_flipped_tilt():
    # θi = 30°, φi = 0: tilt +30° with rotation 180°, or tilt −30° with rotation 0. The detector, along
    # the mirror direction, is then 60° from the light toward lab +x or toward lab −x.
    flipped = [0.0, -30.0, 180.0, 60.0]
    stay = KIN.inverse(R(30), 0.0, R(30), np.pi, current_deg=flipped)
    np.testing.assert_allclose(stay, [flipped], atol=1e-9)
    upright = KIN.inverse(R(30), 0.0, R(30), np.pi, current_deg=[170.0, 20.0, 0.0, 60.0])
    np.testing.assert_allclose(upright, [[180.0, 30.0, 0.0, 60.0]], atol=1e-9)


def test_nearest_is_the_wrapped_rotation():
    # φi = 355° wants rotation 185° (tilt +30°); from −170° the same orientation is one turn back.
    sols = KIN.solutions(R(30), R(355), 0.0, 0.0)[0]
    assert np.any(np.isclose(sols[:, 0], 185.0)) and np.any(np.isclose(sols[:, 0], -175.0))
    got = KIN.inverse(R(30), R(355), 0.0, 0.0, current_deg=[-170.0, 30.0, 0.0, 30.0])
    np.testing.assert_allclose(got, [[-175.0, 30.0, 0.0, 30.0]], atol=1e-9)


# --- the support collision and the free rotation ------------------------------------------------------


def test_the_other_tilt_sign_clears_the_support():
    k = variant(kinematics={"arm_collision_deg": 15.0})
    # Tilt −20° with rotation 0 puts the detector 10° from lab −y; tilt +20° with rotation 180° puts it
    # a half turn away. The first is nearer from home, but it collides.
    sols = k.solutions(R(20), 0.0, R(80), R(270))[0]
    rows = sols[~np.isnan(sols[:, 0])]
    assert len(rows) and np.allclose(rows[:, 1], 20.0)
    got = k.inverse(R(20), 0.0, R(80), R(270))[0]
    np.testing.assert_allclose([abs(got[0]), got[1]], [180.0, 20.0], atol=1e-9)   # ±180° equally near
    np.testing.assert_allclose(angle_deg(detector_lab(got), MINUS_Y), 170.0, atol=1e-9)


def test_arm_collision_when_the_tilt_cannot_flip():
    k = variant(kinematics={"arm_collision_deg": 15.0}, axes={"sample_tilt": {"min_deg": 0.0}})
    # Tilt +20° (rotation 0) leaves the detector 10° from the support: nothing else reaches the pose.
    codes = k.feasibility(R(20), np.pi, R([80.0, 80.0, 70.0]), R([270.0, 90.0, 270.0]))
    assert codes.tolist() == [ARM_COLLISION, OK, OK]
    assert np.isnan(k.inverse(R(20), np.pi, R(80), R(270))).all()


def test_free_rotation_turns_the_detector_off_the_support():
    k = variant(kinematics={"arm_collision_deg": 15.0}, axes={"sample_tilt": {"min_deg": 0.0}})
    # θi = 0: from rotation 0 the detector would be 10° from lab −y. The nearest rotations that clear it
    # put it exactly 15° away: |rotation| = arccos(cos 15° / sin 80°).
    got = k.inverse(0.0, 0.0, R(80), R(270))[0]
    edge = np.degrees(np.arccos(np.cos(R(15)) / np.sin(R(80))))
    np.testing.assert_allclose(abs(got[0]), edge, atol=1e-9)
    np.testing.assert_allclose(angle_deg(detector_lab(got), MINUS_Y), 15.0, atol=1e-9)
    # Clear already: the rotation stays where it is.
    got = k.inverse(0.0, 0.0, R(80), R(270), current_deg=[40.0, 0.0, 0.0, 45.0])[0]
    assert got[0] == 40.0
    # A rotation stage that cannot turn far enough leaves the detector on the support.
    narrow = {"sample_tilt": {"min_deg": 0.0}, "sample_rotation": {"min_deg": -5.0, "max_deg": 5.0}}
    stuck = variant(kinematics={"arm_collision_deg": 15.0}, axes=narrow)
    assert stuck.feasibility(0.0, 0.0, R(80), R(270)).tolist() == [ARM_COLLISION]


def test_out_of_reach_by_sample_tilt_and_by_detector_tilt():
    k = variant(axes={"sample_tilt": {"min_deg": -60.0, "max_deg": 60.0}})
    assert k.feasibility(R([60.0, 70.0]), 0.0, R(30), 0.0).tolist() == [OK, OUT_OF_REACH]
    # The detector arm reaches 120° from the light: a specular pair at 75° is 150° away.
    k = variant(axes={"detector_tilt": {"min_deg": -120.0, "max_deg": 120.0}})
    assert k.feasibility(R([45.0, 75.0]), 0.0, R([75.0, 75.0]), np.pi).tolist() == [OK, OUT_OF_REACH]


def test_detector_overhead_keeps_its_azimuth():
    k = variant(kinematics={"clearance_deg": 0.0})
    got = k.inverse(R(30), R(40), R(30), R(40), current_deg=[0.0, 0.0, 123.0, 10.0])[0]
    np.testing.assert_allclose(got[2:], [123.0, 0.0], atol=1e-9)


# --- brute force --------------------------------------------------------------------------------------


def _stage_settings_by_light(k):
    """Every integer (rotation, tilt) in the limits, grouped by the whole-degree light direction it
    gives in the sample frame (φ = None at the pole), from the explicit matrices."""
    (lo_r, hi_r), (lo_t, hi_t) = k.limits_deg[0], k.limits_deg[1]
    rot, tilt = np.meshgrid(np.arange(lo_r, hi_r + 1), np.arange(lo_t, hi_t + 1), indexing="ij")
    rot, tilt = rot.ravel(), tilt.ravel()
    wi = np.einsum("nji,j->ni", lab_from_sample(rot, tilt), [0.0, 0.0, 1.0])
    th, ph = (np.degrees(a) for a in vec_to_sph(wi))
    th_i, ph_i = np.round(th).astype(int), np.round(ph).astype(int) % 360
    assert np.allclose(th, th_i, atol=1e-6)
    table: dict[tuple, list] = {}
    for r, t, a, b in zip(rot, tilt, th_i, ph_i, strict=True):
        table.setdefault((0, None) if a == 0 else (a, b), []).append((r, t))
    return {key: np.array(v, dtype=float) for key, v in table.items()}


def _detector_reaches(k, beta, alpha):
    """Whether some (azimuth, tilt) in the limits points the detector arm at lab (β, α), degrees (m,)."""
    (lo_a, hi_a), (lo_t, hi_t) = k.limits_deg[2], k.limits_deg[3]
    turns = 360.0 * np.arange(-3, 4)
    reach = np.zeros(beta.shape, dtype=bool)
    for az, tilt in ((alpha, beta), (alpha + 180.0, -beta)):
        wrapped = az[:, None] + turns
        reach |= (lo_t <= tilt) & (tilt <= hi_t) & np.any((wrapped >= lo_a) & (wrapped <= hi_a), axis=1)
    overhead = beta < 1e-7
    return np.where(overhead, lo_t <= 0.0 <= hi_t, reach)


def _brute_force_code(k, table, ti, pi, to, po):
    if max(ti, to) > k.theta_max_deg:
        return BEYOND_THETA_MAX
    wo = sph_to_vec(R(to), R(po))
    if angle_deg(sph_to_vec(R(ti), R(pi)), wo) < k.clearance_deg - 1e-9:
        return OCCLUSION
    stage = table.get((0, None) if ti == 0 else (int(ti), int(pi) % 360))
    if stage is None:
        return OUT_OF_REACH
    d = lab_from_sample(stage[:, 0], stage[:, 1]) @ wo
    beta, alpha = (np.degrees(a) for a in vec_to_sph(d))
    reach = _detector_reaches(k, beta, alpha)
    clear = angle_deg(d, MINUS_Y) >= k.arm_collision_deg
    return OUT_OF_REACH if not reach.any() else OK if (reach & clear).any() else ARM_COLLISION


def test_reason_counts_match_brute_force():
    # No tilt flip and at most 60° of tilt: every reason shows up on this grid.
    k = variant(kinematics={"arm_collision_deg": 15.0},
                axes={"sample_tilt": {"min_deg": 0.0, "max_deg": 60.0}})
    assert isinstance(k, SampleStage)
    table = _stage_settings_by_light(k)
    thetas, phis = [0, 20, 50, 80, 85], [0, 5, 90, 180, 270]
    grid = np.array([(a, b, c, d) for a in thetas for b in phis for c in thetas for d in phis], dtype=float)
    expected = np.array([_brute_force_code(k, table, *pose) for pose in grid])
    codes = k.feasibility(*R(grid.T))
    np.testing.assert_array_equal(codes, expected)
    counts = np.bincount(codes, minlength=5)
    assert np.all(counts > 0), counts
