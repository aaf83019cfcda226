"""Gantry configuration: TOML in, validated pydantic models out.

Every key is checked: an unknown key, a missing one or a value out of range is a :class:`ConfigError`
that names the file, the field and what is allowed. Nothing is clamped.

Each axis, the light and the detector name their ``driver`` (``sim``, ``dynamixel``, ``modbus``,
``serial``); a real device names the ``[buses.NAME]`` section it is reached through, where its port
(or ``url``) is written once for every device on that bus. Settings that only a simulator (or the
emulator of a device) needs live in the device's ``sim`` sub-table (``[light.sim]``,
``[detector.sim]``, ``[axes.NAME.sim]``); the real drivers ignore them. ``[target]`` says how the white
standard gets under the beam (see :class:`TargetConfig`).
"""

from __future__ import annotations

import math
import tomllib
from importlib.resources import files
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

__all__ = ["ConfigError", "GonioConfig", "load_config", "DEFAULT_CONFIG", "design_axes", "CONFIG_DIR",
           "packaged_configs", "resolve_config", "relocate",
           "BUS_LOCATION_FIELDS", "REFERENCE_METHODS"]

#: The configs shipped inside the installed package (``config/`` in the source tree).
CONFIG_DIR = Path(str(files("gonio.configs")))
DEFAULT_CONFIG = CONFIG_DIR / "sim.toml"



def design_axes(design: str) -> tuple[str, ...]:
    """The axes a gantry design drives, in the order of axis arrays everywhere: what its kinematics
    declares (:data:`gonio.registries.DESIGNS`). ValueError naming the designs for an unknown one."""
    from gonio.registries import DESIGNS

    return tuple(DESIGNS.check(design, "design").load().axis_names)


class ConfigError(ValueError):
    pass


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


#: Device drivers a config may name, per kind of device.
AXIS_DRIVERS = ("sim", "dynamixel", "modbus")
LIGHT_DRIVERS = ("sim", "serial")
DETECTOR_DRIVERS = ("sim", "serial")


class KinematicsConfig(_Strict):
    #: A name of :data:`gonio.registries.DESIGNS` (two-arm, sample-stage, or a plugin's).
    design: str
    theta_max_deg: float = Field(80.0, gt=0.0, le=90.0)
    #: The light arm hides the detector when ωi and ωo are closer than this.
    clearance_deg: float = Field(5.0, ge=0.0, lt=90.0)
    #: Two parts of the gantry closer than this collide (design-specific; see gonio.kinematics).
    arm_collision_deg: float = Field(10.0, ge=0.0, lt=180.0)

    @field_validator("design")
    @classmethod
    def _known_design(cls, design: str) -> str:
        from gonio.registries import DESIGNS

        if design not in DESIGNS:
            raise ValueError(f"'{design}' is not a gantry design; allowed: {', '.join(DESIGNS.names())}")
        return design


# -- buses: where devices are reached (each port or host:port written once) -------------------------
class DynamixelBusConfig(_Strict):
    driver: Literal["dynamixel"]
    #: Serial port of the bus (``/dev/serial/by-id/...``, ``/dev/ttyUSB0``).
    port: str = Field(min_length=1)
    baudrate: Literal[9600, 57600, 115200, 1_000_000, 2_000_000, 3_000_000, 4_000_000] = 1_000_000
    retries: int = Field(1, ge=0, le=5)


class ModbusBusConfig(_Strict):
    driver: Literal["modbus"]
    #: ``tcp://host:port`` or ``rtu:///dev/ttyX?baudrate=N``.
    url: str = Field(pattern=r"^(tcp://[^/]+|rtu:///.+)$")
    timeout_s: float = Field(0.5, gt=0.0, le=10.0)
    retries: int = Field(1, ge=0, le=5)


class SerialBusConfig(_Strict):
    driver: Literal["serial"]
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


BusConfig = Annotated[DynamixelBusConfig | ModbusBusConfig | SerialBusConfig, Field(discriminator="driver")]
#: Bus fields that say where a bus is reached (the only ones an emulated twin changes).
BUS_LOCATION_FIELDS = ("port", "url")


# -- axes -------------------------------------------------------------------------------------------
class AxisSimConfig(_Strict):
    #: Encoder resolution: the simulated axis settles on a multiple of it (0: exact).
    resolution_deg: float = Field(0.0, ge=0.0, le=1.0)


