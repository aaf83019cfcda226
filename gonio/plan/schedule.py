"""The step sequence of a campaign: measurement poses interleaved with dark and white-reference readings.

A checkpoint is a dark reading (light off, where the gantry stands: no move) followed by a white
reference reading (move to the reference pose, settle, measure the white standard). Checkpoints come
at the start, after every ``every`` poses, and at the end (never twice in a row), so each run of at
most ``every`` poses is bracketed by two references: the drift between them is what the runner
interpolates, and a dark reading is never older than one run.
"""

from __future__ import annotations

import numpy as np

__all__ = ["STEP_POSE", "STEP_DARK", "STEP_REFERENCE", "STEP_NAMES", "schedule_steps", "schedule_runs",
           "run_starts", "step_table"]

STEP_POSE, STEP_DARK, STEP_REFERENCE = 0, 1, 2
STEP_NAMES = ("pose", "dark", "reference")


def schedule_steps(n_poses: int, every: int) -> tuple[np.ndarray, np.ndarray]:
    """Step kinds and pose indices of a campaign of ``n_poses`` poses in motion order.

    Parameters
    ----------
    n_poses : int
        Measurement poses, >= 0.
    every : int
        Poses between checkpoints, >= 1 (``cfg.reference.every``).

    Returns
    -------
    step_kind : ndarray of int8, shape (S,)
        ``STEP_POSE``, ``STEP_DARK`` or ``STEP_REFERENCE`` for each step.
    step_pose : ndarray of int64, shape (S,)
        Index into the poses for pose steps, -1 for the others.

    Examples
    --------
    >>> kind, pose = schedule_steps(3, 2)
    >>> kind.tolist(), pose.tolist()
    ([1, 2, 0, 0, 1, 2, 0, 1, 2], [-1, -1, 0, 1, -1, -1, 2, -1, -1])
    """
    if n_poses < 0:
        raise ValueError(f"n_poses: must be >= 0, got {n_poses}")
    if every < 1:
        raise ValueError(f"reference.every: must be >= 1 pose between references, got {every}")
    return schedule_runs(n_poses, run_starts(n_poses, every))


def schedule_runs(n_poses: int, starts) -> tuple[np.ndarray, np.ndarray]:
    """Step kinds and pose indices (as :func:`schedule_steps`) for runs beginning at ``starts``
    (sorted pose indices, 0 first; empty when there are no poses): a checkpoint before each run and
    one at the end.

    Examples
    --------
    >>> kind, pose = schedule_runs(3, [0, 1])
    >>> kind.tolist(), pose.tolist()
    ([1, 2, 0, 1, 2, 0, 0, 1, 2], [-1, -1, 0, -1, -1, 1, 2, -1, -1])
    """
    starts = np.asarray(starts, dtype=np.int64).reshape(-1)
    if n_poses and (starts.size == 0 or starts[0] != 0 or np.any(np.diff(starts) <= 0)
                    or starts[-1] >= n_poses):
        raise ValueError(f"starts: need increasing pose indices from 0 below {n_poses}, got "
                         f"{starts[:4].tolist()}...")
    checkpoints = starts.size + 1
    total = n_poses + 2 * checkpoints
    # The poses of run r sit after r + 1 checkpoints of two steps each.
    pose = np.arange(n_poses)
    run_of = np.searchsorted(starts, pose, side="right") - 1 if n_poses else pose
    pose_step = pose + 2 * (run_of + 1)
    kind = np.full(total, STEP_REFERENCE, dtype=np.int8)
    step_pose = np.full(total, -1, dtype=np.int64)
    kind[pose_step] = STEP_POSE
    step_pose[pose_step] = pose
    # The first step of every checkpoint is the dark reading.
    is_ref = kind == STEP_REFERENCE
    first = is_ref & np.concatenate([[True], kind[:-1] == STEP_POSE])
    kind[first] = STEP_DARK
    return kind, step_pose


def run_starts(n_poses: int, every: int) -> np.ndarray:
    """Indices of the poses that start a run (come right after a reference reading)."""
    return np.arange(0, n_poses, every, dtype=np.int64)


def step_table(plan, cfg) -> dict:
    """The journal's steps table of ``plan`` (a :class:`gonio.plan.build.Plan`) on the gantry ``cfg``:
    per step, planned directions and commanded axes. A dark is read where the gantry stands, so it
    inherits the previous step's targets (home before the first move)."""
    kind = plan.step_kind
    pose = plan.step_pose
    n_axes = plan.axes_deg.shape[1]
    angles = np.full((len(kind), 4), np.nan)
    axes = np.empty((len(kind), n_axes))
    last = np.array([cfg.axes[a].home_deg for a in cfg.axis_names], float)
    ref_angles = np.array([cfg.reference.theta_i_deg, 0.0, cfg.reference.theta_o_deg, cfg.reference.dphi_deg])
    pose_angles = np.degrees(np.stack([plan.theta_i, plan.phi_i, plan.theta_o, plan.phi_o], axis=1))
    for s, (k, p) in enumerate(zip(kind, pose, strict=True)):
        if k == STEP_POSE:
            last = plan.axes_deg[p]
            angles[s] = pose_angles[p]
        elif k == STEP_REFERENCE:
            last = plan.reference_axes_deg
            angles[s] = ref_angles
        axes[s] = last
    return {"kind": kind, "pose": pose, "theta_i_deg": angles[:, 0], "phi_i_deg": angles[:, 1],
            "theta_o_deg": angles[:, 2], "phi_o_deg": angles[:, 3], "axes_deg": axes}
