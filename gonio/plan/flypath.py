"""Coordinated fly lines: several axes move together along a path in joint space, read on the fly.

On the sample-stage gantry a Δφ ring (fixed θi, θo) moves both detector axes at once: no single axis
steps along it, so :mod:`gonio.plan.fly` finds no line there. A :class:`PathLine` sweeps such a run of
the plan's poses (consecutive poses of one ring, Δφ stepping by the grid step) along one smooth path
through all of them: the cubic spline Q(u) through the poses' axis positions, u the pose index
(0 .. n − 1), so every pose lies on the path at an integer u. Every axis follows its own component of
Q, so the axes arrive at each pose together by construction.

Time law. u(t) is a trapezoid from rest at the first pose to rest at the last (rate ω, acceleration
α in poses per second and per second squared), with half an exposure at rest before and after, as a
one-axis line's. Each axis i then moves at q_i'(u)·u' and accelerates at q_i'(u)·u'' + q_i''(u)·u'²;
ω and α are chosen so that, over the whole path, the first stays within v_i and the second within
a_i: ω = min_i min(v_i / max|q_i'|, √(a_i / (2 max|q_i''|))), α = min_i a_i / (2 max|q_i'|) (half of
each axis's acceleration for each term). Maxima of the spline's pieces are exact (their derivatives are
quadratics and lines). Exposure: ``FLY_DUTY`` / ω, so a reading blurs over at most ``FLY_DUTY`` of a
grid step of Δφ, as on a one-axis line.

Checks. Limits: each axis's extremes over each piece of the spline (its ends and where its derivative
vanishes) are within the limits. Collisions: on each piece, the margins at its ends, g0 and g1
(:meth:`Kinematics.sweep_clear_one` of a position with itself), and an upper bound ℓ of its travel
summed over axes (max |q_i'| over the piece times its length) prove it clear when (g0 + g1 − ℓ)/2 ≥ 0
(a design's margin changes by at most the axes' travel summed: the premise of
:func:`gonio.kinematics.sweep.lipschitz_min`); pieces not proven are bisected a few levels, and a
line whose path is not proven clear is split at that step.

Where it runs: the simulated gantry renders along Q(u(t)) (:mod:`gonio.sim.fly`); a configured gantry
of Dynamixel servos flies it as straight segments between its poses, each started by one Sync Write of
every moving servo's goal and profile (:mod:`gonio.fly.segments`, :mod:`gonio.fly.hardware`); a gantry
whose moving axes cannot sweep refuses it by name (:func:`gonio.fly.units.check_fly_gantry`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gonio.plan.flyline import FLY_DUTY, FlyLine

__all__ = ["PathLine", "path_line", "COORDINATED"]

#: FlyLine.axis of a coordinated line (several axes move).
COORDINATED = -2
#: Knots per grid step along a ring (the path between two poses follows the ring to ~1e-4° and better).
SUB = 8
#: Bisection levels of a spline piece's collision proof.
_LEVELS = 8
#: Two consecutive poses of a ring are on one smooth path when no axis moves more than this many grid
#: steps between them (a change of IK branch moves an axis by tens of steps).
_MAX_AXIS_STEPS = 4.0


@dataclass(frozen=True)
class PathLine:
    """A coordinated sweep through the plan's poses ``poses`` (see the module docstring).

    Attributes
    ----------
    poses : ndarray of int64, shape (n,)
    knots_deg : ndarray, shape ((n − 1) · SUB + 1, n_axes)
        Axis positions along the path at u = 0, 1/SUB, ..., n − 1 (every SUB-th: a pose, in reading
        order).
    rate : float
        ω, poses per second at full speed.
    accel : float
        α, poses per second squared.
    exposure_s : float
    step_deg : float
        The grid step between readings (of Δφ): ``speed_deg_s`` is ω times it.
    note : str
    """

    poses: np.ndarray
    knots_deg: np.ndarray
    rate: float
    accel: float
    exposure_s: float
    step_deg: float
    note: str = ""
    axis: int = COORDINATED

    @property
    def n(self) -> int:
        return int(self.poses.size)

    @property
    def moving(self) -> bool:
        return True

    @property
    def speed_deg_s(self) -> float:
        """The top rate of the swept coordinate (Δφ), degrees per second."""
        return self.rate * abs(self.step_deg)

    @property
    def first_deg(self) -> np.ndarray:
        return self.knots_deg[0].copy()

    @property
    def start_deg(self) -> np.ndarray:
        return self.knots_deg[0].copy()

    @property
    def n_knots(self) -> int:
        return int(self.knots_deg.shape[0])

    @property
    def end_deg(self) -> np.ndarray:
        return self.knots_deg[-1].copy()

    @property
    def moving_axes(self) -> np.ndarray:
        """Which axes change along the path."""
        return np.ptp(self.knots_deg, axis=0) > 0.0

    def readings_deg(self) -> np.ndarray:
        return self.knots_deg[::SUB].copy()

    def _spline(self):
        from scipy.interpolate import CubicSpline

        return CubicSpline(np.arange(self.n_knots, dtype=np.float64) / SUB, self.knots_deg, axis=0)

    def _clock(self):
        """The time law u(t): a one-axis line over u (span n − 1 at ω, α), the same rests and exposure."""
        return FlyLine(self.poses, 0, np.zeros(1), 1.0, self.rate, self.accel, self.exposure_s)

    @property
    def duration_s(self) -> float:
        return self._clock().duration_s

    def mid_times(self) -> np.ndarray:
        return self._clock().mid_times()

    def pads(self) -> tuple[float, float]:
        return self._clock().pads()

    def position_at(self, t_s) -> np.ndarray:
        """Axis positions (..., n_axes) at times ``t_s`` after the line starts: Q(u(t))."""
        u = self._clock().position_at(t_s)[..., 0]
        return self._spline()(u)

    def travel_deg(self) -> np.ndarray:
        """Each axis's travel between consecutive poses, summed (no path through the poses in order
        travels less)."""
        return np.abs(np.diff(self.readings_deg(), axis=0)).sum(axis=0)


def _piece_extremes(c: np.ndarray, order: int) -> np.ndarray:
    """Max |d^order q / ds^order| over each piece of a cubic spline with coefficients ``c`` (4, P, A),
    q = c0 s³ + c1 s² + c2 s + c3 on s in [0, 1]: exact. Returns (P, A)."""
    if order == 1:
        a, b, cc = 3.0 * c[0], 2.0 * c[1], c[2]
        ends = np.maximum(np.abs(cc), np.abs(a + b + cc))
        with np.errstate(divide="ignore", invalid="ignore"):
            x = np.where(a != 0.0, -b / (2.0 * a), -1.0)
        inside = (x > 0.0) & (x < 1.0)
        vertex = np.abs(a * x * x + b * x + cc)
        return np.where(inside, np.maximum(ends, vertex), ends)
    a, b = 6.0 * c[0], 2.0 * c[1]
    return np.maximum(np.abs(b), np.abs(a + b))


def _piece_ranges(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) of q over each piece (P, A), exact: at the ends and where q' vanishes inside."""
    vals = [c[3], c[0] + c[1] + c[2] + c[3]]
    a, b, cc = 3.0 * c[0], 2.0 * c[1], c[2]
    disc = b * b - 4.0 * a * cc
    with np.errstate(divide="ignore", invalid="ignore"):
        root = np.sqrt(np.maximum(disc, 0.0))
        for sgn in (-1.0, 1.0):
            x = np.where(a != 0.0, (-b + sgn * root) / (2.0 * a), np.where(b != 0.0, -cc / b, -1.0))
            ok = (disc >= 0.0) & (x > 0.0) & (x < 1.0)
            q = ((c[0] * x + c[1]) * x + c[2]) * x + c[3]
            vals += [np.where(ok, q, c[3])]
    stack = np.stack(vals)
    return stack.min(axis=0), stack.max(axis=0)


