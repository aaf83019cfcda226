"""Lower bounds on the motion time of a campaign that visits every pose once.

Two bounds, both true lower bounds for any order of the given axis positions:

- **MST**: a path through all poses is a spanning tree, so it costs at least the minimum spanning tree
  (MST) of the complete graph under the move-time metric. Computed exactly with Prim's algorithm on
  vectorized distance rows (O(N²) work, O(N) memory); affordable to a few tens of thousands of poses.
- **Degree** (nearest neighbours): in a path every pose has two incident moves (the ends of each run
  meet the reference pose), each at least as long as the pose's first and second nearest neighbour,
  so the path costs at least half the sum over poses of those two. Found with a k-d tree, exactly
  when the metric is a weighted Chebyshev norm, else as a lower bound; O(N log N), for any N.

Campaign structure: the runner leaves the poses for the white reference every few poses, so the walk
is ``ref → run 1 → ref → run 2 → … → ref``. With R runs the pose-to-pose moves form a forest of R
trees (≥ the MST minus its R − 1 longest edges) and there are 2R moves between a pose and the
reference (each ≥ the shortest such move). Both bounds account for that; see
:func:`motion_lower_bound`.

Branches: the positions are fixed inverse-kinematics branches (the ones the plan chose); the bound
is for those positions, the same ones the estimate uses, so the two compare like with like.
"""

from __future__ import annotations

import numpy as np

from gonio.motion.metric import MoveMetric
from gonio.motion.nearest import chebyshev_neighbours

__all__ = ["mst_edge_times", "neighbour_times", "motion_lower_bound", "MST_MAX_POSES"]

#: Above this many poses the exact MST (O(N²)) is skipped and only the degree bound is used.
MST_MAX_POSES = 25_000


def mst_edge_times(points_deg, metric: MoveMetric) -> np.ndarray:
    """Move times in s of the edges of an exact minimum spanning tree (Prim's algorithm).

    Parameters
    ----------
    points_deg : array_like, shape (N, n_axes)
        Axis positions in degrees (finite).
    metric : MoveMetric
        The move-time metric.

    Returns
    -------
    ndarray, shape (max(N - 1, 0),)
        Edge times in s, in the order Prim added them; their sum is the MST weight.

    Examples
    --------
    >>> m = MoveMetric([60.0], [120.0])
    >>> mst_edge_times([[0.0], [30.0], [90.0]], m).tolist()     # two cruise moves: 30° and 60°
    [1.0, 1.5]
    """
    pts = _points(points_deg, metric.n_axes)
    n = pts.shape[0]
    if n <= 1:
        return np.empty(0)
    # Columns are poses so that each row update is one contiguous pass per axis.
    coords = np.ascontiguousarray((pts * metric.scale).T if metric.uniform else pts.T)
    scale = np.ones(metric.n_axes) if metric.uniform else None
    best = np.full(n, np.inf)
    buf = np.empty_like(coords)
    row = np.empty(n)
    keys = np.empty(n - 1)
    # Remove the tree's nodes by swapping them to the end: the live part stays contiguous.
    u = coords[:, 0].copy()
    coords[:, 0] = coords[:, n - 1]
    m = n - 1
    for step in range(n - 1):
        live = coords[:, :m]
        if scale is not None:
            np.subtract(live, u[:, None], out=buf[:, :m])
            np.abs(buf[:, :m], out=buf[:, :m])
            np.max(buf[:, :m], axis=0, out=row[:m])
        else:
            row[:m] = metric.key(u[None, :], live.T)
        np.minimum(best[:m], row[:m], out=best[:m])
        j = int(np.argmin(best[:m]))
        keys[step] = best[j]
        u = live[:, j].copy()
        m -= 1
        coords[:, j] = coords[:, m]
        best[j] = best[m]
    return metric.time_from_key(keys)


