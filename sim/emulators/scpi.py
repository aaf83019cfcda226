"""Emulated SCPI instruments, written from their manuals (IEEE 488.2 and SCPI-99 behaviour, and each
instrument's own command reference), not from gonio's profiles: a command a profile gets wrong is
answered as the instrument would answer it.

What every :class:`ScpiEmulator` does, as IEEE 488.2 / SCPI-99 say:

- headers are case-insensitive, in short or long form (``SENS:CORR:WAV`` = ``sense:correction:wavelength``),
  optional nodes may be left out (``[SENSe:]``, ``[:IMMediate]``), a leading ``:`` is allowed, and one
  line may hold several commands separated by ``;`` (their replies joined by ``;`` in one line);
- setters are silent; only queries answer;
- an error goes into a FIFO queue (10 entries; when full the last becomes ``-350,"Queue overflow"``),
  read one entry per ``SYSTem:ERRor[:NEXT]?`` as ``<code>,"<message>"`` and ``0,"No error"`` once empty:
  ``-113`` undefined header, ``-102`` syntax error (a line garbled on the wire), ``-108`` parameter not
  allowed, ``-109`` missing parameter, ``-104`` data type error, ``-222`` data out of range, ``-230``
  data stale (a FETCh? with no measurement); a query that errs gives no reply;
- ``*IDN?``, ``*RST`` (the reset state), ``*CLS`` (clears the queue), ``*OPC?`` (``1`` once pending
  operations are done), ``*OPC``, ``*WAI``, ``*TST?`` (``0``);
- power: :meth:`power_off`/:meth:`power_on` (the power-on state is the reset state, the queue empty).

Faults (:attr:`faults`, matched by the command's header as sent, upper case, e.g. ``"FETC?"`` or
``"OUTP"``): on a query they act on its reply (drop, corrupt, truncate, delay, disconnect, as for every
emulator); on a setter, which has no reply, ``drop`` loses the command on the wire (not executed, no
error), ``corrupt`` and ``truncate`` garble it (not executed, ``-102,"Syntax error"`` queued), ``delay``
holds it back before it executes, ``disconnect`` unplugs before it executes.

Instruments: :class:`Pm100Emulator` (Thorlabs PM100-family power meter) and
:class:`CurrentSourceEmulator` (a SCPI DC source driving a lamp in constant current).
"""

from __future__ import annotations

import math
import re
import time
from collections import deque
from collections.abc import Callable

from gonio.sim.emulators.instruments import LineInstrumentEmulator

__all__ = ["ScpiEmulator", "Pm100Emulator", "CurrentSourceEmulator", "ScpiError", "header_matches"]

#: SCPI-99 error queue: at least 2 entries; these instruments keep 10.
QUEUE_SIZE = 10
_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")


class ScpiError(Exception):
    """A command the instrument refuses: the entry it queues."""

    def __init__(self, code: int, message: str):
        super().__init__(f'{code},"{message}"')
        self.code = code
        self.message = message


def _pattern(spec: str) -> list[tuple[str, str, bool]]:
    """``[SENSe]:CORRection:WAVelength`` -> [(short, long, optional), ...] in upper case."""
    nodes = []
    for part in spec.replace("[:", ":[").split(":"):
        if not part:
            continue
        optional = part.startswith("[")
        name = part.strip("[]")
        short = "".join(ch for ch in name if ch.isupper() or ch in "*?")
        nodes.append((short.upper(), name.upper(), optional))
    return nodes


def header_matches(spec: str, header: str) -> bool:
    """Whether a command header (``sens:corr:wav``) is the one ``spec`` names (SCPI long/short forms,
    optional nodes, a numeric suffix 1 on any node)."""
    nodes = _pattern(spec)
    parts = [p.upper() for p in header.lstrip(":").split(":")]
    if any(not p for p in parts):
        return False

    def same(token: str, short: str, long: str) -> bool:
        if token.endswith("1") and not short.endswith("1"):
            token = token[:-1]  # CORR1 = CORR
        return token in (short, long)

    def match(i: int, j: int) -> bool:
        if i == len(nodes):
            return j == len(parts)
        short, long, optional = nodes[i]
        if j < len(parts) and same(parts[j], short, long) and match(i + 1, j + 1):
            return True
        return optional and match(i + 1, j)
    return match(0, 0)