def _changed(model: BaseModel) -> set[str]:
    """Fields whose value differs from the default (a dumped and re-read config sets every field)."""
    return {k for k, f in type(model).model_fields.items() if getattr(model, k) != f.default}


#: Fields each axis driver accepts beyond the shared ones (limits, speed, home, sim).
_AXIS_FIELDS = {
    "sim": frozenset(),
    "dynamixel": frozenset({"bus", "id", "family", "operating_mode", "gear_ratio", "direction",
                            "homing_offset_ticks", "watchdog_s", "reference", "reference_deg",
                            "reference_direction", "reference_velocity_deg_s", "reference_current_a"}),
    "modbus": frozenset({"bus", "device_id", "profile", "gear_ratio", "direction", "zero_steps",
                         "reference"}),
}
#: Reference methods (``[axes.NAME] reference``; see :mod:`gonio.reference`).
REFERENCE_METHODS = ("none", "hard_stop", "index", "origin")


class AxisConfig(_Strict):
    driver: Literal["sim", "dynamixel", "modbus"] = "sim"
    min_deg: float
    max_deg: float
    #: The axis's speed and acceleration: the planner's, and the profile written to a real controller.
    max_velocity_deg_s: float = Field(gt=0.0)
    max_accel_deg_s2: float = Field(gt=0.0)
    home_deg: float = 0.0
    #: Name of a ``[buses.NAME]`` section (dynamixel, modbus).
    bus: str | None = None
    #: Dynamixel servo ID.
    id: int | None = Field(None, ge=0, le=252)
    family: Literal["XM430", "XL430"] = "XM430"
    operating_mode: Literal["position", "extended"] = "position"
    #: Motor (servo) revolutions per axis revolution.
    gear_ratio: float = Field(1.0, gt=0.0, le=10000.0)
    direction: Literal[1, -1] = 1
    #: Dynamixel Present Position (ticks) at axis 0°.
    homing_offset_ticks: int = Field(0, ge=-1_048_575, le=1_048_575)
    #: Dynamixel bus watchdog while moving (s, up to 2.54; 0 disables it): a servo that hears nothing
    #: for this long mid-move stops by itself (gonio died). The runner reads moving servos every
    #: watchdog_s / 2, so it must be at least 4 x runner.poll_s. Off unless a config sets it.
    watchdog_s: float = Field(0.0, ge=0.0, le=2.54)
    #: Modbus unit id.
    device_id: int | None = Field(None, ge=1, le=247)
    #: Modbus register profile: a shipped profile's name or a path to a TOML profile.
    profile: str = "generic"
    #: Modbus controller position (steps) at axis 0°.
    zero_steps: int = 0
    #: How the axis finds its absolute position after power-up (``gonio gantry reference``): "none" (it
    #: never loses it), "hard_stop" (a Dynamixel XM430 approaches a mechanical stop at reference_deg in
    #: current-based position mode), "index" (it stands at reference_deg, within half a servo turn, when
    #: referenced: a mark, a pin), "origin" (a Modbus controller's return-to-origin operation). Unset:
    #: the driver's own (Dynamixel: "none" in position mode, "index" in extended mode; Modbus: "origin"
    #: where the profile's drive loses its position at power-off, else "none").
    reference: Literal["none", "hard_stop", "index", "origin"] | None = None
    #: Where the stop or index is (°, within the limits); unset: home_deg.
    reference_deg: float | None = None
    #: Hard stop: the direction (+1 / -1, axis degrees) of the approach; unset: toward the limit
    #: nearer reference_deg.
    reference_direction: Literal[1, -1] | None = None
    #: Hard stop: the approach speed (°/s); unset: a tenth of max_velocity_deg_s.
    reference_velocity_deg_s: float | None = Field(None, gt=0.0)
    #: Hard stop: Goal Current while approaching (A): the servo pushes against the stop no harder.
    reference_current_a: float = Field(0.3, gt=0.0, le=5.0)
    sim: AxisSimConfig = AxisSimConfig()

    @model_validator(mode="after")
    def _check(self):
        if not self.min_deg < self.max_deg:
            raise ValueError(f"min_deg ({self.min_deg}) must be less than max_deg ({self.max_deg})")
        if not self.min_deg <= self.home_deg <= self.max_deg:
            raise ValueError(f"home_deg {self.home_deg} is outside [{self.min_deg}, {self.max_deg}]")
        allowed = _AXIS_FIELDS[self.driver]
        foreign = sorted(k for k in _changed(self) if k in _DRIVER_ONLY and k not in allowed)
        if foreign:
            raise ValueError(f"{', '.join(foreign)}: not a setting of a '{self.driver}' axis "
                             f"(allowed: {', '.join(sorted(allowed)) or 'none beyond the shared ones'})")
        if self.driver != "sim" and self.bus is None:
            raise ValueError(f"bus: a '{self.driver}' axis names the [buses.NAME] section it is on")
        if self.driver == "dynamixel" and self.id is None:
            raise ValueError("id: a dynamixel axis names its servo ID (0..252)")
        if self.driver == "modbus" and self.device_id is None:
            raise ValueError("device_id: a modbus axis names its unit id (1..247)")
        self._check_reference()
        return self

    def _check_reference(self) -> None:
        method = self.reference_method
        if self.reference_deg is not None and not self.min_deg <= self.reference_deg <= self.max_deg:
            raise ValueError(f"reference_deg: {self.reference_deg:g} is outside the axis limit "
                             f"[{self.min_deg:g}, {self.max_deg:g}]")
        allowed = {"sim": ("none",), "modbus": ("none", "origin"),
                   "dynamixel": ("hard_stop", "index") if self.operating_mode == "extended" else ("none",)}
        if method not in allowed[self.driver]:
            what = (f"a '{self.driver}' axis" if self.driver != "dynamixel"
                    else f"a dynamixel axis in {self.operating_mode} mode")
            raise ValueError(f"reference: '{method}' is not a method of {what} (allowed: "
                             f"{', '.join(allowed[self.driver])})")
        if method == "hard_stop" and self.family != "XM430":
            raise ValueError(f"reference: 'hard_stop' needs current-based position mode, which the "
                             f"{self.family} lacks (allowed: index)")
        v = self.reference_velocity_deg_s
        if v is not None and v > self.max_velocity_deg_s:
            raise ValueError(f"reference_velocity_deg_s: {v:g} is above max_velocity_deg_s "
                             f"({self.max_velocity_deg_s:g})")

    @property
    def reference_method(self) -> str:
        """The reference method in force (``reference``, or the driver's default: see the field)."""
        if self.reference is not None:
            return self.reference
        if self.driver == "dynamixel":
            return "index" if self.operating_mode == "extended" else "none"
        return "none"

    @property
    def reference_at_deg(self) -> float:
        """Where the stop or index is (°): ``reference_deg``, else ``home_deg``."""
        return self.home_deg if self.reference_deg is None else self.reference_deg

    @property
    def reference_toward(self) -> int:
        """The hard stop's approach direction: ``reference_direction``, else toward the nearer limit."""
        if self.reference_direction is not None:
            return self.reference_direction
        at = self.reference_at_deg
        return -1 if at - self.min_deg <= self.max_deg - at else 1

    @property
    def reference_speed_deg_s(self) -> float:
        return self.reference_velocity_deg_s or self.max_velocity_deg_s / 10.0


