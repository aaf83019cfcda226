"""The shared kinematics interface: helpers, shapes, validation, and what every design must do."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from gonio.config import DEFAULT_CONFIG, load_config, parse_config
from gonio.kinematics import (
    BEYOND_THETA_MAX,
    OCCLUSION,
    OUT_OF_REACH,
    REASONS,
    SampleStage,
    TwoArm,
    make_kinematics,
)
from gonio.kinematics.base import (
    azimuth_wraps,
    circular_distance_deg,
    nearest_allowed_azimuth,
    wrap_360,
)

SAMPLE_STAGE = DEFAULT_CONFIG.parent / "sample-stage.toml"
PATHS = {"two-arm": DEFAULT_CONFIG, "sample-stage": SAMPLE_STAGE}


def variant(design: str, kinematics=None, axes=None):
    """The shipped config of ``design`` with some [kinematics] keys and axis keys replaced."""
    data = tomllib.loads(PATHS[design].read_text())
    data["kinematics"].update(kinematics or {})
    for name, keys in (axes or {}).items():
        data["axes"][name].update(keys)
    return make_kinematics(parse_config(data))


@pytest.fixture(params=["two-arm", "sample-stage"])
def kin(request):
    return make_kinematics(load_config(PATHS[request.param]))


# --- helpers ------------------------------------------------------------------------------------------


def test_wrap_360_and_circular_distance():
    np.testing.assert_array_equal(wrap_360([-90.0, 360.0, 725.0, -1e-20]), [270.0, 0.0, 5.0, 0.0])
    np.testing.assert_allclose(circular_distance_deg([350.0, 10.0, -170.0, 0.0], [10.0, 350.0, 170.0, 180.0]),
                               [20.0, 20.0, 20.0, 180.0])


@pytest.mark.parametrize(
    "lo, hi", [(-200.0, 200.0), (0.0, 360.0), (-360.0, 360.0), (-5.0, 5.0), (10.0, 700.0)]
)
def test_azimuth_wraps_cover_the_limits(lo, hi):
    wraps = azimuth_wraps(lo, hi)
    targets = np.linspace(lo, hi, 997)
    # Every position in the limits is some a in [0, 360) plus one of the turns.
    reps = wrap_360(targets)[:, None] + 360.0 * wraps
    assert np.all(np.min(np.abs(reps - targets[:, None]), axis=1) < 1e-9)


def test_nearest_allowed_azimuth_stays_when_clear():
    assert nearest_allowed_azimuth(40.0, -200.0, 200.0, 0.0, 10.0) == 40.0
    # A half-width of 0 blocks nothing, even right on the obstacle.
    assert nearest_allowed_azimuth(3.0, -200.0, 200.0, 3.0, 0.0) == 3.0


def test_nearest_allowed_azimuth_steps_to_the_nearer_edge():
    # Obstacle at 3° ± 10°: from 5° the edge at 13° is 8° away, the one at −7° is 12°.
    np.testing.assert_allclose(nearest_allowed_azimuth(5.0, -200.0, 200.0, 3.0, 10.0), 13.0)
    np.testing.assert_allclose(nearest_allowed_azimuth(0.0, -200.0, 200.0, 3.0, 10.0), -7.0)
    # The obstacle's copy one turn on (363° ≡ 3°) blocks 190° too.
    np.testing.assert_allclose(nearest_allowed_azimuth(190.0, -200.0, 360.0, 183.0, 10.0), 193.0)


def test_nearest_allowed_azimuth_respects_limits():
    # The nearer edge (−12°) is outside [−5°, 40°]: the far edge it is.
    np.testing.assert_allclose(nearest_allowed_azimuth(-2.0, -5.0, 40.0, 0.0, 10.0), 10.0)
    # Out of the limits and clear: the limit itself.
    np.testing.assert_allclose(nearest_allowed_azimuth(250.0, -200.0, 200.0, 0.0, 10.0), 200.0)
    # Nothing allowed: the current value brought into the limits (the caller then flags a collision).
    np.testing.assert_allclose(nearest_allowed_azimuth(30.0, -5.0, 5.0, 0.0, 10.0), 5.0)


def test_nearest_allowed_azimuth_broadcasts():
    out = nearest_allowed_azimuth(np.array([[5.0], [100.0]]), -200.0, 200.0, np.array([3.0, 95.0]), 10.0)
    np.testing.assert_allclose(out, [[13.0, 5.0], [100.0, 105.0]])


# --- construction -------------------------------------------------------------------------------------


def test_make_kinematics_builds_the_named_design():
    two, stage = make_kinematics(load_config()), make_kinematics(load_config(SAMPLE_STAGE))
    assert isinstance(two, TwoArm) and two.design == "two-arm"
    assert isinstance(stage, SampleStage) and stage.design == "sample-stage"
    for k in (two, stage):
        assert k.axis_names == type(k).axis_names and len(k.axis_names) == 4
        assert k.limits_deg.shape == (4, 2) and k.home_deg.shape == (4,)
        assert k.velocity_deg_s.shape == (4,) and k.accel_deg_s2.shape == (4,)
        assert k.n_branches == 16
    assert two.limits_deg[1].tolist() == [-90.0, 90.0] and two.home_deg[2] == 180.0
    assert two.velocity_deg_s.tolist() == [60.0, 45.0, 60.0, 45.0]
    with pytest.raises(ValueError):
        two.limits_deg[0, 0] = 0.0          # shared by callers: read-only


def test_design_mismatch_is_rejected():
    with pytest.raises(ValueError, match="kinematics.design.*sample-stage"):
        TwoArm(load_config(SAMPLE_STAGE))


def test_reasons_are_the_published_tuple():
    assert REASONS == ("ok", "out_of_reach", "arm_collision", "occlusion", "beyond_theta_max")


# --- shapes -------------------------------------------------------------------------------------------


def test_scalars_give_one_pose(kin):
    r = np.radians
    assert kin.inverse(r(30), 0.0, r(40), np.pi).shape == (1, 4)
    assert kin.solutions(r(30), 0.0, r(40), np.pi).shape == (1, kin.n_branches, 4)
    code = kin.feasibility(r(30), 0.0, r(40), np.pi)
    assert code.shape == (1,) and code.dtype == np.int8 and code[0] == 0
    out = kin.forward(kin.home_deg)
    assert all(a.shape == (1,) for a in out)
    wi, wo = kin.directions(kin.home_deg)
    assert wi.shape == wo.shape == (1, 3)


def test_inputs_broadcast_and_flatten(kin):
    theta_i = np.radians([[10.0], [20.0], [30.0]])        # (3, 1)
    phi_o = np.radians([0.0, 90.0, 180.0, 270.0])         # (4,)
    axes = kin.inverse(theta_i, 0.0, np.radians(50.0), phi_o)
    assert axes.shape == (12, 4)
    theta_i_back, _, _, phi_o_back = kin.forward(axes)
    np.testing.assert_allclose(theta_i_back, np.repeat(np.radians([10.0, 20.0, 30.0]), 4), atol=1e-12)
    np.testing.assert_allclose(phi_o_back, np.tile(phi_o, 3), atol=1e-12)


def test_current_deg_per_pose_rows(kin):
    n = 5
    theta = np.radians(np.linspace(10, 60, n))
    current = np.tile(kin.home_deg, (n, 1))
    np.testing.assert_array_equal(kin.inverse(theta, 0.0, theta, np.pi, current),
                                  kin.inverse(theta, 0.0, theta, np.pi))


def test_empty_input(kin):
    assert kin.inverse([], [], [], []).shape == (0, 4)
    assert kin.feasibility([], [], [], []).shape == (0,)


def test_blocks_join_in_order(kin):
    # More poses than one block: results must line up with their poses.
    rng = np.random.default_rng(7)
    n = 40_000
    ti, to = rng.uniform(0, np.radians(75), (2, n))
    pi, po = rng.uniform(0, 2 * np.pi, (2, n))
    axes = kin.inverse(ti, pi, to, po)
    ok = ~np.isnan(axes[:, 0])
    assert ok.mean() > 0.95
    back = kin.forward(axes[ok])
    np.testing.assert_allclose(back[0], ti[ok], atol=1e-9)
    np.testing.assert_allclose(back[2], to[ok], atol=1e-9)


# --- validation ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "args, field",
    [
        ((np.nan, 0.0, 0.5, 0.0), "theta_i"),
        ((0.5, np.inf, 0.5, 0.0), "phi_i"),
        ((0.5, 0.0, 2.0, 0.0), "theta_o"),
        ((-0.1, 0.0, 0.5, 0.0), "theta_i"),
        ((0.5, 0.0, 0.5, [0.0, np.nan]), "phi_o"),
        ((0.5, 0.0, 0.5, "north"), "phi_o"),
    ],
)
def test_bad_pose_inputs_name_the_field(kin, args, field):
    for method in (kin.inverse, kin.solutions, kin.feasibility):
        with pytest.raises(ValueError, match=field):
            method(*args)


def test_theta_out_of_range_gives_the_range(kin):
    with pytest.raises(ValueError, match=r"theta_o: 2 rad .* outside the allowed range \[0, π/2\]"):
        kin.inverse(0.5, 0.0, 2.0, 0.0)


def test_shapes_that_do_not_broadcast(kin):
    with pytest.raises(ValueError, match="do not broadcast"):
        kin.inverse([0.1, 0.2], 0.0, [0.1, 0.2, 0.3], 0.0)


def test_bad_axes_name_the_field_and_axis(kin):
    with pytest.raises(ValueError, match=r"axes_deg: expected shape \(4,\) or \(N, 4\)"):
        kin.forward(np.zeros(3))
    bad = np.zeros((2, 4))
    bad[1, 1] = np.nan
    with pytest.raises(ValueError, match=f"axes_deg: axis '{kin.axis_names[1]}'"):
        kin.directions(bad)
    with pytest.raises(ValueError, match="current_deg: 3 rows for 2 poses"):
        kin.inverse([0.1, 0.2], 0.0, 0.5, 0.0, current_deg=np.zeros((3, 4)))
    with pytest.raises(ValueError, match=f"current_deg: axis '{kin.axis_names[3]}'"):
        kin.inverse(0.1, 0.0, 0.5, 0.0, current_deg=[0.0, 0.0, 0.0, np.inf])


# --- reasons shared by both designs -------------------------------------------------------------------


def test_beyond_theta_max_wins_over_everything(kin):
    r = np.radians
    codes = kin.feasibility(r([80.0, 80.5, 30.0, 85.0]), 0.0, r([30.0, 30.0, 81.0, 85.0]), 0.0)
    # The last pose is beyond and also occluded: beyond comes first.
    assert codes.tolist() == [0, BEYOND_THETA_MAX, BEYOND_THETA_MAX, BEYOND_THETA_MAX]
    assert np.isnan(kin.inverse(r(30.0), 0.0, r(81.0), 0.0)).all()


def test_occlusion_is_the_angle_between_the_directions(kin):
    r = np.radians
    # ωi and ωo 4.9° then 5.0° apart: at one azimuth, then across the pole (θ 2° and 2.9° or 3°).
    codes = kin.feasibility(r([40.0, 40.0, 2.0, 2.0]), r([0.0, 0.0, 0.0, 0.0]),
                            r([44.9, 45.0, 2.9, 3.0]), r([0.0, 0.0, 180.0, 180.0]))
    assert codes.tolist() == [OCCLUSION, 0, OCCLUSION, 0]
    assert kin.feasibility(r(30.0), r(100.0), r(30.0), r(100.0))[0] == OCCLUSION
    assert np.isnan(kin.solutions(r(30.0), r(100.0), r(30.0), r(100.0))).all()


STRICT = {
    # The light cannot tilt below 81°, yet theta_max is 80°: nothing is reachable.
    "two-arm": {"light_tilt": {"min_deg": 81.0, "max_deg": 90.0, "home_deg": 85.0}},
    # The detector cannot come above 170° from the light, yet it is at most θi + θo = 160° away.
    "sample-stage": {"detector_tilt": {"min_deg": 170.0, "max_deg": 175.0, "home_deg": 170.0}},
}


@pytest.mark.parametrize("design", sorted(STRICT))
def test_a_limit_that_forbids_everything_gives_no_ok(design):
    k = variant(design, axes=STRICT[design])
    grid = np.radians(np.arange(0.0, 91.0, 10.0))
    ti, pi, to, po = (a.ravel() for a in np.meshgrid(grid, 4 * grid, grid, 4 * grid, indexing="ij"))
    codes = k.feasibility(ti, pi, to, po)
    assert np.all(codes != 0)
    # Every pose that is neither beyond theta_max nor occluded fails on reach.
    assert set(np.unique(codes)) == {OUT_OF_REACH, OCCLUSION, BEYOND_THETA_MAX}
    assert np.isnan(k.inverse(ti, pi, to, po)).all()
    assert np.isnan(k.solutions(ti, pi, to, po)).all()
