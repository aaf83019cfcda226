"""The ``serial`` driver's config models: a port (``[buses.NAME] driver = "serial"``, one instrument each)
and the line instruments on it, a lamp (``[light] driver = "serial"``) and a detector (``[detector] driver
= "serial"``: a power meter or a spectrometer), each speaking a TOML profile's dialect. Registered in
:data:`gonio.registries.BUS_DRIVERS`, ``LIGHT_DRIVERS`` and ``DETECTOR_DRIVERS``; building the devices
imports pyserial (or PyVISA), validating reads the profile only.
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field, model_validator

from gonio.device_config import BuildContext, BusConfig, DetectorConfig, LightConfig

__all__ = ["SerialBusConfig", "SerialLightConfig", "SerialDetectorConfig"]


class SerialBusConfig(BusConfig):
    driver: Literal["serial"]
    one_device: ClassVar[bool] = True
    #: A serial port or pyserial URL (``/dev/ttyUSB0``, ``socket://host:5025``), or a VISA resource string
    #: (``ASRL/dev/ttyUSB0::INSTR``, ``TCPIP0::host::5025::SOCKET``), opened through PyVISA.
    port: str = Field(min_length=1)
    baudrate: int = Field(115200, ge=300, le=4_000_000)
    #: Deadline of one reply (s).
    timeout_s: float = Field(1.0, gt=0.0, le=60.0)
    #: Line terminator; None: the instrument profile's.
    terminator: str | None = Field(None, min_length=1)

    @model_validator(mode="after")
    def _check_port(self):
        from gonio.drivers.serial.transport import check_visa_resource, is_visa_resource

        if is_visa_resource(self.port):
            check_visa_resource(self.port)
        return self

    def line_settings(self, clock) -> dict:
        """The keyword arguments of a line instrument on this port."""
        return dict(baudrate=self.baudrate, terminator=self.terminator, timeout_s=self.timeout_s, clock=clock)


def instrument_profile(name: str, kind: str):
    """The instrument profile ``name`` (shipped name or path), which must describe a ``kind``; ValueError
    naming the ``profile`` setting."""
    from gonio.drivers.serial.profile import load_profile

    try:
        profile = load_profile(name)
        section = profile.section(kind)
    except ValueError as err:
        raise ValueError(f"profile: {err}") from None
    return profile, section


class SerialLightConfig(LightConfig):
    """A lamp on a serial line (:class:`gonio.drivers.serial.SerialLightSource`)."""

    driver: Literal["serial"]
    bus_driver: ClassVar[str | None] = "serial"

    bus: str | None = None
    #: Instrument profile: a shipped profile's name (acknowledging, scpi-current-source) or a path to a
    #: TOML profile (gonio.drivers.serial.profile).
    profile: str = "acknowledging"
    #: Output level (%) set at connect and at each switch-on (profiles whose level takes a percentage);
    #: None leaves the lamp's own setting.
    level_percent: float | None = Field(None, ge=0.0, le=100.0)
    #: The lamp's current (A), for profiles whose level is a current (a SCPI current source).
    current_a: float | None = Field(None, gt=0.0, le=100.0)
    #: Longest wait (s) for the lamp's ready flag after it is switched on (0: no wait).
    warmup_timeout_s: float = Field(0.0, ge=0.0, le=3600.0)
    #: Wait (s) after each switch for the lamp to reach its level or go dark.
    settle_s: float = Field(0.0, ge=0.0, le=600.0)

    @model_validator(mode="after")
    def _check_profile(self):
        profile, light = instrument_profile(self.profile, "light")
        unit = light.level_field
        for key, takes in (("level_percent", "percent"), ("current_a", "current_a")):
            if getattr(self, key) is not None and unit != takes:
                what = {"percent": "a percentage (level_percent)", "current_a": "a current (current_a)",
                        None: "nothing (no level command)"}[unit]
                raise ValueError(f"{key}: profile {profile.source} sets the lamp's level as {what}")
        if self.warmup_timeout_s > 0 and light.ready is None:
            raise ValueError(f"warmup_timeout_s: profile {profile.source} has no ready query to wait for "
                             "(leave it 0; settle_s waits a fixed time)")
        return self

    @property
    def level(self) -> float | None:
        """The level the lamp is set to, in its profile's unit (% or A), or None."""
        return self.level_percent if self.level_percent is not None else self.current_a

    def build(self, ctx: BuildContext):
        from gonio.drivers.serial.instruments import SerialLightSource

        bus = ctx.cfg.buses[self.bus]
        return SerialLightSource("light", bus.port, self.profile, level=self.level,
                                 warmup_timeout_s=self.warmup_timeout_s, settle_s=self.settle_s,
                                 **bus.line_settings(ctx.clock))


