"""The byte pipe under a line instrument: pyserial for ports and pyserial URLs, PyVISA for VISA resources.

A port is written as a lab writes it. A VISA resource string (``ASRL/dev/ttyUSB0::INSTR``,
``TCPIP0::192.168.1.20::5025::SOCKET``, ``USB0::0x1313::0x8078::P0012345::INSTR``, ``GPIB0::7::INSTR``)
opens through PyVISA (its pure-Python ``@py`` backend, pyvisa-py, unless ``PYVISA_LIBRARY`` names
another, e.g. ``@ivi`` for NI-VISA); anything else (``/dev/ttyUSB0``, ``/dev/serial/by-id/...``,
``socket://host:5025``, ``loop://``) through pyserial. PyVISA is imported only for a VISA resource.

Both give the driver the same four operations with the same meaning: :meth:`Transport.write`,
:meth:`Transport.flush_input` (discard whatever arrived unasked: a late reply), :meth:`Transport.read_until`
(bytes up to and including the terminator, or what arrived by the deadline, which the driver treats as a
fault) and :meth:`Transport.close`. A port that is gone raises :class:`PortLost`.

Two behaviours of pyvisa-py that this layer works around (measured with pyvisa 1.16 / pyvisa-py 0.8):
on a ``SOCKET`` resource a read returns the bytes it has as a complete message when none follow within
a millisecond or so (a reply cut short would pass for a whole one) unless the suppress-end attribute is
set, and its ``clear()``/read-buffer flush waits 0.1 s for silence each time; the flush here instead
drains with immediate reads.

One of pyserial's (3.5): closing a ``socket://`` port sleeps 0.3 s afterwards ("in case of quick reconnects,
give the server some time"), which an instrument's server does not need; the driver closes a port at
every reconnect after a time-out. The port here is pyserial's own ``socket://`` handler without that
sleep.
"""

from __future__ import annotations

import os
import re
import socket
import termios
import time
from typing import Protocol

import serial
from serial.urlhandler import protocol_socket

__all__ = ["Transport", "PortLost", "SerialTransport", "VisaTransport", "open_transport", "is_visa_resource",
           "check_visa_resource"]

#: The interface types a VISA resource string starts with (VISA specification 4.3).
_VISA = re.compile(r"^(ASRL|TCPIP|USB|GPIB|VXI|PXI)[^:]*::", re.IGNORECASE)


class PortLost(OSError):
    """The port is gone (a cable pulled, a device powered off, a socket closed)."""


class Transport(Protocol):
    def write(self, data: bytes) -> None: ...
    def flush_input(self) -> None: ...
    def read_until(self, terminator: bytes, deadline: float) -> bytes:
        """Bytes up to and including ``terminator``, or what arrived before ``deadline`` (monotonic s)."""
    def close(self) -> None: ...


def is_visa_resource(port: str) -> bool:
    """Whether ``port`` is a VISA resource string (opened through PyVISA) rather than a pyserial port."""
    return bool(_VISA.match(port))


def check_visa_resource(port: str) -> None:
    """ValueError naming what is wrong with a VISA resource string (PyVISA's own parser)."""
    from pyvisa import rname

    try:
        rname.parse_resource_name(port)
    except rname.InvalidResourceName as err:
        raise ValueError(f"{port!r} is not a VISA resource string ({str(err).splitlines()[0]})") from None


class _SocketPort(protocol_socket.Serial):
    """pyserial's ``socket://`` port, closed at once (its own close sleeps 0.3 s after closing)."""

    def close(self) -> None:
        if self.is_open and self._socket is not None:
            try:
                self._socket.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass  # the peer has gone already
            self._socket.close()
            self._socket = None
        self.is_open = False


