"""Serial light source and detectors on :class:`LineInstrument`: a lamp (on/off, level, warm-up), a
photodiode/power meter (one value per frame) and a spectrometer (one value per wavelength bin)."""

from __future__ import annotations

import numpy as np

from gonio.drivers.serial.line import InstrumentCommError, LineInstrument
from gonio.protocols import Reading

__all__ = ["SerialLightSource", "SerialPowerMeter", "SerialSpectrometer"]


class SerialLightSource(LineInstrument):
    """A lamp as a :class:`gonio.protocols.LightSource`; :meth:`wait_ready` polls its warm-up flag."""

    def set_on(self, on: bool) -> None:
        self.command(self.commands.output_on if on else self.commands.output_off)

    def is_on(self) -> bool:
        return self.query(self.commands.output_query) == "1"

    def set_level(self, percent: float) -> None:
        """Output level in % of full power, 0..100."""
        if not 0.0 <= percent <= 100.0:
            raise ValueError(f"light '{self.name}': level {percent}% is outside [0%, 100%]")
        self.command(self.commands.level_set.format(percent))

    def level(self) -> float:
        return self.query_float(self.commands.level_query)

    def is_ready(self) -> bool:
        return self.query(self.commands.ready_query) == "1"

    def wait_ready(self, timeout_s: float, poll_s: float = 0.5) -> None:
        """Poll the ready flag until it rises; InstrumentCommError after ``timeout_s`` (clock time)."""
        deadline = self.clock.now() + timeout_s
        while not self.is_ready():
            if self.clock.now() >= deadline:
                raise InstrumentCommError(self.name, f"not ready (warm-up) within {timeout_s:g} s")
            self.clock.sleep(poll_s)


class SerialPowerMeter(LineInstrument):
    """A photodiode / power meter as a :class:`gonio.protocols.Detector` with one channel."""

    channels = ("power_w",)

    def _exposure(self, exposure_s: float, frames: int) -> None:
        if not 0 < exposure_s <= 60:
            raise ValueError(f"detector '{self.name}': exposure_s {exposure_s} is outside (0, 60] s")
        if not isinstance(frames, int) or frames < 1:
            raise ValueError(f"detector '{self.name}': frames {frames!r} must be an integer >= 1")
        self.command(self.commands.exposure_set.format(exposure_s))

    def _frame(self) -> np.ndarray:
        return np.array([self.query_float(self.commands.measure)])

    def measure(self, exposure_s: float, frames: int = 1, *, key=None) -> Reading:
        """Mean and standard error over ``frames`` readings of ``exposure_s`` s each."""
        self._exposure(exposure_s, frames)
        data = np.stack([self._frame() for _ in range(frames)])
        stderr = data.std(axis=0, ddof=1) / np.sqrt(frames) if frames > 1 else np.zeros(data.shape[1])
        extra = {} if key is None else {"key": tuple(key)}
        return Reading(signal=data.mean(axis=0), stderr=stderr, exposure_s=float(exposure_s), frames=frames,
                       extra=extra)


class SerialSpectrometer(SerialPowerMeter):
    """A spectrometer: one channel per wavelength bin, read at :meth:`connect`."""

    def __init__(self, name: str, port: str, **kwargs):
        super().__init__(name, port, **kwargs)
        self.wavelengths_nm: np.ndarray = np.zeros(0)
        self.channels: tuple[str, ...] = ()

    def connect(self) -> None:
        super().connect()
        self.wavelengths_nm = np.array(self.query_floats(self.commands.wavelengths_query))
        self.channels = tuple(f"{w:g}nm" for w in self.wavelengths_nm)

    def _frame(self) -> np.ndarray:
        values = np.array(self.query_floats(self.commands.measure_spectrum))
        if values.shape != self.wavelengths_nm.shape:
            raise InstrumentCommError(self.name, f"spectrum has {values.size} bins, expected "
                                      f"{self.wavelengths_nm.size}")
        return values
