"""Certified clearance of moves in transit: what the axes sweep between two rest positions.

A move starts every axis at the same instant on its own rest-to-rest trapezoid
(:mod:`gonio.motion.trapezoid`); each holds its target once its profile ends. Two facts make the
swept path checkable without trusting samples:

- every axis moves monotonically from start to target, so axis limits hold over the move exactly when
  they hold at both ends, and an axis travels exactly ``|x(t2) − x(t1)|`` between two instants;
- a position is piecewise quadratic in t and its velocity piecewise linear and continuous, with
  breakpoints at the ends of the acceleration and cruise phases.

Two tools are built on them and used by the designs:

:func:`difference_range`
    The exact range of ``x_j(t) − x_k(t)`` over a move (two-arm: the carriages' azimuth difference):
    its extrema are at the ends or where the (piecewise linear) relative velocity crosses zero.
:func:`lipschitz_min`
    A certified lower bound on ``min_t g(x(t))`` for a clearance function g that changes by at most
    the axes' travel (degrees of g per degree of axis motion ≤ 1, summed over axes) between two
    instants: on an interval whose ends have margins g1, g2 and travel L between them, g stays above
    (g1 + g2 − L) / 2. Intervals that this cannot prove clear are bisected (branch and bound) until the
    bound is within ``tol_deg`` of the smallest margin sampled, so nothing can pass between samples.

Degrees and seconds throughout.
"""

from __future__ import annotations

import math

import numpy as np

from gonio.motion.trapezoid import move_time, position_at

__all__ = ["profile_breaks", "difference_range", "difference_range_scalar", "lipschitz_min", "MARGIN_TOL_DEG"]

#: deg: branch and bound stops once its lower bound is within this of the smallest sampled margin.
MARGIN_TOL_DEG = 1e-3
# Bisection levels at most (a gap halves per level: 40 levels take 1e3° to 1e-9°).
_MAX_LEVELS = 40
# Initial samples per move for branch and bound.
_FIRST_INTERVALS = 8


def _velocity(t, start, target, v, a):
    """Signed velocity (°/s) at ``t`` of the trapezoid from ``start`` to ``target`` (arrays broadcast)."""
    delta = target - start
    d = np.abs(delta)
    v_peak = np.minimum(v, np.sqrt(d * a))
    total = move_time(d, v, a)
    speed = np.minimum(np.minimum(a * t, v_peak), a * (total - t))
    return np.sign(delta) * np.clip(speed, 0.0, None)


def profile_breaks(start, target, v, a) -> np.ndarray:
    """Breakpoints (..., 3) in s of trapezoids: end of acceleration, start of deceleration, end."""
    d = np.abs(np.asarray(target, dtype=np.float64) - np.asarray(start, dtype=np.float64))
    v_peak = np.minimum(v, np.sqrt(d * a))
    t_acc = v_peak / a
    total = move_time(d, v, a)
    return np.stack([t_acc, total - t_acc, total], axis=-1)


def difference_range(start_j, end_j, start_k, end_k, v_j, a_j, v_k, a_k) -> tuple[np.ndarray, np.ndarray]:
    """Exact (min, max) over a move of ``x_j(t) − x_k(t)`` for two axes on their trapezoids.

    Parameters
    ----------
    start_j, end_j, start_k, end_k : ndarray, shape (M,)
        Start and target of axes j and k, degrees.
    v_j, a_j, v_k, a_k : float
        Maximum velocity (°/s) and acceleration (°/s²) of each axis.

    Returns
    -------
    lo, hi : ndarray, shape (M,)
        The smallest and largest difference reached, degrees.
    """
    sj, ej, sk, ek = (np.asarray(x, dtype=np.float64) for x in (start_j, end_j, start_k, end_k))
    # The relative velocity is linear between consecutive breakpoints of either axis, so its zeros
    # (the only interior extrema of the difference) are found exactly piece by piece.
    knots = np.sort(np.concatenate([np.zeros(sj.shape + (1,)), profile_breaks(sj, ej, v_j, a_j),
                                    profile_breaks(sk, ek, v_k, a_k)], axis=-1), axis=-1)
    rel = (_velocity(knots, sj[..., None], ej[..., None], v_j, a_j)
           - _velocity(knots, sk[..., None], ek[..., None], v_k, a_k))
    g0, g1 = rel[..., :-1], rel[..., 1:]
    t0, t1 = knots[..., :-1], knots[..., 1:]
    cross = g0 * g1 < 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        tz = np.where(cross, t0 + g0 / (g0 - g1) * (t1 - t0), t0)
    times = np.concatenate([knots, tz], axis=-1)
    diff = (position_at(times, sj[..., None], ej[..., None], v_j, a_j)
            - position_at(times, sk[..., None], ek[..., None], v_k, a_k))
    return diff.min(axis=-1), diff.max(axis=-1)


