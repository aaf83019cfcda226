"""A lower bound on a campaign's duration that holds for every order *and* every branch choice.

:mod:`gonio.motion.bound` bounds the moves of any order of fixed axis positions (the branches the plan
picked). A campaign may put each pose on any of its inverse-kinematics branches, so that figure is no
bound on what the gantry could do. Here each pose is the set of its branches, and:

- the time between two poses is the least over pairs of their branches (``pair time``). A walk through
  the poses, whatever branches it uses, pays at least the pair time on every move, so the walk is a
  spanning structure of the graph of pair times: its pose-to-pose moves weigh at least the minimum
  spanning forest with as many trees as the walk has runs (Prim on pair times, exact, for small plans),
  and at least half the sum over poses of their two cheapest incident moves (the *degree* bound, from
  a k-d tree over every branch of every pose, for any size);
- up to :data:`LAGRANGE_MAX_POSES` poses, the Held–Karp Lagrangian bound on top: with a penalty
  ``pi_i`` per pose added to every move touching it, each pose's moves in a walk (references included)
  number exactly two, so the walk's cost is unchanged less ``2 sum(pi)``, while the least spanning
  forest plus the least reference moves under the penalised times stays a relaxation. Any penalties
  give a bound; up to :data:`LAGRANGE_STEPS` subgradient steps (penalties raised where the relaxation
  uses a pose more than twice, lowered where less) look for high ones. The relaxation then has to
  use every pose about twice, as a walk does: on the sample stage's ``iso:step=15`` the moves bound
  rises from 207.1 s (degree) to 208.9 s, against a tour of 211.8 s on the same pair times;
- a move between a pose and a reference costs at least the least pair time between the pose's branches
  and every allowed reference position's branches; a run enters and leaves through at most two
  poses, so the 2R such moves cost at least twice the R smallest of those;
- a pose whose azimuth is free (an arm at the pole) can stand anywhere along that axis, so it has no
  finite set of branches: it is left out of the moves. That is still a bound: the moves skipping it
  are a walk in axis space no longer than the one through it (move time is a metric on axis
  positions), and a run made only of such poses disappears (R' runs of the others, R' <= R).

Fixed costs (settle after each move, each reading) are counted exactly; references and darks at the
least the schedule allows: R runs need R + 1 checkpoints, R >= ceil(P / every), and with a time limit
``every_s`` between reference readings, the inner part of the campaign (first reference reading to
last) needs R intervals of at most ``every_s`` each, so R may only take values where the bound on that
inner part fits in ``R * every_s``. The result is the least over the allowed R.
"""

from __future__ import annotations

import numpy as np

from gonio.motion.metric import MoveMetric
from gonio.motion.nearest import chebyshev_neighbours

__all__ = ["pose_branches", "pair_times", "pair_time_matrix", "branch_mst_edge_times",
           "branch_neighbour_times", "lagrangian_penalties", "lagrangian_motion", "relaxed_campaign_bound",
           "BRANCH_MST_MAX_PAIRS", "LAGRANGE_MAX_POSES", "LAGRANGE_STEPS"]

#: Largest N² W² (poses squared times branches squared) for which the exact MST of pair times is run.
BRANCH_MST_MAX_PAIRS = 3e8
#: Largest number of (non-free) poses whose bound adds the Held–Karp Lagrangian (a dense N × N table
#: of pair times, and a dense Prim per step: about 10 ms a step at 1,200 poses).
LAGRANGE_MAX_POSES = 2_000
#: Subgradient steps of the Lagrangian (any number gives a bound; more, a higher one: the sample
#: stage's iso:step=15 campaign bound is 304.1 s with none, 306.1 s after 50, 306.3 s after 100).
LAGRANGE_STEPS = 100
#: The ascent stops after this many steps without a rise.
LAGRANGE_PATIENCE = 25
# Largest N for which Prim runs on Python lists (numpy's per-call cost loses below about 40).
_PRIM_LISTS_MAX = 32
# Pair-time entries (N × chunk × W² × axes) computed at once when building the table.
_CHUNK_ENTRIES = 2e5
# Keys of one branch pair computed at once (a block of rows of the table, in cache).
_KEY_BLOCK_ENTRIES = 2e4
# Poses from which the Lagrangian's Prim makes its penalised rows one at a time (:func:`_prim`).
_PENALISED_ROWS_MIN = 600

