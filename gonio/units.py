"""Units and their sources: what the engine measures and commits whole, chosen by the campaign's kind.

A :class:`Unit` is one stop-and-go step, or a fly campaign's sweep or checkpoint: measured, then
committed in one journal transaction, so that a crash loses at most the unit in flight. A *unit source*
turns a campaign into its units; which one runs is the campaign's **kind**, recorded in its journal when
it is created (:data:`KINDS`):

``stop-and-go``
    One unit per step (:func:`stop_and_go_units`): move, settle, read (:class:`StepReader`).
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

from gonio.plan.schedule import STEP_DARK, STEP_REFERENCE
from gonio.protocols import DeviceFault, Gantry
from gonio.store import Measurement

if TYPE_CHECKING:
    from gonio.config import DetectorConfig
    from gonio.executor import MotionExecutor

__all__ = ["Unit", "StepReader", "stop_and_go_units", "unit_source", "KINDS", "STOP_AND_GO", "FLY",
           "ADAPTIVE"]

STOP_AND_GO, FLY, ADAPTIVE = "stop-and-go", "fly", "adaptive"
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
        s, g, ex = self.steps, self.gantry, self.executor
        kind = int(s["kind"][step])
        det = self.detector
        key = (step, attempt)
        if kind == STEP_DARK:
            commanded = ex.positions()
            g.light.set_on(False)
            try:
                reading = g.detector.measure(det.exposure_s, det.frames, key=key)
            finally:
                g.light.set_on(True)
        else:
            commanded = s["axes_deg"][step]
            ex.goto(commanded)
            ex.settle()
            if kind == STEP_REFERENCE:
                g.set_target("reference")
                try:
                    reading = g.detector.measure(det.exposure_s, det.frames, key=key)
                finally:
                    g.set_target("sample")
            else:
                reading = g.detector.measure(det.exposure_s, det.frames, key=key)
            self._check_lit(step)
        actual = ex.positions()
        ti, pi_, to, po = ex.kinematics.forward(actual[None, :])
        angles = np.degrees([ti[0], pi_[0], to[0], po[0]])
        return Measurement(
            step=step, kind=kind, pose=int(s["pose"][step]), commanded_deg=np.asarray(commanded, float),
            actual_deg=actual, angles_deg=angles, clock_s=g.clock.now(), campaign_s=self.campaign_s(),
            exposure_s=reading.exposure_s, frames=reading.frames, signal=reading.signal,
            stderr=reading.stderr, attempts=attempt, extra=reading.extra)

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
    """One unit per step from the first the journal has no reading for (a stop-and-go campaign)."""
    reader = engine.reader
    return (Unit(s, 1, lambda attempt, s=s: [reader.read(s, attempt)])
            for s in range(engine.journal.next_step(), engine.journal.step_count()))
