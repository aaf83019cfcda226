"""Line instruments as gonio devices, each speaking its profile: a lamp (on/off, level, warm-up), a
photodiode/power meter (one value per frame) and a spectrometer (one value per wavelength bin)."""

from __future__ import annotations

import time

import numpy as np

from gonio.drivers.serial.line import InstrumentCommError, InstrumentError, LineInstrument, refusal_code
from gonio.drivers.serial.profile import command_fields
from gonio.drivers.serial.stream import StreamReader
from gonio.drivers.serial.transport import PortLost
from gonio.protocols import Reading, StreamSamples

__all__ = ["SerialLightSource", "SerialPowerMeter", "SerialSpectrometer", "StreamingPowerMeter"]

#: What a lamp's level command takes: its range and unit.
_LEVEL_RANGE = {"percent": (0.0, 100.0, "%"), "current_a": (0.0, 100.0, " A")}


class SerialLightSource(LineInstrument):
    """A lamp as a :class:`gonio.protocols.LightSource`.

    ``level`` (in the unit the profile's level command takes: % of full output, or A) is set at connect
    and again each time the output is switched on (a source that was power-cycled comes back at its
    default). Every switch is read back (``state``): a setter that was lost on the way, or an output
    that did not follow, is a transient fault, never a dark reading taken as a lit one. Switched on, the
    lamp waits for its warm-up flag (``warmup_timeout_s``, profiles with a ``ready`` query) and then
    ``settle_s`` (clock time) for its output to settle; switched off, ``settle_s`` for it to go dark.
    """

    def __init__(self, name: str, port: str, profile=None, *, level: float | None = None,
                 warmup_timeout_s: float = 0.0, settle_s: float = 0.0, **kwargs):
        super().__init__(name, port, profile, **kwargs)
        self.commands = self.profile.section("light")
        if level is not None:
            self._check_level(level)
        if warmup_timeout_s > 0 and self.commands.ready is None:
            raise ValueError(f"light '{name}': profile {self.profile.source} has no ready query to wait for "
                             "a warm-up")
        if not 0 <= settle_s <= 600:
            raise ValueError(f"light '{name}': settle_s {settle_s} is outside [0, 600] s")
        self.level_setting = level
        self.warmup_timeout_s = float(warmup_timeout_s)
        self.settle_s = float(settle_s)

    def _check_level(self, value: float) -> str:
        unit = self.commands.level_field
        if unit is None:
            raise ValueError(f"light '{self.name}': profile {self.profile.source} has no level command")
        lo, hi, u = _LEVEL_RANGE[unit]
        if not lo <= value <= hi:
            raise ValueError(f"light '{self.name}': level {value:g}{u} is outside [{lo:g}{u}, {hi:g}{u}]")
        return unit

    def connect(self) -> None:
        super().connect()
        if self.level_setting is not None:
            self.set_level(self.level_setting)

    def set_on(self, on: bool) -> None:
        c = self.commands
        if on and self.level_setting is not None:
            self.set_level(self.level_setting)
        cmd = c.on if on else c.off
        self.setters([cmd])
        state = self.is_on()
        if state != on:
            raise InstrumentCommError(self.name, f"{cmd!r}: the output reads {'on' if state else 'off'} "
                                      f"after it ({c.state!r})")
        if on and self.warmup_timeout_s > 0:
            self.wait_ready(self.warmup_timeout_s, poll_s=min(0.5, self.warmup_timeout_s))
        if self.settle_s > 0:
            self.clock.sleep(self.settle_s)

    def is_on(self) -> bool:
        return self.query_bool(self.commands.state)

    def set_level(self, value: float) -> None:
        """The output level in the profile's unit (% of full output, or A); read back where the profile
        has a level query (within 0.5 % or 0.001 of the unit: an instrument rounds to its resolution)."""
        unit = self._check_level(value)
        self.setters([self.commands.level.format(**{unit: value})])
        if self.commands.level_query is not None:
            got = self.level()
            if abs(got - value) > max(0.005 * abs(value), 1e-3):
                u = _LEVEL_RANGE[unit][2]
                raise InstrumentCommError(self.name, f"level set to {value:g}{u} reads back {got:g}{u} "
                                          f"({self.commands.level_query!r})")

    def level(self) -> float:
        if self.commands.level_query is None:
            raise ValueError(f"light '{self.name}': profile {self.profile.source} has no level query")
        return self.query_number(self.commands.level_query)

    def is_ready(self) -> bool:
        if self.commands.ready is None:
            return True
        return self.query_bool(self.commands.ready)

    def wait_ready(self, timeout_s: float, poll_s: float = 0.5) -> None:
        """Poll the ready flag until it rises; InstrumentCommError after ``timeout_s`` (clock time)."""
        deadline = self.clock.now() + timeout_s
        while not self.is_ready():
            if self.clock.now() >= deadline:
                raise InstrumentCommError(self.name, f"not ready (warm-up) within {timeout_s:g} s")
            self.clock.sleep(poll_s)


