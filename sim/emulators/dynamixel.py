"""An emulated Dynamixel Protocol 2.0 bus of X-series servos (XM430-W350, XL430-W250) over a pty.

Each :class:`EmulatedServo` keeps an X-series control table and moves along the trapezoid profile
(:func:`gonio.motion.trapezoid.position_at`) set by its profile velocity and acceleration, on an injected
clock. It models what a driver must get right: EEPROM (addresses < 64) writable only with torque off,
position limits in position mode, the hardware error status (alert bit 7 in every status packet, torque
off, cleared only by a reboot), the bus watchdog (a servo that hears nothing for the set time stops and
locks its goal values until the watchdog is written 0), reg-write/action, and the instructions ping,
read, write, sync read/write, bulk read and reboot. :class:`DynamixelBusEmulator` serves a set of
servos on one pty and applies the faults queued in :attr:`DynamixelBusEmulator.faults` to replies
(matched by servo ID or by ``(id, instruction)``).

References
----------
ROBOTIS e-Manual: "DYNAMIXEL Protocol 2.0"; "XM430-W350" and "XL430-W250" control tables; "Bus Watchdog".
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

from gonio.clock import WallClock
from gonio.motion.trapezoid import move_time, position_at
from gonio.sim.emulators.dxl_packet import BROADCAST_ID, Inst, Packet, PacketReader, status_packet
from gonio.sim.emulators.link import EmulatorThread, FaultPlan, PtyLink, mangle

__all__ = ["EmulatedServo", "DynamixelBusEmulator", "MODELS", "ERR_RESULT_FAIL", "ERR_INSTRUCTION",
           "ERR_CRC", "ERR_DATA_RANGE", "ERR_DATA_LENGTH", "ERR_DATA_LIMIT", "ERR_ACCESS", "ALERT"]

# Status packet ERROR byte: bit 7 is the hardware alert, the low 7 bits an error number.
ERR_RESULT_FAIL, ERR_INSTRUCTION, ERR_CRC, ERR_DATA_RANGE = 1, 2, 3, 4
ERR_DATA_LENGTH, ERR_DATA_LIMIT, ERR_ACCESS = 5, 6, 7
ALERT = 0x80

TICKS_PER_REV = 4096
RPM_PER_VELOCITY_UNIT = 0.229
RPM2_PER_ACCEL_UNIT = 214.577  # rev/min²


@dataclass(frozen=True)
class _Model:
    number: int
    velocity_limit: int  # default Velocity Limit(44), units of 0.229 rev/min
    current_limit: int


#: Model numbers and defaults (e-Manual control tables).
MODELS = {
    "XM430-W350": _Model(1020, 200, 1193),
    "XL430-W250": _Model(1060, 265, 0),
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
_TABLE_SIZE = 147
_READ_ONLY = set(range(0, 7)) | {69, 70} | set(range(120, _TABLE_SIZE))
_EEPROM_END = 64
_GOALS = set(range(100, 120))  # goal PWM .. goal position: locked after a watchdog error


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
    position_ticks : int
        Shaft position at power-up (ticks, before the homing offset).
    """

    def __init__(self, dxl_id: int, model: str = "XM430-W350", clock=None, position_ticks: int = 2048):
        if not 0 <= dxl_id <= 252:
            raise ValueError(f"emulated servo: id {dxl_id} is outside [0, 252]")
        if model not in MODELS:
            raise ValueError(f"emulated servo {dxl_id}: model {model!r} is not one of {sorted(MODELS)}")
        self.dxl_id = dxl_id
        self.model = model
        self.clock = clock or WallClock()
        self._spec = MODELS[model]
        self._mem = bytearray(_TABLE_SIZE)
        self._pending: tuple[int, bytes] | None = None
        self._last_heard = self.clock.now()
        #: When the bus watchdog last fired (clock time), or None.
        self.watchdog_fired_at: float | None = None
        self.reboots = 0
        self.temperature_c = 36
        self.voltage_dv = 120
        self._hold(position_ticks)
        self._power_on_defaults(eeprom=True)

    # -- table access ---------------------------------------------------------------------------------
    def _power_on_defaults(self, eeprom: bool) -> None:
        for addr, (size, default, _signed) in _TABLE.items():
            if addr < _EEPROM_END and not eeprom:
                continue
            if default is None:
                default = {0: self._spec.number, 7: self.dxl_id, 38: self._spec.current_limit,
                           44: self._spec.velocity_limit}[addr]
            self._put(addr, size, default)
        self._put(116, 4, self._present_raw() + self._get(20, 4, True))

    def _put(self, addr: int, size: int, value: int) -> None:
        self._mem[addr:addr + size] = (value & ((1 << (8 * size)) - 1)).to_bytes(size, "little")

    def _get(self, addr: int, size: int, signed: bool = False) -> int:
        return int.from_bytes(self._mem[addr:addr + size], "little", signed=signed)

    def value(self, addr: int) -> int:
        """The current value at a modelled address (dynamic registers refreshed), for tests."""
        self._refresh()
        size, _d, signed = _TABLE[addr]
        return self._get(addr, size, signed)

    # -- motion -----------------------------------------------------------------------------------------
    def _hold(self, raw: float) -> None:
        self._move = (self.clock.now(), float(raw), float(raw), 1.0, 1.0)

    def _present_raw_f(self, t: float | None = None) -> float:
        t0, start, goal, v, a = self._move
        t = self.clock.now() if t is None else t
        if start == goal:
            return goal
        return float(position_at(t - t0, start, goal, v, a))

    def _present_raw(self, t: float | None = None) -> int:
        return int(round(self._present_raw_f(t)))

    def _moving(self) -> bool:
        t0, start, goal, v, a = self._move
        return start != goal and self.clock.now() - t0 < float(move_time(goal - start, v, a))

    def _velocity_ticks_s(self) -> float:
        pv = self._get(112, 4) or self._get(44, 4)
        return max(pv, 1) * RPM_PER_VELOCITY_UNIT * TICKS_PER_REV / 60.0

    def _accel_ticks_s2(self) -> float:
        pa = self._get(108, 4)
        return pa * RPM2_PER_ACCEL_UNIT * TICKS_PER_REV / 3600.0 if pa else 1e9

    def _start_move(self, goal_present: int) -> None:
        raw_goal = goal_present - self._get(20, 4, True)
        now = self.clock.now()
        self._move = (now, self._present_raw_f(now), float(raw_goal), self._velocity_ticks_s(),
                      self._accel_ticks_s2())

    def _refresh(self) -> None:
        now = self.clock.now()
        self._watchdog_due(now)
        offset = self._get(20, 4, True)
        self._put(120, 2, int(now * 1000) % 32768)
        moving = self._moving()
        self._put(122, 1, int(moving))
        self._put(123, 1, 0 if moving else 1)  # bit 0: in position
        self._put(126, 2, 40 if moving else 3)
        self._put(132, 4, self._present_raw(now) + offset)
        dt = 1e-3
        v_ticks_s = ((self._present_raw_f(now + dt) - self._present_raw_f(now - dt)) / (2 * dt)
                     if moving else 0.0)
        self._put(128, 4, int(round(v_ticks_s * 60.0 / TICKS_PER_REV / RPM_PER_VELOCITY_UNIT)))
        self._put(144, 2, self.voltage_dv)
        self._put(146, 1, self.temperature_c)

    # -- faults -------------------------------------------------------------------------------------------
    def inject_hardware_error(self, bits: int) -> None:
        """Latch hardware error ``bits`` (Hardware Error Status(70)): torque off, the shaft stops."""
        self._put(70, 1, self._get(70, 1) | bits)
        self._hold(self._present_raw_f())
        self._put(64, 1, 0)

    @property
    def hardware_error(self) -> int:
        return self._get(70, 1)

    def _watchdog_due(self, now: float) -> None:
        """Fire the bus watchdog if nothing was heard for its time: the shaft stops where it stood at
        that instant (:attr:`watchdog_fired_at`), whether or not anyone asks before ``now``."""
        wd = self._get(98, 1, True)
        if wd > 0 and self._get(64, 1) and now - self._last_heard > wd * 0.02:
            fired = self._last_heard + wd * 0.02
            self._hold(self._present_raw_f(fired))
            self._put(98, 1, -1)
            self.watchdog_fired_at = fired

    def _check_watchdog(self, now: float) -> None:
        self._watchdog_due(now)
        self._last_heard = now

    # -- instructions -----------------------------------------------------------------------------------
    def heard(self) -> None:
        """An instruction packet concerning this servo arrived (the bus watchdog's notion of contact)."""
        self._check_watchdog(self.clock.now())

    def error_byte(self, err: int = 0) -> int:
        return err | (ALERT if self._get(70, 1) else 0)

    def read(self, addr: int, length: int) -> tuple[int, bytes]:
        if length < 1 or addr + length > _TABLE_SIZE:
            return ERR_ACCESS, b""
        self._refresh()
        return 0, bytes(self._mem[addr:addr + length])

    def write(self, addr: int, data: bytes) -> int:
        """Apply a write; returns the error number (0 when accepted)."""
        end = addr + len(data)
        if not data or end > _TABLE_SIZE:
            return ERR_ACCESS
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
        if 116 in span and mode == 3:
            goal = int.from_bytes(new[116:120], "little", signed=True)
            lo = int.from_bytes(new[52:56], "little", signed=True)
            hi = int.from_bytes(new[48:52], "little", signed=True)
            if not lo <= goal <= hi:
                return ERR_DATA_LIMIT
        if 64 in span and new[64] and self._get(70, 1):
            return ERR_RESULT_FAIL  # a latched hardware error keeps torque off until a reboot
        if 64 in span and new[64] not in (0, 1):
            return ERR_DATA_RANGE
        self._mem[addr:end] = data
        if 64 in span and not new[64]:
            self._hold(self._present_raw_f())
        if 64 in span and new[64]:
            self._put(116, 4, self._present_raw() + self._get(20, 4, True))
            self._last_heard = self.clock.now()
        if 116 in span and self._get(64, 1):
            self._start_move(self._get(116, 4, True))
        return 0

    def reg_write(self, addr: int, data: bytes) -> int:
        if not data or addr + len(data) > _TABLE_SIZE:
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
        """Restart: hardware error cleared, torque off, RAM back to defaults, the shaft where it is."""
        self.reboots += 1
        self._hold(self._present_raw_f())
        self._pending = None
        self._power_on_defaults(eeprom=False)