_DRIVER_ONLY = frozenset().union(*_AXIS_FIELDS.values())


# -- light --------------------------------------------------------------------------------------------
class LightSimConfig(_Strict):
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


def _instrument_profile(name: str, kind: str):
    """The instrument profile ``name`` (shipped name or path), which must describe a ``kind``."""
    from gonio.drivers.serial.profile import load_profile

    try:
        profile = load_profile(name)
        section = profile.section(kind)
    except ValueError as err:
        raise ValueError(f"profile: {err}") from None
    return profile, section


class LightConfig(_Strict):
    """The lamp. ``sim``: what a simulated lamp (or the emulator of a real one) emits."""

    driver: Literal["sim", "serial"] = "sim"
    bus: str | None = None
    #: Instrument profile (serial lamps): a shipped profile's name (acknowledging, scpi-current-source)
    #: or a path to a TOML profile (gonio.drivers.serial.profile).
    profile: str = "acknowledging"
    #: Output level (%) set at connect and at each switch-on (profiles whose level takes a percentage);
    #: None leaves the lamp's own setting.
    level_percent: float | None = Field(None, ge=0.0, le=100.0)
    #: The lamp's current (A), for profiles whose level is a current (a SCPI current source).
    current_a: float | None = Field(None, gt=0.0, le=100.0)
    #: Longest wait (s) for the lamp's ready flag after it is switched on (serial lamps; 0: no wait).
    warmup_timeout_s: float = Field(0.0, ge=0.0, le=3600.0)
    #: Wait (s) after each switch for the lamp to reach its level or go dark (serial lamps).
    settle_s: float = Field(0.0, ge=0.0, le=600.0)
    sim: LightSimConfig = LightSimConfig()

    @model_validator(mode="after")
    def _check(self):
        _check_bus_use("light", self.driver, self.bus, _changed(self),
                       {"profile", "level_percent", "current_a", "warmup_timeout_s", "settle_s"})
        if self.driver != "serial":
            return self
        profile, light = _instrument_profile(self.profile, "light")
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
        """The level a serial lamp is set to, in its profile's unit (% or A), or None."""
        return self.level_percent if self.level_percent is not None else self.current_a


