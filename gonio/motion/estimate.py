"""How long a campaign takes, and the least it could take, with the same cost model for both.

Cost model (seconds):

- a move takes the move-time metric between consecutive axis targets (:class:`MoveMetric`);
- every step that moves (a measurement pose or the white reference) then waits ``settle_s``;
- every reading (pose, dark or reference) exposes ``exposure_s × frames``;
- a dark reading is taken where the gantry is, light off: no move, no settle;
- the campaign starts at home and ends with a move back home (no settle, no reading).

The estimate adds these up over the actual step sequence. The lower bound keeps every fixed cost
exactly (they do not depend on the order) and replaces the moves between the reference and the poses
by :func:`gonio.motion.bound.motion_lower_bound`; the two moves between home and the reference are
fixed and counted exactly in both.

Moves that collide in transit go through via points (:mod:`gonio.motion.safe`); the estimate adds
the time they cost. The bound needs no change: a path through via points is never quicker than the
direct move (the move time is a metric), so bounding direct moves still bounds the campaign.
"""

from __future__ import annotations

import numpy as np

from gonio.motion.bound import MST_MAX_POSES, motion_lower_bound
from gonio.motion.metric import MoveMetric

__all__ = ["step_move_times", "campaign_estimate", "campaign_lower_bound"]


def step_move_times(targets_deg, start_deg, metric: MoveMetric) -> np.ndarray:
    """Move time in s into each step of a sequence, starting from ``start_deg``.

    Parameters
    ----------
    targets_deg : array_like, shape (S, n_axes)
        The axis target of each step in degrees; a row of NaN means "stay where you are" (a dark
        reading).
    start_deg : array_like, shape (n_axes,)
        Where the gantry is before the first step.
    metric : MoveMetric
        The move-time metric.

    Returns
    -------
    ndarray, shape (S,)
        Move times in s (0 for the rows that stay).
    """
    targets = np.asarray(targets_deg, dtype=np.float64)
    start = np.asarray(start_deg, dtype=np.float64).reshape(1, -1)
    if targets.ndim != 2 or targets.shape[1] != start.shape[1]:
        raise ValueError(f"targets_deg: expected shape (S, {start.shape[1]}), got {targets.shape}")
    stay = np.isnan(targets).any(axis=1)
    positions = np.concatenate([start, targets])
    # Forward-fill: a staying step is where the last moving step (or the start) left the gantry.
    src = np.where(np.concatenate([[False], stay]), 0, np.arange(targets.shape[0] + 1))
    np.maximum.accumulate(src, out=src)
    positions = positions[src]
    moves = metric.time(positions[:-1], positions[1:])
    return np.where(stay, 0.0, moves)


def campaign_estimate(targets_deg, settles, n_readings: int, home_deg, metric: MoveMetric,
                      settle_s: float, reading_s: float, extra_move_s=None) -> dict[str, float]:
    """Estimated duration of a step sequence that starts and ends at home.

    Parameters
    ----------
    targets_deg : array_like, shape (S, n_axes)
        Axis targets of the steps in order (NaN rows: no move), degrees.
    settles : array_like of bool, shape (S,)
        Which steps wait for the axes to settle (those that move).
    n_readings : int
        Readings taken over the whole sequence (every step is one reading in a plan).
    home_deg : array_like, shape (n_axes,)
        Start and end position, degrees.
    metric : MoveMetric
        The move-time metric.
    settle_s, reading_s : float
        Settle time after a move, and exposure × frames per reading, seconds.
    extra_move_s : array_like, shape (S + 1,), optional
        Seconds each move takes beyond the direct move (via points; :mod:`gonio.motion.safe`), the last
        entry for the return home. The gantry passes via points at rest but does not settle there.

    Returns
    -------
    dict
        ``move_s`` (all moves into steps, via points included), ``return_s`` (back home),
        ``settle_s``, ``reading_s`` and ``total_s``, all seconds, and ``via_s`` (the part of
        ``move_s`` and ``return_s`` spent going round through via points).
    """
    targets = np.asarray(targets_deg, dtype=np.float64)
    moves = step_move_times(targets, home_deg, metric)
    moving = ~np.isnan(targets).any(axis=1)
    last = targets[moving][-1] if moving.any() else np.asarray(home_deg, dtype=np.float64)
    back = float(metric.time(last, home_deg))
    extra = np.zeros(targets.shape[0] + 1) if extra_move_s is None else np.asarray(extra_move_s, float)
    if extra.shape != (targets.shape[0] + 1,):
        raise ValueError(f"extra_move_s: expected shape ({targets.shape[0] + 1},), got {extra.shape}")
    moves = moves + extra[:-1]
    back += float(extra[-1])
    parts = {"move_s": float(moves.sum()), "return_s": back,
             "settle_s": float(np.count_nonzero(settles)) * settle_s,
             "reading_s": float(n_readings) * reading_s}
    parts["total_s"] = sum(parts.values())
    parts["via_s"] = float(extra.sum())
    return parts


def campaign_lower_bound(poses_deg, reference_deg, run_lengths, n_reference: int, n_dark: int,
                         home_deg, metric: MoveMetric, settle_s: float, reading_s: float,
                         mst_max_poses: int = MST_MAX_POSES) -> dict[str, float]:
    """Lower bound on the duration of any campaign over these poses with this reference schedule.

    The campaign is ``home → ref → run 1 → ref → … → run R → ref → home`` with a dark reading beside
    every reference reading. Valid for any order of the poses and any split into R runs.

    Parameters
    ----------
    poses_deg : array_like, shape (P, n_axes)
        Axis positions of the measurement poses (the branches the plan uses), degrees.
    reference_deg : array_like, shape (n_axes,)
        Axis positions of the reference pose, degrees.
    run_lengths : array_like of int, shape (R,)
        Poses in each run between reference readings (the schedule's; see
        :func:`gonio.motion.bound.motion_lower_bound`).
    n_reference, n_dark : int
        Reference readings, dark readings.
    home_deg : array_like, shape (n_axes,)
        Start and end position, degrees.
    metric : MoveMetric
        The move-time metric.
    settle_s, reading_s : float
        Settle time after a move, and exposure × frames per reading, seconds.
    mst_max_poses : int
        Largest pose count for the exact MST (see :func:`gonio.motion.bound.motion_lower_bound`).

    Returns
    -------
    dict
        ``move_s`` (moves bound, home↔reference included), ``settle_s``, ``reading_s``, ``total_s``,
        and the pieces of the motion bound (``mst_s``, ``forest_s``, ``degree_s``), seconds.
    """
    poses = np.asarray(poses_deg, dtype=np.float64)
    ref = np.asarray(reference_deg, dtype=np.float64)
    home_ref = float(metric.time(home_deg, ref))
    motion = motion_lower_bound(poses, ref, run_lengths, metric, mst_max_poses) if len(poses) else {
        "motion_s": 0.0, "mst_s": np.nan, "forest_s": np.nan, "degree_s": np.nan}
    parts = {"move_s": motion["motion_s"] + 2.0 * home_ref,
             "settle_s": float(len(poses) + n_reference) * settle_s,
             "reading_s": float(len(poses) + n_reference + n_dark) * reading_s}
    parts["total_s"] = sum(parts.values())
    for key in ("mst_s", "forest_s", "degree_s"):
        parts[key] = motion[key]
    return parts
