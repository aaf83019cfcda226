"""The small protocols each layer uses to talk to the one below (DESIGN.md, rule 2).

Real drivers (``gonio.drivers``) and simulated devices (``gonio.sim``) satisfy the same protocols; the
config decides which one runs. No I/O in constructors: ``connect()`` is explicit. Angles are degrees
(axis positions are device quantities at the user boundary); times are seconds.

Beside the protocols every device satisfies (:class:`Axis`, :class:`LightSource`, :class:`Detector`,
:class:`Gantry`, :class:`Clock`), a device *declares* what else it can do by satisfying an ability
protocol (as ophyd-async's ``Movable``, ``Flyable``): a servo that sweeps at a set velocity
(:class:`Flyable`), a detector that reads while the axes move (:class:`ReadsOnTheFly`), a gantry that
moves and reads its axes in batches (:class:`BatchedAxes`). Core code asks for an ability once, where
the gantry is assembled (:func:`gonio.gantry.abilities`, :class:`gonio.gantry.AssembledGantry`), with
``isinstance`` against these runtime-checkable protocols, never with ``getattr``/``hasattr`` or a
driver's class.
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
    """Time source. The simulated gantry runs on a virtual clock; hardware on the wall clock.

    ``real_time``: time goes on while no process runs the gantry (the wall clock): the engine adds that
    downtime to the campaign clock, so a lamp's drift stays on the right scale."""

    real_time: bool

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
    """A device that says what it is, for the campaign's journal (:func:`gonio.campaign.journal_devices`):
    ``name``, ``driver``, its identity (a servo's model and firmware, an instrument's ``*IDN?`` reply,
    read at connect), ``units`` and the settings it runs with."""

    def describe(self) -> dict: ...


@runtime_checkable
class Gantry(Protocol):
    """Kinematics + axes + light + detector + clock, wired from a config. ``all_axes``: the kinematics'
    axes and any other (a sample changer's), by name."""

    name: str
    kinematics: object  # gonio.kinematics.Kinematics
    axes: dict[str, Axis]
    all_axes: dict[str, Axis]
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


# -- abilities of axes ------------------------------------------------------------------------------------
@runtime_checkable
class ChecksTarget(Protocol):
    """An axis that checks a target without moving (limits, a latched fault, its reference), so a gantry
    refuses a batch of moves before any axis is commanded."""

    def check_target(self, target_deg: float) -> object:
        """The target in device units; raises ValueError (beyond a limit) or DeviceFault."""


@runtime_checkable
class Flyable(Protocol):
    """An axis that sweeps to a target at a velocity and acceleration set per move (a fly sweep), in the
    manner of ophyd-async's flyers: :meth:`prepare`, :meth:`kickoff`, :meth:`complete`."""

    def prepare(self, velocity_deg_s: float, accel_deg_s2: float) -> tuple[float, float]:
        """Check the sweep's profile (nothing written); the (velocity, acceleration) it will run at, as
        the device quantises them. ValueError outside what it can be given."""
    def kickoff(self, target_deg: float) -> None:
        """Start the prepared sweep toward ``target_deg``; returns at once."""
    def complete(self) -> None:
        """After the sweep: the campaign's own profile back (nothing when it was not replaced)."""


@runtime_checkable
class ReadsState(Protocol):
    """An axis whose position and moving flag come from one transaction (``state_in_one_read``) or two."""

    state_in_one_read: bool

    def read_state(self) -> tuple[float, bool]: ...


@runtime_checkable
class SharesConnection(Protocol):
    """An axis reached through a connection other axes may share (a Modbus client: one transaction at a
    time), so a gantry asks the axes of one connection in turn."""

    client: object


@runtime_checkable
class TimesRoundTrip(Protocol):
    """An axis that knows the shortest round trip of its link (s; None before the first)."""

    round_trip_s: float | None


@runtime_checkable
class Warns(Protocol):
    """A device that reports conditions it does not act on (a servo's low input voltage, a detector's
    stream running off its configured rate)."""

    def warnings(self) -> list[str]:
        """The warnings seen since the last call."""


@runtime_checkable
class CountsLink(Protocol):
    """An axis that counts what its link could not trust (``link``, ``discarded``, ``failed``,
    ``implausible``)."""

    def link_stats(self) -> dict: ...


@runtime_checkable
class HoldsAtGoal(Protocol):
    """An axis stopped by a goal at its present position (a servo): the goal is read first, so the
    gantry can check it before it is written."""

    def stop_goal(self): ...
    def hold(self, goal) -> None: ...


