"""An emulated Modbus motor controller: a pymodbus server (TCP on 127.0.0.1, or RTU over a pty) whose
registers follow a :class:`gonio.drivers.modbus.profile.MotorProfile` and whose position moves over time.

Writing the profile's move block with its trigger value starts a trapezoidal move on the injected clock;
reads see the actual position and the status word (ready, moving, alarm, referenced bits) of that
instant. The profile's origin operation runs the motor to its home sensor (:attr:`home_steps` of the
shaft) and sets the position 0 there, and the referenced bit. Faults: :attr:`ModbusMotorEmulator.faults`
mangles replies (drop, corrupt, truncate, delay, disconnect, duplicate; late: held back and sent just
before the next reply; reorder: sent right after it; stale: the reply to the last identical request
instead; match by function code), :meth:`fail_next` answers
the next request with an exception code, :meth:`raise_alarm` trips an alarm (the motor stops, the alarm
bit and code are set until the profile's alarm reset), :meth:`go_silent` stops answering (a controller
that hangs), :meth:`power_cycle` cuts and restores its power (an incremental drive loses its position and
origin: it counts from 0 where the shaft stands); :attr:`ModbusMotorEmulator.refuse_gaps` answers a read
that touches a register the profile does not name with exception 2, as some units do. Function 23
(Read/Write Multiple Registers) writes, then reads. A request for a function the unit does not implement
gets exception 1 under that function's code, on TCP and RTU; on an RTU line a frame with a bad CRC gets
no reply, and neither costs the request after it.

A profile with a ``[sync_start]`` table (Oriental Motor's direct data operation) holds the data of a
block written with the hold trigger value (0): a later write of the trigger register alone starts the
move with the data held. Those data are volatile: a power cycle clears them, and a trigger on them then
(operating speed 0) trips the operation data alarm (:data:`DATA_ALARM`). Its group register (Oriental
Motor's "Group" command; -1: individual) makes a unit a child of the parent unit it names: a Write
Multiple Registers (0x10) query to the parent's address is executed by every child of it on the same
bus, silently (only the parent answers; :class:`ModbusBusEmulator` puts several units on one RTU line).
The group is volatile too: -1 again after a power cycle (:meth:`ModbusMotorEmulator.power_cycle_after_preload`
cuts the power right after the unit took its next preload, so the trigger lands on a unit that lost it).
A query to unit 0 (broadcast) is executed by every unit on the line and answered by none. Units sharing
a :class:`StartLine` record how a start reached them: the reply to a trigger is held back until every
unit of the line that holds a preloaded move has received its own trigger (a driver that waits for one
reply before sending the next trigger is seen: :attr:`StartLine.late`).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import select
import socket
import threading
import time
from collections import deque

from pymodbus.constants import ExcCodes
from pymodbus.framer.rtu import FramerRTU
from pymodbus.pdu.decoders import DecodePDU
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from gonio.clock import WallClock
from gonio.drivers.modbus.profile import MotorProfile, load_profile
from gonio.motion.trapezoid import move_time, position_at
from gonio.sim.emulators.link import Deferred, FaultPlan, PtyLink, Watched, mangle

__all__ = ["ModbusMotorEmulator", "ModbusBusEmulator", "StartLine", "DATA_ALARM"]

#: The alarm a trigger on data the unit never received trips (the AZ's "operation data error", code
#: from memory of its manual: secondary).
DATA_ALARM = 0x70


class StartLine:
    """Units whose start triggers are watched together (set each unit's :attr:`start_line`).

    A unit that takes a preload (its move block with the hold trigger) is *armed*; one whose trigger
    starts the move is no longer. The reply to a trigger goes out only once no unit is armed (every
    trigger of the start received) or after ``wait_s`` of wall time: then :attr:`late` counts it (the
    driver waited for a reply before the next trigger went out). :attr:`starts` counts the starts.

    Parameters
    ----------
    wait_s : float
        Wall time (s) a trigger's reply waits for the other armed units' triggers.
    """

    def __init__(self, wait_s: float = 0.5):
        self.wait_s = float(wait_s)
        self._cv = threading.Condition()
        self.armed: set[int] = set()
        self.late = 0
        self.starts = 0

    def arm(self, unit) -> None:
        with self._cv:
            self.armed.add(id(unit))

    def fire(self, unit) -> None:
        with self._cv:
            self.armed.discard(id(unit))
            self.starts += 1
            self._cv.notify_all()

    def wait(self) -> None:
        """Before a trigger's reply: until no unit is armed (bounded by ``wait_s``)."""
        with self._cv:
            if not self._cv.wait_for(lambda: not self.armed, timeout=self.wait_s):
                self.late += 1


class ModbusMotorEmulator(Watched):
    """A motor controller following ``profile`` (a MotorProfile or a shipped profile's name). Its
    server's thread and, on RTU, the relay between the ptys are watched (:class:`Watched`): pymodbus
    answers a request the unit cannot serve with an exception response, so only a bug ends them.

    Parameters
    ----------
    profile : MotorProfile or str
    clock : Clock, optional
        Time source of the motion (default: the wall clock).
    device_id : int
        The unit id it answers.
    """

    def __init__(self, profile: MotorProfile | str = "generic", clock=None, device_id: int = 1):
        super().__init__()
        self.profile = profile if isinstance(profile, MotorProfile) else load_profile(profile)
        self.clock = clock or WallClock()
        self.device_id = device_id
        self.faults = FaultPlan()
        self.deferred = Deferred()
        self._last: dict[bytes, bytes] = {}  # the last reply to each request (its PDU), for "stale"
        self._asked = b""
        self.requests: list[bytes] = []  # raw request frames, for byte-exact tests
        #: Where the home sensor is (steps of the shaft, the frame of :meth:`set_position`).
        self.home_steps = 0.0
        #: Whether the controller knows its origin (the profile's referenced bit).
        self.referenced = False
        self._count = 0.0  # the controller's position less the shaft's
        self._homing = False
        self._silent = False
        self.power_cycles = 0
        #: Refuse (exception 2) a read touching an address that no register of the profile covers.
        self.refuse_gaps = False
        self._named = {r.address + i for r in self.profile.registers.values() for i in range(r.count)}
        self._exceptions: deque[tuple[int, int | None]] = deque()
        self._lock = threading.Lock()
        self.alarm_code = 0
        self._move = (0.0, 0.0, 0.0, 1.0, 1.0)
        top = max(r.address + r.count for r in self.profile.registers.values())
        self._base = min(r.address for r in self.profile.registers.values())
        self._regs = [0] * (top - self._base)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server = None
        self._thread: threading.Thread | None = None
        self._links: list[PtyLink] = []
        self._relay_stop = threading.Event()
        self._relay: threading.Thread | None = None
        self._relay_wake: tuple[int, int] | None = None   # a pipe: stop() ends the relay's wait at once
        self._wake: asyncio.Event | None = None            # set by stop(): the server's loop ends at once
        self.address: tuple[str, int] | None = None
        self.port: str | None = None
        #: The line this unit shares with others (set by :class:`ModbusBusEmulator`), or None.
        self.bus: ModbusBusEmulator | None = None
        self._line = None
        sync = self.profile.sync_start
        self._group_reg = None if sync is None else sync.group_register
        if self._group_reg is not None:
            self._set(self._group_reg, -1)
        #: (clock time, index of the request that started it in :attr:`requests` of this unit or its
        #: bus, wall time perf_counter) of every move a trigger started.
        self.starts: list[tuple[float, int, float]] = []
        #: The :class:`StartLine` this unit's triggers are watched on, or None.
        self.start_line: StartLine | None = None
        self._answer_trigger = False
        self._cycle_after_preload = False

    @property
    def plan(self) -> tuple[float, float, float, float, float]:
        """The move under way or last made: (clock time it started, start and goal in shaft steps,
        speed steps/s, acceleration steps/s²)."""
        return self._move

    @property
    def group_id(self) -> int:
        """The parent's address this unit executes group queries of (-1: none)."""
        return -1 if self._group_reg is None else self._get(self._group_reg)

    # -- the motor ------------------------------------------------------------------------------------
    def position_steps(self) -> int:
        """The controller's position (steps) now: the shaft's, in the frame it counts from."""
        return int(round(self._shaft() + self._count))

    def _shaft(self, t: float | None = None) -> float:
        t0, start, goal, v, a = self._move
        if start == goal:
            return goal
        return float(position_at((self.clock.now() if t is None else t) - t0, start, goal, v, a))

    def assume_referenced(self) -> None:
        """As if the origin had been set in an earlier session and kept since: the referenced bit on,
        the controller counting in the shaft's frame."""
        with self._lock:
            self.referenced, self._count = True, 0.0

    def power_cycle(self) -> None:
        """Power off and on: alarms and the move end; an incremental drive (the profile not
        ``absolute``) loses its position and origin: it counts from 0 where the shaft stands."""
        with self._lock:
            self._power_cycle()

    def power_cycle_after_preload(self) -> None:
        """Cut and restore the power right after the unit takes its next preload (the move block with
        the hold trigger): its held data and group are lost before the trigger comes."""
        self._cycle_after_preload = True

    def _power_cycle(self) -> None:
        self.power_cycles += 1
        self._hold()
        self.alarm_code = 0
        self._homing = False
        if self.profile.sync_start is not None:  # the direct data and the group are volatile
            for name in self.profile.move_block:
                self._set(name, 0)
            if self._group_reg is not None:
                self._set(self._group_reg, -1)
        if not self.profile.absolute:
            self._count = -self._shaft()
            self.referenced = False

    def halt(self) -> None:
        """Stop the motor where it is, as its stop input or another client would."""
        with self._lock:
            self._hold()
            self._homing = False

    def go_silent(self, silent: bool = True) -> None:
        """Stop answering every request (a controller that hangs), or answer again."""
        self._silent = silent

    def moving(self) -> bool:
        t0, start, goal, v, a = self._move
        moving = start != goal and self.clock.now() - t0 < float(move_time(goal - start, v, a))
        if self._homing and not moving:  # at the home sensor: the origin is here
            self._homing, self.referenced = False, True
            self._count = -self.home_steps
        return moving

    def set_position(self, steps: int) -> None:
        """Put the motor at rest at ``steps`` (where it stood at power-up; the controller counts there)."""
        with self._lock:
            self._move = (self.clock.now(), float(steps) - self._count, float(steps) - self._count, 1.0, 1.0)

    def position_steps_f(self, t: float | None = None) -> float:
        """The shaft position (steps, unrounded, the frame of :meth:`set_position` when the controller
        counts from its origin) now, or at clock time ``t`` on the move under way: what an optical model
        of the gantry sees."""
        return self._shaft(t)

    def _hold(self) -> None:
        p = float(round(self._shaft()))
        self._move = (self.clock.now(), p, p, 1.0, 1.0)

    def raise_alarm(self, code: int) -> None:
        """Trip alarm ``code``: the motor stops where it is; the alarm bit stays until a reset."""
        with self._lock:
            self._hold()
            self.alarm_code = code

    def fail_next(self, code: int = ExcCodes.ILLEGAL_ADDRESS, *, address: int | None = None,
                  times: int = 1) -> None:
        """Answer the next ``times`` requests (at ``address``, or any) with exception ``code``."""
        with self._lock:
            self._exceptions.extend([(int(code), address)] * times)

    def _get(self, name: str) -> int:
        reg = self.profile[name]
        off = reg.address - self._base
        return reg.decode(self._regs[off:off + reg.count], self.profile.word_order)

    def _set(self, name: str, value: int) -> None:
        reg = self.profile[name]
        off = reg.address - self._base
        self._regs[off:off + reg.count] = reg.encode(value, self.profile.word_order)

    def _refresh(self) -> None:
        p = self.profile
        moving = self.moving()
        self._set("actual_position", self.position_steps())
        status = (int(moving) << p.moving_bit) | (int(bool(self.alarm_code)) << p.alarm_bit)
        if p.ready_bit is not None and not self.alarm_code:
            status |= 1 << p.ready_bit
        if p.referenced_bit is not None and self.referenced:
            status |= 1 << p.referenced_bit
        self._set("status", status)
        self._set("alarm_code", self.alarm_code)

    def _written(self, address: int, count: int) -> None:
        """React to registers just written: a trigger starts a move, stop and alarm reset commands."""
        p = self.profile
        touched = {n for n, r in p.registers.items()
                   if r.address < address + count and address < r.address + r.count}
        last = p.move_block[-1]
        v = p.velocity_rev_s(self._get("velocity")) * p.steps_per_rev
        a = p.accel_rev_s2(self._get("acceleration")) * p.steps_per_rev
        v = v if v > 0 else p.steps_per_rev  # the origin operation before any move: a turn a second
        a = a if a > 0 else 4.0 * p.steps_per_rev
        sync = p.sync_start
        if sync is not None and sync.trigger in touched and self._get(sync.trigger) == sync.hold \
                and len(touched) > 1:  # a preload: the block with the hold trigger
            if self.start_line is not None:
                self.start_line.arm(self)
            if self._cycle_after_preload:
                self._cycle_after_preload = False
                self._power_cycle()
                return
        if last in touched and self._get(last) == p.move_constants.get(last) and not self.alarm_code:
            if sync is not None and len(touched) == 1 and self.start_line is not None:
                self.start_line.fire(self)
                self._answer_trigger = True
            if self._get("velocity") <= 0 and sync is not None:
                self._hold()  # a trigger on data it never received (lost at power-off)
                self.alarm_code = DATA_ALARM
            else:
                goal = float(self._get("target_position")) - self._count
                self._move = (self.clock.now(), self._shaft(), goal, max(v, 1e-9), max(a, 1e-9))
                self._homing = False
                log = self.bus.requests if self.bus is not None else self.requests
                self.starts.append((self.clock.now(), len(log) - 1, time.perf_counter()))
        if (p.origin is not None and p.origin.register in touched and self._get(p.origin.register)
                == p.origin.value and not self.alarm_code):
            self._move = (self.clock.now(), self._shaft(), float(self.home_steps), v, a)
            self._homing, self.referenced = True, False
        if p.stop.register in touched and self._get(p.stop.register) == p.stop.value:
            self._hold()
            self._homing = False
        if p.alarm_reset.register in touched and self._get(p.alarm_reset.register) == p.alarm_reset.value:
            self.alarm_code = 0

    async def _action(self, function_code, start_address, address, count, registers, set_values):
        with self._lock:
            if self._exceptions:
                code, match = self._exceptions[0]
                if match is None or match == address:
                    self._exceptions.popleft()
                    return ExcCodes(code)
            off = address - self._base
            if off < 0 or off + count > len(self._regs):
                return ExcCodes.ILLEGAL_ADDRESS
            if set_values is None:
                if self.refuse_gaps and not self._named.issuperset(range(address, address + count)):
                    return ExcCodes.ILLEGAL_ADDRESS
                self._refresh()
                at = address - start_address
                registers[at:at + count] = self._regs[off:off + count]
                return None
            self._regs[off:off + count] = [int(v) for v in set_values]
            self._written(address, count)
        if self.bus is not None and function_code == 16:
            self.bus.group_write(self, address, set_values)
        return None

    def execute_silently(self, address: int, values) -> None:
        """A write this unit executes without answering (a group or broadcast query)."""
        with self._lock:
            off = address - self._base
            if off < 0 or off + len(values) > len(self._regs):
                return  # the unit would answer exception 2, but it answers nothing here
            self._regs[off:off + len(values)] = [int(v) for v in values]
            self._written(address, len(values))
            self._answer_trigger = False  # no reply to hold back

    def _trace(self, sending: bool, data: bytes) -> bytes:
        if not sending:
            self.requests.append(bytes(data))
            # The request's PDU (no TCP transaction header, no RTU CRC): what "stale" replies are kept by.
            self._asked = bytes(data[7:]) if self.address is not None else bytes(data[1:-2])
            return data
        if self._silent:
            return b""
        if self._answer_trigger:
            self._answer_trigger = False
            self.start_line.wait()
        fc = data[7] if self.address is not None else data[1]
        if fc == 0x80 and self._asked:
            # pymodbus answers a function it does not decode with exception 1 under function 0x80; the
            # spec's exception response carries the request's function code with its high bit set
            fc = (self._asked[0] & 0x7F) | 0x80
            data = data[:7] + bytes([fc]) + data[8:]
        fault = self.faults.take(fc & 0x7F)
        if fault is not None and fault.kind == "disconnect":
            self._disconnect()
            return b""
        earlier, self._last[self._asked] = self._last.get(self._asked, bytes(data)), bytes(data)
        if fault is not None and fault.kind == "stale":
            data, fault = earlier, None  # on TCP it keeps its old transaction id
        if self.deferred.hold(bytes(data), fault):
            return b""
        out = mangle(data, fault)
        if out is None:
            return b""
        frames: list[bytes] = []
        self.deferred.before(frames.append)
        frames.append(out)
        self.deferred.after(frames.append)
        return b"".join(frames)

    def _disconnect(self) -> None:
        if self.address is not None and self._server is not None:
            for conn in list(self._server.active_connections.values()):
                conn.close()
        elif self._links:
            self._links[0].unplug()

    def replug(self) -> None:
        """After a serial disconnect: a fresh pty behind the same port name."""
        if self._links:
            self._unheard = b""  # a frame cut short by the pull is not continued by the next one
            self._links[0].replug()

    # -- serving ---------------------------------------------------------------------------------------------
    def _device(self) -> SimDevice:
        return SimDevice(self.device_id, simdata=[SimData(address=self._base, count=len(self._regs), values=0,
                                                          datatype=DataType.REGISTERS)], action=self._action)

    def _serve(self, make_server, ready: threading.Event, failed: list) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        asyncio.set_event_loop(loop)

        async def main():
            self._server = make_server()
            self._wake = asyncio.Event()
            await self._server.serve_forever(background=True)
            ready.set()
            while self._server is not None and not self._stopping:
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._wake.wait(), 0.02)
            await self._server.shutdown()

        self._stopping = False
        try:
            loop.run_until_complete(main())
        except BaseException as exc:
            if ready.is_set():
                self._died(exc)          # it was serving
            else:
                failed.append(exc)       # it never served: _start raises it
        finally:
            ready.set()
            loop.close()

    def _start(self, make_server) -> None:
        if self._thread is not None:
            raise RuntimeError("modbus emulator is already running")
        ready, failed = threading.Event(), []
        self._thread = threading.Thread(target=self._serve, args=(make_server, ready, failed), daemon=True,
                                        name="emu-modbus")
        self._thread.start()
        if not ready.wait(5.0) or self._server is None or failed:
            self.stop()
            if failed:
                raise RuntimeError(f"modbus emulator could not start: {failed[0]}") from failed[0]
            raise RuntimeError("modbus emulator did not start within 5 s")

    def start_tcp(self, port: int = 0) -> tuple[str, int]:
        """Serve Modbus TCP on 127.0.0.1 at ``port`` (0: a free one); returns (host, port). A port that
        another server holds is refused here (OSError naming it), not left to the server's thread."""
        with socket.socket() as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as asyncio's server binds
            try:
                s.bind(("127.0.0.1", port))
            except OSError as err:
                raise OSError(f"modbus emulator: cannot listen on 127.0.0.1:{port} "
                              f"({(err.strerror or str(err)).lower()})") from None
            port = s.getsockname()[1]
        self.address = ("127.0.0.1", port)
        try:
            self._start(lambda: ModbusTcpServer(self._device(), address=self.address,
                                                trace_packet=self._trace))
        except BaseException:
            self.address = None
            raise
        return self.address

    def start_rtu(self, baudrate: int = 115200, *, units=None, trace=None, line=None) -> str:
        """Serve Modbus RTU on a pty; returns the port name a client opens. ``units`` (emulators,
        default this one) share the line, each answering its own address; ``trace`` replaces this unit's
        packet hook and ``line`` (bytes from the master -> the bytes the units' server is given) sits on
        the wire (:class:`ModbusBusEmulator` gives both)."""
        self._line = line or self._own_line
        self._unheard = b""
        client_side, server_side = PtyLink("ttyMB"), PtyLink("ttyMBsrv")
        self._links = [client_side, server_side]
        self._relay_stop.clear()
        self._relay_wake = os.pipe()
        self._relay = threading.Thread(target=self._bridge, daemon=True, name="emu-modbus-relay")
        self._relay.start()
        self.port = client_side.port
        devices = self._device() if units is None else [u._device() for u in units]
        self._start(lambda: ModbusSerialServer(devices, port=server_side.port, baudrate=baudrate,
                                               trace_packet=trace or self._trace,
                                               ignore_missing_devices=units is not None))
        return self.port

    def _own_line(self, data: bytes) -> bytes:
        """The master's bytes as this unit's server is given them, frame by frame: a frame with a bad CRC
        dropped, a request for a function no unit implements answered here (:func:`_screened`)."""
        frames, self._unheard = _frames(self._unheard + data)
        out = b""
        for frame in frames:
            if _screened(frame, {self.device_id}, self.answer_line):
                continue
            out += frame
        return out

    def answer_line(self, frame: bytes) -> None:
        """Write ``frame`` to the RTU line's master (a reply the units' server does not make)."""
        if self._links:
            self._links[0].write(frame)

    def _bridge(self) -> None:
        """Copy bytes between the client's pty and the server's, waiting on both at once (watched: an
        exception that ends it is told to the watchers)."""
        try:
            self._relay_loop()
        except BaseException as exc:
            self._died(exc)

    def _relay_loop(self) -> None:
        a, b = self._links
        while not self._relay_stop.is_set():
            fds = {fd: (src, dst) for src, dst in ((a, b), (b, a)) if (fd := src.master) is not None}
            if len(fds) < 2:
                self._relay_stop.wait(0.01)
                continue
            try:
                ready, _, _ = select.select([*fds, self._relay_wake[0]], [], [], 0.02)
            except (OSError, ValueError):
                continue
            for fd in ready:
                if fd not in fds:
                    continue   # the wake pipe: stopping
                src, dst = fds[fd]
                data = src.read(0.0)
                if data and src is a and self._line is not None:
                    data = self._line(data)
                if data:
                    dst.write(data)

    def stop(self) -> None:
        self._stopping = True
        loop, wake = self._loop, self._wake
        if loop is not None and wake is not None:
            with contextlib.suppress(RuntimeError):   # its loop has closed already
                loop.call_soon_threadsafe(wake.set)
        if self._thread is not None:
            self._thread.join(5.0)
            if self._thread.is_alive():
                raise RuntimeError("modbus emulator did not stop within 5 s")
        self._thread = None
        self._server = None
        self._relay_stop.set()
        if self._relay_wake is not None:
            os.write(self._relay_wake[1], b"\0")
        if self._relay is not None:
            self._relay.join(5.0)
        if self._relay_wake is not None and (self._relay is None or not self._relay.is_alive()):
            for fd in self._relay_wake:
                os.close(fd)
            self._relay_wake = None
        for link in self._links:
            link.close()
        self._links = []


