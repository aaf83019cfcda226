"""A campaign folder: the journal, the plan it holds, and the sampled BRDF made from it.

``create_campaign`` plans and journals a campaign (no hardware touched); ``run_campaign`` runs it (or
resumes it) on a gantry and, once every step is measured, writes ``brdf.h5``. The CLI and the daemon
both go through here.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np

from gonio.calibrate import calibrate
from gonio.config import GonioConfig, parse_config
from gonio.dataset import BRDF_NAME, write_brdf
from gonio.plan import STEP_POSE, STEP_REFERENCE, Plan, build_plan, parse_grid
from gonio.protocols import Gantry
from gonio.runner import Runner, State
from gonio.store import JOURNAL_NAME, Journal

__all__ = ["Campaign", "create_campaign", "open_campaign", "run_campaign", "software_version"]


def software_version() -> str:
    try:
        return version("gonio")
    except PackageNotFoundError:  # running from a source tree that was never installed
        return "0+unknown"


@dataclass
class Campaign:
    folder: Path
    journal: Journal
    cfg: GonioConfig

    @property
    def meta(self) -> dict:
        return self.journal.meta()

    def close(self) -> None:
        self.journal.close()


def create_campaign(folder: str | Path, cfg: GonioConfig, *, grid: str, material: str, seed: int = 0,
                    plan: Plan | None = None, write_hook=None) -> Campaign:
    """Plan the campaign and journal it in ``folder`` (created; must not hold a campaign already)."""
    folder = Path(folder)
    plan = plan if plan is not None else build_plan(grid, cfg)
    folder.mkdir(parents=True, exist_ok=True)
    kind = plan.step_kind
    pose = plan.step_pose
    n_axes = plan.axes_deg.shape[1]
    # Per step: planned directions and commanded axes. A dark is read where the gantry stands, so it
    # inherits the previous step's targets (home before the first move).
    angles = np.full((len(kind), 4), np.nan)
    axes = np.empty((len(kind), n_axes))
    last = np.array([cfg.axes[a].home_deg for a in cfg.axis_names], float)
    ref_angles = np.array([cfg.reference.theta_i_deg, 0.0, cfg.reference.theta_o_deg, cfg.reference.dphi_deg])
    pose_angles = np.degrees(np.stack([plan.theta_i, plan.phi_i, plan.theta_o, plan.phi_o], axis=1))
    for s, (k, p) in enumerate(zip(kind, pose, strict=True)):
        if k == STEP_POSE:
            last = plan.axes_deg[p]
            angles[s] = pose_angles[p]
        elif k == STEP_REFERENCE:
            last = plan.reference_axes_deg
            angles[s] = ref_angles
        axes[s] = last
    meta = {
        "grid": plan.grid, "grid_requested": parse_grid(grid).normalized, "material": material,
        "seed": int(seed), "symmetries": plan.symmetries,
        "counts": plan.counts, "infeasible": plan.infeasible, "poses": int(len(plan.theta_i)),
        "estimated_s": float(plan.estimated_s), "lower_bound_s": float(plan.lower_bound_s),
        "axis_names": list(cfg.axis_names), "channels": list(cfg.detector.channels),
        "gantry": cfg.name, "config": cfg.model_dump(mode="json"),
        "software_version": software_version(), "created_unix": time.time(),
    }
    steps = {"kind": kind, "pose": pose, "theta_i_deg": angles[:, 0], "phi_i_deg": angles[:, 1],
             "theta_o_deg": angles[:, 2], "phi_o_deg": angles[:, 3], "axes_deg": axes}
    journal = Journal.create(folder / JOURNAL_NAME, meta, steps, write_hook=write_hook)
    return Campaign(folder, journal, cfg)


def open_campaign(folder: str | Path, *, write_hook=None) -> Campaign:
    """Reopen a campaign (to resume it or export it): the config is the snapshot it was planned with."""
    folder = Path(folder)
    journal = Journal.open(folder / JOURNAL_NAME, write_hook=write_hook)
    cfg = parse_config(journal.meta()["config"], f"{folder / JOURNAL_NAME} (config snapshot)")
    return Campaign(folder, journal, cfg)


def finish_campaign(c: Campaign) -> Path:
    """Calibrate every measured pose and write ``brdf.h5``."""
    meta = c.meta
    cal = calibrate(c.journal.measurements(), c.cfg.reference.albedo)
    return write_brdf(c.folder / BRDF_NAME, cal, channels=meta["channels"], symmetries=meta["symmetries"],
                      grid=meta["grid"], material=meta["material"], gantry=meta["gantry"],
                      software_version=software_version())


def run_campaign(c: Campaign, gantry: Gantry,
                 on_step: Callable[[Runner, int], None] | None = None) -> tuple[State, Runner]:
    """Run (or resume) ``c`` on ``gantry``; writes ``brdf.h5`` when the campaign is done."""
    runner = Runner(gantry, c.journal, c.cfg, on_step=on_step)
    gantry.connect()
    try:
        state = runner.run()
    finally:
        gantry.close()
    if state == State.DONE:
        finish_campaign(c)
    return state, runner
