"""Orders improved with the branch choice folded in: local search whose every move is priced exactly.

A move of a tour (2-opt: reverse a stretch; Or-opt: move a stretch of one to three poses elsewhere,
either way round) is worth what it saves *after* the branches are chosen again for the new order, not
what it saves on branches fixed beforehand. Here every candidate order is priced by dynamic
programming over its poses' branches (the same Viterbi as :mod:`gonio.motion.branches`, batched over
candidates), the best improving move is taken, and that repeats until none improves. Then a few
seeded double-bridge kicks (cut the walk in four, swap the middle stretches) followed by the same
descent look past the local optimum (iterated local search); a kick is kept only when it ends shorter.
Last, optionally, stretches of a few stops are solved exactly (:func:`gonio.motion.exact.exact_order`
between the positions on either side; a closed walk's stretches wrap round its depot) and the descent
resumes after each one that saves time: what no single move reaches (on the sample stage, a pose that
belongs at the other end of the tour on its other tilt sign).

The walk is ``start → poses → end`` with fixed ends (the reference pose, or the branches on either
side of a window of a longer tour: :func:`refine_windows`). Batched pricing is O(N² · N · W²) per
descent step, so :func:`refine_order` is for short walks; :func:`refine_windows` slides it along long
ones.
"""

from __future__ import annotations

import functools

import numpy as np

from gonio.motion.exact import exact_order, least_through
from gonio.motion.metric import MoveMetric

__all__ = ["walk_costs", "best_walk", "candidate_orders", "refine_order", "refine_windows"]

# s: a candidate must save more than this to be taken.
_GAIN_EPS = 1e-9


def walk_costs(branches, orders, start_deg, end_deg, metric: MoveMetric) -> np.ndarray:
    """Least move time (B,) in s of ``start → branches[orders[b]] → end`` over every branch choice.

    Parameters
    ----------
    branches : ndarray, shape (N, W, n_axes)
        Finite branch positions (invalid ones replaced by a valid one of the same pose), degrees.
    orders : ndarray of int, shape (B, L)
        Candidate orders (each a sequence of pose indices).
    start_deg, end_deg : array_like, shape (n_axes,)
    metric : MoveMetric
    """
    return _priced(_tables(branches, start_deg, end_deg, metric), orders)


def _tables(branches, start_deg, end_deg, metric):
    """Move times between every pair of branches (N, N, W, W: pose i to pose j, branch of i, branch of
    j, each pose pair's block contiguous), from the start (N, W) and to the end, over each pose's
    distinct branches only (:func:`_distinct`)."""
    b = _distinct(np.asarray(branches, dtype=np.float64))
    pair = metric.time(b[:, None, :, None, :], b[None, :, None, :, :])
    first = metric.time(np.asarray(start_deg, float), b)
    last = metric.time(b, np.asarray(end_deg, float))
    return pair, first, last


def _distinct(b: np.ndarray) -> np.ndarray:
    """Branches (N, W', n_axes) with each pose's repeated branches dropped (first kept, order kept), W'
    the most distinct branches of any pose, the gaps filled with the pose's first branch.

    A repeat changes no minimum, so every walk costs the same to the last digit; the pricing's work
    goes as W'²: the two-arm gantry's poses carry 12 branches of which 3 differ, the sample stage's 9."""
    if b.shape[1] < 2:
        return b
    same = (b[:, :, None, :] == b[:, None, :, :]).all(axis=-1)   # (N, W, W)
    keep = ~np.triu(same, 1).any(axis=1)                           # no earlier branch equal to it
    width = int(keep.sum(axis=1).max())
    if width == b.shape[1]:
        return b
    first = np.argsort(~keep, axis=1, kind="stable")[:, :width]
    out = np.take_along_axis(b, first[:, :, None], axis=1)
    return np.where(np.take_along_axis(keep, first, axis=1)[..., None], out, b[:, :1, :])


def _priced(tables, orders) -> np.ndarray:
    pair, first, last = tables
    orders = np.asarray(orders, dtype=np.int64)
    cost = first[orders[:, 0]]  # (B, W)
    for step in range(1, orders.shape[1]):
        cost = least_through(cost, pair[orders[:, step - 1], orders[:, step]])
    return np.min(cost + last[orders[:, -1]], axis=1)


