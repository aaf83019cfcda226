"""The state block of an X-series servo: the span of the control table one read covers (Bus Watchdog(98)
.. Present Position(132..135)), and what a read of it says of an axis. Shared by the axis, which reads its
own, and the group, which reads every servo of a bus in one Sync Read."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["BLOCK_START", "BLOCK_LEN", "READS", "AxisState"]

#: One block read covers Bus Watchdog(98) .. Present Position(132..135).
BLOCK_START, BLOCK_LEN = 98, 38
#: Reads of a position that are tried before one is called implausible (the first and fresh ones).
READS = 3


@dataclass(frozen=True)
class AxisState:
    """One axis as a read saw it: position (°), moving flag, velocity (°/s)."""

    position_deg: float
    moving: bool
    velocity_deg_s: float