class SerialPowerMeter(LineInstrument):
    """A photodiode / power meter as a :class:`gonio.protocols.Detector` with one channel.

    Each reading sends the profile's ``configure`` setters (exposure, averaging ``count`` = exposure_s /
    sample_s, ``wavelength_nm`` where it is given: a meter power-cycled since the last reading is set up
    again), then per
    frame its ``measure`` commands; the last is the query whose reply is the value. Replies that wait for
    the measurement (``*OPC?`` after ``INIT``, a ``MEAS?``) get the exposure on top of the time-out.
    """

    kind = "power_meter"
    channels = ("power_w",)

    def __init__(self, name: str, port: str, profile=None, *, wavelength_nm: float | None = None, **kwargs):
        super().__init__(name, port, profile, **kwargs)
        self.commands = self.profile.section(self.kind)
        #: None: the configure setters that take it are left out (the meter keeps its own setting).
        self.wavelength_nm = wavelength_nm

    def _check(self, exposure_s: float, frames: int) -> None:
        if not 0 < exposure_s <= 60:
            raise ValueError(f"detector '{self.name}': exposure_s {exposure_s} is outside (0, 60] s")
        if not isinstance(frames, int) or frames < 1:
            raise ValueError(f"detector '{self.name}': frames {frames!r} must be an integer >= 1")

    def _configure(self, exposure_s: float) -> tuple[list[str], float]:
        """The configure setters for ``exposure_s``, and the time one measurement takes."""
        c = self.commands
        count = max(1, round(exposure_s / c.sample_s)) if c.sample_s else 1
        values = {"exposure_s": exposure_s, "count": count, "wavelength_nm": self.wavelength_nm}
        takes = count * c.sample_s if c.sample_s else exposure_s
        given = [cmd for cmd in c.configure if all(values[f] is not None for f in command_fields(cmd))]
        return [cmd.format(**values) for cmd in given], takes

    def _read(self, line: str, wait_s: float) -> np.ndarray:
        return np.array([self.query_number(line, wait_s=wait_s)])

    def read_on_the_fly(self, exposure_s: float, *, key=None) -> Reading:
        """One reading of ``exposure_s`` s while the axes may move (:class:`gonio.protocols.ReadsOnTheFly`):
        the meter integrates from its request."""
        return self.measure(exposure_s, 1, key=key)

    def measure(self, exposure_s: float, frames: int = 1, *, key=None) -> Reading:
        """Mean and standard error over ``frames`` readings of ``exposure_s`` s each."""
        self._check(exposure_s, frames)
        configure, takes = self._configure(exposure_s)
        *start, read = self.commands.measure
        data = []
        for i in range(frames):
            group = (configure if i == 0 else []) + start
            if group:
                self.setters(group, wait_s=takes)
            data.append(self._read(read, takes))
        data = np.stack(data)
        stderr = data.std(axis=0, ddof=1) / np.sqrt(frames) if frames > 1 else np.zeros(data.shape[1])
        extra = {} if key is None else {"key": tuple(key)}
        return Reading(signal=data.mean(axis=0), stderr=stderr, exposure_s=float(exposure_s), frames=frames,
                       extra=extra)


