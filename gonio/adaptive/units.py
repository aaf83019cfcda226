"""The unit source of an ``adaptive`` campaign (:mod:`gonio.units`): the journal's steps, then each
round's, planned from the journal once every step before it is measured.

The engine asks for units lazily: while steps without a reading remain, each is a stop-and-go unit
(:class:`gonio.units.StepReader`); when none remains, the next round is planned from the journal alone
(:func:`gonio.adaptive.plan.next_round`: its meta, config snapshot and readings) and appended to it in
one transaction (:meth:`gonio.store.Journal.append_steps`), and its steps follow. A kill while a round is
planned leaves the journal as it was: the resumed run plans the same round again (the planning is a pure
function of the journal); a kill after the append finds the round in the journal and measures it. The
source ends when the budget is spent; the engine then finishes the campaign (``brdf.h5``).
"""

from __future__ import annotations

from collections.abc import Iterator

from gonio.adaptive.plan import next_round
from gonio.units import StepReader, Unit

__all__ = ["adaptive_units"]


def adaptive_units(engine) -> Iterator[Unit]:
    """The units of an adaptive campaign run by ``engine`` (a :class:`gonio.runner.Runner`)."""
    from gonio.kinematics import make_kinematics

    journal, kin = engine.journal, make_kinematics(engine.cfg)
    while True:
        reader = StepReader(engine.gantry, engine.executor, journal.steps(), engine.cfg.detector,
                            engine.campaign_s)
        done = set(journal.done_steps().tolist())
        for s in range(journal.step_count()):
            if s not in done:
                yield Unit(s, 1, lambda attempt, s=s, reader=reader: [reader.read(s, attempt)])
        planned = next_round(journal, engine.cfg, kin)
        if planned is None:
            return
        steps, meta, line = planned
        journal.append_steps(steps, meta, event=line, campaign_s=engine.campaign_s())