class SerialDetectorConfig(DetectorConfig):
    """A detector on a serial line: a power meter (one value per frame) or a spectrometer (one per band)."""

    driver: Literal["serial"]
    bus_driver: ClassVar[str | None] = "serial"

    bus: str | None = None
    #: What the instrument is: one value per frame, or one per wavelength band.
    kind: Literal["power_meter", "spectrometer"] = "power_meter"
    #: Instrument profile: a shipped profile's name (acknowledging, thorlabs-pm100) or a path to a TOML
    #: profile.
    profile: str = "acknowledging"
    #: The wavelength (nm) a power meter takes its sensor's responsivity at (profiles that set it); None
    #: leaves the meter's own setting (which a power cycle resets).
    wavelength_nm: float | None = Field(None, ge=100.0, le=20000.0)
    #: Where the profile has a continuous mode ([power_meter.stream]): read a fly sweep's sub-reads from
    #: the stream (no dead time between them). False: on request, as a profile without one.
    stream: bool = True
    #: The stream's sample rate (Hz); None: the profile's ``rate_hz``.
    stream_rate_hz: float | None = Field(None, gt=0.0, le=100_000.0)

    @model_validator(mode="after")
    def _check_profile(self):
        profile, meter = instrument_profile(self.profile, self.kind)
        if self.stream_rate_hz is not None and (meter.stream is None or not self.stream):
            raise ValueError(f"stream_rate_hz: profile {profile.source} has no stream to run"
                             if meter.stream is None else "stream_rate_hz: set, but stream = false")
        if "wavelength_nm" not in meter.fields and self.wavelength_nm is not None:
            raise ValueError(f"wavelength_nm: profile {profile.source} sets no wavelength")
        if self.kind == "power_meter" and len(self.channels) != 1:
            raise ValueError(f"channels: a power meter reads one value, so exactly one channel name, got "
                             f"{list(self.channels)}")
        return self

    @property
    def kind_name(self) -> str:
        return self.kind

    def build(self, ctx: BuildContext):
        from gonio.drivers.serial.instruments import SerialPowerMeter, SerialSpectrometer, StreamingPowerMeter
        from gonio.drivers.serial.profile import load_profile
        from gonio.protocols import DeviceFault

        bus = ctx.cfg.buses[self.bus]
        settings = dict(wavelength_nm=self.wavelength_nm, **bus.line_settings(ctx.clock))
        channels = tuple(self.channels)
        if self.kind == "power_meter":
            if self.stream and load_profile(self.profile).power_meter.stream is not None:
                det = StreamingPowerMeter("detector", bus.port, self.profile, rate_hz=self.stream_rate_hz,
                                          **settings)
            else:
                det = SerialPowerMeter("detector", bus.port, self.profile, **settings)
            det.channels = channels
            return det

        class _Spectrometer(SerialSpectrometer):
            """A spectrometer whose bands are the campaign's channels: as many bins as channels, by name."""

            def connect(self) -> None:
                super().connect()
                if len(self.wavelengths_nm) != len(channels):
                    bins = ", ".join(f"{w:g}" for w in self.wavelengths_nm)
                    self.close()
                    raise DeviceFault(self.name, f"reports {len(self.wavelengths_nm)} bands ({bins} nm) but "
                                      f"detector.channels names {len(channels)} ({', '.join(channels)}): "
                                      "configure the instrument to report one band per channel")
                self.channels = channels

        det = _Spectrometer("detector", bus.port, self.profile, **settings)
        det.channels = channels
        return det
