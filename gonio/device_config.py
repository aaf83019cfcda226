"""What every device section of a config shares, and the bases each driver's config model extends.

A device section (``[axes.NAME]``, ``[light]``, ``[detector]``, ``[buses.NAME]``) is validated by the model
of the driver it names with ``driver = ...``: the driver registries of :mod:`gonio.registries`
(``AXIS_DRIVERS``, ``LIGHT_DRIVERS``, ``DETECTOR_DRIVERS``, ``BUS_DRIVERS``) map each name to a model that
extends :class:`AxisConfig`, :class:`LightConfig`, :class:`DetectorConfig` or :class:`BusConfig` with
the driver's own settings (its ``driver`` field a ``Literal`` of its name), and :mod:`gonio.config` joins
them into discriminated unions. The model also builds the device (``build``, ``open``), so the wiring
never asks which driver it has: a new driver is its model and its device, registered, and nothing else.

Settings that only a simulator (or the emulator of a device) needs live in the ``sim`` sub-tables defined
here, shared by every driver (``[light.sim]``, ``[detector.sim]``, ``[axes.NAME.sim]``).

A driver's setting written on a device of another driver is refused naming it ("``profile``: not a
setting of a 'dynamixel' axis"), unless it holds that setting's default: a config dumped in full by an
older gonio (one model held every driver's fields then) still loads.

This module imports pydantic and the standard library only: drivers import it to declare their models.
"""

from __future__ import annotations

import math
import typing
from dataclasses import dataclass, field
from typing import ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

__all__ = ["Strict", "changed_fields", "driver_name", "DeviceConfig", "AxisConfig", "LightConfig",
           "DetectorConfig", "BusConfig", "BuildContext", "AxisSimConfig", "LightSimConfig", "NoiseConfig",
           "SpectrometerSimConfig", "CameraSimConfig", "DetectorSimConfig"]


class Strict(BaseModel):
    """A config table: every key known, values frozen once validated, every number finite (TOML spells
    nan and inf; no setting of a gantry means either)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


def changed_fields(model: BaseModel) -> set[str]:
    """Fields whose value differs from the default (a dumped and re-read config sets every field)."""
    return {k for k, f in type(model).model_fields.items() if getattr(model, k) != f.default}


def driver_name(model: type[BaseModel]) -> str | None:
    """The name a driver model's ``driver: Literal[NAME]`` field takes (None when it is not a Literal)."""
    args = typing.get_args(model.model_fields["driver"].annotation)
    return args[0] if len(args) == 1 and isinstance(args[0], str) else None


@dataclass
class BuildContext:
    """What a device needs from the rest of the gantry when the wiring builds it (:mod:`gonio.wiring`).

    Attributes
    ----------
    cfg : GonioConfig
        The whole config.
    clock : Clock
        The gantry's clock.
    buses : dict
        The bus objects by ``[buses.NAME]`` (:meth:`BusConfig.open`).
    material, seed
        What simulated devices render (real ones ignore them).
    light, axes, kinematics
        The built lamp, design axes and kinematics: set before the detector is built (a simulated
        detector renders what they do).
    """

    cfg: object
    clock: object
    buses: dict = field(default_factory=dict)
    material: object = None
    seed: int = 0
    light: object = None
    axes: dict = field(default_factory=dict)
    kinematics: object = None


class DeviceConfig(Strict):
    """Base of every device section. Subclasses set the class variables below."""

    driver: str
    #: What the section is, in messages ("axis", "light", "detector", "bus").
    device: ClassVar[str] = "device"
    #: The registry of :mod:`gonio.registries` the drivers of this kind of device are in.
    registry: ClassVar[str] = ""
    #: The bus driver a device of this driver is reached through (its ``bus`` names a ``[buses.NAME]``
    #: section of that driver); None: not on a bus.
    bus_driver: ClassVar[str | None] = None
    #: A simulated device (a gantry of only such devices is the simulated gantry).
    simulated: ClassVar[bool] = False

    @model_validator(mode="before")
    @classmethod
    def _other_drivers_settings(cls, data):
        """Another driver's setting is refused by name; one that holds that setting's default (what a
        full dump of an older config carries) is dropped."""
        if not isinstance(data, dict) or not cls.registry:
            return data
        own = cls.model_fields
        theirs = _settings_of_other_drivers(cls)
        foreign = sorted(k for k in data if k not in own and k in theirs and data[k] not in theirs[k])
        if foreign:
            mine = sorted(set(own) - set(_shared_fields(cls)))
            raise ValueError(f"{', '.join(foreign)}: not a setting of a '{driver_name(cls)}' {cls.device} "
                             f"(allowed: {', '.join(mine) or 'none beyond the shared ones'})")
        return {k: v for k, v in data.items() if k in own or k not in theirs}

    @model_validator(mode="after")
    def _names_its_bus(self):
        if self.bus_driver is not None and getattr(self, "bus", None) is None:
            raise ValueError(f"bus: a '{self.driver}' {self.device} names the [buses.NAME] section it is on")
        return self

    def bus_address(self) -> int | None:
        """The device's address on its bus (a servo ID, a Modbus unit id), which no other device on the
        same bus may share; None: none (or not on a bus)."""
        return None

    def check_in(self, cfg, where: str) -> None:
        """Checks against the rest of the config ``cfg`` (``where``: e.g. ``axes.NAME``); ValueError
        naming the field. None by default."""


