"""Safe motion: the waypoints that take the gantry from where it stands to a target without a collision.

Every leg between two waypoints is one move as the runner makes it (all axes start together, each on
its own trapezoid, each holds its target once there) and is certified clear by
:meth:`Kinematics.sweep_clearance <gonio.kinematics.base.Kinematics.sweep_clearance>`. The direct move
is used whenever it is clear. Otherwise these candidates are tried and the quickest clear one is taken
(ties: the first in this list):

1. some axes first, then the others (every split of the axes into two groups);
2. one axis at a time, in every order;
3. the straight line in axis space cut into k equal legs (k = 2 … 32): the axes then keep close to
   step with each other, so carriages that may not pass do not overtake;
4. detours the design offers (:meth:`Kinematics.detours`): one axis to a value where it keeps the
   parts clear whatever the others do, the others across, that axis to its target.

The result depends only on the inputs (no randomness, no state): the planner and the runner compute
the same paths.

A start read back from the axes may itself be a hair inside the forbidden zone: a pose planned exactly at
a clearance (a free azimuth stepped aside to ``arm_collision_deg``) is reached within the axes' position
tolerance, a few encoder ticks either side. Given that tolerance (``start_tol_deg``, per axis), a start
inside by at most ``start_tol_deg`` times the number of axes (each axis moves a design's margin by at most
its own travel: the rules are angles between parts these rotations carry) may be left by legs that come
no closer than it is (within the certification's ``MARGIN_TOL_DEG``); every later leg must be clear as
usual. Without it, a gantry halted there could not be moved at all, not even home.
"""

from __future__ import annotations

import math
from functools import lru_cache
from itertools import combinations, permutations

import numpy as np

from gonio.kinematics.base import DEG_TOL
from gonio.kinematics.sweep import MARGIN_TOL_DEG
from gonio.motion.metric import MoveMetric

__all__ = ["UnsafeMoveError", "safe_path", "park_path", "check_targets", "path_time", "SPLITS"]

#: Numbers of equal legs tried along the straight line.
SPLITS = (2, 3, 4, 6, 8, 12, 16, 24, 32)


class UnsafeMoveError(ValueError):
    """No collision-free path was found between two axis positions."""


def check_targets(kin, target_deg) -> np.ndarray:
    """The target(s) as float64 (n_axes,) or (N, n_axes), or a one-line ValueError naming the first
    axis out of its limits (value and limits) or not finite."""
    target = np.asarray(target_deg, dtype=np.float64)
    if target.shape[-1:] != (len(kin.axis_names),) or target.ndim not in (1, 2):
        n = len(kin.axis_names)
        raise ValueError(f"target_deg: expected shape ({n},) or (N, {n}) with columns "
                         f"{', '.join(kin.axis_names)}; got {target.shape}")
    if target.ndim == 1:
        # One target (the runner's every move, the planner's every step): plain floats, same rule.
        limits = kin.limits_deg.tolist()
        for name, (lo, hi), value in zip(kin.axis_names, limits, target.tolist(), strict=True):
            if not (math.isfinite(value) and lo - 1e-9 <= value <= hi + 1e-9):
                raise ValueError(f"axis '{name}': target {value:g}° is outside the limit [{lo:g}°, {hi:g}°]")
        return target
    rows = target.reshape(-1, target.shape[-1])
    for j, (name, (lo, hi)) in enumerate(zip(kin.axis_names, kin.limits_deg.tolist(), strict=True)):
        col = rows[:, j]
        bad = ~np.isfinite(col) | (col < lo - 1e-9) | (col > hi + 1e-9)
        if bad.any():
            value = col[np.argmax(bad)]
            raise ValueError(f"axis '{name}': target {value:g}° is outside the limit [{lo:g}°, {hi:g}°]")
    return target


def path_time(kin, start_deg, waypoints_deg) -> float:
    """Move time in s of ``start → waypoints[0] → … → waypoints[-1]`` (each leg rest to rest)."""
    pts = np.vstack([np.asarray(start_deg, dtype=np.float64).reshape(1, -1),
                     np.asarray(waypoints_deg, dtype=np.float64).reshape(-1, len(kin.axis_names))])
    metric = MoveMetric(kin.velocity_deg_s, kin.accel_deg_s2)
    return float(np.sum(metric.time(pts[:-1], pts[1:])))