@runtime_checkable
class AxisGroup(Protocol):
    """Axes of one bus moved and read in one transaction each (a Dynamixel Sync Write / Sync Read)."""

    axes: dict
    armed: bool
    #: The shortest bus watchdog of its axes (s), or None without one.
    watchdog_s: float | None

    def move_to(self, targets) -> None: ...
    def read(self) -> dict: ...
    def read_stamped(self, clock) -> tuple[float, dict]: ...
    def stop_goals(self) -> dict: ...
    def write_goals(self, goals) -> None: ...


@runtime_checkable
class JoinsGroup(Protocol):
    """An axis moved and read with the others of its bus as one :class:`AxisGroup`."""

    def group_key(self) -> object:
        """Axes with equal keys share a bus (one group)."""
    def make_group(self, axes: list) -> AxisGroup:
        """The group of ``axes`` (this one among them, all of one key)."""


@runtime_checkable
class StartsTogether(Protocol):
    """An axis whose moves start with the others of its start group's on one start (a Modbus
    controller's held move and trigger), each axis still read and stopped on its own."""

    def start_key(self) -> object | None:
        """Axes with equal keys start together (one group); None: this axis moves alone."""
    def make_start_group(self, axes: list):
        """The start group of ``axes`` (this one among them, all of one key): an object with
        ``axes`` (by name) and ``move_to(targets)`` (every target checked before any is written;
        every start read back, a failed one named and the others stopped); None where there is
        nothing to start together (one axis)."""


@runtime_checkable
class ReportsDeviceUnits(Protocol):
    """An axis with positions in device units (servo ticks, motor steps), for a manual report."""

    def device_units(self) -> dict:
        """``units`` (its name), ``target_units``, ``position_units`` and ``target_deg``."""


@runtime_checkable
class ReferencesIndex(Protocol):
    """Referencing at an index: the axis stands at a known angle within half a turn."""

    def reference_index(self, reference_deg: float) -> float: ...


@runtime_checkable
class SeeksStop(Protocol):
    """Referencing on a hard stop: a slow approach until it stalls there."""

    def seek_start(self, toward: int, velocity_deg_s: float, accel_deg_s2: float, current_a: float,
                   travel_deg: float): ...
    def seek_state(self): ...
    def seek_end(self, reference_deg: float) -> float: ...
    def seek_abort(self) -> None: ...


@runtime_checkable
class ReferencesOrigin(Protocol):
    """Referencing by the controller's own return-to-origin operation."""

    def reference_origin(self, timeout_s: float, poll_s: float) -> None: ...


@runtime_checkable
class Follows(Protocol):
    """An axis that can move along a seeking one, its position unknown (a servo on a shared ring)."""

    def follow_start(self, toward: int, velocity_deg_s: float, accel_deg_s2: float, travel_deg: float): ...
    def follow_stop(self): ...
    def seek_state(self): ...


# -- abilities of detectors -------------------------------------------------------------------------------
@runtime_checkable
class SwitchesTarget(Protocol):
    """A detector that renders the white standard itself (a simulated one): told what is under the beam,
    no changer axis needed."""

    def set_target(self, target: str) -> None: ...


@runtime_checkable
class ReadsOnTheFly(Protocol):
    """A detector that reads while the axes sweep: a reading integrates from its request for the
    exposure asked (a photodiode, a power meter, a spectrometer read on request; not a camera's frame)."""

    def read_on_the_fly(self, exposure_s: float, *, key: tuple[int, int] | None = None) -> Reading:
        """One frame of ``exposure_s`` s, keyed as :meth:`Detector.measure`."""


@runtime_checkable
class ReadsInBatches(Protocol):
    """A detector whose readings can be taken now and computed later, many at once (a simulated one: a
    chunk of poses rendered in one kernel launch). A stop-and-go campaign then takes a chunk of steps
    before developing and committing them (:func:`gonio.units.stop_and_go_units`)."""

    def batch_readings(self) -> int:
        """How many readings are worth developing together (1: nothing is gained; read one at a time)."""
    def take(self, exposure_s: float, frames: int = 1, *, key: tuple[int, int] | None = None) -> object:
        """What :meth:`Detector.measure` would read now, keyed alike, to be developed later; the clock
        advances as ``measure``'s does."""
    def develop(self, takes: list) -> list[Reading]:
        """The readings of ``takes``, in order, each bit for bit what ``measure`` would have returned."""


@dataclass(frozen=True)
class StreamSamples:
    """What a streaming detector sent since its stream started, each sample stamped on the gantry clock.

    ``index`` (K,): the instrument's sample counter (from 0 at the start, consecutive unless lines were
    lost); ``t_end_s`` (K,): when each sample's integration ended (gantry clock, s), so sample k covers
    ``[t_end_s[k] - period_s, t_end_s[k]]``; ``values`` (K, C); ``period_s``: the sample period as
    measured on the gantry clock; ``missing``: the index ranges ``[a, b)`` never received (dropped,
    garbled or overflowed lines), which no reading may span; ``combine``: ``"sum"`` (a sample is
    integrated over its period) or ``"mean"`` (a rate); ``warnings``: what the stream's timing check
    found (a rate off the configured one)."""

    index: np.ndarray
    t_end_s: np.ndarray
    values: np.ndarray
    period_s: float
    missing: tuple[tuple[int, int], ...] = ()
    combine: str = "sum"
    warnings: tuple[str, ...] = ()