# -- detector -----------------------------------------------------------------------------------------
class NoiseConfig(_Strict):
    #: Counts per unit of signal for shot noise (0 disables it).
    shot_counts_per_unit: float = Field(0.0, ge=0.0)
    read_sigma: float = Field(0.0, ge=0.0)
    dark_offset: float = Field(0.0, ge=0.0)


class SpectrometerSimConfig(_Strict):
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


class CameraSimConfig(_Strict):
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


#: Kinds of simulated detector (``[detector.sim] kind``, ``gonio simulate --detector``).
SIM_DETECTOR_KINDS = ("photodiode", "spectrometer", "camera")


class DetectorSimConfig(_Strict):
    #: What the simulated detector is: an RGB photodiode (the default), a spectrometer, a camera.
    kind: Literal["photodiode", "spectrometer", "camera"] = "photodiode"
    half_angle_deg: float = Field(1.0, gt=0.0, le=10.0)
    #: Monte Carlo samples per reading over the source and detector apertures (2 at least: the
    #: detector estimates its integration error from their spread).
    aperture_samples: int = Field(256, ge=2, le=1 << 20)
    noise: NoiseConfig = NoiseConfig()
    spectrometer: SpectrometerSimConfig = SpectrometerSimConfig()
    camera: CameraSimConfig = CameraSimConfig()


class DetectorConfig(_Strict):
    """The detector. ``sim``: how a simulated detector (or the emulator of a real one) renders."""

    driver: Literal["sim", "serial"] = "sim"
    channels: tuple[str, ...] = ("R", "G", "B")
    exposure_s: float = Field(0.1, gt=0.0, le=3600.0)
    frames: int = Field(1, ge=1, le=1000)
    bus: str | None = None
    #: What a serial detector is: one value per frame, or one per wavelength band.
    kind: Literal["power_meter", "spectrometer"] = "power_meter"
    #: Instrument profile (serial detectors): a shipped profile's name (acknowledging, thorlabs-pm100)
    #: or a path to a TOML profile.
    profile: str = "acknowledging"
    #: The wavelength (nm) a power meter takes its sensor's responsivity at (profiles that set it); None
    #: leaves the meter's own setting (which a power cycle resets).
    wavelength_nm: float | None = Field(None, ge=100.0, le=20000.0)
    sim: DetectorSimConfig = DetectorSimConfig()

    @model_validator(mode="after")
    def _check(self):
        if not self.channels or len(set(self.channels)) != len(self.channels):
            raise ValueError(f"channels: must be distinct names, at least one, got {list(self.channels)}")
        _check_bus_use("detector", self.driver, self.bus, _changed(self),
                       {"kind", "profile", "wavelength_nm"})
        if self.driver == "serial":
            profile, meter = _instrument_profile(self.profile, self.kind)
            if "wavelength_nm" not in meter.fields and self.wavelength_nm is not None:
                raise ValueError(f"wavelength_nm: profile {profile.source} sets no wavelength")
        if self.driver == "serial" and self.kind == "power_meter" and len(self.channels) != 1:
            raise ValueError(f"channels: a power meter reads one value, so exactly one channel name, got "
                             f"{list(self.channels)}")
        if self.driver == "sim" and self.sim.kind == "spectrometer" and "channels" in self.model_fields_set:
            raise ValueError("channels: a simulated spectrometer names its bands itself (e.g. 380nm, 390nm, "
                             "...); leave channels out and set [detector.sim.spectrometer] instead")
        if self.driver == "sim" and self.sim.kind == "camera" and self.frames > 32:
            raise ValueError(f"frames: the simulated camera averages at most 32 frames a reading, got "
                             f"{self.frames}")
        if self.driver != "sim" and self.sim.kind != "photodiode":
            raise ValueError(f"sim.kind: '{self.sim.kind}' is a simulated detector; driver '{self.driver}' "
                             f"reads a real one (leave sim.kind out)")
        return self

    @property
    def channel_names(self) -> tuple[str, ...]:
        """The channels a reading has: one per band (``380nm``, ...) for a simulated spectrometer."""
        if self.driver == "sim" and self.sim.kind == "spectrometer":
            return tuple(f"{w:g}nm" for w in self.sim.spectrometer.wavelengths_nm())
        return tuple(self.channels)

    @property
    def wavelengths_nm(self) -> tuple[float, ...] | None:
        """Centre wavelength (nm) of each channel for a simulated spectrometer, else None."""
        if self.driver == "sim" and self.sim.kind == "spectrometer":
            return tuple(self.sim.spectrometer.wavelengths_nm())
        return None

    def descriptor(self) -> dict:
        """What a reading is (:func:`gonio.store.detector_descriptor`), for the campaign's journal."""
        from gonio.store import detector_descriptor

        kind = self.sim.kind if self.driver == "sim" else self.kind
        return detector_descriptor(kind, self.channel_names, self.wavelengths_nm)