class ModbusBusEmulator:
    """Several emulated units on one RTU line (one pty): each answers its own address; a unit that is
    not addressed stays silent, as on RS-485. A Write Multiple Registers (0x10) query to a unit is also
    executed, silently, by every unit whose group register names it (the parent answers alone); a
    query to unit 0 (broadcast) is executed by every unit, and answered by none.

    Parameters
    ----------
    units : sequence of ModbusMotorEmulator
        Distinct device ids; not started on their own.
    """

    def __init__(self, units):
        self.units = {u.device_id: u for u in units}
        if len(self.units) != len(units):
            raise ValueError("modbus bus emulator: device ids must be distinct")
        self.requests: list[bytes] = []  # every frame on the line from the master
        self.replies: list[bytes] = []   # every frame a unit sent
        self.broadcasts = 0
        self._pending = b""
        self._host = ModbusMotorEmulator(units[0].profile, clock=units[0].clock, device_id=units[0].device_id)
        for u in units:
            u.bus = self
        self.port: str | None = None

    def group_write(self, parent: ModbusMotorEmulator, address: int, values) -> None:
        """The children of ``parent`` execute the write it just executed."""
        for u in self.units.values():
            if u is not parent and u.group_id == parent.device_id:
                u.execute_silently(address, values)

    def _trace(self, sending: bool, data: bytes) -> bytes:
        if sending:
            self.replies.append(bytes(data))
        return data

    def _line(self, data: bytes) -> bytes:
        """The master's bytes as the units see them, frame by frame: each recorded; one with a bad CRC
        dropped, one for a function no unit implements answered here (:func:`_screened`); a broadcast
        executed by every unit (and given to none to answer); a frame to an address nobody has, dropped."""
        frames, self._pending = _frames(self._pending + data)
        out = b""
        for frame in frames:
            self.requests.append(frame)
            if _screened(frame, set(self.units), self._answer):
                continue
            if frame[0] == 0:
                self._broadcast(frame)
            elif frame[0] in self.units:
                out += frame
        return out

    def _answer(self, frame: bytes) -> None:
        self.replies.append(frame)
        self._host.answer_line(frame)

    def _broadcast(self, frame: bytes) -> None:
        if frame[1] != 16 or FramerRTU.compute_CRC(frame[:-2]) != int.from_bytes(frame[-2:], "big"):
            return  # only writes are broadcast; a frame with a bad CRC is not executed
        self.broadcasts += 1
        address, count = int.from_bytes(frame[2:4], "big"), int.from_bytes(frame[4:6], "big")
        values = [int.from_bytes(frame[7 + 2 * i:9 + 2 * i], "big") for i in range(count)]
        for u in self.units.values():
            u.execute_silently(address, values)

    @property
    def error(self) -> BaseException | None:
        """What ended the line's serving threads (:attr:`ModbusMotorEmulator.error`), or None."""
        return self._host.error

    def watch(self, callback) -> None:
        """As :meth:`ModbusMotorEmulator.watch`, for the line's threads."""
        self._host.watch(callback)

    def start_rtu(self, baudrate: int = 115200) -> str:
        """Serve the line on a pty; returns the port name a client opens."""
        self.port = self._host.start_rtu(baudrate, units=list(self.units.values()), trace=self._trace,
                                         line=self._line)
        return self.port

    def stop(self) -> None:
        self._host.stop()