def _base_of(cls: type[DeviceConfig]) -> type[DeviceConfig]:
    """The shared base (AxisConfig, LightConfig, ...) a driver model extends."""
    for base in cls.__mro__:
        if base in (AxisConfig, LightConfig, DetectorConfig, BusConfig):
            return base
    return DeviceConfig


def _shared_fields(cls: type[DeviceConfig]) -> dict:
    return _base_of(cls).model_fields


def _settings_of_other_drivers(cls: type[DeviceConfig]) -> dict[str, list]:
    """Every setting the other drivers of the same registry have that ``cls`` lacks -> their defaults."""
    from gonio import registries

    out: dict[str, list] = {}
    for entry in getattr(registries, cls.registry).entries():
        model = entry.load()
        if model is cls:
            continue
        for key, f in model.model_fields.items():
            if key not in cls.model_fields:
                out.setdefault(key, []).append(f.default)
    return out


# -- axes -----------------------------------------------------------------------------------------------
class AxisSimConfig(Strict):
    #: Encoder resolution: the simulated axis settles on a multiple of it (0: exact).
    resolution_deg: float = Field(0.0, ge=0.0, le=1.0)


class AxisConfig(DeviceConfig):
    """``[axes.NAME]``: what every axis has (limits, speed, home, sim settings)."""

    device: ClassVar[str] = "axis"
    registry: ClassVar[str] = "AXIS_DRIVERS"

    min_deg: float
    max_deg: float
    #: The axis's speed and acceleration: the planner's, and the profile written to a real controller.
    #: (From 0.001°/s: slower makes a plan of years, which the planner's arithmetic does not hold.)
    max_velocity_deg_s: float = Field(ge=1e-3, le=1e5)
    max_accel_deg_s2: float = Field(ge=1e-3, le=1e7)
    home_deg: float = 0.0
    sim: AxisSimConfig = AxisSimConfig()

    @model_validator(mode="after")
    def _check_axis(self):
        if not self.min_deg < self.max_deg:
            raise ValueError(f"min_deg ({self.min_deg}) must be less than max_deg ({self.max_deg})")
        if not self.min_deg <= self.home_deg <= self.max_deg:
            raise ValueError(f"home_deg {self.home_deg} is outside [{self.min_deg}, {self.max_deg}]")
        self.check_reference()
        return self

    # -- referencing (gonio gantry reference; gonio.reference) -------------------------------------------
    def reference_methods(self) -> tuple[tuple[str, ...], str]:
        """The reference methods this axis allows, and how messages name the axis."""
        return ("none",), f"a '{self.driver}' axis"

    @property
    def reference_method(self) -> str:
        """The reference method in force: the axis's ``reference`` setting, else its driver's default."""
        return getattr(self, "reference", None) or self.default_reference()

    def default_reference(self) -> str:
        return "none"

    def check_reference(self) -> None:
        allowed, what = self.reference_methods()
        method = self.reference_method
        if method not in allowed:
            raise ValueError(f"reference: '{method}' is not a method of {what} (allowed: "
                             f"{', '.join(allowed)})")

    def build(self, name: str, ctx: BuildContext, start_deg: float | None = None):
        """The axis device (no I/O). ``start_deg``: where a simulated axis powers up."""
        raise NotImplementedError(f"axis driver '{self.driver}' builds no device")