def _clear_piece(kin, spline, speed, x0: float, x1: float, level: int) -> bool:
    """Whether the path Q over [x0, x1] is proven clear of collision (see the module docstring)."""
    g0 = kin.sweep_clear_one(spline(x0), spline(x0))[1]
    g1 = kin.sweep_clear_one(spline(x1), spline(x1))[1]
    if min(g0, g1) < -1e-9:
        return False
    if 0.5 * (g0 + g1 - speed * (x1 - x0)) >= -1e-9:
        return True
    if level >= _LEVELS:
        return False
    mid = 0.5 * (x0 + x1)
    return (_clear_piece(kin, spline, speed, x0, mid, level + 1)
            and _clear_piece(kin, spline, speed, mid, x1, level + 1))


def path_line(kin, plan, axes_deg: np.ndarray, i: int, j: int, step_deg: float) -> list:
    """The coordinated lines over the plan's poses [i, j) (consecutive poses of one ring): one
    :class:`PathLine` if its path is certified, else split at the first piece that is not (a part of
    one pose: a :class:`~gonio.plan.fly.FlyLine` stop-and-go reading). The path follows the ring: its
    knots are the inverse kinematics of ``SUB`` directions per step along it (Δφ linear between the
    poses), each solved from the nearest pose's axes (its branch); where they leave that branch (an
    axis jumps further in a sub-step than over the whole step) the line is read stop-and-go."""
    n = j - i
    poses = np.asarray(axes_deg[i:j], dtype=np.float64)
    if n < 2:
        return [FlyLine(np.array([i], dtype=np.int64), -1, poses[0].copy(), 0.0, 0.0, 1.0, 0.0, "")]
    u = np.arange((n - 1) * SUB + 1) / SUB
    angles = [np.unwrap(np.asarray(x[i:j], dtype=np.float64)) for x in (plan.theta_i, plan.phi_i,
                                                                      plan.theta_o, plan.phi_o)]
    dense = [np.interp(u, np.arange(n), x) for x in angles]
    near = np.rint(u).astype(np.int64)
    knots = kin.inverse(*dense, current_deg=poses[near])
    knots[::SUB] = poses            # the poses themselves, exactly
    # On the poses' branch, no axis moves more in a sub-step than over its whole step (and a grid step):
    # a change of branch jumps by tens of degrees at once.
    allowed = np.repeat(np.abs(np.diff(poses, axis=0)), SUB, axis=0) + step_deg
    if not (np.all(np.isfinite(knots)) and np.all(np.abs(np.diff(knots, axis=0)) <= allowed)):
        return [FlyLine(np.array([k], dtype=np.int64), -1, axes_deg[k].copy(), 0.0, 0.0, 1.0, 0.0,
                        "stop-and-go: its ring leaves one branch of the inverse kinematics")
                for k in range(i, j)]
    line = PathLine(np.arange(i, j, dtype=np.int64), knots, 1.0, 1.0, 0.0, step_deg)
    spline = line._spline()
    # scipy's pieces are polynomials in x − u_p, x in u; over s = (x − u_p) / h in [0, 1] instead.
    h = 1.0 / SUB
    c = spline.c * np.array([h**3, h**2, h, 1.0])[:, None, None]   # (4, P, A)
    lo, hi = np.asarray(kin.limits_deg, dtype=np.float64).T
    qmin, qmax = _piece_ranges(c)
    d1, d2 = _piece_extremes(c, 1) / h, _piece_extremes(c, 2) / h**2  # (P, A): per u and per u²
    bad = np.flatnonzero(((qmin < lo - 1e-9) | (qmax > hi + 1e-9)).any(axis=1))
    travel = d1.sum(axis=1)
    first_bad = int(bad[0]) if bad.size else None
    for p in range(c.shape[1]):
        if first_bad is not None and p >= first_bad:
            break
        if not _clear_piece(kin, spline, float(travel[p]), u[p], u[p + 1], 0):
            first_bad = p
            break
    if first_bad is not None:
        cut = first_bad // SUB + 1
        note = "split: its path collides or leaves a limit between two readings"
        return [_noted(x, note) for x in path_line(kin, plan, axes_deg, i, i + cut, step_deg)
                + path_line(kin, plan, axes_deg, i + cut, j, step_deg)]
    v = np.asarray(kin.velocity_deg_s, dtype=np.float64)
    a = np.asarray(kin.accel_deg_s2, dtype=np.float64)
    d1max, d2max = d1.max(axis=0), d2.max(axis=0)
    with np.errstate(divide="ignore"):
        rate = float(min(np.min(v / d1max), np.min(np.sqrt(a / (2.0 * d2max)))))
        accel = float(np.min(a / (2.0 * d1max)))
    return [PathLine(line.poses, knots, rate, accel, FLY_DUTY / rate, step_deg)]


