"""Manual control of a configured gantry (``gonio gantry status|home|move|jog|stop|reboot|reference``).

``status`` connects the axes read-only (:func:`connect_axes` with ``readonly``): it sends no write of any
kind, so asking a rig for its state never energises it. A move, home or jog first looks read-only
whether every axis is referenced (:mod:`gonio.reference`) and is refused, nothing written, when one is not.

Every move is checked before anything moves: the target within every axis's limits
(:func:`gonio.motion.safe.check_targets`), a pose the gantry can reach (the kinematics' feasibility),
and a collision-free path from where the axes stand (:func:`gonio.motion.safe.safe_path`). The path is
then driven leg by leg, each leg waited for (bounded by ``runner.move_timeout_s``) and its arrival
verified within ``runner.position_tolerance_deg``.
"""

from __future__ import annotations

import numpy as np

from gonio.gantry import start_groups
from gonio.kinematics.base import REASONS
from gonio.motion.safe import check_targets, safe_path
from gonio.motion.trapezoid import move_time
from gonio.protocols import DeviceFault, Referencing

__all__ = ["axis_report", "pose_targets", "plan_move", "arrived", "drive", "connect_axes", "close_axes"]


def connect_axes(gantry, keep_faulted: bool = False, readonly: bool = False) -> dict:
    """Connect the gantry's axes only (and the changer's): manual moves need no lamp or detector.

    ``keep_faulted``: an axis whose connect reports its latched fault (a Modbus alarm) stays in the
    result, so that it can be looked at, stopped and rebooted. ``readonly``: the axes only read (no
    torque, no goal, no watchdog, not even when they are closed)."""
    axes = dict(gantry.all_axes)
    done = []
    try:
        for axis in axes.values():
            try:
                axis.connect(readonly=readonly)
            except DeviceFault:
                if not (keep_faulted and axis.fault() is not None):
                    raise
            done.append(axis)
    except BaseException:
        close_axes(done)
        raise
    return axes


def close_axes(axes) -> None:
    for axis in list(axes.values() if isinstance(axes, dict) else axes):
        try:
            axis.close()
        except Exception:  # closing the rest matters more than one axis's complaint
            pass


def axis_report(axis) -> dict:
    """One axis's target and read-back position, in degrees and in device units where it has them
    (:class:`~gonio.protocols.ReportsDeviceUnits`), and whether it is referenced (None: it never needs
    to be). Reads only."""
    from gonio.protocols import ReportsDeviceUnits

    moving, note = None, None
    try:
        moving = axis.is_moving()
    except DeviceFault as err:  # e.g. a bus watchdog that fired: the state is what is asked for
        note = str(err)
    out = {"axis": axis.name, "driver": type(axis).__name__, "position_deg": axis.position_deg(),
           "target_deg": None, "position_units": None, "target_units": None, "units": None,
           "moving": moving, "fault": axis.fault() or note, "limits_deg": list(axis.limits_deg),
           "referenced": None}
    if isinstance(axis, Referencing) and axis.reference_method != "none":
        out["referenced"] = axis.referenced()
    if isinstance(axis, ReportsDeviceUnits):  # servo ticks, motor steps
        out.update(axis.device_units())
    return out


def pose_targets(kin, current_deg, theta_i_deg, phi_i_deg, theta_o_deg, phi_o_deg) -> np.ndarray:
    """Axis targets (°) for a pose, nearest the current positions; a one-line ValueError naming why a
    pose cannot be reached."""
    angles = np.radians([theta_i_deg, phi_i_deg, theta_o_deg, phi_o_deg])
    reason = int(kin.feasibility(*angles)[0])
    if reason != 0:
        raise ValueError(f"pose (θi={theta_i_deg:g}°, φi={phi_i_deg:g}°, θo={theta_o_deg:g}°, "
                         f"φo={phi_o_deg:g}°) cannot be measured on this gantry: {REASONS[reason]} "
                         f"(theta_max_deg={kin.theta_max_deg:g}, clearance_deg={kin.clearance_deg:g})")
    return kin.inverse(*angles, current_deg=current_deg)[0]


def plan_move(kin, current_deg, target_deg, tolerance_deg: float = 0.0) -> np.ndarray:
    """The legs (K, n_axes) of a collision-free path to ``target_deg``, or a one-line ValueError (a limit,
    a collision) before anything moves. ``current_deg`` is read back: it may be ``tolerance_deg`` (the
    runner's position tolerance) inside a clearance it was sent to (:func:`gonio.motion.safe.safe_path`)."""
    target = check_targets(kin, target_deg)
    return safe_path(kin, np.asarray(current_deg, float), target, tolerance_deg)


def arrived(axes, targets_deg, tolerance_deg: float) -> np.ndarray:
    """The axes' positions (°) read back, once each is within ``tolerance_deg`` of its target; else a
    DeviceFault naming the first axis that stopped elsewhere."""
    actual = np.array([a.position_deg() for a in axes])
    bad = np.flatnonzero(np.abs(actual - targets_deg) > tolerance_deg)
    if bad.size:
        i = int(bad[0])
        raise DeviceFault(axes[i].name, f"stopped at {actual[i]:.4f}°, not at its target "
                          f"{targets_deg[i]:.4f}° (position_tolerance_deg={tolerance_deg})")
    return actual


def drive(gantry, legs, *, cfg, clock, on_leg=None) -> np.ndarray:
    """Drive ``legs`` in order on the kinematics' axes, each waited for and verified; the axes' final
    positions (°). A failure stops every axis and raises DeviceFault."""
    kin = gantry.kinematics
    axes = [gantry.axes[n] for n in kin.axis_names]
    rc = cfg.runner
    start = np.array([a.position_deg() for a in axes])
    groups = start_groups(axes)  # Modbus held moves: each leg's axes of a group start on one start
    for leg in np.atleast_2d(legs):
        try:
            moves = {a.name: float(t) for a, t, s in zip(axes, leg, start, strict=True) if t != s}
            for group in groups:
                mine = {n: t for n, t in moves.items() if n in group.axes}
                if mine:
                    group.move_to(mine)
            for axis in axes:
                if axis.name in moves and not any(axis.name in g.axes for g in groups):
                    axis.move_to(moves[axis.name])
            waited = 0.0
            times = move_time(leg - start, kin.velocity_deg_s, kin.accel_deg_s2)
            expected = float(np.max(times, initial=0.0))
            end = clock.now() + min(expected, rc.move_timeout_s)
            while clock.now() < end:
                # Every axis asked every poll_s while the profile runs: an armed Dynamixel bus
                # watchdog must hear from gonio, or the servo stops short by itself.
                clock.sleep_until(min(clock.now() + rc.poll_s, end))
                for axis in axes:
                    axis.is_moving()
            waited += expected
            while any(a.is_moving() for a in axes):
                if waited >= rc.move_timeout_s:
                    raise DeviceFault("gantry", f"axes did not arrive within move_timeout_s="
                                      f"{rc.move_timeout_s}")
                clock.sleep(rc.poll_s)
                waited += rc.poll_s
        except BaseException:
            gantry.stop()
            raise
        actual = arrived(axes, leg, rc.position_tolerance_deg)
        if on_leg is not None:
            on_leg(leg)
        start = actual
    return start
