"""Exact search for tests: Held-Karp over visiting orders × inverse-kinematics branch choices.

Independent of the planner's code on purpose: plain per-axis trapezoid times (numpy, no MoveMetric),
a dynamic program over (set of poses visited, last pose, its branch). The walk is
``start → poses (any order, each on any of its branches) → end``; fixed costs are not its business.
"""

from __future__ import annotations

import numpy as np


def trapezoid_time(a, b, v, acc) -> np.ndarray:
    """Rest-to-rest move time (broadcast over leading axes) as the maximum over axes of each axis's
    triangle or trapezoid profile."""
    d = np.abs(np.asarray(b, float) - np.asarray(a, float))
    t = np.where(d < v * v / acc, 2.0 * np.sqrt(d / acc), d / v + v / acc)
    return t.max(axis=-1)


def held_karp(branches, start, end, v, acc) -> float:
    """Least move time in s of ``start → every pose once (any order, any branch) → end``.

    Parameters
    ----------
    branches : list of ndarray (W_i, n_axes)
        The valid branches of each pose, degrees.
    start, end : ndarray (n_axes,)
    v, acc : ndarray (n_axes,)
        Axis speeds (°/s) and accelerations (°/s²).
    """
    # A pose's repeated branches (a free azimuth, the two-arm gantry's mirror images) change no minimum.
    branches = [np.unique(np.asarray(b, dtype=np.float64), axis=0) for b in branches]
    n = len(branches)
    w = max(b.shape[0] for b in branches)
    pts = np.full((n, w, len(v)), np.nan)
    for i, b in enumerate(branches):
        pts[i, : b.shape[0]] = b
    valid = ~np.isnan(pts[..., 0])
    # d[i, b, j, c]: pose i branch b -> pose j branch c
    d = trapezoid_time(pts[:, :, None, None, :], pts[None, None, :, :, :], v, acc)
    d = np.where(valid[:, :, None, None] & valid[None, None, :, :], d, np.inf)
    first = np.where(valid, trapezoid_time(start, pts, v, acc), np.inf)  # (n, w)
    last = np.where(valid, trapezoid_time(pts, end, v, acc), np.inf)
    full = 1 << n
    dp = np.full((full, n, w), np.inf)
    for i in range(n):
        dp[1 << i, i] = first[i]
    # One layer of sets at a time (those of k poses visited), all its sets at once:
    # best[m, j, c] = min over (i, b) of dp[m, i, b] + d[i, b, j, c], then each j not in m extends m.
    # Only a pose i in m can be its last (dp is infinite for the others): the sets holding each i are
    # taken in turn. Each (set of k+1, last pose) has exactly one set of k it comes from, so one
    # assignment fills it.
    masks = np.arange(full)
    size = np.array([m.bit_count() for m in range(full)])
    for k in range(1, n):
        layer = masks[size == k]
        best = np.full((layer.size, n, w), np.inf)
        for i in range(n):
            rows = np.flatnonzero(layer & (1 << i))
            # The least over b, one branch b at a time (numpy's reduction over a short middle axis
            # is several times slower; a minimum is exact, so the same figure).
            here = dp[layer[rows], i]                                               # (sets, w)
            via = best[rows]
            for b in range(w):
                np.minimum(via, here[:, b, None, None] + d[i, b][None], out=via)  # (sets, n, w)
            best[rows] = via
        for j in range(n):
            lacking = (layer & (1 << j)) == 0
            dp[layer[lacking] | (1 << j), j] = best[lacking, j]
    return float(np.min(dp[full - 1] + last))