@runtime_checkable
class Streams(Protocol):
    """A detector that sends samples on its own at a set rate (a photodiode or power meter in a
    continuous mode), read by a background reader that stamps them on the gantry clock: readings taken
    from it while the axes sweep have no dead time between them (:mod:`gonio.fly.hardware`)."""

    def start_stream(self) -> float:
        """Start the stream; returns its configured sample period (s)."""
    def read_stream(self) -> StreamSamples:
        """Every sample received since :meth:`start_stream`, stamped (raises DeviceFault where the
        reader lost its port)."""
    def stop_stream(self) -> None:
        """Stop the stream (the instrument answers requests again); safe when it is not running."""


# -- abilities of gantries --------------------------------------------------------------------------------
@runtime_checkable
class BatchedAxes(Protocol):
    """A gantry that moves and reads the kinematics' axes in batches (one transaction per bus)."""

    def positions(self) -> np.ndarray: ...
    def move_axes(self, targets) -> None:
        """Start moving the named axes (name -> °); every target is checked before any is commanded."""
    def poll_axes(self) -> tuple[np.ndarray | None, bool]:
        """One look while waiting for a move: (positions, False) once every axis is still, else
        (None, True)."""


@runtime_checkable
class KeepsAlive(Protocol):
    """A gantry whose axes must hear from gonio while they move (an armed bus watchdog): ``keep_alive``
    between slices of a wait, ``feed_s`` the longest quiet spell allowed (None: no watchdog)."""

    feed_s: float | None

    def keep_alive(self) -> None: ...


@runtime_checkable
class FliesAxes(Protocol):
    """A gantry that sweeps its :class:`Flyable` axes and reads them stamped on its clock (fly scanning
    on hardware: :mod:`gonio.fly.hardware`)."""

    def can_sweep(self, name: str) -> bool: ...
    def sweep(self, name: str, target_deg: float, velocity_deg_s: float,
              accel_deg_s2: float) -> tuple[float, float]: ...
    def sweep_axes(self, sweeps) -> dict[str, tuple[float, float]]: ...
    def end_sweep(self, name: str) -> None: ...
    def stamped_positions(self) -> tuple[np.ndarray, np.ndarray]: ...


@runtime_checkable
class RendersFly(Protocol):
    """A gantry that renders a fly campaign's readings itself, nothing moving (the simulated gantry:
    :mod:`gonio.sim.fly`)."""

    def fly_refusal(self) -> str | None:
        """Why it cannot render a fly campaign (one line naming the setting), or None."""
    def fly_readings(self, fp, item) -> list:
        """The measurements of one entry of :func:`gonio.plan.fly.fly_steps` of the fly plan ``fp``."""


@runtime_checkable
class ReportsWarnings(Protocol):
    """A gantry that collects its devices' hardware warnings (the engine journals them)."""

    def drain_warnings(self) -> list[tuple[str, str]]: ...


@runtime_checkable
class ReportsLink(Protocol):
    """A gantry that says in one line what its drivers could not trust (the engine journals it)."""

    def link_report(self) -> str | None: ...


def detector_descriptor(kind: str, channels, wavelengths_nm=None, shape=None, units: str = "signal") -> dict:
    """What a reading of a detector is, as the journal's meta ``detector`` keeps it.

    Parameters
    ----------
    kind : str
        ``photodiode``, ``spectrometer``, ``camera``, or a real driver's kind.
    channels : sequence of str
        Channel names (R, G, B; or one per band).
    wavelengths_nm : sequence of float, optional
        Centre wavelength of each channel (nm), for spectral channels; None otherwise.
    shape : sequence of int, optional
        The shape of each reading's signal; default ``[len(channels)]``.
    units : str
        Of the signal (``signal``: the detector's own linear units, dark not subtracted).
    """
    channels = [str(c) for c in channels]
    wl = None if wavelengths_nm is None else [float(w) for w in wavelengths_nm]
    if wl is not None and len(wl) != len(channels):
        raise ValueError(f"wavelengths_nm: {len(wl)} for {len(channels)} channels")
    return {"kind": str(kind), "channels": channels, "wavelengths_nm": wl,
            "shape": [len(channels)] if shape is None else [int(n) for n in shape], "dtype": "float64",
            "units": units}