def neighbour_times(points_deg, metric: MoveMetric, k: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Lower bounds in s on each pose's nearest and second-nearest move to another pose.

    Parameters
    ----------
    points_deg : array_like, shape (N, n_axes)
        Axis positions in degrees (finite), N >= 3.
    metric : MoveMetric
        The move-time metric.
    k : int, optional
        Candidates per pose from the k-d tree (default 2 for a Chebyshev metric, where they are exact,
        else 8, and 8k again where those did not settle the second neighbour). Poses outside a pose's
        candidate ball are bounded by the ball's radius.

    Returns
    -------
    nn1, nn2 : ndarray, shape (N,)
        Lower bounds on the shortest and second-shortest move from each pose to another pose, in s
        (exact when ``metric.uniform``).
    """
    pts = _points(points_deg, metric.n_axes)
    n = pts.shape[0]
    if n < 3:
        raise ValueError(f"points_deg: need at least 3 poses for two neighbours each, got {n}")
    k = (2 if metric.uniform else 8) if k is None else int(k)
    nn1, nn2, beyond = _neighbours(pts, np.arange(n), metric, min(k, n - 1))
    if not metric.uniform:
        # Where the ball was too small to settle the second neighbour, look again with a larger one.
        loose = np.flatnonzero(beyond < nn2)
        if loose.size:
            nn1[loose], nn2[loose], beyond[loose] = _neighbours(pts, loose, metric, min(8 * k, n - 1))
    return np.minimum(nn1, beyond), np.minimum(nn2, beyond)


def _neighbours(pts, which, metric, k):
    """Nearest and second-nearest candidate times of poses ``which`` among their k nearest in the
    scaled Chebyshev distance, and the bound on every pose outside that ball."""
    # k + 1 because each pose finds itself.
    dist, idx = chebyshev_neighbours(pts * metric.scale, pts[which] * metric.scale, k + 1, ties_ok=True)
    own = idx == which[:, None]
    # A pose sharing its position with another may not be returned first; drop itself wherever it is,
    # and when it is missing (k + 1 ties at distance 0) drop the last column instead.
    missing = ~own.any(axis=1)
    own[missing, -1] = True
    times = metric.time(pts[which][:, None, :], pts[idx])
    times[own] = np.inf
    times.sort(axis=1)
    return times[:, 0], times[:, 1], metric.time_beyond(dist[:, -1])


def motion_lower_bound(points_deg, reference_deg, run_lengths, metric: MoveMetric,
                       mst_max_poses: int = MST_MAX_POSES) -> dict[str, float]:
    """Lower bound in s on the pose-related motion of ``ref → run → ref → … → run → ref``.

    Parameters
    ----------
    points_deg : array_like, shape (N, n_axes)
        Axis positions of the measurement poses, degrees.
    reference_deg : array_like, shape (n_axes,)
        Axis positions of the reference pose, degrees.
    run_lengths : array_like of int, shape (R,)
        Poses in each run between reference visits (each >= 1, summing to N); the order of the poses
        is free, the schedule's run lengths are not.
    metric : MoveMetric
        The move-time metric.
    mst_max_poses : int
        The exact MST is computed up to this many poses; above it only the degree bound is used.

    Returns
    -------
    dict
        ``"motion_s"``: the bound on every move that starts or ends at a pose (the best of the bounds
        computed); ``"mst_s"``: the MST weight (NaN when skipped); ``"forest_s"``, ``"degree_s"``: the
        two bounds with the reference moves included (forest NaN when skipped); ``"reference_min_s"``:
        the shortest move between the reference and a pose; ``reference_s``: the bound on the 2R moves
        between the reference and the runs.
    """
    pts = _points(points_deg, metric.n_axes)
    n = pts.shape[0]
    lengths = np.asarray(run_lengths, dtype=np.int64).reshape(-1)
    if lengths.size == 0 or np.any(lengths < 1) or lengths.sum() != n:
        raise ValueError(f"run_lengths: need R >= 1 runs of >= 1 pose each summing to the {n} poses, got "
                         f"{lengths.size} runs summing to {int(lengths.sum())}")
    runs = lengths.size
    ref = np.asarray(reference_deg, dtype=np.float64).reshape(1, -1)
    to_ref = metric.time(pts, ref)
    r_min = float(np.min(to_ref))
    # Each run enters from and leaves to the reference: 2R moves. A run of two or more poses does so
    # through two different poses, so the moves touch at least 2R - (runs of one pose) distinct poses,
    # each at least its own distance to the reference away; the other moves are at least r_min.
    singles = int(np.count_nonzero(lengths == 1))
    distinct = min(2 * runs - singles, n)
    ref_moves = float(np.sum(np.partition(to_ref, distinct - 1)[:distinct])) + (2 * runs - distinct) * r_min
    mst = forest = degree = np.nan
    if 1 <= n <= mst_max_poses:
        edges = np.sort(mst_edge_times(pts, metric))
        mst = float(edges.sum())
        # The pose-to-pose moves form R paths: a spanning forest of R trees, which weighs at least
        # the MST without its R - 1 longest edges.
        forest = float(edges[: max(len(edges) - (runs - 1), 0)].sum()) + ref_moves
    if n >= 3:
        nn1, nn2 = neighbour_times(pts, metric)
        # The reference is a possible neighbour on both sides of a pose (a run of one pose).
        four = np.sort(np.stack([nn1, nn2, to_ref, to_ref], axis=1), axis=1)
        degree = 0.5 * float(np.sum(four[:, 0] + four[:, 1])) + 0.5 * ref_moves
    elif n:
        degree = ref_moves
    best = np.nanmax([forest, degree])
    return {"motion_s": float(best), "mst_s": float(mst), "forest_s": float(forest),
            "degree_s": float(degree), "reference_min_s": r_min, "reference_s": ref_moves}


def _points(points_deg, n_axes: int) -> np.ndarray:
    pts = np.asarray(points_deg, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != n_axes:
        raise ValueError(f"points_deg: expected shape (N, {n_axes}), got {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise ValueError("points_deg: positions must be finite degrees (no NaN branch)")
    return pts
