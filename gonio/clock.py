"""Clocks: the wall clock for hardware, a virtual one for simulation and tests (DESIGN.md, rule 6)."""

from __future__ import annotations

import time

_INF = float("inf")


def _check_sleep(seconds: float) -> float:
    value = float(seconds)
    if not value >= 0.0 or value == float("inf"):  # also NaN
        raise ValueError(f"sleep: seconds must be a finite number >= 0, got {seconds!r}")
    return value


class WallClock:
    """The wall clock of real hardware. ``real_time``: time goes on while no process runs the gantry
    (the runner adds that downtime to the campaign clock, so a lamp's drift stays on the right scale)."""

    real_time = True

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        seconds = _check_sleep(seconds)
        if seconds > 0:
            time.sleep(seconds)

    def sleep_until(self, t: float) -> None:
        """Sleep until ``now() >= t`` (at once when that time has passed)."""
        self.sleep(max(0.0, float(t) - self.now()))


class VirtualClock:
    """A clock that only moves when told to: ``sleep`` advances it at once, nothing waits."""

    real_time = False

    def __init__(self, start: float = 0.0):
        self._t = float(start)

    def now(self) -> float:
        return self._t

    def sleep(self, seconds: float) -> None:
        self._t += _check_sleep(seconds)

    def sleep_until(self, t: float) -> None:
        """Advance to exactly ``t`` (no rounding of ``now + (t − now)``); never backwards."""
        t = float(t)
        if not t == t:  # NaN
            raise ValueError(f"sleep_until: t must be a number, got {t!r}")
        if t > self._t:
            if type(self).sleep is VirtualClock.sleep and t != _INF:
                self._t = t   # what sleep() would do, without its call (a campaign sleeps ~16 times a step)
                return
            self.sleep(t - self._t)  # through sleep(): a subclass that watches sleeps sees this one too
            self._t = t