def _scalar_profile(s, e, v, a):
    """(s, e, sign, d, v_peak, t_acc, total) of one trapezoid, plain floats: what :func:`_scalar_state`
    evaluates at each instant, computed once per move (the same operations as :func:`_scalar_breaks`)."""
    delta = e - s
    d = abs(delta)
    v_peak = min(v, math.sqrt(d * a))
    t_acc = v_peak / a
    total = 2.0 * math.sqrt(d / a) if d < v * v / a else d / v + v / a
    return s, e, (1.0 if delta > 0 else -1.0), d, v_peak, t_acc, total, a


def _profile_state(t, p):
    """:func:`_scalar_state` at ``t`` of a profile from :func:`_scalar_profile`: the same floats."""
    s, e, sign, d, v_peak, t_acc, total, a = p
    if d == 0.0:
        return s, 0.0
    if t >= total:
        return e, 0.0
    if t <= t_acc:
        return s + sign * 0.5 * a * t * t, sign * a * t
    if t <= total - t_acc:
        return s + sign * (0.5 * a * t_acc * t_acc + v_peak * (t - t_acc)), sign * v_peak
    r = total - t
    return s + sign * min(d - 0.5 * a * r * r, d), sign * a * r


def difference_range_scalar(sj, ej, sk, ek, v_j, a_j, v_k, a_k) -> tuple[float, float]:
    """:func:`difference_range` of one move in plain floats (no numpy overhead, for the runner)."""
    if sj == ej and sk == ek:   # neither axis moves (a step that keeps the carriages): one value
        return sj - sk, sj - sk
    pj, pk = _scalar_profile(sj, ej, v_j, a_j), _scalar_profile(sk, ek, v_k, a_k)
    knots = sorted((0.0, pj[5], pj[6] - pj[5], pj[6], pk[5], pk[6] - pk[5], pk[6]))
    states = [(_profile_state(t, pj), _profile_state(t, pk)) for t in knots]
    values = [xj - xk for (xj, _), (xk, _) in states]
    rels = [uj - uk for (_, uj), (_, uk) in states]
    for i in range(len(knots) - 1):
        g0, g1 = rels[i], rels[i + 1]
        if g0 * g1 < 0.0:
            t = knots[i] + g0 / (g0 - g1) * (knots[i + 1] - knots[i])
            values.append(_profile_state(t, pj)[0] - _profile_state(t, pk)[0])
    return min(values), max(values)


