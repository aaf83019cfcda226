"""Dynamixel servos as gonio axes: one :class:`DynamixelAxis` per servo, and :class:`DynamixelGroup` to
move and read several servos of one bus with one Sync Write and one Sync Read per step.

Angles: an axis position in degrees is ``direction * (ticks - homing_offset_ticks) / ticks_per_deg`` with
``ticks_per_deg = ticks_per_rev * gear_ratio / 360``, where ``ticks`` is the servo's Present Position and
``gear_ratio`` is servo revolutions per axis revolution. The offset is applied here rather than written to
the servo's Homing Offset(20): the servo's own setting is left as the lab made it, and position mode's
0..4095 goal range then covers an axis range centred anywhere on the turn.

Sweeps (on-the-fly scanning, :mod:`gonio.fly.hardware`): :meth:`DynamixelAxis.sweep` moves one axis to
a goal at a velocity and acceleration given in °/s and °/s²; the servo takes them in whole profile units
(0.229 rev/min, 214.577 rev/min²), so the speed it runs at differs from the one asked (it returns the
quantised pair), which is why a sweep's positions come from timestamped reads
(:meth:`DynamixelGroup.read_stamped`), never from the plan. The campaign's profile comes back with
:meth:`DynamixelAxis.restore_profile`, and before any later move if that could not be written.

Safety: while a move is under way the servo's Bus Watchdog is armed (``watchdog_s``): if gonio stops
talking to the bus (a crash, a hung host), the servo stops by itself. It is disarmed when the axis is
found at rest, so a long exposure with a quiet bus does not trip it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from gonio.drivers.dynamixel.bus import DynamixelBus
from gonio.drivers.dynamixel.control_table import TABLES, ControlTable
from gonio.drivers.dynamixel.errors import (
    DynamixelCommError,
    DynamixelError,
    DynamixelHardwareError,
    HardwareError,
)

__all__ = ["DynamixelAxis", "DynamixelGroup", "AxisState"]

_WATCHDOG_UNIT_S = 0.02
# One block read covers Bus Watchdog(98) .. Present Position(132..135).
_BLOCK_START, _BLOCK_LEN = 98, 38


@dataclass(frozen=True)
class AxisState:
    """One axis as a Sync Read saw it: position (°), moving flag, velocity (°/s)."""

    position_deg: float
    moving: bool
    velocity_deg_s: float


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
        ``"position"`` (one turn, 0..4095 ticks) or ``"extended"`` (multi-turn, ±256 rev).
    gear_ratio : float
        Servo revolutions per axis revolution (> 0).
    direction : int
        +1, or -1 when the axis angle grows as the servo turns clockwise.
    homing_offset_ticks : int
        Present Position (ticks) at axis 0°.
    velocity_deg_s, accel_deg_s2 : float
        Profile velocity (°/s) and acceleration (°/s²) of the axis.
    watchdog_s : float
        Bus watchdog while moving (s, multiple of 0.02, 0.02..2.54); 0 disables it.
    """

    def __init__(self, name: str, bus: DynamixelBus, dxl_id: int, *, limits_deg: tuple[float, float],
                 family: str = "XM430", operating_mode: str = "position", gear_ratio: float = 1.0,
                 direction: int = 1, homing_offset_ticks: int = 0, velocity_deg_s: float = 30.0,
                 accel_deg_s2: float = 60.0, watchdog_s: float = 0.2):
        self.name = name
        self.bus = bus
        if not isinstance(dxl_id, int) or not 0 <= dxl_id <= 252:
            raise ValueError(f"axis '{name}': dxl_id {dxl_id!r} is outside [0, 252]")
        if family not in TABLES:
            raise ValueError(f"axis '{name}': family {family!r} is not one of {sorted(TABLES)}")
        self.table: ControlTable = TABLES[family]
        if operating_mode not in self.table.operating_modes:
            raise ValueError(f"axis '{name}': operating_mode {operating_mode!r} is not one of "
                             f"{sorted(self.table.operating_modes)}")
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
        self._fault: str | None = None
        self._flags = HardwareError(0)
        self._armed = False
        self._connected = False
        # The profile registers hold a sweep's velocity and acceleration, not the campaign's.
        self._profile_dirty = False
        self.model_name: str | None = None

    # -- unit conversions -----------------------------------------------------------------------------
    def _ticks(self, deg: float) -> int:
        return self.homing_offset_ticks + int(round(self.direction * deg * self.ticks_per_deg))

    def _deg(self, ticks: int) -> float:
        return self.direction * (ticks - self.homing_offset_ticks) / self.ticks_per_deg

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

    # -- connection -------------------------------------------------------------------------------------
    def connect(self) -> None:
        """Open the bus, check the model, write EEPROM settings that differ (torque off first), the
        profile, and turn torque on, unless a hardware error is latched (then :meth:`fault` says so)."""
        t, b, i = self.table, self.bus, self.dxl_id
        b.connect()
        try:
            model = b.ping(i)
            if model not in t.model_numbers:
                raise DynamixelError(self.name, f"servo {i} is model {model}, not a {t.family} "
                                     f"({', '.join(map(str, t.model_numbers))})", dxl_id=i)
            self.model_name = t.model_numbers[model]
            self._latch(b.read(i, t["hardware_error_status"]))
            wanted = {"operating_mode": t.operating_modes[self.operating_mode]}
            if self.operating_mode == "position":
                wanted["min_position_limit"], wanted["max_position_limit"] = self._limit_ticks
            changes = {k: v for k, v in wanted.items() if b.read(i, t[k]) != v}
            if changes:
                b.write(i, t["torque_enable"], 0)
                for key, value in changes.items():
                    b.write(i, t[key], value)
            vlimit = b.read(i, t["velocity_limit"])
            if self.profile_velocity > vlimit:
                raise ValueError(f"axis '{self.name}': profile velocity {self.profile_velocity} units is "
                                 f"above servo {i}'s velocity limit {vlimit} units")
            self._apply_ram()
        except BaseException:
            b.close()
            raise
        self._connected = True

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
        """Stop, disarm the watchdog and release the bus (torque stays on: the axis holds its place)."""
        if not self._connected:
            return
        try:
            self.stop()
            self._disarm()
        except DynamixelError:
            pass
        finally:
            self._connected = False
            self.bus.close()

    # -- faults -------------------------------------------------------------------------------------------
    def _latch(self, flags: int) -> None:
        if flags and self._fault is None:
            self._flags = HardwareError(flags)
            self._fault = f"servo {self.dxl_id} hardware error: {self._flags.describe()}"

    def _check_alert(self) -> bool:
        """Decode a new alert bit into a latched fault; True when one was latched just now."""
        if self.dxl_id in self.bus.alerts and self._fault is None:
            self._latch(self.bus.read(self.dxl_id, self.table["hardware_error_status"]) or 0xFF)
            return True
        return False

    def _hardware_error(self) -> DynamixelHardwareError:
        return DynamixelHardwareError(
            self.name, f"{self._fault} (latched, torque off; clear_fault() reboots)", self.dxl_id,
            self._flags)

    def fault(self) -> str | None:
        """The latched hardware fault, or None."""
        return self._fault

    def clear_fault(self) -> None:
        """Reboot the servo (clears its hardware error), wait for it, re-apply the profile, torque on."""
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
        flags = self.bus.read(self.dxl_id, self.table["hardware_error_status"])
        self._fault, self._flags = None, HardwareError(0)
        self.bus.alerts.discard(self.dxl_id)
        self._latch(flags)
        self._apply_ram()

    # -- the Axis protocol ---------------------------------------------------------------------------------
    def check_target(self, target_deg: float) -> int:
        """The goal position (ticks) for ``target_deg``; raises ValueError outside ``limits_deg``."""
        lo, hi = self.limits_deg
        target = float(target_deg)
        if not (math.isfinite(target) and lo <= target <= hi):
            raise ValueError(
                f"axis '{self.name}': target {target:.1f}° is outside the limit [{lo:g}°, {hi:g}°]")
        if self._fault is not None:
            raise self._hardware_error()
        return self._ticks(target)

    def move_to(self, target_deg: float) -> None:
        """Arm the watchdog and write the goal position; returns at once."""
        self._write_goal(self.check_target(target_deg))

    def _write_goal(self, goal: int, profile: tuple[int, int] | None = None) -> None:
        """Under the bus lock: the campaign's profile (``profile`` None; restored if a sweep left its
        own) or ``profile`` = (velocity, acceleration) units, the watchdog armed, the goal written."""
        t, b, i = self.table, self.bus, self.dxl_id
        with b.lock:
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

    def sweep(self, target_deg: float, velocity_deg_s: float, accel_deg_s2: float) -> tuple[float, float]:
        """Start a move to ``target_deg`` at ``velocity_deg_s`` and ``accel_deg_s2`` (a fly sweep): the
        profile is written in whole units, the watchdog armed, the goal written; returns at once.

        Returns
        -------
        (float, float)
            The velocity (°/s) and acceleration (°/s²) the servo runs at: the asked ones quantised to
            its profile units. The campaign's profile stays replaced until :meth:`restore_profile`
            (or the next :meth:`move_to`).

        Raises
        ------
        ValueError
            The target is outside the limits, or the velocity or acceleration outside what the servo
            can be given (nothing is written).
        DynamixelHardwareError
            A hardware error is latched (nothing is written), or latched on the way.
        """
        goal = self.check_target(target_deg)
        v_units = self._velocity_units(velocity_deg_s)
        a_units = self._accel_units(accel_deg_s2)
        self._write_goal(goal, (v_units, a_units))
        return self.velocity_deg_s_of(v_units), self.accel_deg_s2_of(a_units)

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
        ticks = self.bus.read(self.dxl_id, self.table["present_position"])
        self._check_alert()
        return self._deg(ticks)

    def is_moving(self) -> bool:
        """Whether the servo is moving; disarms the watchdog at rest.

        Raises
        ------
        DynamixelHardwareError
            A hardware error latched during the move.
        DynamixelCommError
            The bus watchdog fired (the servo stopped short; transient: the move may be re-issued).
        """
        block = self.bus.read_block(self.dxl_id, _BLOCK_START, _BLOCK_LEN)
        if self._check_alert():
            raise self._hardware_error()
        state = self._state(block)
        if block[0] == 0xFF:
            self.bus.write(self.dxl_id, self.table["bus_watchdog"], 0)  # clears the watchdog error
            self._armed = False
            raise DynamixelCommError(
                self.name, f"servo {self.dxl_id}: bus watchdog fired (no traffic for more than "
                f"{self.watchdog_units * _WATCHDOG_UNIT_S:g} s); stopped at {state.position_deg:.2f}°",
                self.dxl_id)
        if not state.moving and self._armed:
            self._disarm()
        return state.moving

    def _state(self, block: bytes) -> AxisState:
        t = self.table
        off = t["present_position"].address - _BLOCK_START
        ticks = t["present_position"].decode(int.from_bytes(block[off:off + 4], "little"))
        off_v = t["present_velocity"].address - _BLOCK_START
        vel = t["present_velocity"].decode(int.from_bytes(block[off_v:off_v + 4], "little"))
        moving = bool(block[t["moving"].address - _BLOCK_START])
        v_deg_s = self.direction * vel * t.velocity_unit_rpm * 6.0 / self.gear_ratio
        return AxisState(self._deg(ticks), moving, v_deg_s)

    def _disarm(self) -> None:
        if self._armed:
            self.bus.write(self.dxl_id, self.table["bus_watchdog"], 0)
            self._armed = False

    def stop(self) -> None:
        """Hold where the shaft is now: the goal becomes the present position (the servo brakes at its
        profile acceleration). Safe from any thread; does nothing with torque off."""
        t, b, i = self.table, self.bus, self.dxl_id
        with b.lock:
            if not b.read(i, t["torque_enable"]):
                return
            b.write(i, t["goal_position"], b.read(i, t["present_position"]))

    # -- extras ---------------------------------------------------------------------------------------------
    def set_torque(self, on: bool) -> None:
        if on and self._fault is not None:
            raise self._hardware_error()
        self.bus.write(self.dxl_id, self.table["torque_enable"], int(bool(on)))

    def torque(self) -> bool:
        return bool(self.bus.read(self.dxl_id, self.table["torque_enable"]))

    def temperature_c(self) -> float:
        return float(self.bus.read(self.dxl_id, self.table["present_temperature"]))

    def voltage_v(self) -> float:
        return self.bus.read(self.dxl_id, self.table["present_input_voltage"]) * self.table.voltage_unit_v

    def current_a(self) -> float:
        """Present current (A); the XL430 has no current sensor and raises."""
        if self.table.current_unit_a is None:
            raise DynamixelError(self.name, f"{self.table.family} servos report load, not current",
                                 dxl_id=self.dxl_id)
        return self.bus.read(self.dxl_id, self.table["present_current"]) * self.table.current_unit_a


