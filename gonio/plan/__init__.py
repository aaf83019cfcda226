"""Plans: what a campaign measures and in which order, as data (no I/O, no hardware).

``build_plan(grid, cfg)`` turns a GRID string (``iso:step=5``, ``full:step=15``, ``merl:stride=4``, with
options for each shortcut) into a :class:`Plan`: the reachable poses in motion order with their axis
targets, the dark and white-reference readings between them, counts before and after each shortcut,
unreachable poses by reason, and the campaign's estimated duration with a lower bound.
``plan_summary`` and ``format_plan`` report it (``gonio plan``).
"""

from gonio.registry import lazy_attributes

#: Each public name -> the submodule it lives in (imported when the name is first used: a module that
#: needs a light part of the package, the step kinds of .schedule or the GRID parser of .grids, does not
#: load the planner and the libraries it plans with; tools/bench_startup.py).
_EXPORTS = {
    "Plan": "build", "build_plan": "build", "GridSpec": "grids", "parse_grid": "grids",
    "plan_summary": "report", "format_plan": "report", "STEP_POSE": "schedule", "STEP_DARK": "schedule",
    "STEP_REFERENCE": "schedule", "STEP_NAMES": "schedule",
}
__all__ = list(_EXPORTS)
__getattr__ = lazy_attributes(__name__, _EXPORTS)
