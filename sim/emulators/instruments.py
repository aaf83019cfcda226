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
import time
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
        try:
            super().stop(timeout_s)
        finally:  # a thread that did not stop in time loses its port all the same
            self.link.close()

    def step(self) -> None:
        if not self.link.plugged:
            self._stop.wait(self.poll_s)
            return
        data = self.link.read(self.poll_s, self.wake_fd)
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


#: Wall time a drain leaves the driver's stream reader to stamp the lines it just read (s).
STAMP_GRACE_S = 0.0003
#: A drain stops waiting for the driver to read the lines when it took none for this long (s, wall).
UNREAD_S = 0.02


class StreamingPhotodiodeEmulator(PowerMeterEmulator):
    """A photodiode with a stream mode (profile ``streaming-photodiode``): as :class:`PowerMeterEmulator`
    (``CONF:EXP``, ``MEAS?``), and

    - ``STRM:RATE <hz>`` (1 .. 2000 Hz, and no faster than its lines fit the baud rate: ``ERR -222``
      otherwise), ``STRM:RATE?``; ``STRM?`` (1 while streaming);
    - ``STRM ON`` answers ``OK``, then sends ``<index>,<value>`` per sample, unasked: sample ``k`` (from 0)
      integrates ``[t0 + k P, t0 + (k+1) P)`` (``P`` = 1 / rate, on the instrument's own clock, which
      runs ``clock_error`` fast: 0 = exactly the gantry's), its value from ``window(t_start, t_end)``
      (default ``signal(P)``), and its line goes out ``delay_s`` after the end of its integration, the
      last byte arriving after the line's transfer time at ``baudrate`` (8N1: 10 bits a byte);
    - ``STRM OFF`` sends the samples already due, then ``OK``; ``MEAS?`` and ``CONF:EXP`` while streaming
      are refused (``ERR -221,"settings conflict"``), ``STRM:RATE`` too;
    - overflow: a line that does not fit its transmit buffer (``buffer_bytes``, of which what the host
      has not read yet takes its part) is not sent (the counter goes on: the host sees the gap);
    - stream faults (:attr:`faults` with ``match="SAMPLE"``, or ``("SAMPLE", k)`` for line k): ``drop``
      (the line is lost), ``corrupt``
      (line noise in its place: a garbage line), ``truncate`` (no terminator: it runs into the next
      line, both lost), ``late`` (held back and sent with the next line: a late burst; several in a
      row hold several).

    On a :class:`~gonio.sim.emulators.link.SyncedVirtualClock` the clock stops at each line's time
    (:meth:`next_due`) and :meth:`drain` sends it and waits until the driver has read it, so a line
    arrives at its own instant of virtual time."""

    idn = "gonio,streaming-photodiode-emulator,0,1.0"
    #: Longest line (bytes with its terminator) the rate is checked against.
    LINE_BYTES = 24

    def __init__(self, signal: Callable[[float], float], clock=None, link=None, *,
                 window: Callable[[float, float], float] | None = None, baudrate: int = 115200,
                 delay_s: float = 0.0002, clock_error: float = 0.0, buffer_bytes: int = 4096):
        self.baudrate = int(baudrate)
        self.delay_s = float(delay_s)
        self.clock_error = float(clock_error)
        self.buffer_bytes = int(buffer_bytes)
        self.window = window
        super().__init__(signal, clock=clock, link=link)
        #: Lines sent and lines lost to a full buffer, since power-on.
        self.sent = 0
        self.overflowed = 0

    def reset(self) -> None:
        super().reset()
        self.rate_hz = 100.0
        self.streaming = False
        self._k = 0
        self._t0 = 0.0
        self._held: list[bytes] = []

    # -- the stream ------------------------------------------------------------------------------------
    def _period(self) -> float:
        return 1.0 / (self.rate_hz * (1.0 + self.clock_error))

    def _line(self, k: int) -> bytes:
        p = self._period()
        t0 = self._t0 + k * p
        value = self.window(t0, t0 + p) if self.window is not None else self.signal(p)
        return f"{k},{float(value):.9e}".encode("ascii") + self.terminator

    def _due(self, k: int) -> float:
        """When the last byte of sample ``k``'s line arrives (``<k>,`` and a value of 15 characters, its
        sign aside)."""
        nbytes = len(str(k)) + 16 + len(self.terminator)
        return self._t0 + (k + 1) * self._period() + self.delay_s + nbytes * 10.0 / self.baudrate

    def next_due(self) -> float | None:
        """The virtual instant the next line arrives (None: not streaming). Without the lock: the clock
        asks while this emulator's own thread may hold it (its MEAS? sleeps the shared clock)."""
        if not self.streaming or not self.powered:
            return None
        return self._due(self._k)

    def _emit_due(self) -> None:
        """Send every line due by now (the caller holds the lock)."""
        now = self.clock.now() + 1e-9   # a virtual clock stopped at a due instant lands within rounding
        while self.streaming and self._due(self._k) <= now:
            k, self._k = self._k, self._k + 1
            data = self._line(k)
            fault = self.faults.take("SAMPLE", ("SAMPLE", k))
            if fault is not None and fault.kind == "late":
                self._held.append(data)
                continue
            if fault is not None and fault.kind == "corrupt":
                data = b"\x8f#" + data[2:]
            elif fault is not None and fault.kind == "truncate":
                data = data[:-len(self.terminator)]
            elif fault is not None and fault.kind == "drop":
                data = b""
            out, self._held = b"".join(self._held) + data, []
            if self.link.pending() + len(out) > self.buffer_bytes:
                self.overflowed += 1
                continue
            if out:
                self.link.write(out)
                self.sent += 1

    def drain(self, timeout_s: float = 2.0) -> bool:
        """Handle what the driver sent, send the lines due by now, and wait (at most ``timeout_s``) until
        the driver has read them; False if bytes were still waiting. Called from its own thread (whose
        MEAS? sleeps the shared clock through the exposure) it does nothing: that thread is serving."""
        if threading.current_thread() is self._thread:
            return True
        deadline = time.monotonic() + timeout_s
        while self.link.readable(0.0) and time.monotonic() < deadline:
            time.sleep(0.0005)  # the serving thread reads them
        with self.lock:
            sent = self.sent
            if self.powered and self.link.plugged:
                self._emit_due()
            sent = self.sent > sent
        left, still = self.link.pending(), time.monotonic()
        while left > 0:
            time.sleep(0.0002)  # the driver's reader takes them: bounded by the deadline
            now, left, was = time.monotonic(), self.link.pending(), left
            if left < was:
                still = now
            elif now - still > UNREAD_S or now >= deadline:
                return False    # nobody is reading (the lines stay in the buffer, which may overflow)
        if sent:
            # The reader has the bytes; its stamp (the clock's now) follows in its own thread: this one
            # gives it the interpreter before time moves. A reader held up longer stamps late, which the
            # driver's clock model (the lower envelope of the arrivals) absorbs, as a busy host's.
            time.sleep(STAMP_GRACE_S)
        return True

    def step(self) -> None:
        super().step()
        with self.lock:
            if self.powered and self.link.plugged:
                self._emit_due()

    @property
    def poll_s(self) -> float:
        return 0.001 if self.streaming else 0.02

    def handle(self, line):
        parts = line.split()
        head = parts[0].upper()
        if head == "STRM" and len(parts) == 2 and parts[1].upper() in ("ON", "OFF"):
            if parts[1].upper() == "OFF":
                self._emit_due()
                held, self._held = b"".join(self._held), []
                self.link.write(held)
                self.streaming = False
                return "OK"
            if not self.streaming:
                self.streaming, self._k, self._t0, self._held = True, 0, self.clock.now(), []
            return "OK"
        if head == "STRM?":
            return "1" if self.streaming else "0"
        if head == "STRM:RATE?":
            return f"{self.rate_hz:g}"
        if self.streaming and head in ("STRM:RATE", "MEAS?", "CONF:EXP"):
            return 'ERR -221,"settings conflict"'
        if head == "STRM:RATE" and len(parts) == 2:
            try:
                rate = float(parts[1])
            except ValueError:
                return 'ERR -104,"data type error"'
            if not 1.0 <= rate <= 2000.0 or rate * self.LINE_BYTES * 10.0 > self.baudrate:
                return 'ERR -222,"data out of range"'
            self.rate_hz = rate
            return "OK"
        return super().handle(line)
