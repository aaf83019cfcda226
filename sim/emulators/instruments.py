"""Emulated line-based serial instruments over a pty: a light source, a photodiode/power meter (one value)
and a spectrometer (one value per wavelength bin), speaking an SCPI-like command set, one line per
command and per reply. The detector's value comes from a callable (later the Dr.Jit simulation).

Faults (:attr:`LineInstrumentEmulator.faults`, matched by the command's header, e.g. ``"MEAS?"``): drop,
corrupt, truncate (the reply loses its terminator), delay, disconnect; an unknown command or a bad
argument is answered ``ERR <code>,"<text>"``. :meth:`LineInstrumentEmulator.power_off` and
:meth:`~LineInstrumentEmulator.power_on` cycle the instrument's power: off, it hears nothing (and, with
``unplug``, its USB port is gone); on again, it is in its power-on state.

The SCPI instruments (silent setters, an error queue) are in :mod:`gonio.sim.emulators.scpi`.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence

from gonio.clock import WallClock
from gonio.sim.emulators.link import EmulatorThread, FaultPlan, PtyLink, mangle

__all__ = ["LineInstrumentEmulator", "LightSourceEmulator", "PowerMeterEmulator", "SpectrometerEmulator"]


class LineInstrumentEmulator(EmulatorThread):
    """Base: reads lines ending in ``terminator`` and answers via :meth:`handle` (None: no reply)."""

    idn = "gonio,emulator,0,1.0"

    def __init__(self, name: str, terminator: bytes = b"\n", clock=None, link=None):
        super().__init__(name)
        self.link = link or PtyLink(f"tty{name}")
        self.terminator = terminator
        self.clock = clock or WallClock()
        self.faults = FaultPlan()
        self.commands: list[str] = []
        self.answered = 0
        self.lock = threading.Lock()
        self._done = threading.Condition()
        self._buf = b""
        #: False between :meth:`power_off` and :meth:`power_on`: every byte received is lost.
        self.powered = True

    @property
    def port(self) -> str:
        return self.link.port

    def replug(self) -> None:
        self.link.replug()

    def power_off(self, unplug: bool = True) -> None:
        """Switch the instrument off: it hears nothing until :meth:`power_on`; with ``unplug`` its port
        goes too (a USB instrument's adapter is powered by it), else the port stays open and silent (an
        RS-232 cable to an adapter of its own)."""
        with self.lock:
            self.powered = False
            self._buf = b""
            if unplug:
                self.link.unplug()

    def power_on(self) -> None:
        """Switch it on again: its power-on state (:meth:`reset`), the port back if it was gone."""
        with self.lock:
            self.reset()
            self._buf = b""
            self.powered = True
            if not self.link.plugged:
                self.link.replug()

    def reset(self) -> None:
        """The instrument's power-on state (subclasses)."""

    def stop(self, timeout_s: float = 5.0) -> None:
        super().stop(timeout_s)
        self.link.close()

    def step(self) -> None:
        if not self.link.plugged:
            self._stop.wait(self.poll_s)
            return
        data = self.link.read(self.poll_s)
        if not self.powered:
            return
        self._buf += data
        while self.terminator in self._buf:
            line, self._buf = self._buf.split(self.terminator, 1)
            text = line.decode("ascii", "replace").strip()
            if not text:
                continue
            if not self._serve(text):
                return

    def _reply(self, text: str, reply: str, fault) -> bool:
        """Write ``reply`` with ``fault`` applied; False when the fault unplugged the link."""
        if fault is not None and fault.kind == "disconnect":
            self.link.unplug()
            self._buf = b""
            return False
        data = reply.encode("ascii") + self.terminator
        if fault is not None and fault.kind == "truncate":
            data = data[:-len(self.terminator)]  # the reply without its terminator
        elif fault is not None and fault.kind == "corrupt":
            data = b"\x8f#" + data[2:]  # line noise: not a number any more
        elif fault is not None:
            data = mangle(data, fault)  # drop (None) or delay
        if data is not None:
            self.link.write(data)
        with self._done:
            self.answered += 1
            self._done.notify_all()
        return True

    def _serve(self, text: str) -> bool:
        """Handle one command line; False when the link went (stop reading)."""
        with self.lock:
            self.commands.append(text)
            reply = self.handle(text)
        if reply is None:
            return True
        return self._reply(text, reply, self.faults.take(text.split()[0].upper()))

    def wait_answered(self, count: int, timeout_s: float = 2.0) -> bool:
        """Wait until ``count`` commands in all have been answered (delays served, replies written)."""
        with self._done:
            return self._done.wait_for(lambda: self.answered >= count, timeout_s)

    def handle(self, line: str) -> str | None:
        head = line.split()[0].upper()
        if head == "*IDN?":
            return self.idn
        return 'ERR -113,"undefined header"'