# Poses left out (free or thinned) beyond which R' ranges over every value up to R.
_MAX_DROPS = 256


def pose_branches(branches_deg) -> np.ndarray:
    """Branches (N, W, n_axes) with every invalid (NaN) branch replaced by a valid one of the same pose.

    Duplicates change no minimum, and they keep every array finite for the vectorized distances.
    Poses with no valid branch raise ``ValueError``.
    """
    b = np.array(branches_deg, dtype=np.float64)
    valid = ~np.isnan(b).any(axis=-1)
    if b.shape[0] and not valid.any(axis=1).all():
        raise ValueError(f"branches_deg: pose {int(np.argmin(valid.any(axis=1)))} has no valid branch")
    # Valid branches first, and only as many columns as the pose with the most of them needs.
    by_valid = np.argsort(~valid, axis=1, kind="stable")
    width = max(int(valid.sum(axis=1).max(initial=1)), 1)
    b = np.take_along_axis(b, by_valid[:, :width, None], axis=1)
    valid = np.take_along_axis(valid, by_valid[:, :width], axis=1)
    return np.where(valid[..., None], b, b[:, :1, :])


def pair_times(a_deg, b_deg, metric: MoveMetric) -> np.ndarray:
    """Least move time (M, K) in s between any branch of each pose in ``a_deg`` (M, W, n) and any
    branch of each pose in ``b_deg`` (K, V, n) (finite branches; see :func:`pose_branches`)."""
    a = np.asarray(a_deg, dtype=np.float64)
    b = np.asarray(b_deg, dtype=np.float64)
    t = metric.time(a[:, None, :, None, :], b[None, :, None, :, :])
    return t.min(axis=(2, 3))


