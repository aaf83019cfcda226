"""The swept-path check: certified (never clear where a dense replay collides), exact on the two-arm
gantry, and the same in its scalar and vectorized forms."""

from __future__ import annotations

import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gonio.config import DEFAULT_CONFIG, load_config, parse_config
from gonio.kinematics import make_kinematics
from gonio.kinematics.sweep import difference_range
from gonio.motion.trapezoid import move_time, position_at

sys.path.insert(0, str(Path(__file__).parents[1] / "motion"))
from transit_brute import replay  # noqa: E402

TWO_ARM = make_kinematics(load_config(DEFAULT_CONFIG))
STAGE = make_kinematics(load_config(DEFAULT_CONFIG.parent / "sample-stage.toml"))
KINS = {"two-arm": TWO_ARM, "sample-stage": STAGE}


def variant(path, axes):
    data = tomllib.loads(Path(path).read_text())
    for name, keys in axes.items():
        data["axes"][name].update(keys)
    return make_kinematics(parse_config(data))


#: A two-arm gantry whose detector carriage is slower than the light's: the light can catch it up.
SLOW_DETECTOR = variant(DEFAULT_CONFIG, {"detector_azimuth": {"max_velocity_deg_s": 20.0,
                                                              "max_accel_deg_s2": 30.0}})


def random_moves(kin, n, seed, near=True):
    """Moves within the limits; with ``near``, half of them start or end close to the collision rule."""
    rng = np.random.default_rng(seed)
    lo, hi = kin.limits_deg.T
    a = rng.uniform(lo, hi, (n, 4))
    b = rng.uniform(lo, hi, (n, 4))
    if near:
        half = n // 2
        if kin.design == "two-arm":
            # The detector carriage starts or ends a few degrees from the light's.
            offset = rng.choice([-1, 1], half) * rng.uniform(8, 30, half)
            a[:half, 2] = np.clip(a[:half, 0] + offset, lo[2], hi[2])
            b[:half, 0] = np.clip(b[:half, 2] + rng.uniform(-60, 60, half), lo[0], hi[0])
        else:
            # The detector near the support's band (tilt near ±90°, azimuth near ∓90°).
            a[:half, 3] = rng.choice([-1, 1], half) * rng.uniform(60, 120, half)
            b[:half, 2] = rng.uniform(-150, 150, half)
            b[:half, 3] = a[:half, 3] + rng.uniform(-20, 20, half)
    return a, b


@pytest.mark.parametrize("design", list(KINS))
def test_never_clear_where_the_dense_replay_collides(design):
    kin = KINS[design]
    a, b = random_moves(kin, 3000, 7)
    clear, margin = kin.sweep_clearance(a, b)
    hit = replay(kin, a, b, step_deg=0.1)
    assert not np.any(clear & hit)
    assert hit.sum() > 100 and clear.sum() > 100      # both outcomes occur
    # The check without margins (what the planner asks of its candidate moves) answers the same.
    np.testing.assert_array_equal(kin.sweep_clear(a, b), clear)
    # The margin means what it says: a move it puts 1° into the rule collides at some sample (the
    # margin changes by at most 0.2° between samples 0.1° of travel apart) ...
    assert np.all(hit[margin < -1.0])
    # ... and within the limits a margin >= 0 is a clear move.
    assert np.all(clear[(margin >= 0.0) & kin.within_limits(a) & kin.within_limits(b)])


@pytest.mark.parametrize("design", list(KINS))
@settings(max_examples=150, deadline=None, derandomize=True)
@given(data=st.data())
def test_certified_on_arbitrary_moves(design, data):
    kin = KINS[design]
    lo, hi = kin.limits_deg.T
    a = np.array([data.draw(st.floats(float(x), float(y))) for x, y in zip(lo, hi, strict=True)])
    b = np.array([data.draw(st.floats(float(x), float(y))) for x, y in zip(lo, hi, strict=True)])
    clear, margin = kin.sweep_clearance(a, b)
    if clear[0]:
        assert not replay(kin, a, b, step_deg=0.02)[0]
    one = kin.sweep_clear_one(a, b)
    assert one[0] == clear[0] and one[1] == pytest.approx(margin[0], abs=1e-9)
    assert kin.sweep_clear(a, b)[0] == clear[0]


def test_two_arm_margin_is_the_exact_smallest_separation():
    kin = SLOW_DETECTOR
    a, b = random_moves(kin, 500, 3)
    _, margin = kin.sweep_clearance(a, b)
    # Brute force: the smallest carriage separation over 20,000 instants of each move (16 moves at a
    # time: the same figures, with temporaries that stay in cache).
    v, acc = kin.velocity_deg_s, kin.accel_deg_s2
    total = np.max(move_time(b - a, v, acc), axis=1)
    frac = np.linspace(0, 1, 20001)[:, None]
    brute = np.empty(a.shape[0])
    for lo in range(0, a.shape[0], 16):
        m = slice(lo, lo + 16)
        t = frac * total[m]
        light = position_at(t, a[m, 0], b[m, 0], v[0], acc[0])
        gap = np.mod(light - position_at(t, a[m, 2], b[m, 2], v[2], acc[2]), 360.0)
        brute[m] = np.min(np.minimum(gap, 360.0 - gap), axis=0) - kin.arm_collision_deg
    assert np.all(margin <= brute + 1e-9)                 # never more optimistic than any instant
    moved = np.max(np.abs(b - a)[:, [0, 2]], axis=1)
    np.testing.assert_array_less(brute - margin, moved / 20000 * 2 + 1e-9)   # and within sampling