def number(arg: str | None, *, units: tuple[str, ...] = (), minmax: tuple[float, float] | None = None,
           default: float | None = None) -> float:
    """A numeric parameter: decimal data with an optional unit suffix, or MIN/MAX/DEF."""
    if arg is None or not arg.strip():
        raise ScpiError(-109, "Missing parameter")
    text = arg.strip().upper()
    if minmax is not None and text in ("MIN", "MINIMUM"):
        return minmax[0]
    if minmax is not None and text in ("MAX", "MAXIMUM"):
        return minmax[1]
    if default is not None and text in ("DEF", "DEFAULT"):
        return default
    for unit in units:
        if text.endswith(unit.upper()):
            text = text[:-len(unit)].strip()
            break
    if not _NUMBER.fullmatch(text):
        raise ScpiError(-104, "Data type error")
    value = float(text)
    if not math.isfinite(value):  # 1E999: decimal numeric data, past any setting the instrument has
        raise ScpiError(-222, "Data out of range")
    return value


def boolean(arg: str | None) -> bool:
    if arg is None or not arg.strip():
        raise ScpiError(-109, "Missing parameter")
    value = {"ON": True, "1": True, "OFF": False, "0": False}.get(arg.strip().upper())
    if value is None:
        raise ScpiError(-224, "Illegal parameter value")
    return value


def nr3(value: float) -> str:
    """SCPI NR3 response data, as these instruments write it (``1.234567E-03``)."""
    return f"{value:.6E}"


class ScpiEmulator(LineInstrumentEmulator):
    """An IEEE 488.2 / SCPI instrument over a pty (or a :class:`~gonio.sim.emulators.tcp_link.TcpLink`).

    Subclasses list their commands in :meth:`commands_table`: ``(spec, handler)`` pairs, where
    ``handler(arg) -> str | None`` (a query's reply, None for a setter) may raise :class:`ScpiError`;
    a spec ending in ``?`` is a query. :meth:`reset` sets the reset state.
    """

    idn = "EMULATED,SCPI,000000,1.0"

    def __init__(self, name: str, clock=None, link=None):
        super().__init__(name, terminator=b"\n", clock=clock, link=link)
        self.errors: deque[tuple[int, str]] = deque()
        self._table = [(spec, handler) for spec, handler in self._common() + self.commands_table()]

    # -- the common commands (IEEE 488.2) ----------------------------------------------------------
    def _common(self):
        return [("*IDN?", lambda arg: self.idn), ("*RST", lambda arg: self._rst()),
                ("*CLS", lambda arg: self.errors.clear()), ("*OPC?", lambda arg: self._opc()),
                ("*OPC", lambda arg: None), ("*WAI", lambda arg: self._opc() and None),
                ("*TST?", lambda arg: "0"), ("SYSTem:ERRor[:NEXT]?", lambda arg: self._next_error())]

    def commands_table(self) -> list[tuple[str, Callable[[str | None], str | None]]]:
        return []

    def _rst(self) -> None:
        self.reset()

    def _opc(self) -> str:
        self.complete_pending()
        return "1"

    def complete_pending(self) -> None:
        """Finish pending (overlapped) operations: a measurement under way (subclasses)."""

    def reset(self) -> None:
        """The reset (and power-on) state; the error queue is emptied at power-on only."""

    def power_on(self) -> None:
        self.errors.clear()
        super().power_on()

    def push_error(self, code: int, message: str) -> None:
        if len(self.errors) >= QUEUE_SIZE:
            self.errors[-1] = (-350, "Queue overflow")
            return
        self.errors.append((code, message))

    def _next_error(self) -> str:
        code, message = self.errors.popleft() if self.errors else (0, "No error")
        return f'{code},"{message}"'

    # -- one line: commands separated by ';' ----------------------------------------------------------
    def _serve(self, text: str) -> bool:
        replies = []
        for unit in text.split(";"):
            unit = unit.strip()
            if not unit:
                continue
            header, _, arg = unit.partition(" ")
            fault = self.faults.take(header.upper())
            query = header.endswith("?")
            if fault is not None and not query:
                if fault.kind == "disconnect":
                    self.link.unplug()
                    self._buf = b""
                    return False
                if fault.kind == "drop":
                    continue  # lost on the wire
                if fault.kind in ("corrupt", "truncate"):
                    with self.lock:
                        self.commands.append(unit)
                        self.push_error(-102, "Syntax error")
                    continue
                if fault.kind == "delay":
                    time.sleep(fault.delay_s)  # the emulator's own thread: the instrument is slow
            with self.lock:
                self.commands.append(unit)
                reply = self._execute(header, arg.strip() or None)
            if reply is not None:
                if fault is not None:
                    return self._reply(unit, reply, fault) and True
                replies.append(reply)
        if replies:
            return self._reply(text, ";".join(replies), None)
        return True

    def _execute(self, header: str, arg: str | None) -> str | None:
        query = header.endswith("?")
        for spec, handler in self._table:
            if spec.endswith("?") != query:
                continue
            if header_matches(spec.rstrip("?") if query else spec, header.rstrip("?") if query else header):
                try:
                    return handler(arg)
                except ScpiError as err:
                    self.push_error(err.code, err.message)
                    return None
        self.push_error(-113, "Undefined header")
        return None

    @staticmethod
    def no_arg(arg: str | None) -> None:
        if arg is not None:
            raise ScpiError(-108, "Parameter not allowed")


