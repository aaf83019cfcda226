"""Dynamixel servos as gonio axes: one :class:`DynamixelAxis` per servo (several servos of one bus are
moved and read together by :class:`~gonio.drivers.dynamixel.group.DynamixelGroup`).

Angles: an axis position in degrees is ``direction * (ticks + correction - homing_offset_ticks) /
ticks_per_deg`` with ``ticks_per_deg = ticks_per_rev * gear_ratio / 360``, where ``ticks`` is the servo's
Present Position, ``gear_ratio`` is servo revolutions per axis revolution and ``correction`` the whole
turns found by referencing (0 for a servo whose count cannot be ambiguous). The offset is applied here
rather than written to the servo's Homing Offset(20): the servo's own setting is left as the lab made
it, and position mode's 0..4095 goal range then covers an axis range centred anywhere on the turn.

Referencing (:mod:`.reference`): an axis in extended position mode counts turns only while powered; after
power-up its Present Position is within one turn, so the axis is *unreferenced* (moves refused, naming
``gonio gantry reference``) until a reference finds ``correction`` and leaves it in the servo's RAM,
where a later connect finds it (a restart of gonio keeps it) and a power cycle or a reboot erases it.

Read-backs (:mod:`gonio.drivers.readback`): every position read is held against the last good one and
what the axis can have travelled since on the gantry clock; an implausible one is read again, and never
used, not as a path's start and not as a stop's goal. A servo that stopped answering is asked for its
marker before it is given a goal again, so a power cycle in between is found.

Hardware errors (Hardware Error Status(70)): the bits the servo's Shutdown(63) setting acts on turn its
torque off and latch a fault (moves refused until :meth:`DynamixelAxis.clear_fault` reboots it); the
others (input voltage with the default Shutdown) leave the servo running and are reported as warnings
(:meth:`DynamixelAxis.warnings`). Every message says what the servo did, read back, never assumed.

Sweeps (on-the-fly scanning, :mod:`gonio.fly.hardware`): :meth:`DynamixelAxis.sweep` moves one axis to
a goal at a velocity and acceleration given in °/s and °/s²; the servo takes them in whole profile units
(0.229 rev/min, 214.577 rev/min²), so the speed it runs at differs from the one asked (it returns the
quantised pair), which is why a sweep's positions come from timestamped reads
(:meth:`DynamixelGroup.read_stamped`), never from the plan. The campaign's profile comes back with
:meth:`DynamixelAxis.restore_profile`, and before any later move if that could not be written.

Safety: while a move is under way the servo's Bus Watchdog is armed (``watchdog_s``): if gonio stops
talking to the bus (a crash, a hung host), the servo stops by itself. It is disarmed when the axis is
found at rest, so a long exposure with a quiet bus does not trip it.

Read-only: ``connect(readonly=True)`` (``gonio gantry status``, the daemon's ``GET /gantry``) only reads:
no torque, no goal, no watchdog, no marker, not even at close.
"""

from __future__ import annotations

import math
import time

from gonio.clock import WallClock
from gonio.drivers.dynamixel.bus import DynamixelBus
from gonio.drivers.dynamixel.control_table import TABLES, ControlTable
from gonio.drivers.dynamixel.errors import (
    DynamixelCommError,
    DynamixelError,
    DynamixelHardwareError,
    DynamixelStatusError,
    HardwareError,
)
from gonio.drivers.dynamixel.reference import (
    INDIRECT_ADDRESS,
    MARKER_ADDRESS,
    MARKER_LEN,
    decode_marker,
    encode_marker,
    indirect_defaults,
)
from gonio.drivers.dynamixel.state import BLOCK_LEN, BLOCK_START, READS, AxisState
from gonio.drivers.readback import PlausibilityGuard
from gonio.protocols import NotReferencedFault

__all__ = ["DynamixelAxis", "AxisState", "NotReferencedError", "BLOCK_START", "BLOCK_LEN", "READS"]

_WATCHDOG_UNIT_S = 0.02
# Realtime Tick(120): the servo's millisecond clock (from power-up), in every block read; wraps at 32768.
_TICK, _TICK_WRAP = 120 - BLOCK_START, 32768
#: A tick is compared with the last accepted one only within this long (s): past half the wrap an
#: advance and a step back look alike.
_TICK_TRUST_S = 10.0
#: How far the servo's clock may disagree with the host's: its 1 ms steps, and crystal drift.
_TICK_SLACK_MS, _TICK_DRIFT = 3.0, 0.01
#: While a hardware warning keeps the alert bit up, Hardware Error Status is read again at most this
#: often (s): a new bit (one Shutdown acts on) is seen within it, without a read per transaction.
_ALERT_RECHECK_S = 1.0


class NotReferencedError(DynamixelError, NotReferencedFault):
    """The axis's absolute position is not known (never referenced since the servo powered up)."""

    def __init__(self, device: str, message: str, dxl_id: int | None = None):
        DynamixelError.__init__(self, device, message, transient=False, dxl_id=dxl_id)


