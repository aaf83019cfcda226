"""Reports of a plan: a JSON-ready summary and a human-readable text (what ``gonio plan`` prints)."""

from __future__ import annotations

import math

import numpy as np

from gonio.plan.build import Plan
from gonio.plan.schedule import STEP_DARK, STEP_POSE, STEP_REFERENCE

__all__ = ["plan_summary", "format_plan", "hms"]


def hms(seconds: float) -> str:
    """``h:mm:ss`` of a duration in seconds (rounded to the second; hours unbounded).

    Examples
    --------
    >>> hms(3725.4)
    '1:02:05'
    """
    s = int(round(float(seconds)))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


def plan_summary(plan: Plan, fly=None) -> dict:
    """A JSON-ready dict: grid, symmetries, counts, infeasible, poses, steps, durations and their parts.

    ``steps`` counts the steps by kind (``pose``, ``dark``, ``reference``) and in ``total``; ``moves``
    counts the moves (every step but the darks, and the park) and ``via_moves`` those that go through
    via points to stay clear in transit. Durations
    are seconds (``estimated_s``, ``lower_bound_s``: valid for any order and branch choice) with
    ``h:mm:ss`` twins; ``branch_fixed_bound_s`` is the older bound for the plan's own branches only;
    ``reference_s`` and ``reference_share`` what the dark and reference readings add (readings,
    settles and detours); ``timing`` holds the parts (NaN parts, e.g. an MST skipped for a large plan,
    become None). With ``fly`` (a :class:`gonio.plan.fly.FlyPlan` of the same poses), ``fly`` holds
    its estimate, bound and parts (:func:`gonio.plan.fly.fly_summary`).
    """
    kinds = np.asarray(plan.step_kind)
    steps = {"total": int(kinds.size), "pose": int(np.count_nonzero(kinds == STEP_POSE)),
             "dark": int(np.count_nonzero(kinds == STEP_DARK)),
             "reference": int(np.count_nonzero(kinds == STEP_REFERENCE))}
    out = {
        "grid": plan.grid,
        "symmetries": {k: bool(v) for k, v in plan.symmetries.items()},
        "counts": {k: int(v) for k, v in plan.counts.items()},
        "infeasible": {k: int(v) for k, v in plan.infeasible.items()},
        "poses": int(len(plan.theta_i)),
        "steps": steps,
        "order": plan.order,
        "axis_names": list(plan.axis_names),
        "reference_axes_deg": [float(x) for x in plan.reference_axes_deg],
        "estimated_s": float(plan.estimated_s),
        "estimated_hms": hms(plan.estimated_s),
        "lower_bound_s": float(plan.lower_bound_s),
        "lower_bound_hms": hms(plan.lower_bound_s),
        "branch_fixed_bound_s": _part(plan.timing, "branch_fixed_bound"),
        "reference_s": plan.timing.get("reference_s"),
        "reference_share": (plan.timing["reference_s"] / plan.estimated_s
                            if plan.timing.get("reference_s") is not None and plan.estimated_s > 0 else None),
        "timing": _jsonable(plan.timing),
        "moves": int(np.count_nonzero(kinds != STEP_DARK)) + 1,
        "via_moves": int(plan.timing.get("via_moves", len(plan.via_deg))),
    }
    if fly is not None:
        from gonio.plan.fly import fly_summary

        out["fly"] = _jsonable(fly_summary(fly))
    return out


