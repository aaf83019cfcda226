"""An emulated Dynamixel Protocol 2.0 bus of X-series servos (XM430-W350, XL430-W250) over a pty.

Each :class:`~gonio.sim.emulators.dxl_servo.EmulatedServo` keeps an X-series control table and a shaft
(see that module: profiles, mechanical stops, the turn count after power-up, Shutdown, the bus
watchdog, Indirect Data). :class:`DynamixelBusEmulator` serves a set of servos on one pty with the
instructions ping, read, write, reg write, action, sync read/write, bulk read and reboot, lets a servo
without power answer nothing, and applies the faults queued in :attr:`DynamixelBusEmulator.faults` to
replies (matched by servo ID or by ``(id, instruction)``).

References
----------
ROBOTIS e-Manual: "DYNAMIXEL Protocol 2.0"; "XM430-W350" and "XL430-W250" control tables; "Bus Watchdog".
"""

from __future__ import annotations

import threading
import time

from gonio.sim.emulators.dxl_packet import BROADCAST_ID, Inst, Packet, PacketReader, status_packet
from gonio.sim.emulators.dxl_servo import (
    ALERT,
    ERR_ACCESS,
    ERR_CRC,
    ERR_DATA_LENGTH,
    ERR_DATA_LIMIT,
    ERR_DATA_RANGE,
    ERR_INSTRUCTION,
    ERR_RESULT_FAIL,
    MODELS,
    EmulatedServo,
)
from gonio.sim.emulators.link import Deferred, EmulatorThread, FaultPlan, PtyLink, mangle

__all__ = ["EmulatedServo", "DynamixelBusEmulator", "MODELS", "ERR_RESULT_FAIL", "ERR_INSTRUCTION",
           "ERR_CRC", "ERR_DATA_RANGE", "ERR_DATA_LENGTH", "ERR_DATA_LIMIT", "ERR_ACCESS", "ALERT"]

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
        Faults applied to replies; match by servo ID or ``(id, instruction)``. ``late`` and ``reorder``
        replies are held in :attr:`deferred` while the bus goes on answering.
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
        self.deferred = Deferred()
        self._last: dict[tuple, bytes] = {}  # the last reply to each request, for "stale"
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
        try:
            super().stop(timeout_s)
        finally:  # a thread that did not stop in time loses its port all the same
            self.link.close()

    # -- serving ---------------------------------------------------------------------------------------
    def step(self) -> None:
        if not self.link.plugged:
            self._stop.wait(self.poll_s)
            return
        if not self.link.readable(self.poll_s, self.wake_fd):
            return
        with self.lock:  # read under the lock: drain() holding it sees every byte handled or waiting
            data = self.link.read(0.0)
            for packet in self._reader.feed(data):
                self.received.append(packet.raw)
                for dxl_id, reply in self._handle(packet):
                    self._send(dxl_id, packet.inst, reply, (dxl_id, packet.inst, packet.params))
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

    def _send(self, dxl_id: int, inst: int, reply: bytes, key: tuple) -> None:
        fault = self.faults.take(dxl_id, (dxl_id, inst))
        if fault is not None and fault.kind == "disconnect":
            self.link.unplug()
            self._reader = PacketReader()
            return
        earlier, self._last[key] = self._last.get(key, reply), reply
        if fault is not None and fault.kind == "stale":
            reply, fault = earlier, None
        if self.deferred.hold(reply, fault):
            return
        out = mangle(reply, fault)
        if out is not None:
            self.deferred.before(self.link.write)
            self.link.write(out)
            self.deferred.after(self.link.write)

    def _targets(self, dxl_id: int) -> list[EmulatedServo]:
        if dxl_id == BROADCAST_ID:
            return [s for s in self.servos.values() if s.powered]
        return [self.servos[dxl_id]] if dxl_id in self.servos and self.servos[dxl_id].powered else []

    def _servo(self, dxl_id: int) -> EmulatedServo | None:
        s = self.servos.get(dxl_id)
        return s if s is not None and s.powered else None

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
            return 0, s.ping_reply()
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
                s = self._servo(dxl_id)
                if s is None:
                    continue
                s.heard()
                err, data = s.read(int.from_bytes(prm[i + 1:i + 3], "little"),
                                   int.from_bytes(prm[i + 3:i + 5], "little"))
                out.append((dxl_id, status_packet(dxl_id, s.error_byte(err), data)))
            return out
        if p.dxl_id != BROADCAST_ID or len(prm) < 4:
            return out  # Sync Read/Write: Packet ID 0xFE (e-Manual); any other reaches no servo
        addr = int.from_bytes(prm[0:2], "little")
        length = int.from_bytes(prm[2:4], "little")
        body = prm[4:]
        if p.inst == Inst.SYNC_READ:
            for dxl_id in body:
                s = self._servo(dxl_id)
                if s is None:
                    continue
                s.heard()
                err, data = s.read(addr, length)
                out.append((dxl_id, status_packet(dxl_id, s.error_byte(err), data)))
            return out
        # Sync Write: an ID and ``length`` bytes per servo. No servo answers (the packet is broadcast), so
        # what a servo refuses (an EEPROM item with torque on, a goal past its limits, an address no item
        # covers) it refuses silently; a servo whose ID is not in the packet ignores it; a packet whose
        # data do not divide into whole entries is dropped (no servo can know which bytes are its own).
        step = 1 + length
        if length == 0 or len(body) % step:
            return out
        for i in range(0, len(body), step):
            s = self._servo(body[i])
            if s is not None:
                s.heard()
                s.write(addr, body[i + 1:i + step])
        return out
