"""A campaign as the daemon keeps it: ``daemon.json`` beside the journal, and the checks a request passes.

``daemon.json`` holds the request a campaign was submitted with, its place in the queue (``seq``), the
operator's intent (``run`` or ``hold``) and, after a fault the runner could not journal (a full disk),
its reason; it is replaced atomically. A request is checked in two stages, each error naming its field:
:func:`precheck_request` from the request alone in the daemon's process (the grid's pose count from its
parameters, a measured material's name), then :func:`prepare_campaign` in the planner's process
(:mod:`gonio.daemon.planner`): the material and every detail against the gantry, the plan, the journal.
"""

from __future__ import annotations

import errno
import json
import os
import sqlite3
from dataclasses import dataclass, field
from pathlib import Path

from gonio.config import GonioConfig, parse_config

__all__ = ["Record", "FieldError", "Conflict", "NotFound", "DiskFull", "validate_request", "precheck_request",
           "prepare_campaign", "is_disk_full", "ID_PATTERN", "RECORD_NAME", "MAX_STEPS"]

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


def is_disk_full(err: BaseException | None) -> bool:
    """True when ``err`` (or what caused it) is a full disk or a spent quota, from the OS or SQLite."""
    seen = set()
    while err is not None and id(err) not in seen:
        seen.add(id(err))
        if isinstance(err, DiskFull) or (isinstance(err, OSError) and err.errno in (errno.ENOSPC,
                                                                                    errno.EDQUOT)):
            return True
        if isinstance(err, sqlite3.Error) and getattr(err, "sqlite_errorcode", None) == sqlite3.SQLITE_FULL:
            return True
        err = err.__cause__ or err.__context__
    return False


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


def prepare_campaign(cfg: GonioConfig, req: dict, materials, folder: Path) -> str | None:
    """Validate ``req`` (:func:`validate_request`), plan it and create its journal in ``folder`` (the
    planner's process does this); the material's normalized spec, or None."""
    spec, cfg, plan = validate_request(cfg, req, materials)
    args = dict(grid=req["grid"], material=spec, seed=int(req.get("seed", 0)), sample=req.get("sample"))
    if isinstance(plan, tuple):   # order=fly: one unit per sweep (gonio.fly.hardware)
        from gonio.fly.campaign import create_fly_campaign

        c = create_fly_campaign(folder, cfg, plans=plan, **args)
    else:
        from gonio.campaign import create_campaign

        c = create_campaign(folder, cfg, plan=plan, **args)
    c.close()
    return spec


def validate_request(cfg: GonioConfig, req: dict, materials):
    """Check a campaign request against the daemon's gantry; (material spec or None, cfg, plan), the
    plan a (stop-and-go plan, fly plan) pair for ``order=fly``.

    Raises :class:`FieldError` naming the field at fault. Measured materials (``bsdf:NAME``,
    ``merl:NAME``) are names in the daemon's materials folder (``materials``, a
    :class:`gonio.sim.materials.library.MaterialsFolder`): no request may name a path on the daemon's
    machine.
    """
    from gonio.plan import build_plan, parse_grid

    precheck_request(cfg, req, materials)
    material, sample = req.get("material"), req.get("sample")
    simulated = cfg.detector.driver == "sim"
    spec = None
    if simulated:
        if not material:
            raise FieldError("material", "required: the simulated detector renders a MATERIAL, e.g. "
                             "'lambert:albedo=0.5'")
        try:
            spec = materials.load(material).spec
        except (ValueError, KeyError) as err:
            raise FieldError("material", str(err)) from None
    else:
        if material:
            raise FieldError("material", f"gantry '{cfg.name}' has a real detector: name the sample "
                             "('sample'), not a material")
        if not sample:
            raise FieldError("sample", f"required on gantry '{cfg.name}' (a real detector): the name of the "
                             "sample measured")
    fly = parse_grid(req["grid"]).order == "fly"   # spelled right: precheck_request parsed it
    cfg = _with_detector(cfg, req.get("detector"))
    if fly:
        return spec, cfg, _fly_plans(cfg, req["grid"])
    try:
        plan = build_plan(req["grid"], cfg)
    except ValueError as err:
        raise FieldError("grid", str(err)) from None
    _check_steps(cfg, plan, len(plan.step_kind))
    return spec, cfg, plan


def _fly_plans(cfg: GonioConfig, grid: str):
    """A request with ``order=fly``: (plan, fly plan) for a gantry that can fly it (its sweeping axes
    Dynamixel servos, its detector read on request: :func:`gonio.fly.hardware.check_fly_gantry`)."""
    from gonio.fly.hardware import checked_fly_plans
    from gonio.plan.fly import fly_step_table

    if cfg.drivers() == {"sim"}:
        raise FieldError("grid", f"order=fly on the simulated gantry '{cfg.name}': the daemon flies "
                         "configured gantries (Dynamixel sweeping axes); simulate a fly campaign with "
                         "'gonio simulate MATERIAL --grid GRID,order=fly --out DIR'")
    try:
        plan, fp = checked_fly_plans(grid, cfg)
    except ValueError as err:
        raise FieldError("grid", str(err)) from None
    _check_steps(cfg, plan, len(fly_step_table(fp)[0]))
    return plan, fp


def _check_steps(cfg: GonioConfig, plan, steps: int) -> None:
    if steps > MAX_STEPS:
        raise FieldError("grid", f"{steps} steps; the daemon accepts at most {MAX_STEPS} per campaign")
    if steps == 0:
        raise FieldError("grid", f"no pose of {plan.grid} can be measured on gantry '{cfg.name}'")
