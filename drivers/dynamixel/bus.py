"""One Dynamixel Protocol 2.0 bus: a dynamixel-sdk PortHandler and PacketHandler behind one lock.

The SDK's port is not thread-safe, so every transaction (instruction and its status packets) runs under
:attr:`DynamixelBus.lock`; ``stop()`` from another thread waits at most one transaction.

Replies are paired with their request here, not by the SDK. Protocol 2.0 carries no sequence number and
the SDK's ``txRxPacket``/``readRx`` take the first status packet whose ID matches (a reply that comes
after the SDK's time-out is read as the answer to the next request to that servo, and a Sync Read's
``readRx`` drops a reply that comes out of order). Every transaction here sends with the SDK's
``txPacket`` (which flushes the input; bytes found there are counted as discarded first) and receives
with its ``rxPacket`` (header, length, CRC, unstuffing), then keeps only a status packet from a servo it
asked, once per servo, with exactly the length the request calls for; any other packet is discarded and
counted (:attr:`DynamixelBus.discarded`). Reads can also be told how far they may be widened
(``room``: defined addresses before and after the span): successive reads then ask 0..3 bytes more in
turn, so that a late reply to one read has another length than the reply the next read waits for and
cannot be taken for it. What this cannot tell apart (a late reply of the same length, four reads on) is
left to the axes' plausibility check of every position (:mod:`gonio.drivers.readback`).

Failures become typed :class:`~gonio.protocols.DeviceFault` subclasses:

- no reply / corrupt reply / only replies that are not this request's: retried ``retries`` times, then
  :class:`DynamixelCommError` (transient);
- a lost port (the SDK raises ``termios.error`` or ``SerialException`` and leaves ``is_using`` set, so
  every later call would answer "port busy"): the flag is reset, the port reopened and the transaction
  retried; if the port cannot be reopened, :class:`DynamixelCommError` (transient) and the next call
  tries again;
- an error number in the status packet: :class:`DynamixelStatusError` (not transient);
- the alert bit (a hardware error) is recorded in :attr:`DynamixelBus.alerts` for the axis to decode.
"""

from __future__ import annotations

import io
import select
import termios
import threading
from collections import Counter, deque
from collections.abc import Callable, Iterable, Mapping

import dynamixel_sdk as sdk
import serial

from gonio.drivers.dynamixel.control_table import Field
from gonio.drivers.dynamixel.errors import (
    ALERT_BIT,
    DynamixelCommError,
    DynamixelStatusError,
    PacketError,
)

__all__ = ["DynamixelBus", "StuffingPacketHandler", "WaitingPortHandler", "BROADCAST_ID"]

BROADCAST_ID = sdk.BROADCAST_ID
_PORT_ERRORS = (termios.error, serial.SerialException, OSError)
_RETRYABLE = (sdk.COMM_RX_TIMEOUT, sdk.COMM_RX_CORRUPT, sdk.COMM_TX_FAIL, sdk.COMM_RX_FAIL)
_BAUD_RATES = (9600, 57600, 115200, 1_000_000, 2_000_000, 3_000_000, 4_000_000)
_HEADER = b"\xff\xff\xfd\x00"
# Packet offsets (the SDK's): ID, LEN (u16), INST, then a status packet's ERROR and its data.
_ID, _LEN, _INST, _ERR, _DATA = 4, 5, 7, 8, 9


class StuffingPacketHandler(sdk.Protocol2PacketHandler):
    """The SDK's Protocol 2.0 handler with transmit-side byte stuffing that takes effect.

    ``txPacket`` calls ``addStuffing(txpacket)`` and ignores its return value, and ``addStuffing``
    builds a new list whenever it inserts a byte, so a parameter that contains ``FF FF FD`` (e.g. the
    extended-mode goal position -131073 ticks, ``FF FF FD FF``) would go out unstuffed and the servo
    would take it for a header. Stuffing in place fixes it.
    """

    def addStuffing(self, packet):  # noqa: N802 - the SDK's name
        stuffed = super().addStuffing(list(packet))
        packet[:] = stuffed
        return packet


