"""The X-series profile generator, as the e-Manual describes it: where an emulated servo's shaft is between
two goals.

A goal written to Goal Position(116) makes the servo plan a velocity trajectory *from its present
velocity* (the e-Manual's "Velocity Override": a goal written while the servo moves toward an earlier one
re-plans from where it is and how fast it goes, velocity continuous); Profile Velocity(112) and Profile
Acceleration(108) written together with the goal are the ones it uses. Drive Mode(10) bit 2 picks how the
two are read:

- velocity-based (bit 2 = 0): Profile Velocity is the top speed (0.229 rev/min units; 0: no limit, here
  the Velocity Limit), Profile Acceleration the acceleration (214.577 rev/min² units; 0: infinite, a
  rectangular profile). From a velocity toward the goal the servo speeds up (or slows down) to the top
  speed, cruises and brakes to rest on the goal; moving away from the goal, or too fast to stop on it, it
  brakes to rest first and plans again from there;
- time-based (bit 2 = 1): Profile Velocity is the whole move's time t3 (ms) and Profile Acceleration the
  ramp time t1 (ms), clipped to half of t3 ("Profile Acceleration will not exceed 50 % of Profile
  Velocity"). The e-Manual gives the trajectory from rest (ramp up for t1, cruise, ramp down for t1, at
  the goal at t3); from a present velocity v0 the ramp goes from v0, so the peak speed is the one that
  covers the distance in t3: ``vp = (goal − x0 − v0·t1/2) / (t3 − t1)``. Every servo given the same t1
  and t3 arrives at once, whatever its distance: what a coordinated move needs.

Jerk control (the e-Manual's note that the real trajectory may take a little longer than t3) is not
modelled. Positions are in ticks, times in seconds.

References
----------
ROBOTIS e-Manual, X-series control table: "Drive Mode(10)", "Profile Acceleration(108)", "Profile
Velocity(112)" (What is the Profile; Velocity Override), "Goal Position(116)".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["Trajectory", "velocity_based", "time_based"]

#: The acceleration (ticks/s²) of a rectangular profile (Profile Acceleration 0: "infinite").
INFINITE_ACCEL = 1e9


@dataclass(frozen=True)
class Trajectory:
    """Pieces of constant acceleration from ``t0``: each (duration s, start position, start velocity,
    acceleration); before ``t0`` the shaft rests at ``start``, after the last piece on ``goal`` (exactly:
    where the pieces end, bar rounding)."""

    t0: float
    start: float
    pieces: tuple[tuple[float, float, float, float], ...] = ()
    goal: float | None = None

    @property
    def duration(self) -> float:
        return sum(p[0] for p in self.pieces)

    @property
    def end(self) -> float:
        if not self.pieces:
            return self.start
        if self.goal is not None:
            return self.goal
        d, x, v, a = self.pieces[-1]
        return x + v * d + 0.5 * a * d * d

    def _piece(self, t: float):
        tau = t - self.t0
        if tau < 0.0 or not self.pieces:
            return None, 0.0
        for p in self.pieces:
            if tau <= p[0]:
                return p, tau
            tau -= p[0]
        return None, math.inf

    def position(self, t: float) -> float:
        p, tau = self._piece(t)
        if p is None:
            return self.start if tau == 0.0 else self.end
        _d, x, v, a = p
        return x + v * tau + 0.5 * a * tau * tau

    def velocity(self, t: float) -> float:
        p, tau = self._piece(t)
        if p is None:
            return 0.0
        return p[2] + p[3] * tau

    def moving(self, t: float) -> bool:
        return bool(self.pieces) and t - self.t0 < self.duration


def _chain(t0: float, x0: float, parts: list[tuple[float, float, float]], goal: float) -> Trajectory:
    """A trajectory from (duration, start velocity, acceleration) parts laid end to end, to ``goal``."""
    pieces, x = [], x0
    for d, v, a in parts:
        if d > 0.0:
            pieces.append((d, x, v, a))
            x += v * d + 0.5 * a * d * d
    return Trajectory(t0, x0, tuple(pieces), goal)


def velocity_based(t0: float, x0: float, v0: float, goal: float, v_max: float, a_max: float) -> Trajectory:
    """The velocity-based profile from (``x0``, ``v0``) at ``t0`` to rest on ``goal``, top speed ``v_max``
    (ticks/s), acceleration ``a_max`` (ticks/s²)."""
    a = a_max if a_max > 0.0 else INFINITE_ACCEL
    start, x, v = x0, x0, v0
    parts: list[tuple[float, float, float]] = []
    if v != 0.0 and (v * (goal - x) <= 0.0 or v * v / (2.0 * a) > abs(goal - x) + 1e-9):
        # Moving away from the goal, or too fast to stop on it: brake to rest, then plan from there.
        brake = abs(v) / a
        parts.append((brake, v, -math.copysign(a, v)))
        x, v = x + v * brake / 2.0, 0.0
    delta = goal - x
    if delta != 0.0:
        s = math.copysign(1.0, delta)
        d, u0 = abs(delta), abs(v)
        vp = min(v_max, math.sqrt(a * d + 0.5 * u0 * u0))
        t_ramp = abs(vp - u0) / a
        d_ramp = (vp + u0) * t_ramp / 2.0
        t_brake = vp / a
        cruise = max(0.0, d - d_ramp - vp * t_brake / 2.0) / vp
        parts += [(t_ramp, s * u0, s * (a if vp >= u0 else -a)), (cruise, s * vp, 0.0),
                  (t_brake, s * vp, -s * a)]
    return _chain(t0, start, parts, goal)


def time_based(t0: float, x0: float, v0: float, goal: float, t3: float, t1: float) -> Trajectory:
    """The time-based profile from (``x0``, ``v0``) at ``t0`` to rest on ``goal`` ``t3`` s later, ramps of
    ``t1`` s (clipped to ``t3 / 2``; 0: a rectangular profile)."""
    t1 = min(t1, 0.5 * t3)
    if t3 <= 0.0:
        return Trajectory(t0, goal)
    if t1 <= 0.0:
        return _chain(t0, x0, [(t3, (goal - x0) / t3, 0.0)], goal)
    vp = (goal - x0 - 0.5 * v0 * t1) / (t3 - t1)
    return _chain(t0, x0, [(t1, v0, (vp - v0) / t1), (t3 - 2.0 * t1, vp, 0.0), (t1, vp, -vp / t1)], goal)