def _check_bus_use(device: str, driver: str, bus, fields_set, serial_only: set[str]) -> None:
    if driver == "sim":
        foreign = sorted(({"bus"} | serial_only) & set(fields_set))
        if foreign:
            raise ValueError(f"{', '.join(foreign)}: not a setting of a 'sim' {device}")
    elif bus is None:
        raise ValueError(f"bus: a '{driver}' {device} names the [buses.NAME] section it is on")


# -- the rest -------------------------------------------------------------------------------------------
class ReflectanceTable(_Strict):
    """A spectral reflectance: ``reflectance`` at ``wavelength_nm`` (ascending), linear in between."""

    wavelength_nm: tuple[float, ...]
    reflectance: tuple[float, ...]

    @model_validator(mode="after")
    def _check(self):
        wl, rho = self.wavelength_nm, self.reflectance
        if len(wl) < 2 or len(wl) != len(rho):
            raise ValueError(f"wavelength_nm, reflectance: two lists of equal length >= 2, got {len(wl)} "
                             f"and {len(rho)}")
        if any(b <= a for a, b in zip(wl, wl[1:], strict=False)):
            raise ValueError("wavelength_nm: must be strictly ascending")
        if any(not 0.0 < r <= 1.0 for r in rho):
            raise ValueError(f"reflectance: each value in (0, 1], got {list(rho)}")
        return self

    def at(self, wavelength_nm):
        import numpy as np

        wl = np.asarray(wavelength_nm, dtype=float)
        lo, hi = self.wavelength_nm[0], self.wavelength_nm[-1]
        if wl.size and (wl.min() < lo or wl.max() > hi):
            raise ValueError(f"reference.spectrum: the table covers [{lo:g}, {hi:g}] nm, the detector's "
                             f"bands [{wl.min():g}, {wl.max():g}] nm")
        return np.interp(wl, self.wavelength_nm, self.reflectance)


#: Poses between checkpoints when the config schedules them neither by count nor by time.
DEFAULT_EVERY = 50


