"""The motion executor: the public way a unit moves the gantry, waits and stops it.

The engine (:mod:`gonio.runner`) runs units; a unit (a stop-and-go step, a fly sweep) moves the gantry
through one :class:`MotionExecutor`, which every unit of a run shares:

``goto(target)``
    Every target checked against the limits and the swept-path check, then a collision-free path from
    where the axes stand (:func:`gonio.motion.safe.safe_path`) moved leg by leg, only the axes whose
    target changed, each leg waited for (:meth:`arrive`).
``wait(seconds)`` / ``settle()``
    Sleep on the gantry clock in slices of ``runner.poll_s``, so that a halt acts within one; between
    slices a gantry that must feed a bus watchdog (:class:`~gonio.protocols.KeepsAlive`) reads its axes.
``command(send)``
    Commands to the axes (a batch of moves, a sweep's start) under the command lock, never once a halt
    was requested; if they fail, every axis stops (none may go on toward a half-made pose).
``arrive(start, target, expected)``
    Wait for a commanded move to end and check that every axis arrived: :class:`MotionFault` where one
    stopped short (between start and target: stopped by someone else, or blocked), a transient
    :class:`~gonio.protocols.DeviceFault` where one is a little off.
``stop()``
    Stop every axis and wait (bounded) until all are still.
``positions()``
    The axes' positions, one batched read where the gantry declares :class:`~gonio.protocols.BatchedAxes`.
``halt()``
    From any thread: every axis stops now, mid-move too; every later wait or command raises
    :class:`Halted` until the next run :meth:`begin`\\ s.

The executor knows nothing of journals, steps or states: what it must record (a stop that failed) it
hands to ``on_event(kind, message)``.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from gonio.gantry import abilities
from gonio.motion.safe import check_targets, safe_path
from gonio.motion.trapezoid import move_time
from gonio.protocols import DeviceFault, Gantry

if TYPE_CHECKING:  # type hints only: the caller holds the config
    from gonio.config import RunnerConfig

__all__ = ["MotionExecutor", "Halted", "MotionFault"]


class Halted(Exception):
    """A halt was requested: raised by the executor in the engine's thread (never leaves the engine)."""


class MotionFault(Exception):
    """A fault that stops the campaign and latches (an axis stopped short, a target beyond a limit, a
    move with no safe path): not a device's transient hiccup."""

    def __init__(self, device: str, message: str):
        super().__init__(f"{device}: {message}")
        self.device = device


