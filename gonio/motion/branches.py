"""The quickest choice of inverse-kinematics branches for poses in a fixed order.

The greedy rule (:func:`gonio.motion.chain.chain_branches`: each pose on the branch nearest the last)
cannot look ahead: it follows an azimuth to its limit and then pays a full unwinding, or flips an arm
over the zenith for one pose and back for the next. Here the branches of each run (the poses between
two white-reference readings, entered from and left to the reference pose) are chosen by dynamic
programming (Viterbi) to minimize the run's total move time, reference trips included. For the same
order that is never slower than the greedy chain, and on the shipped gantries it removes most of
the branch flips (see BENCHMARKS.md).

Runs are independent, so they are solved in lockstep: step l relaxes the l-th pose of every run at
once over all pairs of branches (S × S per run). A pose whose azimuth is free (an arm at the pole, or
a detector in line with the light) has, for each branch of the pose before it, the one position the
kinematics gives from there (:meth:`Kinematics.inverse`), so the free axis stays where it is.
"""

from __future__ import annotations

import numpy as np

from gonio.motion.chain import free_azimuth, run_inputs
from gonio.motion.metric import MoveMetric

__all__ = ["best_branches", "COLLISION_PENALTY_S"]

#: s: what a move that collides costs on top of its time when ``check_moves`` is on. Far above any
#: campaign's motion, so fewer colliding moves always win; the time decides among equals.
COLLISION_PENALTY_S = 1e7

# Moves swept-path checked in one call when check_moves is on (bounds the checker's temporaries).
_CHECK_MOVES_AT_ONCE = 50_000
# Poses whose branches and back-pointers are held at once (a few hundred MB at most).
_GROUP_POSES = 1 << 16


def best_branches(kin, theta_i, phi_i, theta_o, phi_o, run_starts, reference_deg,
                  check_moves: bool = False) -> np.ndarray:
    """Axis targets (P, n_axes) in degrees minimizing each run's move time, reference trips included.

    Only branches in the reference's part of the collision-free axis space are used
    (:meth:`Kinematics.free_component`): the others cannot be reached from it without a collision.

    Parameters
    ----------
    kin : Kinematics
        Provides ``solutions``, ``inverse`` (with ``current_deg``), ``velocity_deg_s`` and
        ``accel_deg_s2`` (see :mod:`gonio.kinematics`).
    theta_i, phi_i, theta_o, phi_o : ndarray, shape (P,)
        The poses in visiting order, radians; all must be reachable.
    run_starts : array_like of int
        Indices where a run begins; must include 0. Each run goes reference → its poses → reference.
    reference_deg : array_like, shape (n_axes,)
        Axis positions of the reference pose, degrees.
    check_moves : bool
        Also check every candidate move's swept path (:meth:`Kinematics.sweep_clearance`) and price
        the colliding ones at :data:`COLLISION_PENALTY_S` extra, so that a run uses as few of them as
        it can (each then needs via points) and otherwise the quickest branches. Costs a sweep check
        per pair of branches: for re-solving the few runs where the plain choice collides.

    Returns
    -------
    ndarray, shape (P, n_axes)
        Axis targets in degrees.

    Raises
    ------
    ValueError
        When a pose has no valid branch.
    """
    poses, ref, starts, ends = run_inputs(theta_i, phi_i, theta_o, phi_o, run_starts, reference_deg)
    p = poses[0].shape[0]
    if p == 0:
        return np.empty((0, ref.size))
    metric = MoveMetric(kin.velocity_deg_s, kin.accel_deg_s2)
    free = free_azimuth(*poses)
    out = np.empty((p, ref.size))
    first = 0
    while first < starts.size:
        last = int(np.searchsorted(ends, ends[first] + _GROUP_POSES, side="right"))
        last = max(last, first + 1)
        _solve_group(kin, metric, poses, free, starts[first:last], ends[first:last], ref, out, check_moves)
        first = last
    return out


