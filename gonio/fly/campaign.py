"""A fly campaign folder: plan -> journal (one transaction per sweep) -> readings -> brdf.h5.

The journal is the stop-and-go campaign's (:mod:`gonio.store`, the same folder layout and lock); its
steps are the fly campaign's readings in order: the dark and white reference of each checkpoint, then
one step per reading of each line (:func:`gonio.plan.fly.fly_step_table`). Each sweep (and each
checkpoint) is committed in one transaction (:meth:`Journal.commit_measurements`), so a crash loses at
most the sweep in flight; :func:`run_fly_campaign` resumes from the first sweep with no reading. The
fly plan is not stored: it is rebuilt from the journal's grid and config snapshot, which gives the same
plan (planning is deterministic), and checked against the steps table before anything is read.
Readings are keyed by their sweep's first step (:mod:`gonio.sim.fly`), so a resumed campaign writes
the same brdf.h5 as an uninterrupted one.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import numpy as np

from gonio.campaign import Campaign, create_campaign, finish_campaign
from gonio.config import GonioConfig
from gonio.plan import Plan, build_plan, parse_grid
from gonio.plan.fly import FlyPlan, fly_plan, fly_step_table, fly_steps, fly_summary

__all__ = ["create_fly_campaign", "run_fly_campaign", "fly_plan_of", "fly_plans"]


def fly_plans(grid: str, cfg: GonioConfig) -> tuple[Plan, FlyPlan]:
    """The stop-and-go plan of ``grid`` (``order=fly``) and its fly plan; ValueError for another order
    or a grid the planner refuses."""
    spec = parse_grid(grid)
    if spec.order != "fly":
        raise ValueError(f"grid: a fly campaign needs order=fly, got order={spec.order}")
    plan = build_plan(grid, cfg)
    return plan, fly_plan(plan, cfg)


def create_fly_campaign(folder: str | Path, cfg: GonioConfig, *, grid: str, material: str | None,
                        seed: int = 0, write_hook=None, sample: str | None = None,
                        plans: tuple[Plan, FlyPlan] | None = None) -> Campaign:
    """Plan a fly campaign over ``grid`` (``order=fly``) and journal it in ``folder``: read by
    :func:`run_fly_campaign` on the simulated gantry, or by :func:`gonio.campaign.run_campaign` on a
    configured one (``material`` None, ``sample`` the real sample's name).

    The journal's meta is the stop-and-go campaign's, with ``estimated_s`` and ``lower_bound_s`` those
    of the fly plan, ``stop_and_go_estimated_s`` beside them and ``fly`` its summary. ``plans``: what
    :func:`fly_plans` gave for this grid and config, when the caller has it already.
    """
    plan, fp = plans if plans is not None else fly_plans(grid, cfg)
    kind, pose = fly_step_table(fp)
    as_flown = dataclasses.replace(plan, step_kind=kind, step_pose=pose, estimated_s=fp.estimated_s,
                                   lower_bound_s=fp.lower_bound_s)
    c = create_campaign(folder, cfg, grid=grid, material=material, seed=seed, plan=as_flown,
                        write_hook=write_hook, sample=sample)
    c.journal.set_meta("fly", fly_summary(fp))
    c.journal.set_meta("stop_and_go_estimated_s", float(plan.estimated_s))
    return c


def fly_plan_of(c: Campaign) -> FlyPlan:
    """The fly plan of a journaled campaign, rebuilt from its grid and config snapshot; a ValueError
    when it does not give the journal's steps (a different gonio planned it)."""
    _, fp = fly_plans(c.meta["grid"], c.cfg)
    kind, pose = fly_step_table(fp)
    steps = c.journal.steps()
    if not (np.array_equal(kind, steps["kind"]) and np.array_equal(pose, steps["pose"])):
        raise ValueError(f"{c.folder}: the fly plan rebuilt from the journal's grid and config does not "
                         "match its steps (planned by another gonio version?); finish it with that version")
    return fp


def run_fly_campaign(c: Campaign, reader, *, on_sweep: Callable[[int, int], None] | None = None) -> Path:
    """Read every sweep and checkpoint not yet in the journal, one transaction each, then write brdf.h5.

    ``reader.item(fp, item) -> list[Measurement]`` gives the readings of one entry of
    :func:`gonio.plan.fly.fly_steps` (:class:`gonio.sim.fly.FlySimulator`). ``on_sweep(done, total)``
    is called after each commit (progress; an exception there stops the campaign, what was committed
    stays).
    """
    fp = fly_plan_of(c)
    items = fly_steps(fp)
    done = set(c.journal.done_steps().tolist())
    c.journal.log_event("state", state="running", message=f"fly: from step {c.journal.next_step()}")
    try:
        for n, item in enumerate(items):
            if item[2] in done:   # its first step: committed whole, one transaction per item
                continue
            c.journal.commit_measurements(reader.item(fp, item))
            if on_sweep is not None:
                on_sweep(n + 1, len(items))
    except KeyboardInterrupt:
        c.journal.log_event("state", state="paused", message="interrupted: the sweep in flight is not kept")
        raise
    c.journal.log_event("state", state="done", message="fly: every sweep read",
                        campaign_s=float(fp.estimated_s))
    return finish_campaign(c)
