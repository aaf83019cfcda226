"""The move-time metric: the slowest axis's trapezoidal time, a true metric, and its cheap key."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.motion.metric import MoveMetric
from gonio.motion.trapezoid import move_time

UNIFORM = ([60.0, 45.0, 60.0, 45.0], [120.0, 90.0, 120.0, 90.0])  # v/a = 0.5 s on every axis
MIXED = ([90.0, 30.0, 60.0, 10.0], [100.0, 60.0, 300.0, 5.0])


@pytest.fixture
def rng():
    return np.random.default_rng(7)


@pytest.mark.parametrize("speeds, uniform", [(UNIFORM, True), (MIXED, False)])
def test_time_is_the_slowest_axis(speeds, uniform, rng):
    m = MoveMetric(*speeds)
    assert m.uniform is uniform
    a = rng.uniform(-200, 200, (500, 4))
    b = a + rng.normal(0, 1, (500, 4)) * rng.choice([0.01, 1.0, 50.0, 300.0], (500, 1))
    want = np.array([max(float(move_time(d, v, acc)) for d, v, acc in zip(row, *speeds, strict=True))
                     for row in b - a])
    np.testing.assert_allclose(m.time(a, b), want, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(np.max(m.axis_times(a, b), axis=-1), want, rtol=1e-12)
    # The key orders moves exactly as their times do.
    key = m.key(a, b)
    order = np.argsort(key, kind="stable")
    assert np.all(np.diff(want[order]) >= -1e-12)
    np.testing.assert_allclose(m.time_from_key(key), want, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("speeds", [UNIFORM, MIXED])
def test_triangle_inequality_and_symmetry(speeds, rng):
    m = MoveMetric(*speeds)
    x, y, z = (rng.uniform(-200, 200, (2000, 4)) * rng.choice([0.001, 0.1, 1.0], (2000, 1)) for _ in range(3))
    assert np.all(m.time(x, z) <= m.time(x, y) + m.time(y, z) + 1e-9)
    np.testing.assert_array_equal(m.time(x, y), m.time(y, x))
    assert np.all(m.time(x, x) == 0.0)


@pytest.mark.parametrize("speeds", [UNIFORM, MIXED])
def test_time_beyond_bounds_every_move_outside_a_chebyshev_ball(speeds, rng):
    m = MoveMetric(*speeds)
    d = rng.normal(0, 1, (3000, 4)) * rng.choice([0.01, 1.0, 100.0], (3000, 1))
    cheb = np.max(np.abs(d) * m.scale, axis=1)
    assert np.all(m.time_beyond(cheb) <= m.time(np.zeros(4), d) + 1e-12)


def test_bad_speeds_are_rejected():
    with pytest.raises(ValueError, match="every axis needs a finite value > 0"):
        MoveMetric([60.0, 0.0], [120.0, 90.0])
    with pytest.raises(ValueError, match="need equal non-empty shapes"):
        MoveMetric([60.0, 45.0], [120.0])
