"""Plans shared by the tests of one process: planning is deterministic (the same grid on the same gantry
config gives the same poses, order and estimates), so the tests that run many campaigns of one grid plan
it once. Each caller gets its own deep copy: nothing a test or a campaign does to its plan reaches
another's."""

from __future__ import annotations

import copy

from gonio.campaign import Campaign, Planned, config_hash, create_campaign, plan_campaign

_PLANNED: dict[tuple[str, str], Planned] = {}


def planned(grid: str, cfg) -> Planned:
    """:func:`gonio.campaign.plan_campaign` of ``grid`` on ``cfg``, planned once per process."""
    key = (grid, config_hash(cfg))
    if key not in _PLANNED:
        _PLANNED[key] = plan_campaign(grid, cfg)
    return copy.deepcopy(_PLANNED[key])


def create(folder, cfg, *, grid: str, **kw) -> Campaign:
    """:func:`gonio.campaign.create_campaign` with the process's plan of ``grid`` on ``cfg``."""
    return create_campaign(folder, cfg, grid=grid, planned=planned(grid, cfg), **kw)
