"""A toy detector driver (docs/EXTENDING.md, "A new detector"): a photon counter that counts ``rate_hz``
while the lamp is on and ``dark_hz`` while it is off. Its config model (``[detector] driver =
"toy-counter"``, its own settings validated like any driver's) and its device are this file;
``GONIO_PLUGINS=toy_detector`` loads it."""

from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from gonio.device_config import DetectorConfig
from gonio.protocols import Reading
from gonio.registries import DETECTOR_DRIVERS


class ToyCounter:
    """The device: a :class:`gonio.protocols.Detector` reading counts per exposure."""

    def __init__(self, light, channels, rate_hz: float, dark_hz: float):
        self.name, self.channels = "detector", tuple(channels)
        self.light, self.rate_hz, self.dark_hz = light, rate_hz, dark_hz
        self.connected = False

    def connect(self) -> None:
        self.connected = True

    def close(self) -> None:
        self.connected = False

    def measure(self, exposure_s, frames=1, *, key=None) -> Reading:
        if not self.connected:
            raise RuntimeError("toy counter: not connected")
        counts = (self.rate_hz if self.light.is_on() else self.dark_hz) * exposure_s
        signal = np.full(len(self.channels), counts)
        return Reading(signal, np.sqrt(signal / frames), exposure_s, frames)

    def describe(self) -> dict:
        return {"model": "toy counter", "rate_hz": self.rate_hz, "dark_hz": self.dark_hz}


@DETECTOR_DRIVERS.register("toy-counter", "a photon counter (a toy plugin)")
class ToyCounterConfig(DetectorConfig):
    driver: Literal["toy-counter"]
    #: Counts per second while the lamp is on, and while it is off.
    rate_hz: float = Field(gt=0.0, le=1e9)
    dark_hz: float = Field(0.0, ge=0.0)

    @model_validator(mode="after")
    def _dark_below_lit(self):
        if self.dark_hz >= self.rate_hz:
            raise ValueError(f"dark_hz: must be below rate_hz ({self.rate_hz:g}), got {self.dark_hz:g}")
        return self

    def build(self, ctx):
        return ToyCounter(ctx.light, self.channels, self.rate_hz, self.dark_hz)