def _request_len(buf: bytes) -> int:
    """The length of the RTU request frame at the head of ``buf`` (more than ``len(buf)`` while its
    header is incomplete)."""
    if len(buf) < 2:
        return 2
    fc = buf[1]
    if fc in (1, 2, 3, 4, 5, 6):
        return 8
    if fc in (15, 16):
        return 9 + buf[6] if len(buf) > 6 else 7
    if fc == 23:
        return 13 + buf[10] if len(buf) > 10 else 11
    return len(buf)  # a function this line does not frame: passed on whole


def _frames(buf: bytes) -> tuple[list[bytes], bytes]:
    """The whole request frames at the head of ``buf``, and what follows them (a frame not whole yet)."""
    frames = []
    while buf and (n := _request_len(buf)) <= len(buf):
        frames.append(buf[:n])
        buf = buf[n:]
    return frames, buf


def _screened(frame: bytes, units: set[int], answer) -> bool:
    """Whether ``frame`` (a request from the master) is handled here rather than by pymodbus, whose RTU
    framer skips an unknown function byte by byte, and throws the whole buffer away after a bad CRC: the
    next request went with either. As the Modbus over serial line spec says, a frame with a bad CRC gets
    no reply (dropped here); a unit on the line answers a request for a function it does not implement
    with exception 1 (illegal function), the request's code with its high bit set (``answer`` writes
    it); nobody answers a broadcast, or a code that is no function (0, or 128 and above: an exception
    response's)."""
    if len(frame) < 4 or FramerRTU.compute_CRC(frame[:-2]) != int.from_bytes(frame[-2:], "big"):
        return True
    if frame[1] in DecodePDU.pdu_table:
        return False
    if 0 < frame[1] < 0x80 and frame[0] in units:
        reply = bytes([frame[0], frame[1] | 0x80, 0x01])
        answer(reply + FramerRTU.compute_CRC(reply).to_bytes(2, "big"))
    return True
