"""The runner: executes a journaled plan on a gantry, one committed step at a time.

An explicit state machine (``TRANSITIONS``) guards every change of state. For each step: check every
target against the limits and plan a collision-free path to it from where the axes stand
(:func:`gonio.motion.safe.safe_path`), move leg by leg (only the axes whose target changed), wait in
slices of ``poll_s`` so that a halt acts mid-move, verify the positions, settle, measure, commit.

Stops, and what each leaves behind:

``pause`` (any thread; SIGINT/SIGTERM in the CLI)
    Finishes the step in flight, then parks along a safe path; ``paused``. Resume continues.
``abort``
    At the next step boundary: parks, ``aborted`` (final). A paused, halted or faulted campaign aborts
    at once and nothing moves.
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
``runner.retries`` times, after waiting until every axis is still. The runner never sees bytes: it
talks to the gantry through the protocols in :mod:`gonio.protocols`.

Time: ``campaign_s`` continues across resumes: each run starts where the journal's clock left off (plus
the downtime, when the gantry's clock is the wall clock), so the drift correction never sees time go
backwards.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from gonio.config import GonioConfig
from gonio.motion.safe import check_targets, safe_path
from gonio.motion.trapezoid import move_time
from gonio.plan.schedule import STEP_DARK, STEP_REFERENCE
from gonio.protocols import DeviceFault, Gantry
from gonio.store import Journal, Measurement

__all__ = ["Runner", "State", "TRANSITIONS", "TransitionError", "Unit"]

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


#: from-state -> the states it may go to. ``faulted`` runs again only once the fault is cleared.
TRANSITIONS: dict[State, frozenset[State]] = {
    State.IDLE: frozenset({State.RUNNING, State.ABORTED}),
    State.RUNNING: frozenset({State.PAUSING, State.DONE, State.ABORTED, State.FAULTED, State.HALTED}),
    State.PAUSING: frozenset({State.PAUSED, State.DONE, State.ABORTED, State.FAULTED, State.HALTED}),
    State.PAUSED: frozenset({State.RUNNING, State.ABORTED, State.HALTED}),   # halted: while it parks
    State.HALTED: frozenset({State.RUNNING, State.ABORTED}),
    State.FAULTED: frozenset({State.RUNNING, State.ABORTED}),
    State.DONE: frozenset(),
    State.ABORTED: frozenset(),
}


class TransitionError(RuntimeError):
    pass


@dataclass(frozen=True)
class Unit:
    """What the runner measures and commits whole: one step (stop-and-go), or a fly campaign's sweep or
    checkpoint (:mod:`gonio.fly.hardware`), committed in one transaction so that a crash loses at most
    the unit in flight.

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


class _Halted(Exception):
    """Raised inside the runner's thread when a halt was requested; never leaves :meth:`Runner.run`."""


class _Fault(Exception):
    """A fault that stops the campaign and latches (not a device's transient hiccup)."""

    def __init__(self, device: str, message: str):
        super().__init__(f"{device}: {message}")
        self.device = device


