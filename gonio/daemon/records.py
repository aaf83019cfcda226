"""A campaign as the daemon keeps it: ``daemon.json`` beside the journal, and the checks a request passes.

``daemon.json`` holds the request a campaign was submitted with, its place in the queue (``seq``), the
operator's intent (``run`` or ``hold``) and, after a fault the runner could not journal (a full disk),
its reason; it is replaced atomically. A request is checked in two stages, each error naming its field:
:func:`precheck_request` from the request alone in the daemon's process (the grid's pose count from its
parameters, a measured material's name), then :func:`prepare_campaign` in the planner's process
(:mod:`gonio.daemon.planner`): the material and every detail against the gantry, the plan, the journal.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # type hints only: the caller holds the config
    from gonio.config import GonioConfig

__all__ = ["Record", "FieldError", "Conflict", "NotFound", "DiskFull", "validate_request", "precheck_request",
           "prepare_campaign", "ID_PATTERN", "RECORD_NAME", "MAX_STEPS"]

RECORD_NAME = "daemon.json"
ID_PATTERN = r"^c[0-9]{5}$"
#: A plan longer than this is refused through the API (a typo such as step=0.01 would journal millions).
MAX_STEPS = 500_000


class FieldError(ValueError):
    """A request field that is wrong: ``field`` names it (``grid``, ``detector.exposure_s``)."""

    def __init__(self, field: str, message: str):
        super().__init__(message)
        self.field = field


class Conflict(RuntimeError):
    """The request is valid but the campaign's (or the gantry's) state does not allow it now."""


class NotFound(LookupError):
    pass


class DiskFull(OSError):
    """The data folder's disk is full (or the quota spent): nothing was written (507)."""


@dataclass
class Record:
    """What the daemon keeps beside a campaign's journal (``daemon.json``) and a few live flags."""

    id: str
    seq: int
    folder: Path
    request: dict
    submitted_unix: float
    intent: str = "run"                 # run | hold
    clear_fault: bool = False           # the operator's resume clears the latched fault
    halt_pending: bool = False          # a halt that came before the runner was running
    abort_pending: bool = False         # an abort that came before the runner was running
    error: str | None = None            # why the daemon could not run it (not a runner fault)
    unclean: str | None = None          # a fault the runner could not journal, journaled at the next start
    static: dict = field(default_factory=dict)   # meta that never changes (grid, poses, steps, ...)
    final: str | None = None            # done or aborted, once seen: never changes again
    live: tuple | None = None           # (steps done, campaign_s, Unix time) from the runner's last step
    cache: tuple | None = None          # (monotonic time, status) of the running or a final campaign
    resumes: int = 0                    # resumes asked so far (in memory): one after a run ended stands

    def save(self, folder: Path | None = None) -> None:
        """Write ``daemon.json`` into its folder (or ``folder``: a campaign being admitted), atomically."""
        folder = self.folder if folder is None else folder
        data = {"id": self.id, "seq": self.seq, "request": self.request,
                "submitted_unix": self.submitted_unix, "intent": self.intent, "error": self.error,
                "unclean_stop": self.unclean}
        tmp = folder / f".{RECORD_NAME}.partial"
        try:
            with open(tmp, "w") as fh:
                fh.write(json.dumps(data, indent=1))
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, folder / RECORD_NAME)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise

    @classmethod
    def load(cls, folder: Path) -> Record:
        d = json.loads((folder / RECORD_NAME).read_text())
        return cls(id=d["id"], seq=int(d["seq"]), folder=folder, request=d["request"],
                   submitted_unix=float(d["submitted_unix"]), intent=d.get("intent", "run"),
                   error=d.get("error"), unclean=d.get("unclean_stop"))


