"""The quickest walk through a few poses, exactly: Held-Karp over visiting orders × branch choices.

For a walk ``start → every pose once (any order, each on any of its branches) → end`` the dynamic
program over (set of poses visited, last pose, its branch) finds the optimum (a generalized travelling
salesman: a pose is visited on one of its branches). It costs O(2^N · (N·W)²) time, so it is for short
walks: the planner's tours of at most :data:`EXACT_MAX_POSES` poses, where local search, even with
exact branch pricing, still ended up to 13 % above the optimum on the sample stage (its two tilt signs
make the best order depend on the branch choice and the other way round).

Sets of masks with the same number of poses are relaxed together, a block at a time, so the work is
numpy's and memory stays bounded (a few tens of MB at N = 12, W = 16). Each pose's duplicate
branches (a free azimuth, invalid branches filled in) are states only once.
"""

from __future__ import annotations

import numpy as np

from gonio.motion.metric import MoveMetric

__all__ = ["exact_order", "least_through", "EXACT_MAX_POSES"]

#: The largest walk :func:`exact_order` takes (2^12 sets of poses).
EXACT_MAX_POSES = 12
# (mask, pose, branch) states relaxed at once: bounds the (block, N·W, N·W) temporary.
_BLOCK_STATES = 1 << 21


def least_through(cost: np.ndarray, moves: np.ndarray) -> np.ndarray:
    """``np.min(cost[:, :, None] + moves, axis=1)``: the least cost (B, K) of standing on each of K
    states after one move, from ``cost`` (B, K) of standing on each before it and the move times
    ``moves`` (B, K, K) or (K, K) between them (from, to).

    One state before at a time: the same sums and the same least to the last digit (a minimum is
    exact), two to four times quicker than numpy's reduction over a short middle axis, which is the
    inner loop of every branch-priced walk (this Held-Karp, :mod:`gonio.motion.refine`)."""
    out = cost[:, 0, None] + moves[..., 0, :]
    for i in range(1, cost.shape[1]):
        np.minimum(out, cost[:, i, None] + moves[..., i, :], out=out)
    return out


def exact_order(branches, start_deg, end_deg, metric: MoveMetric) -> tuple[np.ndarray, float]:
    """The order of the poses that makes ``start → poses → end`` quickest over every branch choice.

    Parameters
    ----------
    branches : ndarray, shape (N, W, n_axes)
        Finite branch positions (invalid ones replaced by a valid one of the same pose, as
        :func:`gonio.motion.relaxed.pose_branches` does), degrees; N <= :data:`EXACT_MAX_POSES`.
    start_deg, end_deg : array_like, shape (n_axes,)
    metric : MoveMetric

    Returns
    -------
    order : ndarray of int64, shape (N,)
    cost_s : float
        Its move time: the least over every order and branch choice.
    """
    b = np.asarray(branches, dtype=np.float64)
    n, w, n_axes = b.shape
    if n > EXACT_MAX_POSES:
        raise ValueError(f"exact_order: {n} poses; at most {EXACT_MAX_POSES}")
    if n == 0:
        return np.empty(0, dtype=np.int64), float(metric.time(np.asarray(start_deg, float),
                                                              np.asarray(end_deg, float)))
    # The distinct branches of every pose, as one list of states (duplicates change no minimum).
    keep = np.ones((n, w), dtype=bool)
    for c in range(1, w):
        keep[:, c] = ~(b[:, :c] == b[:, c:c + 1]).all(axis=-1).any(axis=1)
    pose_of, branch_of = np.nonzero(keep)
    pts = b[pose_of, branch_of]                                         # (K, n_axes)
    k = pts.shape[0]
    pair = metric.time(pts[:, None, :], pts[None, :, :])                # (K, K)
    first = metric.time(np.asarray(start_deg, float), pts)              # (K,)
    last = metric.time(pts, np.asarray(end_deg, float))

    full = 1 << n
    bit_of = (1 << pose_of).astype(np.int64)
    cost = np.full((full, k), np.inf)
    cost[bit_of, np.arange(k)] = first
    masks = np.arange(full)
    popcount = np.zeros(full, dtype=np.int64)
    for j in range(n):
        popcount += (masks >> j) & 1
    block = max(1, _BLOCK_STATES // (k * k))
    for size in range(1, n):
        layer = masks[popcount == size]
        for lo in range(0, layer.size, block):
            m = layer[lo:lo + block]
            best = least_through(cost[m], pair)                         # (B, K)
            # Each (grown set, state) comes from exactly one smaller set: the set without its pose.
            out = (m[:, None] & bit_of[None, :]) == 0
            rows, states = np.nonzero(out)
            grown = m[rows] | bit_of[states]
            cost[grown, states] = best[rows, states]
    total = cost[full - 1] + last
    state = int(np.argmin(total))
    best_cost = float(total[state])
    order = np.empty(n, dtype=np.int64)
    mask = full - 1
    # Back from the last state: the state before is the first one whose cost plus the move equals this
    # state's cost (the same sum the forward pass took its least of, so equal to the last digit).
    for pos in range(n - 1, 0, -1):
        order[pos] = pose_of[state]
        here = cost[mask, state]
        mask ^= int(bit_of[state])
        state = int(np.flatnonzero(cost[mask] + pair[:, state] == here)[0])
    order[0] = pose_of[state]
    return order, best_cost
