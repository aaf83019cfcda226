"""Choosing an inverse-kinematics branch for every pose of an ordered campaign.

Each pose takes the valid branch nearest to where the gantry is when it gets there: the previous
pose, or the reference pose at the start of a run (the runner visits the reference between runs).
"Nearest" is the rule of :meth:`Kinematics.inverse`: the smallest maximum over axes of the trapezoidal
move time, ties (within 1 ns) to the smallest total, then to the first branch.

That is a sequential recurrence, but runs are independent of each other, so the runs are walked in
lockstep: step l picks the branch of the l-th pose of every run at once. The branches of a pose do not
depend on where the gantry comes from, except where an azimuth is free (an arm at the pole, or a
detector in line with the light) and stays where it is, so they are computed once per group of runs
(:meth:`Kinematics.solutions`) and only those poses ask the kinematics again at their step
(:meth:`Kinematics.inverse` from the current axes).

The cost is one lockstep step per pose of the longest run: with the default reference schedule
(a reference every 50 poses) that is 50 vectorized steps whatever the campaign's size.
"""

from __future__ import annotations

import numpy as np

from gonio.motion.metric import MoveMetric

__all__ = ["chain_branches", "nearest_branch", "free_azimuth", "run_inputs"]

# Poses whose branches are held in memory at once (about 64 MB of (poses, S, n_axes) float64).
_GROUP_POSES = 1 << 17
# rad: a direction this close to the pole has a free azimuth (as in gonio.kinematics.base.POLE_EPS).
_POLE_EPS = 1e-9
# s: move times closer than this are ties (as in gonio.kinematics.base.TIME_TOL).
_TIME_TOL = 1e-9


def nearest_branch(branches_deg, current_deg, metric: MoveMetric) -> np.ndarray:
    """The branch of each pose nearest to ``current_deg`` by the rule of :meth:`Kinematics.inverse`.

    Parameters
    ----------
    branches_deg : ndarray, shape (B, S, n_axes)
        Candidate axis positions in degrees, NaN for invalid branches.
    current_deg : ndarray, shape (B, n_axes)
        Where the gantry is, degrees.
    metric : MoveMetric
        The move-time metric of the axes.

    Returns
    -------
    ndarray, shape (B, n_axes)
        The chosen positions (NaN rows where no branch is valid).
    """
    branches = np.asarray(branches_deg, dtype=np.float64)
    current = np.asarray(current_deg, dtype=np.float64)
    valid = ~np.isnan(branches[..., 0])
    slowest = np.where(valid, metric.time(current[:, None, :], branches), np.inf)
    near = slowest <= np.min(slowest, axis=-1, keepdims=True) + _TIME_TOL
    pick = np.argmax(near, axis=-1)
    # Ties on the slowest axis go to the smallest total move time: per-axis times only where needed.
    tied = np.flatnonzero(np.count_nonzero(near, axis=-1) > 1)
    if tied.size:
        times = metric.axis_times(current[tied, None, :], branches[tied])
        total = np.where(near[tied], np.sum(times, axis=-1), np.inf)
        pick[tied] = np.argmin(total, axis=-1)
    return np.take_along_axis(branches, pick[:, None, None], axis=1)[:, 0, :]


def chain_branches(kin, theta_i, phi_i, theta_o, phi_o, run_starts, start_deg) -> np.ndarray:
    """Axis targets (P, n_axes) in degrees for poses in motion order, each branch nearest the last.

    Parameters
    ----------
    kin : Kinematics
        Provides ``solutions``, ``inverse`` (with ``current_deg``), ``velocity_deg_s`` and
        ``accel_deg_s2`` (see :mod:`gonio.kinematics`).
    theta_i, phi_i, theta_o, phi_o : ndarray, shape (P,)
        The poses in visiting order, radians; all must be reachable.
    run_starts : array_like of int
        Indices where a run begins (the gantry comes from ``start_deg``); must include 0.
    start_deg : array_like, shape (n_axes,)
        Axis positions at the start of every run (the reference pose), degrees.

    Returns
    -------
    ndarray, shape (P, n_axes)
        Axis targets in degrees.

    Raises
    ------
    ValueError
        When a pose has no valid branch.
    """
    poses, start, starts, run_ends = run_inputs(theta_i, phi_i, theta_o, phi_o, run_starts, start_deg)
    p = poses[0].shape[0]
    if p == 0:
        return np.empty((0, start.size))
    prev = np.broadcast_to(start, (starts.size, start.size)).copy()
    metric = MoveMetric(kin.velocity_deg_s, kin.accel_deg_s2)
    pole = free_azimuth(*poses)
    out = np.empty((p, start.size))
    # Groups of whole runs, so that each group's branches fit in memory.
    first = 0
    while first < starts.size:
        last = int(np.searchsorted(run_ends, run_ends[first] + _GROUP_POSES, side="right"))
        last = max(last, first + 1)
        _chain_group(kin, metric, poses, pole, starts[first:last], run_ends[first:last],
                     prev[first:last], out)
        first = last
    return out


