"""The gantry while no campaign runs: status, manual home and move, and the emergency halt.

The daemon owns one gantry. While a campaign runs, its runner drives it and manual moves are refused;
otherwise the daemon keeps an idle gantry (wired from the daemon's config, connected on first use and
closed before a campaign connects its own, so a real bus is never opened twice). A status request
connects its axes read-only (no torque, no goal, no watchdog: asking never energises the rig; the lamp
and detector are not connected, the light's state is then unknown, ``null``); a manual move reconnects
them to drive, and is refused (409, one line naming the axis and ``gonio gantry reference``) while an
axis is not referenced.

Every manual move is checked before anything moves: the pose is one the gantry can reach (the
kinematics' feasibility), every target is within its axis's limits (:func:`gonio.motion.safe.check_targets`)
and a collision-free path leads there from where the axes stand (:func:`gonio.motion.safe.safe_path`).
The path is driven leg by leg, waiting in slices of ``runner.poll_s``, so that a halt from another
request stops it mid-move.
"""

from __future__ import annotations

import logging
import threading

import numpy as np

from gonio.config import GonioConfig
from gonio.daemon.pacing import PacedClock
from gonio.daemon.records import Conflict, FieldError
from gonio.manual import arrived, close_axes, connect_axes, plan_move, pose_targets
from gonio.protocols import DeviceFault, Referencing
from gonio.reference import refusal, unreferenced

__all__ = ["GantryOwner", "ANGLES"]

log = logging.getLogger(__name__)

#: The arm angles of a manual move, in the order the kinematics take them.
ANGLES = ("theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg")


def reference_fr(cfg: GonioConfig) -> list[float]:
    """ρ_ref · response of the white standard per detector channel: a reading's ratio to the reference
    times this over π is f_r in sr⁻¹ (the web view's slice)."""
    d = cfg.detector
    return [float(x) for x in cfg.reference.reference_fr(d.channel_names, d.wavelengths_nm)]


def snapshot(gantry, owner: str | None, cfg: GonioConfig | None = None, light: bool = True) -> dict:
    """Axes (position, moving, fault, limits), the arm angles they make, light and detector (with the
    white standard's :func:`reference_fr` when ``cfg`` is given; ``light`` False: the lamp is not
    connected and is not asked)."""
    kin = gantry.kinematics
    axes, pos = [], []
    for name in kin.axis_names:
        a = gantry.axes[name]
        p = float(a.position_deg())
        pos.append(p)
        axes.append({"name": name, "position_deg": p, "moving": bool(a.is_moving()), "fault": a.fault(),
                     "limits_deg": [float(x) for x in a.limits_deg]})
    ti, pi_, to, po = (float(np.degrees(x[0])) for x in kin.forward(np.asarray(pos)[None, :]))
    lamp = gantry.light
    unreferenced = [n for n in kin.axis_names if isinstance(gantry.axes[n], Referencing)
                    and gantry.axes[n].reference_method != "none" and not gantry.axes[n].referenced()]
    return {"gantry": gantry.name, "owner": owner, "axes": axes,
            "angles": {"theta_i_deg": ti, "phi_i_deg": pi_, "theta_o_deg": to, "phi_o_deg": po},
            "moving": any(a["moving"] for a in axes), "faults": [a["name"] for a in axes if a["fault"]],
            "unreferenced": unreferenced,
            "light": {"name": lamp.name, "on": bool(lamp.is_on()) if light else None},
            "detector": {"name": gantry.detector.name, "channels": list(gantry.detector.channels),
                         **({"reference_fr": reference_fr(cfg)} if cfg is not None else {})}}