def _solve_group(kin, metric, poses, free, r_starts, r_ends, ref, out, check_moves) -> None:
    lo, hi = int(r_starts[0]), int(r_ends[-1])
    sols = np.asarray(kin.solutions(*(a[lo:hi] for a in poses)), dtype=np.float64)
    home_part = kin.free_component(ref)[0]
    valid = ~np.isnan(sols[..., 0])
    valid &= kin.free_component(np.where(valid[..., None], sols, 0.0)).reshape(valid.shape) == home_part
    sols[~valid] = np.nan
    # Valid branches first, and only as many columns as the widest pose needs.
    by_valid = np.argsort(~valid, axis=1, kind="stable")
    width = max(int(valid.sum(axis=1).max()), 1)
    sols = np.take_along_axis(sols, by_valid[:, :width, None], axis=1)
    lengths = r_ends - r_starts
    n_runs, n_axes = r_starts.size, ref.size
    if check_moves:
        clear_in, clear_home = _clear_moves(kin, sols, free[lo:hi], r_starts - lo, r_ends - lo, ref)
    back = np.zeros((hi - lo, width), dtype=np.int16)
    chosen = np.empty((hi - lo, width, n_axes))  # the candidates actually used at each pose
    cost = np.zeros((n_runs, width))
    prev = np.broadcast_to(ref, (n_runs, width, n_axes)).copy()
    final = np.empty(n_runs, dtype=np.int64)
    for step in range(int(lengths.max())):
        active = np.flatnonzero(lengths > step)
        rows = r_starts[active] + step - lo
        cand = sols[rows]
        is_free = free[lo + rows]
        # times[r, s_prev, s] of every pair of branches of consecutive poses.
        times = _pair_times(prev[active], cand, metric)
        if step == 0:
            times = times[:, :1, :]  # every run starts from the one reference position
        if check_moves:
            # Moves from a pose of fixed branches (or the reference) were checked all at once before;
            # those from a free pose start where the chain put it, so they are checked here.
            after_free = free[lo + rows - 1] if step else np.zeros(rows.size, dtype=bool)
            known = np.flatnonzero(~is_free & ~after_free)
            blocked = np.isfinite(times[known]) & ~clear_in[rows[known], :times.shape[1]]
            times[known] += np.where(blocked, COLLISION_PENALTY_S, 0.0)
            fixed = np.flatnonzero(~is_free & after_free)
            priced = times[fixed]
            _price_collisions(kin, priced, prev[active[fixed]][:, :times.shape[1]], cand[fixed])
            times[fixed] = priced
        if is_free.any():
            # A free pose's positions depend on the branch before it: solved again from each one.
            f = np.flatnonzero(is_free)
            w_prev = times.shape[1]
            before = cost[active[f]][:, :w_prev] if step else np.zeros((f.size, 1))
            cand[f], times[f] = _free_candidates(
                kin, metric, tuple(a[lo + rows[f]] for a in poses), prev[active[f]][:, :w_prev], before,
                width, home_part, ref, check_moves)
        chosen[rows] = cand
        if step == 0:
            total = times[:, 0, :]
            back[rows] = 0
        else:
            through = cost[active][:, :, None] + times
            back[rows] = np.argmin(through, axis=1)
            total = np.min(through, axis=1)
        cost[active] = total
        prev[active] = cand
        done = lengths[active] == step + 1
        if done.any():
            d = active[done]
            home = metric.time(prev[d], ref)
            if check_moves:
                last_rows = r_ends[d] - 1 - lo
                known = ~free[lo + last_rows]
                home[known] += np.where(~np.isnan(home[known]) & ~clear_home[last_rows[known]],
                                        COLLISION_PENALTY_S, 0.0)
                at_free = np.flatnonzero(~known)
            if check_moves and at_free.size:
                finite = np.flatnonzero(~np.isnan(home[at_free].reshape(-1)))
                clear = kin.sweep_clear(prev[d[at_free]].reshape(-1, n_axes)[finite], ref)
                sub = home[at_free]
                sub.reshape(-1)[finite[~clear]] += COLLISION_PENALTY_S
                home[at_free] = sub
            final[d] = np.argmin(np.where(np.isnan(home), np.inf, cost[d] + home), axis=1)
    if not np.all(np.isfinite(cost[np.arange(n_runs), final])):
        bad = int(np.flatnonzero(~np.isfinite(cost[np.arange(n_runs), final]))[0])
        raise ValueError(f"poses {int(r_starts[bad])}..{int(r_ends[bad]) - 1}: some pose has no valid "
                         "branch; plans keep only feasible poses")
    # Walk the back-pointers from each run's last pose to its first.
    state = final.copy()
    for step in range(int(lengths.max()) - 1, -1, -1):
        active = np.flatnonzero(lengths > step)
        rows = r_starts[active] + step - lo
        out[lo + rows] = chosen[rows, state[active]]
        state[active] = back[rows, state[active]]


