"""Nearest neighbours of axis positions in a Chebyshev distance (the :class:`gonio.motion.metric.MoveMetric`
key, in its scaled coordinates): every pair compared in numpy for small sets, a k-d tree for large ones.

The two give the same distances, bit for bit (both are the largest absolute coordinate difference), and
the same neighbours in the same order wherever no two of a query's k nearest lie at exactly the same
distance (nor the k-th at the distance of the next). Among equal distances a k-d tree's order is its
own (how its nodes split), which plans depend on (a tour search tries neighbours in order); so where the
brute force meets such a tie it asks the tree after all (unless the caller reads the distances alone,
``ties_ok``), and a plan is the same, bit for bit, whichever way its neighbours were found. A tree of
at most :data:`LEAF_SIZE` points is one leaf, whose order is plain to follow: its points in index
order, each nearer than the k-th so far pushed into a binary heap of k (:func:`_leaf_order`, checked
against scipy's on random sets full of ties in tests/motion/test_motion_nearest.py). So plans of a
few poses (a small ``gonio simulate``) and tie-free ones up to :data:`BRUTE_MAX_PAIRS` need no k-d
tree, and never import scipy.spatial (a third of a second of start-up).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["chebyshev_neighbours", "BRUTE_MAX_PAIRS", "LEAF_SIZE", "KD_THREADS_MIN_POINTS", "kd_workers"]

#: Query × data pairs up to which the neighbours are found by comparing every pair (numpy), above
#: which by a k-d tree: at this size both take about as long (a few ms), without counting the import.
BRUTE_MAX_PAIRS = 1 << 20
#: Points in one leaf of scipy's ``cKDTree`` (its default ``leafsize``): a tree of no more is one leaf.
LEAF_SIZE = 16
#: Query points from which a k-d tree search uses every core: below it the calling thread searches
#: alone, since starting the pool costs about a millisecond, more than a search of a few thousand points.
KD_THREADS_MIN_POINTS = 20_000
# Distance entries per block of the brute force: a few MB of temporaries.
_BLOCK_ENTRIES = 1 << 18


def kd_workers(points: int) -> int:
    """``workers`` for a ``cKDTree.query`` of this many points (:data:`KD_THREADS_MIN_POINTS`); the
    answer is the same either way."""
    return -1 if points >= KD_THREADS_MIN_POINTS else 1


def chebyshev_neighbours(data, queries, k: int, ties_ok: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` rows of ``data`` nearest to each row of ``queries`` in the Chebyshev distance
    (max over columns of the absolute difference), nearest first: what
    ``cKDTree(data).query(queries, k=k, p=np.inf)`` returns for k >= 1, always two-dimensional.

    Parameters
    ----------
    data : ndarray, shape (N, D)
    queries : ndarray, shape (M, D)
    k : int
        1 <= k <= N.
    ties_ok : bool
        The caller reads only the distances (and which neighbour is which query's own point), which no
        tie changes: the brute force answers even where a tie makes its order differ from the tree's
        (lower indices first among equal distances).

    Returns
    -------
    dist : ndarray, shape (M, k)
    idx : ndarray of int64, shape (M, k)
    """
    data = np.asarray(data, dtype=np.float64)
    queries = np.asarray(queries, dtype=np.float64)
    n, m, k = data.shape[0], queries.shape[0], int(k)
    if not 1 <= k <= n:
        raise ValueError(f"k: {k} neighbours asked of {n} points; give 1 <= k <= {n}")
    found = _brute(data, queries, k, ties_ok) if n * m <= BRUTE_MAX_PAIRS else None
    if found is None and n <= LEAF_SIZE:
        found = _leaf_order(_distances(data, queries), k)
    if found is not None:
        return found
    from scipy.spatial import cKDTree

    dist, idx = cKDTree(data).query(queries, k=k, p=np.inf, workers=kd_workers(m))
    return dist.reshape(m, k), idx.reshape(m, k).astype(np.int64, copy=False)


