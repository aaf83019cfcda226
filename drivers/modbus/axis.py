"""A Modbus motor controller as a gonio axis, driven entirely by a :class:`MotorProfile`.

Errors: an exception response becomes :class:`ModbusExceptionError` carrying the exception code
(transient only for 5 acknowledge / 6 device busy); no reply, a bad CRC or a lost connection
(pymodbus raises after ``timeout_s × (retries + 1)``) becomes :class:`ModbusCommError` (transient) after
one reconnection attempt; a status word with the alarm bit becomes :class:`ModbusAlarmError` with the
controller's alarm code, latched until :meth:`ModbusAxis.clear_fault`.

Replies paired with their request: on TCP pymodbus skips a frame whose transaction id is not the
request's; on RTU there is none, and it takes the first frame from the unit. So every reply is checked
here too: its function code and its register count must be the request's, or it is discarded (counted
in :attr:`ModbusAxis.discarded`) and the call fails as transient; on an RTU line bytes waiting before a
request are read and counted first (a late frame that would otherwise answer it). A stale frame of the
same function and count cannot be told apart on the wire: every position is then held against what the
axis can have travelled since its last good read (:mod:`gonio.drivers.readback`), read again, never used.

Referencing: an axis whose profile's drive is not ``absolute`` (an incremental stepper), or whose config
says ``reference = "origin"``, is unreferenced while the controller's ``referenced_bit`` is clear (at
power-up, for an incremental drive): moves are refused; :meth:`ModbusAxis.reference_origin` runs the
profile's return-to-origin operation.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from urllib.parse import parse_qs, urlparse

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException

from gonio.clock import WallClock
from gonio.drivers.modbus.errors import ModbusAlarmError, ModbusCommError, ModbusExceptionError
from gonio.drivers.modbus.profile import FAMILIES, Command, MotorProfile, load_profile
from gonio.drivers.readback import PlausibilityGuard
from gonio.protocols import DeviceFault, NotReferencedFault

__all__ = ["ModbusAxis", "ModbusCommError", "ModbusExceptionError", "ModbusAlarmError", "make_client",
           "axis_class"]


def make_client(url: str, *, timeout_s: float = 0.5, retries: int = 1):
    """An unconnected pymodbus sync client for ``tcp://host:port`` or ``rtu:///dev/ttyX?baudrate=N``."""
    u = urlparse(url)
    if u.scheme == "tcp":
        return ModbusTcpClient(u.hostname or "127.0.0.1", port=u.port or 502, timeout=timeout_s,
                               retries=retries, reconnect_delay=0.1)
    if u.scheme == "rtu":
        q = parse_qs(u.query)
        return ModbusSerialClient(u.path, baudrate=int(q.get("baudrate", ["115200"])[0]),
                                  parity=q.get("parity", ["N"])[0], timeout=timeout_s, retries=retries)
    raise ValueError(f"modbus url {url!r}: scheme {u.scheme!r} is not one of tcp, rtu")


