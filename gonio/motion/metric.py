"""The move-time metric: how long the gantry takes to go from one set of axis positions to another.

All axes start together and the move is over when the slowest one arrives, so the time of a move is
the maximum over axes of each axis's rest-to-rest trapezoidal time
(:func:`gonio.motion.trapezoid.move_time`). Each per-axis time is increasing and subadditive in the
distance (its square-root start is concave), so the maximum over axes is a metric on axis space: the
triangle inequality holds, which is what makes minimum-spanning-tree bounds and shortcutting valid.

Settle time and exposure are per-reading fixed costs and are not part of the metric.

When every axis has the same ratio v/a (true of both shipped configs), the time is a single increasing
function of a weighted Chebyshev distance: with u_k = |Δ_k| a_k / v_k² and τ(u) = 2√u (u < 1), u + 1
(u >= 1), each axis takes (v/a)·τ(u_k), so the move takes (v/a)·τ(max_k u_k). :class:`MoveMetric`
exposes that "key" (monotone in time, much cheaper, and a norm a k-d tree can search exactly); with
unequal ratios the key is the time itself and neighbour searches are bounded instead of exact.
"""

from __future__ import annotations

import numpy as np

from gonio.motion.trapezoid import move_time

__all__ = ["MoveMetric"]

# Relative tolerance for "all axes share one v/a ratio" (config values are plain decimals).
_RATIO_RTOL = 1e-12


class MoveMetric:
    """Move times between axis positions, in seconds.

    Parameters
    ----------
    velocity_deg_s, accel_deg_s2 : array_like, shape (n_axes,)
        Maximum speed (°/s) and acceleration (°/s²) of each axis, all > 0.

    Attributes
    ----------
    uniform : bool
        True when every axis has the same v/a ratio, so :meth:`key` is a weighted Chebyshev norm.
    scale : ndarray, shape (n_axes,)
        Per-axis weights (1/°) that make axis distances comparable: a_k / v_k². Multiplying axis
        positions by ``scale`` gives the coordinates in which the key is a Chebyshev distance.

    Examples
    --------
    >>> m = MoveMetric([60.0, 45.0], [120.0, 90.0])
    >>> float(m.time([0.0, 0.0], [30.0, 0.0]))      # cruise: 30/60 + 60/120
    1.0
    """

    def __init__(self, velocity_deg_s, accel_deg_s2):
        v = np.asarray(velocity_deg_s, dtype=np.float64).reshape(-1)
        a = np.asarray(accel_deg_s2, dtype=np.float64).reshape(-1)
        if v.shape != a.shape or v.size == 0:
            raise ValueError(f"velocity_deg_s and accel_deg_s2: need equal non-empty shapes, got {v.shape}, "
                             f"{a.shape}")
        if not (np.all(v > 0) and np.all(a > 0) and np.all(np.isfinite(v)) and np.all(np.isfinite(a))):
            raise ValueError("velocity_deg_s and accel_deg_s2: every axis needs a finite value > 0")
        self.velocity_deg_s = v
        self.accel_deg_s2 = a
        self.n_axes = v.size
        ratio = v / a
        self.uniform = bool(np.all(np.abs(ratio - ratio[0]) <= _RATIO_RTOL * ratio[0]))
        self._ratio = float(ratio[0])
        self.scale = a / (v * v)

    def axis_times(self, a_deg, b_deg) -> np.ndarray:
        """Per-axis move times (..., n_axes) in s between positions ``a_deg`` and ``b_deg`` (broadcast)."""
        d = np.asarray(b_deg, dtype=np.float64) - np.asarray(a_deg, dtype=np.float64)
        return move_time(d, self.velocity_deg_s, self.accel_deg_s2)

    def time(self, a_deg, b_deg) -> np.ndarray:
        """Move time (...) in s between axis positions ``a_deg`` and ``b_deg`` (..., n_axes); NaN if NaN."""
        if self.uniform:
            return self.time_from_key(self.key(a_deg, b_deg))
        return np.max(self.axis_times(a_deg, b_deg), axis=-1)

    def key(self, a_deg, b_deg) -> np.ndarray:
        """A quantity that increases with the move time (equal keys, equal times): the weighted
        Chebyshev distance when :attr:`uniform`, else the time itself. Cheaper than :meth:`time`."""
        if not self.uniform:
            return self.time(a_deg, b_deg)
        d = np.asarray(b_deg, dtype=np.float64) - np.asarray(a_deg, dtype=np.float64)
        return np.max(np.abs(d) * self.scale, axis=-1)

    def time_from_key(self, key) -> np.ndarray:
        """Move time in s of a :meth:`key` value."""
        u = np.asarray(key, dtype=np.float64)
        if not self.uniform:
            return u
        # A move shorter than v²/a (u < 1) never reaches cruise speed: the triangle profile.
        if u.ndim == 0:
            return self._ratio * np.where(u < 1.0, 2.0 * np.sqrt(np.abs(u)), u + 1.0)
        # The same operations in one array (a table of pair times is millions of keys: each temporary
        # of that size costs as much as the arithmetic).
        t = np.abs(u)
        np.sqrt(t, out=t)
        t *= 2.0
        np.add(u, 1.0, out=t, where=~(u < 1.0))
        t *= self._ratio
        return t

    def time_beyond(self, chebyshev) -> np.ndarray:
        """A lower bound in s on the time of any move whose scaled Chebyshev distance (positions times
        :attr:`scale`) is at least ``chebyshev``: exact when :attr:`uniform`."""
        r = np.asarray(chebyshev, dtype=np.float64)
        if self.uniform:
            return self.time_from_key(r)
        # Some axis k moves at least r / scale_k degrees; the move takes at least that axis's time.
        return np.min(move_time(r[..., None] / self.scale, self.velocity_deg_s, self.accel_deg_s2), axis=-1)

