"""The valid lower bound and the branch-aware order against an exact search on small real pose sets.

For random subsets of 8 or 9 of the poses a plan of ``iso:step=10`` visits (its reachable poses, on both
shipped gantries; the grid is not planned), the walk
``home → reference → poses → reference → home`` is solved exactly by Held-Karp over orders × branch
choices (:mod:`tests.plan.exact`, independent of the planner's code). The bound of
:mod:`gonio.motion.relaxed` must never exceed that optimum, and :func:`gonio.motion.refine.refine_order`
(from a 2-opt tour of the poses' branches nearest home) must come within 3 % of it on average.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from gonio.config import CONFIG_DIR, load_config
from gonio.kinematics import make_kinematics
from gonio.motion.chain import free_azimuth
from gonio.motion.metric import MoveMetric
from gonio.motion.order import improve_tour, nearest_neighbour_tour
from gonio.motion.refine import refine_order, walk_costs
from gonio.motion.relaxed import pose_branches, relaxed_campaign_bound

sys.path.insert(0, str(Path(__file__).parent))
from exact import held_karp  # noqa: E402

SUBSETS = 100


@pytest.fixture(scope="module", params=["sim.toml", "sample-stage.toml"])
def subsets(request):
    kin, metric, angles, home, ref = _reachable_poses(request.param, "iso:step=10")
    # Fixed branches for the branch-fixed bound: each pose's nearest home (as a chain from home takes).
    axes = kin.inverse(*angles, current_deg=home)
    rng = np.random.default_rng(20240611)
    cases = []
    for _ in range(SUBSETS):
        idx = rng.choice(angles.shape[1], int(rng.integers(8, 10)), replace=False)
        sols = np.asarray(kin.solutions(*angles[:, idx], current_deg=home))
        branches = [s[~np.isnan(s[:, 0])] for s in sols]
        optimum = held_karp(branches, ref, ref, kin.velocity_deg_s, kin.accel_deg_s2)
        cases.append((idx, sols, optimum))
    return kin, metric, angles, ref, home, axes, cases


def test_bound_is_never_above_the_exact_optimum(subsets):
    kin, metric, angles, ref, home, axes, cases = subsets
    home_legs = 2.0 * float(metric.time(home, ref))
    above_old = 0
    for idx, sols, optimum in cases:
        free = free_azimuth(*angles[:, idx])
        bound = relaxed_campaign_bound(sols, free, ref[None], home, metric, 0.0, 0.0, every=100,
                                       run_lengths=[idx.size])
        assert bound["runs"] == 1
        assert bound["move_s"] - home_legs <= optimum + 1e-9
    # The branch-fixed bound is no bound here: it is above the optimum on some subsets.
    from gonio.motion.bound import motion_lower_bound
    for idx, _, optimum in cases:
        old = motion_lower_bound(axes[idx], ref, [idx.size], metric)["motion_s"]
        above_old += old > optimum + 1e-9
    assert above_old > 0


def test_refined_order_is_within_3_percent_of_the_optimum_on_average(subsets):
    kin, metric, angles, ref, home, _, cases = subsets
    gaps, old_gaps = [], []
    for idx, sols, optimum in cases:
        branches = pose_branches(sols)
        near = kin.inverse(*angles[:, idx], current_deg=home)
        start = improve_tour(near, nearest_neighbour_tour(near, metric, ref), metric, ref)
        old = float(walk_costs(branches, start[None], ref, ref, metric)[0])
        order, cost = refine_order(branches, start, ref, ref, metric)
        assert sorted(order.tolist()) == list(range(idx.size))
        assert cost <= old + 1e-9
        assert cost >= optimum - 1e-9
        gaps.append(cost / optimum - 1.0)
        old_gaps.append(old / optimum - 1.0)
    assert np.mean(gaps) < 0.03
    assert np.mean(gaps) < np.mean(old_gaps)


def test_the_planners_tour_is_within_3_percent_of_the_optimum_on_average(subsets):
    """What ``build_plan`` does for a tour of these poses: the seeded branch sets it tries, each ordered
    (nearest neighbour, kicked 2-opt/Or-opt, then exact branch pricing on so few poses), the quicker
    kept. Without the exact pricing the sample stage's mean gap was 4 %."""
    import gonio.plan.build as build

    kin, metric, angles, ref, home, _, cases = subsets
    gaps = []
    for idx, sols, optimum in cases:
        branches = pose_branches(sols)
        sub = tuple(angles[:, idx])
        seeds = build._tour_seeds(kin, sub, np.vstack([home, ref[None]]), metric)[:build.TOUR_SEED_TRIALS]
        costs = [float(walk_costs(branches, build._tour_order(kin, sub, pts, neigh, ref, home, metric)[None],
                                  ref, ref, metric)[0]) for pts, neigh in seeds]
        assert min(costs) >= optimum - 1e-9
        gaps.append(min(costs) / optimum - 1.0)
    assert np.mean(gaps) < 0.03
    assert np.mean(np.asarray(gaps) < 1e-9) > 0.5   # the optimum itself, most of the time


def _sample_stage_poses(grid):
    """The sample stage's kinematics, metric, reachable poses of ``grid`` (4, P), home and reference."""
    return _reachable_poses("sample-stage.toml", grid)


