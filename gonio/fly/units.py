"""The unit source of fly campaigns (campaign kind ``fly``, :data:`gonio.units.KINDS`).

One unit per checkpoint (its dark and white reference) and one per line of the fly plan, in campaign
order, each committed whole by the engine. Who reads them is what the gantry declares it can do:

- a gantry that renders fly readings itself (:class:`gonio.protocols.RendersFly`: the simulated gantry,
  :mod:`gonio.sim.fly`) renders each unit, nothing moving; the engine's clock is then brought to the
  unit's last reading, in slices as any wait, so pause, abort and halt act as on hardware (a halt in
  that wait drops the unit, rendered again, bit for bit, on resume);
- a gantry that sweeps its axes (:class:`gonio.protocols.FliesAxes`) reads the checkpoints stop-and-go
  (:class:`gonio.units.StepReader`) and the lines with :class:`gonio.fly.hardware.FlySweeper`.

:func:`check_fly_gantry` says, before anything is written or moved, whether a gantry can fly a plan.
"""

from __future__ import annotations

from functools import partial

from gonio.config import GonioConfig
from gonio.fly.plans import rebuild_fly_plan
from gonio.fly.segments import on_limits, path_segments
from gonio.gantry import abilities
from gonio.plan.fly import FlyPlan, fly_steps
from gonio.plan.flypath import COORDINATED
from gonio.protocols import Gantry
from gonio.store import Measurement
from gonio.units import Unit

__all__ = ["fly_units", "check_fly_gantry"]


def check_fly_gantry(gantry: Gantry, cfg: GonioConfig, fp: FlyPlan) -> None:
    """Whether ``gantry`` (wired from ``cfg``, connected or not) can fly the plan ``fp``, from the
    abilities its devices declare: it renders fly readings itself and says it can, or every axis that
    sweeps a line is :class:`~gonio.protocols.Flyable` (its velocity set per sweep, its position read
    with timestamps; a coordinated line's axes are started together, one packet per Dynamixel bus, along
    chords that must be clear: :mod:`gonio.fly.segments`) and the detector reads while the axes move
    (:class:`~gonio.protocols.ReadsOnTheFly`: not a camera's frame).

    Raises
    ------
    ValueError
        Naming the first axis (or the detector) that cannot, and why.
    """
    can = abilities(gantry)
    if can.renders_fly is not None:
        why = can.renders_fly.fly_refusal()
        if why is not None:
            raise ValueError(why)
        return
    names = gantry.kinematics.axis_names

    def sweeps(ln, axis):
        return bool(ln.moving_axes[axis]) if ln.axis == COORDINATED else ln.axis == axis

    for axis in range(len(names)):
        lines = sum(sweeps(ln, axis) for ln in fp.lines if ln.moving)
        if not lines:
            continue
        name = names[axis]
        if can.flies is None or not can.flies.can_sweep(name):
            plural = "s" if lines != 1 else ""
            raise ValueError(f"axes.{name}: driver '{cfg.axes[name].driver}' cannot sweep a line of "
                             f"order=fly (it would sweep {lines} line{plural}; fly scanning on hardware "
                             "needs Dynamixel servos, whose velocity is set per sweep and whose positions "
                             "are sync-read with timestamps); use order=auto for this gantry")
    # Coordinated lines fly as straight segments between their poses (gonio.fly.segments): each chord
    # must be clear (the planner certified the curve through them).
    kin = gantry.kinematics
    for ln in fp.lines:
        if ln.axis == COORDINATED:
            path_segments(kin, ln, on_limits(kin, ln.readings_deg()))
    if not can.reads_on_the_fly:
        det = cfg.detector
        field, what = (("detector.sim.kind", det.sim.kind) if det.driver == "sim" else ("detector.driver",
                                                                                          det.driver))
        raise ValueError(f"{field}: '{what}' cannot read while the axes sweep (a frame per reading); "
                         "order=fly needs a photodiode, power meter or spectrometer")


def fly_units(engine, fp: FlyPlan | None = None) -> list[Unit]:
    """The units of the fly campaign the ``engine`` (:class:`gonio.runner.Runner`) runs: one per
    checkpoint and one per line, in campaign order. ``fp``: the fly plan the journal's steps were made
    from, where the caller has it (:attr:`gonio.campaign.Campaign.fly`: planned and created in this
    process); None: rebuilt from the journal and checked against its steps.

    Raises
    ------
    ValueError
        The journal's fly plan cannot be rebuilt (:func:`gonio.fly.plans.rebuild_fly_plan`) or the
        gantry cannot fly it (:func:`check_fly_gantry`).
    """
    journal = engine.journal
    if fp is None:
        fp = rebuild_fly_plan(journal.meta(), engine.cfg, journal.steps(), journal.path.parent)
    check_fly_gantry(engine.gantry, engine.cfg, fp)
    renders = engine.executor.abilities.renders_fly
    if renders is not None:
        return [Unit(step, _count(fp, kind, k), partial(_rendered, engine, renders, fp, (kind, k, step)))
                for kind, k, step in fly_steps(fp)]
    from gonio.fly.hardware import FlySweeper

    sweeper = FlySweeper(engine)
    reader = engine.reader
    units = []
    for kind, k, step in fly_steps(fp):
        if kind == "checkpoint":
            units.append(Unit(step, 2, partial(_checkpoint, reader, step)))
        else:
            then = fp.lines[k + 1] if k + 1 < len(fp.lines) and fp.swept_turn(k + 1) else None
            units.append(Unit(step, fp.lines[k].n, partial(sweeper.sweep, fp.lines[k], step, then=then)))
    return units


def _count(fp: FlyPlan, kind: str, k: int) -> int:
    return 2 if kind == "checkpoint" else fp.lines[k].n


def _checkpoint(reader, step: int, attempt: int) -> list[Measurement]:
    return [reader.read(step, attempt), reader.read(step + 1, attempt)]


def _rendered(engine, renders, fp: FlyPlan, item, attempt: int) -> list[Measurement]:
    """A rendered unit (the same whatever the attempt: its random numbers are keyed by its first step),
    once the campaign clock has reached its last reading."""
    ms = renders.fly_readings(fp, item)
    engine.executor.wait(max(0.0, max(m.campaign_s for m in ms) - engine.campaign_s()))
    return ms
