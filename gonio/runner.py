"""The engine: runs a journaled campaign's units on a gantry, one committed unit at a time.

One engine runs every kind of campaign: its units come from a source chosen by the campaign's kind
(:mod:`gonio.units`: stop-and-go steps, fly sweeps, adaptive rounds) and move the gantry
through the public motion executor (:class:`gonio.executor.MotionExecutor`: goto, wait, settle,
arrive, stop). The engine itself is the state machine: an explicit table (``TRANSITIONS``) guards every
change of state; units are measured, retried on transient faults, committed in one transaction each;
faults latch; operator requests act between units.

Operator requests (pause, resume, abort, halt) come from any thread through the engine's command queue
(:meth:`Runner.request`): each is decided under the engine's lock against the state it finds, then either
acted on at once (an abort of a paused campaign, the halt's stop of every axis) or queued for the
engine's thread, which takes the queue at each unit boundary (and, for requests made before a run
starts, when it starts).

Stops, and what each leaves behind:

``pause`` (any thread; SIGINT/SIGTERM in the CLI)
    Finishes the unit in flight, then parks along a safe path; ``paused``. Resume continues. A pause
    requested before a run starts acts before its first unit.
``resume``
    A pause not acted on yet (``pausing``) is withdrawn: the run goes on. A stopped campaign resumes by
    running again (:meth:`Runner.run`, :func:`gonio.lifecycle.run_campaign`).
``abort``
    At the next unit boundary: parks, ``aborted`` (final). A paused, halted or faulted campaign aborts
    at once and nothing moves; one not started yet aborts when it starts, before anything moves.
``halt`` (emergency stop, any thread)
    Every axis is stopped at once, mid-move too; nothing further is commanded and nothing is parked;
    ``halted``. Resume continues from the step in flight.
fault
    A device fault that is not transient (an error bit, an alarm), an axis that stopped short of its
    target (stopped by someone else, or blocked), a target beyond a limit or a move with no safe path:
    every axis is stopped and left where it is, the campaign is ``faulted`` and the fault is latched
    in the journal. It stays latched across restarts until an operator clears it
    (:meth:`Runner.clear_fault`, ``--clear-fault``); only then does the campaign run again.

Transient faults (a time-out, a corrupt reply, a small position error) are retried up to
``runner.retries`` times (the whole unit again), after waiting until every axis is still. The engine
never sees bytes: it talks to the gantry through the protocols in :mod:`gonio.protocols`.

Time: ``campaign_s`` continues across resumes: each run starts where the journal's clock left off (plus
the downtime, when the gantry's clock is the wall clock), so the drift correction never sees time go
backwards.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from enum import StrEnum
from typing import TYPE_CHECKING

from gonio.executor import Halted, MotionExecutor, MotionFault
from gonio.protocols import DeviceFault, Gantry
from gonio.store import Journal
from gonio.units import Cut, StepReader, Unit, stop_and_go_units

if TYPE_CHECKING:  # type hints only: the caller holds the config
    from gonio.config import GonioConfig

__all__ = ["Runner", "State", "TRANSITIONS", "TransitionError", "Command"]

log = logging.getLogger(__name__)


class State(StrEnum):
    IDLE = "idle"
    RUNNING = "running"
    PAUSING = "pausing"
    PAUSED = "paused"
    HALTED = "halted"
    DONE = "done"
    ABORTED = "aborted"
    FAULTED = "faulted"


#: from-state -> the states it may go to. ``faulted`` runs again only once the fault is cleared; a
#: ``pausing`` run goes back to ``running`` when the pause is withdrawn before it acted.
TRANSITIONS: dict[State, frozenset[State]] = {
    State.IDLE: frozenset({State.RUNNING, State.ABORTED}),
    State.RUNNING: frozenset({State.PAUSING, State.DONE, State.ABORTED, State.FAULTED, State.HALTED}),
    State.PAUSING: frozenset({State.RUNNING, State.PAUSED, State.DONE, State.ABORTED, State.FAULTED,
                              State.HALTED}),
    State.PAUSED: frozenset({State.RUNNING, State.ABORTED, State.HALTED}),   # halted: while it parks
    State.HALTED: frozenset({State.RUNNING, State.ABORTED}),
    State.FAULTED: frozenset({State.RUNNING, State.ABORTED}),
    State.DONE: frozenset(),
    State.ABORTED: frozenset(),
}


class Command(StrEnum):
    """An operator's request to the engine (:meth:`Runner.request`)."""

    PAUSE = "pause"
    RESUME = "resume"
    ABORT = "abort"
    HALT = "halt"