class Runner:
    """Runs the campaign held in ``journal`` on ``gantry``.

    ``on_step(runner, step)`` is called after each committed step (progress bars, the daemon's event
    stream, and tests that pause or abort at a precise step).
    """

    def __init__(self, gantry: Gantry, journal: Journal, cfg: GonioConfig,
                 on_step: Callable[[Runner, int], None] | None = None):
        self.gantry = gantry
        self.journal = journal
        self.cfg = cfg
        self.on_step = on_step
        self._state = State.IDLE
        self._lock = threading.Lock()
        # Held while axes are being commanded: a halt waits for a batch of commands to be sent, then
        # stops every axis; no batch starts once the halt flag is set.
        self._command_lock = threading.RLock()
        self._pause = threading.Event()
        self._abort = threading.Event()
        self._halt = threading.Event()
        self.fault: str | None = None
        self.stop_reason: str = ""
        self._steps = journal.steps()
        kin = gantry.kinematics
        self._kin = kin
        self._vmax = np.asarray(kin.velocity_deg_s, float)
        self._amax = np.asarray(kin.accel_deg_s2, float)
        self._axes = [gantry.axes[n] for n in kin.axis_names]
        self._home = np.asarray(kin.home_deg, float)
        self._offset_s = 0.0  # campaign clock − gantry clock
        # (positions, clock) of the last committed reading: where the next step's path starts
        self._rest: tuple[np.ndarray, float] | None = None
        # The target the axes last arrived at (within position_tolerance_deg; set by _arrive, cleared by
        # every command), or None
        self._arrived: np.ndarray | None = None
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

    def _to(self, new: State, message: str = "") -> None:
        with self._lock:
            old = self._state
            if new not in TRANSITIONS[old]:
                raise TransitionError(f"runner: cannot go from '{old}' to '{new}'")
            self._state = new
        self.journal.log_event("state", state=str(new), message=message or f"{old} -> {new}",
                               campaign_s=self.campaign_s())
        log.info("campaign %s -> %s %s", old, new, message)

    def request_pause(self, reason: str = "pause requested") -> None:
        """Pause at the next step boundary, then park (from any thread).

        The request is journaled before the runner's thread is told, so the journal never shows the
        park (or the paused state) before the pause that caused it."""
        with self._lock:
            pausing = self._state == State.RUNNING
            if pausing:
                self._state = State.PAUSING
        if pausing:
            self.journal.log_event("pause", state=str(State.PAUSING), message=reason,
                                   campaign_s=self.campaign_s())
        self._pause.set()

    def request_abort(self) -> None:
        """Abort at the next step boundary and park; a paused, halted, faulted or idle campaign aborts at
        once and nothing moves."""
        self._abort.set()
        if self._state in (State.PAUSED, State.FAULTED, State.IDLE, State.HALTED):
            self._to(State.ABORTED, "abort requested")

    def request_halt(self, reason: str = "halt requested") -> None:
        """Emergency stop (from any thread): every axis stops now, mid-move too; nothing is parked.

        The runner's thread notices within one ``poll_s`` slice and ends the run ``halted``.
        """
        self._halt.set()
        with self._command_lock:
            try:
                self.gantry.stop()
            except Exception as err:  # the halt stands; a failing stop is recorded beside it
                self.journal.log_event("fault", message=f"stop failed during halt: {err}",
                                       campaign_s=self.campaign_s())
        self.journal.log_event("halt", message=reason, campaign_s=self.campaign_s())

    def clear_fault(self, operator_note: str = "cleared by the operator") -> None:
        """Clear a latched fault: the devices' own latches (reboot, alarm reset) and the journal's."""
        if self._state not in (State.FAULTED, State.IDLE):
            raise TransitionError(f"runner: campaign is {self._state}; there is no fault to clear")
        for axis in self._axes:
            if axis.fault() is not None:
                axis.clear_fault()
        if self.journal.latched_fault() is not None:
            self.journal.delete_meta("latched_fault")
        self.journal.log_event("fault-cleared", message=f"{self.fault or 'no fault'}: {operator_note}",
                               campaign_s=self.journal.campaign_clock()[0])
        self.fault = None

    # -- running ---------------------------------------------------------------------------------
    def run(self, units: Iterable[Unit] | None = None) -> State:
        """Run (or resume) from the first step the journal has no measurement for.

        ``units`` (default: one per step, stop-and-go) are measured and committed whole, in order; the
        units whose first step the journal holds are skipped (a fly campaign's sweeps).

        Returns the state it stopped in: done, paused, halted, aborted or faulted. A campaign whose
        fault is latched returns ``faulted`` at once without touching the gantry. A pause halted while it
        parks ends ``halted``.
        """
        self._run(units)
        return self._state

    def _run(self, units: Iterable[Unit] | None) -> State:
        if self._state in (State.DONE, State.ABORTED):
            raise TransitionError(f"runner: campaign is {self._state}; nothing to run")
        latched = self.journal.latched_fault()
        if latched is not None:
            self.fault = latched["reason"]
            self._state = State.FAULTED
            return self._state
        self.journal.note_unclean_stop()   # the last run was killed mid-way: the journal says so first
        self._pause.clear()
        self._rest = None
        self._arrived = None
        self._halt.clear()
        self._start_clock()
        step = self.journal.next_step()
        n = self.journal.step_count()
        self._to(State.RUNNING, f"{'resume' if step > 0 else 'start'} at step {step}")
        self.fault = None
        park = True
        try:
            self.gantry.light.set_on(True)
            self.gantry.set_target("sample")
            if units is None:
                units = (Unit(s, 1, lambda attempt, s=s: [self._measure_step(s, attempt)])
                         for s in range(step, n))
            else:
                done = set(self.journal.done_steps().tolist())
                units = [u for u in units if u.first not in done]
            for unit in units:
                step = unit.first
                if self._abort.is_set():
                    self._to(State.ABORTED, f"aborted before step {step}")
                    return self._state
                if self._pause.is_set():
                    self._to(State.PAUSED, f"paused before step {step}")
                    return self._state
                self._run_unit(unit)
                if self.on_step is not None:
                    self.on_step(self, unit.first + unit.count - 1)
            self._to(State.DONE, f"{n} steps measured")
            return self._state
        except _Halted:
            park = False
            self._to(State.HALTED, f"halted during step {step}")
            return self._state
        except _Fault as err:
            park = False
            self._fail(str(err), [err.device])
            return self._state
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

    def _start_clock(self) -> None:
        base, last_wall = self.journal.campaign_clock()
        if getattr(self.gantry.clock, "real_time", False) and last_wall is not None:
            base += max(0.0, time.time() - last_wall)  # a lamp drifts while nobody runs the gantry
        self._offset_s = base - self.gantry.clock.now()

    def _fail(self, reason: str, devices: list[str]) -> None:
        self.fault = reason
        self._stop_all()
        self.journal.latch_fault(reason, devices)
        self.journal.log_event("fault", message=reason, campaign_s=self.campaign_s())
        if self._state in (State.RUNNING, State.PAUSING):
            self._to(State.FAULTED, reason)

    def _journal_warnings(self, step: int | None = None) -> None:
        """Hardware warnings the devices reported (they went on: a warning, not a fault)."""
        drain = getattr(self.gantry, "drain_warnings", None)
        if drain is not None:
            for device, message in drain():
                self.journal.log_event("warning", step=step, message=f"{device}: {message}",
                                       campaign_s=self.campaign_s())

    def _finish(self, park: bool) -> None:
        """Light off; park along a safe path after done, pause and abort; record where the axes stand,
        the hardware warnings and what the drivers could not trust on the way."""
        try:
            self.gantry.light.set_on(False)
        except Exception as err:
            self.journal.log_event("fault", message=f"light off failed: {err}", campaign_s=self.campaign_s())
        try:
            if park:
                self._goto(self._home)
            self.journal.log_event("park" if park else "stopped", message="axes home" if park else
                                   "axes left where they stopped", campaign_s=self.campaign_s(),
                                   axes_deg=self._positions())
        except _Halted:
            # A halt (a second Ctrl-C) while parking: the axes stop where they are, as a halt says. The
            # campaign is halted, not paused, unless it had finished or been aborted.
            self.journal.log_event("stopped", message="halted while parking: axes left where they stopped",
                                   campaign_s=self.campaign_s(), axes_deg=self._positions())
            if self._state == State.PAUSED:
                self._to(State.HALTED, "halted while parking")
        except Exception as err:
            reason = str(err) or type(err).__name__
            self.journal.log_event("fault", message=f"park failed: {reason}", campaign_s=self.campaign_s())
        self._journal_warnings()
        report = getattr(self.gantry, "link_report", None)
        line = report() if report is not None else None
        if line:
            self.journal.log_event("link", message=line, campaign_s=self.campaign_s())

    def _run_unit(self, unit: Unit) -> None:
        """Measure and commit one unit (a step, or a sweep in one transaction), retrying transient
        faults."""
        retries = self.cfg.runner.retries
        step = unit.first
        for attempt in range(1, retries + 2):
            try:
                ms = unit.measure(attempt)
            except DeviceFault as err:
                if not err.transient:
                    raise _Fault(err.device, str(err).removeprefix(f"{err.device}: ")) from None
                self._stop_all()
                if attempt > retries:
                    raise _Fault(err.device, f"step {step}: {str(err).removeprefix(f'{err.device}: ')} "
                                 f"(gave up after {retries} retries)") from None
                self.journal.log_event("retry", step=step, campaign_s=self.campaign_s(),
                                       message=f"step {step}, attempt {attempt}: {err}; retrying")
                continue
            if self._halt.is_set():
                raise _Halted  # the reading is whole, but a halt means nothing more is committed
            if unit.count == 1:
                self.journal.commit_measurement(ms[0])
                self._rest = (ms[0].actual_deg, self.gantry.clock.now())
            else:  # a sweep: the axes stand at its run-down's end, not where its readings were
                self.journal.commit_measurements(ms)
            self._journal_warnings(step)
            return
        raise AssertionError("unreachable")  # pragma: no cover

    def _measure_step(self, step: int, attempt: int) -> Measurement:
        s = self._steps
        kind = int(s["kind"][step])
        g = self.gantry
        det = self.cfg.detector
        key = (step, attempt)
        if kind == STEP_DARK:
            commanded = self._positions()
            g.light.set_on(False)
            try:
                reading = g.detector.measure(det.exposure_s, det.frames, key=key)
            finally:
                g.light.set_on(True)
        else:
            commanded = s["axes_deg"][step]
            self._goto(commanded)
            self._wait(self.cfg.runner.settle_s)
            if kind == STEP_REFERENCE:
                g.set_target("reference")
                try:
                    reading = g.detector.measure(det.exposure_s, det.frames, key=key)
                finally:
                    g.set_target("sample")
            else:
                reading = g.detector.measure(det.exposure_s, det.frames, key=key)
            self._check_lit(step)
        actual = self._positions()
        ti, pi_, to, po = self._kin.forward(actual[None, :])
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

    # -- motion ----------------------------------------------------------------------------------
    def _positions(self) -> np.ndarray:
        read = getattr(self.gantry, "positions", None)  # batched: one read per bus (AssembledGantry)
        if read is not None:
            return read()
        return np.array([a.position_deg() for a in self._axes], dtype=float)

    def _start_positions(self) -> np.ndarray:
        """Where the axes stand before a move: the positions the last committed reading read, when
        nothing was commanded since and no more than ``poll_s`` passed (one read of every axis fewer
        per step on real buses); otherwise read now.

        When every axis is within ``position_tolerance_deg`` of the last target it arrived at, that
        target is returned instead: the axes are there as far as the arrival check can tell, and the
        path then starts where the planner certified it. A read-back a few encoder ticks from a pose
        planned exactly at a clearance (a free azimuth stepped aside to arm_collision_deg) would
        otherwise count as a start inside the forbidden zone, from which no path is clear; and axes
        whose target does not change are not commanded again."""
        rest, self._rest = self._rest, None
        if rest is not None and self.gantry.clock.now() - rest[1] <= self.cfg.runner.poll_s:
            actual = rest[0].copy()
        else:
            actual = self._positions()
        there = self._arrived
        if there is not None and np.all(np.abs(actual - there) <= self.cfg.runner.position_tolerance_deg):
            return there.copy()
        return actual

    def _poll(self) -> tuple[np.ndarray | None, bool]:
        """(positions, whether any axis moves): one batched read where the gantry offers it; else the
        axes are asked one by one, and positions come later."""
        poll = getattr(self.gantry, "poll_axes", None)
        if poll is None:
            return None, any(a.is_moving() for a in self._axes)
        return poll()

    def _goto(self, target: np.ndarray) -> None:
        """Move to ``target`` along a collision-free path, leg by leg; every target is checked against
        the limits and the sweep check before any axis is commanded."""
        target = np.asarray(target, dtype=float)
        try:
            check_targets(self._kin, target)
            start = self._start_positions()
            path = safe_path(self._kin, start, target)
        except ValueError as err:
            raise _Fault("gantry", str(err)) from None
        for leg in path:
            self._move_leg(start, leg)
            start = leg

    def _command(self, send: Callable[[], object]) -> object:
        """``send()`` (commands to the axes) under the command lock, unless a halt was requested; if it
        fails, every axis stops (none may go on toward a half-made pose)."""
        with self._command_lock:
            if self._halt.is_set():
                raise _Halted
            self._arrived = None  # the axes leave where they arrived; _arrive records the new target
            try:
                return send()
            except BaseException:
                self._stop_all()
                raise

    def _move_leg(self, start: np.ndarray, target: np.ndarray) -> None:
        moved = target != start

        def send():
            move = getattr(self.gantry, "move_axes", None)  # batched: one write per bus
            if move is not None:
                move({n: float(t) for n, t, m in zip(self._kin.axis_names, target, moved, strict=True) if m})
            else:
                for axis, t, m in zip(self._axes, target, moved, strict=True):
                    if m:
                        axis.move_to(float(t))

        self._command(send)
        expected = float(np.max(move_time(target - start, self._vmax, self._amax), initial=0.0))
        self._arrive(start, target, expected)

    def _arrive(self, start: np.ndarray, target: np.ndarray, expected: float) -> None:
        """Wait for a commanded move from ``start`` to ``target`` (``expected`` s) to end, then check
        every axis arrived: a fault where one stopped short, a transient fault where one is a little off."""
        rc = self.cfg.runner
        # Wait the time the profile needs in short slices (a halt acts within one), then poll.
        expected = max(float(expected), 0.0)
        self._wait(min(expected, rc.move_timeout_s))
        waited = expected
        actual, moving = self._poll()
        while moving:
            if waited >= rc.move_timeout_s:
                self._stop_all()
                raise DeviceFault("gantry", f"axes did not arrive within move_timeout_s={rc.move_timeout_s}",
                                  transient=True)
            self._wait(rc.poll_s)
            waited += rc.poll_s
            actual, moving = self._poll()
        if self._halt.is_set():
            raise _Halted
        if actual is None:
            actual = self._positions()
        err = np.abs(actual - target)
        bad = np.flatnonzero(err > rc.position_tolerance_deg)
        if bad.size:
            i = int(bad[0])
            name = self._axes[i].name
            lo, hi = sorted((start[i], target[i]))
            if lo + rc.position_tolerance_deg < actual[i] < hi - rc.position_tolerance_deg:
                # Between start and target: stopped by someone else, or blocked. Never retried blindly.
                raise _Fault(name, f"stopped at {actual[i]:.4f}°, {err[i]:.4f}° short of its target "
                             f"{target[i]:.4f}° (stopped by another client, or blocked): inspect the "
                             "gantry, then clear the fault to resume")
            raise DeviceFault(name, f"position {actual[i]:.4f}° is {err[i]:.4f}° from target "
                              f"{target[i]:.4f}° (position_tolerance_deg={rc.position_tolerance_deg})",
                              transient=True)
        self._arrived = np.array(target, dtype=float)

    def _wait(self, seconds: float) -> None:
        """Sleep ``seconds`` on the gantry clock in slices of ``poll_s``, raising at a halt; between
        slices a gantry with ``keep_alive`` reads its axes when an armed bus watchdog needs to hear."""
        poll = self.cfg.runner.poll_s
        clock = self.gantry.clock
        keep_alive = getattr(self.gantry, "keep_alive", None)
        start = clock.now()
        end = start + seconds  # the instant the slowest axis arrives, computed as the axis computes it
        k = 0
        while clock.now() < end:
            if self._halt.is_set():
                raise _Halted
            k += 1
            clock.sleep_until(min(start + k * poll, end))
            if keep_alive is not None:
                keep_alive()
        if self._halt.is_set():
            raise _Halted

    def _stop_all(self) -> None:
        """Stop every axis, then wait (bounded) until all are still, so nothing is commanded mid-brake."""
        rc = self.cfg.runner
        with self._command_lock:
            try:
                self.gantry.stop()
            except Exception as err:
                self.journal.log_event("fault", message=f"stop failed: {err}", campaign_s=self.campaign_s())
                return
        waited = 0.0
        clock = self.gantry.clock
        while waited < rc.move_timeout_s:
            try:
                if not any(a.is_moving() for a in self._axes):
                    return
            except DeviceFault:
                return  # an axis that cannot be asked cannot be waited for; the fault says why
            clock.sleep(rc.poll_s)
            waited += rc.poll_s
        self.journal.log_event("fault", message=f"axes still moving {rc.move_timeout_s} s after stop",
                               campaign_s=self.campaign_s())
