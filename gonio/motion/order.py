"""Orders in which to visit poses: raster and serpentine for grids, nearest neighbour + 2-opt/Or-opt for
scattered sets.

Grid orders work on each pose's integer loop indices (outer loop first); they need no positions.
Tour orders work on axis positions (degrees) under the move-time metric and treat the walk as a
closed tour from and back to a depot (the reference pose, where every campaign starts and ends).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from gonio.motion.metric import MoveMetric
from gonio.motion.nearest import chebyshev_neighbours

__all__ = ["raster_order", "serpentine_order", "nearest_neighbour_tour", "improve_tour", "perturb_tour",
           "tour_time", "neighbour_lists", "PERTURB_SPAN"]

# s: a move must save more than this to be taken (float noise must not make the search cycle).
_GAIN_EPS = 1e-9
#: Poses within which a kick's three cuts fall (:func:`perturb_tour`).
PERTURB_SPAN = 30


def raster_order(loops) -> np.ndarray:
    """Plain nested-loop order: lexicographic in the loop indices (P, L), outer loop first."""
    loops = _loops(loops)
    if loops.shape[1] == 0:
        return np.arange(loops.shape[0])
    return np.lexsort(loops.T[::-1])


def serpentine_order(loops) -> np.ndarray:
    """Boustrophedon order of a (possibly ragged) grid given loop indices (P, L), outer loop first.

    Every level alternates direction from one row to the next in the order rows are visited (not by
    the parity of the row's own index), so consecutive rows always join end to end even when rows
    differ in length or a level above has itself been reversed.

    Returns
    -------
    ndarray, shape (P,)
        The permutation of poses (indices into ``loops``).

    Examples
    --------
    >>> serpentine_order([[0, 0], [0, 1], [1, 0], [1, 1], [2, 0], [2, 1]]).tolist()
    [0, 1, 3, 2, 4, 5]
    """
    loops = _loops(loops)
    p, levels = loops.shape
    if levels == 0 or p == 0:
        return np.arange(p)
    signed = loops.copy()
    for level in range(1, levels):
        # Rank the rows of this level (prefixes) in visiting order; odd-ranked rows run backward.
        order = np.lexsort(signed[:, :level].T[::-1])
        prefix = signed[order, :level]
        new_row = np.empty(p, dtype=bool)
        new_row[0] = True
        new_row[1:] = np.any(prefix[1:] != prefix[:-1], axis=1)
        rank = np.empty(p, dtype=np.int64)
        rank[order] = np.cumsum(new_row) - 1
        signed[:, level] = np.where(rank % 2 == 1, -loops[:, level], loops[:, level])
    return np.lexsort(signed.T[::-1])


def tour_time(points_deg, order, metric: MoveMetric, depot_deg) -> float:
    """Move time in s of ``depot → points[order[0]] → … → points[order[-1]] → depot``."""
    pts = np.asarray(points_deg, dtype=np.float64)[np.asarray(order)]
    depot = np.asarray(depot_deg, dtype=np.float64).reshape(1, -1)
    if pts.shape[0] == 0:
        return 0.0
    walk = np.concatenate([depot, pts, depot])
    return float(np.sum(metric.time(walk[:-1], walk[1:])))


def neighbour_lists(points_deg, metric: MoveMetric, k: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Each pose's ``k`` nearest other poses by move time, nearest first.

    Candidates are the nearest in the metric's scaled Chebyshev coordinates
    (:func:`gonio.motion.nearest.chebyshev_neighbours`; exact when the metric is uniform, a good
    approximation otherwise), re-ranked by the true move time.

    Returns
    -------
    idx : ndarray of int64, shape (N, k')
        Neighbour indices, k' = min(k, N - 1).
    times : ndarray, shape (N, k')
        Their move times in s.
    """
    pts = np.asarray(points_deg, dtype=np.float64)
    n = pts.shape[0]
    k = min(k, n - 1)
    if k <= 0:
        return np.empty((n, 0), dtype=np.int64), np.empty((n, 0))
    extra = 0 if metric.uniform else k  # oversample when the tree's norm only approximates the metric
    q = min(k + 1 + extra, n)
    _, idx = chebyshev_neighbours(pts * metric.scale, pts * metric.scale, q)
    times = metric.time(pts[:, None, :], pts[idx])
    times[idx == np.arange(n)[:, None]] = np.inf
    pick = np.argsort(times, axis=1, kind="stable")[:, :k]
    return np.take_along_axis(idx, pick, axis=1), np.take_along_axis(times, pick, axis=1)


def nearest_neighbour_tour(points_deg, metric: MoveMetric, depot_deg, neighbours=None) -> np.ndarray:
    """Greedy tour: from the depot, always move to the nearest pose not yet visited.

    Parameters
    ----------
    points_deg : array_like, shape (N, n_axes)
        Axis positions in degrees.
    metric : MoveMetric
        The move-time metric.
    depot_deg : array_like, shape (n_axes,)
        Where the walk starts (degrees).
    neighbours : ndarray, optional
        Precomputed :func:`neighbour_lists` indices; computed when None.

    Returns
    -------
    ndarray of int64, shape (N,)
        The visiting order (a permutation of range(N)).
    """
    pts = np.asarray(points_deg, dtype=np.float64)
    n = pts.shape[0]
    if n == 0:
        return np.empty(0, dtype=np.int64)
    if neighbours is None:
        neighbours = neighbour_lists(pts, metric)[0]
    neigh = neighbours.tolist()
    visited = np.zeros(n, dtype=bool)
    remaining = np.arange(n)
    order = np.empty(n, dtype=np.int64)
    here = np.asarray(depot_deg, dtype=np.float64)
    cur = -1
    for step in range(n):
        nxt = -1
        if cur >= 0:
            for c in neigh[cur]:
                if not visited[c]:
                    nxt = c
                    break
        if nxt < 0:
            # The neighbourhood is used up: scan everything left (compacting the list as it empties).
            if remaining.size > 2 * (n - step):
                remaining = remaining[~visited[remaining]]
            key = metric.key(here, pts[remaining])
            key[visited[remaining]] = np.inf
            nxt = int(remaining[np.argmin(key)])
        order[step] = nxt
        visited[nxt] = True
        cur = nxt
        here = pts[nxt]
    return order


def improve_tour(points_deg, order, metric: MoveMetric, depot_deg, neighbours=None,
                 max_moves: int | None = None) -> np.ndarray:
    """2-opt and Or-opt local search on the closed tour ``depot → order → depot``.

    Moves are searched among each pose's nearest neighbours with a queue of poses to revisit
    ("don't-look bits"), and one is taken only when it shortens the tour by more than 1 ns, so the
    result is never longer than the input. 2-opt reverses a stretch of the tour; Or-opt moves a run
    of one to three poses elsewhere (possibly reversed).

    Parameters
    ----------
    points_deg : array_like, shape (N, n_axes)
        Axis positions in degrees.
    order : array_like of int, shape (N,)
        The tour to improve (a permutation of range(N)).
    metric : MoveMetric
        The move-time metric.
    depot_deg : array_like, shape (n_axes,)
        Start and end of the tour (degrees).
    neighbours : ndarray, optional
        Precomputed :func:`neighbour_lists` indices.
    max_moves : int, optional
        Stop after this many improving moves (default: 50 N).

    Returns
    -------
    ndarray of int64, shape (N,)
        The improved order.
    """
    order = np.asarray(order, dtype=np.int64)
    if order.size < 3:
        return order.copy()
    search = _TourSearch(points_deg, order, metric, depot_deg, neighbours)
    search.descend(order, 50 * order.size if max_moves is None else int(max_moves))
    return search.order()


def perturb_tour(points_deg, order, metric: MoveMetric, depot_deg, neighbours=None, kicks: int = 0,
                 seed: int = 0, span: int = PERTURB_SPAN) -> np.ndarray:
    """Iterated local search: :func:`improve_tour`, then ``kicks`` seeded segment double bridges, each
    followed by the same 2-opt/Or-opt descent from the poses it touched and kept only when the tour
    ends shorter (by more than 1 ns), so the result is never longer than the input.

    A double bridge cuts the tour at three points within ``span`` consecutive poses and swaps the two
    stretches between them (``A B C D -> A C B D``): a change no sequence of improving 2-opt and
    Or-opt moves makes, which is what keeps local search stuck (row ends of a grid joined the wrong
    way). Kicks near each other let the descent repair them locally, so each costs about as much as
    a few moves, not a pass over the tour. Deterministic for a given seed.

    Parameters
    ----------
    points_deg, order, metric, depot_deg, neighbours
        As for :func:`improve_tour`.
    kicks : int
        Double bridges tried.
    seed : int
        Seed of the cut points.
    span : int
        Poses within which the three cuts fall.

    Returns
    -------
    ndarray of int64, shape (N,)
    """
    order = np.asarray(order, dtype=np.int64)
    n = order.size
    if n < 3:
        return order.copy()
    search = _TourSearch(points_deg, order, metric, depot_deg, neighbours)
    search.descend(order, 50 * n)
    m = n + 1
    span = min(int(span), m - 1)
    if span < 4:
        return search.order()
    rng = np.random.default_rng(seed)
    for _ in range(int(kicks)):
        lo = int(rng.integers(0, m - span))
        a, b, c = np.sort(rng.choice(np.arange(lo + 1, lo + span + 1), size=3, replace=False)).tolist()
        saved = search.tour.copy()
        search.mark()
        gain = search.double_bridge(a, b, c)
        gain += search.descend([saved[k] for k in (a - 1, a, b - 1, b, c - 1, c % m)], 50 * span)
        if gain <= _GAIN_EPS:
            search.revert(saved)
    return search.order()


class _TourSearch:
    """A closed tour over poses 0..N-1 and the depot (node N) with its 2-opt and Or-opt moves.

    Every move returns what it saved (s), so a caller can add up the gain of a kick and its repair.
    The tour and each node's place in it are plain lists (the search reads them a few million times
    per plan, one element at a time); :meth:`mark` and :meth:`revert` undo a kick by rewriting only
    the places the moves since the mark changed.
    """

    def __init__(self, points_deg, order, metric: MoveMetric, depot_deg, neighbours=None):
        pts = np.asarray(points_deg, dtype=np.float64)
        n = pts.shape[0]
        if neighbours is None:
            neighbours = neighbour_lists(pts, metric)[0]
        self.depot = n
        allpts = np.concatenate([pts, np.asarray(depot_deg, dtype=np.float64).reshape(1, -1)])
        self.dist = _memoised(_scalar_metric(allpts, metric), n + 1)
        # The depot has no neighbour list of its own, but it is a neighbour of nobody either; tours
        # pass through it like any other node.
        self.neigh = neighbours.tolist() + [[]]
        self.m = n + 1
        self.tour = [self.depot] + [int(x) for x in order]
        self.pos = [0] * self.m
        for i, x in enumerate(self.tour):
            self.pos[x] = i
        self.changed = [0, self.m]  # the places changed since the last mark: [lo, hi)

    def order(self) -> np.ndarray:
        start = self.pos[self.depot]
        return np.array(self.tour[start + 1:] + self.tour[:start], dtype=np.int64)

    def mark(self) -> None:
        self.changed = [self.m, 0]

    def revert(self, tour: list) -> None:
        """Back to ``tour``, a copy of the tour taken at the last :meth:`mark`."""
        lo, hi = self.changed
        self.tour = tour
        pos = self.pos
        for k in range(lo, hi):
            pos[tour[k]] = k

    def _placed(self, lo: int, hi: int) -> None:
        """The tour changed at places [lo, hi) only: their positions set again, the range noted."""
        tour, pos = self.tour, self.pos
        for k in range(lo, hi):
            pos[tour[k]] = k
        self.changed = [min(self.changed[0], lo), max(self.changed[1], hi)]

    def succ(self, x: int) -> int:
        return self.tour[(self.pos[x] + 1) % self.m]

    def pred(self, x: int) -> int:
        return self.tour[self.pos[x] - 1]

    def descend(self, look_at, budget: int) -> float:
        """Take improving moves, searching from the poses ``look_at`` and every pose a taken move
        touches, until none improves or ``budget`` moves were taken; what they saved in all."""
        queue = deque(int(x) for x in look_at if x != self.depot)
        queued = [False] * self.m
        for x in queue:
            queued[x] = True
        moves, saved = 0, 0.0
        while queue and moves < budget:
            a = queue.popleft()
            queued[a] = False
            found = self.two_opt(a) or self.or_opt(a)
            if found is None:
                continue
            touched, gain = found
            moves += 1
            saved += gain
            for x in touched:
                if x != self.depot and not queued[x]:
                    queued[x] = True
                    queue.append(x)
        return saved

    def double_bridge(self, a: int, b: int, c: int) -> float:
        """Swap the stretches [a, b) and [b, c) of the tour array (0 < a < b < c <= N); the gain."""
        t, dist, m = self.tour, self.dist, self.m
        p, q, r = t[a - 1], t[b - 1], t[c - 1]
        x, y, z = t[a], t[b], t[c % m]
        gain = dist(p, x) + dist(q, y) + dist(r, z) - dist(p, y) - dist(r, x) - dist(q, z)
        t[a:c] = t[b:c] + t[a:b]
        self._placed(a, c)
        return gain

    def _reverse(self, x: int, y: int) -> None:
        """Reverse the stretch of the cycle from node x forward to node y (both included)."""
        m, tour, pos = self.m, self.tour, self.pos
        i, j = pos[x], pos[y]
        length = (j - i) % m + 1
        if 2 * length > m:  # reversing the complement gives the same cycle with less copying
            i, j = (j + 1) % m, (i - 1) % m
            length = m - length
        if i + length <= m:
            tour[i:i + length] = tour[i:i + length][::-1]
            self._placed(i, i + length)
            return
        idx = [(i + k) % m for k in range(length)]
        values = [tour[k] for k in reversed(idx)]
        for k, v in zip(idx, values, strict=True):
            tour[k] = v
            pos[v] = k
        self.changed = [0, m]

    def two_opt(self, a: int):
        dist, neigh, tour, pos, m = self.dist, self.neigh, self.tour, self.pos, self.m
        for forward in (True, False):
            b = tour[(pos[a] + 1) % m] if forward else tour[pos[a] - 1]
            d_ab = dist(a, b)
            for c in neigh[a]:
                g1 = d_ab - dist(a, c)
                if g1 <= _GAIN_EPS:
                    break  # neighbours are sorted: no later c can do better
                d = tour[(pos[c] + 1) % m] if forward else tour[pos[c] - 1]
                if c == b or d == a:
                    continue
                gain = g1 + dist(c, d) - dist(b, d)
                if gain > _GAIN_EPS:
                    if forward:
                        self._reverse(b, c)  # a b … c d …  ->  a c … b d …
                    else:
                        self._reverse(a, d)  # a … d c … b  ->  d … a c … b (joined b-d, a-c)
                    return [a, b, c, d], gain
        return None

    def or_opt(self, a: int):
        dist, neigh, depot, tour, pos, m = self.dist, self.neigh, self.depot, self.tour, self.pos, self.m
        for seg in (1, 2, 3):
            # The run a .. e of `seg` poses going forward; the depot never moves.
            run = [a]
            for _ in range(seg - 1):
                run.append(tour[(pos[run[-1]] + 1) % m])
            if depot in run:
                return None
            e = run[-1]
            p, q = tour[pos[a] - 1], tour[(pos[e] + 1) % m]
            if q == a or p == e:
                return None
            removed = dist(p, a) + dist(e, q) - dist(p, q)
            if removed <= _GAIN_EPS:
                continue
            for end in (a, e):
                for c in neigh[end]:
                    if c in run:
                        continue
                    if dist(end, c) >= removed:
                        break
                    for d in (tour[(pos[c] + 1) % m], tour[pos[c] - 1]):
                        if d in run:
                            continue
                        # Either way round the run fits between c and d; _move_run takes the better.
                        added = min(dist(c, a) + dist(e, d), dist(c, e) + dist(a, d)) - dist(c, d)
                        if removed - added > _GAIN_EPS:
                            self._move_run(run, c, d)
                            return [p, q, c, d, a, e], removed - added
        return None

    def _move_run(self, run, c, d):
        """Take the run out and put it between the adjacent nodes c and d, in the better direction."""
        dist, m, tour, pos = self.dist, self.m, self.tour, self.pos
        a, e = run[0], run[-1]
        first, size = pos[a], len(run)
        if first + size <= m:   # the run does not wrap round the end of the list: moved in place
            # Places in the tour without the run.
            ic, id_ = (pos[x] if pos[x] < first else pos[x] - size for x in (c, d))
            count = m - size
        else:
            keep = [x for x in tour if x not in run]
            ic, id_ = keep.index(c), keep.index(d)
            count = len(keep)
        # c and d are still adjacent in the tour without the run.
        left, right = (c, d) if (id_ - ic) % count == 1 else (d, c)
        seq = run if dist(left, a) + dist(e, right) <= dist(left, e) + dist(a, right) else run[::-1]
        cut = (ic if left == c else id_) + 1
        if first + size <= m:
            del tour[first:first + size]
            tour[cut:cut] = seq
            self._placed(min(first, cut), max(first, cut) + size)
        else:
            self.tour = keep[:cut] + seq + keep[cut:]
            self._placed(0, m)


def _memoised(dist, m: int):
    """``dist`` remembering each pair it was asked for: the search asks for the same few pairs (a pose
    and its neighbours) again and again, about 300 times each on a 1,156-pose tour."""
    known: dict[int, float] = {}

    def cached(i, j):
        key = i * m + j
        d = known.get(key)
        if d is None:
            d = known[key] = dist(i, j)
        return d
    return cached


def _scalar_metric(points: np.ndarray, metric: MoveMetric):
    """A plain-Python d(i, j) in s between rows of ``points``: far faster than numpy for one pair."""
    if metric.uniform:
        coords = [tuple(r) for r in (points * metric.scale).tolist()]
        ratio = metric.time_from_key(1.0) / 2.0  # v/a, from τ(1) = 2

        def dist(i, j):
            u = max(abs(x - y) for x, y in zip(coords[i], coords[j], strict=True))
            return ratio * (2.0 * math.sqrt(u) if u < 1.0 else u + 1.0)
        return dist
    coords = [tuple(r) for r in points.tolist()]
    axes = list(zip(metric.velocity_deg_s.tolist(), metric.accel_deg_s2.tolist(), strict=True))

    def dist(i, j):
        worst = 0.0
        for x, y, (v, acc) in zip(coords[i], coords[j], axes, strict=True):
            d = abs(x - y)
            t = 2.0 * math.sqrt(d / acc) if d < v * v / acc else d / v + v / acc
            worst = max(worst, t)
        return worst
    return dist


def _loops(loops) -> np.ndarray:
    arr = np.asarray(loops, dtype=np.int64)
    if arr.ndim != 2:
        raise ValueError(f"loops: expected integer loop indices of shape (P, L), got shape {arr.shape}")
    return arr
