"""One Dynamixel Protocol 2.0 bus: a dynamixel-sdk PortHandler and PacketHandler behind one lock.

The SDK's port is not thread-safe, so every transaction (instruction and its status packets) runs under
:attr:`DynamixelBus.lock`; ``stop()`` from another thread waits at most one transaction. Failures become
typed :class:`~gonio.protocols.DeviceFault` subclasses:

- no reply / corrupt reply: retried ``retries`` times, then :class:`DynamixelCommError` (transient);
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
    port_factory : callable, optional
        ``port_factory(port) -> PortHandler`` (default :class:`WaitingPortHandler`); tests and socket
        transports inject their own.

    Notes
    -----
    No I/O happens until :meth:`connect`.
    """

    def __init__(self, port: str, baudrate: int = 1_000_000, *, name: str = "dxl", retries: int = 1,
                 port_factory: Callable[[str], sdk.PortHandler] | None = None):
        if baudrate not in _BAUD_RATES:
            raise ValueError(f"dynamixel bus '{name}': baudrate {baudrate} is not one of {_BAUD_RATES}")
        if not isinstance(retries, int) or not 0 <= retries <= 5:
            raise ValueError(f"dynamixel bus '{name}': retries {retries!r} is outside [0, 5]")
        self.port_name = port
        self.baudrate = baudrate
        self.name = name
        self.retries = retries
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
            if not self._port.openPort() or not self._port.setBaudRate(self.baudrate):
                raise OSError("openPort/setBaudRate returned False")
        except _PORT_ERRORS as exc:
            self._open = False
            raise DynamixelCommError(
                self.name, f"cannot open port {self.port_name} ({type(exc).__name__})") from exc
        self._open = True

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
                    last = DynamixelCommError(
                        self.name, f"{what}: port {self.port_name} lost ({exc})", dxl_id)
                    continue
                if comm == sdk.COMM_PORT_BUSY:
                    self._shut()
                    last = DynamixelCommError(self.name, f"{what}: port {self.port_name} busy", dxl_id, comm)
                    continue
                if comm in _RETRYABLE:
                    who = f"servo {dxl_id}" if dxl_id is not None else "servos"
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

    # -- instructions -----------------------------------------------------------------------------------
    def ping(self, dxl_id: int) -> int:
        """The model number of servo ``dxl_id``."""
        return int(self._call(f"ping {dxl_id}", dxl_id, lambda: self._ph.ping(self._port, dxl_id)))

    def read(self, dxl_id: int, field: Field) -> int:
        """Read one field (decoded: signed fields sign-extended)."""
        fns = {1: self._ph.read1ByteTxRx, 2: self._ph.read2ByteTxRx, 4: self._ph.read4ByteTxRx}
        raw = self._call(f"read {field.name}", dxl_id,
                         lambda: fns[field.size](self._port, dxl_id, field.address))
        return field.decode(int(raw))

    def read_block(self, dxl_id: int, address: int, length: int) -> bytes:
        data = self._call(f"read {length} bytes at {address}", dxl_id,
                          lambda: self._ph.readTxRx(self._port, dxl_id, address, length))
        return bytes(data)

    def write(self, dxl_id: int, field: Field, value: int) -> None:
        """Write one field and wait for the servo's status packet."""
        raw = field.encode(int(value))
        fns = {1: self._ph.write1ByteTxRx, 2: self._ph.write2ByteTxRx, 4: self._ph.write4ByteTxRx}

        def op():
            comm, err = fns[field.size](self._port, dxl_id, field.address, raw)
            return None, comm, err

        self._call(f"write {field.name}={value}", dxl_id, op)

    def reg_write(self, dxl_id: int, field: Field, value: int) -> None:
        """Register a write, applied at the next :meth:`action`."""
        data = list(field.encode(int(value)).to_bytes(field.size, "little"))

        def op():
            comm, err = self._ph.regWriteTxRx(self._port, dxl_id, field.address, field.size, data)
            return None, comm, err

        self._call(f"reg write {field.name}={value}", dxl_id, op)

    def action(self, dxl_id: int = BROADCAST_ID) -> None:
        self._call("action", None, lambda: (None, self._ph.action(self._port, dxl_id), 0))

    def reboot(self, dxl_id: int) -> None:
        def op():
            comm, err = self._ph.reboot(self._port, dxl_id)
            return None, comm, err

        self._call(f"reboot {dxl_id}", dxl_id, op)
        self.alerts.discard(dxl_id)

    def sync_write(self, field: Field, values: Mapping[int, int]) -> None:
        """One Sync Write of ``field`` for every servo in ``values`` (no status packets)."""
        params = {dxl_id: list(field.encode(int(v)).to_bytes(field.size, "little"))
                  for dxl_id, v in values.items()}

        def op():
            group = sdk.GroupSyncWrite(self._port, self._ph, field.address, field.size)
            for dxl_id, data in params.items():
                group.addParam(dxl_id, data)
            return None, group.txPacket(), 0

        self._call(f"sync write {field.name}", None, op)

    def sync_read(self, address: int, length: int, ids: Iterable[int]) -> dict[int, bytes]:
        """One Sync Read of ``length`` bytes at ``address`` from each of ``ids``.

        Every servo must answer: a silent or corrupt one raises :class:`DynamixelCommError` naming it
        (the SDK would leave its data at 0). The status packets are read one by one with the SDK's
        ``readRx`` so that each servo's error byte (its alert bit) is checked too.
        """
        ids = list(ids)

        def op():
            group = sdk.GroupSyncRead(self._port, self._ph, address, length)
            for dxl_id in ids:
                group.addParam(dxl_id)
            comm = group.txPacket()
            if comm != sdk.COMM_SUCCESS:
                return None, comm, 0
            out = {}
            for dxl_id in ids:
                data, comm, err = self._ph.readRx(self._port, dxl_id, length)
                if comm != sdk.COMM_SUCCESS or len(data) != length:
                    self._silent = dxl_id
                    return None, comm if comm != sdk.COMM_SUCCESS else sdk.COMM_RX_CORRUPT, 0
                self._check_error(f"sync read at {address}", dxl_id, err)
                out[dxl_id] = bytes(data)
            return out, sdk.COMM_SUCCESS, 0

        self._silent = None
        try:
            return self._call(f"sync read {length} bytes at {address}", None, op)
        except DynamixelCommError as exc:
            if self._silent is not None:
                raise DynamixelCommError(
                    self.name, f"sync read {length} bytes at {address}: servo {self._silent} did not answer "
                    f"({self._ph.getTxRxResult(exc.result or 0).split('] ')[-1]})", self._silent,
                    exc.result) from None
            raise

    def bulk_read(self, items: Iterable[tuple[int, Field]]) -> dict[int, int]:
        """One Bulk Read: a (possibly different) field from each servo; every servo must answer."""
        items = list(items)

        def op():
            group = sdk.GroupBulkRead(self._port, self._ph)
            for dxl_id, field in items:
                group.addParam(dxl_id, field.address, field.size)
            comm = group.txRxPacket()
            if comm != sdk.COMM_SUCCESS:
                return None, comm, 0
            out = {}
            for dxl_id, field in items:
                if not group.isAvailable(dxl_id, field.address, field.size):
                    return None, sdk.COMM_RX_CORRUPT, 0
                out[dxl_id] = field.decode(group.getData(dxl_id, field.address, field.size))
            return out, sdk.COMM_SUCCESS, 0

        return self._call("bulk read", None, op)
