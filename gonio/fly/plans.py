"""A fly campaign's plans: the stop-and-go plan of an ``order=fly`` grid and the fly plan of its lines.

A fly campaign's journal is the stop-and-go campaign's (:mod:`gonio.store`, the same folder layout and
lock; its kind ``fly``, :func:`gonio.campaign.create_campaign`); its steps are the fly campaign's
readings in order: the dark and white reference of each checkpoint, then one step per reading of each
line (:func:`gonio.plan.fly.fly_step_table`). Each sweep (and each checkpoint) is committed in one
transaction, so a crash loses at most the sweep in flight, and a resumed campaign starts from the first
sweep with no reading. The fly plan is not stored: it is rebuilt from the journal's grid and config
snapshot (:func:`rebuild_fly_plan`), which gives the same plan (planning is deterministic), and
checked against the steps table and the motion model of its lines (``meta["fly"]["motion"]``,
:data:`gonio.plan.fly.FLY_MOTION`) before anything is read.
"""

from __future__ import annotations

import numpy as np

from gonio.config import GonioConfig
from gonio.plan import Plan, build_plan, parse_grid
from gonio.plan.fly import FLY_MOTION, FlyPlan, fly_plan, fly_step_table

__all__ = ["fly_plans", "fly_plan_of", "rebuild_fly_plan"]


def fly_plans(grid: str, cfg: GonioConfig) -> tuple[Plan, FlyPlan]:
    """The stop-and-go plan of ``grid`` (``order=fly``) and its fly plan; ValueError for another order
    or a grid the planner refuses."""
    spec = parse_grid(grid)
    if spec.order != "fly":
        raise ValueError(f"grid: a fly campaign needs order=fly, got order={spec.order}")
    plan = build_plan(grid, cfg)
    return plan, fly_plan(plan, cfg)


def rebuild_fly_plan(meta: dict, cfg: GonioConfig, steps: dict, where) -> FlyPlan:
    """The fly plan of a journal (its ``meta``, config snapshot ``cfg`` and ``steps`` table), rebuilt
    from its grid; a ValueError naming ``where`` when it does not give the journal's steps (a different
    gonio planned it)."""
    motion = (meta.get("fly") or {}).get("motion", 1)
    if motion != FLY_MOTION:
        raise ValueError(f"{where}: planned with fly motion model {motion} (this gonio sweeps lines with "
                         f"model {FLY_MOTION}: rest to rest between their end poses, turnarounds swept), so "
                         "its sweeps cannot be timed as planned; finish it with the gonio version that "
                         "planned it")
    _, fp = fly_plans(meta["grid"], cfg)
    kind, pose = fly_step_table(fp)
    if not (np.array_equal(kind, steps["kind"]) and np.array_equal(pose, steps["pose"])):
        raise ValueError(f"{where}: the fly plan rebuilt from the journal's grid and config does not "
                         "match its steps (planned by another gonio version?); finish it with that version")
    return fp


def fly_plan_of(c) -> FlyPlan:
    """The fly plan of the campaign ``c`` (a :class:`gonio.campaign.Campaign`; see
    :func:`rebuild_fly_plan`)."""
    return rebuild_fly_plan(c.meta, c.cfg, c.journal.steps(), c.folder)
