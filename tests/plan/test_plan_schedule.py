"""Dark and white-reference readings: at the start, after every `every` poses, and at the end."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.plan.schedule import STEP_DARK, STEP_POSE, STEP_REFERENCE, run_starts, schedule_steps


def expected(n_poses, every):
    """The schedule written out by hand: checkpoint, then runs of `every` poses each followed by one."""
    kinds, poses = [STEP_DARK, STEP_REFERENCE], [-1, -1]
    for p in range(n_poses):
        kinds.append(STEP_POSE)
        poses.append(p)
        if (p + 1) % every == 0 or p == n_poses - 1:
            kinds += [STEP_DARK, STEP_REFERENCE]
            poses += [-1, -1]
    return kinds, poses


@pytest.mark.parametrize("n_poses, every", [(0, 5), (1, 1), (1, 50), (7, 3), (9, 3), (10, 1), (120, 50)])
def test_schedule_matches_the_rule(n_poses, every):
    kind, pose = schedule_steps(n_poses, every)
    want_kind, want_pose = expected(n_poses, every)
    assert kind.tolist() == want_kind
    assert pose.tolist() == want_pose
    assert kind.dtype == np.int8 and pose.dtype == np.int64


def test_every_pose_once_in_order_and_never_two_checkpoints_in_a_row():
    kind, pose = schedule_steps(103, 10)
    assert pose[kind == STEP_POSE].tolist() == list(range(103))
    assert np.all(pose[kind != STEP_POSE] == -1)
    # A dark reading always comes right before a reference reading, and runs are at most 10 poses.
    dark = np.flatnonzero(kind == STEP_DARK)
    assert np.all(kind[dark + 1] == STEP_REFERENCE)
    assert len(dark) == 12  # start, 10 in between (after 10, 20, ..., 100), end
    gaps = np.diff(dark) - 2
    assert gaps.max() == 10 and gaps.min() == 3
    assert kind[0] == STEP_DARK and kind[-1] == STEP_REFERENCE


def test_run_starts():
    assert run_starts(7, 3).tolist() == [0, 3, 6]
    assert run_starts(6, 3).tolist() == [0, 3]


def test_bad_arguments():
    with pytest.raises(ValueError, match=r"reference.every: must be >= 1 pose between references, got 0"):
        schedule_steps(5, 0)
    with pytest.raises(ValueError, match="n_poses: must be >= 0"):
        schedule_steps(-1, 5)