class GantryOwner:
    """The daemon's idle gantry (see the module docstring).

    Parameters
    ----------
    cfg : GonioConfig
        The daemon's gantry.
    pace : float
        Real seconds per gantry second of a simulated gantry.
    clock : Clock, optional
        Time source of a gantry with real devices (default: the wall clock).
    """

    def __init__(self, cfg: GonioConfig, pace: float = 0.0, *, clock=None):
        self.cfg = cfg
        self.pace = pace
        self.clock = clock
        self._gantry = None
        self._readonly = False               # the idle gantry's axes are connected read-only
        self._lock = threading.Lock()        # held while the idle gantry moves or is closed
        self._build = threading.Lock()       # held while it is wired and connected
        self._halt = threading.Event()

    def _idle(self, readonly: bool = False):
        """The idle gantry, wired and connected on first use: its axes only and read-only for
        ``readonly`` (a status), whole for a move (a read-only one is closed and connected again)."""
        with self._build:
            return self._idle_locked(readonly)

    def _idle_locked(self, readonly: bool):
        if self._gantry is not None and self._readonly and not readonly:
            close_axes(self._gantry.all_axes)
            self._gantry = None
        if self._gantry is None:
            from gonio.wiring import build_gantry

            sim = self.cfg.drivers() == {"sim"}
            material = f"lambert:albedo={self.cfg.reference.albedo!r}" if self.cfg.detector.driver == "sim" \
                else None
            g = build_gantry(self.cfg, material, clock=PacedClock(0.0, self.pace) if sim else self.clock)
            if readonly and not sim:
                connect_axes(g, keep_faulted=True, readonly=True)
            else:
                g.connect()
                readonly = False
            self._gantry, self._readonly = g, readonly
        return self._gantry

    def release(self) -> None:
        """Close the idle gantry (waits for a manual move in progress): a campaign is about to connect."""
        with self._lock, self._build:
            if self._gantry is not None:
                try:
                    if self._readonly:
                        close_axes(self._gantry.all_axes)
                    else:
                        self._gantry.close()
                finally:
                    self._gantry = None

    def status(self) -> dict:
        """The idle gantry's status; answers during a manual move too (reads only; see the module
        docstring)."""
        g = self._idle(readonly=True)
        return snapshot(g, None, self.cfg, light=not self._readonly)

    def unreferenced(self) -> list[str]:
        """The axes not referenced, looked at read-only (a submitted campaign is refused while any)."""
        g = self._idle(readonly=True)
        return unreferenced(g.all_axes)

    def halt(self) -> None:
        """Stop every axis of the idle gantry now, mid-move too (never waits for a lock)."""
        self._halt.set()
        g = self._gantry
        if g is not None:
            g.stop()
        log.warning("gantry: halt")

    def move(self, angles: dict | None) -> dict:
        """Drive to the pose ``angles`` (degrees, keys :data:`ANGLES`), or home for None; the status
        after. Raises FieldError for a pose that cannot be reached, Conflict when another move is under
        way or a halt stopped this one."""
        if not self._lock.acquire(blocking=False):
            raise Conflict("the gantry is busy (another manual move, or a campaign is starting)")
        try:
            missing = self.unreferenced()
            if missing:
                raise Conflict(refusal(missing))
            g = self._idle()
            kin = g.kinematics
            axes = [g.axes[n] for n in kin.axis_names]
            current = np.array([a.position_deg() for a in axes], float)
            try:
                target = (np.asarray(kin.home_deg, float) if angles is None
                          else pose_targets(kin, current, *(float(angles[k]) for k in ANGLES)))
                legs = plan_move(kin, current, target, self.cfg.runner.position_tolerance_deg)
            except ValueError as err:
                raise FieldError("move", str(err)) from None
            self._halt.clear()
            for leg in np.atleast_2d(legs):
                self._drive_leg(g, axes, leg)
            return snapshot(g, None, self.cfg)
        finally:
            self._lock.release()

    def _wait_still(self, g, axes) -> None:
        """After a stop: wait (bounded) until every axis has braked, so the status says where they stand
        (a virtual clock moves only when someone waits on it)."""
        rc = self.cfg.runner
        waited = 0.0
        try:
            while any(a.is_moving() for a in axes) and waited < rc.move_timeout_s:
                g.clock.sleep(rc.poll_s)
                waited += rc.poll_s
        except DeviceFault:
            pass  # an axis that cannot be asked cannot be waited for

    def _drive_leg(self, g, axes, leg) -> None:
        rc = self.cfg.runner
        clock = g.clock
        start = np.array([a.position_deg() for a in axes])
        try:
            for axis, t, s in zip(axes, leg, start, strict=True):
                if t != s:
                    axis.move_to(float(t))
            waited = 0.0
            while any(a.is_moving() for a in axes):
                if self._halt.is_set():
                    raise Conflict("halted: the move was stopped mid-way; the axes are left where they "
                                   "stopped")
                if waited >= rc.move_timeout_s:
                    raise DeviceFault("gantry", "axes did not arrive within "
                                      f"move_timeout_s={rc.move_timeout_s}")
                clock.sleep(rc.poll_s)
                waited += rc.poll_s
        except BaseException:
            g.stop()
            self._wait_still(g, axes)
            raise
        if self._halt.is_set():
            raise Conflict("halted: the move was stopped; the axes are left where they stopped")
        arrived(axes, leg, rc.position_tolerance_deg)