def run_inputs(theta_i, phi_i, theta_o, phi_o, run_starts, start_deg):
    """Validated inputs of a branch choice over runs: flat pose arrays, the start axes, and the sorted
    run starts and ends (empty runs when there are no poses)."""
    poses = [np.asarray(a, dtype=np.float64).reshape(-1) for a in (theta_i, phi_i, theta_o, phi_o)]
    p = poses[0].shape[0]
    start = np.asarray(start_deg, dtype=np.float64).reshape(-1)
    starts = np.unique(np.asarray(run_starts, dtype=np.int64))
    if p and (starts.size == 0 or starts[0] != 0 or starts[-1] >= p):
        raise ValueError(f"run_starts: must include 0 and lie in [0, {p}), got {starts[:3].tolist()}...")
    return poses, start, starts, np.append(starts[1:], p)


def free_azimuth(theta_i, phi_i, theta_o, phi_o) -> np.ndarray:
    """Poses (P,) whose branches depend on where the gantry comes from: an arm at the pole (θ = 0), or
    ωi = ωo (a detector in line with the light has a free azimuth on some designs; only reachable with
    clearance_deg = 0)."""
    theta_i, phi_i, theta_o, phi_o = (np.asarray(a, dtype=np.float64)
                                      for a in (theta_i, phi_i, theta_o, phi_o))
    cos = (np.cos(theta_i) * np.cos(theta_o)
           + np.sin(theta_i) * np.sin(theta_o) * np.cos(phi_o - phi_i))
    return (theta_i < _POLE_EPS) | (theta_o < _POLE_EPS) | (cos > 1.0 - 1e-12)


def _chain_group(kin, metric, poses, pole, c_starts, c_ends, prev, out) -> None:
    lo, hi = int(c_starts[0]), int(c_ends[-1])
    lengths = c_ends - c_starts
    offset = np.arange(lo, hi) - np.repeat(c_starts, lengths)  # each pose's place in its run
    # Branches are fetched for a window of steps at a time, so one very long run stays in memory too.
    window = max(1, _GROUP_POSES // len(c_starts))
    where = np.empty(hi - lo, dtype=np.int64)
    prev = prev.copy()
    for w0 in range(0, int(lengths.max()), window):
        inside = np.flatnonzero((offset >= w0) & (offset < w0 + window))
        sols = np.asarray(kin.solutions(*(a[lo + inside] for a in poses)), dtype=np.float64)
        where[inside] = np.arange(inside.size)
        for step in range(w0, min(w0 + window, int(lengths.max()))):
            active = np.flatnonzero(lengths > step)
            rows = c_starts[active] + step
            axes = nearest_branch(sols[where[rows - lo]], prev[active], metric)
            at_pole = pole[rows]
            if at_pole.any():
                # A free azimuth stays where the gantry is: only the kinematics knows where that is.
                r = rows[at_pole]
                axes[at_pole] = kin.inverse(*(a[r] for a in poses), current_deg=prev[active[at_pole]])
            if np.isnan(axes).any():
                bad = int(rows[np.isnan(axes).any(axis=1)][0])
                raise ValueError(f"pose {bad} (θi={np.degrees(poses[0][bad]):.4g}°, "
                                 f"θo={np.degrees(poses[2][bad]):.4g}°) has no valid branch; plans keep "
                                 "only feasible poses")
            out[rows] = axes
            prev[active] = axes
