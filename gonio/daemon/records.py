"""A campaign as the daemon keeps it: ``daemon.json`` beside the journal, and the checks a request passes.

``daemon.json`` holds the request a campaign was submitted with, its place in the queue (``seq``) and
the operator's intent (``run`` or ``hold``); it is replaced atomically. A request is validated field by
field against the daemon's gantry (:func:`validate_request`) before anything is written, and every error
names its field.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from gonio.config import GonioConfig, parse_config

__all__ = ["Record", "FieldError", "Conflict", "NotFound", "validate_request", "ID_PATTERN", "RECORD_NAME",
           "MAX_STEPS"]

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
    static: dict = field(default_factory=dict)   # meta that never changes (grid, poses, steps, ...)
    final: str | None = None            # done or aborted, once seen: never changes again
    live: tuple | None = None           # (steps done, campaign_s, Unix time) from the runner's last step
    cache: tuple | None = None          # (monotonic time, status) of the running or a final campaign

    def save(self) -> None:
        data = {"id": self.id, "seq": self.seq, "request": self.request,
                "submitted_unix": self.submitted_unix, "intent": self.intent, "error": self.error}
        tmp = self.folder / f".{RECORD_NAME}.partial"
        tmp.write_text(json.dumps(data, indent=1))
        os.replace(tmp, self.folder / RECORD_NAME)

    @classmethod
    def load(cls, folder: Path) -> Record:
        d = json.loads((folder / RECORD_NAME).read_text())
        return cls(id=d["id"], seq=int(d["seq"]), folder=folder, request=d["request"],
                   submitted_unix=float(d["submitted_unix"]), intent=d.get("intent", "run"),
                   error=d.get("error"))


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


def validate_request(cfg: GonioConfig, req: dict):
    """Check a campaign request against the daemon's gantry; (material spec or None, cfg, plan), the
    plan a (stop-and-go plan, fly plan) pair for ``order=fly``.

    Raises :class:`FieldError` naming the field at fault. Material specs that name a file (``merl:``)
    are refused: no request may name a path on the daemon's machine.
    """
    from gonio.plan import build_plan, parse_grid

    material, sample = req.get("material"), req.get("sample")
    simulated = cfg.detector.driver == "sim"
    spec = None
    if simulated:
        if not material:
            raise FieldError("material", "required: the simulated detector renders a MATERIAL, e.g. "
                             "'lambert:albedo=0.5'")
        if material.split(":", 1)[0].strip().lower() == "merl":
            raise FieldError("material", "merl:PATH names a file; the API accepts analytic materials only "
                             "(lambert, ggx, cook-torrance, ward, ...)")
        from gonio.sim.materials import load

        try:
            spec = load(material).spec
        except (ValueError, KeyError) as err:
            raise FieldError("material", str(err)) from None
    else:
        if material:
            raise FieldError("material", f"gantry '{cfg.name}' has a real detector: name the sample "
                             "('sample'), not a material")
        if not sample:
            raise FieldError("sample", f"required on gantry '{cfg.name}' (a real detector): the name of the "
                             "sample measured")
    try:
        fly = parse_grid(req["grid"]).order == "fly"
    except ValueError as err:
        raise FieldError("grid", str(err)) from None
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