class MotionExecutor:
    """Moves, waits and stops on ``gantry`` for the units of a run (see the module docstring).

    Parameters
    ----------
    gantry : Gantry
        Connected. Its declared abilities are asked once, here (:func:`gonio.gantry.abilities`).
    rc : RunnerConfig
        ``poll_s``, ``settle_s``, ``move_timeout_s``, ``position_tolerance_deg``.
    on_event : callable, optional
        ``on_event(kind, message)``: what must be recorded (``fault``: a stop that failed).
    """

    def __init__(self, gantry: Gantry, rc: RunnerConfig,
                 on_event: Callable[[str, str], None] | None = None):
        self.gantry = gantry
        self.rc = rc
        self.abilities = abilities(gantry)
        self.kinematics = kin = gantry.kinematics
        self.home_deg = np.asarray(kin.home_deg, float)
        self._on_event = on_event or (lambda kind, message: None)
        self._axes = [gantry.axes[n] for n in kin.axis_names]
        self._vmax = np.asarray(kin.velocity_deg_s, float)
        self._amax = np.asarray(kin.accel_deg_s2, float)
        self._vmax_list, self._amax_list = self._vmax.tolist(), self._amax.tolist()
        self._halt = threading.Event()
        # Held while axes are being commanded: a halt waits for a batch of commands to be sent, then
        # stops every axis; no batch starts once the halt flag is set.
        self._command_lock = threading.RLock()
        # (positions, clock) of the last committed reading: where the next path starts
        self._rest: tuple[np.ndarray, float] | None = None
        # The target the axes last arrived at (within position_tolerance_deg; set by arrive, cleared by
        # every command), or None
        self._arrived: np.ndarray | None = None

    # -- a run, and its halt -----------------------------------------------------------------------
    def begin(self) -> None:
        """A new run: no halt, nothing known of where the axes stand."""
        self._halt.clear()
        self._rest = None
        self._arrived = None

    @property
    def halted(self) -> bool:
        return self._halt.is_set()

    def check_halt(self) -> None:
        """Raise :class:`Halted` when a halt was requested."""
        if self._halt.is_set():
            raise Halted

    def halt(self) -> Exception | None:
        """Emergency stop (from any thread): every axis stops now, mid-move too; nothing further is
        commanded. Returns the error of a stop that failed (the halt stands), else None."""
        self._halt.set()
        with self._command_lock:
            try:
                self.gantry.stop()
            except Exception as err:
                return err
        return None

    # -- reading where the axes are ----------------------------------------------------------------
    def positions(self) -> np.ndarray:
        """The kinematics' axes' positions (°): one batched read where the gantry has it."""
        batched = self.abilities.batched
        if batched is not None:
            return batched.positions()
        return np.array([a.position_deg() for a in self._axes], dtype=float)

    def note_rest(self, positions: np.ndarray) -> None:
        """The positions a committed reading read: the next move starts there when nothing was commanded
        since and no more than ``poll_s`` passed (one read of every axis fewer per step on real buses)."""
        self._rest = (np.asarray(positions, float), self.gantry.clock.now())

    def _start_positions(self) -> np.ndarray:
        """Where the axes stand before a move: the rest :meth:`note_rest` recorded, if recent; otherwise
        read now.

        When every axis is within ``position_tolerance_deg`` of the last target it arrived at, that
        target is returned instead: the axes are there as far as the arrival check can tell, and the
        path then starts where the planner certified it. A read-back a few encoder ticks from a pose
        planned exactly at a clearance (a free azimuth stepped aside to arm_collision_deg) would
        otherwise count as a start inside the forbidden zone, from which no path is clear; and axes
        whose target does not change are not commanded again."""
        rest, self._rest = self._rest, None
        if rest is not None and self.gantry.clock.now() - rest[1] <= self.rc.poll_s:
            actual = rest[0].copy()
        else:
            actual = self.positions()
        there = self._arrived
        tol = self.rc.position_tolerance_deg
        if there is not None and all(abs(x - t) <= tol for x, t in zip(actual.tolist(), there.tolist(),
                                                                       strict=True)):
            return there.copy()
        return actual

    def _poll(self) -> tuple[np.ndarray | None, bool]:
        """(positions, whether any axis moves): one batched read where the gantry offers it; else the
        axes are asked one by one, and positions come later."""
        batched = self.abilities.batched
        if batched is None:
            return None, any(a.is_moving() for a in self._axes)
        return batched.poll_axes()

    # -- moving --------------------------------------------------------------------------------------
    def goto(self, target: np.ndarray) -> None:
        """Move to ``target`` along a collision-free path, leg by leg; every target is checked against
        the limits and the sweep check before any axis is commanded (:class:`MotionFault` if refused)."""
        target = np.asarray(target, dtype=float)
        kin = self.kinematics
        try:
            check_targets(kin, target)
            start = self._start_positions()
            path = safe_path(kin, start, target, self.rc.position_tolerance_deg)
        except ValueError as err:
            raise MotionFault("gantry", str(err)) from None
        for leg in path:
            self._move_leg(start, leg)
            start = leg

    def settle(self) -> None:
        """Wait ``runner.settle_s`` (vibrations die down after a move)."""
        self.wait(self.rc.settle_s)

    def command(self, send: Callable[[], object]) -> object:
        """``send()`` (commands to the axes) under the command lock, unless a halt was requested
        (:class:`Halted`); if it fails, every axis stops (none may go on toward a half-made pose)."""
        with self._command_lock:
            if self._halt.is_set():
                raise Halted
            self._arrived = None  # the axes leave where they arrived; arrive() records the new target
            try:
                return send()
            except BaseException:
                self.stop()
                raise

    def _move_leg(self, start: np.ndarray, target: np.ndarray) -> None:
        self.send_move(start, target)
        # The slowest axis's profile, in plain floats (the same value numpy gives; one move per step)
        expected = max((move_time(t - s, v, a) for s, t, v, a in
                        zip(start.tolist(), target.tolist(), self._vmax_list, self._amax_list, strict=True)),
                       default=0.0)
        self.arrive(start, target, expected)

    def send_move(self, start: np.ndarray, target: np.ndarray) -> None:
        """Command the axes whose ``target`` differs from ``start`` (one write per bus where the gantry
        batches), without waiting (the caller then calls :meth:`arrive`). Unchecked: for a move whose
        whole path its caller certified (a fly turnaround's change, while the sweeping axis runs out)."""
        target = np.asarray(target, dtype=float).tolist()
        moved = [t != s for t, s in zip(target, np.asarray(start, dtype=float).tolist(), strict=True)]
        names = self.kinematics.axis_names
        batched = self.abilities.batched

        def send():
            if batched is not None:  # one write per bus
                batched.move_axes({n: t for n, t, m in zip(names, target, moved, strict=True) if m})
            else:
                for axis, t, m in zip(self._axes, target, moved, strict=True):
                    if m:
                        axis.move_to(t)

        self.command(send)

    def arrive(self, start: np.ndarray, target: np.ndarray, expected: float) -> None:
        """Wait for a commanded move from ``start`` to ``target`` (``expected`` s) to end, then check
        every axis arrived: :class:`MotionFault` where one stopped short, a transient DeviceFault where
        one is a little off, or did not arrive within ``move_timeout_s``."""
        rc = self.rc
        # Wait the time the profile needs in short slices (a halt acts within one), then poll.
        expected = max(float(expected), 0.0)
        self.wait(min(expected, rc.move_timeout_s))
        waited = expected
        actual, moving = self._poll()
        while moving:
            if waited >= rc.move_timeout_s:
                self.stop()
                raise DeviceFault("gantry", f"axes did not arrive within move_timeout_s={rc.move_timeout_s}",
                                  transient=True)
            self.wait(rc.poll_s)
            waited += rc.poll_s
            actual, moving = self._poll()
        self.check_halt()
        if actual is None:
            actual = self.positions()
        tol = rc.position_tolerance_deg
        if any(abs(x - t) > tol for x, t in zip(np.asarray(actual, dtype=float).tolist(),
                                                 np.asarray(target, dtype=float).tolist(), strict=True)):
            err = np.abs(actual - target)
            bad = np.flatnonzero(err > tol)
            i = int(bad[0])
            name = self._axes[i].name
            lo, hi = sorted((start[i], target[i]))
            if lo + rc.position_tolerance_deg < actual[i] < hi - rc.position_tolerance_deg:
                # Between start and target: stopped by someone else, or blocked. Never retried blindly.
                raise MotionFault(name, f"stopped at {actual[i]:.4f}°, {err[i]:.4f}° short of its target "
                                  f"{target[i]:.4f}° (stopped by another client, or blocked): inspect the "
                                  "gantry, then clear the fault to resume")
            raise DeviceFault(name, f"position {actual[i]:.4f}° is {err[i]:.4f}° from target "
                              f"{target[i]:.4f}° (position_tolerance_deg={rc.position_tolerance_deg})",
                              transient=True)
        self._arrived = np.array(target, dtype=float)

    def wait(self, seconds: float) -> None:
        """Sleep ``seconds`` on the gantry clock in slices of ``poll_s``, raising :class:`Halted` at a
        halt; between slices a gantry that keeps its axes alive reads them when an armed bus watchdog
        needs to hear."""
        poll = self.rc.poll_s
        clock = self.gantry.clock
        now, sleep_until, halted = clock.now, clock.sleep_until, self._halt.is_set   # looked up once
        keep_alive = self.abilities.keep_alive
        start = now()
        end = start + seconds  # the instant the slowest axis arrives, computed as the axis computes it
        k = 0
        while now() < end:
            if halted():
                raise Halted
            k += 1
            sleep_until(min(start + k * poll, end))
            if keep_alive is not None:
                keep_alive.keep_alive()
        if halted():
            raise Halted

    def stop(self) -> None:
        """Stop every axis, then wait (bounded) until all are still, so nothing is commanded mid-brake."""
        rc = self.rc
        with self._command_lock:
            try:
                self.gantry.stop()
            except Exception as err:
                self._on_event("fault", f"stop failed: {err}")
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
        self._on_event("fault", f"axes still moving {rc.move_timeout_s} s after stop")