def best_walk(branches, order, start_deg, end_deg, metric: MoveMetric) -> np.ndarray:
    """The branch (L, n_axes) of each pose of ``order`` that makes the walk quickest."""
    order = np.asarray(order, dtype=np.int64)
    seq = branches[order]
    n_steps, w = seq.shape[:2]
    back = np.zeros((n_steps, w), dtype=np.int64)
    cost = metric.time(np.asarray(start_deg, float), seq[0])
    for step in range(1, n_steps):
        t = cost[:, None] + metric.time(seq[step - 1][:, None, :], seq[step][None, :, :])
        back[step] = np.argmin(t, axis=0)
        cost = np.min(t, axis=0)
    state = int(np.argmin(cost + metric.time(seq[-1], np.asarray(end_deg, float))))
    out = np.empty((n_steps, seq.shape[2]))
    for step in range(n_steps - 1, -1, -1):
        out[step] = seq[step, state]
        state = int(back[step, state])
    return out


def candidate_orders(order) -> np.ndarray:
    """Every 2-opt and Or-opt neighbour (C, L) of ``order`` (a walk with fixed ends)."""
    order = np.asarray(order, dtype=np.int64)
    return order[_moves(order.size)]


@functools.lru_cache(maxsize=64)
def _moves(n: int) -> np.ndarray:
    """The 2-opt and Or-opt neighbours (C, n) of the walk 0..n-1: every walk's are these positions."""
    order = np.arange(n)
    out = []
    for i in range(n - 1):
        for j in range(i + 1, n):
            o = order.copy()
            o[i:j + 1] = o[i:j + 1][::-1]
            out.append(o)
    for seg in (1, 2, 3):
        for i in range(n - seg + 1):
            piece = order[i:i + seg]
            rest = np.concatenate([order[:i], order[i + seg:]])
            for k in range(rest.size + 1):
                if k == i:
                    if seg > 1:
                        out.append(np.concatenate([rest[:k], piece[::-1], rest[k:]]))
                    continue
                out.append(np.concatenate([rest[:k], piece, rest[k:]]))
                if seg > 1:
                    out.append(np.concatenate([rest[:k], piece[::-1], rest[k:]]))
    moves = np.array(out, dtype=np.int64).reshape(-1, n)
    moves.flags.writeable = False
    return moves


@functools.lru_cache(maxsize=64)
def _move_spans(n: int):
    """The distinct moves of :func:`_moves` (first of each kept, in order), the first and last position
    each changes, and for each step s the moves whose pricing needs the move into position s (those
    from their first changed position to the one after their last)."""
    moves = _moves(n)
    _, first_seen = np.unique(moves, axis=0, return_index=True)
    moves = moves[np.sort(first_seen)]
    changed = moves != np.arange(n)
    lo = np.argmax(changed, axis=1)
    hi = n - 1 - np.argmax(changed[:, ::-1], axis=1)
    until = np.minimum(hi + 1, n - 1)
    active = [np.flatnonzero((np.maximum(lo, 1) <= s) & (s <= until)) for s in range(n)]
    for a in (moves, lo, until, *active):
        a.flags.writeable = False
    return moves, lo, until, active


def _neighbour_costs(tables, order) -> np.ndarray:
    """What :func:`_priced` gives for every distinct 2-opt/Or-opt neighbour of ``order`` (C,), the
    neighbours (C, L), in the order of :func:`candidate_orders` with repeats dropped.

    A neighbour differs from ``order`` only on a stretch: before it, its forward costs are the order's
    own (the same sums, so the same digits); after it, the order's backward costs (least time from each
    branch to the end) finish it. Those are summed the other way round, so their last digits may differ:
    every neighbour within a rounding margin of the least is priced again forwards (:func:`_priced`),
    which is the figure returned for those, so the least and which neighbour has it are exactly
    :func:`_priced`'s over all neighbours."""
    pair, first, last = tables
    n = order.size
    moves, lo, until, active = _move_spans(n)
    cands = order[moves]
    # The order's forward costs F[s] (cost of standing on each branch of its pose s) and backward ones
    # G[s] (least time from each branch of pose s to the end).
    fwd = np.empty((n, pair.shape[2]))
    fwd[0] = first[order[0]]
    for s in range(1, n):
        fwd[s] = np.min(fwd[s - 1][:, None] + pair[order[s - 1], order[s]], axis=0)
    back = np.empty_like(fwd)
    back[-1] = last[order[-1]]
    for s in range(n - 2, -1, -1):
        back[s] = np.min(pair[order[s], order[s + 1]] + back[s + 1][None, :], axis=1)
    cost = np.where((lo == 0)[:, None], first[cands[:, 0]], fwd[np.maximum(lo - 1, 0)])
    for s in range(1, n):
        rows = active[s]
        if rows.size:
            cost[rows] = least_through(cost[rows], pair[cands[rows, s - 1], cands[rows, s]])
    # Moves ending at the last pose, or at the one before it, are priced forwards to the end already.
    ends = np.where((until == n - 1)[:, None], last[cands[:, -1]], back[until])
    costs = np.min(cost + ends, axis=1)
    least = float(costs.min())
    near = np.flatnonzero(costs <= least + max(_GAIN_EPS, 1e-12 * abs(least)))
    costs[near] = _priced(tables, cands[near])
    return costs, cands