def pair_time_matrix(branches, metric: MoveMetric) -> np.ndarray:
    """Pair times (N, N) in s between every two poses (:func:`pair_times`), infinite on the diagonal;
    computed a block of rows at a time (small enough to stay in cache) so that memory stays near
    ``N²``."""
    b = np.asarray(branches, dtype=np.float64)
    n, w, n_axes = b.shape
    out = np.empty((n, n))
    if metric.uniform:
        # The least key over branch pairs (weighted Chebyshev, one axis at a time), then its time. A
        # pose's repeated branches (pose_branches fills its invalid ones with a copy) change no least
        # key: the poses are grouped by how many distinct branches they have, and each block of two
        # groups measures only those (the two-arm gantry's merl:stride=8 poses have 2.2 of 5 on average,
        # a fifth of the pairs; the sample stage's 6.1 of 9). The same keys to the last bit.
        scaled = b * metric.scale
        distinct, count = _distinct_first(scaled)
        groups = [np.flatnonzero(count == c) for c in np.unique(count)]
        for gi, rows_g in enumerate(groups):
            a = np.ascontiguousarray(np.moveaxis(distinct[rows_g, :count[rows_g[0]]], 2, 0))
            for cols_g in groups[gi:]:
                c = np.ascontiguousarray(np.moveaxis(distinct[cols_g, :count[cols_g[0]]], 2, 0))
                block = _key_block(a, c, cols_g is rows_g)
                out[np.ix_(rows_g, cols_g)] = block
                if cols_g is not rows_g:
                    out[np.ix_(cols_g, rows_g)] = block.T
        out = metric.time_from_key(out)
    else:
        rows = max(1, int(_CHUNK_ENTRIES // max(n * w * w, 1)))
        for lo in range(0, n, rows):
            out[lo:lo + rows] = pair_times(b[lo:lo + rows], b, metric)
    np.fill_diagonal(out, np.inf)
    return out


def _distinct_first(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each pose's branches (N, W, n) with its distinct ones first (in their order), and their count (N,)."""
    same = (points[:, :, None, :] == points[:, None, :, :]).all(axis=-1)        # (N, W, W)
    repeat = np.tril(same, -1).any(axis=2)     # branch b equals an earlier branch of its pose
    first = np.argsort(repeat, axis=1, kind="stable")
    return np.take_along_axis(points, first[..., None], axis=1), points.shape[1] - repeat.sum(axis=1)


def _key_block(a: np.ndarray, c: np.ndarray, triangle: bool) -> np.ndarray:
    """Least weighted-Chebyshev key (M, K) between any branch of the poses ``a`` (n_axes, M, V) and any
    of ``c`` (n_axes, K, U); ``triangle`` (a and c the same poses): the upper triangle, mirrored below
    (keys are symmetric). One branch pair at a time over a block of rows, so that every operation runs
    along a contiguous row of poses (broadcasting the branch axes instead ran numpy's inner loops over
    U <= 9 elements)."""
    n_axes, m, v = a.shape
    k_, u = c.shape[1], c.shape[2]
    c = np.ascontiguousarray(np.moveaxis(c, 2, 1))      # (n_axes, U, K)
    out = np.full((m, k_), np.inf)
    rows = max(1, int(_KEY_BLOCK_ENTRIES // max(k_, 1)))
    d, t = np.empty(rows * k_), np.empty(rows * k_)
    for lo in range(0, m, rows):
        hi, first = min(lo + rows, m), (lo if triangle else 0)
        block = out[lo:hi, first:]
        dd, tt = d[:block.size].reshape(block.shape), t[:block.size].reshape(block.shape)
        for i in range(v):
            for j in range(u):
                np.subtract(a[0, lo:hi, i, None], c[0, j, first:], out=dd)
                np.abs(dd, out=dd)
                for k in range(1, n_axes):
                    np.subtract(a[k, lo:hi, i, None], c[k, j, first:], out=tt)
                    np.abs(tt, out=tt)
                    np.maximum(dd, tt, out=dd)
                np.minimum(block, dd, out=block)
    if triangle:
        below = np.tril_indices(m, -1)
        out[below] = out.T[below]
    return out


def _prim(weights: np.ndarray, pi: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A minimum spanning tree of the complete graph with these (N, N) weights (diagonal ignored):
    (child, parent) index arrays of its N - 1 edges.

    With penalties ``pi`` (N,): the tree of ``weights[i, j] + pi[i] + pi[j]`` (added in that order, so
    the same weights to the last digit), each row made as the tree takes its pose instead of the whole
    table first: Prim reads every row once, and a table of a thousand poses or more is otherwise
    written and read back from memory (about 15 % of a Lagrangian step at 1,748 poses; below
    :data:`_PENALISED_ROWS_MIN` poses the table stays in cache and the whole-table sums are quicker)."""
    n = weights.shape[0]
    if n <= _PRIM_LISTS_MAX and pi is None:
        return _prim_lists(weights)
    row = np.empty(n)
    best = weights[0].copy() if pi is None else np.add(weights[0], pi[0]) + pi
    parent = np.zeros(n, dtype=np.int64)
    best[0] = np.inf
    child = np.empty(n - 1, dtype=np.int64)
    closer = np.empty(n, dtype=bool)
    if pi is None:
        left = np.ones(n, dtype=bool)   # not in the tree yet
        left[0] = False
    else:
        # The penalties with +inf at the poses in the tree: their penalised entries are then +inf,
        # never closer than their best (+inf), so no mask of the poses left is needed; the others
        # are the same sums as without it.
        outside = pi.copy()
        outside[0] = np.inf
    for step in range(n - 1):
        j = int(best.argmin())
        child[step] = j
        best[j] = np.inf
        if pi is None:
            left[j] = False
            row = weights[j]
            np.less(row, best, out=closer)
            closer &= left
            np.copyto(best, row, where=closer)
        else:
            outside[j] = np.inf
            np.add(weights[j], pi[j], out=row)
            row += outside
            np.less(row, best, out=closer)
            np.minimum(best, row, out=best)   # row where closer; the poses in the tree stay +inf
        np.copyto(parent, j, where=closer)
    return child, parent[child]


def _prim_lists(weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_prim` in plain Python lists, the same steps (first least entry, strictly closer only):
    the same tree, quicker where N is small and numpy's per-call cost is most of the work (the
    Lagrangian runs up to a hundred Prims per bound, and tours of a few poses are planned by the
    thousand: adaptive rounds, the option matrix of the tests)."""
    n = weights.shape[0]
    rows = weights.tolist()
    best = list(rows[0])
    best[0] = np.inf
    parent = [0] * n
    done = [False] * n
    done[0] = True
    child = []
    order = range(n)
    for _ in range(n - 1):
        j = min(order, key=best.__getitem__)
        child.append(j)
        done[j] = True
        best[j] = np.inf
        for i, w in enumerate(rows[j]):
            if w < best[i] and not done[i]:
                best[i] = w
                parent[i] = j
    return np.array(child, dtype=np.int64), np.array([parent[c] for c in child], dtype=np.int64)


def _relaxation(pair, to_ref, pi, runs: int, scratch=None):
    """The Lagrangian relaxation at penalties ``pi`` for ``runs`` runs: its value, each pose's degree
    in it, and the parts :func:`lagrangian_motion` needs for other run counts. ``scratch``: an array
    like ``pair`` to hold the penalised times (a new one each step costs as much as a Prim)."""
    n = pair.shape[0]
    if n >= _PENALISED_ROWS_MIN:
        child, parent = _prim(pair, pi)
    else:
        weights = np.add(pair, pi[:, None], out=scratch)
        child, parent = _prim(np.add(weights, pi[None, :], out=weights))
    w = pair[child, parent] + pi[child] + pi[parent]
    order = np.argsort(w, kind="stable")
    kept = order[:n - runs]
    degree = (np.bincount(child[kept], minlength=n) + np.bincount(parent[kept], minlength=n)).astype(float)
    enter = to_ref + pi
    ends = np.argsort(enter, kind="stable")[:runs]
    degree[ends] += 2.0
    value = float(w[kept].sum() + 2.0 * enter[ends].sum() - 2.0 * pi.sum())
    return value, degree, np.sort(w), np.sort(enter)


def lagrangian_penalties(pair, to_ref, runs: int, steps: int = LAGRANGE_STEPS) -> np.ndarray:
    """Per-pose penalties (N,) in s for which :func:`lagrangian_motion` is high at ``runs`` runs.

    Subgradient ascent from zero: each step moves the penalties along (degree - 2) of the relaxation's
    forest plus reference moves (blended with the step before, 0.7 / 0.3), at a step length of 1 % of
    the first value per pose, kept for the first quarter of the steps and then shrunk by 2 % a step;
    it stops early after :data:`LAGRANGE_PATIENCE` steps without a rise. Deterministic; the penalties
    returned are those of the highest value met.

    Parameters
    ----------
    pair : ndarray, shape (N, N)
        Pair times (:func:`pair_time_matrix`), s.
    to_ref : ndarray, shape (N,)
        Least time from each pose to a reference position, s.
    runs : int
        Runs (paths between reference readings), 1 <= runs <= N.
    steps : int
    """
    n = pair.shape[0]
    runs = int(np.clip(runs, 1, n))
    pi = np.zeros(n)
    best_value, best_pi = -np.inf, pi.copy()
    previous = np.zeros(n)
    length = None
    since = 0   # steps since the value last rose by more than a part in 10⁹
    scratch = np.empty_like(pair) if n < _PENALISED_ROWS_MIN else None
    for k in range(int(steps)):
        value, degree, _, _ = _relaxation(pair, to_ref, pi, runs, scratch)
        since = 0 if value > best_value + 1e-9 * abs(best_value if np.isfinite(best_value) else value) \
            else since + 1
        if value > best_value:
            best_value, best_pi = value, pi.copy()
        if since >= LAGRANGE_PATIENCE:   # no ascent (the two-arm gantry: zero penalties are best)
            break
        g = degree - 2.0
        if not g.any():  # the relaxation is a walk: nothing higher exists
            break
        if length is None:
            length = 0.01 * abs(value) / n if value else 0.01
        pi = pi + length * (0.7 * g + 0.3 * previous)
        previous = g
        if k >= steps // 4:
            length *= 0.98
    return best_pi


def lagrangian_motion(pair, to_ref, pi, runs) -> np.ndarray:
    """The Lagrangian bound (R,) in s on the pose-to-pose and pose-to-reference moves of a campaign of
    R' = ``runs`` runs, at penalties ``pi`` (any penalties give a bound).

    For R' runs the walk's pose-to-pose moves form R' paths, a spanning forest of R' trees, and its
    2R' reference moves end them, at most two at any pose; every pose is met exactly twice. So, with
    every move touching pose i dearer by ``pi[i]``, the walk costs its true time plus ``2 sum(pi)``,
    and at least the least R'-tree forest (the minimum spanning tree without its R' - 1 dearest
    edges) plus twice the R' cheapest penalised reference moves.
    """
    rp = np.clip(np.asarray(runs, dtype=np.int64), 1, pair.shape[0])
    _, _, edges, enter = _relaxation(pair, to_ref, np.asarray(pi, dtype=np.float64), 1)
    forest = np.concatenate([[0.0], np.cumsum(edges)])  # forest(R') = forest[N - R']
    ends = np.concatenate([[0.0], np.cumsum(enter)])
    return forest[pair.shape[0] - rp] + 2.0 * ends[rp] - 2.0 * float(np.sum(pi))


def branch_mst_edge_times(branches, metric: MoveMetric) -> np.ndarray:
    """Edge times (N - 1,) in s of an exact minimum spanning tree of the poses under pair times.

    Prim's algorithm over poses; each step measures the new tree pose's W branches against every
    branch of every pose left (O(N² W² n) in all).

    Parameters
    ----------
    branches : ndarray, shape (N, W, n_axes)
        Finite branch positions in degrees (:func:`pose_branches`).
    metric : MoveMetric

    Returns
    -------
    ndarray, shape (max(N - 1, 0),)
        Edge times in s in the order Prim added them.
    """
    pts = np.asarray(branches, dtype=np.float64)
    n = pts.shape[0]
    if n <= 1:
        return np.empty(0)
    if metric.uniform:
        live = np.ascontiguousarray(np.moveaxis(pts * metric.scale, 2, 0))  # (n_axes, N, W)
    else:
        live = pts.copy()
    best = np.full(n, np.inf)
    keys = np.empty(n - 1)
    u = live[:, 0].copy() if metric.uniform else live[0].copy()
    if metric.uniform:
        live[:, 0] = live[:, n - 1]
    else:
        live[0] = live[n - 1]
    m = n - 1
    for step in range(n - 1):
        if metric.uniform:
            # row[j] = min over (b, c) of max over axes |u[k, b] - live[k, j, c]|
            d = np.abs(live[0, :m, None, :] - u[0][None, :, None])
            for k in range(1, live.shape[0]):
                np.maximum(d, np.abs(live[k, :m, None, :] - u[k][None, :, None]), out=d)
            row = d.min(axis=(1, 2))
        else:
            row = metric.time(u[None, :, None, :], live[:m, None, :, :]).min(axis=(1, 2))
        np.minimum(best[:m], row, out=best[:m])
        j = int(np.argmin(best[:m]))
        keys[step] = best[j]
        m -= 1
        if metric.uniform:
            u = live[:, j].copy()
            live[:, j] = live[:, m]
        else:
            u = live[j].copy()
            live[j] = live[m]
        best[j] = best[m]
    return metric.time_from_key(keys) if metric.uniform else keys


def branch_neighbour_times(branches, metric: MoveMetric, k: int | None = None):
    """Lower bounds in s on each pose's cheapest and second-cheapest pair time to another pose.

    A k-d tree over every branch of every pose (scaled Chebyshev coordinates) finds each branch's
    ``k`` nearest branch points; a pose not met among them is at least the ball's radius away from
    every branch of the pose asking.

    Parameters
    ----------
    branches : ndarray, shape (N, W, n_axes)
        Finite branch positions in degrees, N >= 3.
    metric : MoveMetric
    k : int, optional
        Neighbours per branch point (default 2 W + 2, enough to meet two other poses in most cases).

    Returns
    -------
    nn1, nn2 : ndarray, shape (N,)
        Bounds on the least and second-least pair time from each pose to another pose, in s.
    """
    pts = np.asarray(branches, dtype=np.float64)
    n, w, n_axes = pts.shape
    if n < 3:
        raise ValueError(f"branches: need at least 3 poses, got {n}")
    flat = pts.reshape(-1, n_axes)
    owner = np.repeat(np.arange(n), w)
    k = min(2 * w + 2 if k is None else int(k), flat.shape[0] - 1)
    dist, idx = chebyshev_neighbours(flat * metric.scale, flat * metric.scale, k + 1, ties_ok=True)
    # With one v/a ratio the tree's distance is the metric's key: no need to measure the pairs again.
    times = metric.time_from_key(dist) if metric.uniform else metric.time(flat[:, None, :], flat[idx])
    other = owner[idx]
    times[other == owner[:, None]] = np.inf
    # Per pose: its branches' candidate lists side by side (N, W (k + 1)).
    times = times.reshape(n, -1)
    other = other.reshape(n, -1)
    beyond = metric.time_beyond(dist[:, -1].reshape(n, w).min(axis=1))
    order = np.argsort(times, axis=1, kind="stable")
    times = np.take_along_axis(times, order, axis=1)
    other = np.take_along_axis(other, order, axis=1)
    nn1 = times[:, 0]
    # The second pose: the first candidate that belongs to a pose other than the first one's.
    differs = (other != other[:, :1]) & np.isfinite(times)
    has = differs.any(axis=1)
    nn2 = np.where(has, times[np.arange(n), np.argmax(differs, axis=1)], np.inf)
    return np.minimum(nn1, beyond), np.minimum(nn2, beyond)


def relaxed_campaign_bound(branches, free, reference_options, home_deg, metric: MoveMetric,
                           settle_s: float, reading_s: float, every: int, every_s: float | None = None,
                           run_lengths=None, max_pairs: float = BRANCH_MST_MAX_PAIRS,
                           lagrange_steps: int | None = None) -> dict[str, float]:
    """Lower bound on the duration of any campaign over these poses, any order, any branches.

    The campaign is ``home → ref → run 1 → ref → … → run R → ref → home`` with a dark reading beside
    every reference reading (see :mod:`gonio.motion.estimate` for the cost model).

    Parameters
    ----------
    branches : ndarray, shape (P, W, n_axes)
        Every branch of every pose in degrees, NaN for invalid ones (rows of free poses are ignored).
    free : ndarray of bool, shape (P,)
        Poses with a free azimuth (left out of the moves; see the module docstring).
    reference_options : ndarray, shape (K, n_axes)
        Every axis position the white reference may be read at (all branches of all allowed
        reference poses), degrees.
    home_deg : array_like, shape (n_axes,)
        Start and end of the campaign.
    metric : MoveMetric
    settle_s, reading_s : float
        Settle time after each move, exposure × frames per reading, seconds.
    every : int
        At most this many poses per run.
    every_s : float, optional
        At most this many seconds from one reference reading to the next.
    run_lengths : array_like of int, optional
        The runs when the schedule fixes them (count-only schedules): R is then their number.
    max_pairs : float
        The exact MST of pair times runs when P² W² is at most this.
    lagrange_steps : int, optional
        Subgradient steps of the Lagrangian bound (up to :data:`LAGRANGE_MAX_POSES` poses; 0: penalties
        of zero, the forest bound again). Default :data:`LAGRANGE_STEPS`.

    Returns
    -------
    dict
        ``total_s``, ``move_s`` (moves, home legs included), ``settle_s``, ``reading_s``, ``runs``
        (the R the bound takes), ``mst_s`` / ``forest_s`` / ``degree_s`` / ``lagrange_s``
        (motion bounds at that R, NaN when not computed), ``reference_s`` (the pose ↔ reference moves
        bound), all seconds.
    """
    free = np.asarray(free, dtype=bool).reshape(-1)
    p = free.size
    ref = np.asarray(reference_options, dtype=np.float64).reshape(-1, metric.n_axes)
    home = np.asarray(home_deg, dtype=np.float64).reshape(1, -1)
    home_legs = 2.0 * float(np.min(metric.time(home, ref)))
    if p:
        pts = pose_branches(np.asarray(branches, dtype=np.float64)[~free])
    else:
        pts = np.empty((0, 1, ref.shape[1]))
    q = pts.shape[0]
    f = p - q
    to_ref = _to_nearest(pts, ref, metric) if q else np.empty(0)
    sorted_ref = np.concatenate([[0.0], np.cumsum(np.sort(to_ref))])
    mst = forest_edges = np.nan
    degree_base = np.nan
    # The table of pair times, where the Lagrangian uses it: its Prim is the MST as well.
    pair = pair_time_matrix(pts, metric) if 3 <= q <= LAGRANGE_MAX_POSES else None
    if q >= 2 and float(q) ** 2 * pts.shape[1] ** 2 <= max_pairs:
        edges = np.sort(branch_mst_edge_times(pts, metric) if pair is None else pair[_prim(pair)])
        mst = float(edges.sum())
        forest_edges = np.concatenate([[0.0], np.cumsum(edges)])  # forest(R') = forest_edges[q - R']
    if q >= 3:
        nn1, nn2 = branch_neighbour_times(pts, metric)
        four = np.sort(np.stack([nn1, nn2, to_ref, to_ref], axis=1), axis=1)
        degree_base = 0.5 * float(np.sum(four[:, 0] + four[:, 1]))
    r_lo = max(1, -(-p // int(every))) if p else 0
    lagrange_at = None  # lagrange_at[R' - 1]: the Lagrangian bound for R' runs
    if pair is not None:
        target = np.asarray(run_lengths).size if run_lengths is not None and every_s is None else r_lo
        steps = LAGRANGE_STEPS if lagrange_steps is None else int(lagrange_steps)
        pi = lagrangian_penalties(pair, to_ref, min(max(int(target), 1), q), steps)
        lagrange_at = lagrangian_motion(pair, to_ref, pi, np.arange(1, q + 1))

    def motion(r_prime: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Motion bound for R' runs of the non-free poses: (best, forest, degree, Lagrangian)."""
        rp = np.clip(r_prime, 0, q)
        ref_moves = 2.0 * sorted_ref[rp]
        forest = (forest_edges[np.maximum(q - rp, 0)] if np.ndim(forest_edges) else
                  np.full(rp.shape, np.nan)) + ref_moves
        if q >= 3:
            degree = degree_base + 0.5 * ref_moves
        else:
            degree = ref_moves.astype(float)
        lagrange = (lagrange_at[np.maximum(rp, 1) - 1] if lagrange_at is not None else
                    np.full(rp.shape, np.nan))
        best = np.fmax(np.fmax(forest, degree), lagrange)
        best = np.where(rp == 0, 0.0, best) if q == 0 else best
        return best, forest, degree, lagrange

    fixed_pose = p * (settle_s + reading_s)
    per_checkpoint = settle_s + 2.0 * reading_s

    def evaluate(rs: np.ndarray):
        """Least motion over R' in [R - f, R] (runs made of free poses only vanish), and its parts
        (forest, degree, Lagrangian) at the R' taken."""
        if f > _MAX_DROPS:
            # Many poses left out: take the least over every R' <= R (a weaker bound, still valid).
            m, *parts = motion(np.arange(1 if q else 0, max(int(rs.max(initial=1)), 1) + 1))
            at = np.minimum.accumulate(m)
            arg = np.maximum.accumulate(np.where(m == at, np.arange(m.size), 0))
            k = np.clip(rs - (1 if q else 0), 0, m.size - 1)
            return at[k], [x[arg[k]] for x in parts]
        best = np.full(rs.shape, np.inf)
        parts = [np.full(rs.shape, np.nan) for _ in range(3)]
        for drop in range(0, min(f, int(rs.max(initial=0))) + 1):
            m, *these = motion(np.maximum(rs - drop, 1 if q else 0))
            better = m < best
            best = np.where(better, m, best)
            parts = [np.where(better, x, old) for x, old in zip(these, parts, strict=True)]
        return best, parts

    if p == 0:
        chosen, m, parts = 0, 0.0, [np.nan] * 3
    elif run_lengths is not None and every_s is None:
        chosen = int(np.asarray(run_lengths).size)
        mb, pb = evaluate(np.array([chosen]))
        m, parts = float(mb[0]), [float(x[0]) for x in pb]
    else:
        # Least over the allowed R; R above the best total's reach cannot win (each checkpoint costs
        # at least per_checkpoint and the motion is at least its least value over all R').
        floor_motion = float(np.min(evaluate(np.arange(1, p + 1))[0])) if p <= 200_000 else 0.0
        best_total, chosen, m, parts = np.inf, r_lo, np.nan, [np.nan] * 3
        start = r_lo
        while start <= p:
            rs = np.arange(start, min(start + 4096, p + 1))
            mb, pb = evaluate(rs)
            inner = mb + fixed_pose + rs * per_checkpoint
            ok = np.ones(rs.shape, dtype=bool) if every_s is None else inner <= rs * every_s + 1e-9
            total = np.where(ok, inner, np.inf)
            i = int(np.argmin(total))
            if total[i] < best_total:
                best_total, chosen, m = float(total[i]), int(rs[i]), float(mb[i])
                parts = [float(x[i]) for x in pb]
            reach = fixed_pose + (rs[-1] + 1) * per_checkpoint + floor_motion
            if np.isfinite(best_total) and reach >= best_total:
                break
            start = int(rs[-1]) + 1
        if not np.isfinite(best_total):  # no R fits the time limit by this bound: one checkpoint per pose
            chosen = p
            mb, pb = evaluate(np.array([p]))
            m, parts = float(mb[0]), [float(x[0]) for x in pb]
    checkpoints = chosen + 1 if p else 1
    out = {"move_s": float(m) + home_legs,
           "settle_s": float(p + checkpoints) * settle_s,
           "reading_s": float(p + 2 * checkpoints) * reading_s}
    out["total_s"] = sum(out.values())
    out.update({"runs": int(chosen), "mst_s": mst, "forest_s": parts[0], "degree_s": parts[1],
                "lagrange_s": parts[2], "reference_s": float(2.0 * sorted_ref[min(chosen, q)])})
    return out


def _to_nearest(branches, options, metric: MoveMetric) -> np.ndarray:
    """Least move time (N,) from any branch of each pose (N, W, n) to any of ``options`` (K, n): a
    nearest-neighbour search when the metric's key is a scaled Chebyshev distance, else every pair."""
    if not metric.uniform:
        return pair_times(branches, options[None], metric)[:, 0]
    n, w, n_axes = branches.shape
    dist, _ = chebyshev_neighbours(options * metric.scale, branches.reshape(-1, n_axes) * metric.scale, 1,
                                   ties_ok=True)
    return metric.time_from_key(dist.reshape(n, w).min(axis=1))
