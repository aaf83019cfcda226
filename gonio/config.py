"""Gantry configuration: TOML in, validated pydantic models out.

Every key is checked: an unknown key, a missing one or a value out of range is a :class:`ConfigError`
that names the file, the field and what is allowed. Nothing is clamped.
"""

from __future__ import annotations

import tomllib
from importlib.resources import files
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

__all__ = ["ConfigError", "GonioConfig", "load_config", "DEFAULT_CONFIG", "DESIGN_AXES", "CONFIG_DIR",
           "packaged_configs", "resolve_config"]

#: The configs shipped inside the installed package (``config/`` in the source tree).
CONFIG_DIR = Path(str(files("gonio.configs")))
DEFAULT_CONFIG = CONFIG_DIR / "sim.toml"

#: The axes each kinematic design drives, in the order of axis arrays everywhere (columns of (N, 4)).
DESIGN_AXES: dict[str, tuple[str, ...]] = {
    "two-arm": ("light_azimuth", "light_tilt", "detector_azimuth", "detector_tilt"),
    "sample-stage": ("sample_rotation", "sample_tilt", "detector_azimuth", "detector_tilt"),
}


class ConfigError(ValueError):
    pass


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class KinematicsConfig(_Strict):
    design: Literal["two-arm", "sample-stage"]
    theta_max_deg: float = Field(80.0, gt=0.0, le=90.0)
    #: The light arm hides the detector when ωi and ωo are closer than this.
    clearance_deg: float = Field(5.0, ge=0.0, lt=90.0)
    #: Two parts of the gantry closer than this collide (design-specific; see gonio.kinematics).
    arm_collision_deg: float = Field(10.0, ge=0.0, lt=180.0)


class AxisConfig(_Strict):
    driver: Literal["sim"] = "sim"
    min_deg: float
    max_deg: float
    max_velocity_deg_s: float = Field(gt=0.0)
    max_accel_deg_s2: float = Field(gt=0.0)
    home_deg: float = 0.0
    #: Encoder resolution: the simulated axis settles on a multiple of it (0: exact).
    resolution_deg: float = Field(0.0, ge=0.0, le=1.0)

    @model_validator(mode="after")
    def _check(self):
        if not self.min_deg < self.max_deg:
            raise ValueError(f"min_deg ({self.min_deg}) must be less than max_deg ({self.max_deg})")
        if not self.min_deg <= self.home_deg <= self.max_deg:
            raise ValueError(f"home_deg {self.home_deg} is outside [{self.min_deg}, {self.max_deg}]")
        return self


class LightConfig(_Strict):
    driver: Literal["sim"] = "sim"
    #: Radiance of the source (arbitrary but consistent units; the white reference calibrates it out).
    radiance: float = Field(1000.0, gt=0.0)
    #: Half-angle of the cone the source subtends, seen from the sample.
    half_angle_deg: float = Field(0.5, gt=0.0, le=10.0)
    #: Relative change of radiance per hour of (virtual) time: what the periodic white reference tracks.
    drift_per_hour: float = Field(0.0, ge=-0.5, le=0.5)


class NoiseConfig(_Strict):
    #: Counts per unit of signal for shot noise (0 disables it).
    shot_counts_per_unit: float = Field(0.0, ge=0.0)
    read_sigma: float = Field(0.0, ge=0.0)
    dark_offset: float = Field(0.0, ge=0.0)


class DetectorConfig(_Strict):
    driver: Literal["sim"] = "sim"
    channels: tuple[str, ...] = ("R", "G", "B")
    half_angle_deg: float = Field(1.0, gt=0.0, le=10.0)
    exposure_s: float = Field(0.1, gt=0.0, le=3600.0)
    frames: int = Field(1, ge=1, le=1000)
    #: Monte Carlo samples per reading over the source and detector apertures.
    aperture_samples: int = Field(256, ge=1, le=1 << 20)
    noise: NoiseConfig = NoiseConfig()


class ReferenceConfig(_Strict):
    #: Hemispherical reflectance of the white standard (a Lambertian, e.g. sintered PTFE).
    albedo: float = Field(0.99, gt=0.0, le=1.0)
    #: A dark and a white-reference reading every this many poses (and at the start and end).
    every: int = Field(50, ge=1)
    theta_i_deg: float = Field(0.0, ge=0.0, lt=90.0)
    theta_o_deg: float = Field(45.0, ge=0.0, lt=90.0)
    dphi_deg: float = Field(180.0, ge=0.0, lt=360.0)


class RunnerConfig(_Strict):
    retries: int = Field(2, ge=0, le=20)
    position_tolerance_deg: float = Field(0.05, gt=0.0, le=5.0)
    settle_s: float = Field(0.2, ge=0.0, le=600.0)
    move_timeout_s: float = Field(120.0, gt=0.0)
    poll_s: float = Field(0.05, gt=0.0, le=10.0)


class GonioConfig(_Strict):
    name: str
    kinematics: KinematicsConfig
    axes: dict[str, AxisConfig]
    light: LightConfig = LightConfig()
    detector: DetectorConfig = DetectorConfig()
    reference: ReferenceConfig = ReferenceConfig()
    runner: RunnerConfig = RunnerConfig()

    @model_validator(mode="after")
    def _axes_match_design(self):
        want = DESIGN_AXES[self.kinematics.design]
        missing = [a for a in want if a not in self.axes]
        extra = [a for a in self.axes if a not in want]
        if missing or extra:
            raise ValueError(
                f"design '{self.kinematics.design}' drives exactly the axes {', '.join(want)}"
                + (f"; missing: {', '.join(missing)}" if missing else "")
                + (f"; unknown: {', '.join(extra)}" if extra else "")
            )
        return self

    @property
    def axis_names(self) -> tuple[str, ...]:
        return DESIGN_AXES[self.kinematics.design]


def _format(err: ValidationError, source: str) -> str:
    lines = []
    for e in err.errors():
        loc = ".".join(str(p) for p in e["loc"]) or "(top level)"
        msg = e["msg"].removeprefix("Value error, ")
        if e["type"] == "extra_forbidden":
            msg = "unknown key"
        lines.append(f"{source}: {loc}: {msg}")
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
    if path.exists() or path.suffix == ".toml" or len(path.parts) > 1:
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
