"""A coordinated line (:class:`gonio.plan.flypath.PathLine`) as the servos fly it: straight joint-space
segments between its poses, each started by one command to every moving axis.

The path through a ring's poses is a smooth curve; servos that are given a goal and a profile move
straight in joint space when their profiles are scaled together. So the line is flown as its chords,
pose to pose: segment k goes from pose k to pose k + 1. Every moving axis i of a segment gets a speed
proportional to its travel d_i on it, ``|d_i|·ω``, ω (segments per second) common to all axes and
within every axis's limits on every segment. The first segment starts from rest with accelerations
``|d_i|·β`` (β likewise common): started together (one Sync Write,
:meth:`gonio.gantry.AssembledGantry.sweep_axes`) the axes keep the same fraction of their travel at every
instant, so the pose moves along the chord and every axis arrives together. Each later segment is
written as the axes pass its first pose (:func:`corner`): from where the axes are then (the latest
stamped read), every axis changes speed over the same ramp time and gets the speed that brings it to
the segment's end pose when the lead axis gets there, so a servo that ran a quantisation step fast or
slow makes it up on that segment instead of carrying the error on.

No stop at the poses in between: a segment's goal lies past its end pose, on the chord's extension, by
the braking distance at speed (ω²/2β segments) and half a segment more, so the servos pass the pose at
full speed and do not brake before the next segment's command, which is written as they pass it (a
goal written during a move is planned from the present velocity: the e-Manual's Velocity Override). The
last segment ends on the last pose, at rest, every axis braking over the same time. Where the extension
is not clear of collision or leaves a limit (:meth:`Kinematics.sweep_clear_one`), it is shortened
(halved, down to none: that segment then slows toward its pose); a chord that is not clear itself makes
the line unflyable on hardware (a ValueError naming it: the planner's certificate covers the curve, not
its chords). Should gonio fall silent mid-line, every servo heads for a goal whose straight sweep from
the segment's start was checked clear, and its bus watchdog stops it.

The servos quantise speeds and accelerations (a Dynamixel: 0.229 rev/min and 214.577 rev/min² steps),
so the scaling holds to a step: the positions of a reading come from the timestamped reads of every
moving axis (:mod:`gonio.fly.hardware`), never from this plan. Speeds and accelerations have floors
(``SPEED_FLOOR``, ``ACCEL_FLOOR`` of the axis's own) so an axis that barely moves on a segment is still
given a profile its driver accepts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gonio.plan.flyline import FLY_TOL_DEG

__all__ = ["Segment", "path_segments", "corner", "on_limits", "SPEED_FLOOR", "ACCEL_FLOOR"]

#: The least speed and acceleration a moving axis is given on a segment, as a share of its own.
SPEED_FLOOR, ACCEL_FLOOR = 0.02, 0.1
#: Past the braking distance, how far (segments) a goal lies beyond its end pose.
_SLACK = 0.5


def on_limits(kin, axes_deg: np.ndarray) -> np.ndarray:
    """A line's rest position with the planner's rounding at a limit taken off: the planner lets a run-up
    end within its tolerance (``FLY_TOL_DEG``, 1e-6°) beyond a limit, which a driver refuses; further
    than that is left for the driver to refuse."""
    lo, hi = np.asarray(kin.limits_deg, dtype=np.float64).T
    out = np.asarray(axes_deg, dtype=np.float64).copy()
    near = ((out < lo) & (out >= lo - FLY_TOL_DEG)) | ((out > hi) & (out <= hi + FLY_TOL_DEG))
    out[near] = np.clip(out, lo, hi)[near]
    return out


@dataclass(frozen=True)
class Segment:
    """One straight segment of a coordinated line.

    Attributes
    ----------
    start_deg, end_deg : ndarray (n_axes,)
        The poses it goes between (its chord).
    goal_deg : ndarray (n_axes,)
        Where the moving axes are sent: ``end_deg`` for the last segment, past it on the chord otherwise.
    axes : tuple of int
        The axes it commands (those that move on the line).
    speed_deg_s, accel_deg_s2 : ndarray (n_axes,)
        Each commanded axis's speed and acceleration (0 elsewhere).
    rate : float
        ω: segments per second at speed.
    """

    start_deg: np.ndarray
    end_deg: np.ndarray
    goal_deg: np.ndarray
    axes: tuple[int, ...]
    speed_deg_s: np.ndarray
    accel_deg_s2: np.ndarray
    rate: float

    @property
    def lead_axis(self) -> int:
        """The commanded axis with the longest travel (the one whose position times the segment)."""
        d = np.abs(self.end_deg - self.start_deg)[list(self.axes)]
        return self.axes[int(np.argmax(d))]

    def time_to(self, along: float, v0: float, v: float, a: float, ramp_at: float = 0.0) -> float:
        """Seconds for the lead axis to travel ``along`` (degrees from the segment's start; clamped to
        ``ramp_at``..its goal) from ``ramp_at``, where the segment was written (a host writes it late:
        the servo carries on at ``v0`` until then), ramping from speed ``v0`` to top speed ``v`` at ``a``
        toward a goal ``|goal − start|`` away (braking at the end), as its servo plans it."""
        ax = self.lead_axis
        total = abs(self.goal_deg[ax] - self.start_deg[ax]) - ramp_at
        along = min(max(along - ramp_at, 0.0), max(total, 0.0))
        t_ramp = abs(v - v0) / a
        d_ramp = (v + v0) * t_ramp / 2.0
        brake_at = total - v * v / (2.0 * a)
        if along <= d_ramp:   # on the ramp: s = v0 t ± a t²/2
            s = np.sign(v - v0) * a
            if s == 0:
                return float(along / v0)
            return float((-v0 + np.sqrt(max(v0 * v0 + 2 * s * along, 0.0))) / s)
        if along <= brake_at:
            return t_ramp + (along - d_ramp) / v
        cruise = max(brake_at - d_ramp, 0.0) / v
        return t_ramp + cruise + (v - np.sqrt(max(v * v - 2.0 * a * (along - brake_at), 0.0))) / a


def path_segments(kin, line, poses_deg: np.ndarray) -> list[Segment]:
    """The segments of coordinated line ``line`` through ``poses_deg`` (its poses' axis positions, n ×
    n_axes, as the sweeper will command them) on kinematics ``kin`` (see the module docstring).

    Raises
    ------
    ValueError
        A chord between two of its poses is not clear of collision or leaves a limit.
    """
    w = np.asarray(poses_deg, dtype=np.float64)
    moving = tuple(int(i) for i in np.flatnonzero(line.moving_axes))
    v = np.asarray(kin.velocity_deg_s, dtype=np.float64)
    a = np.asarray(kin.accel_deg_s2, dtype=np.float64)
    d = np.abs(np.diff(w, axis=0))[:, list(moving)]                        # (n − 1, m)
    vm, am = v[list(moving)], a[list(moving)]
    with np.errstate(divide="ignore"):
        omega = float(min(line.rate, np.min(vm / d)))
        beta = float(np.min(am / d))
    past = omega * omega / (2.0 * beta) + _SLACK
    out = []
    for k in range(w.shape[0] - 1):
        start, end = w[k], w[k + 1]
        ok, _margin = kin.sweep_clear_one(start, end)
        if not ok:
            raise ValueError(f"coordinated line through poses {int(line.poses[k])}.."
                             f"{int(line.poses[k + 1])}: "
                             "its chord between them is not clear of collision or leaves a limit")
        goal = end.copy()
        if k + 2 < w.shape[0]:
            extra = past
            while extra > 1e-3:
                cand = end + (end - start) * extra
                if kin.sweep_clear_one(start, cand)[0]:
                    goal = cand
                    break
                extra /= 2.0
        speed, accel = np.zeros_like(v), np.zeros_like(a)
        speed[list(moving)] = np.maximum(d[k] * omega, SPEED_FLOOR * vm)
        # From rest: scaled, so the axes leave the first pose along the chord. Later segments' are set as
        # the axes pass their first pose, from where they are then (:func:`corner`): their top ones here.
        accel[list(moving)] = np.maximum(d[k] * beta, ACCEL_FLOOR * am) if k == 0 else am
        out.append(Segment(start.copy(), end.copy(), goal, moving, speed, accel, omega))
    return out


def corner(kin, seg: Segment, now_deg: np.ndarray, was_deg_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Speeds and accelerations (n_axes,) of segment ``seg``, written as the axes pass its first pose,
    where they stand at ``now_deg`` moving at ``was_deg_s`` (signed; from the latest read, carried on at
    the speeds given them): every axis ramps to its new speed over the same time (the slowest change at
    its top acceleration), each speed such that, ramp included, every axis reaches the segment's end pose
    when the lead axis does (a servo a quantisation step fast or slow makes it up on this segment, not
    ever after); no acceleration below what keeps a servo from braking toward its goal before the next
    segment (on the last segment: before its end pose)."""
    vmax = np.asarray(kin.velocity_deg_s, dtype=np.float64)
    amax = np.asarray(kin.accel_deg_s2, dtype=np.float64)
    ax = list(seg.axes)
    sign = np.sign(seg.goal_deg - seg.start_deg)
    u0 = (np.asarray(was_deg_s, dtype=np.float64) * sign)[ax]     # toward the new goal (< 0: away)
    left = np.abs(seg.end_deg - now_deg)[ax]
    plan = seg.speed_deg_s[ax]
    lead = ax.index(seg.lead_axis)
    if np.all(seg.goal_deg == seg.end_deg):
        return _to_rest(seg, ax, u0, left, plan, lead, vmax, amax)
    v = plan
    for _ in range(4):    # the ramp time from the speeds, the speeds from the ramp time: a few rounds
        t_c = max(float(np.max(np.abs(v - u0) / amax[ax])), 1e-3)
        span = (left[lead] + (plan[lead] - u0[lead]) * t_c / 2.0) / plan[lead]
        v = np.clip((left - u0 * t_c / 2.0) / max(span - t_c / 2.0, 1e-3), SPEED_FLOOR * vmax[ax], vmax[ax])
        v[lead] = plan[lead]
    # The servo brakes toward its goal once the goal is its braking distance away: not before it passes
    # the segment's end pose, where the next segment is written.
    room = np.maximum(np.abs(seg.goal_deg - seg.end_deg)[ax], 1e-6)
    hold = 1.25 * v * v / (2.0 * room)
    a = np.clip(np.maximum(np.abs(v - u0) / t_c, hold), ACCEL_FLOOR * amax[ax], amax[ax])
    speed, accel = np.zeros_like(vmax), np.zeros_like(amax)
    speed[ax], accel[ax] = v, a
    return speed, accel


