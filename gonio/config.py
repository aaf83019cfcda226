"""Gantry configuration: TOML in, validated pydantic models out.

Every key is checked: an unknown key, a missing one or a value out of range is a :class:`ConfigError`
that names the file, the field and what is allowed. Nothing is clamped.

Each axis, the light and the detector name their ``driver`` (``sim``, ``dynamixel``, ``modbus``,
``serial``, or a plugin's: the driver registries of :mod:`gonio.registries`), and the driver's own config
model (:mod:`gonio.device_config`, kept with the driver) validates the section; a real device names the
``[buses.NAME]`` section it is reached through, where its port (or ``url``) is written once for every
device on that bus. Settings that only a simulator (or the
emulator of a device) needs live in the device's ``sim`` sub-table (``[light.sim]``,
``[detector.sim]``, ``[axes.NAME.sim]``); the real drivers ignore them. ``[target]`` says how the white
standard gets under the beam (see :class:`TargetConfig`).
"""

from __future__ import annotations

import tomllib
from importlib.resources import files
from pathlib import Path
from typing import Annotated, Literal, Union

from pydantic import (
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    ValidationError,
    create_model,
    field_validator,
    model_validator,
)

from gonio.device_config import (
    AxisConfig,
    AxisSimConfig,
    BusConfig,
    DetectorConfig,
    DeviceConfig,
    LightConfig,
    Strict,
    driver_name,
)
from gonio.files import NamedFileError, read_named_file
from gonio.registries import AXIS_DRIVERS, BUS_DRIVERS, DETECTOR_DRIVERS, LIGHT_DRIVERS, SIM_DETECTORS
from gonio.registry import PluginError

__all__ = ["ConfigError", "GonioConfig", "load_config", "DEFAULT_CONFIG", "design_axes", "CONFIG_DIR",
           "AxisConfig", "AxisSimConfig", "BusConfig", "DetectorConfig", "LightConfig",
           "packaged_configs", "resolve_config", "relocate",
           "BUS_LOCATION_FIELDS"]

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


class KinematicsConfig(Strict):
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


def _driver_union(registry, default: str | None):
    """The union of the models of ``registry``'s drivers, chosen by the section's ``driver`` (``default``
    where it names none). A driver no model has fails on ``driver`` naming the allowed ones."""
    names = registry.names()
    members = []
    for name in names:
        model = registry.load(name)
        if driver_name(model) != name:
            raise PluginError(f"{registry.kind} '{name}': its config model {model.__name__} takes driver = "
                              f"{driver_name(model)!r}, not {name!r}")
        members.append(Annotated[model, Tag(name)])
    unknown = create_model(f"Unknown{registry.kind.title().replace(' ', '')}",
                           __config__=ConfigDict(extra="allow"), driver=(Literal[names], ...))
    members.append(Annotated[unknown, Tag(_UNKNOWN)])

    def tag(value):
        driver = value.get("driver", default) if isinstance(value, dict) else getattr(value, "driver", None)
        return driver if isinstance(driver, str) and driver in names else _UNKNOWN

    return Annotated[Union[tuple(members)], Discriminator(tag)]  # noqa: UP007 (a tuple of members)


_UNKNOWN = "?"
#: Every ``[buses.NAME]``, ``[axes.NAME]``, ``[light]`` and ``[detector]`` section is validated by the model
#: of the driver it names (the driver registries of :mod:`gonio.registries`, plugins included): one
#: discriminated union per kind of section, a section that names no driver being ``sim``.
AnyBus = _driver_union(BUS_DRIVERS, None)
AnyAxis = _driver_union(AXIS_DRIVERS, "sim")
AnyLight = _driver_union(LIGHT_DRIVERS, "sim")
AnyDetector = _driver_union(DETECTOR_DRIVERS, "sim")
#: Bus fields that say where a bus is reached (the only ones an emulated twin changes).
BUS_LOCATION_FIELDS = ("port", "url")


# -- the rest -------------------------------------------------------------------------------------------
class ReflectanceTable(Strict):
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


class ReferenceConfig(Strict):
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


class TargetConfig(Strict):
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


class RunnerConfig(Strict):
    retries: int = Field(2, ge=0, le=20)
    position_tolerance_deg: float = Field(0.05, gt=0.0, le=5.0)
    settle_s: float = Field(0.2, ge=0.0, le=600.0)
    move_timeout_s: float = Field(120.0, gt=0.0)
    poll_s: float = Field(0.05, gt=0.0, le=10.0)