# -- light ----------------------------------------------------------------------------------------------
class LightSimConfig(Strict):
    #: Radiance of the source (arbitrary but consistent units; the white reference calibrates it out).
    radiance: float = Field(1000.0, gt=0.0)
    #: Half-angle of the cone the source subtends, seen from the sample.
    half_angle_deg: float = Field(0.5, gt=0.0, le=10.0)
    #: Relative change of radiance per hour of (virtual) time: what the periodic white reference tracks.
    drift_per_hour: float = Field(0.0, ge=-0.5, le=0.5)
    #: Warm-up: the output starts this fraction below its settled value and approaches it as
    #: exp(-t / warmup_s) (a lamp switched on when the campaign began; 0: already warm).
    warmup_fraction: float = Field(0.0, ge=0.0, le=0.5)
    warmup_s: float = Field(600.0, gt=0.0, le=86400.0)
    #: A slow periodic wander (room temperature, supply) of this relative amplitude and period.
    wander_fraction: float = Field(0.0, ge=0.0, le=0.2)
    wander_period_s: float = Field(1800.0, gt=0.0, le=86400.0)


class LightConfig(DeviceConfig):
    """``[light]``, the lamp. ``sim``: what a simulated lamp (or the emulator of a real one) emits."""

    device: ClassVar[str] = "light"
    registry: ClassVar[str] = "LIGHT_DRIVERS"

    sim: LightSimConfig = LightSimConfig()

    def build(self, ctx: BuildContext):
        """The light source (no I/O)."""
        raise NotImplementedError(f"light driver '{self.driver}' builds no device")


# -- detector -------------------------------------------------------------------------------------------
class NoiseConfig(Strict):
    #: Counts per unit of signal for shot noise (0 disables it).
    shot_counts_per_unit: float = Field(0.0, ge=0.0)
    read_sigma: float = Field(0.0, ge=0.0)
    dark_offset: float = Field(0.0, ge=0.0)


class SpectrometerSimConfig(Strict):
    """Bands of a simulated spectrometer: ``start_nm`` to ``stop_nm`` (inclusive) every ``step_nm``."""

    start_nm: float = Field(380.0, ge=300.0, le=900.0)
    stop_nm: float = Field(780.0, ge=300.0, le=900.0)
    step_nm: float = Field(10.0, gt=0.0, le=100.0)

    @model_validator(mode="after")
    def _check(self):
        if self.stop_nm < self.start_nm:
            raise ValueError(f"stop_nm: must be >= start_nm ({self.start_nm:g}), got {self.stop_nm:g}")
        if len(self.wavelengths_nm()) > 1000:
            raise ValueError(f"step_nm: at most 1000 bands, got {len(self.wavelengths_nm())}")
        return self

    def wavelengths_nm(self) -> list[float]:
        n = int(math.floor((self.stop_nm - self.start_nm) / self.step_nm + 1e-9)) + 1
        return [self.start_nm + i * self.step_nm for i in range(n)]


class CameraSimConfig(Strict):
    """A simulated camera on the detector arm (see :mod:`gonio.sim.camera`; lengths in m, angles in °).
    The light's radiance and half-angle come from ``[light.sim]``."""

    width: int = Field(64, ge=8, le=4096)
    height: int = Field(64, ge=8, le=4096)
    samples_per_pixel: int = Field(16, ge=1, le=4096)
    fov_deg: float = Field(4.0, gt=0.0, lt=120.0)
    distance_m: float = Field(0.5, gt=0.0)
    sample_size_m: float = Field(0.02, gt=0.0)
    light_distance_m: float = Field(1.0, gt=0.0)
    vignetting: bool = False
    black_level: float = Field(0.0, ge=0.0)
    read_sigma: float = Field(0.0, ge=0.0)
    shot_counts_per_unit: float = Field(0.0, ge=0.0)
    #: Full-scale reading (signal units, black level included); None: the sensor never saturates.
    saturation: float | None = Field(None, gt=0.0)
    #: Pixels taken off the sample region's border (the edge pixels see part sample, part surround).
    erode_px: int = Field(2, ge=0, le=64)
    #: Choose each reading's exposure from a probe frame at ``detector.exposure_s``.
    auto_exposure: bool = False
    #: Exposure bracket: multiples of the exposure merged into one HDR frame (empty: one frame).
    brackets: tuple[float, ...] = ()
    #: Keep every frame as EXR in the campaign's frames/ folder.
    save_frames: bool = True

    @model_validator(mode="after")
    def _check(self):
        if any(not (0.0 < b <= 1e4) for b in self.brackets):
            raise ValueError(f"brackets: each multiple must be in (0, 10000], got {list(self.brackets)}")
        if len(self.brackets) > 16:
            raise ValueError(f"brackets: at most 16 exposures, got {len(self.brackets)}")
        if (self.auto_exposure or self.brackets) and self.saturation is None:
            raise ValueError("saturation: auto_exposure and brackets need the sensor's full-scale reading")
        if self.saturation is not None and self.saturation <= self.black_level:
            raise ValueError(f"saturation: must exceed black_level ({self.black_level:g}), got "
                             f"{self.saturation:g}")
        diagonal = math.sqrt(2.0) * self.sample_size_m
        for name in ("distance_m", "light_distance_m"):
            if getattr(self, name) <= diagonal:
                raise ValueError(f"{name}: must exceed the sample's diagonal ({diagonal:g} m), got "
                                 f"{getattr(self, name):g}")
        return self


