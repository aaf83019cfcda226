"""The exact order of a few poses against the tests' own Held-Karp (tests/plan/exact.py)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from gonio.motion.exact import EXACT_MAX_POSES, exact_order
from gonio.motion.metric import MoveMetric
from gonio.motion.refine import walk_costs

sys.path.insert(0, str(Path(__file__).parents[1] / "plan"))
from exact import held_karp  # noqa: E402

V = np.array([60.0, 45.0, 60.0, 45.0])
A = np.array([120.0, 90.0, 120.0, 90.0])


@pytest.mark.parametrize("seed", range(12))
def test_exact_order_is_the_optimum_over_orders_and_branches(seed):
    rng = np.random.default_rng(seed)
    n, w = int(rng.integers(1, 9)), int(rng.integers(1, 5))
    branches = rng.uniform(-180, 180, (n, w, 4))
    # Some poses repeat a branch (a free azimuth, invalid branches filled in): counted once.
    branches[:, -1] = branches[:, 0] if seed % 2 else branches[:, -1]
    start, end = rng.uniform(-90, 90, 4), rng.uniform(-90, 90, 4)
    metric = MoveMetric(V, A)
    order, cost = exact_order(branches, start, end, metric)
    assert sorted(order.tolist()) == list(range(n))
    assert cost == pytest.approx(float(walk_costs(branches, order[None], start, end, metric)[0]), abs=1e-9)
    assert cost == pytest.approx(held_karp(list(branches), start, end, V, A), abs=1e-9)


def test_exact_order_refuses_walks_it_cannot_afford():
    branches = np.zeros((EXACT_MAX_POSES + 1, 1, 4))
    with pytest.raises(ValueError, match="at most 12"):
        exact_order(branches, np.zeros(4), np.zeros(4), MoveMetric(V, A))


@pytest.mark.parametrize("closed", [True, False])
def test_refine_orders_exact_windows_never_lose_and_price_what_they_return(closed):
    """Windows solved exactly (wrapping round the depot of a closed walk) after the moves: a
    permutation, priced as walk_costs prices it, never above the moves alone, never below the optimum."""
    from gonio.motion.refine import refine_order

    rng = np.random.default_rng(3)
    metric = MoveMetric(V, A)
    branches = rng.uniform(-120, 120, (11, 3, 4))
    start = rng.uniform(-90, 90, 4)
    end = start if closed else rng.uniform(-90, 90, 4)
    order0 = rng.permutation(11)
    plain = refine_order(branches, order0, start, end, metric, kicks=0)[1]
    order, cost = refine_order(branches, order0, start, end, metric, kicks=0, window=6)
    assert sorted(order.tolist()) == list(range(11))
    assert cost == pytest.approx(float(walk_costs(branches, order[None], start, end, metric)[0]), abs=1e-9)
    assert exact_order(branches, start, end, metric)[1] - 1e-9 <= cost <= plain + 1e-9
