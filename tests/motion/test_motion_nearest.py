"""Nearest neighbours without a k-d tree give what scipy's cKDTree gives: the same distances, and the
same neighbours in the same order wherever the order can matter (plans depend on it)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

import gonio.motion.nearest as nearest
from gonio.motion.nearest import LEAF_SIZE, chebyshev_neighbours


def _tree(data, queries, k):
    dist, idx = cKDTree(data).query(queries, k=k, p=np.inf)
    return dist.reshape(len(queries), k), idx.reshape(len(queries), k)


def test_one_leaf_gives_the_trees_order_among_ties():
    """Points on a coarse lattice (ties everywhere, duplicates too) in sets of at most one leaf: the
    order of equal distances is the tree's own, and it is followed exactly."""
    rng = np.random.default_rng(11)
    for _ in range(600):
        n = int(rng.integers(2, LEAF_SIZE + 1))
        data = rng.integers(0, 3, (n, int(rng.integers(1, 5)))) * rng.choice([0.5, 1.0, 3.0])
        k = int(rng.integers(1, n + 1))
        dist, idx = chebyshev_neighbours(data, data, k)
        want_dist, want_idx = _tree(data, data, k)
        np.testing.assert_array_equal(idx, want_idx)
        np.testing.assert_array_equal(dist, want_dist)


def test_beyond_one_leaf_the_brute_force_answers_only_without_ties(monkeypatch):
    rng = np.random.default_rng(12)
    asked = []
    real = nearest._brute
    monkeypatch.setattr(nearest, "_brute", lambda *a: asked.append(r := real(*a)) or r)
    # Distinct random distances: the brute force's answer, the tree's to the last bit.
    data = rng.uniform(-180, 180, (300, 4))
    queries = rng.uniform(-180, 180, (200, 4))
    for k in (1, 2, 9, 300):
        got = chebyshev_neighbours(data, queries, k)
        assert asked.pop() is not None
        for a, b in zip(got, _tree(data, queries, k), strict=True):
            np.testing.assert_array_equal(a, b)
    # A lattice of 64 points: ties beyond one leaf go to the tree, whose order stands.
    grid = np.stack(np.meshgrid(*[np.arange(4.0)] * 3), -1).reshape(-1, 3)
    got = chebyshev_neighbours(grid, grid, 7)
    assert asked.pop() is None
    for a, b in zip(got, _tree(grid, grid, 7), strict=True):
        np.testing.assert_array_equal(a, b)
    # A tie among the k nearest, the k-th alone at its distance: the tree's order still.
    line = np.concatenate([[0.0, 1.0, -1.0, 2.5], 10.0 + 1.37 * np.arange(20)])[:, None]
    got = chebyshev_neighbours(line, line[:1], 4)
    assert asked.pop() is None
    for a, b in zip(got, _tree(line, line[:1], 4), strict=True):
        np.testing.assert_array_equal(a, b)
    # A caller that reads distances only gets them without the tree, the same values.
    dist, idx = chebyshev_neighbours(grid, grid, 7, ties_ok=True)
    assert asked.pop() is not None
    np.testing.assert_array_equal(dist, _tree(grid, grid, 7)[0])
    np.testing.assert_array_equal(np.max(np.abs(grid[idx] - grid[:, None]), axis=-1), dist)
    assert np.all(idx[:, 0] == np.arange(len(grid)))   # each point first among its equals at 0


def test_large_sets_use_the_tree(monkeypatch):
    monkeypatch.setattr(nearest, "BRUTE_MAX_PAIRS", 10)
    monkeypatch.setattr(nearest, "_brute", lambda *a: pytest.fail("brute force above its size"))
    data = np.random.default_rng(13).uniform(0, 1, (20, 2))
    for a, b in zip(chebyshev_neighbours(data, data, 3), _tree(data, data, 3), strict=True):
        np.testing.assert_array_equal(a, b)


def test_k_out_of_range_is_refused():
    with pytest.raises(ValueError, match="k: 4 neighbours asked of 3 points"):
        chebyshev_neighbours(np.zeros((3, 2)), np.zeros((1, 2)), 4)
