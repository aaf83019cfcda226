"""Plans: what a campaign measures and in which order, as data (no I/O, no hardware).

``build_plan(grid, cfg)`` turns a GRID string (``iso:step=5``, ``full:step=15``, ``merl:stride=4``, with
options for each shortcut) into a :class:`Plan`: the reachable poses in motion order with their axis
targets, the dark and white-reference readings between them, counts before and after each shortcut,
unreachable poses by reason, and the campaign's estimated duration with a lower bound.
``plan_summary`` and ``format_plan`` report it (``gonio plan``).
"""

from gonio.plan.build import Plan, build_plan
from gonio.plan.grids import GridSpec, parse_grid
from gonio.plan.report import format_plan, plan_summary
from gonio.plan.schedule import STEP_DARK, STEP_NAMES, STEP_POSE, STEP_REFERENCE

__all__ = [
    "Plan",
    "GridSpec",
    "build_plan",
    "parse_grid",
    "plan_summary",
    "format_plan",
    "STEP_POSE",
    "STEP_DARK",
    "STEP_REFERENCE",
    "STEP_NAMES",
]