class LightSourceEmulator(LineInstrumentEmulator):
    """``OUTP ON|OFF``, ``OUTP?``, ``SOUR:POW:LEV <percent>``, ``SOUR:POW:LEV?``, ``STAT:READY?`` (ready
    ``warmup_s`` after switching on). Setters answer ``OK``."""

    idn = "gonio,lamp-emulator,0,1.0"

    def __init__(self, warmup_s: float = 0.0, clock=None, link=None):
        super().__init__("LAMP", clock=clock, link=link)
        self.warmup_s = warmup_s
        self.reset()

    def reset(self) -> None:
        self.on = False
        self.level = 100.0
        self._on_since = 0.0

    def handle(self, line):
        parts = line.split()
        head = parts[0].upper()
        if head == "OUTP" and len(parts) == 2 and parts[1].upper() in ("ON", "OFF"):
            on = parts[1].upper() == "ON"
            if on and not self.on:
                self._on_since = self.clock.now()
            self.on = on
            return "OK"
        if head == "OUTP?":
            return "1" if self.on else "0"
        if head == "SOUR:POW:LEV" and len(parts) == 2:
            try:
                level = float(parts[1])
            except ValueError:
                return 'ERR -104,"data type error"'
            if not 0.0 <= level <= 100.0:
                return 'ERR -222,"data out of range"'
            self.level = level
            return "OK"
        if head == "SOUR:POW:LEV?":
            return f"{self.level:g}"
        if head == "STAT:READY?":
            return "1" if self.on and self.clock.now() - self._on_since >= self.warmup_s else "0"
        return super().handle(line)


class PowerMeterEmulator(LineInstrumentEmulator):
    """``CONF:EXP <s>``, ``MEAS?`` -> one value from ``signal(exposure_s)``."""

    idn = "gonio,powermeter-emulator,0,1.0"

    def __init__(self, signal: Callable[[float], float], clock=None, link=None):
        super().__init__("PM", clock=clock, link=link)
        self.signal = signal
        self.reset()

    def reset(self) -> None:
        self.exposure_s = 0.1

    def handle(self, line):
        parts = line.split()
        head = parts[0].upper()
        if head == "CONF:EXP" and len(parts) == 2:
            try:
                value = float(parts[1])
            except ValueError:
                return 'ERR -104,"data type error"'
            if not 1e-6 <= value <= 60.0:
                return 'ERR -222,"data out of range"'
            self.exposure_s = value
            return "OK"
        if head == "MEAS?":
            return f"{float(self.signal(self.exposure_s)):.9e}"
        return super().handle(line)


class SpectrometerEmulator(PowerMeterEmulator):
    """Adds ``SENS:WAV?`` (the bin centres, nm) and ``MEAS:SPEC?`` (one value per bin from
    ``signal(exposure_s)``, a sequence as long as the wavelengths)."""

    idn = "gonio,spectrometer-emulator,0,1.0"

    def __init__(self, wavelengths_nm: Sequence[float], signal: Callable[[float], Sequence[float]],
                 clock=None, link=None):
        super().__init__(signal, clock=clock, link=link)
        self.wavelengths_nm = [float(w) for w in wavelengths_nm]

    def handle(self, line):
        head = line.split()[0].upper()
        if head == "SENS:WAV?":
            return ",".join(f"{w:g}" for w in self.wavelengths_nm)
        if head == "MEAS:SPEC?":
            return ",".join(f"{float(v):.6e}" for v in self.signal(self.exposure_s))
        return super().handle(line)