class DynamixelBusEmulator(EmulatorThread):
    """Servos on one Protocol 2.0 bus, served over a pty.

    Parameters
    ----------
    servos : iterable of EmulatedServo
        The servos on the bus (distinct IDs).
    link : PtyLink, optional
        The wire (default: a new pty; :attr:`port` is the path a driver opens).

    Attributes
    ----------
    faults : FaultPlan
        Faults applied to replies; match by servo ID or ``(id, instruction)``.
    received : list of bytes
        Every instruction packet received, raw (stuffed), for byte-exact tests.
    """

    def __init__(self, servos, link: PtyLink | None = None):
        super().__init__("dynamixel")
        self.servos = {}
        for s in servos:
            if s.dxl_id in self.servos:
                raise ValueError(f"dynamixel bus emulator: id {s.dxl_id} appears twice")
            self.servos[s.dxl_id] = s
        self.link = link or PtyLink("ttyDXL")
        self.faults = FaultPlan()
        self.received: list[bytes] = []
        self.handled = 0
        self.lock = threading.RLock()
        self._heard = threading.Condition(self.lock)
        self._reader = PacketReader()

    @property
    def port(self) -> str:
        return self.link.port

    def unplug(self) -> None:
        """Pull the cable: the driver's port fails until :meth:`replug`."""
        with self.lock:
            self.link.unplug()
            self._reader = PacketReader()

    def replug(self) -> None:
        with self.lock:
            self.link.replug()

    def stop(self, timeout_s: float = 5.0) -> None:
        super().stop(timeout_s)
        self.link.close()

    # -- serving ---------------------------------------------------------------------------------------
    def step(self) -> None:
        if not self.link.plugged:
            self._stop.wait(self.poll_s)
            return
        if not self.link.readable(self.poll_s):
            return
        with self.lock:  # read under the lock: drain() holding it sees every byte handled or waiting
            data = self.link.read(0.0)
            for packet in self._reader.feed(data):
                self.received.append(packet.raw)
                for dxl_id, reply in self._handle(packet):
                    self._send(dxl_id, packet.inst, reply)
                self.handled += 1
                self._heard.notify_all()

    def wait_received(self, count: int, timeout_s: float = 2.0) -> bool:
        """Wait until ``count`` packets in all have been received and answered (replies sent, delays
        served): for packets that get no reply, and before asserting on what a late reply did."""
        with self._heard:
            return self._heard.wait_for(lambda: self.handled >= count, timeout_s)

    def drain(self, timeout_s: float = 2.0) -> bool:
        """Wait (at most ``timeout_s`` s) until every byte the driver sent has been handled; False if
        some were still waiting. :class:`~gonio.sim.emulators.link.SyncedVirtualClock` calls it
        before time moves."""
        deadline = time.monotonic() + timeout_s
        with self._heard:
            while self.link.readable(0.0) and self._thread is not None:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._heard.wait(min(left, 0.01))
        return True

    def _send(self, dxl_id: int, inst: int, reply: bytes) -> None:
        fault = self.faults.take(dxl_id, (dxl_id, inst))
        if fault is not None and fault.kind == "disconnect":
            self.link.unplug()
            self._reader = PacketReader()
            return
        out = mangle(reply, fault)
        if out is not None:
            self.link.write(out)

    def _targets(self, dxl_id: int) -> list[EmulatedServo]:
        if dxl_id == BROADCAST_ID:
            return list(self.servos.values())
        return [self.servos[dxl_id]] if dxl_id in self.servos else []

    def _handle(self, p: Packet) -> list[tuple[int, bytes]]:
        servos = self._targets(p.dxl_id)
        if not p.crc_ok:
            # A servo answers a corrupt packet addressed to it with a CRC error.
            return [(s.dxl_id, status_packet(s.dxl_id, s.error_byte(ERR_CRC))) for s in servos
                    if p.dxl_id != BROADCAST_ID]
        if p.inst in (Inst.SYNC_WRITE, Inst.SYNC_READ, Inst.BULK_READ):
            return self._group(p)
        for s in servos:
            s.heard()
        reply = p.dxl_id != BROADCAST_ID or p.inst == Inst.PING
        out = []
        for s in servos:
            err, params = self._single(s, p)
            if err is None or not reply:
                continue
            out.append((s.dxl_id, status_packet(s.dxl_id, s.error_byte(err), params)))
        if p.inst == Inst.REBOOT:
            for s in servos:
                s.reboot()
        return out

    def _single(self, s: EmulatedServo, p: Packet) -> tuple[int | None, bytes]:
        prm = p.params
        if p.inst == Inst.PING:
            return 0, s._spec.number.to_bytes(2, "little") + bytes([s._get(6, 1)])
        if p.inst == Inst.READ:
            if len(prm) != 4:
                return ERR_DATA_LENGTH, b""
            return s.read(int.from_bytes(prm[0:2], "little"), int.from_bytes(prm[2:4], "little"))
        if p.inst in (Inst.WRITE, Inst.REG_WRITE):
            if len(prm) < 3:
                return ERR_DATA_LENGTH, b""
            addr = int.from_bytes(prm[0:2], "little")
            fn = s.write if p.inst == Inst.WRITE else s.reg_write
            return fn(addr, prm[2:]), b""
        if p.inst == Inst.ACTION:
            return s.action(), b""
        if p.inst == Inst.REBOOT:
            return 0, b""
        return ERR_INSTRUCTION, b""

    def _group(self, p: Packet) -> list[tuple[int, bytes]]:
        prm = p.params
        out = []
        if p.inst == Inst.BULK_READ:
            for i in range(0, len(prm) - 4, 5):
                dxl_id = prm[i]
                s = self.servos.get(dxl_id)
                if s is None:
                    continue
                s.heard()
                err, data = s.read(int.from_bytes(prm[i + 1:i + 3], "little"),
                                   int.from_bytes(prm[i + 3:i + 5], "little"))
                out.append((dxl_id, status_packet(dxl_id, s.error_byte(err), data)))
            return out
        addr = int.from_bytes(prm[0:2], "little")
        length = int.from_bytes(prm[2:4], "little")
        body = prm[4:]
        if p.inst == Inst.SYNC_READ:
            for dxl_id in body:
                s = self.servos.get(dxl_id)
                if s is None:
                    continue
                s.heard()
                err, data = s.read(addr, length)
                out.append((dxl_id, status_packet(dxl_id, s.error_byte(err), data)))
            return out
        step = 1 + length
        for i in range(0, len(body) - step + 1, step):
            s = self.servos.get(body[i])
            if s is not None:
                s.heard()
                s.write(addr, body[i + 1:i + step])
        return out