def format_plan(plan: Plan, fly=None) -> str:
    """A human report: counts after each stage (and what each removed), infeasible poses by reason,
    the steps, and the estimated duration with its lower bound in h:mm:ss and seconds; with ``fly``
    (a :class:`gonio.plan.fly.FlyPlan`), the stop-and-go and fly estimates side by side, each with
    its bound."""
    s = plan_summary(plan, fly)
    lines = [f"plan         {s['grid']}",
             "symmetries   " + ", ".join(f"{k} {'on' if v else 'off'}" for k, v in s["symmetries"].items()),
             "", "poses after each stage"]
    previous = None
    for stage, count in s["counts"].items():
        removed = "" if previous is None else f"   (-{previous - count:,})"
        lines.append(f"  {stage:<16}{count:>12,}{removed}")
        previous = count
    if s["infeasible"]:
        lines += ["", "infeasible by reason"]
        lines += [f"  {reason:<16}{count:>12,}" for reason, count in s["infeasible"].items()]
    st = s["steps"]
    lines += ["", f"steps        {st['total']:,}: {st['pose']:,} poses, {st['dark']:,} dark, "
                  f"{st['reference']:,} white reference",
              f"order        {s['order']}",
              f"via points   {s['via_moves']:,} of {s['moves']:,} moves (the park included) go round a "
              "collision in transit", ""]
    est, low = s["estimated_s"], s["lower_bound_s"]
    ratio = f"   (estimate / bound = {est / low:.3f})" if low > 0 else ""
    lines += [f"estimated    {hms(est):>10}   {est:,.1f} s",
              f"lower bound  {hms(low):>10}   {low:,.1f} s{ratio}   (any order, any branches)"]
    fixed = s["branch_fixed_bound_s"]
    if fixed:
        lines.append(f"  for the plan's own branches only (not a bound on other branch choices): "
                     f"{fixed:,.1f} s (estimate / that = {est / fixed:.3f})")
    if s["reference_share"] is not None:
        share = 100 * s["reference_share"]
        lines.append(f"  dark + white reference: {s['reference_s']:,.1f} s, {share:.1f} % of the campaign "
                     " (readings, settles and detours to the reference)")
    parts = s["timing"].get("estimate") or {}
    if parts:
        lines.append(
            "  estimate: moves {:,.1f} s (pose to pose {:,.1f} s), settle {:,.1f} s, readings {:,.1f} s, "
            "return home {:,.1f} s".format(parts["move_s"], s["timing"].get("pose_motion_s") or 0.0,
                                           parts["settle_s"], parts["reading_s"], parts["return_s"]))
    bound = s["timing"].get("lower_bound") or {}
    if bound:
        lines.append("  bound: moves >= {:,.1f} s, settle {:,.1f} s, readings {:,.1f} s".format(
            bound["move_s"], bound["settle_s"], bound["reading_s"]))
    if fly is not None:
        lines += [""] + _format_fly(s)
    return "\n".join(lines)


def _format_fly(s: dict) -> list[str]:
    """Stop-and-go and fly side by side (:mod:`gonio.plan.fly`)."""
    f = s["fly"]
    est, low, fest, flow = s["estimated_s"], s["lower_bound_s"], f["estimated_s"], f["lower_bound_s"]
    gain = "" if fest <= 0 else (f"   (fly: {est / fest:.1f}x less gantry time)" if est >= fest
                                 else f"   (fly: {fest / est:.2f}x the stop-and-go time)")

    def ratio(e, b):
        return f"{e / b:.3f}" if b > 0 else "-"

    lines = [f"{'':<18}{'stop-and-go':>14}{'fly':>14}",
             f"{'estimated':<18}{hms(est):>14}{hms(fest):>14}{gain}",
             f"{'lower bound':<18}{hms(low):>14}{hms(flow):>14}",
             f"{'estimate / bound':<18}{ratio(est, low):>14}{ratio(fest, flow):>14}"]
    # one exposure per sweeping axis's top speed (half a grid step of its travel): "125 ms or 167 ms"
    exposures = " or ".join(f"{1000 * e:.3g} ms" for e in f["exposure_s"]) or "-"
    coordinated = f.get("coordinated_lines", 0)
    several = f" ({coordinated:,} of them coordinated: several axes along a path)" if coordinated else ""
    lines.append(f"fly          {f['lines']:,} lines{several} sweep "
                 f"{f['readings'] - f['stop_and_go_readings']:,} "
                 f"readings (exposure {exposures}, blur up to {f['max_blur_deg']:.2f}° of axis travel), "
                 f"{f['stop_and_go_readings']:,} read stop-and-go; {f['checkpoints']:,} dark + white "
                 f"reference checkpoints, one every {f['reference_interval_s']:.1f} s of gantry time")
    e, b = f["estimate"], f["lower_bound"]
    lines.append("  estimate: lines {:,.1f} s (rest to rest), transits {:,.1f} s, swept turnarounds "
                 "{:,.1f} s ({:,} of them), checkpoints {:,.1f} s, stop-and-go readings {:,.1f} s".format(
                     e["line_s"], e["transit_s"], e.get("turn_s", 0.0), int(e.get("turnarounds", 0)),
                     e["reference_s"], e["settle_s"] + e["reading_s"]))
    lines.append("  bound (any order and direction of these lines): sweeps >= {:,.1f} s, entries >= {:,.1f} "
                 "s, settles and readings {:,.1f} s".format(b["sweeps_s"], b["entries_s"], b["fixed_s"]))
    lines += [f"  {count:,} {'line' if 'split' in note else 'pose'}(s): {note}"
              for note, count in f["notes"].items()]
    return lines


def _part(timing: dict, name: str) -> float | None:
    total = (timing.get(name) or {}).get("total_s")
    return None if total is None else float(total)


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return None if not math.isfinite(float(value)) else float(value)
    return value
