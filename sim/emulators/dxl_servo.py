"""One emulated Dynamixel X-series servo (XM430-W350, XL430-W250): its control table and its shaft.

The servo keeps the X-series control table (EEPROM below 64, writable only with torque off; RAM from 64,
back to its initial values at power-up and after a reboot) and moves its shaft along the profile its
Drive Mode(10), Profile Velocity and Acceleration set (:mod:`.dxl_profile`: velocity- or time-based, a goal
written during a move re-planned from the present velocity), on an injected clock. What a driver must get
right, as the e-Manual describes it:

- Present Position counts turns while powered; at power-up, after a reboot and when Operating Mode
  changes, it restarts within one turn (0..4095 plus Homing Offset): behind a gear the axis angle is
  then ambiguous (:attr:`EmulatedServo.true_ticks` is where the shaft really is);
- mechanical stops (``stops_ticks``): the shaft cannot pass them; driven into one in position or
  extended position mode (3, 4) the servo pushes at full current and latches an overload after
  :data:`OVERLOAD_S`; in current-based position mode (5) it pushes at Goal Current(102), no harder;
- Hardware Error Status(70): the bits its Shutdown(63) setting names turn torque off; the others only
  raise the alert bit of every status packet; a reboot clears them;
- the bus watchdog (98), reg-write/action, position limits in position mode;
- Indirect Address 1..28 (168..223) and Indirect Data 1..28 (224..251): a byte of Indirect Data N is the
  byte at the address Indirect Address N holds, by default Indirect Data N itself (plain RAM, 0 at
  power-up);
- power: :meth:`EmulatedServo.power_off` (it stops answering, torque drops, its count is lost) and
  :meth:`EmulatedServo.power_on` (RAM at its initial values, the count within one turn).

Writes to an address no item covers, and reads beyond the modelled table, are refused with an access
error (reads across the reserved bytes between items read 0).

References
----------
ROBOTIS e-Manual: "XM430-W350" and "XL430-W250" control tables (Present Position, Operating Mode,
Shutdown, Hardware Error Status, Indirect Address/Data, Bus Watchdog).
"""

from __future__ import annotations

from dataclasses import dataclass

from gonio.clock import WallClock
from gonio.sim.emulators.dxl_profile import Trajectory, time_based, velocity_based

__all__ = ["EmulatedServo", "MODELS", "ERR_RESULT_FAIL", "ERR_INSTRUCTION", "ERR_CRC", "ERR_DATA_RANGE",
           "ERR_DATA_LENGTH", "ERR_DATA_LIMIT", "ERR_ACCESS", "ALERT", "OVERLOAD_S"]

# Status packet ERROR byte: bit 7 is the hardware alert, the low 7 bits an error number.
ERR_RESULT_FAIL, ERR_INSTRUCTION, ERR_CRC, ERR_DATA_RANGE = 1, 2, 3, 4
ERR_DATA_LENGTH, ERR_DATA_LIMIT, ERR_ACCESS = 5, 6, 7
ALERT = 0x80

TICKS_PER_REV = 4096
RPM_PER_VELOCITY_UNIT = 0.229
RPM2_PER_ACCEL_UNIT = 214.577  # rev/min²
#: Seconds of pushing at full current against a stop (modes 3, 4) before the overload error latches.
OVERLOAD_S = 2.0
_OVERLOAD = 0x20


@dataclass(frozen=True)
class _Model:
    number: int
    velocity_limit: int  # default Velocity Limit(44), units of 0.229 rev/min
    current_limit: int
    modes: frozenset[int]


#: Model numbers and defaults (e-Manual control tables).
MODELS = {
    "XM430-W350": _Model(1020, 200, 1193, frozenset({0, 1, 3, 4, 5, 16})),
    "XL430-W250": _Model(1060, 265, 0, frozenset({1, 3, 4, 16})),
}