def _to_rest(seg: Segment, ax: list[int], u0, left, plan, lead: int, vmax, amax):
    """The last segment's speeds and accelerations: every axis brakes onto the last pose over the same
    time (accelerations in proportion to speeds, the one braking hardest at its top acceleration; more
    for an axis that comes in too fast to stop there), each speed such that, its ramp from ``u0``
    included, it comes to rest there when the lead axis does."""
    t_b = float(np.max(plan / amax[ax]))
    ramp = np.abs(plan - u0) * t_b / plan
    end = (left[lead] + ramp[lead] * (plan[lead] - u0[lead]) / 2.0) / plan[lead] + t_b / 2.0
    v = plan.copy()
    for _ in range(6):
        ramp = np.abs(v - u0) * t_b / v
        v = np.clip((left + ramp * (v - u0) / 2.0) / max(end - t_b / 2.0, 1e-3), SPEED_FLOOR * vmax[ax],
                    vmax[ax])
        v[lead] = plan[lead]
    # no less than what lets an axis coming in faster stop on the pose (else it would overshoot, stop
    # and come back)
    need = u0 * u0 / (1.8 * np.maximum(left, 1e-6))
    a = np.clip(np.maximum(v / t_b, need), ACCEL_FLOOR * amax[ax], amax[ax])
    speed, accel = np.zeros_like(vmax), np.zeros_like(amax)
    speed[ax], accel[ax] = v, a
    return speed, accel