class DynamixelGroup:
    """Several axes of one bus, moved with one Sync Write and read with one Sync Read per step.

    Parameters
    ----------
    axes : sequence of DynamixelAxis
        Connected axes sharing one :class:`DynamixelBus` (distinct IDs; X-series families, whose
        watchdog, goal and present fields share addresses).
    """

    def __init__(self, axes: Sequence[DynamixelAxis]):
        axes = list(axes)
        if not axes:
            raise ValueError("dynamixel group: needs at least one axis")
        bus = axes[0].bus
        if any(a.bus is not bus for a in axes):
            raise ValueError("dynamixel group: every axis must be on the same bus")
        if len({a.dxl_id for a in axes}) != len(axes):
            raise ValueError("dynamixel group: servo IDs must be distinct")
        shared = ("bus_watchdog", "goal_position", "present_velocity", "present_position", "moving")
        if any(a.table[f] != axes[0].table[f] for a in axes for f in shared):
            raise ValueError("dynamixel group: the axes' control tables must place the watchdog, goal and "
                             "present fields at the same addresses")
        self.bus = bus
        self.axes = {a.name: a for a in axes}
        self._table = axes[0].table

    @property
    def armed(self) -> bool:
        """Whether any servo of the group has its bus watchdog armed (a move is under way)."""
        return any(a._armed for a in self.axes.values())

    def move_to(self, targets: Mapping[str, float]) -> None:
        """Check every target first (nothing moves if one is refused), arm the watchdogs that are not
        armed (one Sync Write), then one Sync Write of the goal positions."""
        unknown = set(targets) - set(self.axes)
        if unknown:
            raise ValueError(f"dynamixel group: unknown axes {sorted(unknown)}; known: {sorted(self.axes)}")
        goals = {self.axes[n].dxl_id: self.axes[n].check_target(v) for n, v in targets.items()}
        with self.bus.lock:
            for n in targets:  # a sweep's profile left behind (its restore failed): the campaign's first
                self.axes[n].restore_profile()
            arm = {a.dxl_id: a.watchdog_units for a in self.axes.values()
                   if a.name in targets and not a._armed and a.watchdog_units}
            if arm:
                self.bus.sync_write(self._table["bus_watchdog"], arm)
                for a in self.axes.values():
                    if a.dxl_id in arm:
                        a._armed = True
            self.bus.sync_write(self._table["goal_position"], goals)

    def read_stamped(self, clock) -> tuple[float, dict[str, AxisState]]:
        """:meth:`read`, stamped: (time, states), the time on ``clock`` (the gantry's) halfway through
        the Sync Read transaction. Each servo latches its Present Position while it answers, within the
        transaction, so the stamp is off by at most half of it (~0.5 ms for four servos at 1 Mbit/s);
        timestamps of a sweep's reads are what its positions are interpolated on.

        Raises
        ------
        As :meth:`read`.
        """
        t0 = clock.now()
        states = self.read()
        return 0.5 * (t0 + clock.now()), states

    def read(self) -> dict[str, AxisState]:
        """Every axis's state from one Sync Read; a servo that does not answer raises (never a silent 0).

        Raises
        ------
        DynamixelCommError
            A servo did not answer, or a bus watchdog fired (the servos named stopped short).
        DynamixelHardwareError
            A hardware error latched on one of the servos.
        """
        by_id = {a.dxl_id: a for a in self.axes.values()}
        blocks = self.bus.sync_read(_BLOCK_START, _BLOCK_LEN, by_id)
        out, fired = {}, []
        for dxl_id, block in blocks.items():
            axis = by_id[dxl_id]
            if axis._check_alert():
                raise axis._hardware_error()
            out[axis.name] = axis._state(block)
            if block[0] == 0xFF:
                fired.append(axis)
        if fired:
            self.bus.sync_write(self._table["bus_watchdog"], {a.dxl_id: 0 for a in fired})
            for a in fired:
                a._armed = False
            names = ", ".join(f"'{a.name}' at {out[a.name].position_deg:.2f}°" for a in fired)
            raise DynamixelCommError(self.bus.name, f"bus watchdog fired; stopped short: {names}")
        rest = {a.dxl_id: 0 for a in self.axes.values() if a._armed and not out[a.name].moving}
        if rest:
            self.bus.sync_write(self._table["bus_watchdog"], rest)
            for dxl_id in rest:
                by_id[dxl_id]._armed = False
        return out
