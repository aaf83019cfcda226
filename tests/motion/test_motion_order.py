"""Visiting orders: serpentine and raster on grids, nearest neighbour + 2-opt/Or-opt on scattered poses."""

from __future__ import annotations

import itertools
import sys
from pathlib import Path

import numpy as np
import pytest

from gonio.motion.bound import mst_edge_times
from gonio.motion.metric import MoveMetric
from gonio.motion.order import (
    improve_tour,
    nearest_neighbour_tour,
    neighbour_lists,
    perturb_tour,
    raster_order,
    serpentine_order,
    tour_time,
)

sys.path.insert(0, str(Path(__file__).parent.parent / "plan"))
from exact import held_karp  # noqa: E402

METRIC = MoveMetric([60.0, 45.0, 60.0, 45.0], [120.0, 90.0, 120.0, 90.0])
MIXED = MoveMetric([90.0, 30.0, 60.0, 10.0], [100.0, 60.0, 300.0, 5.0])


@pytest.fixture
def rng():
    return np.random.default_rng(3)


def test_serpentine_by_hand():
    loops = np.array(list(itertools.product(range(3), range(2), range(3))))
    got = [tuple(loops[i]) for i in serpentine_order(loops)]
    want = [(0, 0, 0), (0, 0, 1), (0, 0, 2), (0, 1, 2), (0, 1, 1), (0, 1, 0),
            (1, 1, 0), (1, 1, 1), (1, 1, 2), (1, 0, 2), (1, 0, 1), (1, 0, 0),
            (2, 0, 0), (2, 0, 1), (2, 0, 2), (2, 1, 2), (2, 1, 1), (2, 1, 0)]
    assert got == want
    assert [tuple(loops[i]) for i in raster_order(loops)] == sorted(want)


def test_serpentine_on_a_ragged_grid_moves_one_step_at_a_time(rng):
    # A triangle (b >= a, like an iso grid with reciprocity) in shuffled input order.
    loops = np.array([(a, b, m) for a in range(6) for b in range(a, 6) for m in range(5)])
    loops = loops[rng.permutation(len(loops))]
    order = serpentine_order(loops)
    assert sorted(order.tolist()) == list(range(len(loops)))
    steps = np.abs(np.diff(loops[order], axis=0)).sum(axis=1)
    # Within a row one step of m; between rows of one slab one step of b. Slabs alternate direction
    # in b: slab 0 runs b 0..5, slab 1 5..1, slab 2 2..5, slab 3 5..3, slab 4 4..5, slab 5 5..5, so
    # entering slabs 2 and 4 steps both a and b (the triangle's edge); the others only a.
    assert steps.max() <= 2
    assert np.count_nonzero(steps == 2) == 2


def test_serpentine_beats_raster_on_an_axis_grid():
    loops = np.array(list(itertools.product(range(5), range(6), range(12))))
    pts = loops * np.array([10.0, 7.5, 15.0])
    pts = np.concatenate([pts, np.zeros((len(pts), 1))], axis=1)
    depot = np.zeros(4)
    serp = tour_time(pts, serpentine_order(loops), METRIC, depot)
    rast = tour_time(pts, raster_order(loops), METRIC, depot)
    # Raster flies back across every row (11 steps of m, 5 rows of b per slab) and every slab.
    assert serp < rast
    assert rast - serp > 0.5 * (5 * 6 - 1) * float(METRIC.time(np.zeros(4), [0, 0, 11 * 15.0, 0]))


def test_bad_loops():
    with pytest.raises(ValueError, match=r"loops: expected integer loop indices of shape \(P, L\)"):
        serpentine_order(np.arange(5))


@pytest.mark.parametrize("metric", [METRIC, MIXED], ids=["uniform", "mixed"])
def test_neighbour_lists_are_the_nearest(metric, rng):
    pts = rng.uniform(-100, 100, (300, 4))
    idx, times = neighbour_lists(pts, metric, k=5)
    d = metric.time(pts[:, None], pts[None])
    np.fill_diagonal(d, np.inf)
    assert np.all(idx != np.arange(300)[:, None])
    assert np.all(np.diff(times, axis=1) >= 0)
    np.testing.assert_allclose(times, np.take_along_axis(d, idx, axis=1))
    if metric.uniform:
        np.testing.assert_allclose(times, np.sort(d, axis=1)[:, :5])


def test_nearest_neighbour_tour_is_greedy(rng):
    pts = rng.uniform(-100, 100, (200, 4))
    depot = np.full(4, 5.0)
    order = nearest_neighbour_tour(pts, METRIC, depot)
    assert sorted(order.tolist()) == list(range(200))
    # Brute force: at every step, no unvisited pose is strictly nearer than the one taken.
    here, left = depot, set(range(200))
    for nxt in order:
        rest = np.array(sorted(left))
        assert METRIC.time(here, pts[nxt]) <= METRIC.time(here, pts[rest]).min() + 1e-12
        left.remove(nxt)
        here = pts[nxt]