class Pm100Emulator(ScpiEmulator):
    """A Thorlabs PM100D with a photodiode sensor, as its manual's SCPI chapter describes it.

    ``signal(exposure_s) -> W`` is the optical power the sensor sees during a measurement of
    ``exposure_s`` s (the gantry's rendering); ``dark_w`` is added (the sensor's dark level). One
    measurement averages ``SENS:AVER:COUN`` readings of ``sample_s`` (about 3 ms) each: ``INIT`` starts
    it (the emulator's clock advances by its duration), ``*OPC?`` answers ``1`` once it is done,
    ``FETC?`` returns it (``-230`` before any), ``READ?`` is INIT + FETC?, ``MEAS:POW?`` is CONF:POW +
    READ?. The responsivity correction is exact at every wavelength of the sensor's range
    (``wavelength_range_nm``; outside it ``-222``). Reset state: wavelength ``default_wavelength_nm``,
    averaging 1, power measurement, no measurement data.
    """

    idn = "Thorlabs,PM100D,P0012345,2.8.0"

    def __init__(self, signal: Callable[[float], float], *, dark_w: float = 0.0, sample_s: float = 0.003,
                 wavelength_range_nm: tuple[float, float] = (400.0, 1100.0),
                 default_wavelength_nm: float = 635.0, max_count: int = 100_000, clock=None, link=None):
        self.signal = signal
        self.dark_w = float(dark_w)
        self.sample_s = float(sample_s)
        self.wavelength_range_nm = wavelength_range_nm
        self.default_wavelength_nm = float(default_wavelength_nm)
        self.max_count = int(max_count)
        super().__init__("PM100", clock=clock, link=link)
        self.reset()
        #: Every measurement taken: (wavelength_nm, count, watts).
        self.measurements: list[tuple[float, int, float]] = []

    def reset(self) -> None:
        self.wavelength_nm = self.default_wavelength_nm
        self.count = 1
        self.configured = "POW"
        self.value: float | None = None

    def commands_table(self):
        return [
            ("[SENSe]:CORRection:WAVelength", self._set_wavelength),
            ("[SENSe]:CORRection:WAVelength?", lambda arg: nr3(self.wavelength_nm)),
            ("[SENSe]:AVERage[:COUNt]", self._set_count),
            ("[SENSe]:AVERage[:COUNt]?", lambda arg: str(self.count)),
            ("CONFigure[:SCALar]:POWer", self._configure),
            ("CONFigure?", lambda arg: self.configured),
            ("INITiate[:IMMediate]", self._init),
            ("ABORt", lambda arg: self.no_arg(arg)),
            ("FETCh?", self._fetch),
            ("READ?", lambda arg: self._init(arg) or self._fetch(None)),
            ("MEASure[:SCALar]:POWer?", lambda arg: self._configure(arg) or self._init(None)
             or self._fetch(None)),
        ]

    def _set_wavelength(self, arg):
        lo, hi = self.wavelength_range_nm
        value = number(arg, units=("NM",), minmax=(lo, hi))
        if not lo <= value <= hi:
            raise ScpiError(-222, "Data out of range")
        self.wavelength_nm = value

    def _set_count(self, arg):
        value = number(arg, minmax=(1, self.max_count))
        if value != int(value):
            raise ScpiError(-104, "Data type error")
        if not 1 <= value <= self.max_count:
            raise ScpiError(-222, "Data out of range")
        self.count = int(value)

    def _configure(self, arg):
        self.no_arg(arg)
        self.configured = "POW"
        self.value = None

    def _init(self, arg):
        self.no_arg(arg)
        exposure_s = self.count * self.sample_s
        watts = float(self.signal(exposure_s)) + self.dark_w  # the clock runs through the measurement
        self.value = watts
        self.measurements.append((self.wavelength_nm, self.count, watts))

    def _fetch(self, arg):
        self.no_arg(arg)
        if self.value is None:
            raise ScpiError(-230, "Data corrupt or stale")
        return nr3(self.value)