def test_difference_range_of_a_catch_up():
    # The light (60°/s, 120°/s², 90° in 2 s) starts 30° behind a detector that moves 40° at 20°/s
    # (40°/s², 2.5 s). The light passes it and ends 20° ahead, but the difference peaks before that,
    # where the decelerating light's speed falls to the detector's 20°/s: t = 11/6 s, light at
    # 90 − 60 (1/6)² = 88.33°, detector at 30 + 5 + 20 (4/3) = 61.67°: 26.67° ahead.
    lo, hi = difference_range(np.array([0.0]), np.array([90.0]), np.array([30.0]), np.array([70.0]),
                              60.0, 120.0, 20.0, 40.0)
    assert lo[0] == pytest.approx(-30.0) and hi[0] == pytest.approx(80.0 / 3.0)


def test_light_carriage_passing_the_detector_carriage_collides():
    # Same tilts, the light carriage from 0° to 180° through the detector's at 90°: separation 0.
    clear, margin = TWO_ARM.sweep_clearance([0.0, 30.0, 90.0, 30.0], [180.0, 30.0, 90.0, 30.0])
    assert not clear[0] and margin[0] == pytest.approx(-10.0)
    # Swinging the detector a whole turn (180° to −180°: the same place) passes the light carriage.
    clear, _ = TWO_ARM.sweep_clearance([0.0, 0.0, 180.0, 45.0], [0.0, 0.0, -180.0, 45.0])
    assert not clear[0]
    # The slow detector carriage is caught up by the light although both ends are clear.
    start, end = [0.0, 0.0, 30.0, 0.0], [100.0, 0.0, 115.0, 0.0]
    assert SLOW_DETECTOR.sweep_clearance(start, start)[0][0] and SLOW_DETECTOR.sweep_clearance(end, end)[0][0]
    assert not SLOW_DETECTOR.sweep_clearance(start, end)[0][0]
    assert replay(SLOW_DETECTOR, start, end)[0]


def test_detector_sweeping_past_the_support_collides():
    # At tilt 90° the detector arm is horizontal: azimuth −120° -> −60° passes lab −y (−90°).
    clear, margin = STAGE.sweep_clearance([0.0, 0.0, -120.0, 90.0], [0.0, 0.0, -60.0, 90.0])
    assert not clear[0] and margin[0] == pytest.approx(-10.0, abs=1e-3)
    # Raised to 60° it stays 30° away (the sample stage's axes do not matter).
    clear, margin = STAGE.sweep_clearance([150.0, -80.0, -120.0, 60.0], [-150.0, 80.0, -60.0, 60.0])
    assert clear[0] and margin[0] >= 0.0
    assert STAGE.sweep_clear_one([150.0, -80.0, -120.0, 60.0], [-150.0, 80.0, -60.0, 60.0])[0]


@pytest.mark.parametrize("design", list(KINS))
def test_limits_hold_at_both_ends_or_the_move_is_not_clear(design):
    kin = KINS[design]
    home = kin.home_deg
    out = home.copy()
    out[1] = kin.limits_deg[1, 1] + 1.0
    clear, _ = kin.sweep_clearance(np.vstack([home, out]), np.vstack([out, home]))
    assert not clear.any()
    assert not kin.sweep_clear_one(home, out)[0]


def test_shapes_and_errors():
    clear, margin = TWO_ARM.sweep_clearance(np.zeros((0, 4)), np.zeros((0, 4)))
    assert clear.shape == margin.shape == (0,)
    clear, _ = TWO_ARM.sweep_clearance(TWO_ARM.home_deg, np.tile(TWO_ARM.home_deg, (3, 1)))
    assert clear.shape == (3,) and clear.all()
    with pytest.raises(ValueError, match="start_deg"):
        TWO_ARM.sweep_clearance([0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="end_deg: axis 'light_tilt'"):
        TWO_ARM.sweep_clearance(TWO_ARM.home_deg, [0.0, np.nan, 180.0, 0.0])
    with pytest.raises(ValueError, match="rows"):
        TWO_ARM.sweep_clearance(np.zeros((2, 4)), np.zeros((3, 4)))


def test_free_components_of_the_two_arm_ring():
    # Light − detector in (−360°, 0°) and in (0°, 360°) are different strips: no motion joins them.
    labels = TWO_ARM.free_component([[0, 0, 180, 0], [0, 0, -180, 0], [100, 0, 150, 0], [100, 0, 50, 0]])
    assert labels.tolist() == [-1, 0, -1, 0]
    assert STAGE.free_component(np.zeros((3, 4))).tolist() == [0, 0, 0]