class StreamingPowerMeter(SerialPowerMeter):
    """A power meter with a continuous mode (its profile's ``[power_meter.stream]``), as a
    :class:`gonio.protocols.Streams`: :meth:`start_stream` sets the rate (``rate_hz``, default the
    profile's), sends ``start`` and hands the port's reads to a :class:`~gonio.drivers.serial.stream.
    StreamReader`, which stamps every line on the gantry clock; :meth:`stop_stream` sends ``stop`` and
    waits for its acknowledgement behind the last samples. Readings on request (:meth:`measure`) are
    refused while the stream runs."""

    def __init__(self, name: str, port: str, profile=None, *, rate_hz: float | None = None, **kwargs):
        super().__init__(name, port, profile, **kwargs)
        stream = self.commands.stream
        if stream is None:
            raise ValueError(f"detector '{name}': profile {self.profile.source} has no [power_meter.stream]")
        if rate_hz is not None and not 0 < rate_hz <= 100_000:
            raise ValueError(f"detector '{name}': rate_hz {rate_hz} is outside (0, 100000] Hz")
        self.stream_commands = stream
        self.rate_hz = float(rate_hz if rate_hz is not None else stream.rate_hz)
        self._reader: StreamReader | None = None
        self._warnings: list[str] = []
        self._reported: float | None = None   # the off-rate period last reported
        self._may_stream = False   # the instrument may still stream (a stream that did not stop cleanly)
        self._started = 0.0        # when the last stream was started (gantry clock)

    def connect(self) -> None:
        """Stop a stream a previous process left running (killed mid-sweep, the instrument streams on and
        would answer the identity query among its samples), then connect as any line instrument."""
        self._open()
        try:
            self._quiet()
        except PortLost as exc:
            raise InstrumentCommError(self.name, f"cannot open {self.port} ({exc})") from exc
        super().connect()
        self._may_stream = False

    def _quiet(self) -> str:
        """Send ``stop`` and discard what comes before its acknowledgement (samples on their way); where
        none comes (an instrument that is not there), the exchange that follows says so."""
        t, ok = self._t, self.profile.ok_reply.encode("ascii")
        t.flush_input()
        t.write(self.stream_commands.stop.encode("ascii") + self.terminator)
        deadline = time.monotonic() + self.timeout_s + 2.0 / self.rate_hz
        for _ in range(100_000):   # bounded: the samples already on their way, then the OK
            buf = t.read_until(self.terminator, deadline)
            if not buf.endswith(self.terminator) or buf[:-len(self.terminator)].strip() == ok:
                break
            self.late_replies += 1
        return ""

    def start_stream(self) -> float:
        if self._reader is not None:
            self.stop_stream()
        s = self.stream_commands
        if self._may_stream:   # a stream that did not stop cleanly (a lost port) may still be running
            self._io(s.stop, self._quiet)
            self._may_stream = False
        self.setters([s.rate.format(rate_hz=self.rate_hz)])
        p = self.profile

        def go() -> str:
            self._t.flush_input()
            reader = StreamReader(self.name, self._t, self.terminator, s, self.rate_hz, self.baudrate,
                                  self.clock, p.ok_reply, p.error_prefix)
            reader.start()
            self._t.write(s.start.encode("ascii") + self.terminator)
            self._reader = reader
            return ""

        self._io(s.start, go)
        reader = self._reader
        self._started = self.clock.now()
        acked = reader.wait_ack(self.timeout_s)
        if not acked or reader.refusals or reader.error is not None:
            self._abandon()
            what = (reader.refusals[0] if reader.refusals else f"port lost ({reader.error})"
                    if reader.error is not None else f"no {p.ok_reply!r} within {self.timeout_s:g} s")
            if reader.refusals:
                raise InstrumentError(self.name, f"{s.start!r} refused: {what}",
                                      refusal_code(what, p.error_prefix))
            raise InstrumentCommError(self.name, f"{s.start!r}: {what}")
        return 1.0 / self.rate_hz

    def read_stream(self) -> StreamSamples:
        reader = self._reader
        if reader is None:
            raise ValueError(f"detector '{self.name}': no stream running (start_stream() first)")
        if reader.error is not None:
            raise InstrumentCommError(self.name, f"stream: port {self.port} lost ({reader.error})")
        return reader.samples()

    def warnings(self) -> list[str]:
        """What the timing checks of the streams stopped since the last call found
        (:class:`gonio.protocols.Warns`)."""
        out, self._warnings = self._warnings, []
        return out

    def stop_stream(self) -> None:
        reader, self._reader = self._reader, None
        if reader is None:
            return
        s = self.stream_commands
        stopped = self.clock.now()
        try:
            self._t.write(s.stop.encode("ascii") + self.terminator)
            acked = reader.wait_ack(self.timeout_s + 2.0 / self.rate_hz)
        except PortLost:
            acked = False
        finally:
            reader.halt()
        # the stream's timing check over all of it: a rate off the configured one is reported once,
        # and again only where a later stream's differs from it by more than the tolerance
        samples = reader.samples()
        tol = s.rate_tolerance * samples.period_s
        if samples.warnings and (self._reported is None or abs(samples.period_s - self._reported) > tol):
            self._reported = samples.period_s
            self._warnings += list(samples.warnings)
        # and the lines lost: the counter's gaps, and those after the last line received (the samples
        # the instrument had ended by its stop: a stream gone silent leaves no gap behind it)
        missing = list(samples.missing)
        ended = int((stopped - self._started) / samples.period_s) - 1
        after = int(samples.index[-1]) + 1 if len(samples.index) else 0
        if ended > after:
            missing.append((after, ended))
        if missing:
            lost = sum(b - a for a, b in missing)
            where = ", ".join(f"{a}..{b - 1}" for a, b in missing[:5])
            more = ", ..." if len(missing) > 5 else ""
            self._warnings.append(f"stream: {lost} of {lost + len(samples.index)} lines lost (samples {where}"
                                  f"{more}; {reader.garbage} garbled); a reading they fell in was read again")
        if not acked or reader.error is not None:
            self._abandon()
            raise InstrumentCommError(self.name, f"{s.stop!r}: no {self.profile.ok_reply!r} after the stream")

    def _abandon(self) -> None:
        """After a stream that did not start or stop cleanly: its reader gone, the port reopened (and the
        link re-synchronised on the identity) at the next exchange."""
        if self._reader is not None:
            self._reader.halt()
            self._reader = None
        self._drop()
        self._stale = max(self._stale or 0.0, 0.0)
        self._may_stream = True

    def measure(self, exposure_s: float, frames: int = 1, *, key=None) -> Reading:
        if self._reader is not None:
            raise ValueError(f"detector '{self.name}': a reading on request while the stream runs")
        return super().measure(exposure_s, frames, key=key)

    def close(self) -> None:
        if self._reader is not None:
            try:
                self.stop_stream()
            except InstrumentCommError:
                pass
        super().close()


class SerialSpectrometer(SerialPowerMeter):
    """A spectrometer: one channel per wavelength bin, read at :meth:`connect`."""

    kind = "spectrometer"

    def __init__(self, name: str, port: str, profile=None, **kwargs):
        super().__init__(name, port, profile, **kwargs)
        self.wavelengths_nm: np.ndarray = np.zeros(0)
        self.channels: tuple[str, ...] = ()

    def connect(self) -> None:
        super().connect()
        self.wavelengths_nm = np.array(self.query_numbers(self.commands.wavelengths))
        self.channels = tuple(f"{w:g}nm" for w in self.wavelengths_nm)

    def _read(self, line: str, wait_s: float) -> np.ndarray:
        values = np.array(self.query_numbers(line, wait_s=wait_s))
        if values.shape != self.wavelengths_nm.shape:
            raise InstrumentCommError(self.name, f"spectrum has {values.size} bins, expected "
                                      f"{self.wavelengths_nm.size}")
        return values
