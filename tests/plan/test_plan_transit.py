"""Plans whose every move is clear in transit: replayed on densely sampled trapezoids by an independent
brute force (tests/motion/transit_brute.py), on both shipped gantries."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from gonio.config import DEFAULT_CONFIG, load_config
from gonio.kinematics import make_kinematics
from gonio.motion.estimate import campaign_estimate
from gonio.motion.metric import MoveMetric
from gonio.motion.safe import park_path, path_time, safe_path
from gonio.plan import STEP_DARK, format_plan, plan_summary
from gonio.plan.transit import step_targets, via_points

sys.path.insert(0, str(Path(__file__).parents[1] / "motion"))
from transit_brute import planned_moves, replay  # noqa: E402

CONFIGS = {"two-arm": DEFAULT_CONFIG, "sample-stage": DEFAULT_CONFIG.parent / "sample-stage.toml"}
# Not iso:step=5 as well (9,196 poses, 8 s of planning on the two gantries): scratch breaks of the
# transit planning (re-solving turned off; colliding moves credited to the run before; the two-arm
# check turned permissive with its carriages' sides merged) fail here exactly where they failed with it,
# on iso:step=10 (the sample stage's 1,156 poses, re-solved in checks of several chunks) or full:step=15.
GRIDS = ["iso:step=10", "full:step=15", "merl:stride=8"]


@pytest.fixture(scope="module", params=list(CONFIGS))
def gantry(request):
    cfg = load_config(CONFIGS[request.param])
    return cfg, make_kinematics(cfg)


@pytest.mark.parametrize("grid", GRIDS)
def test_every_planned_move_and_the_park_replay_without_collision(gantry, grid, planned):
    cfg, kin = gantry
    plan = planned(grid, cfg, kin)
    a, b = planned_moves(kin, plan)
    assert a.shape[0] >= np.count_nonzero(plan.step_kind != STEP_DARK) + 1
    hit = replay(kin, a, b, step_deg=0.1)
    assert not hit.any(), f"{grid}: {hit.sum()} moves collide, first {a[hit][0]} -> {b[hit][0]}"
    # The runner recomputes each path with safe_path: the plan holds exactly those.
    targets = step_targets(plan.step_kind, plan.step_pose, plan.axes_deg, plan.reference_axes_deg)
    here = kin.home_deg
    for s in np.flatnonzero(~np.isnan(targets).any(axis=1)):
        path = safe_path(kin, here, targets[s])
        np.testing.assert_array_equal(path[:-1], plan.via_deg.get(int(s), np.empty((0, 4))))
        here = targets[s]
    np.testing.assert_array_equal(plan.park_deg, park_path(kin, here))
    assert plan.lower_bound_s <= plan.estimated_s


def test_first_merl_move_no_longer_spins_the_detector_a_whole_turn(planned):
    cfg = load_config(DEFAULT_CONFIG)
    kin = make_kinematics(cfg)
    plan = planned("merl:stride=8", cfg, kin)
    a, b = planned_moves(kin, plan)
    # Home -> white reference: the detector carriage stays within half a turn of home.
    assert abs(b[0, 2] - a[0, 2]) <= 180.0
    assert kin.free_component(plan.reference_axes_deg)[0] == kin.free_component(kin.home_deg)[0]
    # No two-arm branch in the plan has the carriages the other way round the ring than at home.
    assert np.all(kin.free_component(plan.axes_deg) == kin.free_component(kin.home_deg)[0])


def test_via_points_are_timed_in_the_estimate():
    cfg = load_config(CONFIGS["sample-stage"])
    kin = make_kinematics(cfg)
    metric = MoveMetric(kin.velocity_deg_s, kin.accel_deg_s2)
    # A step that takes the horizontal detector arm past the support, a dark reading, then home.
    targets = np.array([[0.0, 0.0, -120.0, 90.0], [0.0, 0.0, -60.0, 90.0], [np.nan] * 4])
    via, park, extra = via_points(kin, targets, kin.home_deg)
    assert 1 in via and 2 not in via
    path = np.vstack([via[1], targets[1]])
    np.testing.assert_array_equal(path, safe_path(kin, targets[0], targets[1]))
    assert extra[1] == pytest.approx(path_time(kin, targets[0], path) - metric.time(targets[0], targets[1]))
    assert all(extra[k] > 0 for k in via) and extra[2] == 0.0
    np.testing.assert_array_equal(park[-1], kin.home_deg)
    plain = campaign_estimate(targets, [True, True, False], 3, kin.home_deg, metric, 0.2, 0.1)
    routed = campaign_estimate(targets, [True, True, False], 3, kin.home_deg, metric, 0.2, 0.1, extra)
    assert routed["total_s"] == pytest.approx(plain["total_s"] + extra.sum())
    assert routed["via_s"] == pytest.approx(extra.sum())


def test_report_counts_the_moves_with_via_points(gantry, planned):
    cfg, kin = gantry
    plan = planned("iso:step=15", cfg, kin)
    summary = plan_summary(plan)
    assert summary["moves"] == np.count_nonzero(plan.step_kind != STEP_DARK) + 1
    assert summary["via_moves"] == len(plan.via_deg) + (plan.park_deg.shape[0] > 1)
    assert f"via points   {summary['via_moves']} of {summary['moves']:,} moves" in format_plan(plan)
