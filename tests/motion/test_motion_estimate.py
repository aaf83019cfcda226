"""Campaign duration and its lower bound: the same cost model, and the bound below the estimate."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.motion.estimate import campaign_estimate, campaign_lower_bound, step_move_times
from gonio.motion.metric import MoveMetric
from gonio.motion.trapezoid import move_time

METRIC = MoveMetric([60.0, 45.0], [120.0, 90.0])


def test_step_move_times_by_hand():
    home = np.array([0.0, 0.0])
    targets = np.array([[np.nan, np.nan], [30.0, 0.0], [30.0, 45.0], [np.nan, np.nan], [0.0, 0.0]])
    got = step_move_times(targets, home, METRIC)
    want = [0.0, float(move_time(30, 60, 120)), float(move_time(45, 45, 90)), 0.0,
            max(float(move_time(30, 60, 120)), float(move_time(45, 45, 90)))]
    np.testing.assert_allclose(got, want)


def test_campaign_estimate_adds_up():
    home = np.array([0.0, 0.0])
    targets = np.array([[np.nan, np.nan], [30.0, 0.0], [30.0, 45.0], [np.nan, np.nan]])
    settles = np.array([False, True, True, False])
    got = campaign_estimate(targets, settles, 4, home, METRIC, settle_s=0.25, reading_s=0.5)
    moves = float(move_time(30, 60, 120) + move_time(45, 45, 90))
    back = max(float(move_time(30, 60, 120)), float(move_time(45, 45, 90)))
    assert got["move_s"] == pytest.approx(moves)
    assert got["return_s"] == pytest.approx(back)
    assert got["settle_s"] == pytest.approx(0.5) and got["reading_s"] == pytest.approx(2.0)
    assert got["total_s"] == pytest.approx(moves + back + 0.5 + 2.0)


@pytest.mark.parametrize("every", [1, 3, 10, 100])
def test_lower_bound_is_below_the_estimate_of_any_order(every):
    rng = np.random.default_rng(every)
    poses = rng.uniform(-90, 90, (40, 2))
    ref, home = np.array([10.0, -20.0]), np.array([0.0, 5.0])
    starts = np.arange(0, 40, every)
    lengths = np.diff(np.append(starts, 40))
    bound = campaign_lower_bound(poses, ref, lengths, len(starts) + 1, len(starts) + 1, home, METRIC, 0.2,
                                 0.1)
    for _ in range(20):
        order = rng.permutation(40)
        steps = []
        for s, length in zip(starts, lengths, strict=True):
            steps += [np.full(2, np.nan), ref] + [poses[i] for i in order[s:s + length]]
        steps += [np.full(2, np.nan), ref]
        targets = np.array(steps)
        settles = ~np.isnan(targets[:, 0])
        est = campaign_estimate(targets, settles, len(targets), home, METRIC, 0.2, 0.1)
        assert bound["total_s"] <= est["total_s"]
        # Fixed costs agree exactly: only the moves differ.
        assert bound["settle_s"] == pytest.approx(est["settle_s"])
        assert bound["reading_s"] == pytest.approx(est["reading_s"])
