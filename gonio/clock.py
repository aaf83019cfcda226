"""Clocks: the wall clock for hardware, a virtual one for simulation and tests (DESIGN.md, rule 6)."""

from __future__ import annotations

import time


class WallClock:
    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


class VirtualClock:
    """A clock that only moves when told to: ``sleep`` advances it at once, nothing waits."""

    def __init__(self, start: float = 0.0):
        self._t = float(start)

    def now(self) -> float:
        return self._t

    def sleep(self, seconds: float) -> None:
        if seconds < 0:
            raise ValueError(f"sleep: seconds must be >= 0, got {seconds}")
        self._t += seconds