class CurrentSourceEmulator(ScpiEmulator):
    """A programmable DC source in constant current (a lamp's supply), SCPI-99 SOURce/OUTPut/MEASure.

    ``SOUR:CURR <A>`` (0 .. ``max_current_a``, MIN/MAX/DEF; outside ``-222``), ``SOUR:CURR?``,
    ``SOUR:VOLT <V>`` (the compliance, 0 .. ``max_voltage_v``), ``OUTP ON|OFF|1|0``, ``OUTP?`` (``1``|``0``),
    ``MEAS:CURR?`` (the current flowing: 0 with the output off). Reset and power-on state: output off,
    0 A, the compliance at its maximum. :attr:`on` is whether the lamp is lit (output on, current > 0).
    """

    idn = "EMULATED,DC-SOURCE-3A,000001,1.0"

    def __init__(self, *, max_current_a: float = 3.0, max_voltage_v: float = 30.0, clock=None, link=None):
        self.max_current_a = float(max_current_a)
        self.max_voltage_v = float(max_voltage_v)
        super().__init__("SRC", clock=clock, link=link)
        self.reset()

    def reset(self) -> None:
        self.output = False
        self.current_a = 0.0
        self.voltage_v = self.max_voltage_v

    @property
    def on(self) -> bool:
        return self.output and self.current_a > 0.0

    def commands_table(self):
        return [
            ("[SOURce]:CURRent[:LEVel][:IMMediate][:AMPLitude]", self._set_current),
            ("[SOURce]:CURRent[:LEVel][:IMMediate][:AMPLitude]?", lambda arg: nr3(self.current_a)),
            ("[SOURce]:VOLTage[:LEVel][:IMMediate][:AMPLitude]", self._set_voltage),
            ("[SOURce]:VOLTage[:LEVel][:IMMediate][:AMPLitude]?", lambda arg: nr3(self.voltage_v)),
            ("OUTPut[:STATe]", self._set_output),
            ("OUTPut[:STATe]?", lambda arg: "1" if self.output else "0"),
            ("MEASure[:SCALar]:CURRent[:DC]?", lambda arg: nr3(self.current_a if self.output else 0.0)),
        ]

    def _set_current(self, arg):
        value = number(arg, units=("A",), minmax=(0.0, self.max_current_a), default=0.0)
        if not 0.0 <= value <= self.max_current_a:
            raise ScpiError(-222, "Data out of range")
        self.current_a = value

    def _set_voltage(self, arg):
        value = number(arg, units=("V",), minmax=(0.0, self.max_voltage_v), default=self.max_voltage_v)
        if not 0.0 <= value <= self.max_voltage_v:
            raise ScpiError(-222, "Data out of range")
        self.voltage_v = value

    def _set_output(self, arg):
        self.output = boolean(arg)