def _descend(tables, order, cost):
    while True:
        if order.size < 2:
            return order, cost
        costs, cands = _neighbour_costs(tables, order)
        if cands.shape[0] == 0:
            return order, cost
        k = int(np.argmin(costs))
        if costs[k] >= cost - _GAIN_EPS:
            return order, cost
        order, cost = cands[k], float(costs[k])


def _exact_windows(branches, tables, order, cost, start, end, metric, window):
    """Each stretch of ``window`` stops of the walk (overlapping by half) replaced by the exact optimum
    between the positions the walk stands on before and after it (:func:`gonio.motion.exact.exact_order`),
    kept when the whole walk, its branches chosen again, ends shorter; the new order and its cost.

    A closed walk (``start`` equal to ``end``: a tour from and back to the reference) is a cycle whose
    depot is one more stop with the one position: windows wrap round it, so the poses just before and
    just after the depot can trade places (the end of a tour is as much its start)."""
    n = order.size
    closed = bool(np.array_equal(start, end))
    if closed:
        depot = np.broadcast_to(start, (1,) + branches.shape[1:])
        stops = np.concatenate([branches, depot])              # stop n is the depot
        nodes = np.concatenate([[n], order])
    else:
        stops, nodes = branches, order
    m = nodes.size
    if m <= window + (0 if closed else -1):
        return order, cost
    step = max(window // 2, 1)
    firsts = list(range(0, m, step)) if closed else list(range(0, m - window, step)) + [m - window]

    def positions(order):
        walk = best_walk(branches, order, start, end, metric)
        return np.concatenate([start[None], walk]) if closed else walk

    at = positions(order)
    for lo in firsts:
        idx = (lo + np.arange(window)) % m
        if closed:
            before, after = at[(lo - 1) % m], at[(lo + window) % m]
        else:
            before = at[lo - 1] if lo else start
            after = at[lo + window] if lo + window < m else end
        piece = nodes[idx]
        sub, _ = exact_order(stops[piece], before, after, metric)
        if np.array_equal(sub, np.arange(window)):
            continue
        cycle = nodes.copy()
        cycle[idx] = piece[sub]
        if closed:
            k = int(np.flatnonzero(cycle == n)[0])
            new = np.concatenate([cycle[k + 1:], cycle[:k]])
        else:
            new = cycle
        new_cost = float(_priced(tables, new[None])[0])
        if new_cost < cost - _GAIN_EPS:
            order, cost = new, new_cost
            nodes = np.concatenate([[n], order]) if closed else order
            at = positions(order)
    return order, cost


def _improve(branches, tables, order, cost, start, end, metric, window):
    """2-opt/Or-opt descent and exact windows in turn until neither saves anything."""
    while True:
        order, cost = _descend(tables, order, cost)
        if window < 2:
            return order, cost
        order, new_cost = _exact_windows(branches, tables, order, cost, start, end, metric, window)
        if new_cost >= cost - _GAIN_EPS:
            return order, cost
        cost = new_cost


def refine_order(branches, order, start_deg, end_deg, metric: MoveMetric, kicks: int = 8,
                 seed: int = 0, window: int = 0) -> tuple[np.ndarray, float]:
    """Best-improvement 2-opt/Or-opt descent with exact branch pricing, then ``kicks`` double-bridge
    restarts (seeded; each kept only if it ends shorter).

    Parameters
    ----------
    branches : ndarray, shape (N, W, n_axes)
        Finite branch positions of the poses, degrees.
    order : array_like of int, shape (L,)
        The walk to improve (indices into ``branches``).
    start_deg, end_deg : array_like, shape (n_axes,)
        Fixed ends of the walk.
    metric : MoveMetric
    kicks : int
        Double-bridge restarts.
    seed : int
        Seed of the kicks' cut points.
    window : int
        Once 2-opt/Or-opt find nothing, stretches of this many stops (poses, and the depot of a closed
        walk) are solved exactly between the positions on either side of them, overlapping by half, and
        the descent resumes after any that saves time (at most
        :data:`gonio.motion.exact.EXACT_MAX_POSES`; below 2, none: the default). A walk no longer than a
        window is left to the moves (solve it with :func:`gonio.motion.exact.exact_order`).

    Returns
    -------
    order : ndarray of int64, shape (L,)
        Never slower than the input.
    cost_s : float
        Its least move time over branch choices.
    """
    order = np.asarray(order, dtype=np.int64)
    if order.size == 0:
        return order.copy(), 0.0
    # Only the poses of the walk, renumbered, so the tables stay small.
    poses = order.copy()
    pose_b = np.asarray(branches, dtype=np.float64)[poses]
    start, end = np.asarray(start_deg, float), np.asarray(end_deg, float)
    tables = _tables(pose_b, start, end, metric)
    local = np.arange(order.size)
    cost = float(_priced(tables, local[None])[0])
    if order.size < 2:
        return order.copy(), cost
    best, cost = _descend(tables, local, cost)
    rng = np.random.default_rng(seed)
    n = order.size
    for _ in range(kicks if n >= 4 else 0):
        a, b, c = np.sort(rng.choice(np.arange(1, n), size=3, replace=False))
        kicked = np.concatenate([best[:a], best[b:c], best[a:b], best[c:]])
        k_cost = float(_priced(tables, kicked[None])[0])
        kicked, k_cost = _descend(tables, kicked, k_cost)
        if k_cost < cost - _GAIN_EPS:
            best, cost = kicked, k_cost
    # Exact windows last: the kicks' descents are cheap, a window pass is not.
    best, cost = _improve(pose_b, tables, best, cost, start, end, metric, window)
    return poses[best], cost


def refine_windows(branches, order, axes_deg, start_deg, end_deg, metric: MoveMetric, window: int = 9,
                   kicks: int = 2) -> np.ndarray:
    """A long walk improved window by window: each stretch of ``window`` poses is reordered by
    :func:`refine_order` between the fixed positions on either side of it (the chosen branches of its
    neighbours), so every accepted change shortens the walk on those branches.

    Parameters
    ----------
    branches : ndarray, shape (N, W, n_axes)
        Finite branch positions, degrees.
    order : ndarray of int, shape (N,)
        The walk.
    axes_deg : ndarray, shape (N, n_axes)
        The branch each pose of the walk stands on now, in walk order.
    start_deg, end_deg : array_like, shape (n_axes,)
    metric : MoveMetric
    window : int
        Poses per window; windows overlap by half.
    kicks : int
        Double-bridge restarts per window.

    Returns
    -------
    ndarray of int64, shape (N,)
        The walk's new order (the caller chooses the branches again over the whole of it).
    """
    order = np.asarray(order, dtype=np.int64).copy()
    axes = np.asarray(axes_deg, dtype=np.float64).copy()
    n = order.size
    if n < 3:
        return order
    step = max(window // 2, 1)
    for lo in range(0, max(n - window, 0) + 1, step):
        hi = min(lo + window, n)
        before = axes[lo - 1] if lo else np.asarray(start_deg, float)
        after = axes[hi] if hi < n else np.asarray(end_deg, float)
        piece = order[lo:hi]
        old = float(walk_costs(branches[piece], np.arange(piece.size)[None], before, after, metric)[0])
        new, cost = refine_order(branches, piece, before, after, metric, kicks=kicks, seed=lo)
        if cost < old - _GAIN_EPS:
            order[lo:hi] = new
            axes[lo:hi] = best_walk(branches[new], np.arange(new.size), before, after, metric)
    return order