class ReferenceConfig(_Strict):
    #: Hemispherical reflectance of the white standard (a Lambertian, e.g. sintered PTFE).
    albedo: float = Field(0.99, gt=0.0, le=1.0)
    #: Instead of ``albedo``: the standard's reflectance per detector channel (one value each).
    reflectance: tuple[float, ...] | None = None
    #: Instead of ``albedo``: its spectral reflectance (a spectrometer reads it at its bands; an RGB
    #: detector at the table's linear sRGB under D65, gonio.colour).
    spectrum: ReflectanceTable | None = None
    #: The standard's own angular response where it is read (θi_ref, θo_ref, Δφ_ref below): its f_r
    #: there over ρ/π, e.g. the 0°/45° reflectance factor of its certificate; 1 for an ideal diffuser.
    response: float = Field(1.0, ge=0.8, le=1.2)
    #: A dark and a white-reference reading every this many poses (and at the start and end). Left out,
    #: it is 50 when ``every_s`` is left out too, and no count limit when ``every_s`` is given.
    every: int | None = Field(None, ge=1)
    #: One at least this often in gantry time (s) between reference readings (as well as ``every``
    #: when both are given); None: by count only.
    every_s: float | None = Field(None, gt=0.0, le=86400.0)
    theta_i_deg: float = Field(0.0, ge=0.0, lt=90.0)
    theta_o_deg: float = Field(45.0, ge=0.0, lt=90.0)
    dphi_deg: float = Field(180.0, ge=0.0, lt=360.0)

    @model_validator(mode="before")
    @classmethod
    def _default_count(cls, data):
        if isinstance(data, dict) and data.get("every") is None and data.get("every_s") is None:
            data = {**data, "every": DEFAULT_EVERY}
        return data

    @model_validator(mode="after")
    def _check_reflectance(self):
        if self.reflectance is not None and self.spectrum is not None:
            raise ValueError("reflectance, spectrum: give one of them (or albedo alone), not both")
        if self.reflectance is not None and any(not 0.0 < r <= 1.0 for r in self.reflectance):
            raise ValueError(f"reflectance: each value in (0, 1], got {list(self.reflectance)}")
        return self

    def poses_per_run(self, n_poses: int) -> int:
        """At most this many poses between two checkpoints by count (``n_poses`` when only the time
        limit ``every_s`` schedules them), >= 1."""
        if self.every is not None:
            return int(self.every)
        return DEFAULT_EVERY if self.every_s is None else max(int(n_poses), 1)

    def reference_fr(self, channels, wavelengths_nm=None):
        """ρ_ref · response per channel: π times the standard's f_r at the angles it is read at."""
        return self.reflectance_for(channels, wavelengths_nm) * self.response

    def reflectance_for(self, channels, wavelengths_nm=None):
        """The standard's reflectance per channel, (C,) float: ``reflectance``, the ``spectrum`` at the
        bands (or as linear sRGB for R, G, B), or ``albedo`` for every channel. ValueError if they do
        not fit the detector's channels."""
        import numpy as np

        channels = tuple(channels)
        if self.reflectance is not None:
            if len(self.reflectance) != len(channels):
                raise ValueError(f"reference.reflectance: {len(self.reflectance)} values for the detector's "
                                 f"{len(channels)} channels ({', '.join(channels[:4])}"
                                 f"{', ...' if len(channels) > 4 else ''})")
            return np.asarray(self.reflectance, dtype=float)
        if self.spectrum is not None:
            if wavelengths_nm is not None:
                return self.spectrum.at(wavelengths_nm)
            if channels == ("R", "G", "B"):
                from gonio.colour import WAVELENGTH_NM, spectral_to_rgb

                return spectral_to_rgb(self.spectrum.at(WAVELENGTH_NM))
            raise ValueError(f"reference.spectrum: the detector's channels ({', '.join(channels)}) have no "
                             "wavelengths; give reference.reflectance per channel instead")
        return np.full(len(channels), self.albedo)


class TargetConfig(_Strict):
    """How the white standard gets under the beam (``gantry.set_target``).

    With ``axis`` (an extra axis in ``[axes]``, e.g. a sample changer), ``set_target("reference")``
    moves that axis to ``reference_deg`` and ``set_target("sample")`` to ``sample_deg``, and waits until
    it is there. Without it only a simulated detector can swap the two (it renders the standard); a real
    detector needs the axis: a campaign never waits for a person to swap them.
    """

    axis: str | None = None
    sample_deg: float = 0.0
    reference_deg: float = 0.0
    #: Longest wait (s) for the changer to arrive.
    timeout_s: float = Field(60.0, gt=0.0, le=3600.0)


