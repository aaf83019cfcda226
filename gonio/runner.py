"""The runner: executes a journaled plan on a gantry, one committed step at a time.

An explicit state machine (``TRANSITIONS``) guards every change of state; pause, resume and abort take
effect at step boundaries. For each step: move the axes whose target changed, wait (the expected
trapezoid time, then poll), verify the positions within tolerance, settle, measure, commit. Transient
device faults are retried; a hardware fault stops every axis and leaves the campaign ``faulted`` with
the reason. The gantry is parked (light off, axes home) in a ``finally``. The runner never sees bytes:
it talks to the gantry through the protocols in :mod:`gonio.protocols`.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from enum import StrEnum

import numpy as np

from gonio.config import GonioConfig
from gonio.motion.trapezoid import move_time
from gonio.plan.schedule import STEP_DARK, STEP_REFERENCE
from gonio.protocols import DeviceFault, Gantry
from gonio.store import Journal, Measurement

__all__ = ["Runner", "State", "TRANSITIONS", "TransitionError"]

log = logging.getLogger(__name__)


class State(StrEnum):
    IDLE = "idle"
    RUNNING = "running"
    PAUSING = "pausing"
    PAUSED = "paused"
    DONE = "done"
    ABORTED = "aborted"
    FAULTED = "faulted"


#: from-state -> the states it may go to. ``faulted`` may resume once the cause is cleared.
TRANSITIONS: dict[State, frozenset[State]] = {
    State.IDLE: frozenset({State.RUNNING, State.ABORTED}),
    State.RUNNING: frozenset({State.PAUSING, State.DONE, State.ABORTED, State.FAULTED}),
    State.PAUSING: frozenset({State.PAUSED, State.DONE, State.ABORTED, State.FAULTED}),
    State.PAUSED: frozenset({State.RUNNING, State.ABORTED}),
    State.FAULTED: frozenset({State.RUNNING, State.ABORTED}),
    State.DONE: frozenset(),
    State.ABORTED: frozenset(),
}


class TransitionError(RuntimeError):
    pass


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
        self._pause = threading.Event()
        self._abort = threading.Event()
        self.fault: str | None = None
        self._steps = journal.steps()
        kin = gantry.kinematics
        self._vmax = np.asarray(kin.velocity_deg_s, float)
        self._amax = np.asarray(kin.accel_deg_s2, float)
        self._axes = [gantry.axes[n] for n in kin.axis_names]
        self._target: np.ndarray | None = None  # last commanded targets

    # -- state -----------------------------------------------------------------------------------
    @property
    def state(self) -> State:
        return self._state

    def _to(self, new: State, message: str = "") -> None:
        with self._lock:
            old = self._state
            if new not in TRANSITIONS[old]:
                raise TransitionError(f"runner: cannot go from '{old}' to '{new}'")
            self._state = new
        self.journal.log_event("state", state=str(new), message=message or f"{old} -> {new}",
                               virtual_s=self.gantry.clock.now())
        log.info("campaign %s -> %s %s", old, new, message)

    def request_pause(self) -> None:
        """Pause at the next step boundary (from any thread)."""
        self._pause.set()
        with self._lock:
            pausing = self._state == State.RUNNING
            if pausing:
                self._state = State.PAUSING
        if pausing:
            self.journal.log_event("pause", state=str(State.PAUSING), message="pause requested")

    def request_abort(self) -> None:
        """Abort at the next step boundary; a paused, faulted or idle campaign aborts at once."""
        self._abort.set()
        if self._state in (State.PAUSED, State.FAULTED, State.IDLE):
            self._to(State.ABORTED, "abort requested")

    # -- running ---------------------------------------------------------------------------------
    def run(self) -> State:
        """Run (or resume) from the first step the journal has no measurement for.

        Returns the state it stopped in: done, paused, aborted or faulted.
        """
        if self._state in (State.DONE, State.ABORTED):
            raise TransitionError(f"runner: campaign is {self._state}; nothing to run")
        self._pause.clear()
        step = self.journal.next_step()
        resumed = step > 0
        self._to(State.RUNNING, f"{'resume' if resumed else 'start'} at step {step}")
        self.fault = None
        n = self.journal.step_count()
        try:
            self.gantry.light.set_on(True)
            self.gantry.set_target("sample")
            while step < n:
                if self._abort.is_set():
                    self._to(State.ABORTED, f"aborted before step {step}")
                    return self._state
                if self._pause.is_set():
                    self._to(State.PAUSED, f"paused before step {step}")
                    return self._state
                if not self._run_step(step):
                    return self._state
                if self.on_step is not None:
                    self.on_step(self, step)
                step += 1
            self._to(State.DONE, f"{n} steps measured")
            return self._state
        except DeviceFault as err:
            self._fail(str(err))
            return self._state
        except Exception as err:
            self._fail(f"{type(err).__name__}: {err}")
            raise
        finally:
            self._park()

    def _fail(self, reason: str) -> None:
        self.fault = reason
        try:
            self.gantry.stop()
        except Exception as err:  # the fault is what matters; a failing stop is logged beside it
            self.journal.log_event("fault", message=f"stop failed: {err}")
        self.journal.log_event("fault", message=reason, virtual_s=self.gantry.clock.now())
        if self._state in (State.RUNNING, State.PAUSING):
            self._to(State.FAULTED, reason)

    def _park(self) -> None:
        try:
            self.gantry.light.set_on(False)
            self.gantry.park()
            self._target = None
        except Exception as err:
            self.journal.log_event("fault", message=f"park failed: {err}",
                                   virtual_s=self.gantry.clock.now())

    def _run_step(self, step: int) -> bool:
        """Measure and commit one step, retrying transient faults. False when the campaign faulted."""
        retries = self.cfg.runner.retries
        events: list[tuple[str, str | None, str]] = []
        for attempt in range(1, retries + 2):
            try:
                m = self._measure_step(step, attempt)
            except DeviceFault as err:
                if err.transient and attempt <= retries:
                    msg = f"step {step}, attempt {attempt}: {err}; retrying"
                    events.append(("retry", None, msg))
                    self.journal.log_event("retry", step=step, message=msg,
                                           virtual_s=self.gantry.clock.now())
                    self._target = None  # re-command every axis on the next attempt
                    continue
                self._fail(f"step {step}: {err}")
                return False
            self.journal.commit_measurement(m)
            return True
        raise AssertionError("unreachable")  # pragma: no cover

    def _measure_step(self, step: int, attempt: int) -> Measurement:
        s = self._steps
        kind = int(s["kind"][step])
        g = self.gantry
        if kind == STEP_DARK:
            commanded = self._current_positions() if self._target is None else self._target
            g.light.set_on(False)
            try:
                reading = g.detector.measure(self.cfg.detector.exposure_s, self.cfg.detector.frames)
            finally:
                g.light.set_on(True)
        else:
            commanded = s["axes_deg"][step]
            self._move(commanded)
            g.clock.sleep(self.cfg.runner.settle_s)
            if kind == STEP_REFERENCE:
                g.set_target("reference")
                try:
                    reading = g.detector.measure(self.cfg.detector.exposure_s, self.cfg.detector.frames)
                finally:
                    g.set_target("sample")
            else:
                reading = g.detector.measure(self.cfg.detector.exposure_s, self.cfg.detector.frames)
        actual = self._current_positions()
        ti, pi_, to, po = g.kinematics.forward(actual[None, :])
        angles = np.degrees([ti[0], pi_[0], to[0], po[0]])
        return Measurement(
            step=step, kind=kind, pose=int(s["pose"][step]), commanded_deg=np.asarray(commanded, float),
            actual_deg=actual, angles_deg=angles, virtual_s=g.clock.now(), exposure_s=reading.exposure_s,
            frames=reading.frames, signal=reading.signal, stderr=reading.stderr, attempts=attempt)

    def _current_positions(self) -> np.ndarray:
        return np.array([a.position_deg() for a in self._axes], dtype=float)

    def _move(self, target: np.ndarray) -> None:
        """Move every axis whose target changed; wait; verify the positions within tolerance."""
        rc = self.cfg.runner
        clock = self.gantry.clock
        # Where the axes stand: the last verified targets, or read back when unknown (start, retry).
        current = self._current_positions() if self._target is None else self._target
        moved = np.ones(len(self._axes), bool) if self._target is None else target != self._target
        for axis, t, m in zip(self._axes, target, moved, strict=True):
            if m:
                axis.move_to(float(t))
        self._target = np.array(target, float)
        # Sleep the time the profile needs, then poll: a handful of polls per move, not thousands.
        expected = float(np.max(move_time(target - current, self._vmax, self._amax), initial=0.0))
        clock.sleep(min(expected, rc.move_timeout_s))
        waited = expected
        while any(a.is_moving() for a in self._axes):
            if waited >= rc.move_timeout_s:
                self.gantry.stop()
                raise DeviceFault("gantry", f"axes did not arrive within move_timeout_s={rc.move_timeout_s}",
                                  transient=True)
            clock.sleep(rc.poll_s)
            waited += rc.poll_s
        actual = self._current_positions()
        err = np.abs(actual - target)
        bad = np.flatnonzero(err > rc.position_tolerance_deg)
        if bad.size:
            i = int(bad[0])
            raise DeviceFault(self._axes[i].name,
                              f"position {actual[i]:.4f}° is {err[i]:.4f}° from target {target[i]:.4f}° "
                              f"(position_tolerance_deg={rc.position_tolerance_deg})", transient=True)
