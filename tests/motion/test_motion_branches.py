"""Branch choice by dynamic programming: the quickest assignment per run, never slower than greedy."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from gonio.config import DEFAULT_CONFIG, load_config
from gonio.kinematics import make_kinematics
from gonio.motion.branches import best_branches
from gonio.motion.chain import chain_branches
from gonio.motion.metric import MoveMetric

CONFIGS = {"two-arm": DEFAULT_CONFIG, "sample-stage": DEFAULT_CONFIG.parent / "sample-stage.toml"}


@pytest.fixture(params=list(CONFIGS))
def kin(request):
    return make_kinematics(load_config(CONFIGS[request.param]))


def random_poses(kin, n, seed, pole=False):
    rng = np.random.default_rng(seed)
    m = 4 * n
    ti, to = rng.uniform(0.05, 1.35, m), rng.uniform(0.05, 1.35, m)
    if pole:
        ti[rng.random(m) < 0.2] = 0.0
    pi_, po = rng.uniform(0, 2 * np.pi, m), rng.uniform(0, 2 * np.pi, m)
    ok = np.flatnonzero(kin.feasibility(ti, pi_, to, po) == 0)[:n]
    assert ok.size == n
    return [a[ok] for a in (ti, pi_, to, po)]


def walk(axes, starts, ref, metric):
    """Move time of ref → run → ref → … → run → ref."""
    total = 0.0
    bounds = list(starts) + [len(axes)]
    for s, e in itertools.pairwise(bounds):
        path = np.concatenate([ref[None], axes[s:e], ref[None]])
        total += float(metric.time(path[:-1], path[1:]).sum())
    return total


def test_dynamic_programming_finds_the_brute_force_optimum(kin):
    metric = MoveMetric(kin.velocity_deg_s, kin.accel_deg_s2)
    poses = random_poses(kin, 8, seed=2)
    ref = kin.inverse(0.0, 0.0, np.radians(45), np.pi)[0]
    starts = [0, 3, 4]  # runs of 3, 1 and 4 poses
    got = best_branches(kin, *poses, starts, ref)
    sols = kin.solutions(*poses)
    options = [s[~np.isnan(s[:, 0])] for s in sols]
    best = 0.0
    for s, e in itertools.pairwise(starts + [8]):
        best += min(walk(np.array(choice), [0], ref, metric)
                    for choice in itertools.product(*options[s:e]))
    assert walk(got, starts, ref, metric) == pytest.approx(best, rel=1e-12)


@pytest.mark.parametrize("pole", [False, True])
def test_never_slower_than_the_greedy_chain(kin, pole):
    metric = MoveMetric(kin.velocity_deg_s, kin.accel_deg_s2)
    poses = random_poses(kin, 300, seed=4, pole=pole)
    order = np.argsort(poses[1] * 3 + poses[3])  # some coherent order, azimuth-major
    poses = [a[order] for a in poses]
    ref = kin.inverse(0.0, 0.0, np.radians(45), np.pi)[0]
    starts = np.arange(0, 300, 40)
    dp = best_branches(kin, *poses, starts, ref)
    greedy = chain_branches(kin, *poses, starts, ref)
    assert walk(dp, starts, ref, metric) <= walk(greedy, starts, ref, metric) + 1e-9
    # Every target is a solution of its pose, within the limits.
    wi, wo = kin.directions(dp)
    np.testing.assert_allclose(wi[:, 2], np.cos(poses[0]), atol=1e-9)
    np.testing.assert_allclose(wo[:, 2], np.cos(poses[2]), atol=1e-9)
    assert np.all((dp >= kin.limits_deg[:, 0] - 1e-9) & (dp <= kin.limits_deg[:, 1] + 1e-9))


def test_groups_of_runs_give_the_same_answer(kin, monkeypatch):
    import gonio.motion.branches as branches

    poses = random_poses(kin, 120, seed=9, pole=True)
    ref = kin.home_deg
    starts = np.arange(0, 120, 7)
    whole = best_branches(kin, *poses, starts, ref)
    monkeypatch.setattr(branches, "_GROUP_POSES", 10)
    np.testing.assert_array_equal(best_branches(kin, *poses, starts, ref), whole)