class RunnerConfig(_Strict):
    retries: int = Field(2, ge=0, le=20)
    position_tolerance_deg: float = Field(0.05, gt=0.0, le=5.0)
    settle_s: float = Field(0.2, ge=0.0, le=600.0)
    move_timeout_s: float = Field(120.0, gt=0.0)
    poll_s: float = Field(0.05, gt=0.0, le=10.0)


#: Which bus driver each device driver needs.
_BUS_FOR = {"dynamixel": "dynamixel", "modbus": "modbus", "serial": "serial"}


class GonioConfig(_Strict):
    name: str
    kinematics: KinematicsConfig
    buses: dict[str, BusConfig] = {}
    axes: dict[str, AxisConfig]
    light: LightConfig = LightConfig()
    detector: DetectorConfig = DetectorConfig()
    reference: ReferenceConfig = ReferenceConfig()
    target: TargetConfig = TargetConfig()
    runner: RunnerConfig = RunnerConfig()

    @model_validator(mode="after")
    def _axes_match_design(self):
        want = design_axes(self.kinematics.design)
        missing = [a for a in want if a not in self.axes]
        extra = [a for a in self.axes if a not in want and a != self.target.axis]
        if missing or extra:
            raise ValueError(
                f"design '{self.kinematics.design}' drives exactly the axes {', '.join(want)} (plus the "
                "target.axis, if any)"
                + (f"; missing: {', '.join(missing)}" if missing else "")
                + (f"; unknown: {', '.join(extra)}" if extra else "")
            )
        if self.target.axis is not None:
            if self.target.axis in want:
                raise ValueError(f"target.axis: '{self.target.axis}' is one of the design's axes; the "
                                 "sample changer is an axis of its own")
            if self.target.axis not in self.axes:
                raise ValueError(f"target.axis: no [axes.{self.target.axis}] section")
            ax = self.axes[self.target.axis]
            for key in ("sample_deg", "reference_deg"):
                v = getattr(self.target, key)
                if not ax.min_deg <= v <= ax.max_deg:
                    raise ValueError(f"target.{key}: {v} is outside the axis limit [{ax.min_deg}, "
                                     f"{ax.max_deg}]")
        elif self.detector.driver != "sim":
            raise ValueError("target.axis: a real detector needs an axis that puts the white standard "
                             "under the beam (a sample changer); only a simulated detector swaps by itself")
        users = [(f"axes.{n}", a.driver, a.bus) for n, a in self.axes.items()]
        users += [("light", self.light.driver, self.light.bus), ("detector", self.detector.driver,
                                                                  self.detector.bus)]
        for where, driver, bus in users:
            if driver == "sim":
                continue
            if bus not in self.buses:
                raise ValueError(f"{where}.bus: no [buses.{bus}] section; buses: "
                                 f"{', '.join(self.buses) or 'none'}")
            if self.buses[bus].driver != _BUS_FOR[driver]:
                raise ValueError(f"{where}.bus: a '{driver}' device cannot be on bus '{bus}', a "
                                 f"'{self.buses[bus].driver}' bus")
        ids: dict[tuple[str, int], str] = {}
        for n, a in self.axes.items():
            if a.driver == "sim":
                continue
            key = (a.bus, a.id if a.driver == "dynamixel" else a.device_id)
            if key in ids:
                raise ValueError(f"axes.{n}: bus '{key[0]}' id {key[1]} is also axes.{ids[key]}")
            ids[key] = n
        for bus in self.buses:
            on = [w for w, d, b in users if b == bus and d == "serial"]
            if len(on) > 1:
                raise ValueError(f"buses.{bus}: one serial instrument per port, but {', '.join(on)} share it")
        for n, a in self.axes.items():
            # The runner reads the moving servos every watchdog_s / 2, checked between poll_s slices.
            if a.driver == "dynamixel" and 0 < a.watchdog_s < 4 * self.runner.poll_s:
                raise ValueError(f"axes.{n}.watchdog_s: {a.watchdog_s} is below 4 x runner.poll_s "
                                 f"({4 * self.runner.poll_s:g} s); allowed: 0 (off) or "
                                 f"[{4 * self.runner.poll_s:g}, 2.54] s")
        return self

    @model_validator(mode="after")
    def _reference_fits_the_detector(self):
        fr = self.reference.reference_fr(self.detector.channel_names, self.detector.wavelengths_nm)
        if self.detector.driver == "sim" and fr.max() > 1.0:
            raise ValueError(f"reference.response: the simulated standard would reflect reflectance x "
                             f"response = {float(fr.max()):g} > 1 of the light it receives")
        return self

    @property
    def axis_names(self) -> tuple[str, ...]:
        return design_axes(self.kinematics.design)

    def drivers(self) -> set[str]:
        """The device drivers this config uses."""
        return {a.driver for a in self.axes.values()} | {self.light.driver, self.detector.driver}