class DynamixelAxis:
    """One X-series servo as a :class:`gonio.protocols.Axis`.

    Parameters
    ----------
    name : str
        Axis name, used in every error message.
    bus : DynamixelBus
        The bus the servo is on (shared by the axes of one port).
    dxl_id : int
        Servo ID, 0..252.
    limits_deg : tuple of float
        Axis travel (°); moves outside are refused. In position mode they are also written to the
        servo's position limits.
    family : str
        Control-table family, ``"XM430"`` or ``"XL430"``; the servo's model number is checked against it.
    operating_mode : str
        ``"position"`` (one turn, 0..4095 ticks) or ``"extended"`` (multi-turn, ±256 rev; the axis then
        needs a reference after power-up).
    gear_ratio : float
        Servo revolutions per axis revolution (> 0).
    direction : int
        +1, or -1 when the axis angle grows as the servo turns clockwise.
    homing_offset_ticks : int
        Present Position (ticks) at axis 0° (modulo whole turns in extended mode: referencing finds
        the turns).
    velocity_deg_s, accel_deg_s2 : float
        Profile velocity (°/s) and acceleration (°/s²) of the axis.
    watchdog_s : float
        Bus watchdog while moving (s, multiple of 0.02, 0.02..2.54); 0 disables it.
    clock : Clock, optional
        The gantry's clock (default: the wall clock): read-backs are stamped on it.
    reference_method : str, optional
        How :mod:`gonio.reference` finds the turns of an extended-mode axis: ``"hard_stop"`` or
        ``"index"`` (the default); ``"none"`` for a position-mode axis (the only one it may have).
    """

    def __init__(self, name: str, bus: DynamixelBus, dxl_id: int, *, limits_deg: tuple[float, float],
                 family: str = "XM430", operating_mode: str = "position", gear_ratio: float = 1.0,
                 direction: int = 1, homing_offset_ticks: int = 0, velocity_deg_s: float = 30.0,
                 accel_deg_s2: float = 60.0, watchdog_s: float = 0.2, clock=None,
                 reference_method: str | None = None):
        self.name = name
        self.bus = bus
        if not isinstance(dxl_id, int) or not 0 <= dxl_id <= 252:
            raise ValueError(f"axis '{name}': dxl_id {dxl_id!r} is outside [0, 252]")
        if family not in TABLES:
            raise ValueError(f"axis '{name}': family {family!r} is not one of {sorted(TABLES)}")
        self.table: ControlTable = TABLES[family]
        if operating_mode not in ("position", "extended"):
            raise ValueError(f"axis '{name}': operating_mode {operating_mode!r} is not one of "
                             "'extended', 'position'")
        if not (math.isfinite(gear_ratio) and gear_ratio > 0):
            raise ValueError(f"axis '{name}': gear_ratio {gear_ratio} must be > 0")
        if direction not in (1, -1):
            raise ValueError(f"axis '{name}': direction {direction!r} is not one of 1, -1")
        if not 0 <= watchdog_s <= 127 * _WATCHDOG_UNIT_S:
            raise ValueError(f"axis '{name}': watchdog_s {watchdog_s} is outside [0, 2.54] s")
        self.dxl_id = dxl_id
        self.operating_mode = operating_mode
        self.gear_ratio = float(gear_ratio)
        self.direction = direction
        self.homing_offset_ticks = int(homing_offset_ticks)
        self.ticks_per_deg = self.table.ticks_per_rev * self.gear_ratio / 360.0
        self.correction_ticks = 0
        lo, hi = (float(limits_deg[0]), float(limits_deg[1]))
        if not lo < hi:
            raise ValueError(f"axis '{name}': limits_deg {limits_deg} must be increasing")
        self.limits_deg = (lo, hi)
        rng = (self.table.position_mode_range if operating_mode == "position"
               else self.table.extended_mode_range)
        t_lo, t_hi = sorted((self._ticks(lo), self._ticks(hi)))
        if t_lo < rng[0] or t_hi > rng[1]:
            raise ValueError(
                f"axis '{name}': limits_deg [{lo:g}°, {hi:g}°] are ticks [{t_lo}, {t_hi}], outside the "
                f"{operating_mode} mode range [{rng[0]}, {rng[1]}] (check homing_offset_ticks, gear_ratio)")
        self._limit_ticks = (t_lo, t_hi)
        self.profile_velocity = self._velocity_units(velocity_deg_s)
        self.profile_acceleration = self._accel_units(accel_deg_s2)
        self.watchdog_units = round(watchdog_s / _WATCHDOG_UNIT_S)
        self.clock = clock or WallClock()
        #: Whether the servo's count can be ambiguous after power-up (extended position mode).
        self.needs_reference = operating_mode == "extended"
        allowed = ("hard_stop", "index") if self.needs_reference else ("none",)
        self.reference_method = reference_method or allowed[-1]
        if self.reference_method not in allowed:
            raise ValueError(f"axis '{name}': reference_method {self.reference_method!r} is not one of "
                             f"{', '.join(allowed)} in {operating_mode} mode")
        self._referenced = not self.needs_reference
        #: Unix time the reference was found (from the servo's marker), or None.
        self.reference_stamp: int | None = None
        self._fault: str | None = None
        self._flags = HardwareError(0)
        self._shutdown = HardwareError(0x34)  # the e-Manual's default until connect reads the servo's
        self._warned = HardwareError(0)
        self._warnings: list[str] = []
        self._alert_read_at: float | None = None
        self._armed = False
        self._connected = False
        self._readonly = False
        self._marker_ok = True  # the servo keeps a marker (False: its RAM items there are refused)
        # The profile registers hold a sweep's velocity and acceleration, not the campaign's.
        self._profile_dirty = False
        self._prepared: tuple[int, int] | None = None   # a fly sweep's profile units, until kickoff
        self.model_name: str | None = None
        self.firmware_version: int | None = None
        # (Realtime Tick, start, end on the clock) of the last accepted read; whether the tick runs (a
        # servo whose tick never moves is held to its positions only).
        self._tick: tuple[int, float, float] | None = None
        self._tick_live = False
        self._rejection: str | None = None  # why the last read was not trusted
        self.guard = PlausibilityGuard(
            name, self.velocity_deg_s_of(self.profile_velocity),
            self.accel_deg_s2_of(self.profile_acceleration), self.clock,
            slack_deg=max(0.05, 3.0 / self.ticks_per_deg))
        room = self.table.room
        self._room = {"block": room(BLOCK_START, BLOCK_LEN)}
        for key in ("present_position", "goal_position", "torque_enable", "hardware_error_status",
                    "operating_mode", "shutdown", "velocity_limit", "min_position_limit",
                    "max_position_limit", "present_temperature", "present_input_voltage"):
            f = self.table[key]
            self._room[key] = room(f.address, f.size)

    # -- unit conversions -----------------------------------------------------------------------------
    def _ticks(self, deg: float) -> int:
        return self.homing_offset_ticks + int(round(self.direction * deg * self.ticks_per_deg)) \
            - self.correction_ticks

    def _deg(self, ticks: int) -> float:
        ticks = ticks + self.correction_ticks - self.homing_offset_ticks
        return self.direction * ticks / self.ticks_per_deg

    def deg_of_ticks(self, ticks: int) -> float:
        """The axis angle (°) of a Present/Goal Position of ``ticks``."""
        return self._deg(ticks)

    def _velocity_units(self, v: float) -> int:
        rpm = v * self.gear_ratio * 60.0 / 360.0
        units = round(rpm / self.table.velocity_unit_rpm)
        if not (math.isfinite(v) and units >= 1):
            vmin = self.table.velocity_unit_rpm * 360.0 / 60.0 / self.gear_ratio
            raise ValueError(
                f"axis '{self.name}': velocity_deg_s {v} is below the smallest step {vmin:.3g} °/s")
        return units

    def velocity_deg_s_of(self, units: int) -> float:
        """The axis speed (°/s) of a Profile Velocity of ``units``."""
        return units * self.table.velocity_unit_rpm * 360.0 / 60.0 / self.gear_ratio

    def accel_deg_s2_of(self, units: int) -> float:
        """The axis acceleration (°/s²) of a Profile Acceleration of ``units``."""
        return units * self.table.accel_unit_rpm2 * 360.0 / 3600.0 / self.gear_ratio

    def _accel_units(self, a: float) -> int:
        rpm2 = a * self.gear_ratio * 3600.0 / 360.0
        units = round(rpm2 / self.table.accel_unit_rpm2) if math.isfinite(a) else 0
        unit_deg = self.table.accel_unit_rpm2 * 360.0 / 3600.0 / self.gear_ratio
        if not 1 <= units <= self.table.profile_accel_max:
            raise ValueError(f"axis '{self.name}': accel_deg_s2 {a} is outside "
                             f"[{unit_deg:.3g}, {unit_deg * self.table.profile_accel_max:.4g}] °/s²")
        return units

    def _read(self, key: str) -> int:
        """One field, read widened within its room (see :meth:`DynamixelBus.read_block`)."""
        return self.bus.read(self.dxl_id, self.table[key], self._room.get(key, (0, 0)))

    # -- connection -------------------------------------------------------------------------------------
    def connect(self, readonly: bool = False) -> None:
        """Open the bus, check the model, read the hardware error status, the Shutdown setting and the
        reference marker; unless ``readonly``, write EEPROM settings that differ (torque off first),
        the profile, and turn torque on (not while a hardware error is latched: :meth:`fault` says so).

        ``readonly`` reads and nothing else: a servo can be looked at without energising it."""
        t, b, i = self.table, self.bus, self.dxl_id
        b.connect()
        try:
            model, self.firmware_version = b.identify(i)
            if model not in t.model_numbers:
                raise DynamixelError(self.name, f"servo {i} is model {model}, not a {t.family} "
                                     f"({', '.join(map(str, t.model_numbers))})", dxl_id=i)
            self.model_name = t.model_numbers[model]
            self._readonly = readonly
            self._shutdown = HardwareError(self._read("shutdown"))
            self._latch(self._read("hardware_error_status"))
            marker = self._read_marker()
            wanted = {"operating_mode": t.operating_modes[self.operating_mode]}
            if self.operating_mode == "position":
                wanted["min_position_limit"], wanted["max_position_limit"] = self._limit_ticks
            changes = {k: v for k, v in wanted.items() if self._read(k) != v}
            if readonly:
                self._adopt(None if "operating_mode" in changes else marker)
                self._connected = True
                return
            if changes:
                b.write(i, t["torque_enable"], 0)
                for key, value in changes.items():
                    b.write(i, t[key], value)
                if "operating_mode" in changes:
                    marker = None  # a new operating mode restarts the count within one turn
            vlimit = self._read("velocity_limit")
            if self.profile_velocity > vlimit:
                raise ValueError(f"axis '{self.name}': profile velocity {self.profile_velocity} units is "
                                 f"above servo {i}'s velocity limit {vlimit} units")
            self._apply_ram()
            self._adopt(marker)
            if marker is None and not self.needs_reference:
                self._write_marker(0)  # a later loss of it tells of a power cycle
        except BaseException:
            b.close()
            raise
        b.take_troubled(i)
        self._connected = True

    def _read_marker(self) -> tuple[int, int] | None:
        """The servo's reference marker (correction, stamp), or None (absent, erased, or the servo
        refuses those RAM items: then a reference cannot be kept on it)."""
        try:
            data = self.bus.read_block(self.dxl_id, MARKER_ADDRESS, MARKER_LEN, (3, 0),
                                       what="read the reference marker (Indirect Data 17..28)")
        except DynamixelStatusError:
            self._marker_ok = False
            return None
        self._marker_ok = True
        return decode_marker(self.dxl_id, data)

    def _write_marker(self, correction: int) -> None:
        """Leave ``correction`` in the servo's RAM (see :mod:`.reference`); for an axis that needs no
        reference a servo that refuses it only loses power-cycle detection."""
        b, i = self.bus, self.dxl_id
        try:
            try:
                pointers = b.read_block(i, INDIRECT_ADDRESS, 2 * MARKER_LEN,
                                        what="read Indirect Address 17..28")
            except DynamixelStatusError:
                pointers = indirect_defaults()  # a servo without readable pointers: plain storage
            if pointers != indirect_defaults():
                raise DynamixelError(
                    self.name, f"servo {i}: Indirect Address 17..28 do not hold their power-up defaults "
                    "(240..251): another program maps Indirect Data 17..28, where gonio keeps the reference; "
                    "power-cycle the servo or free those items", dxl_id=i)
            b.write_block(i, MARKER_ADDRESS, encode_marker(i, correction, int(time.time())),
                          what="write the reference marker (Indirect Data 17..28)")
        except DynamixelStatusError as err:
            self._marker_ok = False
            if self.needs_reference:
                raise DynamixelError(self.name, f"servo {i} refuses Indirect Data 17..28, where gonio keeps "
                                     f"the reference: {err}", dxl_id=i) from None
            return
        self._marker_ok = True
        self._adopt((correction, int(time.time())))

    def _adopt(self, marker: tuple[int, int] | None) -> None:
        self.guard.reset()
        self._tick = None
        if not self.needs_reference:
            self._referenced, self.correction_ticks = True, 0
            self.reference_stamp = None if marker is None else marker[1]
            return
        self._referenced = marker is not None
        self.correction_ticks = 0 if marker is None else marker[0]
        self.reference_stamp = None if marker is None else marker[1]

    def _apply_ram(self) -> None:
        t, b, i = self.table, self.bus, self.dxl_id
        b.write(i, t["bus_watchdog"], 0)
        self._armed = False
        b.write(i, t["profile_acceleration"], self.profile_acceleration)
        b.write(i, t["profile_velocity"], self.profile_velocity)
        self._profile_dirty = False
        if self._fault is None:
            b.write(i, t["torque_enable"], 1)

    def close(self) -> None:
        """Stop, disarm the watchdog and release the bus (torque stays on: the axis holds its place).
        A read-only connection only releases the bus."""
        if not self._connected:
            return
        try:
            if not self._readonly:
                self.stop()
                self._disarm()
        except DynamixelError:
            pass
        finally:
            self._connected = False
            self._readonly = False
            self.bus.close()

    def _writable(self, what: str) -> None:
        if self._readonly:
            raise DynamixelError(self.name, f"{what}: connected read-only (nothing is written)",
                                 dxl_id=self.dxl_id)

    # -- referencing ----------------------------------------------------------------------------------
    def referenced(self) -> bool:
        """Whether the axis's angle can be trusted (never ambiguous, or referenced since power-up)."""
        return self._referenced

    def reference_info(self) -> dict:
        """What is known of the reference: needed, referenced, correction (ticks), when (Unix s)."""
        return {"needed": self.needs_reference, "referenced": self._referenced,
                "correction_ticks": self.correction_ticks, "stamp": self.reference_stamp}

    def _not_referenced(self) -> NotReferencedError:
        return NotReferencedError(
            self.name, f"servo {self.dxl_id} is not referenced (its turn count restarted at power-up, so "
            f"the angle is known only modulo {360.0 / self.gear_ratio:g}°): run `gonio gantry reference`",
            self.dxl_id)

    def _require_referenced(self) -> None:
        if not self._referenced:
            raise self._not_referenced()

    def _check_power(self) -> None:
        """After the servo failed a transaction, before it is given a goal: see :meth:`_power_cycled`."""
        if self.bus.take_troubled(self.dxl_id):
            err = self._power_cycled()
            if err is not None:
                raise err

    def _power_cycled(self) -> DynamixelError | None:
        """Whether the servo's RAM was reset since gonio wrote its marker (a power cycle, a reboot: torque
        off, the count restarted): the fault to raise, else None. An axis that needs a reference has lost
        it (not transient); any other is set up again (torque, profile, marker) and the caller's step
        may be retried (transient)."""
        if not self._marker_ok or self._readonly or self._read_marker() is not None:
            return None
        self.guard.reset()
        self._tick = None
        if self.needs_reference:
            self._referenced = False
            return NotReferencedError(
                self.name, f"servo {self.dxl_id} lost its reference: its RAM was reset (a power cycle or a "
                "reboot) and its turn count restarted; run `gonio gantry reference`", self.dxl_id)
        self._latch(self._read("hardware_error_status"))
        self._apply_ram()
        self._write_marker(0)
        return DynamixelCommError(self.name, f"servo {self.dxl_id} was power-cycled (its RAM was reset: "
                                  "torque was off); its settings are written again", self.dxl_id)

    def reference_index(self, reference_deg: float) -> float:
        """Reference at an index: the axis stands at ``reference_deg`` within half a servo turn (a mark,
        a pin, a jig). The whole turns are taken from there, the rest from the encoder; returns how far
        (°) the axis stood from ``reference_deg``."""
        self._writable("reference")
        ticks = self._fresh_ticks()
        return self._reference_at(ticks, reference_deg, 0.5)

    def _reference_at(self, ticks: int, reference_deg: float, within_turns: float) -> float:
        """Set the correction so that Present Position ``ticks`` is ``reference_deg`` up to the encoder's
        part of a turn; refuse when that part is more than ``within_turns`` of a turn away."""
        rev = self.table.ticks_per_rev
        want = self.homing_offset_ticks + round(self.direction * reference_deg * self.ticks_per_deg)
        turns = round((want - ticks) / rev)
        residual = want - ticks - turns * rev
        off_deg = residual / self.ticks_per_deg
        if abs(residual) > within_turns * rev:
            raise DynamixelError(
                self.name, f"servo {self.dxl_id}: the reference position reads {ticks} ticks, "
                f"{abs(off_deg):.1f}° (axis) from {reference_deg:g}° within its turn: the axis stopped short "
                f"of the reference (against something else?), or homing_offset_ticks is off "
                f"({self.homing_offset_ticks - residual} would put this position at {reference_deg:g}°)",
                dxl_id=self.dxl_id)
        self._write_marker(turns * rev)
        return -off_deg * self.direction

    def _fresh_ticks(self) -> int:
        return self._read("present_position")

    def seek_start(self, toward: int, velocity_deg_s: float, accel_deg_s2: float, current_a: float,
                   travel_deg: float) -> None:
        """Start a hard-stop approach: torque off, current-based position mode (5) with Goal Current
        ``current_a`` (so the servo pushes no harder than that), the profile ``velocity_deg_s`` and
        ``accel_deg_s2``, the watchdog, and a goal ``travel_deg`` beyond the present position in the
        axis direction ``toward`` (+1 / -1). Poll :meth:`seek_state`; :meth:`seek_end` finishes."""
        self._writable("reference")
        t, b, i = self.table, self.bus, self.dxl_id
        if "current_position" not in t.operating_modes:
            raise DynamixelError(self.name, f"{t.family} servos have no current-based position mode: "
                                 "reference this axis at an index instead", dxl_id=i)
        unit = t.current_unit_a
        current = max(1, round(current_a / unit))
        with b.lock:
            b.write(i, t["torque_enable"], 0)
            b.write(i, t["operating_mode"], t.operating_modes["current_position"])
            self._referenced, self.correction_ticks = False, 0  # the count restarts within the turn
            self.guard.reset()
            limit = b.read(i, t["current_limit"])
            if current > limit:
                raise DynamixelError(self.name, f"reference current {current_a:g} A is above servo {i}'s "
                                     f"Current Limit ({limit * unit:.3f} A)", dxl_id=i)
            b.write(i, t["goal_current"], current)
            b.write(i, t["profile_acceleration"], self._accel_units(accel_deg_s2))
            b.write(i, t["profile_velocity"], self._velocity_units(velocity_deg_s))
            self._profile_dirty = True
            b.write(i, t["bus_watchdog"], 0)
            b.write(i, t["torque_enable"], 1)
            if self.watchdog_units:
                b.write(i, t["bus_watchdog"], self.watchdog_units)
                self._armed = True
            here = self._fresh_ticks()
            goal = here + round(toward * self.direction * travel_deg * self.ticks_per_deg)
            lo, hi = t.extended_mode_range
            b.write(i, t["goal_position"], min(max(goal, lo), hi))

    def follow_start(self, toward: int, velocity_deg_s: float, accel_deg_s2: float,
                     travel_deg: float) -> None:
        """Move ``travel_deg`` in the axis direction ``toward`` at ``velocity_deg_s`` and ``accel_deg_s2``
        from wherever the shaft is, referenced or not: the other carriage of a ring while one seeks its
        stop (they keep their distance). :meth:`follow_stop` ends it."""
        self._writable("reference")
        t, b, i = self.table, self.bus, self.dxl_id
        with b.lock:
            if self._armed:  # a watchdog that fired locks the goal and profile until it is written 0
                b.write(i, t["bus_watchdog"], 0)
                self._armed = False
            b.write(i, t["profile_acceleration"], self._accel_units(accel_deg_s2))
            b.write(i, t["profile_velocity"], self._velocity_units(velocity_deg_s))
            self._profile_dirty = True
            if self.watchdog_units:
                b.write(i, t["bus_watchdog"], self.watchdog_units)
                self._armed = True
            goal = self._fresh_ticks() + round(toward * self.direction * travel_deg * self.ticks_per_deg)
            lo, hi = t.extended_mode_range if self.operating_mode == "extended" else self._limit_ticks
            b.write(i, t["goal_position"], min(max(goal, lo), hi))
        self.guard.reset()

    def follow_stop(self) -> None:
        """End :meth:`follow_start`: hold where the shaft is, the campaign's profile back."""
        t, b, i = self.table, self.bus, self.dxl_id
        with b.lock:
            b.write(i, t["goal_position"], self._fresh_ticks())
            self.restore_profile()
        self.guard.reset()

    def seek_state(self) -> AxisState:
        """Position (raw frame, °), moving flag and velocity during an approach (feeds the watchdog).

        A fired bus watchdog (gonio silent longer than ``watchdog_s``: the servo stopped by itself, its
        goal locked) raises the transient fault of :meth:`watchdog_fired`, never a state: a servo the
        watchdog stopped would look like one against its stop."""
        block = self.bus.read_block(self.dxl_id, BLOCK_START, BLOCK_LEN, self._room["block"])
        if self._check_alert():
            raise self._hardware_error()
        state = self._state(block)
        if block[0] == 0xFF:  # Bus Watchdog reads -1
            raise self.watchdog_fired(state)
        return state

    def seek_end(self, reference_deg: float, within_turns: float = 0.25) -> float:
        """The axis rests against its stop at ``reference_deg``: stop pushing, back to extended position
        mode (its count may restart within the turn there: it is read again with torque off), set the
        correction from the encoder's part of the turn, the campaign's profile, torque on. Returns how
        far (°) the stop is from where ``homing_offset_ticks`` puts ``reference_deg``."""
        t, b, i = self.table, self.bus, self.dxl_id
        with b.lock:
            b.write(i, t["goal_position"], self._fresh_ticks())
            b.write(i, t["torque_enable"], 0)
            b.write(i, t["bus_watchdog"], 0)
            self._armed = False
            b.write(i, t["operating_mode"], t.operating_modes[self.operating_mode])
            ticks = self._fresh_ticks()
            off = self._reference_at(ticks, reference_deg, within_turns)
            self._apply_ram()
            return off

    def seek_abort(self) -> None:
        """After a failed approach: hold where it is, back to the configured mode (unreferenced)."""
        t, b, i = self.table, self.bus, self.dxl_id
        with b.lock:
            try:
                b.write(i, t["goal_position"], self._fresh_ticks())
            finally:
                b.write(i, t["torque_enable"], 0)
                b.write(i, t["bus_watchdog"], 0)
                self._armed = False
                b.write(i, t["operating_mode"], t.operating_modes[self.operating_mode])
                self._adopt(None)
                self._apply_ram()

    # -- faults and warnings ------------------------------------------------------------------------------
    def _latch(self, flags: int) -> bool:
        """Sort Hardware Error Status ``flags``: bits the Shutdown setting acts on latch a fault (True
        when one latched just now), the others become a warning (once per bit)."""
        flags = HardwareError(flags)
        warn = HardwareError(flags & ~self._shutdown & ~self._warned)
        if warn:
            self._warned |= warn
            self._warnings.append(
                f"servo {self.dxl_id} hardware warning: {warn.describe()} (its Shutdown setting does not act "
                "on it: the servo keeps its torque and goes on)")
        fault = HardwareError(flags & self._shutdown)
        if not fault or self._fault is not None:
            return False
        try:
            torque = self._read("torque_enable")
            did = "torque is off" if torque == 0 else "torque is still on"
        except DynamixelError:
            did = "torque state unknown (no reply)"
        self._flags = flags
        self._fault = f"servo {self.dxl_id} hardware error: {fault.describe()} (Shutdown acts on it: {did})"
        return True

    def alert_fault(self) -> DynamixelHardwareError | None:
        """After a read: the fault when the servo's alert bit latched one just now (else None)."""
        return self._hardware_error() if self._check_alert() else None

    def _check_alert(self) -> bool:
        """A status packet carried the alert bit: read Hardware Error Status (again only once
        :data:`_ALERT_RECHECK_S` passed while the alert stays up); True when a fault latched now."""
        if self.dxl_id not in self.bus.alerts or self._fault is not None:
            return False
        now = self.clock.now()
        if self._alert_read_at is not None and now - self._alert_read_at < _ALERT_RECHECK_S:
            return False
        self._alert_read_at = now
        return self._latch(self._read("hardware_error_status"))

    def _hardware_error(self) -> DynamixelHardwareError:
        return DynamixelHardwareError(self.name, f"{self._fault}; latched: clear_fault() reboots it",
                                      self.dxl_id, self._flags)

    def fault(self) -> str | None:
        """The latched hardware fault, or None."""
        return self._fault

    def link_stats(self) -> dict:
        """What the bus threw away and what failed, and the positions found implausible (see the module
        docstring): ``link`` (the bus), ``discarded``, ``failed`` (by kind), ``implausible``."""
        return {"link": self.bus.name, "discarded": self.bus.discarded, "failed": dict(self.bus.counts),
                "implausible": self.guard.rejected}

    def warnings(self) -> list[str]:
        """Hardware warnings seen since the last call (the servo went on: see the module docstring)."""
        out, self._warnings = self._warnings, []
        return out

    def clear_fault(self) -> None:
        """Reboot the servo (clears its hardware error), wait for it, re-apply the profile, torque on.

        A reboot resets the servo's RAM and restarts its count within one turn. A referenced axis is read
        just before (its torque is off: the shaft stays put) and referenced again at that position from
        the encoder, within a quarter turn; if it cannot be read, it stays unreferenced."""
        self._writable("clear_fault")
        before = None
        if self.needs_reference and self._referenced:
            try:
                before = self.position_deg()
            except DynamixelError:
                before = None
        self.bus.reboot(self.dxl_id)
        last: Exception | None = None
        for _ in range(10):  # the servo takes a moment to boot; each ping waits one SDK time-out
            try:
                self.bus.ping(self.dxl_id)
                break
            except DynamixelCommError as exc:
                last = exc
        else:
            raise DynamixelCommError(self.name, f"servo {self.dxl_id} did not come back after reboot: {last}",
                                     self.dxl_id)
        flags = self._read("hardware_error_status")
        self._fault, self._flags, self._warned = None, HardwareError(0), HardwareError(0)
        self.bus.alerts.discard(self.dxl_id)
        self._alert_read_at = None
        self._latch(flags)
        self._apply_ram()
        self.bus.take_troubled(self.dxl_id)
        self._adopt(self._read_marker())
        if not self.needs_reference:
            self._write_marker(0)
        elif not self._referenced and before is not None:
            self._reference_at(self._fresh_ticks(), before, 0.25)

    # -- the Axis protocol ---------------------------------------------------------------------------------
    def check_target(self, target_deg: float) -> int:
        """The goal position (ticks) for ``target_deg``; raises ValueError outside ``limits_deg``, and
        a fault when the axis is not referenced or a hardware error is latched."""
        lo, hi = self.limits_deg
        target = float(target_deg)
        if not (math.isfinite(target) and lo <= target <= hi):
            raise ValueError(
                f"axis '{self.name}': target {target:.1f}° is outside the limit [{lo:g}°, {hi:g}°]")
        if self._fault is not None:
            raise self._hardware_error()
        self._require_referenced()
        return self._ticks(target)

    def move_to(self, target_deg: float) -> None:
        """Arm the watchdog and write the goal position; returns at once."""
        self._write_goal(self.check_target(target_deg))

    @property
    def armed(self) -> bool:
        """Whether gonio armed the servo's bus watchdog (a move under way)."""
        return self._armed

    def mark_armed(self, armed: bool) -> None:
        """A group wrote the watchdog of this servo (armed or 0)."""
        self._armed = bool(armed)

    def prepare_goal(self) -> None:
        """Before a goal is written by anyone (this axis or its group): writable, and a servo that went
        silent since is asked whether it was power-cycled (see :meth:`_check_power`)."""
        self._writable("move")
        self._check_power()

    def _write_goal(self, goal: int, profile: tuple[int, int] | None = None) -> None:
        """Under the bus lock: the campaign's profile (``profile`` None; restored if a sweep left its
        own) or ``profile`` = (velocity, acceleration) units, the watchdog armed, the goal written."""
        t, b, i = self.table, self.bus, self.dxl_id
        with b.lock:
            self.prepare_goal()
            if profile is None:
                self.restore_profile()
            else:
                self._profile_dirty = True
                b.write(i, t["profile_acceleration"], profile[1])
                b.write(i, t["profile_velocity"], profile[0])
            if not self._armed and self.watchdog_units:
                b.write(i, t["bus_watchdog"], self.watchdog_units)
                self._armed = True
            try:
                b.write(i, t["goal_position"], goal)
            finally:
                if self._check_alert():
                    raise self._hardware_error()

    def prepare(self, velocity_deg_s: float, accel_deg_s2: float) -> tuple[float, float]:
        """Check a fly sweep's profile and keep it for :meth:`kickoff` (nothing is written).

        Returns
        -------
        (float, float)
            The velocity (°/s) and acceleration (°/s²) the servo will run at: the asked ones quantised
            to its profile units.

        Raises
        ------
        ValueError
            The velocity or acceleration is outside what the servo can be given.
        """
        v_units = self._velocity_units(velocity_deg_s)
        a_units = self._accel_units(accel_deg_s2)
        v, a = self.velocity_deg_s_of(v_units), self.accel_deg_s2_of(a_units)
        self.guard.raise_limits(v, a)
        self._prepared = (v_units, a_units)
        return v, a

    def kickoff(self, target_deg: float) -> None:
        """Start the sweep :meth:`prepare` set toward ``target_deg``: the profile written in whole units,
        the watchdog armed, the goal written; returns at once. The campaign's profile stays replaced
        until :meth:`complete` (or the next :meth:`move_to`).

        Raises
        ------
        ValueError
            The target is outside the limits, or no sweep was prepared (nothing is written).
        DynamixelHardwareError
            A hardware error is latched (nothing is written), or latched on the way.
        """
        goal = self.check_target(target_deg)
        if self._prepared is None:
            raise ValueError(f"axis '{self.name}': kickoff without a prepared sweep (prepare first)")
        profile, self._prepared = self._prepared, None
        self._write_goal(goal, profile)

    def sweep_start(self, target_deg: float) -> tuple[int, int, int]:
        """For a group that starts several prepared sweeps in one Sync Write
        (:meth:`DynamixelGroup.start_sweeps`): (goal ticks, Profile Velocity, Profile Acceleration) of the
        sweep :meth:`prepare` set toward ``target_deg``; nothing is written, the sweep stays prepared.

        Raises
        ------
        ValueError
            The target is outside the limits, or no sweep was prepared.
        DynamixelHardwareError
            A hardware error is latched.
        """
        goal = self.check_target(target_deg)
        if self._prepared is None:
            raise ValueError(f"axis '{self.name}': kickoff without a prepared sweep (prepare first)")
        return goal, *self._prepared

    def took_sweep(self) -> None:
        """The group is writing the prepared sweep's profile and goal: the campaign's profile is replaced
        until :meth:`complete`."""
        self._prepared = None
        self._profile_dirty = True

    def complete(self) -> None:
        """After a sweep: the campaign's profile written back (see :meth:`restore_profile`)."""
        self.restore_profile()

    def sweep(self, target_deg: float, velocity_deg_s: float, accel_deg_s2: float) -> tuple[float, float]:
        """:meth:`prepare` then :meth:`kickoff` (the target checked first: nothing is written when either
        is refused); the (velocity, acceleration) the servo runs at."""
        self.check_target(target_deg)
        v, a = self.prepare(velocity_deg_s, accel_deg_s2)
        self.kickoff(target_deg)
        return v, a

    def restore_profile(self) -> None:
        """Write back the campaign's profile velocity and acceleration after a :meth:`sweep` (nothing
        when they were not replaced)."""
        if not self._profile_dirty:
            return
        t, b, i = self.table, self.bus, self.dxl_id
        with b.lock:
            b.write(i, t["profile_acceleration"], self.profile_acceleration)
            b.write(i, t["profile_velocity"], self.profile_velocity)
            self._profile_dirty = False

    def position_deg(self) -> float:
        """The present position (°) from a block read (Realtime Tick and Present Velocity with it),
        checked (see :meth:`checked_state`)."""
        return self._trusted_state()[0].position_deg

    def implausible(self, deg: float, at: float) -> DynamixelError:
        """The fault for a position that could not be trusted over fresh reads: the servo's RAM was
        reset (see :meth:`_power_cycled`), or a transient one (a stale or foreign reply). The servo's
        clock is taken afresh at the next read whose position is plausible."""
        why = self._rejection or "implausible"
        self._tick = None
        err = self._power_cycled()
        if err is not None:
            return err
        return DynamixelCommError(self.name, f"servo {self.dxl_id}: position not used: {why}", self.dxl_id)

    def checked_state(self, block: bytes, span: tuple[float, float]) -> AxisState | None:
        """The state in a block read during ``span`` = (start, end) on the clock if it can be trusted
        (then accepted), else None:

        - the servo's Realtime Tick(120) in the block must not be behind the last accepted one's: a reply
          carrying an earlier sample of the same request (late, of the same length) is older than the
          last good read, however plausible its position (the axis could have come back there);
        - its position must be within reach of the last good one (:mod:`gonio.drivers.readback`). The
          servo sampled it somewhere in the span: it is checked at the end and kept as of the start, so a
          reply stamped late (a busy host) cannot make a true position look too far from the last one."""
        state = self._state(block)
        tick = int.from_bytes(block[_TICK:_TICK + 2], "little")
        if self._tick is not None and span[1] - self._tick[1] < _TICK_TRUST_S:
            # The servo's clock must have run as long as the host's between the two samples (each taken
            # somewhere within its read): a reply carrying an earlier sample, or a servo that restarted
            # (its clock starts at 0 at power-up), is out of step.
            last, last_t0, last_t1 = self._tick
            forward = (tick - last) % _TICK_WRAP
            lo = 1000.0 * (span[0] - last_t1) * (1.0 - _TICK_DRIFT) - _TICK_SLACK_MS
            hi = 1000.0 * (span[1] - last_t0) * (1.0 + _TICK_DRIFT) + _TICK_SLACK_MS
            if not lo <= forward <= hi:
                if self._tick_live:
                    self.guard.rejected += 1
                    self._rejection = (f"read {state.position_deg:.3f}° with the servo's Realtime Tick "
                                       f"{forward} ms on from the last good read, {lo:.0f}..{hi:.0f} ms "
                                       "by the host: an earlier reply, or the servo restarted")
                    return None
            elif forward > 0:
                self._tick_live = True  # this servo's clock runs: from now on it is held to it
        if not self.guard.plausible(state.position_deg, span[1]):
            self.guard.rejected += 1
            self._rejection = self.guard.describe(state.position_deg, span[1])
            return None
        # Kept without its Present Velocity: the bound must not hang on an item a servo (or an
        # emulator) may not fill in, and the top speed bounds any travel anyway.
        self.guard.accept(state.position_deg, span[0])
        self._tick = (tick, span[0], span[1])
        return state

    def is_moving(self) -> bool:
        """Whether the servo is moving; disarms the watchdog at rest.

        Raises
        ------
        DynamixelHardwareError
            A hardware error latched during the move.
        DynamixelCommError
            The bus watchdog fired (the servo stopped short; transient: the move may be re-issued), or
            the position read stayed implausible.
        """
        return self.read_state()[1]

    def read_state(self) -> tuple[float, bool]:
        """(position °, moving) from one block read, the position checked (read again if it cannot be
        trusted); a fired bus watchdog raises (see :meth:`is_moving`)."""
        state, fired = self._trusted_state()
        if fired:
            raise self.watchdog_fired(state)
        if not state.moving and self._armed:
            self._disarm()
        return state.position_deg, state.moving

    def _trusted_state(self) -> tuple[AxisState, bool]:
        """(state, whether the bus watchdog fired) from a block read whose position can be trusted
        (:meth:`checked_state`), read again while it cannot; a latched hardware error raises."""
        first = None
        for _ in range(READS):
            t0 = self.clock.now()
            block = self.bus.read_block(self.dxl_id, BLOCK_START, BLOCK_LEN, self._room["block"])
            at = self.clock.now()
            if self._check_alert():
                raise self._hardware_error()
            state = self.checked_state(block, (t0, at))
            if state is None:
                first = first or (self._state(block).position_deg, at)
                continue
            return state, block[0] == 0xFF
        raise self.implausible(*first)

    def watchdog_fired(self, state: AxisState) -> DynamixelCommError:
        """The servo's bus watchdog fired (Bus Watchdog reads -1): the error is cleared (unless read-only)
        and the transient fault that names where the servo stopped returned."""
        if not self._readonly:
            self.bus.write(self.dxl_id, self.table["bus_watchdog"], 0)  # clears the watchdog error
            self._armed = False
        return DynamixelCommError(
            self.name, f"servo {self.dxl_id}: bus watchdog fired (no traffic for more than "
            f"{self.watchdog_units * _WATCHDOG_UNIT_S:g} s); stopped at {state.position_deg:.2f}°",
            self.dxl_id)

    def state_of(self, block: bytes) -> AxisState:
        """The state a block read (Bus Watchdog .. Present Position) holds, unchecked."""
        return self._state(block)

    def _state(self, block: bytes) -> AxisState:
        t = self.table
        off = t["present_position"].address - BLOCK_START
        ticks = t["present_position"].decode(int.from_bytes(block[off:off + 4], "little"))
        off_v = t["present_velocity"].address - BLOCK_START
        vel = t["present_velocity"].decode(int.from_bytes(block[off_v:off_v + 4], "little"))
        moving = bool(block[t["moving"].address - BLOCK_START])
        v_deg_s = self.direction * vel * t.velocity_unit_rpm * 6.0 / self.gear_ratio
        return AxisState(self._deg(ticks), moving, v_deg_s)

    @property
    def readonly(self) -> bool:
        return self._readonly

    def _disarm(self) -> None:
        if self._armed and not self._readonly:
            self.bus.write(self.dxl_id, self.table["bus_watchdog"], 0)
            self._armed = False

    def stop_goal(self) -> tuple[int, AxisState] | None:
        """(goal ticks, state) that holds the axis where it stands now: from a fresh read whose position
        is plausible (read again if not); None when the servo's watchdog already stopped it. Raises
        when no plausible position is to be had: no goal may come from a reply that cannot be trusted."""
        first = None
        for _ in range(READS):
            t0 = self.clock.now()
            block = self.bus.read_block(self.dxl_id, BLOCK_START, BLOCK_LEN, self._room["block"])
            at = self.clock.now()
            state = self.checked_state(block, (t0, at))
            if state is None:
                first = first or (self._state(block).position_deg, at)
                continue
            if block[0] == 0xFF:  # stopped by its watchdog; goals are locked until the error is cleared
                self.bus.write(self.dxl_id, self.table["bus_watchdog"], 0)
                self._armed = False
                return None
            off = self.table["present_position"].address - BLOCK_START
            return self.table["present_position"].decode(int.from_bytes(block[off:off + 4], "little")), state
        err = self.implausible(*first)
        raise DynamixelCommError(self.name, f"stop: no goal written ({err}); the servo goes on to the goal "
                                 "it had, which was checked before it was given", self.dxl_id)

    def hold(self, goal_ticks: int) -> None:
        """Write a stop's goal (from :meth:`stop_goal`)."""
        self._writable("stop")
        self.bus.write(self.dxl_id, self.table["goal_position"], goal_ticks)

    def stop(self) -> None:
        """Hold where the shaft is now: the goal becomes the present position, read fresh and checked
        for plausibility (the servo brakes at its profile acceleration). Safe from any thread. A read
        that cannot be trusted writes no goal and raises (see :meth:`stop_goal`)."""
        self._writable("stop")
        with self.bus.lock:
            found = self.stop_goal()
            if found is not None:
                self.bus.write(self.dxl_id, self.table["goal_position"], found[0])

    # -- declared abilities (gonio.protocols) ----------------------------------------------------------------
    @property
    def watchdog_s(self) -> float:
        """The bus watchdog armed while the servo moves (s; 0: none)."""
        return self.watchdog_units * _WATCHDOG_UNIT_S

    def group_key(self) -> int:
        """Axes of one bus are moved and read together (:class:`JoinsGroup`)."""
        return id(self.bus)

    def make_group(self, axes: list):
        """The :class:`~gonio.drivers.dynamixel.group.DynamixelGroup` of ``axes`` (one bus)."""
        from gonio.drivers.dynamixel.group import DynamixelGroup

        return DynamixelGroup(axes)

    def device_units(self) -> dict:
        """Goal and Present Position in ticks, the goal in degrees (:class:`ReportsDeviceUnits`)."""
        goal, present = self.goal_ticks(), self.present_ticks()
        return {"units": "ticks", "target_units": goal, "position_units": present,
                "target_deg": self.deg_of_ticks(goal)}

    def describe(self) -> dict:
        """What this servo is (model and firmware from its Ping at connect), its units and settings."""
        return {"name": self.name, "driver": "dynamixel", "identity": self.model_name,
                "firmware": self.firmware_version, "units": "ticks", "bus": self.bus.name,
                "settings": {"id": self.dxl_id, "family": self.table.family,
                             "operating_mode": self.operating_mode, "gear_ratio": self.gear_ratio,
                             "direction": self.direction, "homing_offset_ticks": self.homing_offset_ticks,
                             "limits_deg": list(self.limits_deg),
                             "velocity_deg_s": self.velocity_deg_s_of(self.profile_velocity),
                             "accel_deg_s2": self.accel_deg_s2_of(self.profile_acceleration),
                             "watchdog_s": self.watchdog_s,
                             "reference_method": self.reference_method}}

    # -- extras ---------------------------------------------------------------------------------------------
    def set_torque(self, on: bool) -> None:
        self._writable("torque")
        if on and self._fault is not None:
            raise self._hardware_error()
        self.bus.write(self.dxl_id, self.table["torque_enable"], int(bool(on)))

    def torque(self) -> bool:
        return bool(self._read("torque_enable"))

    def goal_ticks(self) -> int:
        """The servo's Goal Position (ticks)."""
        return self._read("goal_position")

    def present_ticks(self) -> int:
        """The servo's Present Position (ticks, unchecked: for reports)."""
        return self._read("present_position")

    def temperature_c(self) -> float:
        return float(self._read("present_temperature"))

    def voltage_v(self) -> float:
        return self._read("present_input_voltage") * self.table.voltage_unit_v

    def current_a(self) -> float:
        """Present current (A); the XL430 has no current sensor and raises."""
        if self.table.current_unit_a is None:
            raise DynamixelError(self.name, f"{self.table.family} servos report load, not current",
                                 dxl_id=self.dxl_id)
        return self.bus.read(self.dxl_id, self.table["present_current"]) * self.table.current_unit_a
