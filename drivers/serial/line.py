"""A line-based serial instrument: one command line out, one reply line back, through pyserial.

Every query flushes the input first (a late reply must not be taken for this one's answer), then reads
until the terminator under one deadline for the whole reply; a reply without its terminator is an
error (pyserial's ``read_until`` returns a partial line on time-out without raising). A lost port is
reopened with exponential back-off before the query is retried once; after a time-out the port is
reopened at the next query (a dead port can swallow writes without an error).
"""

from __future__ import annotations

import termios
import time
from collections.abc import Callable
from dataclasses import dataclass

import serial

from gonio.clock import WallClock
from gonio.protocols import DeviceFault

__all__ = ["LineInstrument", "InstrumentCommError", "InstrumentError", "CommandSet", "SCPI"]


class InstrumentCommError(DeviceFault):
    """No reply, a reply without its terminator, a garbled reply, or a lost port (transient)."""

    def __init__(self, device: str, message: str):
        super().__init__(device, message, transient=True)


class InstrumentError(DeviceFault):
    """The instrument refused a command (``ERR <code>,...``): not transient."""

    def __init__(self, device: str, message: str, code: int | None = None):
        super().__init__(device, message, transient=False)
        self.code = code


@dataclass(frozen=True)
class CommandSet:
    """An instrument's commands as data; ``{}`` takes the argument. The default is SCPI-like."""

    identify: str = "*IDN?"
    output_on: str = "OUTP ON"
    output_off: str = "OUTP OFF"
    output_query: str = "OUTP?"
    level_set: str = "SOUR:POW:LEV {:.3f}"
    level_query: str = "SOUR:POW:LEV?"
    ready_query: str = "STAT:READY?"
    exposure_set: str = "CONF:EXP {:.6g}"
    measure: str = "MEAS?"
    measure_spectrum: str = "MEAS:SPEC?"
    wavelengths_query: str = "SENS:WAV?"
    ok_reply: str = "OK"
    error_prefix: str = "ERR"


#: The SCPI-like default command set.
SCPI = CommandSet()


class LineInstrument:
    """Base of the serial instrument drivers.

    Parameters
    ----------
    name : str
        Device name in error messages.
    port : str
        A pyserial port name or URL (``/dev/ttyUSB0``, ``socket://127.0.0.1:5025``, ``loop://``, a pty).
    baudrate : int
    terminator : str
        Line terminator, both ways.
    timeout_s : float
        Deadline for one whole reply (s).
    commands : CommandSet
    reconnect_attempts : int
        Reopen attempts after a lost port (back-off 0.05, 0.1, 0.2 ... s).
    serial_factory : callable, optional
        ``serial_factory(port, baudrate) -> Serial``-like; default ``serial.serial_for_url``.
    clock : Clock, optional
        For the back-off waits.
    """

    def __init__(self, name: str, port: str, *, baudrate: int = 115200, terminator: str = "\n",
                 timeout_s: float = 1.0, commands: CommandSet = SCPI, reconnect_attempts: int = 3,
                 serial_factory: Callable | None = None, clock=None):
        if not 0 < timeout_s <= 60:
            raise ValueError(f"instrument '{name}': timeout_s {timeout_s} is outside (0, 60] s")
        if not terminator:
            raise ValueError(f"instrument '{name}': terminator must not be empty")
        self.name = name
        self.port = port
        self.baudrate = baudrate
        self.terminator = terminator.encode("ascii")
        self.timeout_s = float(timeout_s)
        self.commands = commands
        self.reconnect_attempts = reconnect_attempts
        self._factory = serial_factory or (lambda p, b: serial.serial_for_url(p, baudrate=b, timeout=0.01))
        self.clock = clock or WallClock()
        self._ser = None
        self._connected = False
        self.reconnects = 0

    def connect(self) -> None:
        self._open()
        self._connected = True

    def close(self) -> None:
        self._connected = False
        self._drop()

    def _drop(self) -> None:
        if self._ser is not None:
            try:
                self._ser.close()
            except (serial.SerialException, OSError):
                pass
        self._ser = None

    def _open(self) -> None:
        self._drop()
        try:
            self._ser = self._factory(self.port, self.baudrate)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise InstrumentCommError(self.name, f"cannot open {self.port} ({type(exc).__name__})") from exc

    def _reopen_with_backoff(self) -> None:
        delay = 0.05
        for attempt in range(self.reconnect_attempts):
            try:
                self._open()
                self.reconnects += 1
                return
            except InstrumentCommError:
                if attempt + 1 == self.reconnect_attempts:
                    raise
                self.clock.sleep(delay)
                delay *= 2

    def _exchange(self, line: str) -> str:
        ser = self._ser
        if ser is None:
            raise InstrumentCommError(self.name, "not connected; call connect() first")
        ser.reset_input_buffer()
        ser.write(line.encode("ascii") + self.terminator)
        deadline = time.monotonic() + self.timeout_s
        buf = bytearray()
        while not buf.endswith(self.terminator):
            left = deadline - time.monotonic()
            if left <= 0:
                break
            ser.timeout = left
            chunk = ser.read_until(self.terminator)
            buf += chunk
        if not buf.endswith(self.terminator):
            # A silent port may be a dead one (a pty or USB adapter gone without an error on write):
            # the next query reopens it.
            self._drop()
            what = "no reply" if not buf else f"reply {bytes(buf)!r} without its terminator"
            raise InstrumentCommError(self.name, f"{line!r}: {what} within {self.timeout_s:g} s")
        try:
            return buf[:-len(self.terminator)].decode("ascii").strip()
        except UnicodeDecodeError:
            raise InstrumentCommError(self.name, f"{line!r}: garbled reply {bytes(buf)!r}") from None

    def query(self, line: str) -> str:
        """Send ``line`` and return the reply line (raises InstrumentError on an ``ERR`` reply)."""
        if self._ser is None and self._connected:
            self._reopen_with_backoff()  # a port lost earlier (connect() was called before)
        try:
            reply = self._exchange(line)
        except (serial.SerialException, OSError, termios.error) as exc:
            self._reopen_with_backoff()
            try:
                reply = self._exchange(line)
            except (serial.SerialException, OSError, termios.error):
                raise InstrumentCommError(self.name, f"{line!r}: port {self.port} lost ({exc})") from exc
        if reply.startswith(self.commands.error_prefix):
            code = None
            try:
                code = int(reply[len(self.commands.error_prefix):].split(",")[0])
            except ValueError:
                pass
            raise InstrumentError(self.name, f"{line!r} refused: {reply}", code)
        return reply

    def command(self, line: str) -> None:
        """Send a setter; its reply must be the command set's OK."""
        reply = self.query(line)
        if reply != self.commands.ok_reply:
            raise InstrumentCommError(self.name,
                                      f"{line!r}: expected {self.commands.ok_reply!r}, got {reply!r}")

    def query_float(self, line: str) -> float:
        reply = self.query(line)
        try:
            return float(reply)
        except ValueError:
            raise InstrumentCommError(self.name, f"{line!r}: reply {reply!r} is not a number") from None

    def query_floats(self, line: str) -> list[float]:
        reply = self.query(line)
        try:
            return [float(x) for x in reply.split(",")]
        except ValueError:
            raise InstrumentCommError(
                self.name, f"{line!r}: reply {reply[:40]!r} is not a list of numbers") from None

    def identify(self) -> str:
        return self.query(self.commands.identify)