class GonioConfig(Strict):
    #: Printed at the head of plans and campaigns, journaled, served by the daemon: no control characters
    #: (an escape sequence or a line break would rewrite what a terminal shows).
    name: str
    kinematics: KinematicsConfig
    buses: dict[str, AnyBus] = {}
    axes: dict[str, AnyAxis]
    light: AnyLight = LIGHT_DRIVERS.load("sim")()
    detector: AnyDetector = DETECTOR_DRIVERS.load("sim")()
    reference: ReferenceConfig = ReferenceConfig()
    target: TargetConfig = TargetConfig()
    runner: RunnerConfig = RunnerConfig()

    @field_validator("name")
    @classmethod
    def _printable_name(cls, name: str) -> str:
        """Printed at the head of plans and campaigns, journaled and served by the daemon: an escape
        sequence or a line break in it would rewrite what a terminal shows."""
        if not 1 <= len(name) <= 120 or any(ord(c) < 0x20 or ord(c) == 0x7f for c in name):
            raise ValueError("must be 1 to 120 printable characters (no control characters: escape "
                             "sequences, tabs, line breaks)")
        return name

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
        elif not self.detector.simulated:
            raise ValueError("target.axis: a real detector needs an axis that puts the white standard "
                             "under the beam (a sample changer); only a simulated detector swaps by itself")
        return self

    @model_validator(mode="after")
    def _devices_fit_their_buses(self):
        devices = self.devices()
        on_bus = [(where, d) for where, d in devices.items() if d.bus_driver is not None]
        for where, d in on_bus:
            if d.bus not in self.buses:
                raise ValueError(f"{where}.bus: no [buses.{d.bus}] section; buses: "
                                 f"{', '.join(self.buses) or 'none'}")
            if self.buses[d.bus].driver != d.bus_driver:
                raise ValueError(f"{where}.bus: a '{d.driver}' device cannot be on bus '{d.bus}', a "
                                 f"'{self.buses[d.bus].driver}' bus")
        ids: dict[tuple[str, int], str] = {}
        for where, d in on_bus:
            key = (d.bus, d.bus_address())
            if key[1] is None:
                continue
            if key in ids:
                raise ValueError(f"{where}: bus '{key[0]}' id {key[1]} is also {ids[key]}")
            ids[key] = where
        for name, bus in self.buses.items():
            on = [where for where, d in on_bus if d.bus == name]
            if bus.one_device and len(on) > 1:
                raise ValueError(f"buses.{name}: one {bus.driver} instrument per port, but {', '.join(on)} "
                                 "share it")
        for where, d in devices.items():
            d.check_in(self, where)
        return self

    @model_validator(mode="after")
    def _reference_fits_the_detector(self):
        fr = self.reference.reference_fr(self.detector.channel_names, self.detector.wavelengths_nm)
        if self.detector.simulated and fr.max() > 1.0:
            raise ValueError(f"reference.response: the simulated standard would reflect reflectance x "
                             f"response = {float(fr.max()):g} > 1 of the light it receives")
        return self

    @property
    def axis_names(self) -> tuple[str, ...]:
        return design_axes(self.kinematics.design)

    def devices(self) -> dict[str, DeviceConfig]:
        """Every device section by where it is (``axes.NAME``, ``light``, ``detector``)."""
        return {**{f"axes.{n}": a for n, a in self.axes.items()}, "light": self.light,
                "detector": self.detector}

    def drivers(self) -> set[str]:
        """The device drivers this config uses."""
        return {d.driver for d in self.devices().values()}

    @property
    def simulated(self) -> bool:
        """Every device is simulated (the simulated gantry: :class:`gonio.sim.gantry.SimGantry`)."""
        return all(d.simulated for d in self.devices().values())


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
    """``cfg`` with its simulated detector made a ``kind`` of :data:`gonio.registries.SIM_DETECTORS`
    (``gonio simulate --detector``); ConfigError for another kind or a real detector. ``settings`` replace
    sub-tables of ``[detector.sim]`` (e.g. ``camera={"saturation": 0.02}``)."""
    if kind not in SIM_DETECTORS:
        raise ConfigError(f"--detector: '{kind}' is not one of {', '.join(SIM_DETECTORS.names())}")
    if not cfg.detector.simulated:
        raise ConfigError(f"--detector: the detector of config '{cfg.name}' is a real one (driver "
                          f"'{cfg.detector.driver}'); --detector chooses a simulated detector")
    if cfg.detector.sim.kind == kind and not settings:
        return cfg
    data = cfg.model_dump(mode="python", exclude_unset=True)
    detector = data.setdefault("detector", {})
    detector.setdefault("sim", {}).update(settings, kind=kind)
    if SIM_DETECTORS.load(kind).channels is not None:  # the kind names its channels itself
        detector.pop("channels", None)
    return parse_config(data, f"config '{cfg.name}' with --detector {kind}")


def _format(err: ValidationError, source: str) -> str:
    lines = []
    for e in err.errors():
        loc = list(e["loc"])
        # A device section's errors carry the driver tag of its union after the section (axes.NAME.TAG.x,
        # light.TAG.x): the section's own driver setting says it already.
        at = {"buses": 2, "axes": 2, "light": 1, "detector": 1}.get(loc[0] if loc else None)
        if at is not None and len(loc) > at:
            del loc[at]
        loc = ".".join(str(p) for p in loc)
        msg = e["msg"].removeprefix("Value error, ")
        if e["type"] == "extra_forbidden":
            msg = "unknown key"
        lines.append(f"{loc}: {msg}" if loc else msg)
    return f"{source}: {'; '.join(lines)}"   # one line, every field named


def parse_config(data: dict, source: str = "<config>") -> GonioConfig:
    try:
        return GonioConfig.model_validate(data)
    except ValidationError as err:
        raise ConfigError(_format(err, source)) from None


def packaged_configs() -> dict[str, Path]:
    """The configs shipped with gonio: name (file name without ``.toml``) -> path."""
    return {p.stem: p for p in sorted(CONFIG_DIR.glob("*.toml"))}


#: The largest config file read (the shipped ones are 1-10 kB): a name that points at a device or at
#: some other huge file is refused, not read.
CONFIG_MAX_BYTES = 1 << 20


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
        data = tomllib.loads(read_named_file(path, CONFIG_MAX_BYTES, "config file").decode("utf-8"))
    except NamedFileError as err:
        raise ConfigError(f"{path}: {err}") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a text file") from None
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML: {err}") from None
    return parse_config(data, str(path))