class WaitingPortHandler(sdk.PortHandler):
    """The SDK's port handler, except that a read with nothing to read waits for bytes (``select`` on
    the port, at most until the packet's time-out) instead of returning at once.

    The SDK's receive loop calls ``readPort`` back to back until a packet is whole or its time-out
    passes; with the port's zero read time-out that is a busy loop that keeps a core (and the GIL) busy
    for the whole wait on every transaction. Waiting in ``select`` returns as soon as a byte arrives,
    so replies are seen no later, and the time-outs are the SDK's own.
    """

    #: The USB-serial adapter's latency timer (ms) a reply's time-out allows for, twice: the SDK's
    #: fixed 16 ms (FTDI's default) unless the bus sets another (:class:`DynamixelBus`).
    latency_timer_ms: float = 16.0

    def setPacketTimeout(self, packet_length):  # noqa: N802 - the SDK's name
        """The SDK's time-out (the packet's bytes on the wire, twice the latency timer, 2 ms) with this
        port's :attr:`latency_timer_ms` in place of the SDK's module constant."""
        self.packet_start_time = self.getCurrentTime()
        self.packet_timeout = self.tx_time_per_byte * packet_length + 2.0 * self.latency_timer_ms + 2.0

    def readPort(self, length):  # noqa: N802 - the SDK's name
        ser = self.ser
        try:
            if not ser.in_waiting:
                left_ms = self.packet_timeout - self.getTimeSinceStart()
                if left_ms > 0:
                    select.select([ser.fileno()], [], [], left_ms / 1000.0)
        except (AttributeError, ValueError, io.UnsupportedOperation):
            pass  # a port without a file descriptor: the SDK's own polling
        return ser.read(length)


