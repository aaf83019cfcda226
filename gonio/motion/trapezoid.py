"""Trapezoidal velocity profiles: accelerate at a_max, cruise at v_max, decelerate at a_max.

Shared by the motion planner (how long a move takes) and the simulated axes (where an axis is at time
t), so that the plan's estimate and the simulation agree by construction. Degrees and seconds.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["move_time", "position_at"]

_Scalar = (int, float)


def _move_time_scalar(d: float, v: float, a: float) -> float:
    return 2.0 * math.sqrt(d / a) if d < v * v / a else d / v + v / a


def _position_at_scalar(t: float, start: float, target: float, v: float, a: float) -> float:
    # The same profile as the array path below, in plain floats: a simulated axis asks for one
    # position at a time, thousands of times per campaign, where numpy's per-call cost dominates.
    delta = target - start
    d = abs(delta)
    total = _move_time_scalar(d, v, a)
    if t >= total:
        return target if d > 0 else start
    t = max(t, 0.0)
    v_peak = min(v, math.sqrt(d * a))
    t_acc = v_peak / a
    t_cruise = total - 2.0 * t_acc
    if t <= t_acc:
        s = 0.5 * a * t * t
    elif t <= t_acc + t_cruise:
        s = 0.5 * a * t_acc * t_acc + v_peak * (t - t_acc)
    else:
        td = t - t_acc - t_cruise
        s = 0.5 * a * t_acc * t_acc + v_peak * t_cruise + v_peak * td - 0.5 * a * td * td
    return start + math.copysign(min(s, d), delta)


def move_time(distance_deg, v_max_deg_s, a_max_deg_s2) -> np.ndarray:
    """Time of a rest-to-rest move over ``|distance_deg|``; broadcasts over arrays."""
    if isinstance(distance_deg, _Scalar) and isinstance(v_max_deg_s, _Scalar) \
            and isinstance(a_max_deg_s2, _Scalar):
        return _move_time_scalar(abs(float(distance_deg)), float(v_max_deg_s), float(a_max_deg_s2))
    d = np.abs(np.asarray(distance_deg, dtype=np.float64))
    v = np.asarray(v_max_deg_s, dtype=np.float64)
    a = np.asarray(a_max_deg_s2, dtype=np.float64)
    # A move shorter than v²/a never reaches cruise speed: a triangle profile.
    triangle = d < v * v / a
    return np.where(triangle, 2.0 * np.sqrt(d / a), d / v + v / a)


def position_at(t_s, start_deg, target_deg, v_max_deg_s, a_max_deg_s2) -> np.ndarray:
    """Position ``t_s`` seconds after a rest-to-rest move from ``start_deg`` toward ``target_deg``
    began (the target itself once the move is over)."""
    if all(isinstance(x, _Scalar) for x in (t_s, start_deg, target_deg, v_max_deg_s, a_max_deg_s2)):
        return _position_at_scalar(float(t_s), float(start_deg), float(target_deg), float(v_max_deg_s),
                                   float(a_max_deg_s2))
    start = np.asarray(start_deg, dtype=np.float64)
    delta = np.asarray(target_deg, dtype=np.float64) - start
    d = np.abs(delta)
    v = np.asarray(v_max_deg_s, dtype=np.float64)
    a = np.asarray(a_max_deg_s2, dtype=np.float64)
    t = np.clip(np.asarray(t_s, dtype=np.float64), 0.0, None)
    v_peak = np.minimum(v, np.sqrt(d * a))       # the speed actually reached
    t_acc = v_peak / a
    total = move_time(d, v, a)
    t_cruise = total - 2.0 * t_acc
    s_acc = 0.5 * a * np.minimum(t, t_acc) ** 2
    s_cruise = v_peak * np.clip(t - t_acc, 0.0, t_cruise)
    t_dec = np.clip(t - t_acc - t_cruise, 0.0, t_acc)
    s_dec = v_peak * t_dec - 0.5 * a * t_dec**2
    s = np.where(t >= total, d, np.minimum(s_acc + s_cruise + s_dec, d))
    return start + np.sign(delta) * s