def _brute(data, queries, k, ties_ok):
    """:func:`chebyshev_neighbours` by comparing every pair; None where a tie leaves the order to the
    k-d tree (see the module's docstring)."""
    n, m = data.shape[0], queries.shape[0]
    dist = np.empty((m, k))
    idx = np.empty((m, k), dtype=np.int64)
    rows = max(1, _BLOCK_ENTRIES // max(n, 1))
    for lo in range(0, m, rows):
        d = _distances(data, queries[lo:lo + rows])
        if k < n:
            # The k least: those below the k-th, and the k-th itself when nothing else lies as far.
            kth = np.partition(d, k - 1, axis=1)[:, k - 1:k]
            less = d < kth
            tied = d == kth
            if not ties_ok and np.any(np.count_nonzero(tied, axis=1) > 1):
                return None   # the k-th is tied (with a nearer one or one left out)
            # Of the points as far as the k-th, the lowest indices (nonzero lists each row by index).
            room = k - np.count_nonzero(less, axis=1, keepdims=True)
            pick = np.nonzero(less | (tied & (np.cumsum(tied, axis=1) <= room)))[1].reshape(d.shape[0], k)
        else:
            pick = np.broadcast_to(np.arange(n), d.shape)
        near = np.take_along_axis(d, pick, axis=1)
        order = np.argsort(near, axis=1, kind="stable")
        near = np.take_along_axis(near, order, axis=1)
        if not ties_ok and np.any(near[:, 1:] == near[:, :-1]):
            return None
        dist[lo:lo + rows] = near
        idx[lo:lo + rows] = np.take_along_axis(pick, order, axis=1)
    return dist, idx


def _distances(data: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Chebyshev distances (M, N) from each query to each data row."""
    d = np.abs(queries[:, :1] - data[:, 0])
    for axis in range(1, data.shape[1]):
        np.maximum(d, np.abs(queries[:, axis:axis + 1] - data[:, axis]), out=d)
    return d


def _leaf_order(d: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The k nearest of each row of distances ``d`` (M, N) in the order a k-d tree that is a single
    leaf returns them: the points in index order, each nearer than the k-th so far (all of them until
    there are k) pushed into a binary heap of the k nearest (the farthest on top, sifted as scipy's
    ``cKDTree`` sifts it), then popped farthest first into the answer from its end."""
    dist = np.empty((d.shape[0], k))
    idx = np.empty((d.shape[0], k), dtype=np.int64)
    for r, row in enumerate(d.tolist()):
        heap: list[tuple[float, int]] = []   # (-distance, index): the top is the farthest
        bound = math.inf
        for j, dj in enumerate(row):
            if dj < bound:
                if len(heap) == k:
                    _heap_remove(heap)
                _heap_push(heap, (-dj, j))
                if len(heap) == k:
                    bound = -heap[0][0]
        for c in range(k - 1, -1, -1):
            dist[r, c], idx[r, c] = -heap[0][0], heap[0][1]
            _heap_remove(heap)
    return dist, idx


def _heap_push(heap: list, item) -> None:
    heap.append(item)
    i = len(heap) - 1
    while i > 0 and heap[i][0] < heap[(i - 1) // 2][0]:
        heap[(i - 1) // 2], heap[i] = heap[i], heap[(i - 1) // 2]
        i = (i - 1) // 2


def _heap_remove(heap: list) -> None:
    """Drop the top: the last item moves to the top and sinks past any child of lower priority (the
    lower of two, the left one on a tie)."""
    last = heap.pop()
    if not heap:
        return
    heap[0] = last
    n, i = len(heap), 0
    while True:
        j, r = 2 * i + 1, 2 * i + 2
        if not ((j < n and heap[i][0] > heap[j][0]) or (r < n and heap[i][0] > heap[r][0])):
            return
        c = r if r < n and heap[j][0] > heap[r][0] else j
        heap[c], heap[i] = heap[i], heap[c]
        i = c