def lipschitz_min(margin_fn, start, end, velocity, accel, axes, tol_deg: float = MARGIN_TOL_DEG,
                  floor: float | None = None) -> np.ndarray:
    """A certified lower bound (M,) on ``min_t margin_fn(x(t))`` over each move, degrees.

    Parameters
    ----------
    margin_fn : callable
        ``margin_fn(positions (K, n_axes)) -> (K,)`` margin in degrees; it must change by at most
        ``Σ_j |Δx_j|`` over the axes ``axes`` when the positions change by Δx (1-Lipschitz in the L1
        norm of those axes) and not depend on the others.
    start, end : ndarray, shape (M, n_axes)
        Rest positions before and after each move, degrees.
    velocity, accel : ndarray, shape (n_axes,)
        Per-axis maximum velocity (°/s) and acceleration (°/s²).
    axes : sequence of int
        The columns the margin depends on (only they are evaluated and travel).
    tol_deg : float
        Where the first bound is negative, intervals are bisected until the bound is within this of the
        smallest sampled margin (or proves the move clear): the result is then that close to the
        true minimum. Where the first bound is >= 0 it is returned as is.
    floor : float, optional
        Only whether each bound is below ``floor`` is wanted: a move stops being refined as soon as a
        sampled margin or a settled interval's bound is below it (every sample's margin ends up in some
        settled interval's bound, so the full refinement would end below it too), and its result is
        then some value below ``floor``. Results at or above ``floor`` are those of a call without it.

    Returns
    -------
    ndarray, shape (M,)
        Lower bounds on the smallest margin, degrees.
    """
    start = np.asarray(start, dtype=np.float64)
    end = np.asarray(end, dtype=np.float64)
    m = start.shape[0]
    cols = list(axes)
    v = np.asarray(velocity, dtype=np.float64)[cols]
    a = np.asarray(accel, dtype=np.float64)[cols]
    s, e = start[:, cols], end[:, cols]
    full = np.zeros((1, start.shape[1]))

    def margins(pos):
        arr = np.broadcast_to(full, (pos.shape[0], start.shape[1])).copy()
        arr[:, cols] = pos
        return np.asarray(margin_fn(arr), dtype=np.float64)

    g_s, g_e = margins(s), margins(e)
    travel = np.sum(np.abs(e - s), axis=1)
    bound = 0.5 * (g_s + g_e - travel)
    out = np.minimum(bound, np.minimum(g_s, g_e))
    need = np.flatnonzero(out < 0.0)
    if need.size == 0:
        return out
    total = np.max(move_time(e[need] - s[need], v, a), axis=1)
    # Intervals as rows: (move, t0, t1, g0, g1, positions at t0 and t1).
    frac = np.linspace(0.0, 1.0, _FIRST_INTERVALS + 1)
    t_all = total[:, None] * frac
    pos = position_at(t_all[..., None], s[need][:, None, :], e[need][:, None, :], v, a)
    g = margins(pos.reshape(-1, len(cols))).reshape(need.size, -1)
    move = np.repeat(need, _FIRST_INTERVALS)
    t0, t1 = t_all[:, :-1].reshape(-1), t_all[:, 1:].reshape(-1)
    g0, g1 = g[:, :-1].reshape(-1), g[:, 1:].reshape(-1)
    p0, p1 = pos[:, :-1].reshape(-1, len(cols)), pos[:, 1:].reshape(-1, len(cols))
    best = np.full(m, np.inf)          # smallest sampled margin per move (an upper bound on the min)
    np.minimum.at(best, need, g.min(axis=1))
    lower = np.full(m, np.inf)         # lower bounds of the intervals settled so far
    for _ in range(_MAX_LEVELS):
        lb = 0.5 * (g0 + g1 - np.sum(np.abs(p1 - p0), axis=1))
        # An interval is settled when it cannot hide a margin below 0 or below the best sample by
        # more than tol: its bound then counts as it is.
        settled = (lb >= 0.0) | (lb >= best[move] - tol_deg)
        np.minimum.at(lower, move[settled], np.minimum(lb[settled], np.minimum(g0, g1)[settled]))
        keep = ~settled
        if floor is not None:
            keep &= np.minimum(lower, best)[move] >= floor
        if not keep.any():
            break
        move, t0, t1, g0, g1, p0, p1 = (x[keep] for x in (move, t0, t1, g0, g1, p0, p1))
        tm = 0.5 * (t0 + t1)
        pm = position_at(tm[:, None], s[move], e[move], v, a)
        gm = margins(pm)
        np.minimum.at(best, move, gm)
        move = np.concatenate([move, move])
        t0, t1 = np.concatenate([t0, tm]), np.concatenate([tm, t1])
        g0, g1 = np.concatenate([g0, gm]), np.concatenate([gm, g1])
        p0, p1 = np.concatenate([p0, pm]), np.concatenate([pm, p1])
    else:
        # Out of levels (only for a pathological margin function): count what is left as it stands.
        lb = 0.5 * (g0 + g1 - np.sum(np.abs(p1 - p0), axis=1))
        np.minimum.at(lower, move, lb)
    out[need] = lower[need]
    if floor is not None:
        below = np.minimum(lower[need], best[need]) < floor
        out[need[below]] = np.minimum(lower, best)[need[below]]
    return out