def relocate(snapshot: GonioConfig, now: GonioConfig) -> GonioConfig:
    """``snapshot`` with each bus reached where ``now`` says (its ``port``/``url``): a campaign planned
    with one config resumes when a device was re-plugged under another name, or an emulator restarted
    on another pty. Buses absent from ``now`` keep the snapshot's location."""
    data = snapshot.model_dump(mode="json")
    for name, bus in data.get("buses", {}).items():
        if name in now.buses:
            theirs = now.buses[name].model_dump(mode="json")
            for key in BUS_LOCATION_FIELDS:
                if key in bus and key in theirs:
                    bus[key] = theirs[key]
    return GonioConfig.model_validate(data)


def with_sim_detector(cfg: GonioConfig, kind: str, **settings) -> GonioConfig:
    """``cfg`` with its simulated detector made a ``kind`` of :data:`SIM_DETECTOR_KINDS` (``gonio simulate
    --detector``); ConfigError for another kind or a real detector. ``settings`` replace sub-tables of
    ``[detector.sim]`` (e.g. ``camera={"saturation": 0.02}``)."""
    if kind not in SIM_DETECTOR_KINDS:
        raise ConfigError(f"--detector: '{kind}' is not one of {', '.join(SIM_DETECTOR_KINDS)}")
    if cfg.detector.driver != "sim":
        raise ConfigError(f"--detector: the detector of config '{cfg.name}' is a real one (driver "
                          f"'{cfg.detector.driver}'); --detector chooses a simulated detector")
    if cfg.detector.sim.kind == kind and not settings:
        return cfg
    data = cfg.model_dump(mode="python", exclude_unset=True)
    detector = data.setdefault("detector", {})
    detector.setdefault("sim", {}).update(settings, kind=kind)
    if kind == "spectrometer":
        detector.pop("channels", None)
    return parse_config(data, f"config '{cfg.name}' with --detector {kind}")


def _format(err: ValidationError, source: str) -> str:
    lines = []
    for e in err.errors():
        loc = ".".join(str(p) for p in e["loc"])
        msg = e["msg"].removeprefix("Value error, ")
        if e["type"] == "extra_forbidden":
            msg = "unknown key"
        lines.append(f"{source}: {loc}: {msg}" if loc else f"{source}: {msg}")
    return "\n".join(lines)


def parse_config(data: dict, source: str = "<config>") -> GonioConfig:
    try:
        return GonioConfig.model_validate(data)
    except ValidationError as err:
        raise ConfigError(_format(err, source)) from None


def packaged_configs() -> dict[str, Path]:
    """The configs shipped with gonio: name (file name without ``.toml``) -> path."""
    return {p.stem: p for p in sorted(CONFIG_DIR.glob("*.toml"))}


def resolve_config(path_or_name: str | Path | None = None) -> Path:
    """The config file meant by a path, or by the name of a shipped config (``sample-stage``)."""
    if path_or_name is None:
        return DEFAULT_CONFIG
    path = Path(path_or_name)
    if path.is_file() or path.suffix == ".toml" or len(path.parts) > 1:
        return path
    shipped = packaged_configs()
    if str(path_or_name) in shipped:
        return shipped[str(path_or_name)]
    raise ConfigError(f"--config: '{path_or_name}' is neither a file nor a shipped config; shipped: "
                      f"{', '.join(shipped)}")


def load_config(path: str | Path | None = None) -> GonioConfig:
    """Read and validate a gantry config: a file, the name of a shipped config, or (None) the simulated
    two-arm gantry."""
    path = resolve_config(path)
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such config file") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a folder, not a config file") from None
    except PermissionError:
        raise ConfigError(f"{path}: permission denied") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a text file") from None
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML: {err}") from None
    return parse_config(data, str(path))