class DynamixelBus:
    """A Protocol 2.0 bus on one serial port.

    Parameters
    ----------
    port : str
        Serial port name (``/dev/ttyUSB0``, ``/dev/serial/by-id/...``, or an emulator's pty).
    baudrate : int
        Bits per second; one of 9600, 57600, 115200, 1e6, 2e6, 3e6, 4e6.
    name : str
        Name used in error messages (e.g. ``"dxl0"``).
    retries : int
        Extra attempts after a time-out or corrupt reply (0..5).
    latency_timer_ms : float
        The latency timer of the USB-serial adapter (ms, 0 < x <= 500): a reply's time-out allows for
        it twice, as the SDK does with its fixed 16 ms (FTDI's default). An adapter set to 1 ms can say
        so and learn of a silent servo sooner; an emulator's pty, served by a thread on a loaded host,
        needs more (:class:`gonio.sim.emulators.gantry.EmulatedGantry` writes 50 ms). Applies to a
        :class:`WaitingPortHandler` (the default port).
    port_factory : callable, optional
        ``port_factory(port) -> PortHandler`` (default :class:`WaitingPortHandler`); tests and socket
        transports inject their own.

    Attributes
    ----------
    discarded : int
        Status packets thrown away because they were not the reply of the transaction under way (late,
        duplicated, from a servo not asked, of the wrong length) or were waiting before it began.
    counts : collections.Counter
        Failed attempts by kind (``"timeout"``, ``"corrupt"``, ``"port"``): with :attr:`discarded`, what
        the runner journals about the link.

    Notes
    -----
    No I/O happens until :meth:`connect`.
    """

    def __init__(self, port: str, baudrate: int = 1_000_000, *, name: str = "dxl", retries: int = 1,
                 latency_timer_ms: float = WaitingPortHandler.latency_timer_ms,
                 port_factory: Callable[[str], sdk.PortHandler] | None = None):
        if baudrate not in _BAUD_RATES:
            raise ValueError(f"dynamixel bus '{name}': baudrate {baudrate} is not one of {_BAUD_RATES}")
        if not isinstance(retries, int) or not 0 <= retries <= 5:
            raise ValueError(f"dynamixel bus '{name}': retries {retries!r} is outside [0, 5]")
        if not 0 < latency_timer_ms <= 500:  # NaN fails too
            raise ValueError(f"dynamixel bus '{name}': latency_timer_ms {latency_timer_ms!r} is outside "
                             "(0, 500]")
        self.port_name = port
        self.baudrate = baudrate
        self.name = name
        self.retries = retries
        self.latency_timer_ms = float(latency_timer_ms)
        self._factory = port_factory or WaitingPortHandler
        self.lock = threading.RLock()
        self._port: sdk.PortHandler | None = None
        self._ph = StuffingPacketHandler()
        self._open = False
        self._users = 0
        #: IDs whose last status packet carried the alert bit (a hardware error), until cleared.
        self.alerts: set[int] = set()
        #: Reconnections made so far (a lost port reopened).
        self.reconnects = 0
        self.discarded = 0
        self.counts: Counter[str] = Counter()
        #: IDs that failed a transaction (no reply, a corrupt one, a lost port) since their owner last
        #: looked (:meth:`take_troubled`): a servo that went silent may have lost power.
        self.troubled: set[int] = set()
        self._turn = 0  # where the next widened read starts looking
        self._recent: dict[int, deque[int]] = {}  # the reply lengths each servo was asked for last

    # -- connection ---------------------------------------------------------------------------------
    def connect(self) -> None:
        """Open the port (counted: several axes share one bus, the last ``close`` closes it)."""
        with self.lock:
            self._users += 1
            if not self._open:
                self._reopen()

    def close(self) -> None:
        with self.lock:
            self._users = max(0, self._users - 1)
            if self._users == 0 and self._port is not None:
                self._shut()

    @property
    def is_open(self) -> bool:
        return self._open

    def _shut(self) -> None:
        port = self._port
        self._open = False
        if port is None:
            return
        port.is_using = False
        try:
            if port.ser is not None:
                port.closePort()
        except _PORT_ERRORS:
            pass

    def _reopen(self) -> None:
        self._shut()
        try:
            if self._port is None:
                self._port = self._factory(self.port_name)
                if isinstance(self._port, WaitingPortHandler):
                    self._port.latency_timer_ms = self.latency_timer_ms
            if not self._port.openPort() or not self._port.setBaudRate(self.baudrate):
                raise OSError("openPort/setBaudRate returned False")
        except _PORT_ERRORS as exc:
            self._open = False
            raise DynamixelCommError(
                self.name, f"cannot open port {self.port_name} ({type(exc).__name__})") from exc
        self._open = True

    def take_troubled(self, dxl_id: int) -> bool:
        """Whether ``dxl_id`` failed a transaction since the last call (and forget it)."""
        with self.lock:
            if dxl_id in self.troubled:
                self.troubled.discard(dxl_id)
                return True
            return False

    # -- one transaction, with retries and reconnection ------------------------------------------------
    def _call(self, what: str, dxl_id: int | None, fn: Callable[[], tuple]) -> object:
        """Run ``fn() -> (value, comm_result, error)`` under the lock; see the module docstring."""
        with self.lock:
            if self._users == 0:
                raise DynamixelCommError(self.name, f"{what}: not connected; call connect() first", dxl_id)
            last: DynamixelCommError | None = None
            for _attempt in range(self.retries + 1):
                if not self._open:
                    self.reconnects += 1
                    self._reopen()
                try:
                    value, comm, error = fn()
                except _PORT_ERRORS as exc:
                    # The SDK leaves is_using set after a port failure: every later call would be
                    # "port busy". Reopen on the next attempt.
                    self._shut()
                    self.counts["port"] += 1
                    self._trouble(dxl_id)
                    last = DynamixelCommError(
                        self.name, f"{what}: port {self.port_name} lost ({exc})", dxl_id)
                    continue
                if comm == sdk.COMM_PORT_BUSY:
                    self._shut()
                    last = DynamixelCommError(self.name, f"{what}: port {self.port_name} busy", dxl_id, comm)
                    continue
                if comm in _RETRYABLE:
                    who = f"servo {dxl_id}" if dxl_id is not None else "servos"
                    self.counts["timeout" if comm == sdk.COMM_RX_TIMEOUT else "corrupt"] += 1
                    self._trouble(dxl_id)
                    last = DynamixelCommError(
                        self.name, f"{what}: {who}: {self._ph.getTxRxResult(comm).split('] ')[-1]}",
                        dxl_id, comm)
                    continue
                if comm != sdk.COMM_SUCCESS:
                    raise DynamixelCommError(
                        self.name, f"{what}: {self._ph.getTxRxResult(comm)}", dxl_id, comm)
                if dxl_id is not None and dxl_id != BROADCAST_ID:
                    self._check_error(what, dxl_id, error)
                return value
            assert last is not None
            raise last

    def _trouble(self, dxl_id: int | None) -> None:
        if dxl_id is not None and dxl_id != BROADCAST_ID:
            self.troubled.add(dxl_id)

    def _check_error(self, what: str, dxl_id: int, error: int) -> None:
        if error & ALERT_BIT:
            self.alerts.add(dxl_id)
        number = error & 0x7F
        if number:
            try:
                err = PacketError(number)
                text = err.describe()
            except ValueError:
                err, text = PacketError.RESULT_FAIL, f"unknown error number {number}"
            raise DynamixelStatusError(self.name, f"{what}: servo {dxl_id} refused: {text}", dxl_id, err)

    # -- paired transactions ------------------------------------------------------------------------------
    def _send(self, dxl_id: int, inst: int, params: Iterable[int]) -> int:
        """Send one instruction packet with the SDK's ``txPacket`` (which stuffs it, adds the CRC and
        flushes the input first: what waits there now is counted as discarded)."""
        ser = self._port.ser
        waiting = ser.in_waiting if ser is not None else 0
        if waiting:
            self.discarded += max(1, bytes(ser.read(waiting)).count(_HEADER))
        params = list(params)
        packet = [0] * (len(params) + 10)
        packet[_ID] = dxl_id
        packet[_LEN], packet[_LEN + 1] = (len(params) + 3) & 0xFF, (len(params) + 3) >> 8
        packet[_INST] = inst
        packet[_INST + 1:_INST + 1 + len(params)] = params
        return self._ph.txPacket(self._port, packet)

    def _receive(self, ids: Iterable[int], length: int, timeout_bytes: int | None) -> tuple[dict, int]:
        """Status packets of ``ids``, each with ``length`` data bytes: ({id: (data, error)}, comm).
        Every other packet is discarded; stops at the first failure (time-out, corrupt) of the SDK's
        ``rxPacket`` or once every servo answered. ``timeout_bytes`` sets the SDK's packet time-out
        (None: the one running goes on)."""
        want = set(ids)
        if timeout_bytes is not None:
            self._port.setPacketTimeout(timeout_bytes)
        got: dict[int, tuple[bytes, int]] = {}
        while len(got) < len(want):
            rx, comm = self._ph.rxPacket(self._port, False)
            if comm != sdk.COMM_SUCCESS:
                return got, comm
            rid, n = rx[_ID], (rx[_LEN] | rx[_LEN + 1] << 8) - 4  # less INST, ERROR and the CRC
            refused = n == 0 and rx[_ERR] & 0x7F  # an error number: the servo sends no data with it
            if rid not in want or rid in got or (n != length and not refused):
                self.discarded += 1
                continue
            got[rid] = (bytes(rx[_DATA:_DATA + length]), rx[_ERR])
        return got, sdk.COMM_SUCCESS

    def _txrx(self, dxl_id: int, inst: int, params: Iterable[int], length: int) -> tuple:
        """One instruction to one servo and its status packet: (data, comm, error)."""
        comm = self._send(dxl_id, inst, params)
        if comm != sdk.COMM_SUCCESS:
            return None, comm, 0
        got, comm = self._receive((dxl_id,), length, length + 11)
        if comm != sdk.COMM_SUCCESS:
            return None, comm, 0
        data, error = got[dxl_id]
        return data, comm, error

    def _widen(self, ids: Iterable[int], length: int, room: tuple[int, int]) -> tuple[int, int]:
        """The (before, after) widening of the next read of ``length`` bytes from ``ids`` within ``room``:
        one whose reply length none of these servos was asked for in its last three reads (taken in
        turn among those that qualify), so that a late reply to one of those cannot pass for this one."""
        before, after = room
        options = [(0, 0), *((0, k) for k in range(1, after + 1)), *((k, 0) for k in range(1, before + 1))]
        ids = list(ids)
        used = set().union(*(self._recent.get(i, ()) for i in ids))
        fresh = [o for o in options if length + sum(o) not in used] or options
        self._turn += 1
        choice = fresh[self._turn % len(fresh)]
        for i in ids:
            self._recent.setdefault(i, deque(maxlen=3)).append(length + sum(choice))
        return choice

    # -- instructions -----------------------------------------------------------------------------------
    def ping(self, dxl_id: int) -> int:
        """The model number of servo ``dxl_id``."""
        return self.identify(dxl_id)[0]

    def identify(self, dxl_id: int) -> tuple[int, int]:
        """(model number, firmware version) of servo ``dxl_id``: both are in its reply to a Ping."""
        data = self._call(f"ping {dxl_id}", dxl_id, lambda: self._txrx(dxl_id, sdk.INST_PING, (), 3))
        return int.from_bytes(data[:2], "little"), int(data[2])

    def read(self, dxl_id: int, field: Field, room: tuple[int, int] = (0, 0)) -> int:
        """Read one field (decoded: signed fields sign-extended); ``room`` as for :meth:`read_block`."""
        data = self.read_block(dxl_id, field.address, field.size, room, what=f"read {field.name}")
        return field.decode(int.from_bytes(data, "little"))

    def read_block(self, dxl_id: int, address: int, length: int, room: tuple[int, int] = (0, 0), *,
                   what: str | None = None) -> bytes:
        """``length`` bytes at ``address``. ``room`` = (before, after): how many defined addresses lie
        right before and after the span; the read is widened into them in turn (see the module
        docstring) and the span itself returned."""
        what = what or f"read {length} bytes at {address}"

        def op():
            before, after = self._widen((dxl_id,), length, room)
            lo, n = address - before, length + before + after
            data, comm, err = self._txrx(dxl_id, sdk.INST_READ, (lo & 0xFF, lo >> 8, n & 0xFF, n >> 8), n)
            return (None if data is None else data[before:before + length]), comm, err

        return bytes(self._call(what, dxl_id, op))

    def write(self, dxl_id: int, field: Field, value: int) -> None:
        """Write one field and wait for the servo's status packet."""
        self.write_block(dxl_id, field.address, field.encode(int(value)).to_bytes(field.size, "little"),
                         what=f"write {field.name}={value}")

    def write_block(self, dxl_id: int, address: int, data: bytes, *, what: str | None = None) -> None:
        """Write ``data`` at ``address`` and wait for the servo's status packet."""
        params = (address & 0xFF, address >> 8, *bytes(data))
        self._call(what or f"write {len(data)} bytes at {address}", dxl_id,
                   lambda: self._txrx(dxl_id, sdk.INST_WRITE, params, 0))

    def reg_write(self, dxl_id: int, field: Field, value: int) -> None:
        """Register a write, applied at the next :meth:`action`."""
        data = field.encode(int(value)).to_bytes(field.size, "little")
        params = (field.address & 0xFF, field.address >> 8, *data)
        self._call(f"reg write {field.name}={value}", dxl_id,
                   lambda: self._txrx(dxl_id, sdk.INST_REG_WRITE, params, 0))

    def action(self, dxl_id: int = BROADCAST_ID) -> None:
        """Apply registered writes (a broadcast gets no status packet, a unicast one does)."""
        if dxl_id != BROADCAST_ID:
            self._call("action", dxl_id, lambda: self._txrx(dxl_id, sdk.INST_ACTION, (), 0))
            return

        def op():
            comm = self._send(dxl_id, sdk.INST_ACTION, ())
            self._port.is_using = False
            return None, comm, 0

        self._call("action", None, op)

    def reboot(self, dxl_id: int) -> None:
        self._call(f"reboot {dxl_id}", dxl_id, lambda: self._txrx(dxl_id, sdk.INST_REBOOT, (), 0))
        self.alerts.discard(dxl_id)

    def sync_write(self, field: Field, values: Mapping[int, int]) -> None:
        """One Sync Write of ``field`` for every servo in ``values`` (no status packets)."""
        self.sync_write_block(field.address, field.size,
                              {i: field.encode(int(v)).to_bytes(field.size, "little")
                               for i, v in values.items()},
                              what=f"sync write {field.name}")

    def sync_write_block(self, address: int, length: int, blocks: Mapping[int, bytes], *,
                         what: str | None = None) -> None:
        """One Sync Write (instruction 0x83 to the broadcast ID) of ``length`` bytes at ``address`` for
        every servo in ``blocks`` (ID -> its bytes): ``4 + (1 + length) * len(blocks)`` parameters, no
        status packet. Every servo named applies its own bytes as the packet ends, so contiguous items
        written together (Profile Acceleration, Profile Velocity and Goal Position: 108..119) take effect
        at once on every servo: a servo plans its goal with the profile written beside it.

        Raises
        ------
        ValueError
            A block of another length than ``length``, or an ID outside 0..252 (nothing is sent).
        """
        params = [address & 0xFF, address >> 8, length & 0xFF, length >> 8]
        for dxl_id, data in blocks.items():
            if not 0 <= dxl_id <= 252 or len(data) != length:
                raise ValueError(f"dynamixel bus '{self.name}': sync write at {address}: servo {dxl_id} "
                                 f"with {len(data)} bytes (want an ID in 0..252 and {length} bytes)")
            params += [dxl_id, *bytes(data)]

        def op():
            comm = self._send(BROADCAST_ID, sdk.INST_SYNC_WRITE, params)
            self._port.is_using = False
            return None, comm, 0

        self._call(what or f"sync write {length} bytes at {address}", None, op)

    def sync_read(self, address: int, length: int, ids: Iterable[int],
                  room: tuple[int, int] = (0, 0)) -> dict[int, bytes]:
        """One Sync Read of ``length`` bytes at ``address`` from each of ``ids`` (widened within
        ``room`` as :meth:`read_block` does).

        Every servo must answer: a silent or corrupt one raises :class:`DynamixelCommError` naming it
        (the SDK would leave its data at 0). Replies are taken in any order, each servo's once; each
        servo's error byte (its alert bit) is checked too.
        """
        ids = list(ids)
        silent: list[int] = []

        def op():
            before, after = self._widen(ids, length, room)
            lo, n = address - before, length + before + after
            params = [lo & 0xFF, lo >> 8, n & 0xFF, n >> 8, *ids]
            comm = self._send(BROADCAST_ID, sdk.INST_SYNC_READ, params)
            if comm != sdk.COMM_SUCCESS:
                return None, comm, 0
            got, comm = self._receive(ids, n, (11 + n) * len(ids))
            if comm != sdk.COMM_SUCCESS:
                silent[:] = [i for i in ids if i not in got]
                return None, comm, 0
            out = {}
            for dxl_id in ids:
                data, err = got[dxl_id]
                self._check_error(f"sync read at {address}", dxl_id, err)
                out[dxl_id] = data[before:before + length]
            return out, sdk.COMM_SUCCESS, 0

        try:
            return self._call(f"sync read {length} bytes at {address}", None, op)
        except DynamixelCommError as exc:
            if silent:
                for i in silent:
                    self._trouble(i)
                raise DynamixelCommError(
                    self.name, f"sync read {length} bytes at {address}: servo {silent[0]} did not answer "
                    f"({self._ph.getTxRxResult(exc.result or 0).split('] ')[-1]})", silent[0],
                    exc.result) from None
            raise

    def bulk_read(self, items: Iterable[tuple[int, Field]]) -> dict[int, int]:
        """One Bulk Read: a (possibly different) field from each servo; every servo must answer."""
        items = list(items)
        params = []
        for dxl_id, field in items:
            params += [dxl_id, field.address & 0xFF, field.address >> 8, field.size & 0xFF, field.size >> 8]

        def op():
            comm = self._send(BROADCAST_ID, sdk.INST_BULK_READ, params)
            if comm != sdk.COMM_SUCCESS:
                return None, comm, 0
            out = {}
            self._port.setPacketTimeout(sum(11 + f.size for _, f in items))
            for dxl_id, field in items:  # replies of several lengths: one servo at a time
                got, comm = self._receive((dxl_id,), field.size, None)
                if comm != sdk.COMM_SUCCESS:
                    return None, comm, 0
                data, err = got[dxl_id]
                self._check_error("bulk read", dxl_id, err)
                out[dxl_id] = field.decode(int.from_bytes(data, "little"))
            return out, sdk.COMM_SUCCESS, 0

        return self._call("bulk read", None, op)
