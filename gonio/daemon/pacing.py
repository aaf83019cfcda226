"""A virtual clock that can also spend real time: the daemon's simulated gantry at a watchable pace.

A simulated campaign runs thousands of poses per second of wall time, too fast for anyone watching the
web view. :class:`PacedClock` is a :class:`gonio.clock.VirtualClock` whose every sleep also waits
``pace`` real seconds per gantry second. The virtual time it keeps is exactly the virtual clock's, so a
paced campaign measures bit for bit what an unpaced one does; ``pace=0`` is the virtual clock itself.
The runner waits in slices of ``runner.poll_s``, so a halt still acts within ``pace * poll_s`` seconds.
"""

from __future__ import annotations

import time

from gonio.clock import VirtualClock

__all__ = ["PacedClock", "check_pace"]


def check_pace(pace: float) -> float:
    """``pace`` as a float, or a ValueError naming the allowed range."""
    value = float(pace)
    if not 0.0 <= value <= 10.0:
        raise ValueError(f"--pace: must be within [0, 10] real seconds per gantry second, got {pace!r}")
    return value


class PacedClock(VirtualClock):
    """A virtual clock whose sleeps also wait ``pace`` real seconds per gantry second.

    Parameters
    ----------
    start : float
        Gantry seconds at the start (a resumed campaign's clock).
    pace : float
        Real seconds per gantry second, in [0, 10]; 0 spends no real time.

    Examples
    --------
    >>> c = PacedClock(5.0, pace=0.0)
    >>> c.sleep(2.5)
    >>> c.now()
    7.5
    """

    def __init__(self, start: float = 0.0, pace: float = 0.0):
        super().__init__(start)
        self.pace = check_pace(pace)

    def sleep(self, seconds: float) -> None:
        if self.pace > 0.0 and seconds > 0.0:
            time.sleep(float(seconds) * self.pace)
        super().sleep(seconds)