# The part of the X-series control table the emulator models: address -> (size, default, signed).
_TABLE = {
    0: (2, None, False), 6: (1, 45, False), 7: (1, None, False), 8: (1, 1, False), 9: (1, 250, False),
    10: (1, 0, False), 11: (1, 3, False), 13: (1, 2, False), 20: (4, 0, True), 24: (4, 10, False),
    31: (1, 80, False), 32: (2, 160, False), 34: (2, 95, False), 36: (2, 885, False),
    38: (2, None, False), 44: (4, None, False), 48: (4, 4095, True), 52: (4, 0, True),
    63: (1, 0x34, False), 64: (1, 0, False), 65: (1, 0, False), 68: (1, 2, False), 69: (1, 0, False),
    70: (1, 0, False), 98: (1, 0, True), 100: (2, 0, True), 102: (2, 0, True), 104: (4, 0, True),
    108: (4, 0, True), 112: (4, 0, True), 116: (4, 0, True), 120: (2, 0, False), 122: (1, 0, False),
    123: (1, 0, False), 124: (2, 0, True), 126: (2, 0, True), 128: (4, 0, True), 132: (4, 0, True),
    136: (4, 0, True), 140: (4, 0, True), 144: (2, 120, False), 146: (1, 36, False),
}
_TABLE.update({168 + 2 * k: (2, 224 + k, False) for k in range(28)})  # Indirect Address 1..28
_TABLE.update({224 + k: (1, 0, False) for k in range(28)})  # Indirect Data 1..28
_TABLE_SIZE = 252
_DEFINED = frozenset(a for addr, (size, _d, _s) in _TABLE.items() for a in range(addr, addr + size))
# Reads may span the reserved bytes between items (they read 0, as a block read of 98..135 spans 99),
# not the unmodelled area past Present Temperature(146) before Indirect Address 1(168).
_READABLE = frozenset(range(0, 147)) | frozenset(range(168, _TABLE_SIZE))
_READ_ONLY = set(range(0, 7)) | {69, 70} | set(range(120, 147))
_EEPROM_END = 64
_GOALS = set(range(100, 120))  # goal PWM .. goal position: locked after a watchdog error
_INDIRECT_DATA = range(224, 252)


