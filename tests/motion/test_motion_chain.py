"""Branch chaining: each pose on the branch nearest where the gantry is, runs restarting at the reference."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.config import DEFAULT_CONFIG, load_config
from gonio.kinematics import make_kinematics
from gonio.motion.chain import chain_branches, nearest_branch
from gonio.motion.metric import MoveMetric
from gonio.plan.grids import enumerate_grid, parse_grid

CONFIGS = {"two-arm": DEFAULT_CONFIG, "sample-stage": DEFAULT_CONFIG.parent / "sample-stage.toml"}


@pytest.fixture(params=list(CONFIGS))
def kin(request):
    return make_kinematics(load_config(CONFIGS[request.param]))


def reachable_poses(kin, grid, seed):
    g = enumerate_grid(parse_grid(grid), 80)
    angles = [g.theta_i, g.phi_i, g.theta_o, g.phi_o]
    ok = kin.feasibility(*angles) == 0
    perm = np.random.default_rng(seed).permutation(int(ok.sum()))
    return [a[ok][perm] for a in angles]


def reference_chain(kin, poses, starts, start):
    """The rule spelled out one pose at a time with the kinematics' own inverse."""
    out, here = [], None
    for j in range(len(poses[0])):
        if j in starts:
            here = start
        here = kin.inverse(*(a[j] for a in poses), current_deg=here)[0]
        out.append(here)
    return np.array(out)


@pytest.mark.parametrize("grid", ["iso:step=20", "full:step=60", "merl:stride=30"])
def test_chain_equals_the_one_pose_at_a_time_rule(kin, grid):
    poses = reachable_poses(kin, grid, seed=5)
    start = kin.inverse(0.0, 0.0, np.radians(45), np.pi)[0]
    starts = [0, 7, 8, 15]
    got = chain_branches(kin, *poses, starts, start)
    want = reference_chain(kin, poses, set(starts), start)
    np.testing.assert_allclose(got, want, atol=1e-9)
    # Every target is a true solution of its pose.
    wi, wo = kin.directions(got)
    np.testing.assert_allclose(wi[:, 2], np.cos(poses[0]), atol=1e-9)
    np.testing.assert_allclose(wo[:, 2], np.cos(poses[2]), atol=1e-9)


def test_one_long_run_is_chained_in_windows(kin, monkeypatch):
    import gonio.motion.chain as chain

    poses = reachable_poses(kin, "iso:step=20", seed=6)
    start = kin.home_deg
    want = reference_chain(kin, poses, {0}, start)
    monkeypatch.setattr(chain, "_GROUP_POSES", 16)  # windows of 16 steps instead of one
    np.testing.assert_allclose(chain_branches(kin, *poses, [0], start), want, atol=1e-9)


def test_nearest_branch_breaks_ties_by_total_time():
    metric = MoveMetric([60.0, 60.0], [120.0, 120.0])
    here = np.zeros((1, 2))
    branches = np.array([[[np.nan, np.nan], [30.0, 20.0], [30.0, 5.0], [-30.0, 10.0]]])
    # Three branches share the slowest move (30°); the one with the smallest total wins.
    np.testing.assert_array_equal(nearest_branch(branches, here, metric), [[30.0, 5.0]])


def test_bad_run_starts(kin):
    poses = reachable_poses(kin, "iso:step=30", seed=1)
    with pytest.raises(ValueError, match="run_starts: must include 0"):
        chain_branches(kin, *poses, [3], kin.home_deg)