#: States in which requests wait in the queue for the engine's thread (not started yet, or running).
_QUEUED_IN = frozenset({State.IDLE, State.RUNNING, State.PAUSING})
#: States a stopped run can be aborted from at once (its thread acts on nothing any more).
_ABORT_AT_ONCE = frozenset({State.PAUSED, State.FAULTED, State.HALTED})


class TransitionError(RuntimeError):
    pass


class Runner:
    """The engine: runs the campaign held in ``journal`` on ``gantry``.

    ``on_step(runner, step)`` is called after each committed unit with its last step (progress bars, the
    daemon's event stream, and tests that pause or abort at a precise step).

    Attributes
    ----------
    executor : MotionExecutor
        The public motion API the units use (goto, wait, settle, arrive, stop, positions).
    reader : StepReader
        Stop-and-go readings of the journal's steps (a stop-and-go step; a fly campaign's checkpoint).
    """

    def __init__(self, gantry: Gantry, journal: Journal, cfg: GonioConfig,
                 on_step: Callable[[Runner, int], None] | None = None):
        self.gantry = gantry
        self.journal = journal
        self.cfg = cfg
        self.on_step = on_step
        self._state = State.IDLE
        self._lock = threading.Lock()
        self._commands: deque[Command] = deque()   # requests waiting for the engine's thread
        # Halts not journaled yet: the requester journals its halt once the axes are told to stop, but
        # the engine can end the run halted (and its owner close the journal) before that thread gets
        # there, so whichever comes first journals it, once (_journal_halts).
        self._halts: list[str] = []
        self._halt_lock = threading.Lock()
        self.fault: str | None = None
        self.stop_reason: str = ""
        self._offset_s = 0.0  # campaign clock − gantry clock
        self.executor = MotionExecutor(gantry, cfg.runner, on_event=self._record)
        self.reader = StepReader(gantry, self.executor, journal.steps(), cfg.detector, self.campaign_s)
        latched = journal.latched_fault()
        if latched is not None:
            self._state = State.FAULTED
            self.fault = latched["reason"]

    # -- state -----------------------------------------------------------------------------------
    @property
    def state(self) -> State:
        return self._state

    def campaign_s(self) -> float:
        """The campaign clock now: seconds since the campaign began, continuing across resumes."""
        # One offset, added once: a gantry clock that already runs on campaign time (a resumed
        # simulation) has offset 0.0 and gives its own readings bit for bit.
        return self.gantry.clock.now() + self._offset_s

    def _record(self, kind: str, message: str) -> None:
        self.journal.log_event(kind, message=message, campaign_s=self.campaign_s())

    def _to(self, new: State, message: str = "") -> None:
        with self._lock:
            old = self._state
            if new not in TRANSITIONS[old]:
                raise TransitionError(f"runner: cannot go from '{old}' to '{new}'")
            self._state = new
        if new == State.HALTED:
            self._journal_halts()
        self.journal.log_event("state", state=str(new), message=message or f"{old} -> {new}",
                               campaign_s=self.campaign_s())
        log.info("campaign %s -> %s %s", old, new, message)

    # -- operator requests: the command queue ----------------------------------------------------
    def request(self, command: Command | str, reason: str = "") -> bool:
        """An operator's request, from any thread: ``pause``, ``resume``, ``abort`` or ``halt`` (see the
        module docstring). Each is decided under the engine's lock against the state it finds; True
        when it took effect or waits in the queue, False when there was nothing to do (a pause of a
        stopped campaign, a resume of a pause already under way)."""
        command = Command(command)
        handler = {Command.PAUSE: self._on_pause, Command.RESUME: self._on_resume,
                   Command.ABORT: self._on_abort, Command.HALT: self._on_halt}[command]
        return handler(reason or f"{command} requested")

    def request_pause(self, reason: str = "pause requested") -> bool:
        """:meth:`request` ``pause``: at the next unit boundary, then park."""
        return self.request(Command.PAUSE, reason)

    def request_resume(self, reason: str = "resume requested") -> bool:
        """:meth:`request` ``resume``: withdraw a pause that has not acted yet."""
        return self.request(Command.RESUME, reason)

    def request_abort(self, reason: str = "abort requested") -> bool:
        """:meth:`request` ``abort``: at the next unit boundary (parks); a paused, halted or faulted
        campaign at once, and nothing moves."""
        return self.request(Command.ABORT, reason)

    def request_halt(self, reason: str = "halt requested") -> bool:
        """:meth:`request` ``halt``: every axis stops now, mid-move too (from the caller's thread);
        nothing is parked. The engine's thread notices within one ``poll_s`` slice and ends the run
        ``halted``."""
        return self.request(Command.HALT, reason)

    def _on_pause(self, reason: str) -> bool:
        # The request is journaled before the engine's thread can see it, so the journal never shows the
        # park (or the paused state) before the pause that caused it.
        with self._lock:
            state = self._state
            if state == State.RUNNING:
                self._state = State.PAUSING
        if state not in (State.IDLE, State.RUNNING):
            return False   # pausing already, or stopped
        if state == State.RUNNING:
            self.journal.log_event("pause", state=str(State.PAUSING), message=reason,
                                   campaign_s=self.campaign_s())
        with self._lock:
            self._commands.append(Command.PAUSE)
        return True

    def _on_resume(self, reason: str) -> bool:
        with self._lock:
            if Command.PAUSE not in self._commands:
                return False   # no pause waits: running, or the pause acts already (run again after it)
            self._commands = deque(c for c in self._commands if c != Command.PAUSE)
            withdrawn = self._state == State.PAUSING
            if withdrawn:
                self._state = State.RUNNING
        if withdrawn:
            self.journal.log_event("resume", state=str(State.RUNNING), message=reason,
                                   campaign_s=self.campaign_s())
        return True

    def _on_abort(self, reason: str) -> bool:
        with self._lock:
            state = self._state
            if state in _QUEUED_IN:
                self._commands.append(Command.ABORT)
                return True
        if state in _ABORT_AT_ONCE:
            self._to(State.ABORTED, reason)
            return True
        return False

    def _on_halt(self, reason: str) -> bool:
        with self._lock:
            started = self._state != State.IDLE
            if self._state in _QUEUED_IN:
                self._commands.append(Command.HALT)   # not started yet: it starts halted, nothing moves
        with self._halt_lock:
            self._halts.append(reason)
        if started:
            err = self.executor.halt()
            if err is not None:  # the halt stands; a failing stop is recorded beside it
                self._record("fault", f"stop failed during halt: {err}")
        self._journal_halts()
        return True

    def _journal_halts(self) -> None:
        """Journal the halts requested and not journaled yet (from the requester's thread or the
        engine's, whichever comes first)."""
        with self._halt_lock:
            reasons, self._halts = self._halts, []
            for reason in reasons:
                self.journal.log_event("halt", message=reason, campaign_s=self.campaign_s())

    def requests_waiting(self) -> bool:
        """Whether a request waits for the next unit boundary (a unit of several steps ends early at
        one: :func:`gonio.units.stop_and_go_units`)."""
        return bool(self._commands)

    def _take(self) -> set[Command]:
        """The queued requests, taken (the engine's thread, at a unit boundary)."""
        with self._lock:
            taken = set(self._commands)
            self._commands.clear()
        return taken

    def clear_fault(self, operator_note: str = "cleared by the operator") -> None:
        """Clear a latched fault: the devices' own latches (reboot, alarm reset) and the journal's."""
        if self._state not in (State.FAULTED, State.IDLE):
            raise TransitionError(f"runner: campaign is {self._state}; there is no fault to clear")
        for name in self.gantry.kinematics.axis_names:
            axis = self.gantry.axes[name]
            if axis.fault() is not None:
                axis.clear_fault()
        if self.journal.latched_fault() is not None:
            self.journal.delete_meta("latched_fault")
        self.journal.log_event("fault-cleared", message=f"{self.fault or 'no fault'}: {operator_note}",
                               campaign_s=self.journal.campaign_clock()[0])
        self.fault = None

    # -- running ---------------------------------------------------------------------------------
    def run(self, units: Iterable[Unit] | None = None) -> State:
        """Run (or resume) the campaign's units not yet in the journal.

        ``units`` (default: one per step, stop-and-go: :func:`gonio.units.stop_and_go_units`) are
        measured and committed whole, in order; the units whose first step the journal holds are
        skipped (a fly campaign's sweeps).

        Returns the state it stopped in: done, paused, halted, aborted or faulted. A campaign whose
        fault is latched returns ``faulted`` at once without touching the gantry. A pause halted while it
        parks ends ``halted``.
        """
        if self._state in (State.DONE, State.ABORTED):
            raise TransitionError(f"runner: campaign is {self._state}; nothing to run")
        latched = self.journal.latched_fault()
        if latched is not None:
            self.fault = latched["reason"]
            self._state = State.FAULTED
            return self._state
        self.journal.note_unclean_stop()   # the last run was killed mid-way: the journal says so first
        try:
            self._run(units)
        finally:
            self._settle_requests()
        return self._state

    def _settle_requests(self) -> None:
        """After a run: an abort it never reached (it stopped first: paused, halted, faulted) acts now;
        the other requests ended with the run."""
        taken = self._take()
        if Command.ABORT in taken and self._state in _ABORT_AT_ONCE:
            self._to(State.ABORTED, "abort requested")

    def _run(self, units: Iterable[Unit] | None) -> None:
        step = self.journal.next_step()
        # Requests made before the run started: an abort or a halt ends it before anything moves.
        with self._lock:
            early = set(self._commands) & {Command.ABORT, Command.HALT}
            if early:
                self._commands.clear()
        self._start_clock()
        if Command.ABORT in early:
            self._to(State.ABORTED, f"aborted before step {step}, before it started")
            return
        self.executor.begin()
        self._to(State.RUNNING, f"{'resume' if step > 0 else 'start'} at step {step}")
        if Command.HALT in early:
            self._to(State.HALTED, f"halted before step {step}")
            return
        self.fault = None
        park = True
        try:
            self.gantry.light.set_on(True)
            self.gantry.set_target("sample")
            done = set(self.journal.done_steps().tolist())
            for unit in (stop_and_go_units(self) if units is None else units):
                if unit.first in done:
                    continue
                step = unit.first
                if self._stopped_at(step):
                    return
                last = self._run_unit(unit)
                if self.on_step is not None:
                    self.on_step(self, last)
            # A request after the last unit comes too late. The count is the journal's now: an adaptive
            # campaign's source appended its rounds while it ran.
            self._to(State.DONE, f"{self.journal.step_count()} steps measured")
        except Halted:
            park = False
            self._to(State.HALTED, f"halted during step {step}")
        except MotionFault as err:
            park = False
            self._fail(str(err), [err.device])
        except KeyboardInterrupt:
            # Not through the CLI's handlers (a library user's Ctrl-C): stop everything where it is.
            park = False
            self.request_halt("interrupted (KeyboardInterrupt)")
            self._to(State.HALTED, f"interrupted during step {step}")
            raise
        except Exception as err:
            park = False
            self._fail(f"{type(err).__name__}: {err}", ["gantry"])
            raise
        finally:
            self._finish(park)

    def _stopped_at(self, step: int) -> bool:
        """At a unit boundary (before ``step``): act on the queued requests; True when the run stops."""
        taken = self._take()
        if Command.ABORT in taken:
            self._to(State.ABORTED, f"aborted before step {step}")
            return True
        if Command.HALT in taken:
            raise Halted   # requested as the run started, before the executor could be told
        self.executor.check_halt()
        if Command.PAUSE in taken:
            with self._lock:
                early = self._state == State.RUNNING   # requested before the run started
                if early:
                    self._state = State.PAUSING
            if early:
                self.journal.log_event("pause", state=str(State.PAUSING), campaign_s=self.campaign_s(),
                                       message="pause requested before the run started")
            self._to(State.PAUSED, f"paused before step {step}")
            return True
        return False

    def _start_clock(self) -> None:
        base, last_wall = self.journal.campaign_clock()
        if self.gantry.clock.real_time and last_wall is not None:
            base += max(0.0, time.time() - last_wall)  # a lamp drifts while nobody runs the gantry
        self._offset_s = base - self.gantry.clock.now()

    def _fail(self, reason: str, devices: list[str]) -> None:
        self.fault = reason
        self.executor.stop()
        self.journal.latch_fault(reason, devices)
        self.journal.log_event("fault", message=reason, campaign_s=self.campaign_s())
        if self._state in (State.RUNNING, State.PAUSING):
            self._to(State.FAULTED, reason)

    def _journal_warnings(self, step: int | None = None) -> None:
        """Hardware warnings the devices reported (they went on: a warning, not a fault)."""
        reports = self.executor.abilities.warnings
        if reports is not None:
            for device, message in reports.drain_warnings():
                self.journal.log_event("warning", step=step, message=f"{device}: {message}",
                                       campaign_s=self.campaign_s())

    def _finish(self, park: bool) -> None:
        """Light off; park along a safe path after done, pause and abort; record where the axes stand,
        the hardware warnings and what the drivers could not trust on the way."""
        ex = self.executor
        try:
            self.gantry.light.set_on(False)
        except Exception as err:
            self.journal.log_event("fault", message=f"light off failed: {err}", campaign_s=self.campaign_s())
        try:
            if park:
                ex.goto(ex.home_deg)
            self.journal.log_event("park" if park else "stopped", message="axes home" if park else
                                   "axes left where they stopped", campaign_s=self.campaign_s(),
                                   axes_deg=ex.positions())
        except Halted:
            # A halt (a second Ctrl-C) while parking: the axes stop where they are, as a halt says. The
            # campaign is halted, not paused, unless it had finished or been aborted.
            self.journal.log_event("stopped", message="halted while parking: axes left where they stopped",
                                   campaign_s=self.campaign_s(), axes_deg=ex.positions())
            if self._state == State.PAUSED:
                self._to(State.HALTED, "halted while parking")
        except Exception as err:
            reason = str(err) or type(err).__name__
            self.journal.log_event("fault", message=f"park failed: {reason}", campaign_s=self.campaign_s())
        self._journal_warnings()
        link = ex.abilities.link
        line = link.link_report() if link is not None else None
        if line:
            self.journal.log_event("link", message=line, campaign_s=self.campaign_s())

    def _run_unit(self, unit: Unit) -> int:
        """Measure and commit one unit (a step, or several in one transaction), retrying transient
        faults; returns the last step committed (a unit may end early: :func:`gonio.units.stop_and_go_units`).
        A unit cut by a fault part-way (:class:`gonio.units.Cut`) commits the steps before the fault;
        the fault is then its failing step's, retried as that step's own."""
        retries = self.cfg.runner.retries
        attempt = 1
        while True:
            try:
                ms = unit.measure(attempt)
            except Cut as cut:
                self._commit(unit, cut.done)
                unit, attempt, err = cut.rest, 1, cut.fault
                if not isinstance(err, DeviceFault):
                    raise err from None
            except DeviceFault as fault:
                err = fault
            else:
                self.executor.check_halt()  # the readings are whole; after a halt nothing more is committed
                return self._commit(unit, ms)
            step = unit.first
            if not err.transient:
                raise MotionFault(err.device, str(err).removeprefix(f"{err.device}: ")) from None
            self.executor.stop()
            if attempt > retries:
                raise MotionFault(err.device, f"step {step}: {str(err).removeprefix(f'{err.device}: ')} "
                                  f"(gave up after {retries} retries)") from None
            self.journal.log_event("retry", step=step, campaign_s=self.campaign_s(),
                                   message=f"step {step}, attempt {attempt}: {err}; retrying")
            attempt += 1

    def _commit(self, unit: Unit, ms: list) -> int:
        """Commit the measurements of ``unit`` (one step alone, or several in one transaction); the
        last step committed."""
        if unit.count == 1:
            self.journal.commit_measurement(ms[0])
            self.executor.note_rest(ms[0].actual_deg)
        else:  # a sweep's axes stand at its run-down's end; a chunk of steps noted its own rests
            self.journal.commit_measurements(ms)
        self._journal_warnings(unit.first)
        return unit.first + len(ms) - 1
