"""Request and reply bodies of the daemon's API (pydantic; they make the OpenAPI document)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from gonio import SEED_MAX

__all__ = ["CampaignRequest", "DetectorOptions", "MoveRequest", "CampaignStatus", "CampaignList",
           "GantryStatus", "Health", "Accepted"]

_NAME = r"^[\x20-\x7e]*$"   # printable ASCII: names end up in logs and file metadata


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class DetectorOptions(_Strict):
    """Per-campaign detector settings (the config's are the defaults)."""

    exposure_s: float | None = Field(None, gt=0.0, le=3600.0, description="exposure per frame (s)")
    frames: int | None = Field(None, ge=1, le=1000, description="frames averaged per reading")


class CampaignRequest(_Strict):
    """A campaign: ``material`` on a simulated detector, ``sample`` (its name) on a real one."""

    material: str | None = Field(None, max_length=400, pattern=_NAME,
                                 examples=["ggx:alpha=0.2,metal=gold"], description="MATERIAL (simulated)")
    sample: str | None = Field(None, min_length=1, max_length=200, pattern=_NAME,
                               description="name of the sample measured (real detector)")
    grid: str = Field(max_length=200, pattern=_NAME, examples=["iso:step=15"], description="GRID")
    seed: int = Field(0, ge=0, le=SEED_MAX, description="seed of the simulated devices' random numbers")
    detector: DetectorOptions | None = None


class MoveRequest(_Strict):
    """Arm angles of a manual move (degrees)."""

    theta_i_deg: float = Field(ge=0.0, le=90.0)
    phi_i_deg: float = Field(ge=-360.0, le=360.0)
    theta_o_deg: float = Field(ge=0.0, le=90.0)
    phi_o_deg: float = Field(ge=-360.0, le=360.0)


class CampaignStatus(BaseModel):
    id: str
    state: str
    seq: int
    submitted_unix: float
    grid: str
    material: str | None
    sample: str | None
    seed: int
    poses: int
    gantry: str
    channels: list[str]
    steps: int
    steps_done: int
    progress: float
    campaign_s: float
    eta_gantry_s: float
    eta_wall_s: float | None
    last_update_unix: float | None
    latched_fault: str | None
    last_fault: str | None
    error: str | None
    brdf: bool
    ended_short: str | None = None   # why an adaptive campaign ended short of its budget


class CampaignList(BaseModel):
    running: str | None
    halted: bool = False
    campaigns: list[CampaignStatus]


class GantryStatus(BaseModel):
    gantry: str
    owner: str | None
    axes: list[dict]
    angles: dict[str, float]
    moving: bool
    faults: list[str]
    #: Axes whose position is unknown until `gonio gantry reference` (moves are refused meanwhile).
    unreferenced: list[str] = []
    light: dict
    detector: dict


class Health(BaseModel):
    status: str
    version: str
    gantry: str
    running: str | None
    queued: int
    auth: bool


class Accepted(BaseModel):
    id: str | None
    state: str
    message: str