class ModbusAxis:
    """One motor on a Modbus controller, as a :class:`gonio.protocols.Axis`.

    Parameters
    ----------
    name : str
        Axis name, in every error message.
    client : pymodbus sync client
        Unconnected (see :func:`make_client`); its timeout and retries are the transaction's.
    profile : MotorProfile or str
        The register map, or the name/path of one.
    device_id : int
        Modbus unit (1..247).
    limits_deg : tuple of float
        Axis travel (°).
    gear_ratio : float
        Motor revolutions per axis revolution.
    direction : int
        +1 or -1.
    zero_steps : int
        Controller position (steps) at axis 0°.
    velocity_deg_s, accel_deg_s2 : float
        Axis speed (°/s) and acceleration (°/s²).
    start_timeout_s : float
        How long :meth:`move_to` waits for the moving bit to rise (or the target to be reached).
    clock : Clock
        Time source for that wait, and the stamps of read-backs (the gantry's).
    reference_method : str, optional
        ``"origin"`` (the profile's return-to-origin operation before the axis moves) or ``"none"``;
        default: ``"origin"`` where the profile's drive is not absolute.
    sync_start : str
        How a gantry starts this axis's moves with the others' (:meth:`start_key`): ``"auto"`` (with
        every other axis whose profile has ``[sync_start]``, in the mode their links allow:
        :meth:`ModbusStartGroup.for_axes`), one of the modes of
        :data:`~gonio.drivers.modbus.group.START_MODES` (with the others that name it), or ``"off"``
        (alone, one write that also triggers).
    """

    def __init__(self, name: str, client, profile: MotorProfile | str, *, device_id: int = 1,
                 limits_deg: tuple[float, float], gear_ratio: float = 1.0, direction: int = 1,
                 zero_steps: int = 0, velocity_deg_s: float = 20.0, accel_deg_s2: float = 40.0,
                 start_timeout_s: float = 0.5, clock=None, reference_method: str | None = None,
                 sync_start: str = "auto"):
        self.name = name
        self.client = client
        self.profile = profile if isinstance(profile, MotorProfile) else load_profile(profile)
        if not 1 <= int(device_id) <= 247:
            raise ValueError(f"axis '{name}': device_id {device_id} is outside [1, 247]")
        if direction not in (1, -1):
            raise ValueError(f"axis '{name}': direction {direction!r} is not one of 1, -1")
        if not (math.isfinite(gear_ratio) and gear_ratio > 0):
            raise ValueError(f"axis '{name}': gear_ratio {gear_ratio} must be > 0")
        lo, hi = float(limits_deg[0]), float(limits_deg[1])
        if not lo < hi:
            raise ValueError(f"axis '{name}': limits_deg {limits_deg} must be increasing")
        for key, v in (("velocity_deg_s", velocity_deg_s), ("accel_deg_s2", accel_deg_s2)):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"axis '{name}': {key} {v} must be > 0")
        self.device_id = int(device_id)
        self.limits_deg = (lo, hi)
        self.gear_ratio = float(gear_ratio)
        self.direction = direction
        self.zero_steps = int(zero_steps)
        self.steps_per_deg = self.profile.steps_per_rev * self.gear_ratio / 360.0
        motor_rev_s = velocity_deg_s * self.gear_ratio / 360.0
        self.velocity_value = self.profile.velocity_value(motor_rev_s)
        self.accel_value = self.profile.accel_value(accel_deg_s2 * self.gear_ratio / 360.0)
        for key, reg in (("velocity_deg_s", "velocity"), ("accel_deg_s2", "acceleration")):
            value = self.velocity_value if reg == "velocity" else self.accel_value
            self.profile[reg].encode(value, "big")  # raises ValueError naming the register and range
            if value < 1:
                raise ValueError(f"axis '{name}': {key} gives register {reg} = {value}, below 1")
        self.start_timeout_s = float(start_timeout_s)
        self.clock = clock or WallClock()
        p = self.profile
        if reference_method is None:
            reference_method = "origin" if p.origin is not None and not p.absolute else "none"
        if reference_method not in ("none", "origin"):
            raise ValueError(f"axis '{name}': reference_method {reference_method!r} is not one of "
                             "none, origin")
        if reference_method == "origin" and p.origin is None:
            raise ValueError(f"axis '{name}': reference_method 'origin', but profile '{p.name}' has no "
                             "[origin] operation")
        self.reference_method = reference_method
        if sync_start not in ("auto", "off", "group", "broadcast", "back_to_back"):
            raise ValueError(f"axis '{name}': sync_start {sync_start!r} is not one of auto, off, group, "
                             "broadcast, back_to_back")
        if sync_start not in ("auto", "off") and p.sync_start is None:
            raise ValueError(f"axis '{name}': sync_start {sync_start!r}, but profile '{p.name}' has no "
                             "[sync_start] (its manual gives no held move and trigger)")
        self.sync_start = sync_start
        self.needs_reference = reference_method != "none"
        self._status: int | None = None
        #: Replies thrown away: not this request's (another function code or register count), or
        #: waiting on an RTU line before a request.
        self.discarded = 0
        self.guard = PlausibilityGuard(
            name, p.velocity_rev_s(self.velocity_value) * 360.0 / self.gear_ratio,
            p.accel_rev_s2(self.accel_value) * 360.0 / self.gear_ratio, self.clock,
            slack_deg=max(0.01, 2.0 / self.steps_per_deg))
        self._fault: str | None = None
        self._alarm = 0
        #: Set when the controller refused a read spanning status and position (exception 2): from then
        #: on they are read apart.
        self.span_refused = False
        #: Set when the controller answered function 23 with exception 1 (not supported).
        self.write_read_refused = False
        #: The shortest wall time (s) of one transaction so far (None before the first): the link's own
        #: latency, which neither a slow first call nor a busy machine inflates; what a gantry weighs to
        #: decide whether asking several controllers at once pays.
        self.round_trip_s: float | None = None

    # -- transport --------------------------------------------------------------------------------------
    def connect(self, readonly: bool = False) -> None:
        """Connect; an alarm already standing is latched (:meth:`fault` says so, moves are refused) but
        does not fail the connection, so that an operator can look at it and reset it. Connecting only
        reads (``readonly`` changes nothing: it is there for the :class:`Axis` callers that ask)."""
        if not self.client.connect():
            raise ModbusCommError(self.name, f"cannot connect to the controller ({self._where()})")
        try:
            self._look()  # also learns whether the unit answers a spanning read
        except ModbusAlarmError:
            pass

    def close(self) -> None:
        self.client.close()

    def _where(self) -> str:
        p = self.client.comm_params
        return f"{p.host}:{p.port}" if p.host else str(p.port)

    def _drain(self) -> None:
        """RTU: bytes waiting on the line before a request (a frame that came after its time-out) are
        read and counted, so that the request's own reply is the first one (pymodbus would flush them
        too, uncounted)."""
        port = getattr(self.client, "socket", None) if isinstance(self.client, ModbusSerialClient) else None
        if port is None:
            return
        try:
            waiting = port.in_waiting
            if waiting:
                port.read(waiting)
                self.discarded += 1
        except (OSError, ValueError):
            pass  # a lost port: the request itself reports it

    def _call(self, what: str, fn, expect: tuple[int, int | None] | None = None):
        """``fn()`` (one pymodbus request), with one reconnection; ``expect`` = (function code, register
        count or None): a reply that is not that (a late or stray frame, which pymodbus takes on RTU) is
        discarded and counted, and the request sent once more (its own reply, come meanwhile, is read
        and counted first); a second one fails (transient)."""
        last, stray = None, None
        for attempt in range(2):
            t0 = time.perf_counter()
            self._drain()
            try:
                response = fn()
            except ConnectionException as exc:
                last = exc
                self.client.close()
                if attempt == 0 and self.client.connect():
                    continue
                break
            except ModbusException as exc:  # no reply / bad CRC after the client's own retries
                raise ModbusCommError(self.name, f"{what}: {exc}") from exc
            if response is None:  # a broadcast: nobody answers
                return None
            dt = time.perf_counter() - t0
            self.round_trip_s = dt if self.round_trip_s is None else min(self.round_trip_s, dt)
            stray = self._stray(what, response, expect)
            if stray is not None:
                self.discarded += 1
                continue
            if response.isError():
                code = int(getattr(response, "exception_code", 4))
                raise ModbusExceptionError(self.name, f"{what}: exception response, code {code}", code)
            return response
        if stray is not None:
            raise stray
        raise ModbusCommError(self.name, f"{what}: connection lost ({last})")

    @staticmethod
    def _stray_of(response, expect) -> bool:
        if expect is None:
            return False
        fc, count = expect
        if response.isError():
            return response.function_code & 0x7F != fc
        regs = getattr(response, "registers", None)
        return response.function_code != fc or (count is not None and (regs is None or len(regs) != count))

    def _stray(self, what: str, response, expect) -> ModbusCommError | None:
        """The fault for a reply that is not this request's (see :meth:`_call`), else None."""
        if not self._stray_of(response, expect):
            return None
        regs = getattr(response, "registers", None)
        return ModbusCommError(self.name, f"{what}: the reply is not this request's (function "
                               f"{response.function_code}, {'no' if regs is None else len(regs)} registers; "
                               f"expected function {expect[0]}"
                               + (f", {expect[1]} registers" if expect[1] is not None else "")
                               + "): a late or stray frame, discarded")

    def _read(self, name: str) -> list[int]:
        reg = self.profile[name]
        r = self._call(f"read {name} at {reg.address:#06x}", lambda: self.client.read_holding_registers(
            reg.address, count=reg.count, device_id=self.device_id), (3, reg.count))
        return list(r.registers)

    def _read_value(self, name: str) -> int:
        return self.profile[name].decode(self._read(name), self.profile.word_order)

    def _write(self, name: str, value: int) -> None:
        reg = self.profile[name]
        words = reg.encode(value, self.profile.word_order)
        if len(words) == 1:
            self._call(f"write {name}", lambda: self.client.write_register(
                reg.address, words[0], device_id=self.device_id), (6, None))
        else:
            self._call(f"write {name}", lambda: self.client.write_registers(
                reg.address, words, device_id=self.device_id), (16, None))

    def read_value(self, name: str) -> int:
        """Register ``name`` of the profile, read (answered) and decoded."""
        return self._read_value(name)

    def write_value(self, name: str, value: int) -> None:
        """Register ``name`` of the profile written with ``value`` (answered)."""
        self._write(name, value)

    def write_value_read_back(self, name: str, value: int) -> int:
        """Register ``name`` of the profile written with ``value`` and read back (decoded): one Read/Write
        Multiple Registers (function 23, the write done before the read) where the profile has
        ``write_read``, else a write and a read (both answered)."""
        reg = self.profile[name]
        regs = self._write_read(f"write {name}", reg.address, reg.encode(value, self.profile.word_order),
                                reg.address, reg.count)
        if regs is None:
            self._write(name, value)
            return self._read_value(name)
        return reg.decode(regs, self.profile.word_order)

    def _write_read(self, what: str, address: int, words: list[int], read_address: int,
                    count: int) -> list[int] | None:
        """``words`` written at ``address``, then ``count`` registers read at ``read_address``, in one
        function 23 request: the registers read, or None where the profile has no ``write_read`` or the
        unit refused function 23 (exception 1: it wrote nothing; 23 is never asked of it again)."""
        if not self.profile.write_read or self.write_read_refused:
            return None
        try:
            r = self._call(f"{what} and read {count} at {read_address:#06x} (function 23)",
                           lambda: self.client.readwrite_registers(
                               read_address=read_address, read_count=count, write_address=address,
                               values=words, device_id=self.device_id), (23, count))
        except ModbusExceptionError as err:
            if err.code != 1:
                raise
            self.write_read_refused = True
            return None
        return list(r.registers)

    def write_words(self, address: int, words: list[int], *, what: str, device_id: int | None = None) -> None:
        """One Write Multiple Registers of ``words`` at ``address`` to unit ``device_id`` (default this
        axis's) on this axis's link; a broadcast (unit 0) is sent and not answered."""
        unit = self.device_id if device_id is None else int(device_id)
        self._call(what, lambda: self.client.write_registers(address, words, device_id=unit,
                                                             no_response_expected=unit == 0),
                   None if unit == 0 else (16, None))

    def _command(self, cmd: Command) -> None:
        self._write(cmd.register, cmd.value)
        if cmd.release is not None:
            self._write(cmd.register, cmd.release)

    # -- status and faults ------------------------------------------------------------------------------
    def _check_status(self, status: int) -> int:
        self._status = status
        if status >> self.profile.alarm_bit & 1 and self._fault is None:
            self._alarm = self._read_value("alarm_code")
            self._fault = f"controller alarm {self._alarm:#06x}"
            raise ModbusAlarmError(self.name, f"{self._fault} (latched; clear_fault() resets)", self._alarm)
        return status

    def fault(self) -> str | None:
        return self._fault

    def link_stats(self) -> dict:
        """Replies discarded (see the module docstring) and positions found implausible."""
        return {"link": f"{self.name} ({self._where()})", "discarded": self.discarded, "failed": {},
                "implausible": self.guard.rejected}

    def clear_fault(self) -> None:
        """Send the profile's alarm reset; raises ModbusAlarmError if the alarm persists."""
        self._command(self.profile.alarm_reset)
        self._fault = None
        self._check_status(self._read("status")[0])

    # -- referencing ---------------------------------------------------------------------------------
    def referenced(self) -> bool:
        """Whether the axis's position can be trusted: it needs no reference, or the controller's status
        (as last read) says its origin is set."""
        if not self.needs_reference:
            return True
        bit = self.profile.referenced_bit
        return self._status is not None and bool(self._status >> bit & 1)

    def reference_info(self) -> dict:
        return {"needed": self.needs_reference, "referenced": self.referenced(), "stamp": None}

    def reference_origin(self, timeout_s: float, poll_s: float) -> None:
        """Run the profile's return-to-origin operation and wait (at most ``timeout_s`` on the clock,
        looking every ``poll_s``) until the controller is still with its origin set."""
        p = self.profile
        if p.origin is None:
            raise DeviceFault(self.name, f"profile '{p.name}' has no [origin] operation")
        if self._fault is not None:
            raise ModbusAlarmError(self.name, f"{self._fault} (latched; clear_fault() resets)", self._alarm)
        self._command(p.origin)
        self.guard.reset()
        waited = 0.0
        while True:
            self.clock.sleep(poll_s)
            waited += poll_s
            status = self._check_status(self._read("status")[0])
            if not status >> p.moving_bit & 1 and status >> p.referenced_bit & 1:
                return
            if waited >= timeout_s:
                raise DeviceFault(self.name, f"the return to origin did not end with the origin set within "
                                  f"{timeout_s:g} s (status {status:#06x})", transient=True)

    # -- the Axis protocol ------------------------------------------------------------------------------
    def check_target(self, target_deg: float) -> int:
        """The target position (steps) for ``target_deg``; ValueError outside ``limits_deg`` (nothing is
        written: a gantry checks a batch of moves with it first)."""
        return self.steps_for(target_deg)

    def steps_for(self, target_deg: float) -> int:
        lo, hi = self.limits_deg
        t = float(target_deg)
        if not (math.isfinite(t) and lo <= t <= hi):
            raise ValueError(f"axis '{self.name}': target {t:.1f}° is outside the limit [{lo:g}°, {hi:g}°]")
        return self.zero_steps + round(self.direction * t * self.steps_per_deg)

    def move_to(self, target_deg: float) -> None:
        """Write the profile's move block (one Write Multiple Registers that also triggers; one Read/Write
        Multiple Registers that also reads the state back where the profile has ``write_read``), then
        wait until the moving bit rises or the position equals the target (at most ``start_timeout_s``)."""
        steps = self.steps_for(target_deg)
        self._ready_to_move()
        p = self.profile
        words = self._block_words(steps, self.velocity_value, self.accel_value)
        what = f"write move block at {p.block_start:#06x}"
        # Function 23 writes the block, then reads (the Modbus spec orders the write first): the start
        # check's first look rides on the write's own request, seeing exactly what a read sent right
        # after it would. The check itself is unchanged. (The span was tried at connect, so a span the
        # unit refuses is not asked here.)
        lo, count = self.state_block or (p["status"].address, p["status"].count)
        regs = self._write_read(what, p.block_start, words, lo, count)
        if regs is not None:
            status, at = self._state_of(regs, lo)
        else:
            self._call(what, lambda: self.client.write_registers(p.block_start, words,
                                                                 device_id=self.device_id), (16, None))
            status, at = self._look()
        deadline = self.clock.now() + self.start_timeout_s
        while True:
            if at is None and not status >> p.moving_bit & 1:
                at = self._read_value("actual_position")
            if status >> p.moving_bit & 1 or at == steps:
                return
            if self.clock.now() >= deadline:
                raise ModbusCommError(self.name, f"move to {target_deg}° did not start within "
                                      f"{self.start_timeout_s} s (moving bit never rose)")
            self.clock.sleep(0.002)
            status, at = self._look()

    def _block_words(self, steps: int, velocity_value: int, accel_value: int, **constants) -> list[int]:
        """The move block's words: target ``steps``, speed and acceleration register values, the profile's
        constants (``constants`` overriding some)."""
        p = self.profile
        values = dict(p.move_constants, target_position=steps, velocity=velocity_value,
                      acceleration=accel_value, deceleration=accel_value, **constants)
        return [w for name in p.move_block for w in p[name].encode(values[name], p.word_order)]

    def _ready_to_move(self) -> None:
        if self._fault is not None:
            raise ModbusAlarmError(self.name, f"{self._fault} (latched; clear_fault() resets)", self._alarm)
        if not self.referenced():
            raise NotReferencedFault(
                self.name, f"controller {self.device_id} has no origin set (its position is lost at "
                "power-off, or it was never referenced): run `gonio gantry reference`")

    def preload(self, target_deg: float, velocity_deg_s: float | None = None,
                accel_deg_s2: float | None = None) -> int:
        """Write the move block with the profile's hold trigger (``[sync_start]``): the controller keeps
        target, speed (default the axis's) and acceleration and does not move until a trigger write
        (:class:`gonio.drivers.modbus.group.ModbusStartGroup`). Returns the target (steps).

        Raises
        ------
        ValueError
            The target outside the limits, a speed or acceleration not > 0 or out of its register's
            range, or a profile with no ``[sync_start]``.
        """
        p = self.profile
        if p.sync_start is None:
            raise ValueError(f"axis '{self.name}': profile '{p.name}' has no [sync_start] (its manual gives "
                             "no way to hold a move's data until a trigger)")
        steps = self.steps_for(target_deg)
        vel, acc = self.velocity_value, self.accel_value
        g = 360.0 / self.gear_ratio
        for key, v, top in (("velocity_deg_s", velocity_deg_s, p.velocity_rev_s(vel) * g),
                            ("accel_deg_s2", accel_deg_s2, p.accel_rev_s2(acc) * g)):
            if v is not None and not (math.isfinite(v) and 0 < v <= top * (1 + 1e-9)):
                raise ValueError(f"axis '{self.name}': {key} {v} is outside (0, {top:g}] (the axis's own)")
        if velocity_deg_s is not None:
            vel = max(1, self.profile.velocity_value(velocity_deg_s * self.gear_ratio / 360.0))
        if accel_deg_s2 is not None:
            acc = max(1, self.profile.accel_value(accel_deg_s2 * self.gear_ratio / 360.0))
        words = self._block_words(steps, vel, acc, **{p.sync_start.trigger: p.sync_start.hold})
        self._ready_to_move()
        self._call(f"preload move block at {p.block_start:#06x}", lambda: self.client.write_registers(
            p.block_start, words, device_id=self.device_id), (16, None))
        return steps

    def start_state(self, steps: int) -> bool:
        """Whether the move to ``steps`` has started (the moving bit, or the position there): one look
        (raises :class:`ModbusAlarmError` on an alarm)."""
        status, at = self._look()
        if status >> self.profile.moving_bit & 1:
            return True
        if at is None:
            at = self._read_value("actual_position")
        return at == steps

    def _deg(self, steps: int) -> float:
        return self.direction * (steps - self.zero_steps) / self.steps_per_deg

    def _checked(self, read) -> float:
        """``read() -> (position °, extra)`` until the position is plausible (fresh reads); see the module
        docstring. Returns (position, extra)."""
        first = None
        for _ in range(3):
            t0 = self.clock.now()
            deg, extra = read()
            at = self.clock.now()
            if self.guard.plausible(deg, at):  # checked at the end of the read, kept as of its start
                self.guard.accept(deg, t0)
                return deg, extra
            self.guard.rejected += 1
            first = first or (deg, at)
        raise ModbusCommError(self.name, f"implausible position, not used: {self.guard.describe(*first)}")

    def position_deg(self) -> float:
        return self._checked(lambda: (self._deg(self._read_value("actual_position")), None))[0]

    def deg_of_steps(self, steps: int) -> float:
        """The axis angle (°) of a controller position of ``steps``."""
        return self._deg(steps)

    def goal_steps(self) -> int:
        """The controller's target position register (steps)."""
        return self._read_value("target_position")

    def present_steps(self) -> int:
        """The controller's actual position (steps, unchecked: for reports)."""
        return self._read_value("actual_position")

    def device_units(self) -> dict:
        """Target and actual position in steps, the target in degrees (for a manual report)."""
        goal, present = self.goal_steps(), self.present_steps()
        return {"units": "steps", "target_units": goal, "position_units": present,
                "target_deg": self.deg_of_steps(goal)}

    def describe(self) -> dict:
        """What this axis is (its controller's profile and unit), its units and settings."""
        return {"name": self.name, "driver": "modbus",
                "identity": f"{self.profile.name} unit {self.device_id}", "firmware": None, "units": "steps",
                "link": self._where(),
                "settings": {"profile": self.profile.name, "device_id": self.device_id,
                             "gear_ratio": self.gear_ratio, "direction": self.direction,
                             "zero_steps": self.zero_steps, "limits_deg": list(self.limits_deg),
                             "velocity_value": self.velocity_value, "accel_value": self.accel_value,
                             "reference_method": self.reference_method}}

    def is_moving(self) -> bool:
        return bool(self._check_status(self._read("status")[0]) >> self.profile.moving_bit & 1)

    @property
    def state_block(self) -> tuple[int, int] | None:
        """(address, count) of the one read that gives status and actual position, or None where they
        are read apart: the profile's :attr:`MotorProfile.state_block`, unless the controller refused
        the span, or the span's extra bytes on an RTU wire cost more than a second request would."""
        block = self.profile.state_block
        if block is None or self.profile.state_adjacent:
            return block
        if self.span_refused:
            return None
        if isinstance(self.client, ModbusSerialClient):
            # Bytes on the wire: the span's registers that nobody needs, against a second request
            # (8 bytes) and its reply (5 + 2 per register) with the 3.5-character gaps around both.
            # The drive's own turnaround time, not known here, would only favour the span.
            extra = 2 * (block[1] - self.profile["status"].count - self.profile["actual_position"].count)
            second = 8 + 5 + 2 * self.profile["actual_position"].count + 2 * 3.5
            if extra > second:
                return None
        return block

    @property
    def state_in_one_read(self) -> bool:
        """Whether one read gives both status and actual position (see :attr:`state_block`)."""
        return self.state_block is not None

    def _state_of(self, words: list[int], lo: int) -> tuple[int, int | None]:
        """(status, position steps or None) from ``words`` read at ``lo``; the status checked for an
        alarm (raises :class:`ModbusAlarmError`)."""
        p = self.profile
        pos, st = p["actual_position"], p["status"]
        status = self._check_status(words[st.address - lo])
        off = pos.address - lo
        if off < 0 or off + pos.count > len(words):
            return status, None
        return status, pos.decode(words[off:off + pos.count], p.word_order)

    def _look(self) -> tuple[int, int | None]:
        """(status, position steps or None): one read of :attr:`state_block`, else the status alone. A
        span the controller refuses with exception 2 is not asked again (the status is read alone,
        and the position after it as the caller needs it)."""
        block = self.state_block
        if block is not None:
            lo, count = block
            try:
                r = self._call(f"read status and actual_position at {lo:#06x} ({count} registers)",
                               lambda: self.client.read_holding_registers(lo, count=count,
                                                                          device_id=self.device_id),
                               (3, count))
                return self._state_of(r.registers, lo)
            except ModbusExceptionError as err:
                if err.code != 2 or self.profile.state_adjacent:
                    raise
                self.span_refused = True
        return self._check_status(self._read("status")[0]), None

    def read_state(self) -> tuple[float, bool]:
        """Position (°) and moving flag: one Read Holding Registers where :attr:`state_block` allows
        it, else two (the status first: an alarm raises before the position is asked); the position
        checked for plausibility (both read again when it is not)."""
        def read():
            status, steps = self._look()
            if steps is None:
                steps = self._read_value("actual_position")
            return self._deg(steps), bool(status >> self.profile.moving_bit & 1)

        return self._checked(read)

    def stop(self) -> None:
        self._command(self.profile.stop)

    # -- declared abilities (gonio.protocols) ----------------------------------------------------------------
    def start_key(self) -> tuple | None:
        """Which axes start together with this one (:class:`~gonio.protocols.StartsTogether`): None
        (alone) where the profile has no ``[sync_start]`` or ``sync_start`` is ``"off"``; else the
        axes of one RTU line or TCP connection, or every axis on a TCP connection of its own
        (``back_to_back``), by the mode asked. ``"auto"`` on a shared line takes the group send only
        (a broadcast is executed by every unit of the line, the gantry's or not: asked by name)."""
        sync = self.profile.sync_start
        if sync is None or self.sync_start == "off":
            return None
        if self.sync_start == "back_to_back" or (self.sync_start == "auto"
                                                  and isinstance(self.client, ModbusTcpClient)):
            return ("modbus-tcp", self.sync_start)
        if self.sync_start == "auto" and sync.group_register is None:
            return None  # a broadcast reaches every unit of the line, ours or not: only when asked
        return ("modbus-line", id(self.client), self.sync_start)

    def make_start_group(self, axes: list):
        """The :class:`~gonio.drivers.modbus.group.ModbusStartGroup` of ``axes`` (one key), left (any
        group a crashed process left standing on the units is undone, each write read back); None for
        an axis alone in ``"auto"``; ValueError (naming the axes) for a mode their links or profiles
        do not allow."""
        from gonio.drivers.modbus.group import ModbusStartGroup

        if len(axes) == 1:
            if self.sync_start == "auto":
                return None
            raise ValueError(f"axis '{self.name}': sync_start {self.sync_start!r} starts it with other "
                             "axes, but no other axis naming that mode shares its "
                             + ("TCP gateways" if self.sync_start == "back_to_back" else "line")
                             + " (sync_start = \"auto\" or \"off\" moves it alone)")
        try:
            group = (ModbusStartGroup.for_axes(axes) if self.sync_start == "auto"
                     else ModbusStartGroup(axes, self.sync_start))
        except ValueError as err:
            raise ValueError(f"{err} (axes {', '.join(a.name for a in axes)}; sync_start = \"off\" "
                             "moves an axis alone)") from None
        group.leave()
        return group


def axis_class(name_or_path: str | Path):
    """The axis class that drives a family (:data:`gonio.drivers.modbus.profile.FAMILIES`); a profile
    given by path is driven by :class:`ModbusAxis`."""
    if str(name_or_path) in FAMILIES:
        return FAMILIES.load(str(name_or_path))
    return ModbusAxis
