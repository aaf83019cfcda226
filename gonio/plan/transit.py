"""Making every move of a plan clear in transit, not only its poses.

The moves of a campaign are ``home → first target``, each moving step's target to the next one (dark
readings do not move; white references are real targets), and the park ``last → home``. Each is
checked on its swept path (:meth:`Kinematics.sweep_clearance`). Where one collides:

1. the runs (poses between two references) holding such a move have their branches chosen again
   with every candidate move checked and colliding ones priced out
   (:func:`gonio.motion.branches.best_branches` with ``check_moves``), which finds a clear sequence
   of branches wherever one exists among the poses' branches;
2. what still collides (or is too close to the rule to trust round-off) gets the via points of
   :func:`gonio.motion.safe.safe_path`, exactly those the runner computes at run time.
"""

from __future__ import annotations

import numpy as np

from gonio.motion.branches import best_branches
from gonio.motion.metric import MoveMetric
from gonio.motion.safe import park_path, path_time, safe_path
from gonio.plan.schedule import STEP_POSE, STEP_REFERENCE

__all__ = ["step_targets", "colliding_runs", "secure_branches", "via_points", "BORDER_DEG"]

#: deg: moves whose certified margin is within this of the rule also go through safe_path, so that a
#: round-off difference between the vectorized and the scalar check cannot make plan and runner differ.
BORDER_DEG = 1e-6


def step_targets(step_kind, step_pose, axes_deg, reference_deg) -> np.ndarray:
    """Axis targets (S, n_axes) of every step in degrees; NaN rows for dark readings (no move)."""
    axes = np.asarray(axes_deg, dtype=np.float64)
    targets = np.full((len(step_kind), axes.shape[1]), np.nan)
    is_pose = step_kind == STEP_POSE
    targets[is_pose] = axes[step_pose[is_pose]]
    targets[step_kind == STEP_REFERENCE] = reference_deg
    return targets


def _moves(targets, home):
    """(moving step indices, start of each move, end of each move) including the park (step −1)."""
    moving = np.flatnonzero(~np.isnan(targets).any(axis=1))
    ends = np.vstack([targets[moving], home[None, :]])
    starts = np.vstack([home[None, :], targets[moving]])
    return np.append(moving, -1), starts, ends


def colliding_runs(kin, step_kind, step_pose, axes_deg, reference_deg, home_deg, run_starts) -> np.ndarray:
    """Indices of the runs with a move into, inside or out of them that collides in transit."""
    targets = step_targets(step_kind, step_pose, axes_deg, reference_deg)
    steps, a, b = _moves(targets, np.asarray(home_deg, dtype=np.float64))
    clear = kin.sweep_clear(a, b)
    bad = steps[~clear]
    bad = bad[bad >= 0]
    runs = []
    for s in bad:
        if step_kind[s] == STEP_POSE:
            runs.append(np.searchsorted(run_starts, step_pose[s], side="right") - 1)
        else:
            # A move into a reference comes from the run before it (if there is one).
            before = step_pose[:s][step_kind[:s] == STEP_POSE]
            if before.size:
                runs.append(np.searchsorted(run_starts, before[-1], side="right") - 1)
    return np.unique(np.asarray(runs, dtype=np.int64))


def secure_branches(kin, angles, run_starts, reference_deg, axes_deg, runs) -> np.ndarray:
    """``axes_deg`` with the branches of ``runs`` chosen again with every candidate move checked."""
    axes = np.array(axes_deg, dtype=np.float64)
    if len(runs) == 0:
        return axes
    n = axes.shape[0]
    ends = np.append(run_starts[1:], n)
    idx = np.concatenate([np.arange(run_starts[r], ends[r]) for r in runs])
    lengths = np.array([ends[r] - run_starts[r] for r in runs])
    local_starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    axes[idx] = best_branches(kin, *(np.asarray(a)[idx] for a in angles), local_starts, reference_deg,
                              check_moves=True)
    return axes


def via_points(kin, targets, home_deg) -> tuple[dict[int, np.ndarray], np.ndarray, np.ndarray]:
    """Via points of the moves that need them, and the extra time they cost.

    Parameters
    ----------
    kin : Kinematics
    targets : ndarray, shape (S, n_axes)
        Step targets in degrees, NaN rows for steps that do not move.
    home_deg : array_like, shape (n_axes,)

    Returns
    -------
    via : dict of int to ndarray (k, n_axes)
        Step index -> waypoints (degrees) to pass before that step's target.
    park : ndarray, shape (K, n_axes)
        The park path from the last target home (the last row is home).
    extra_s : ndarray, shape (S + 1,)
        Seconds each move takes beyond the direct move (the last entry: the park).

    Raises
    ------
    UnsafeMoveError
        When some move has no clear path (:func:`gonio.motion.safe.safe_path`).
    """
    home = np.asarray(home_deg, dtype=np.float64)
    steps, a, b = _moves(targets, home)
    clear, margin = kin.sweep_clearance(a, b)
    metric = MoveMetric(kin.velocity_deg_s, kin.accel_deg_s2)
    extra = np.zeros(targets.shape[0] + 1)
    via: dict[int, np.ndarray] = {}
    park = home.reshape(1, -1).copy()
    for m in np.flatnonzero(~clear | (np.abs(margin) <= BORDER_DEG)):
        step = int(steps[m])
        path = park_path(kin, a[m]) if step < 0 else safe_path(kin, a[m], b[m])
        if step < 0:
            park = path
        if path.shape[0] > 1:
            extra[step] = path_time(kin, a[m], path) - float(metric.time(a[m], b[m]))
            if step >= 0:
                via[step] = path[:-1].copy()
    return via, park, extra
