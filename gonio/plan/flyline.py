"""One fly line: the readings of consecutive poses while one axis sweeps rest to rest between its ends
(or, in a swept turnaround, between its run-up and run-out), its time law and positions. Planned by
:mod:`gonio.plan.fly` (which says why lines look as they do), rendered by :mod:`gonio.sim.fly`, swept by
:mod:`gonio.fly.hardware`; :mod:`gonio.plan.flypath` uses its time law along a coordinated path."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FLY_DUTY", "FLY_TOL_DEG", "FlyLine"]

#: Exposure / time between readings at the axis's top speed: the axis travels this fraction of a grid
#: step during one exposure.
FLY_DUTY = 0.5
#: Degrees: two positions closer than this on an axis count as equal; steps equal within it are equal.
FLY_TOL_DEG = 1e-6


@dataclass(frozen=True)
class FlyLine:
    """One sweep: readings of the plan's poses ``poses`` while ``axis`` moves at ``speed_deg_s``.

    Attributes
    ----------
    poses : ndarray of int64, shape (n,)
        The plan's pose indices, in reading order.
    axis : int
        The sweeping axis (column of the plan's axes); -1 for a stop-and-go reading (n = 1).
    first_deg : ndarray, shape (n_axes,)
        Axis positions at the first reading's mid-time.
    step_deg : float
        Signed travel of ``axis`` from one reading to the next (0 for a stop-and-go reading).
    speed_deg_s : float
        Top speed of the sweep (0 for a stop-and-go reading).
    accel_deg_s2 : float
        The axis's acceleration from rest at the first pose and to rest at the last one.
    exposure_s : float
        Exposure of each reading.
    note : str
        Why the line was split ("" when it was not).
    """

    poses: np.ndarray
    axis: int
    first_deg: np.ndarray
    step_deg: float
    speed_deg_s: float
    accel_deg_s2: float
    exposure_s: float
    note: str = ""
    #: Travel (°) from rest before the first reading's pose (the run-up of a swept turnaround).
    lead: float = 0.0
    #: Travel (°) past the last reading's pose to rest (the run-out of a swept turnaround).
    tail: float = 0.0

    @property
    def n(self) -> int:
        return int(self.poses.size)

    @property
    def moving(self) -> bool:
        return self.axis >= 0

    @property
    def span_deg(self) -> float:
        return abs(self.step_deg) * (self.n - 1)

    def readings_deg(self) -> np.ndarray:
        """Axis positions (n, n_axes) at each reading's mid-time."""
        out = np.repeat(self.first_deg[None, :], self.n, axis=0)
        if self.moving:
            out[:, self.axis] += self.step_deg * np.arange(self.n)
        return out

    @property
    def start_deg(self) -> np.ndarray:
        """Where the axes rest before the line: its first reading's pose, ``lead`` back."""
        out = self.first_deg.copy()
        if self.moving:
            out[self.axis] -= np.sign(self.step_deg) * self.lead
        return out

    @property
    def end_deg(self) -> np.ndarray:
        """Where the axes rest after the line: its last reading's pose, ``tail`` on."""
        out = self.readings_deg()[-1].copy()
        if self.moving:
            out[self.axis] += np.sign(self.step_deg) * self.tail
        return out

    # -- the motion: a trapezoid (or triangle) from rest at start_deg to rest at end_deg ---------------
    def _profile(self) -> tuple[float, float, float, float]:
        """(travel, peak speed, acceleration time, motion time) of the rest-to-rest move."""
        d = self.lead + self.span_deg + self.tail
        a = self.accel_deg_s2
        v = min(self.speed_deg_s, float(np.sqrt(a * d)))
        t_acc = v / a
        return d, v, t_acc, 2.0 * t_acc + (d - v * t_acc) / v if v > 0 else 0.0

    def _motion_time(self, s) -> np.ndarray:
        """Time after the motion starts at which the axis has travelled ``s`` (0..travel)."""
        d, v, t_acc, total = self._profile()
        a = self.accel_deg_s2
        s = np.clip(np.asarray(s, dtype=np.float64), 0.0, d)
        d_acc = 0.5 * v * t_acc
        up = np.sqrt(2.0 * np.minimum(s, d_acc) / a)
        cruise = np.clip(s - d_acc, 0.0, d - 2 * d_acc) / v
        down_s = np.clip(s - (d - d_acc), 0.0, d_acc)
        down = t_acc - np.sqrt(np.maximum(t_acc * t_acc - 2.0 * down_s / a, 0.0))
        return up + cruise + down

    def pads(self) -> tuple[float, float]:
        """Rest before the motion and after it, so that every exposure lies in the line's time: where
        the first reading is at the line's start (no lead), its exposure starts half an exposure before
        the axis does; the same at the end."""
        if not self.moving:
            return 0.0, 0.0
        total = self._profile()[3]
        first = float(self._motion_time(self.lead))
        last = float(self._motion_time(self.lead + self.span_deg))
        half = 0.5 * self.exposure_s
        return max(0.0, half - first), max(0.0, half - (total - last))

    @property
    def duration_s(self) -> float:
        """Rest to rest: run-up, the readings, run-down (a stop-and-go reading: its exposure only)."""
        if not self.moving:
            return self.exposure_s
        front, back = self.pads()
        return front + self._profile()[3] + back

    def mid_times(self) -> np.ndarray:
        """Each reading's mid-time, seconds after the line starts (the moment the axis passes its pose)."""
        if not self.moving:
            return np.array([0.5 * self.exposure_s])
        return self.pads()[0] + self._motion_time(self.lead + abs(self.step_deg) * np.arange(self.n))

    def time_at(self, along_deg) -> np.ndarray:
        """When (s after the line starts) the sweeping axis passes ``along_deg`` (its position), on the
        planned profile; clipped to the travel."""
        s = np.sign(self.step_deg) * (np.asarray(along_deg, dtype=np.float64) - self.start_deg[self.axis])
        return self.pads()[0] + self._motion_time(s)

    def position_at(self, t_s) -> np.ndarray:
        """Axis positions (..., n_axes) at times ``t_s`` (s after the line starts): at rest, accelerate
        at ``accel_deg_s2``, cruise at ``speed_deg_s`` (where the travel is long enough), decelerate, at
        rest, as :meth:`duration_s` has it; constant outside."""
        t = np.asarray(t_s, dtype=np.float64)
        start = self.start_deg
        out = np.broadcast_to(start, t.shape + start.shape).copy()
        if not self.moving:
            return out
        d, v, t_acc, total = self._profile()
        a = self.accel_deg_s2
        tc = np.clip(t - self.pads()[0], 0.0, total)
        s = (0.5 * a * np.minimum(tc, t_acc) ** 2 + v * np.clip(tc - t_acc, 0.0, total - t_acc)
             - 0.5 * a * np.clip(tc - (total - t_acc), 0.0, t_acc) ** 2)
        out[..., self.axis] += np.sign(self.step_deg) * s
        return out