class EmulatedServo:
    """One X-series servo: a control table and a trapezoidal motion model on ``clock``.

    Parameters
    ----------
    dxl_id : int
        Bus ID, 0..252.
    model : str
        ``"XM430-W350"`` or ``"XL430-W250"``.
    clock : gonio.protocols.Clock, optional
        Time source (default: the wall clock); a virtual clock makes moves instant in wall time.
    position_ticks : float
        Where the shaft stands at power-up (ticks, before the homing offset): :attr:`true_ticks`.
        Present Position then reads it within one turn.
    stops_ticks : (float or None, float or None)
        Mechanical stops of the shaft (ticks, the frame of ``position_ticks``); None: no stop.
    operating_mode : int
        Operating Mode(11) in its EEPROM at power-up (3 from the factory; a rig's servos keep what
        their lab set once).
    """

    def __init__(self, dxl_id: int, model: str = "XM430-W350", clock=None, position_ticks: float = 2048,
                 stops_ticks: tuple[float | None, float | None] = (None, None), operating_mode: int = 3):
        if not 0 <= dxl_id <= 252:
            raise ValueError(f"emulated servo: id {dxl_id} is outside [0, 252]")
        if model not in MODELS:
            raise ValueError(f"emulated servo {dxl_id}: model {model!r} is not one of {sorted(MODELS)}")
        lo, hi = stops_ticks
        if lo is not None and hi is not None and not lo < hi:
            raise ValueError(f"emulated servo {dxl_id}: stops_ticks {stops_ticks} must be increasing")
        if (lo is not None and position_ticks < lo) or (hi is not None and position_ticks > hi):
            raise ValueError(f"emulated servo {dxl_id}: position_ticks {position_ticks} is beyond its stops")
        self.dxl_id = dxl_id
        self.model = model
        self.clock = clock or WallClock()
        self.stops_ticks = (lo, hi)
        self._spec = MODELS[model]
        self._mem = bytearray(_TABLE_SIZE)
        self._pending: tuple[int, bytes] | None = None
        self._last_heard = self.clock.now()
        self._stalled_since: float | None = None
        #: When the bus watchdog last fired (clock time), or None.
        self.watchdog_fired_at: float | None = None
        self.reboots = 0
        self.power_cycles = 0
        #: False while the servo has no power: it answers nothing.
        self.powered = True
        self.temperature_c = 36
        self.voltage_dv = 120
        self._count = 0.0  # Present Position - Homing Offset - true shaft ticks
        self._booted = self.clock.now()  # Realtime Tick counts from power-up
        self._hold(position_ticks)
        self._power_on_defaults(eeprom=True)
        if operating_mode not in self._spec.modes:
            raise ValueError(f"emulated servo {dxl_id}: operating_mode {operating_mode} is not one of "
                             f"{sorted(self._spec.modes)} on the {model}")
        self._put(11, 1, operating_mode)

    # -- table access ---------------------------------------------------------------------------------
    def _power_on_defaults(self, eeprom: bool) -> None:
        """RAM (and ``eeprom``) at initial values, the turn count restarted within one turn."""
        for addr, (size, default, _signed) in _TABLE.items():
            if addr < _EEPROM_END and not eeprom:
                continue
            if default is None:
                default = {0: self._spec.number, 7: self.dxl_id, 38: self._spec.current_limit,
                           44: self._spec.velocity_limit}[addr]
            self._put(addr, size, default)
        self._restart_count()
        self._put(116, 4, self._present_raw() + self._get(20, 4, True))

    def _restart_count(self) -> None:
        """Present Position within one turn of the absolute encoder (e-Manual, Present Position)."""
        raw = self._true_f()
        self._count = (raw % TICKS_PER_REV) - raw

    def _put(self, addr: int, size: int, value: int) -> None:
        self._mem[addr:addr + size] = (value & ((1 << (8 * size)) - 1)).to_bytes(size, "little")

    def ping_reply(self) -> bytes:
        """What a Ping's status packet carries: Model Number (2 bytes) and Firmware Version(6)."""
        return self._spec.number.to_bytes(2, "little") + bytes([self._get(6, 1)])

    def _get(self, addr: int, size: int, signed: bool = False) -> int:
        return int.from_bytes(self._mem[addr:addr + size], "little", signed=signed)

    def value(self, addr: int) -> int:
        """The current value at a modelled address (dynamic registers refreshed), for tests."""
        self._refresh()
        size, _d, signed = _TABLE[addr]
        return self._get(addr, size, signed)

    # -- motion -----------------------------------------------------------------------------------------
    def _hold(self, raw_true: float) -> None:
        self._move = Trajectory(self.clock.now(), float(raw_true))

    @property
    def trajectory(self) -> Trajectory:
        """The shaft's planned trajectory (ticks, the frame of ``position_ticks``; before the stops), from
        the last goal (its ``t0``: when the goal was applied) or hold."""
        return self._move

    def _clamp(self, x: float) -> float:
        lo, hi = self.stops_ticks
        if lo is not None and x < lo:
            return float(lo)
        if hi is not None and x > hi:
            return float(hi)
        return x

    def _true_f(self, t: float | None = None) -> float:
        """Where the shaft is (ticks, the frame of ``position_ticks``) at ``t`` (default now)."""
        t = self.clock.now() if t is None else t
        return self._clamp(self._move.position(t))

    @property
    def true_ticks(self) -> float:
        """Where the shaft really is (ticks, the frame of ``position_ticks``), whatever the servo reports."""
        return self._true_f()

    def shaft_ticks(self, t: float | None = None) -> float:
        """The Present Position (unrounded) the servo would report at ``t`` (default now) had it counted
        turns since ``position_ticks`` was given: the true shaft, plus Homing Offset."""
        return self._true_f(t) + self._get(20, 4, True)

    def _present_raw_f(self, t: float | None = None) -> float:
        """Present Position less Homing Offset: the true shaft position where the servo counts from."""
        return self._true_f(t) + self._count

    def _present_raw(self, t: float | None = None) -> int:
        return int(round(self._present_raw_f(t)))

    def _moving(self) -> bool:
        return self._move.moving(self.clock.now())

    def _pushing(self, now: float) -> bool:
        """Whether the shaft is held by a stop short of where the profile wants it."""
        if not self._move.pieces:
            return False
        want = self._move.position(now)
        return self._clamp(want) != want

    def _velocity_ticks_s(self) -> float:
        pv = self._get(112, 4) or self._get(44, 4)
        return max(pv, 1) * RPM_PER_VELOCITY_UNIT * TICKS_PER_REV / 60.0

    def _accel_ticks_s2(self) -> float:
        pa = self._get(108, 4)
        return pa * RPM2_PER_ACCEL_UNIT * TICKS_PER_REV / 3600.0  # 0: infinite (dxl_profile)

    @property
    def time_based(self) -> bool:
        """Drive Mode(10) bit 2: Profile Velocity and Acceleration are times (ms), not a speed and an
        acceleration."""
        return bool(self._get(10, 1) & 0x04)

    def _start_move(self, goal_present: int) -> None:
        """Plan the trajectory to a new goal from where the shaft is and how fast it goes (Velocity
        Override), with the profile registers as they are now (written with the goal or before)."""
        raw_goal = float(goal_present - self._get(20, 4, True) - self._count)
        now = self.clock.now()
        x = self._true_f(now)
        v = 0.0 if self._pushing(now) else self._move.velocity(now)
        if self.time_based and self._get(112, 4):
            self._move = time_based(now, x, v, raw_goal, self._get(112, 4) / 1000.0,
                                    self._get(108, 4) / 1000.0)
        else:
            self._move = velocity_based(now, x, v, raw_goal, self._velocity_ticks_s(), self._accel_ticks_s2())

    def _refresh(self) -> None:
        now = self.clock.now()
        self._watchdog_due(now)
        self._overload_due(now)
        offset = self._get(20, 4, True)
        self._put(120, 2, int(round((now - self._booted) * 1000)) % 32768)
        moving = self._moving()
        pushing = self._get(64, 1) and self._pushing(now)
        self._put(122, 1, int(moving))
        self._put(123, 1, 0 if moving or pushing else 1)  # bit 0: in position
        current = 40 if moving else 3
        if pushing:  # against a stop: the current limit, or Goal Current in mode 5
            current = self._get(102, 2, True) if self._get(11, 1) == 5 else self._get(38, 2)
        self._put(126, 2, current)
        self._put(132, 4, self._present_raw(now) + offset)
        v_ticks_s = self._move.velocity(now) if moving and not pushing else 0.0
        self._put(128, 4, int(round(v_ticks_s * 60.0 / TICKS_PER_REV / RPM_PER_VELOCITY_UNIT)))
        self._put(144, 2, self.voltage_dv)
        self._put(146, 1, self.temperature_c)

    # -- faults, power ------------------------------------------------------------------------------------
    def inject_hardware_error(self, bits: int) -> None:
        """Set hardware error ``bits`` (Hardware Error Status(70)): the alert bit goes up; where Shutdown(63)
        names one of them, torque goes off and the shaft stops."""
        self._put(70, 1, self._get(70, 1) | bits)
        if bits & self._get(63, 1):
            self._hold(self._true_f())
            self._put(64, 1, 0)

    @property
    def hardware_error(self) -> int:
        return self._get(70, 1)

    def _overload_due(self, now: float) -> None:
        """Pushing against a stop at full current (modes 3, 4) for :data:`OVERLOAD_S` latches overload."""
        if self._get(64, 1) and self._get(11, 1) in (3, 4) and self._pushing(now):
            if self._stalled_since is None:
                self._stalled_since = now
            elif now - self._stalled_since >= OVERLOAD_S:
                self._stalled_since = None
                self.inject_hardware_error(_OVERLOAD)
        else:
            self._stalled_since = None

    def _watchdog_due(self, now: float) -> None:
        """Fire the bus watchdog if nothing was heard for its time: the shaft stops where it stood at
        that instant (:attr:`watchdog_fired_at`), whether or not anyone asks before ``now``."""
        wd = self._get(98, 1, True)
        if wd > 0 and self._get(64, 1) and now - self._last_heard > wd * 0.02:
            fired = self._last_heard + wd * 0.02
            self._hold(self._true_f(fired))
            self._put(98, 1, -1)
            self.watchdog_fired_at = fired

    def _check_watchdog(self, now: float) -> None:
        self._watchdog_due(now)
        self._last_heard = now

    def assume_referenced(self) -> None:
        """As if gonio had referenced this servo in an earlier session and its power had stayed on since:
        Present Position counts from ``position_ticks``' frame and Indirect Data 17..28 hold gonio's
        reference marker for that (no correction)."""
        from gonio.drivers.dynamixel.reference import MARKER_ADDRESS, encode_marker

        self._count = 0.0
        self._put(116, 4, self._present_raw() + self._get(20, 4, True))
        marker = encode_marker(self.dxl_id, 0, 0)
        self._mem[MARKER_ADDRESS:MARKER_ADDRESS + len(marker)] = marker

    def power_off(self) -> None:
        """Cut the servo's power: it stops answering, torque drops (the shaft stays where it is)."""
        self._hold(self._true_f())
        self._put(64, 1, 0)
        self.powered = False

    def power_on(self) -> None:
        """Power comes back: RAM at its initial values (hardware errors, watchdog, Indirect Data cleared),
        EEPROM kept, Present Position within one turn of where the shaft is."""
        self.power_cycles += 1
        self._booted = self.clock.now()
        self._pending = None
        self._stalled_since = None
        self._power_on_defaults(eeprom=False)
        self.powered = True

    # -- instructions -----------------------------------------------------------------------------------
    def heard(self) -> None:
        """An instruction packet concerning this servo arrived (the bus watchdog's notion of contact)."""
        self._check_watchdog(self.clock.now())

    def error_byte(self, err: int = 0) -> int:
        return err | (ALERT if self._get(70, 1) else 0)

    def _resolve(self, addr: int) -> int:
        """Where a byte access at ``addr`` lands: Indirect Data N goes where Indirect Address N points."""
        if addr in _INDIRECT_DATA:
            return self._get(168 + 2 * (addr - 224), 2)
        return addr

    def read(self, addr: int, length: int) -> tuple[int, bytes]:
        if length < 1 or not _READABLE.issuperset(range(addr, addr + length)):
            return ERR_ACCESS, b""
        self._refresh()
        out = bytearray()
        for a in range(addr, addr + length):
            target = self._resolve(a)
            out.append(self._mem[target] if 0 <= target < _TABLE_SIZE else 0)
        return 0, bytes(out)

    def write(self, addr: int, data: bytes, *, indirect: bool = True) -> int:
        """Apply a write; returns the error number (0 when accepted). A byte of Indirect Data goes where
        its Indirect Address points, one level deep as a read goes (``indirect`` False: the bytes at
        ``addr`` themselves): an Indirect Address pointing at another Indirect Data names that byte, not
        the address it holds in turn, so two pointing at each other are no loop."""
        end = addr + len(data)
        if not data or not _DEFINED.issuperset(range(addr, end)):
            return ERR_ACCESS
        if indirect and any(self._resolve(a) != a for a in range(addr, end)):
            # Indirect Data pointing elsewhere: each byte written at the item it points at.
            for a, byte in zip(range(addr, end), data, strict=True):
                err = self.write(self._resolve(a), bytes([byte]), indirect=False)
                if err:
                    return err
            return 0
        span = set(range(addr, end))
        if span & _READ_ONLY:
            return ERR_ACCESS
        torque = self._get(64, 1)
        if addr < _EEPROM_END and torque:
            return ERR_ACCESS
        if self._get(98, 1, True) == -1 and span & _GOALS:
            return ERR_DATA_RANGE
        new = bytearray(self._mem)
        new[addr:end] = data
        mode = new[11]
        if 11 in span and mode not in self._spec.modes:
            return ERR_DATA_RANGE
        if 116 in span and mode == 3:
            goal = int.from_bytes(new[116:120], "little", signed=True)
            lo = int.from_bytes(new[52:56], "little", signed=True)
            hi = int.from_bytes(new[48:52], "little", signed=True)
            if not lo <= goal <= hi:
                return ERR_DATA_LIMIT
        if 64 in span and new[64] and self._get(70, 1) & self._get(63, 1):
            return ERR_RESULT_FAIL  # a latched shutdown error keeps torque off until a reboot
        if 64 in span and new[64] not in (0, 1):
            return ERR_DATA_RANGE
        changed_mode = 11 in span and new[11] != self._mem[11]
        self._mem[addr:end] = data
        if changed_mode:
            self._restart_count()
        if 64 in span and not new[64]:
            self._hold(self._true_f())
        if 64 in span and new[64]:
            self._put(116, 4, self._present_raw() + self._get(20, 4, True))
            self._last_heard = self.clock.now()
        if 116 in span and self._get(64, 1):
            self._start_move(self._get(116, 4, True))
        return 0

    def reg_write(self, addr: int, data: bytes) -> int:
        if not data or not _DEFINED.issuperset(range(addr, addr + len(data))):
            return ERR_ACCESS
        self._pending = (addr, bytes(data))
        self._put(69, 1, 1)
        return 0

    def action(self) -> int:
        if self._pending is None:
            return ERR_INSTRUCTION
        addr, data = self._pending
        self._pending = None
        self._put(69, 1, 0)
        return self.write(addr, data)

    def reboot(self) -> None:
        """Restart: hardware error cleared, torque off, RAM back to defaults, the count within one turn
        (the shaft where it is)."""
        self.reboots += 1
        self._booted = self.clock.now()
        self._hold(self._true_f())
        self._pending = None
        self._power_on_defaults(eeprom=False)
