"""Plans shared by the tests of one process: planning is deterministic (the same grid on the same gantry
config gives the same poses, order and estimates), so the tests that run many campaigns of one grid plan
it once. Each caller gets its own deep copy: nothing a test or a campaign does to its plan reaches
another's."""

from __future__ import annotations

import copy

import gonio.fly.plans as fly_planning
from gonio.campaign import Campaign, Planned, config_hash, create_campaign, plan_campaign

_PLANNED: dict[tuple[str, str], Planned] = {}
_FLY_PLANS: dict[tuple[str, str], tuple] = {}
#: The planner's own fly_plans, taken before a test puts :func:`fly_plans` in its place.
_PLAN_FLY = fly_planning.fly_plans


def planned(grid: str, cfg) -> Planned:
    """:func:`gonio.campaign.plan_campaign` of ``grid`` on ``cfg``, planned once per process."""
    key = (grid, config_hash(cfg))
    if key not in _PLANNED:
        _PLANNED[key] = plan_campaign(grid, cfg)
    return copy.deepcopy(_PLANNED[key])


def create(folder, cfg, *, grid: str, **kw) -> Campaign:
    """:func:`gonio.campaign.create_campaign` with the process's plan of ``grid`` on ``cfg``."""
    return create_campaign(folder, cfg, grid=grid, planned=planned(grid, cfg), **kw)


def fly_plans(grid: str, cfg):
    """:func:`gonio.fly.plans.fly_plans` of ``grid`` on ``cfg`` (the stop-and-go plan and its fly plan),
    planned once per process: what a fly campaign's every run rebuilds from its journal."""
    key = (grid, config_hash(cfg))
    if key not in _FLY_PLANS:
        _FLY_PLANS[key] = _PLAN_FLY(grid, cfg)
    return copy.deepcopy(_FLY_PLANS[key])