def safe_path(kin, start_deg, target_deg, start_tol_deg: float = 0.0) -> np.ndarray:
    """Waypoints (K, n_axes) in degrees from ``start_deg`` to ``target_deg``, every leg clear.

    Parameters
    ----------
    kin : Kinematics
        The gantry (limits, speeds, collision rule, :meth:`sweep_clearance`).
    start_deg : array_like, shape (n_axes,)
        Where the axes stand, degrees (at rest).
    target_deg : array_like, shape (n_axes,)
        Where they must go, degrees; within the limits (:func:`check_targets`).
    start_tol_deg : float
        How far each axis of the start may be from where it was sent (the position tolerance, where the
        start is a read-back): a start that much inside the forbidden zone may be left, not approached.
        0: the start must be clear.

    Returns
    -------
    ndarray, shape (K, n_axes)
        The positions to pass at rest, in order; the last row is ``target_deg``. K = 1 when the direct
        move is clear.

    Raises
    ------
    ValueError
        When the target is outside the limits (:func:`check_targets`).
    UnsafeMoveError
        When no candidate path is clear (e.g. a carriage on the far side of the other, or a start that
        itself collides): one line naming start, target and the blocking rule.
    """
    start = [float(x) for x in np.asarray(start_deg, dtype=np.float64).reshape(-1)]
    target = check_targets(kin, target_deg).reshape(-1)
    if len(start) != target.size:
        raise ValueError(f"start_deg: expected {target.size} axes, got {len(start)}")
    clear, margin = kin.sweep_clear_one(start, target.tolist())
    if clear:
        return target.reshape(1, -1).copy()
    floor = _start_floor(kin, start, start_tol_deg)   # only a move that is not clear asks
    if floor is not None and margin >= floor and kin.within_limits(np.array([start]))[0]:
        return target.reshape(1, -1).copy()
    return _detour(kin, np.array(start), target, floor)


def park_path(kin, current_deg, start_tol_deg: float = 0.0) -> np.ndarray:
    """:func:`safe_path` from ``current_deg`` to home (``kin.home_deg``)."""
    return safe_path(kin, current_deg, kin.home_deg, start_tol_deg)


def _start_floor(kin, start: list[float], tol_deg: float) -> float | None:
    """The least margin a leg from ``start`` may keep when ``start`` is itself inside the forbidden zone
    by no more than ``tol_deg`` on each axis could make it: its own margin less the certification's slack
    (it may be left, not approached); None when the start is clear or further inside."""
    if not tol_deg > 0.0:
        return None
    here = kin.sweep_clear_one(start, start)[1]
    return here - MARGIN_TOL_DEG if -tol_deg * len(start) <= here < -DEG_TOL else None


def _detour(kin, start: np.ndarray, target: np.ndarray, floor: float | None = None) -> np.ndarray:
    paths = _candidates(kin, start, target)
    n_axes = start.size
    # Every leg of every candidate in one certified check.
    legs_from, legs_to, owner, first = [], [], [], []
    for c, path in enumerate(paths):
        pts = np.vstack([start[None, :], path])
        legs_from.append(pts[:-1])
        legs_to.append(pts[1:])
        owner.append(np.full(path.shape[0], c))
        first.append(np.arange(path.shape[0]) == 0)
    a, b, owner = np.vstack(legs_from), np.vstack(legs_to), np.concatenate(owner)
    clear, margin = kin.sweep_clearance(a, b)
    if floor is not None:  # a start a hair inside the zone: its first legs may leave it, not approach
        first = np.concatenate(first)
        clear = clear | (first & (margin >= floor) & kin.within_limits(a) & kin.within_limits(b))
    ok = np.ones(len(paths), dtype=bool)
    np.logical_and.at(ok, owner, clear)
    metric = MoveMetric(kin.velocity_deg_s, kin.accel_deg_s2)
    leg_s = metric.time(a, b)
    total = np.zeros(len(paths))
    np.add.at(total, owner, leg_s)
    # Ties within 1 ns go to the earlier candidate (fewer legs come first).
    total = np.round(np.where(ok, total, np.inf), 9)
    if not np.isfinite(total).any():
        fmt = ", ".join
        raise UnsafeMoveError(
            f"no collision-free path from [{fmt(f'{x:g}' for x in start)}]° to "
            f"[{fmt(f'{x:g}' for x in target)}]° ({', '.join(kin.axis_names)}): {kin.collision_rule}")
    best = paths[int(np.argmin(total))]
    # Drop waypoints that repeat the one before (a group of axes already at its target).
    keep = [i for i in range(best.shape[0])
            if not np.array_equal(best[i], best[i - 1] if i else start) or i == best.shape[0] - 1]
    return best[keep].reshape(-1, n_axes).copy()


def _candidates(kin, start: np.ndarray, target: np.ndarray) -> list[np.ndarray]:
    n = start.size
    paths = []
    for mask in _splits(n):
        via = np.where(mask, target, start)
        paths.append(np.vstack([via, target]))
    for order in permutations(range(n)):
        pts, here = [], start.copy()
        for j in order[:-1]:
            here = here.copy()
            here[j] = target[j]
            pts.append(here)
        paths.append(np.vstack(pts + [target]))
    for k in SPLITS:
        frac = np.arange(1, k + 1)[:, None] / k
        line = start + frac * (target - start)
        line[-1] = target
        paths.append(line)
    for j, value in kin.detours():
        first, last = start.copy(), target.copy()
        first[j] = value
        last[j] = value
        paths.append(np.vstack([first, last, target]))
    return paths


@lru_cache(maxsize=8)
def _splits(n: int) -> tuple[np.ndarray, ...]:
    """Masks of the axes moved in the first of two legs: every nonempty proper subset, small first."""
    return tuple(np.isin(np.arange(n), group)
                 for size in range(1, n) for group in combinations(range(n), size))