def _noted(line, note: str):
    from dataclasses import replace

    return line if line.note else replace(line, note=note)


def ring_runs(plan, axes_deg: np.ndarray, step_deg: float, i: int, j: int) -> list[tuple[int, int]]:
    """Maximal runs [a, b) within the plan's poses [i, j) whose consecutive poses are on one ring (the
    same θi, θo), Δφ stepping by one signed grid step, no axis moving more than ``_MAX_AXIS_STEPS``
    grid steps (one smooth branch)."""
    ti, to = (np.degrees(np.asarray(x, dtype=np.float64)) for x in (plan.theta_i, plan.theta_o))
    dphi = np.degrees(np.asarray(plan.phi_o, dtype=np.float64) - np.asarray(plan.phi_i, dtype=np.float64))
    k = np.arange(i, j - 1)
    d = (dphi[k + 1] - dphi[k] + 180.0) % 360.0 - 180.0
    ok = ((np.abs(ti[k + 1] - ti[k]) < 1e-6) & (np.abs(to[k + 1] - to[k]) < 1e-6) & (ti[k] > 1e-6)
          & (to[k] > 1e-6) & (np.abs(np.abs(d) - step_deg) < 1e-6)
          & (np.abs(axes_deg[k + 1] - axes_deg[k]).max(axis=1) <= _MAX_AXIS_STEPS * step_deg))
    sign = np.sign(d)
    out, a = [], i
    while a < j:
        b = a + 1
        while b < j and ok[b - 1 - i] and sign[b - 1 - i] == sign[a - i]:
            b += 1
        out.append((a, b))
        a = b
    return out
