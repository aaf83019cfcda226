"""Units and their sources: what the engine measures and commits whole, chosen by the campaign's kind.

A :class:`Unit` is one stop-and-go step, or a fly campaign's sweep or checkpoint: measured, then
committed in one journal transaction, so that a crash loses at most the unit in flight. A *unit source*
turns a campaign into its units; which one runs is the campaign's **kind**, recorded in its journal when
it is created (:data:`KINDS`):

``stop-and-go``
    One unit per step (:func:`stop_and_go_units`): move, settle, read (:class:`StepReader`); where the
    detector takes readings to develop them later in batches (:class:`~gonio.protocols.ReadsInBatches`:
    a simulated one renders a chunk of poses in one launch), one unit per chunk of steps, each step
    moved to, settled and taken in turn, the chunk developed and committed in one transaction. The
    readings are those of one unit per step, bit for bit (each is keyed by its step and attempt); a
    chunk ends early where an operator's request waits (it acts before the next step, as between
    steps), and a fault at one of its steps commits the steps before it first (:class:`Cut`), so
    retries, faults and their journal are those of one unit per step.
``fly``
    One unit per checkpoint and per line of the fly plan (:func:`gonio.fly.units.fly_units`): swept on
    a gantry whose axes fly (:class:`gonio.fly.hardware.FlySweeper`), or rendered by a gantry that
    renders fly readings itself (the simulated gantry).
``adaptive``
    The pilot's steps, then each round's, planned from the journal once the steps before it are
    measured and appended to it in one transaction (:func:`gonio.adaptive.units.adaptive_units`): the
    engine asks a source for its units lazily, one at a time, so a source may plan the next unit from
    the journal.

A source is ``source(engine) -> Iterable[Unit]`` (``engine``: the :class:`gonio.runner.Runner` that runs
them: its gantry, journal, config, :class:`~gonio.executor.MotionExecutor`, :class:`StepReader` and
campaign clock); the engine skips the units whose first step the journal holds already.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from importlib import import_module
from typing import TYPE_CHECKING

import numpy as np

from gonio.executor import Halted
from gonio.plan.schedule import STEP_DARK, STEP_REFERENCE
from gonio.protocols import DeviceFault, Gantry, Reading, ReadsInBatches
from gonio.store import Measurement

if TYPE_CHECKING:
    from gonio.config import DetectorConfig
    from gonio.executor import MotionExecutor

__all__ = ["Unit", "Cut", "StepReader", "stop_and_go_units", "unit_source", "KINDS", "STOP_AND_GO", "FLY",
           "ADAPTIVE"]

STOP_AND_GO, FLY, ADAPTIVE = "stop-and-go", "fly", "adaptive"
#: A chunk of stop-and-go steps (a detector that reads in batches) ends once it spans this much gantry
#: time (s): a paced simulation (the daemon's) commits at least this often (1.2 s of wall time at its
#: default pace), and a crash redoes no more.
CHUNK_SPAN_S = 60.0
#: Campaign kind -> its unit source, "module:function" (imported when a campaign of that kind runs).
KINDS = {STOP_AND_GO: "gonio.units:stop_and_go_units", FLY: "gonio.fly.units:fly_units",
         ADAPTIVE: "gonio.adaptive.units:adaptive_units"}


@dataclass(frozen=True)
class Unit:
    """What the engine measures and commits whole: one step (stop-and-go), or a fly campaign's sweep or
    checkpoint, committed in one transaction so that a crash loses at most the unit in flight.

    Attributes
    ----------
    first, count : int
        Its steps: ``first`` .. ``first + count - 1``.
    measure : callable
        ``measure(attempt) -> list[Measurement]`` (attempt from 1), one per step in order; may raise a
        :class:`~gonio.protocols.DeviceFault` (transient ones are retried after the axes are still).
    """

    first: int
    count: int
    measure: Callable[[int], list[Measurement]]


class Cut(Exception):
    """A unit of several steps that failed part-way (raised by its ``measure``): ``done`` are the
    measurements of the steps before the failing one, whole and to be committed; ``fault`` is the
    failing step's exception; ``rest`` the unit of the steps from the failing one on, whose attempt 1
    was the one that failed."""

    def __init__(self, done: list[Measurement], fault: Exception, rest: Unit):
        super().__init__(str(fault))
        self.done = done
        self.fault = fault
        self.rest = rest


@dataclass(frozen=True, slots=True)
class _Taken:
    """A step read up to its reading: where and when, and what the detector returned (a Reading, or a
    take to develop)."""

    step: int
    kind: int
    pose: int
    commanded: np.ndarray
    actual: np.ndarray
    clock_s: float
    campaign_s: float
    attempt: int
    reading: object

    def measurement(self, reading: Reading, angles: np.ndarray) -> Measurement:
        """Its measurement, with ``reading`` and the directions ``angles`` (θi, φi, θo, φo in degrees) of
        its actual positions (:func:`_angles`)."""
        return Measurement(
            step=self.step, kind=self.kind, pose=self.pose, commanded_deg=self.commanded,
            actual_deg=self.actual, angles_deg=angles, clock_s=self.clock_s, campaign_s=self.campaign_s,
            exposure_s=reading.exposure_s, frames=reading.frames, signal=reading.signal,
            stderr=reading.stderr, attempts=self.attempt, extra=reading.extra)


def unit_source(kind: str) -> Callable:
    """The unit source of campaign kind ``kind`` (:data:`KINDS`); ValueError naming the kinds known."""
    where = KINDS.get(kind)
    if where is None:
        raise ValueError(f"kind: {kind!r} is not a campaign kind this gonio runs; known: {', '.join(KINDS)}")
    module, name = where.split(":")
    return getattr(import_module(module), name)


class StepReader:
    """A stop-and-go reading of one journaled step: a dark where the gantry stands (the light off), a
    white reference or a pose after moving there (:meth:`MotionExecutor.goto`) and settling.

    Parameters
    ----------
    gantry : Gantry
        Its light, detector and target.
    executor : MotionExecutor
        Moves, settles and reads the positions.
    steps : dict
        The journal's steps table (:meth:`gonio.store.Journal.steps`).
    detector : DetectorConfig
        ``exposure_s`` and ``frames`` of a reading.
    campaign_s : callable
        The campaign clock now (s).
    """

    def __init__(self, gantry: Gantry, executor: MotionExecutor, steps: dict, detector: DetectorConfig,
                 campaign_s: Callable[[], float]):
        self.gantry = gantry
        self.executor = executor
        self.steps = steps
        self.detector = detector
        self.campaign_s = campaign_s

    def read(self, step: int, attempt: int) -> Measurement:
        """The reading of ``step`` (attempt from 1); a DeviceFault where a device failed (transient ones
        are retried by the engine)."""
        taken = self._take(step, attempt, self.gantry.detector.measure)
        return taken.measurement(taken.reading, _angles(self.executor.kinematics, [taken])[0])

    def take(self, step: int, attempt: int, detector: ReadsInBatches) -> _Taken:
        """:meth:`read` up to the reading, which ``detector`` takes to develop later."""
        return self._take(step, attempt, detector.take)

    def _take(self, step: int, attempt: int, measure: Callable) -> _Taken:
        s, g, ex = self.steps, self.gantry, self.executor
        kind = int(s["kind"][step])
        det = self.detector
        key = (step, attempt)
        if kind == STEP_DARK:
            commanded = ex.positions()
            g.light.set_on(False)
            try:
                reading = measure(det.exposure_s, det.frames, key=key)
            finally:
                g.light.set_on(True)
        else:
            commanded = s["axes_deg"][step]
            ex.goto(commanded)
            ex.settle()
            if kind == STEP_REFERENCE:
                g.set_target("reference")
                try:
                    reading = measure(det.exposure_s, det.frames, key=key)
                finally:
                    g.set_target("sample")
            else:
                reading = measure(det.exposure_s, det.frames, key=key)
            self._check_lit(step)
        actual = ex.positions()
        return _Taken(step, kind, int(s["pose"][step]), np.asarray(commanded, float), actual,
                      g.clock.now(), self.campaign_s(), attempt, reading)

    def _check_lit(self, step: int) -> None:
        """A lit reading counts only if the lamp is still on after it: one switched off or power-cycled
        during the step (a source comes back with its output off) gave a dark reading. The lamp is
        switched on again and the step measured again (a transient fault: a retry in the journal)."""
        light = self.gantry.light
        if not light.is_on():
            light.set_on(True)
            raise DeviceFault(light.name, f"output found off after the reading of step {step} (switched off "
                              "or power-cycled); switched on again", transient=True)


def stop_and_go_units(engine) -> Iterable[Unit]:
    """One unit per step from the first the journal has no reading for (a stop-and-go campaign); where
    the detector develops readings in batches (the engine's ``executor.abilities.batches``), one unit
    per chunk of up to ``batch_readings()`` steps (module docstring)."""
    reader = engine.reader
    first, n = engine.journal.next_step(), engine.journal.step_count()
    batches = engine.executor.abilities.batches
    if batches is None:
        return (Unit(s, 1, lambda attempt, s=s: [reader.read(s, attempt)]) for s in range(first, n))
    return _chunks(engine, batches, first, n)


def _chunks(engine, detector: ReadsInBatches, first: int, n: int) -> Iterable[Unit]:
    """Units of up to ``detector.batch_readings()`` consecutive steps not in the journal; each starts
    at the step after the last one the previous unit measured (it may end early)."""
    size = detector.batch_readings()
    done = set(engine.journal.done_steps().tolist())
    reached = [first]
    s = first
    while s < n:
        if s in done:
            s += 1
            continue
        end = s + 1
        while end < n and end - s < size and end not in done:
            end += 1
        yield _chunk(engine, detector, s, end, reached)
        s = reached[0]


def _chunk(engine, detector: ReadsInBatches, first: int, end: int, reached: list[int]) -> Unit:
    """The unit of steps ``first`` .. ``end - 1``: each moved to and taken in turn (its attempt 1, the
    first step's ``attempt``), then all developed; it ends early where a request waits or once it spans
    :data:`CHUNK_SPAN_S` of gantry time, and raises
    :class:`Cut` where a later step fails. ``reached[0]``: the step after the last one measured."""

    def measure(attempt: int) -> list[Measurement]:
        taken = []
        clock = engine.gantry.clock
        start = clock.now()
        for s in range(first, end):
            if s > first and (engine.requests_waiting() or clock.now() - start >= CHUNK_SPAN_S):
                break   # a request acts at this boundary, as between units
            try:
                taken.append(engine.reader.take(s, attempt if s == first else 1, detector))
            except Exception as err:
                if s == first or isinstance(err, Halted):
                    raise    # a halt commits nothing more: the chunk is measured again on resuming
                rest = _chunk(engine, detector, s, end, reached)
                raise Cut(_developed(engine, detector, taken), err, rest) from None
            engine.executor.note_rest(taken[-1].actual)
        reached[0] = first + len(taken)
        return _developed(engine, detector, taken)

    return Unit(first, end - first, measure)


def _angles(kinematics, taken: list[_Taken]) -> np.ndarray:
    """(θi, φi, θo, φo) in degrees (K, 4) of the steps' actual positions: forward kinematics of a chunk
    in one call (each row the same floats as a call of its own)."""
    return np.degrees(np.stack(kinematics.forward(np.array([t.actual for t in taken])), axis=1))


def _developed(engine, detector: ReadsInBatches, taken: list[_Taken]) -> list[Measurement]:
    readings = detector.develop([t.reading for t in taken])
    angles = _angles(engine.executor.kinematics, taken) if taken else ()
    return [t.measurement(r, a) for t, r, a in zip(taken, readings, angles, strict=True)]