@pytest.mark.parametrize("metric", [METRIC, MIXED], ids=["uniform", "mixed"])
@pytest.mark.parametrize("n", [3, 4, 5, 60, 1500])
def test_local_search_never_lengthens_and_keeps_a_permutation(metric, n, rng):
    pts = rng.uniform(-150, 150, (n, 4))
    depot = np.zeros(4)
    nn = nearest_neighbour_tour(pts, metric, depot)
    better = improve_tour(pts, nn, metric, depot)
    assert sorted(better.tolist()) == list(range(n))
    assert tour_time(pts, better, metric, depot) <= tour_time(pts, nn, metric, depot) + 1e-9
    # The kicks keep it a permutation, never end above the local search alone, and follow their seed.
    kicks = min(3 * n, 300)
    kicked = perturb_tour(pts, nn, metric, depot, kicks=kicks, seed=7)
    assert sorted(kicked.tolist()) == list(range(n))
    assert tour_time(pts, kicked, metric, depot) <= tour_time(pts, better, metric, depot) + 1e-9
    assert np.array_equal(kicked, perturb_tour(pts, nn, metric, depot, kicks=kicks, seed=7))
    # From a poor start (a random order) the search must find real improvements.
    rand = rng.permutation(n)
    fixed = improve_tour(pts, rand, metric, depot)
    assert sorted(fixed.tolist()) == list(range(n))
    if n >= 60:
        assert tour_time(pts, fixed, metric, depot) < 0.6 * tour_time(pts, rand, metric, depot)


def test_local_search_finds_the_optimum_of_a_small_instance(rng):
    pts = rng.uniform(-150, 150, (7, 4))
    depot = np.zeros(4)
    best = min(tour_time(pts, list(p), METRIC, depot) for p in itertools.permutations(range(7)))
    got = tour_time(pts, improve_tour(pts, nearest_neighbour_tour(pts, METRIC, depot), METRIC, depot),
                    METRIC, depot)
    assert best <= got <= 1.1 * best


def test_tour_of_scattered_poses_is_near_the_mst(rng):
    pts = rng.uniform([-200, -90, -200, -90], [200, 90, 200, 90], (2000, 4))
    depot = np.zeros(4)
    order = improve_tour(pts, nearest_neighbour_tour(pts, METRIC, depot), METRIC, depot)
    ratio = tour_time(pts, order, METRIC, depot) / mst_edge_times(pts, METRIC).sum()
    # Any tour is at least the MST; a good one on random points stays well under twice it.
    assert 1.0 < ratio < 1.3


@pytest.mark.parametrize("metric", [METRIC, MIXED], ids=["uniform", "mixed"])
def test_kicks_reach_the_exact_optimum_where_local_search_stops_short(metric):
    """40 random 10-pose tours against Held-Karp: 2-opt/Or-opt alone stops above the optimum in many of
    them; the kicked search finds it in nearly all, and is never below it."""
    rng = np.random.default_rng(5)
    v, acc = metric.velocity_deg_s, metric.accel_deg_s2
    local_hits = kicked_hits = 0
    gaps = []
    for _ in range(40):
        pts = rng.uniform(-150, 150, (10, 4))
        depot = np.zeros(4)
        optimum = held_karp([p[None] for p in pts], depot, depot, v, acc)
        nn = nearest_neighbour_tour(pts, metric, depot)
        local = tour_time(pts, improve_tour(pts, nn, metric, depot), metric, depot)
        kicked = tour_time(pts, perturb_tour(pts, nn, metric, depot, kicks=20, span=10), metric, depot)
        assert kicked >= optimum - 1e-9
        local_hits += local <= optimum + 1e-9
        kicked_hits += kicked <= optimum + 1e-9
        gaps.append(kicked / optimum - 1.0)
    assert kicked_hits >= 36 and kicked_hits > local_hits
    assert np.mean(gaps) < 0.002


def test_kicks_shorten_a_large_tour_that_local_search_left(rng):
    """300 scattered poses on axes of very different speeds: the kicks take several % off the 2-opt/Or-opt
    tour (5.8 % here)."""
    pts = rng.uniform(-150, 150, (300, 4))
    depot = np.zeros(4)
    nn = nearest_neighbour_tour(pts, MIXED, depot)
    local = tour_time(pts, improve_tour(pts, nn, MIXED, depot), MIXED, depot)
    kicked = tour_time(pts, perturb_tour(pts, nn, MIXED, depot, kicks=600), MIXED, depot)
    assert kicked < 0.97 * local
