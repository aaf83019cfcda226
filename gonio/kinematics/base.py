"""The kinematics interface shared by every gantry design, and the helpers the designs share.

A design maps axis positions (degrees, device quantities) to the pair of sample-frame directions
(ωi toward the light, ωo toward the detector) and back. The inverse is multi-valued: every design
enumerates a fixed number S of branches per pose (sign flips over the zenith, 360° wraps of azimuths
whose limits span more than a turn), and this base class turns those branches into the four things
the rest of gonio asks for: all valid branches (:meth:`Kinematics.solutions`), the nearest one
(:meth:`Kinematics.inverse`), the reason a pose cannot be reached (:meth:`Kinematics.feasibility`),
and the forward map (:meth:`Kinematics.forward`, :meth:`Kinematics.directions`).

Shapes: pose inputs broadcast against each other and are flattened (C order) to N poses, so scalars
give N = 1. Axis arrays are (N, n_axes) with columns in the order of ``axis_names``; a single (n_axes,)
row is accepted as N = 1. Sample-frame angles are radians; axis positions are degrees.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from gonio.geometry import sph_to_vec, vec_to_sph
from gonio.motion.trapezoid import move_time

if TYPE_CHECKING:  # type hints only: a design plugin is imported while gonio.config is
    from gonio.config import GonioConfig

__all__ = [
    "REASONS",
    "OK",
    "OUT_OF_REACH",
    "ARM_COLLISION",
    "OCCLUSION",
    "BEYOND_THETA_MAX",
    "Kinematics",
    "arm_vector",
    "azimuth_wraps",
    "circular_distance_deg",
    "nearest_allowed_azimuth",
    "wrap_360",
]

#: Why a pose cannot be reached; :meth:`Kinematics.feasibility` returns indices into this tuple (int8).
REASONS: tuple[str, ...] = ("ok", "out_of_reach", "arm_collision", "occlusion", "beyond_theta_max")
OK, OUT_OF_REACH, ARM_COLLISION, OCCLUSION, BEYOND_THETA_MAX = range(len(REASONS))

#: rad: a direction closer than this to the pole has no meaningful azimuth (the azimuth axis is free).
POLE_EPS = 1e-9
#: deg: round-off allowance when comparing computed angles with limits and collision boundaries, so
#: that a pose exactly on a boundary (e.g. θ = theta_max from a degree grid) is not lost to one ulp.
DEG_TOL = 1e-9
#: s: branches whose move times differ by less than this are ties (broken by the total move time).
TIME_TOL = 1e-9
# Poses per block in the public methods: bounds the (block, S, n_axes) temporaries to a few MB while
# keeping every block vectorized.
_BLOCK = 1 << 14

_POSE_FIELDS = ("theta_i", "phi_i", "theta_o", "phi_o")


def wrap_360(angle_deg) -> np.ndarray:
    """Angle(s) in degrees folded into [0°, 360°)."""
    out = np.mod(np.asarray(angle_deg, dtype=np.float64), 360.0)
    # np.mod can return exactly 360 for tiny negative inputs.
    return np.where(out >= 360.0, 0.0, out)


def circular_distance_deg(a_deg, b_deg) -> np.ndarray:
    """Smallest angle in degrees, in [0°, 180°], between azimuths ``a_deg`` and ``b_deg`` (mod 360°)."""
    d = wrap_360(np.asarray(a_deg, dtype=np.float64) - np.asarray(b_deg, dtype=np.float64))
    return np.minimum(d, 360.0 - d)


def azimuth_wraps(lo_deg: float, hi_deg: float) -> np.ndarray:
    """Turns k such that ``a + 360 k`` for a in [0°, 360°) covers every position in [lo_deg, hi_deg]."""
    return np.arange(np.floor(lo_deg / 360.0), np.floor(hi_deg / 360.0) + 1.0)


def arm_vector(azimuth_deg, tilt_deg) -> np.ndarray:
    """Unit vector(s) (..., 3) of an arm at carriage azimuth ``azimuth_deg`` and tilt ``tilt_deg``.

    The tilt is the polar angle from +z; a negative tilt swings the arm over the zenith, so
    (a, −t) points where (a + 180°, t) does.
    """
    a = np.radians(azimuth_deg)
    t = np.radians(tilt_deg)
    st = np.sin(t)
    return np.stack(np.broadcast_arrays(st * np.cos(a), st * np.sin(a), np.cos(t)), axis=-1)


def angle_between(u, v) -> np.ndarray:
    """Angle in radians between vectors ``u`` and ``v`` (..., 3); atan2 keeps precision near 0 and π."""
    u, v = np.broadcast_arrays(np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64))
    return np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1), np.sum(u * v, axis=-1))


def nearest_allowed_azimuth(current_deg, lo_deg: float, hi_deg: float, centre_deg, half_width_deg):
    """The azimuth in [lo_deg, hi_deg] nearest to ``current_deg`` outside the blocked arcs.

    The blocked arcs are the open intervals ``|a − centre − 360 k| < half_width`` for every k (an
    obstacle at azimuth ``centre_deg`` that the axis may not come within ``half_width_deg`` of); a
    half-width of 0 blocks nothing. This is the rule for a free azimuth (the arm at the pole): stay
    where it is when that is allowed, else move the shortest way to an allowed position. When no
    position in the limits is allowed, the result is ``current_deg`` brought into the limits (the
    caller's collision check then rejects it). Arrays broadcast; degrees.
    """
    current, centre, half = np.broadcast_arrays(
        np.asarray(current_deg, dtype=np.float64),
        wrap_360(centre_deg),
        np.asarray(half_width_deg, dtype=np.float64),
    )
    # The nearest point of a union of closed intervals is the point itself or an interval end, and
    # every end is a limit or an edge of a blocked arc: those are all the candidates there are.
    turns = np.arange(np.floor((lo_deg - 540.0) / 360.0), np.ceil((hi_deg + 180.0) / 360.0) + 1.0)
    edges = centre[..., None, None] + 360.0 * turns[:, None] + np.stack([-half, half], -1)[..., None, :]
    cands = np.concatenate(
        [
            current[..., None],
            np.broadcast_to(np.array([lo_deg, hi_deg]), current.shape + (2,)),
            edges.reshape(current.shape + (2 * turns.size,)),
        ],
        axis=-1,
    )
    inside = (cands >= lo_deg - DEG_TOL) & (cands <= hi_deg + DEG_TOL)
    clear = circular_distance_deg(cands, centre[..., None]) >= half[..., None] - DEG_TOL
    cost = np.where(inside & clear, np.abs(cands - current[..., None]), np.inf)
    best = np.take_along_axis(cands, np.argmin(cost, axis=-1)[..., None], axis=-1)[..., 0]
    found = np.isfinite(np.min(cost, axis=-1))
    return np.clip(np.where(found, best, current), lo_deg, hi_deg)


class Kinematics:
    """Base class of the gantry designs (see :mod:`gonio.kinematics.two_arm` and
    :mod:`gonio.kinematics.sample_stage`).

    Attributes
    ----------
    design : str
        The name the design is registered under (:data:`gonio.registries.DESIGNS`), from the config.
    axis_names : tuple of str
        The axes the design drives (a class attribute each design declares): the columns of every
        (N, n_axes) array, and the ``[axes.NAME]`` sections its config must have.
    limits_deg : ndarray, shape (n_axes, 2)
        [min, max] of each axis, degrees.
    velocity_deg_s, accel_deg_s2, home_deg : ndarray, shape (n_axes,)
        Maximum speed (°/s), acceleration (°/s²) and home position (°) of each axis.
    theta_max_deg, clearance_deg, arm_collision_deg : float
        From ``[kinematics]`` of the config, degrees.
    n_branches : int
        S, the number of inverse-kinematics branches enumerated per pose.
    """

    axis_names: tuple[str, ...] = ()

    def __init__(self, cfg: GonioConfig):
        from gonio.registries import DESIGNS

        design = cfg.kinematics.design
        if design not in DESIGNS or DESIGNS.load(design) is not type(self):
            raise ValueError(f"kinematics.design: {type(self).__name__} is not the kinematics of design "
                             f"'{design}'")
        self.design = design
        axes = [cfg.axes[name] for name in self.axis_names]
        self.limits_deg = _frozen([[a.min_deg, a.max_deg] for a in axes])
        self.velocity_deg_s = _frozen([a.max_velocity_deg_s for a in axes])
        self.accel_deg_s2 = _frozen([a.max_accel_deg_s2 for a in axes])
        self.home_deg = _frozen([a.home_deg for a in axes])
        self.theta_max_deg = float(cfg.kinematics.theta_max_deg)
        self.clearance_deg = float(cfg.kinematics.clearance_deg)
        self.arm_collision_deg = float(cfg.kinematics.arm_collision_deg)
        #: S: set by each design once it knows how many azimuth wraps its limits admit.
        self.n_branches = 0
        self._limits_list = [tuple(r) for r in self.limits_deg.tolist()]
        self._velocity_list = self.velocity_deg_s.tolist()
        self._accel_list = self.accel_deg_s2.tolist()

    def __repr__(self) -> str:
        return f"{type(self).__name__}(axes={self.axis_names}, theta_max_deg={self.theta_max_deg})"

    # --- what a design provides -----------------------------------------------------------------

    def _branches(self, theta_i, phi_i, theta_o, phi_o, current) -> tuple[np.ndarray, np.ndarray]:
        """Every branch of N validated poses (radians, (N,)) given the current axes (N, n_axes).

        Returns the candidates (N, S, n_axes) in degrees (limits not yet checked; free azimuths
        already chosen) and a mask (N, S) of the branches whose parts collide.
        """
        raise NotImplementedError

    def _directions(self, axes_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(ωi, ωo), each (N, 3), of validated axis positions (N, n_axes)."""
        raise NotImplementedError

    # --- public interface -----------------------------------------------------------------------

    def solutions(self, theta_i, phi_i, theta_o, phi_o, current_deg=None) -> np.ndarray:
        """Every inverse-kinematics branch of each pose.

        Parameters
        ----------
        theta_i, phi_i, theta_o, phi_o : array_like
            Sample-frame angles of ωi and ωo in radians; θ in [0, π/2], φ any finite value. They
            broadcast against each other and are flattened to N poses.
        current_deg : array_like, shape (n_axes,) or (N, n_axes), optional
            Axis positions in degrees now (home when None). A free azimuth (its arm at θ = 0) keeps
            its current value when that is within its limits and collision-free, else takes the
            nearest value that is.

        Returns
        -------
        ndarray, shape (N, S, n_axes)
            Axis positions in degrees. A branch is NaN when it violates a limit or collides, and every
            branch of a pose is NaN when the pose is beyond theta_max or occluded.
        """
        return self._blocked(self._solutions, theta_i, phi_i, theta_o, phi_o, current_deg)

    def inverse(self, theta_i, phi_i, theta_o, phi_o, current_deg=None) -> np.ndarray:
        """The valid branch nearest to ``current_deg`` for each pose.

        "Nearest" is the shortest move: the smallest maximum over axes of the trapezoidal move time
        (:func:`gonio.motion.trapezoid.move_time`) from ``current_deg``; ties (within 1 ns) go to the
        smallest total move time, then to the first branch.

        Parameters
        ----------
        theta_i, phi_i, theta_o, phi_o, current_deg
            As for :meth:`solutions`.

        Returns
        -------
        ndarray, shape (N, n_axes)
            Axis positions in degrees; a row is NaN where the pose has no valid branch (see
            :meth:`feasibility` for why).
        """
        return self._blocked(self._inverse, theta_i, phi_i, theta_o, phi_o, current_deg)

    def feasibility(self, theta_i, phi_i, theta_o, phi_o) -> np.ndarray:
        """Why each pose can or cannot be reached: an int8 index into :data:`REASONS`, shape (N,).

        0 (``ok``) when some branch is valid. Otherwise the first that applies of: ``beyond_theta_max``
        (θi or θo above theta_max_deg), ``occlusion`` (ωi and ωo closer than clearance_deg),
        ``out_of_reach`` (no branch within the axis limits), ``arm_collision`` (every branch within
        the limits collides). The answer does not depend on where the axes are: a free azimuth finds a
        collision-free position whenever its limits hold one.
        """
        return self._blocked(self._feasibility, theta_i, phi_i, theta_o, phi_o, None)

    def forward(self, axes_deg) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(θi, φi, θo, φo) in radians, each (N,), of axis positions ``axes_deg`` (N, n_axes) or
        (n_axes,) in degrees; φ in [0, 2π) and 0 at the pole. Pure geometry: limits are not checked
        (positions read back from moving axes are welcome)."""
        wi, wo = self.directions(axes_deg)
        theta_i, phi_i = vec_to_sph(wi)
        theta_o, phi_o = vec_to_sph(wo)
        return theta_i, phi_i, theta_o, phi_o

    def directions(self, axes_deg) -> tuple[np.ndarray, np.ndarray]:
        """(ωi, ωo): unit vectors (N, 3) in the sample frame of axis positions ``axes_deg`` (N, n_axes)
        or (n_axes,) in degrees."""
        return self._directions(self._axes(axes_deg, "axes_deg"))

    # --- moves in transit -------------------------------------------------------------------------

    #: One line naming the collision rule a blocked move breaks (set by each design).
    collision_rule: str = ""

    def sweep_clearance(self, start_deg, end_deg) -> tuple[np.ndarray, np.ndarray]:
        """Whether each move is clear over its whole swept path, certified (not merely sampled).

        Every axis starts at the same instant on its own rest-to-rest trapezoid (per-axis maximum
        velocity and acceleration) and holds its target once its profile ends, as the runner and the
        simulated axes move them. A move is clear when both ends are within the axis limits (axes move
        monotonically, so the limits then hold throughout) and the design's collision rule holds at
        every instant (see :mod:`gonio.kinematics.sweep` for how that is proved).

        Parameters
        ----------
        start_deg, end_deg : array_like, shape (M, n_axes) or (n_axes,)
            Rest positions before and after each move, degrees (finite).

        Returns
        -------
        clear : ndarray of bool, shape (M,)
            True when the move can be made as it is.
        min_margin_deg : ndarray, shape (M,)
            The smallest margin to the collision rule over the move, degrees (negative: it collides);
            exact on the two-arm gantry, a certified lower bound on the sample-stage gantry (within
            1e-3° of the true minimum when negative). Limits are not part of it.
        """
        start, end = self._moves(start_deg, end_deg)
        margin = self._sweep_margin(start, end) if start.shape[0] else np.empty(0)
        return (margin >= -DEG_TOL) & self.within_limits(start) & self.within_limits(end), margin

    def sweep_clear(self, start_deg, end_deg) -> np.ndarray:
        """The first result of :meth:`sweep_clearance` alone (bool (M,)), the same move for move, without
        the margins: quicker where a design refines a margin only until it is known to break the rule
        (the planner asks this of every candidate move)."""
        start, end = self._moves(start_deg, end_deg)
        margin = self._sweep_margin_below(start, end, -DEG_TOL) if start.shape[0] else np.empty(0)
        return (margin >= -DEG_TOL) & self.within_limits(start) & self.within_limits(end)

    def _moves(self, start_deg, end_deg) -> tuple[np.ndarray, np.ndarray]:
        """Validated (start, end) rows of moves, one row broadcast against the other's count."""
        start = self._axes(start_deg, "start_deg")
        end = self._axes(end_deg, "end_deg")
        if start.shape != end.shape:
            if start.shape[0] == 1:
                start = np.broadcast_to(start, end.shape)
            elif end.shape[0] == 1:
                end = np.broadcast_to(end, start.shape)
            else:
                raise ValueError(f"start_deg, end_deg: {start.shape[0]} and {end.shape[0]} rows; give equal "
                                 "counts or one row")
        return start, end

    def sweep_clear_one(self, start_deg, end_deg) -> tuple[bool, float]:
        """:meth:`sweep_clearance` of one move given as two sequences of floats (unvalidated), in plain
        Python: the runner asks this before every move, where numpy's per-call cost would dominate."""
        start = [float(x) for x in start_deg]
        end = [float(x) for x in end_deg]
        margin = self._sweep_margin_one(start, end)
        inside = all(lo - DEG_TOL <= x <= hi + DEG_TOL and lo - DEG_TOL <= y <= hi + DEG_TOL
                     for (lo, hi), x, y in zip(self._limits_list, start, end, strict=True))
        return margin >= -DEG_TOL and inside, margin

    def within_limits(self, axes_deg) -> np.ndarray:
        """Rows (N,) of ``axes_deg`` (N, n_axes) inside every axis limit (within round-off)."""
        axes = np.asarray(axes_deg, dtype=np.float64).reshape(-1, len(self.axis_names))
        lo, hi = self.limits_deg[:, 0], self.limits_deg[:, 1]
        return np.all((axes >= lo - DEG_TOL) & (axes <= hi + DEG_TOL), axis=1)

    def free_component(self, axes_deg) -> np.ndarray:
        """Label (N,) of the connected part of the collision-free axis space each row lies in.

        Two positions with different labels cannot be joined by any collision-free motion (the two
        carriages of a two-arm gantry cannot pass each other); equal labels can. Meaningful only for
        positions that are themselves clear.
        """
        return np.zeros(np.asarray(axes_deg).reshape(-1, len(self.axis_names)).shape[0], dtype=np.int64)

    def coupled_axes(self, name: str) -> tuple[str, ...]:
        """The axes that must move along with ``name`` (same direction, same speed, so that their
        differences stay as they are) when it moves without a planned path, as when it seeks its
        reference stop while its position is unknown (none by default)."""
        return ()

    def detours(self) -> list[tuple[int, float]]:
        """(axis, value) pairs worth trying as a via position for one axis when a move is blocked: a
        value where that axis keeps the parts clear whatever the others do (none by default)."""
        return []

    def box_clear(self, lo_deg, hi_deg) -> bool:
        """Whether every position in the axis-aligned box [lo_deg, hi_deg] (n_axes each) is within the
        limits and clear of collision, certified: any path that stays in the box is then clear (a
        swept fly turnaround: one axis runs out and back while others move). The design's margin
        changes by at most the axes' travel summed (the premise of
        :func:`gonio.kinematics.sweep.lipschitz_min`), so the margin at the centre less the half
        widths summed bounds it over the box."""
        lo, hi = (np.asarray(x, dtype=np.float64) for x in (lo_deg, hi_deg))
        if not (self.within_limits(lo[None])[0] and self.within_limits(hi[None])[0]):
            return False
        centre = [float(x) for x in 0.5 * (lo + hi)]
        return self._sweep_margin_one(centre, centre) - float(np.sum(hi - lo)) / 2.0 >= -DEG_TOL

    def _sweep_margin(self, start: np.ndarray, end: np.ndarray) -> np.ndarray:
        """Smallest collision margin (M,) in degrees over moves (M, n_axes) -> (M, n_axes)."""
        raise NotImplementedError

    def _sweep_margin_below(self, start: np.ndarray, end: np.ndarray, floor: float) -> np.ndarray:
        """:meth:`_sweep_margin`, except that a margin below ``floor`` may be any value below it (a design
        whose margins are refined iteratively stops there; by default the margins themselves)."""
        return self._sweep_margin(start, end)

    def _sweep_margin_one(self, start: list, end: list) -> float:
        """:meth:`_sweep_margin` of one move in plain floats."""
        return float(self._sweep_margin(np.array([start]), np.array([end]))[0])

    # --- machinery ------------------------------------------------------------------------------

    def _blocked(self, fn, theta_i, phi_i, theta_o, phi_o, current_deg):
        """Validate, then run ``fn`` over blocks of poses and join the results."""
        poses = _poses(theta_i, phi_i, theta_o, phi_o)
        n = poses[0].shape[0]
        current = self.home_deg if current_deg is None else self._axes(current_deg, "current_deg")
        if current.ndim == 2 and current.shape[0] not in (1, n):
            raise ValueError(f"current_deg: {current.shape[0]} rows for {n} poses; give 1 row or {n}")
        current = np.broadcast_to(current, (n, len(self.axis_names)))
        parts = [
            fn(*(p[s : s + _BLOCK] for p in poses), current[s : s + _BLOCK])
            for s in range(0, max(n, 1), _BLOCK)
        ]
        return np.concatenate(parts, axis=0)

    def _evaluate(self, theta_i, phi_i, theta_o, phi_o, current):
        """Candidates snapped into the limits, and the masks (in_limits, collides, beyond, occluded)."""
        cands, collides = self._branches(theta_i, phi_i, theta_o, phi_o, current)
        lo, hi = self.limits_deg[:, 0], self.limits_deg[:, 1]
        in_limits = np.all((cands >= lo - DEG_TOL) & (cands <= hi + DEG_TOL), axis=-1)
        # Only round-off is absorbed here: a candidate that is out by more than DEG_TOL stays out.
        cands = np.where(in_limits[..., None], np.clip(cands, lo, hi), cands)
        tmax = np.radians(self.theta_max_deg) + np.radians(DEG_TOL)
        beyond = (theta_i > tmax) | (theta_o > tmax)
        sep = angle_between(sph_to_vec(theta_i, phi_i), sph_to_vec(theta_o, phi_o))
        occluded = sep < np.radians(self.clearance_deg - DEG_TOL)
        return cands, in_limits, collides, beyond, occluded

    def _solutions(self, theta_i, phi_i, theta_o, phi_o, current):
        cands, in_limits, collides, beyond, occluded = self._evaluate(theta_i, phi_i, theta_o, phi_o, current)
        valid = in_limits & ~collides & ~(beyond | occluded)[:, None]
        return np.where(valid[..., None], cands, np.nan)

    def _inverse(self, theta_i, phi_i, theta_o, phi_o, current):
        sols = self._solutions(theta_i, phi_i, theta_o, phi_o, current)
        times = move_time(sols - current[:, None, :], self.velocity_deg_s, self.accel_deg_s2)
        valid = ~np.isnan(sols[..., 0])
        slowest = np.where(valid, np.max(times, axis=-1), np.inf)
        total = np.where(valid, np.sum(times, axis=-1), np.inf)
        fastest = np.min(slowest, axis=-1, keepdims=True)
        near = slowest <= fastest + TIME_TOL
        pick = np.argmin(np.where(near, total, np.inf), axis=-1)
        return np.take_along_axis(sols, pick[:, None, None], axis=1)[:, 0, :]

    def _feasibility(self, theta_i, phi_i, theta_o, phi_o, current):
        _, in_limits, collides, beyond, occluded = self._evaluate(theta_i, phi_i, theta_o, phi_o, current)
        reach = np.any(in_limits, axis=-1)
        clear = np.any(in_limits & ~collides, axis=-1)
        code = np.select(
            [beyond, occluded, ~reach, ~clear],
            [BEYOND_THETA_MAX, OCCLUSION, OUT_OF_REACH, ARM_COLLISION],
            default=OK,
        )
        return code.astype(np.int8)

    def _axes(self, axes_deg, field: str) -> np.ndarray:
        """Validated axis positions: (N, n_axes) float64, or (n_axes,) for a single row."""
        n_axes = len(self.axis_names)
        arr = np.asarray(axes_deg, dtype=np.float64)
        if arr.ndim not in (1, 2) or arr.shape[-1] != n_axes:
            raise ValueError(
                f"{field}: expected shape ({n_axes},) or (N, {n_axes}) with columns "
                f"{', '.join(self.axis_names)}; got shape {arr.shape}"
            )
        bad = ~np.isfinite(arr.reshape(-1, n_axes)).all(axis=0)
        if bad.any():
            names = ", ".join(f"'{n}'" for n, b in zip(self.axis_names, bad, strict=True) if b)
            raise ValueError(f"{field}: axis {names} holds NaN or inf; positions must be finite degrees")
        return arr if field == "current_deg" else arr.reshape(-1, n_axes)


def _frozen(values) -> np.ndarray:
    arr = np.array(values, dtype=np.float64)
    arr.setflags(write=False)
    return arr


def _poses(theta_i, phi_i, theta_o, phi_o) -> tuple[np.ndarray, ...]:
    """Validated pose angles, broadcast and flattened to (N,) float64 each."""
    arrays = []
    for name, value in zip(_POSE_FIELDS, (theta_i, phi_i, theta_o, phi_o), strict=True):
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"{name}: expected a number or an array of numbers (radians)") from None
        if not np.isfinite(arr).all():
            raise ValueError(f"{name}: NaN or inf is not an angle; give finite radians")
        if name.startswith("theta") and ((arr < 0.0) | (arr > 0.5 * np.pi)).any():
            worst = arr.flat[np.argmax(np.abs(arr - 0.25 * np.pi))]
            raise ValueError(
                f"{name}: {worst:.6g} rad ({np.degrees(worst):.4g}°) is outside the allowed range "
                f"[0, π/2] rad ([0°, 90°])"
            )
        arrays.append(arr)
    try:
        arrays = np.broadcast_arrays(*arrays)
    except ValueError:
        shapes = ", ".join(f"{n} {a.shape}" for n, a in zip(_POSE_FIELDS, arrays, strict=True))
        raise ValueError(f"theta_i, phi_i, theta_o, phi_o: shapes do not broadcast: {shapes}") from None
    return tuple(a.reshape(-1) for a in arrays)