def _reachable_poses(config, grid):
    """Kinematics, metric, reachable poses of ``grid`` (4, P), home and the reference pose's branch
    nearest home on the shipped ``config``: what a plan of ``grid`` visits, without planning it."""
    from gonio.plan.grids import enumerate_grid, parse_grid

    cfg = load_config(CONFIG_DIR / config)
    kin = make_kinematics(cfg)
    metric = MoveMetric(kin.velocity_deg_s, kin.accel_deg_s2)
    poses = enumerate_grid(parse_grid(grid), cfg.kinematics.theta_max_deg)
    angles = np.stack([poses.theta_i, poses.phi_i, poses.theta_o, poses.phi_o])
    angles = angles[:, kin.feasibility(*angles) == 0]
    home = np.asarray(kin.home_deg, float)
    ref = kin.inverse(*np.radians([cfg.reference.theta_i_deg, 0.0, cfg.reference.theta_o_deg,
                                   cfg.reference.dphi_deg]), current_deg=home)[0]
    return kin, metric, angles, home, ref


@pytest.mark.parametrize("grid", ["iso:step=10", "full:step=15"])
def test_the_planners_tour_is_within_3_percent_of_the_optimum_on_every_8_to_12_pose_subset(grid):
    """Not only on average: on the sample stage (whose two tilt signs make order and branch choice depend
    on each other) local search with exact branch pricing was up to 13 % above the optimum on some
    8-12-pose subsets (4.2 % on one of these 40 full:step=15 subsets, 2.4 % on iso:step=10). Tours
    that small are now solved exactly (:func:`gonio.motion.exact.exact_order`); the optimum here is the
    tests' own Held-Karp."""
    import gonio.plan.build as build

    kin, metric, angles, home, ref = _sample_stage_poses(grid)
    rng = np.random.default_rng(5)
    gaps = []
    for size in np.repeat(np.arange(8, 13), 8):
        idx = rng.choice(angles.shape[1], int(size), replace=False)
        sub = tuple(angles[:, idx])
        sols = np.asarray(kin.solutions(*sub, current_deg=home))
        optimum = held_karp([s[~np.isnan(s[:, 0])] for s in sols], ref, ref, kin.velocity_deg_s,
                            kin.accel_deg_s2)
        seeds = build._tour_seeds(kin, sub, np.vstack([home, ref[None]]), metric)[:build.TOUR_SEED_TRIALS]
        orders = [build._tour_order(kin, sub, pts, neigh, ref, home, metric) for pts, neigh in seeds]
        cost = float(walk_costs(pose_branches(sols), np.array(orders), ref, ref, metric).min())
        assert cost >= optimum - 1e-9
        gaps.append(cost / optimum - 1.0)
    assert max(gaps) <= 0.03, f"gaps above 3 %: {sorted(gaps)[-3:]}"


# Of 40 seeded 8-12-pose subsets (seed 7) of each grid, those where the search ended farthest above the
# optimum before it had exact windows and 16 restarts (3.65 %, 1.79 % and 1.22 % on iso:step=10;
# 5.62 %, 5.24 %, 1.92 % and 2.85 % on full:step=15), and one that was optimal.
_SEARCH_PICKS = {"iso:step=10": (38, 24, 18, 0), "full:step=15": (24, 38, 13, 32)}


@pytest.mark.parametrize("grid", sorted(_SEARCH_PICKS))
def test_the_tour_search_itself_is_within_3_percent_of_the_optimum_on_small_subsets(grid, monkeypatch):
    """The local search that orders the sample stage's tours of 13-24 poses (nearest neighbour, kicked
    2-opt/Or-opt, then 2-opt/Or-opt priced after the branch choice, restarted, and exact windows), run
    on 8-12-pose subsets with the exact shortcut for tours of at most 12 poses turned off, so that the
    tests' own Held-Karp can check it: within 3 % of the optimum on each."""
    import gonio.plan.build as build

    monkeypatch.setattr(build, "EXACT_MAX_POSES", 1)
    kin, metric, angles, home, ref = _sample_stage_poses(grid)
    rng = np.random.default_rng(7)
    drawn = [rng.choice(angles.shape[1], int(rng.integers(8, 13)), replace=False) for _ in range(40)]
    gaps = {}
    for pick in _SEARCH_PICKS[grid]:
        sub = tuple(angles[:, drawn[pick]])
        sols = np.asarray(kin.solutions(*sub, current_deg=home))
        optimum = held_karp([s[~np.isnan(s[:, 0])] for s in sols], ref, ref, kin.velocity_deg_s,
                            kin.accel_deg_s2)
        seeds = build._tour_seeds(kin, sub, np.vstack([home, ref[None]]), metric)[:build.TOUR_SEED_TRIALS]
        orders = np.array([build._tour_order(kin, sub, pts, neigh, ref, home, metric)
                           for pts, neigh in seeds])
        assert all(sorted(o.tolist()) == list(range(sub[0].size)) for o in orders)
        cost = float(walk_costs(pose_branches(sols), orders, ref, ref, metric).min())
        assert cost >= optimum - 1e-9
        gaps[pick] = cost / optimum - 1.0
    assert max(gaps.values()) <= 0.03, f"gaps: {gaps}"