def _with_detector(cfg: GonioConfig, detector: dict | None) -> GonioConfig:
    """``cfg`` with the request's detector options (exposure_s, frames) applied and validated."""
    from gonio.config import parse_config

    if not detector:
        return cfg
    data = cfg.model_dump(mode="json")
    for key, value in detector.items():
        if value is not None:
            data["detector"][key] = value
    try:
        return parse_config(data, "request")
    except Exception as err:
        raise FieldError("detector", str(err)) from None


def precheck_request(cfg: GonioConfig, req: dict, materials) -> None:
    """The checks a request passes in the daemon's own process, from its text alone (milliseconds): the
    grid's spelling and its pose count bounded from its parameters (:func:`gonio.plan.grids.pose_bound`),
    and a measured material's name (``materials``: a :class:`gonio.sim.materials.library.MaterialsFolder`).
    FieldError naming the field."""
    from gonio.plan.grids import check_pose_bound, parse_grid
    from gonio.sim.materials.library import FILE_MODELS
    from gonio.sim.materials.spec import split_spec

    try:
        spec = parse_grid(req["grid"])
        check_pose_bound(spec, spec.theta_max_deg or cfg.kinematics.theta_max_deg, MAX_STEPS,
                         "the daemon accepts per campaign")
    except ValueError as err:
        raise FieldError("grid", str(err)) from None
    material = req.get("material")
    if material:
        model, name = split_spec(material)
        if model in FILE_MODELS:
            try:
                materials.check_name(model, name)
            except ValueError as err:
                raise FieldError("material", str(err)) from None


def prepare_campaign(cfg: GonioConfig, req: dict, materials, folder: Path, plan=None) -> str | None:
    """Validate ``req`` (:func:`validate_request`), plan it (with ``plan``, as there) and create its
    journal in ``folder`` (the planner's process does this); the material's normalized spec, or None."""
    from gonio.campaign import create_campaign

    spec, cfg, planned = validate_request(cfg, req, materials, plan=plan)
    c = create_campaign(folder, cfg, grid=req["grid"], material=spec, seed=int(req.get("seed", 0)),
                        sample=req.get("sample"), planned=planned)
    c.close()
    return spec


def validate_request(cfg: GonioConfig, req: dict, materials, plan=None):
    """Check a campaign request against the daemon's gantry by the lifecycle's request rules
    (:func:`gonio.lifecycle.check_request`, :func:`gonio.lifecycle.plan_request`) and plan it (with
    ``plan``, as there); (material spec or None, cfg, :class:`gonio.campaign.Planned`). A fly campaign
    (``order=fly``) is planned once the gantry's devices declare they can fly it, on a configured gantry
    or the simulated one.

    Raises :class:`FieldError` naming the field at fault (``grid`` where the gantry cannot do what the
    grid asks). Measured materials (``bsdf:NAME``, ``merl:NAME``) are names in the daemon's materials
    folder (``materials``, a :class:`gonio.sim.materials.library.MaterialsFolder`, whose ``load``
    refuses paths): no request may name a path on the daemon's machine.
    """
    from gonio.lifecycle import Request, RequestError, check_request, plan_request

    precheck_request(cfg, req, materials)
    request = Request(req["grid"], material=req.get("material"), sample=req.get("sample"),
                      seed=int(req.get("seed", 0)))
    try:
        material = check_request(cfg, request, materials.load)
    except RequestError as err:
        raise FieldError(err.field, str(err)) from None
    cfg = _with_detector(cfg, req.get("detector"))
    try:
        planned = plan_request(cfg, request, material, plan=plan)
    except RequestError as err:
        raise FieldError("grid" if err.field == "gantry" else err.field, str(err)) from None
    steps = planned.steps
    if steps > MAX_STEPS:
        raise FieldError("grid", f"{steps} steps; the daemon accepts at most {MAX_STEPS} per campaign")
    if steps == 0:
        raise FieldError("grid", f"no pose of {planned.plan.grid} can be measured on gantry '{cfg.name}'")
    return (material.spec if material is not None else None), cfg, planned