class DetectorSimConfig(Strict):
    #: What the simulated detector is: a name of :data:`gonio.registries.SIM_DETECTORS` (an RGB
    #: photodiode, the default; a spectrometer; a camera).
    kind: str = "photodiode"
    half_angle_deg: float = Field(1.0, gt=0.0, le=10.0)
    #: Monte Carlo samples per reading over the source and detector apertures (2 at least: the
    #: detector estimates its integration error from their spread).
    aperture_samples: int = Field(256, ge=2, le=1 << 20)
    #: Dr.Jit backend of the render (photodiode, spectrometer, camera); None: ``GONIO_BACKEND``, else
    #: CUDA when present, else LLVM (:func:`gonio.jit.resolve_backend`).
    backend: Literal["llvm", "cuda"] | None = None
    noise: NoiseConfig = NoiseConfig()
    spectrometer: SpectrometerSimConfig = SpectrometerSimConfig()
    camera: CameraSimConfig = CameraSimConfig()

    @field_validator("kind")
    @classmethod
    def _known_kind(cls, kind: str) -> str:
        from gonio.registries import SIM_DETECTORS

        if kind not in SIM_DETECTORS:
            raise ValueError(f"'{kind}' is not a simulated detector; allowed: "
                             f"{', '.join(SIM_DETECTORS.names())}")
        return kind


class DetectorConfig(DeviceConfig):
    """``[detector]``: what every detector has. ``sim``: how a simulated detector (or the emulator of a
    real one) renders."""

    device: ClassVar[str] = "detector"
    registry: ClassVar[str] = "DETECTOR_DRIVERS"

    channels: tuple[str, ...] = ("R", "G", "B")
    exposure_s: float = Field(0.1, gt=0.0, le=3600.0)
    frames: int = Field(1, ge=1, le=1000)
    sim: DetectorSimConfig = DetectorSimConfig()

    @model_validator(mode="after")
    def _check_detector(self):
        if not self.channels or len(set(self.channels)) != len(self.channels):
            raise ValueError(f"channels: must be distinct names, at least one, got {list(self.channels)}")
        if not self.simulated and self.sim.kind != "photodiode":
            raise ValueError(f"sim.kind: '{self.sim.kind}' is a simulated detector; driver '{self.driver}' "
                             f"reads a real one (leave sim.kind out)")
        return self

    @property
    def kind_name(self) -> str:
        """What a reading is, as the journal names it (``photodiode``, ``power_meter``, ...)."""
        return self.driver

    @property
    def channel_names(self) -> tuple[str, ...]:
        """The channels a reading has."""
        return tuple(self.channels)

    @property
    def wavelengths_nm(self) -> tuple[float, ...] | None:
        """Centre wavelength (nm) of each channel where the channels are bands, else None."""
        return None

    def descriptor(self) -> dict:
        """What a reading is (:func:`gonio.protocols.detector_descriptor`), for the campaign's journal."""
        from gonio.protocols import detector_descriptor

        return detector_descriptor(self.kind_name, self.channel_names, self.wavelengths_nm)

    def build(self, ctx: BuildContext):
        """The detector (no I/O); ``ctx`` has the built light, axes and kinematics."""
        raise NotImplementedError(f"detector driver '{self.driver}' builds no device")


# -- buses ----------------------------------------------------------------------------------------------
class BusConfig(DeviceConfig):
    """``[buses.NAME]``: where devices are reached (each port or url written once)."""

    device: ClassVar[str] = "bus"
    registry: ClassVar[str] = ""   # a bus of one driver never carries another's settings
    #: At most one device on a bus of this driver (a serial instrument owns its port).
    one_device: ClassVar[bool] = False

    def open(self, name: str):
        """The bus object the devices on it share (no I/O)."""
        return self
