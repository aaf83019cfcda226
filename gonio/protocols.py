"""The small protocols each layer uses to talk to the one below (DESIGN.md, rule 2).

Real drivers (``gonio.drivers``) and simulated devices (``gonio.sim``) satisfy the same protocols; the
config decides which one runs. No I/O in constructors: ``connect()`` is explicit. Angles are degrees
(axis positions are device quantities at the user boundary); times are seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np


class DeviceFault(Exception):
    """A device reported a fault. ``transient`` faults (a time-out, a corrupt reply) may be retried;
    the others (a hardware error bit, an over-temperature, a limit switch) stop the campaign."""

    def __init__(self, device: str, message: str, transient: bool = False):
        super().__init__(f"{device}: {message}")
        self.device = device
        self.transient = transient


class NotReferencedFault(DeviceFault):
    """The axis's absolute position is unknown (its controller powered up since it was referenced):
    nothing moves it until ``gonio gantry reference`` has run. Not transient."""

    def __init__(self, device: str, message: str, transient: bool = False):
        super().__init__(device, message, transient=False)


@runtime_checkable
class Clock(Protocol):
    """Time source. The simulated gantry runs on a virtual clock; hardware on the wall clock."""

    def now(self) -> float: ...
    def sleep(self, seconds: float) -> None: ...
    def sleep_until(self, t: float) -> None:
        """Sleep until ``now() >= t``; a virtual clock lands on ``t`` exactly."""


@runtime_checkable
class Axis(Protocol):
    name: str
    limits_deg: tuple[float, float]

    def connect(self) -> None: ...
    def close(self) -> None: ...
    def move_to(self, target_deg: float) -> None:
        """Start a move and return at once; rejects targets outside ``limits_deg``."""
    def position_deg(self) -> float: ...
    def is_moving(self) -> bool: ...
    def stop(self) -> None:
        """Stop at once (brake at the maximum deceleration); safe to call from any thread, at rest too."""
    def fault(self) -> str | None:
        """The latched hardware fault (an error bit, an alarm), or None. A latched axis refuses moves."""
    def clear_fault(self) -> None:
        """Clear a latched fault (a reboot or alarm reset): only ever on an operator's explicit request."""


@runtime_checkable
class Referencing(Protocol):
    """An axis whose absolute position a power cycle can lose (a multi-turn servo behind a gear, an
    incremental stepper): moves are refused until it is referenced (``gonio gantry reference``)."""

    #: "none", "hard_stop", "index" or "origin" (see :mod:`gonio.reference`).
    reference_method: str

    def referenced(self) -> bool:
        """Whether its angle can be trusted now."""
    def reference_info(self) -> dict:
        """What is known of its reference, for the journal: ``referenced``, and when it was found."""


@runtime_checkable
class LightSource(Protocol):
    name: str

    def connect(self) -> None: ...
    def close(self) -> None: ...
    def set_on(self, on: bool) -> None: ...
    def is_on(self) -> bool: ...


@dataclass(frozen=True)
class Reading:
    """One detector reading: ``signal`` per channel (mean over the frames) and its standard error."""

    signal: np.ndarray
    stderr: np.ndarray
    exposure_s: float
    frames: int = 1
    extra: dict = field(default_factory=dict)


@runtime_checkable
class Detector(Protocol):
    name: str
    channels: tuple[str, ...]

    def connect(self) -> None: ...
    def close(self) -> None: ...
    def measure(self, exposure_s: float, frames: int = 1, *, key: tuple[int, int] | None = None) -> Reading:
        """Integrate ``frames`` frames of ``exposure_s`` s. ``key`` = (step, attempt) names the reading
        within its campaign: a simulated detector draws every random number of the reading from a stream
        keyed by (seed, step, attempt), so a resumed campaign replays an uninterrupted one exactly; a real
        detector may record it."""


@runtime_checkable
class Describes(Protocol):
    """A device that says what it is (an instrument: its profile and the identity it reported at
    connect), for the campaign's journal."""

    def describe(self) -> dict: ...


@runtime_checkable
class Gantry(Protocol):
    """Kinematics + axes + light + detector + clock, wired from a config."""

    name: str
    kinematics: object  # gonio.kinematics.Kinematics
    axes: dict[str, Axis]
    light: LightSource
    detector: Detector
    clock: Clock

    def connect(self) -> None: ...
    def close(self) -> None: ...
    def set_target(self, target: str) -> None:
        """Put ``"sample"`` or ``"reference"`` (the white standard) under the beam."""
    def stop(self) -> None:
        """Stop every axis at once (a halt, a fault); safe to call from any thread, mid-move too.

        Parking is not the gantry's job: the runner plans a collision-free path home
        (:func:`gonio.motion.safe.safe_path`) and moves it like any other step."""