def _clear_moves(kin, sols, free, starts, ends, ref):
    """Swept-path checks of every move the Viterbi may price whose start does not depend on its choices,
    in a few large :meth:`Kinematics.sweep_clearance` calls instead of one per step (each call costs
    about a millisecond of numpy overhead before any work).

    Returns ``clear_in`` (P, W, W): whether the move from branch i of the pose before (the reference's
    one position, i = 0, at a run's first pose) to branch j of the pose is clear; and ``clear_home``
    (P, W): from branch j of the pose to the reference. True where either end is invalid or free
    (those are checked as the chain reaches them). The checks are per move, so each result is the
    one a call with that move alone gives."""
    p, w, n_axes = sols.shape
    is_start = np.zeros(p, dtype=bool)
    is_start[starts] = True
    is_last = np.zeros(p, dtype=bool)
    is_last[ends - 1] = True
    valid = ~np.isnan(sols[..., 0])
    prev_free = np.zeros(p, dtype=bool)
    prev_free[1:] = free[:-1]
    # Whose moves in are checked here: poses of fixed branches after a pose of fixed branches (or the
    # reference); and whose moves home: fixed last poses of runs.
    checked_in = ~free & (is_start | ~prev_free)
    checked_home = ~free & is_last
    clear_in = np.ones((p, w, w), dtype=bool)
    clear_home = np.ones((p, w), dtype=bool)
    rows_at_once = max(1, _CHECK_MOVES_AT_ONCE // (w * w + w))
    for lo in range(0, p, rows_at_once):
        hi = min(lo + rows_at_once, p)
        before = sols[max(lo - 1, 0):hi - 1] if lo else \
            np.concatenate([np.full((1, w, n_axes), np.nan), sols[:hi - 1]])
        before = before.copy()
        here_start = is_start[lo:hi]
        before[here_start] = np.nan
        before[here_start, 0] = ref
        wanted = valid[lo:hi, None, :] & ~np.isnan(before[..., 0])[:, :, None] & checked_in[lo:hi, None, None]
        r, i, j = np.nonzero(wanted)
        home_r, home_j = np.nonzero(valid[lo:hi] & checked_home[lo:hi, None])
        a = np.concatenate([before[r, i], sols[lo + home_r, home_j]])
        b = np.concatenate([sols[lo + r, j], np.broadcast_to(ref, (home_r.size, n_axes))])
        if a.shape[0] == 0:
            continue
        clear = kin.sweep_clear(a, b)
        clear_in[lo + r, i, j] = clear[:r.size]
        clear_home[lo + home_r, home_j] = clear[r.size:]
    return clear_in, clear_home


def _free_candidates(kin, metric, poses, prev, before, width, home_part, ref, check_moves):
    """Candidates (F, W, n) and move times (F, W', W) of F poses whose azimuth is free.

    Where a free arm goes depends on where it comes from, so every branch is solved again from each
    branch ``prev`` (F, W', n) of the pose before; each branch keeps the predecessor that reaches it
    at the least cost (``before`` (F, W') plus the move), and the ``width`` cheapest branches are
    kept, with a finite time only from that predecessor. Solving only the quickest branch from each
    predecessor (as :meth:`Kinematics.inverse` would) loses the branches a later pose needs: a light
    circling a detector at the zenith must flip over its own zenith to keep from pushing the
    detector's carriage round the ring into its limit.
    """
    n_free, w_prev, n_axes = prev.shape
    here = np.where(np.isnan(prev).any(axis=2, keepdims=True), ref, prev).reshape(-1, n_axes)
    sols = np.asarray(kin.solutions(*(np.repeat(a, w_prev) for a in poses), current_deg=here),
                      dtype=np.float64)
    n_b = sols.shape[1]
    sols = sols.reshape(n_free, w_prev, n_b, n_axes)
    elsewhere = kin.free_component(np.nan_to_num(sols).reshape(-1, n_axes)).reshape(sols.shape[:3])
    sols[elsewhere != home_part] = np.nan
    times = metric.time(prev[:, :, None, :], sols)
    times = np.where(np.isnan(times), np.inf, times)
    if check_moves:
        b, i, j = np.nonzero(np.isfinite(times))
        clear = kin.sweep_clear(prev[b, i], sols[b, i, j])
        times[b[~clear], i[~clear], j[~clear]] += COLLISION_PENALTY_S
    through = before[:, :, None] + times
    via = np.argmin(through, axis=1)                                   # (F, n_b)
    best = np.take_along_axis(through, via[:, None, :], axis=1)[:, 0]  # (F, n_b)
    keep = np.argsort(best, axis=1, kind="stable")[:, :width]          # (F, W)
    src = np.take_along_axis(via, keep, axis=1)
    rows = np.arange(n_free)[:, None]
    cand = sols[rows, src, keep]
    out = np.full((n_free, w_prev, keep.shape[1]), np.inf)
    out[rows, src, np.arange(keep.shape[1])[None, :]] = times[rows, src, keep]
    cand[~np.isfinite(np.take_along_axis(best, keep, axis=1))] = np.nan
    if keep.shape[1] < width:
        pad = width - keep.shape[1]
        cand = np.concatenate([cand, np.full((n_free, pad, n_axes), np.nan)], axis=1)
        out = np.concatenate([out, np.full((n_free, w_prev, pad), np.inf)], axis=2)
    return cand, out


def _price_collisions(kin, times, prev, cand) -> None:
    """Add the penalty to ``times`` (B, W', W) where the move from ``prev`` (B, W', n) to ``cand``
    (B, W, n) collides in transit (finite entries only)."""
    finite = np.isfinite(times)
    if not finite.any():
        return
    b, i, j = np.nonzero(finite)
    clear = kin.sweep_clear(prev[b, i], cand[b, j])
    times[b[~clear], i[~clear], j[~clear]] += COLLISION_PENALTY_S


def _pair_times(prev: np.ndarray, cand: np.ndarray, metric: MoveMetric) -> np.ndarray:
    """Move times (B, W, W) from every branch in ``prev`` (B, W, n) to every one in ``cand``; inf for
    invalid (NaN) branches."""
    if metric.uniform:
        # One axis at a time over contiguous (B, W, W) blocks: much quicker than reducing a last axis
        # of length n, and this is the inner loop of the whole planner.
        a = prev * metric.scale
        b = cand * metric.scale
        key = np.abs(a[:, :, None, 0] - b[:, None, :, 0])
        for k in range(1, a.shape[-1]):
            np.maximum(key, np.abs(a[:, :, None, k] - b[:, None, :, k]), out=key)
        times = metric.time_from_key(key)
    else:
        times = metric.time(prev[:, :, None, :], cand[:, None, :, :])
    return np.where(np.isnan(times), np.inf, times)