class SerialTransport:
    """A pyserial port or URL."""

    def __init__(self, port: str, baudrate: int):
        try:
            if port.lower().startswith("socket://"):
                self._ser = _SocketPort(port, baudrate=baudrate, timeout=0.01)
            else:
                self._ser = serial.serial_for_url(port, baudrate=baudrate, timeout=0.01)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise PortLost(f"cannot open {port} ({type(exc).__name__})") from exc

    def write(self, data: bytes) -> None:
        try:
            self._ser.write(data)
        except (serial.SerialException, OSError, termios.error) as exc:
            raise PortLost(str(exc)) from exc

    def flush_input(self) -> None:
        try:
            self._ser.reset_input_buffer()
        except (serial.SerialException, OSError, termios.error) as exc:
            raise PortLost(str(exc)) from exc

    def read_until(self, terminator: bytes, deadline: float) -> bytes:
        buf = bytearray()
        try:
            while not buf.endswith(terminator):
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._ser.timeout = left
                buf += self._ser.read_until(terminator)
        except (serial.SerialException, OSError, termios.error) as exc:
            raise PortLost(str(exc)) from exc
        return bytes(buf)

    def close(self) -> None:
        try:
            self._ser.close()
        except (serial.SerialException, OSError, termios.error):
            pass


_RM = None


def _resource_manager():
    global _RM
    if _RM is None:
        import pyvisa

        _RM = pyvisa.ResourceManager(os.environ.get("PYVISA_LIBRARY", "@py"))
    return _RM


class VisaTransport:
    """A VISA resource through PyVISA: ASRL (serial), TCPIP SOCKET (raw SCPI, port 5025), USB, GPIB."""

    def __init__(self, resource: str, baudrate: int, terminator: bytes):
        import pyvisa
        from pyvisa import constants

        self._errors = pyvisa.errors.VisaIOError
        self._timeout = constants.StatusCode.error_timeout
        self._constants = constants
        check_visa_resource(resource)
        try:
            inst = _resource_manager().open_resource(resource, open_timeout=1000)
        except (self._errors, serial.SerialException, OSError, ValueError) as exc:
            raise PortLost(f"cannot open {resource} ({exc})") from exc
        self._inst = inst
        self._socket = inst.resource_info.resource_class == "SOCKET"
        inst.write_termination = ""
        inst.read_termination = terminator.decode("ascii")[-1]  # pyvisa ends a read on one character
        if inst.resource_info.interface_type == constants.InterfaceType.asrl:
            inst.baud_rate = baudrate
        if self._socket:
            # Without it a SOCKET read hands back a partial reply as a whole message.
            inst.set_visa_attribute(constants.ResourceAttribute.suppress_end_enabled, True)

    def _lost(self, exc) -> PortLost:
        return PortLost(str(exc))

    def write(self, data: bytes) -> None:
        try:
            self._inst.write_raw(data)
        except (self._errors, serial.SerialException, OSError, termios.error) as exc:
            raise self._lost(exc) from exc

    def flush_input(self) -> None:
        c = self._constants
        try:
            if not self._socket:
                self._inst.flush(c.BufferOperation.discard_read_buffer)
                return
            self._inst.flush(c.BufferOperation.discard_read_buffer_no_io)
            self._inst.timeout = 0
            for _ in range(1000):  # bounded: each read takes one pending line
                self._inst.read_raw()
        except self._errors as exc:
            if exc.error_code != self._timeout:
                raise self._lost(exc) from exc
        except (serial.SerialException, OSError, termios.error) as exc:
            raise self._lost(exc) from exc

    def read_until(self, terminator: bytes, deadline: float) -> bytes:
        buf = b""
        try:
            while not buf.endswith(terminator):
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._inst.timeout = max(1, round(left * 1000))
                buf += self._inst.read_raw()
        except self._errors as exc:
            if exc.error_code != self._timeout:
                raise self._lost(exc) from exc
        except (serial.SerialException, OSError, termios.error) as exc:
            raise self._lost(exc) from exc
        return buf

    def close(self) -> None:
        try:
            self._inst.close()
        except (self._errors, serial.SerialException, OSError):
            pass


def open_transport(port: str, baudrate: int, terminator: bytes) -> Transport:
    """The transport for ``port``: PyVISA for a VISA resource string, else pyserial (PortLost if it
    cannot be opened)."""
    if is_visa_resource(port):
        return VisaTransport(port, baudrate, terminator)
    return SerialTransport(port, baudrate)
