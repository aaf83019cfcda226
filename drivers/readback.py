"""Position read-backs checked for plausibility: what an axis can have travelled since its last good one.

A reply that was paired with the wrong request (a late status packet of the same length, a stale frame
an RTU line delivered after its time-out) decodes into a position that is real but old, or not a
position at all. Taken as where the axis stands, it would start a path from the wrong place or become a
stop's goal. Every position a driver reads is therefore held against the last one it accepted: between
the two instants (on the gantry clock) the axis can have moved at most what its top speed and
acceleration allow, starting from the speed it had then::

    travel <= min(v_max * dt, |v0| * dt + a_max * dt**2 / 2) * margin + slack

A read beyond that is implausible: the driver reads again (a fresh transaction), and when that one is
implausible too, raises a transient fault; it never uses it. Once a read is accepted it becomes the
reference for the next.

``margin`` covers a servo that runs a little faster than its profile (and a host clock stamping a read a
transaction late); ``slack`` covers encoder noise and the resolution of the reads.
"""

from __future__ import annotations

import math

__all__ = ["PlausibilityGuard"]


class PlausibilityGuard:
    """The last good position of one axis and the travel it bounds.

    Parameters
    ----------
    name : str
        Axis name (in messages).
    velocity_deg_s, accel_deg_s2 : float
        Top speed (°/s) and acceleration (°/s²) the axis can reach (the profile the driver writes, or
        the largest it ever writes).
    clock : Clock
        Time source of the stamps (the gantry's).
    slack_deg : float
        Travel always allowed (°): encoder noise, rounding.
    margin : float
        Factor on the kinematic bound (>= 1).
    """

    def __init__(self, name: str, velocity_deg_s: float, accel_deg_s2: float, clock, *,
                 slack_deg: float = 0.05, margin: float = 1.25):
        if not (velocity_deg_s > 0 and accel_deg_s2 > 0 and math.isfinite(velocity_deg_s)
                and math.isfinite(accel_deg_s2)):
            raise ValueError(f"axis '{name}': plausibility needs a finite speed and acceleration > 0")
        self.name = name
        self.velocity_deg_s = float(velocity_deg_s)
        self.accel_deg_s2 = float(accel_deg_s2)
        self.clock = clock
        self.slack_deg = float(slack_deg)
        self.margin = float(margin)
        #: (position °, clock s, speed °/s or None) of the last accepted read, or None.
        self.last: tuple[float, float, float | None] | None = None
        #: Reads found implausible so far.
        self.rejected = 0

    def raise_limits(self, velocity_deg_s: float, accel_deg_s2: float) -> None:
        """The axis may now run this fast (a sweep's profile): the bound grows, never shrinks."""
        self.velocity_deg_s = max(self.velocity_deg_s, float(velocity_deg_s))
        self.accel_deg_s2 = max(self.accel_deg_s2, float(accel_deg_s2))

    def reset(self) -> None:
        """Forget the last good read (after a reference moved the axis's frame)."""
        self.last = None

    def reach_deg(self, dt_s: float, speed_deg_s: float | None = None) -> float:
        """The farthest (°) the axis can travel in ``dt_s`` s starting at ``speed_deg_s`` (None:
        unknown, so any speed up to the top)."""
        dt = max(float(dt_s), 0.0)
        v, a = self.velocity_deg_s, self.accel_deg_s2
        travel = v * dt
        if speed_deg_s is not None:
            travel = min(travel, abs(speed_deg_s) * dt + 0.5 * a * dt * dt)
        return travel * self.margin + self.slack_deg

    @property
    def brake_deg(self) -> float:
        """The braking distance (°) from the top speed at the acceleration."""
        return self.velocity_deg_s ** 2 / (2.0 * self.accel_deg_s2)

    def plausible(self, position_deg: float, t: float | None = None) -> bool:
        """Whether ``position_deg`` read at ``t`` (default: now) is within reach of the last good read
        (always, before the first)."""
        if not math.isfinite(position_deg):
            return False
        if self.last is None:
            return True
        p0, t0, v0 = self.last
        t = self.clock.now() if t is None else t
        return abs(position_deg - p0) <= self.reach_deg(t - t0, v0)

    def accept(self, position_deg: float, t: float | None = None, speed_deg_s: float | None = None) -> None:
        """Make this read the reference for the next."""
        self.last = (float(position_deg), self.clock.now() if t is None else float(t),
                     None if speed_deg_s is None else float(speed_deg_s))

    def describe(self, position_deg: float, t: float | None = None) -> str:
        """Why ``position_deg`` is implausible, in one clause."""
        p0, t0, v0 = self.last
        t = self.clock.now() if t is None else t
        return (f"read {position_deg:.3f}° but {t - t0:.3f} s after it read {p0:.3f}° it can have travelled "
                f"at most {self.reach_deg(t - t0, v0):.3f}° (top speed {self.velocity_deg_s:g}°/s, "
                f"acceleration {self.accel_deg_s2:g}°/s²)")
