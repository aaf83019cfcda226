"""Motion-cost weighting of a round's poses (:mod:`gonio.adaptive.motion`): a candidate's share of the
error per second of gantry time, the move measured from the nearest pose chosen before it."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.adaptive import acquire, material_measure, plan_round
from gonio.adaptive.motion import Motion, cheapest_first, round_motion
from gonio.adaptive.plan import MOTION_WEIGHT
from gonio.config import load_config
from gonio.kinematics import make_kinematics
from gonio.motion.metric import MoveMetric
from gonio.plan.build import build_plan
from gonio.plan.grids import GridPoses
from gonio.sim.materials import load


@pytest.fixture(scope="module")
def gantry():
    cfg = load_config()
    kin = make_kinematics(cfg)
    return cfg, kin, round_motion(cfg, kin, MOTION_WEIGHT)


def test_the_motion_of_the_shipped_gantry(gantry):
    cfg, kin, motion = gantry
    per_pose = cfg.runner.settle_s + cfg.detector.exposure_s * cfg.detector.frames
    assert motion.fixed_s == pytest.approx(per_pose) and motion.weight == MOTION_WEIGHT
    # the white reference's axes: θi = 0, θo = 45°, Δφ = 180°
    ti, _, to, _ = kin.forward(motion.start_deg[None, :])
    assert np.degrees(ti[0]) == pytest.approx(0.0, abs=1e-9) and np.degrees(to[0]) == pytest.approx(45.0)


def test_equal_worth_goes_to_the_cheapest_chain(gantry):
    _, kin, motion = gantry
    # four candidates: two near the reference (θo 45° and 50°), two far off (θi 70°)
    ti = np.radians([70.0, 0.0, 70.0, 5.0])
    to = np.radians([10.0, 50.0, 20.0, 45.0])
    d = np.radians([0.0, 180.0, 90.0, 180.0])
    chosen = cheapest_first(kin, motion, ti, to, d, np.ones(4), 2)
    assert sorted(chosen.tolist()) == [1, 3]
    # a far candidate worth much more than the time it costs comes first
    worth = np.array([50.0, 1.0, 1.0, 1.0])
    assert cheapest_first(kin, motion, ti, to, d, worth, 1).tolist() == [0]
    # weight 0: the worth alone (ties to the first)
    flat = Motion(motion.start_deg, motion.fixed_s, 0.0)
    assert cheapest_first(kin, flat, ti, to, d, np.array([1.0, 2.0, 3.0, 0.5]), 4).tolist() == [2, 1, 0, 3]


def test_a_weighted_round_tours_quicker_than_an_unweighted_one(gantry):
    """The same samples, the same round size: the poses chosen with the motion cost make a shorter tour
    (the planner's own estimate) than those chosen by error alone."""
    cfg, kin, motion = gantry
    tmax = np.radians(cfg.kinematics.theta_max_deg)
    samples = acquire(material_measure(load("ggx:alpha=0.2,metal=gold")), kin, tmax, 200).samples
    times = {}
    for name, m in (("error", None), ("motion", motion)):
        ti, to, d = plan_round(samples, 40, kin, tmax, motion=m)
        assert ti.size == 40
        n = ti.size
        poses = GridPoses(ti, np.zeros(n), to, d, np.arange(n)[:, None], {"grid": n})
        times[name] = build_plan("adaptive:poses=400", cfg, kin, poses=poses).timing["pose_motion_s"]
    assert times["motion"] < 0.8 * times["error"], times   # measured: 35.7 s and 23.8 s (a pool of 3: 23.1 s)
    assert MoveMetric(kin.velocity_deg_s, kin.accel_deg_s2).n_axes == motion.start_deg.size
