"""The daemon's campaign states: an explicit table derived from the engine's state.

A campaign the worker runs has an engine (:class:`gonio.runner.Runner`); its state is the engine's,
read through :data:`IN_WORKER` (a stopped engine still parks, and a done one writes brdf.h5, before the
campaign leaves the worker: pausing, aborting, finishing). A campaign out of the worker has only its
journal: the engine state it last recorded, the latched fault, brdf.h5, and the operator's intent kept
in ``daemon.json`` (``run``: it waits for the gantry; ``hold``: it waits for the operator); its state is
read through :func:`campaign_state`'s rules, in order, ending in :data:`HELD`.

=============  =====================================================================================
creating       planned and journaled in the staging folder, or its journal not there yet
queued         waits for the gantry (intent ``run``)
starting       the worker picked it; its engine is not running yet
running        the engine runs its units
pausing        a pause was requested and acts at the next unit boundary, or the engine parks
paused         held by the operator (or stopped with the daemon and held with ``--hold``)
halted         stopped at once by a halt; the axes are where they stopped
faulted        a fault is latched: cleared only by a resume with ``clear_fault``
aborting       aborted; the engine parks
finishing      every unit measured; brdf.h5 is being written
done           final: brdf.h5 written
aborted        final
failed         the daemon could not run it (not a device fault); a resume tries again
=============  =====================================================================================
"""

from __future__ import annotations

from dataclasses import dataclass

from gonio.runner import State

__all__ = ["STATES", "IN_WORKER", "HELD", "FINAL", "CampaignView", "campaign_state"]

#: Every state the daemon reports.
STATES = ("creating", "queued", "starting", "running", "pausing", "paused", "halted", "faulted", "aborting",
          "finishing", "done", "aborted", "failed")
#: The campaign the worker runs: its engine's state (None: no engine yet) -> the daemon's.
IN_WORKER: dict[State | None, str] = {
    None: "starting", State.IDLE: "starting", State.RUNNING: "running", State.PAUSING: "pausing",
    State.PAUSED: "pausing", State.HALTED: "halted", State.FAULTED: "faulted", State.DONE: "finishing",
    State.ABORTED: "aborting",
}
#: A campaign out of the worker and held by the operator: the engine state its journal last recorded
#: (None: it never ran) -> the daemon's.
HELD: dict[str | None, str] = {
    None: "paused", State.IDLE: "paused", State.RUNNING: "paused", State.PAUSING: "paused",
    State.PAUSED: "paused", State.HALTED: "halted", State.FAULTED: "faulted", State.DONE: "paused",
}
#: Final states: once seen, a campaign keeps them.
FINAL = frozenset({"done", "aborted"})


@dataclass(frozen=True)
class CampaignView:
    """What the daemon knows of one campaign when it says its state.

    Attributes
    ----------
    in_worker : bool
        The worker runs it (and has not begun to let it go).
    engine : State or None
        Its engine's state while in the worker (None: no engine yet).
    journal : bool
        Its journal exists.
    last : str or None
        The engine state its journal last recorded (None: it never ran).
    latched : bool
        A fault is latched in its journal.
    brdf : bool
        brdf.h5 is written.
    intent : str
        The operator's: ``run`` or ``hold``.
    clear_fault : bool
        The operator's resume clears the latched fault.
    error : bool
        The daemon could not run it.
    """

    in_worker: bool = False
    engine: State | None = None
    journal: bool = True
    last: str | None = None
    latched: bool = False
    brdf: bool = False
    intent: str = "run"
    clear_fault: bool = False
    error: bool = False


def campaign_state(v: CampaignView) -> str:
    """The daemon's state of a campaign (see the module docstring), one of :data:`STATES`."""
    if v.in_worker:
        return IN_WORKER[v.engine]
    if not v.journal:
        return "failed" if v.error else "creating"
    if v.last == State.ABORTED or (v.last == State.DONE and v.brdf):
        return str(v.last)
    if v.intent == "run":
        return "faulted" if v.latched and not v.clear_fault else "queued"
    if v.error:
        return "failed"
    if v.latched:
        return "faulted"
    return HELD.get(v.last, "paused")
