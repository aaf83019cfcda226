"""What a round's poses cost in gantry time, and the choice of poses that trades error against it.

A round's tour starts and ends at the white reference (the checkpoint before it and the one that closes
it), and each pose costs its settle and reading (``fixed_s``) plus the moves that reach it. A pose near
others of the round is cheap: the tour passes it on the way. :func:`cheapest_first` picks ``n`` of a
pool of candidate poses greedily by

    E_j / (fixed_s + Δ_j) ** weight,

with E_j the candidate's share of the error (:func:`gonio.adaptive.refine.cell_errors`) and Δ_j its
move time (:class:`gonio.motion.metric.MoveMetric`, the axes' speeds and accelerations) from the nearest
pose chosen so far or from the reference: the cost of a detour to it, a nearest-neighbour stand-in for
its insertion into the tour. ``weight`` 0 takes the pool in order of E_j; 1 divides by the time.

The axis positions are those :meth:`gonio.kinematics.base.Kinematics.inverse` gives nearest the
reference pose's; the tour itself is planned afterwards as any grid's (:func:`gonio.plan.build.build_plan`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gonio.motion.metric import MoveMetric

__all__ = ["Motion", "round_motion", "cheapest_first", "POOL"]

#: Candidate poses placed per pose taken. At 148 poses (``iso:step=20``'s count) a pool of 3 · n let the
#: cost pass over the worst cells: lambert+ggx 0.0567 (3.6x below the uniform grid), with 2 0.0472
#: (4.3x); the other panel materials stay above 4x (BENCHMARKS.md, "Motion cost").
POOL = 2


@dataclass(frozen=True)
class Motion:
    """How a round's poses are costed.

    Attributes
    ----------
    start_deg : ndarray, shape (n_axes,)
        Axis positions the round's tour starts and ends at (the white reference pose).
    fixed_s : float
        Seconds each pose costs wherever it is (settle and reading).
    weight : float
        Exponent of the cost in a candidate's worth (0: motion ignored).
    pool : int
        Candidate poses placed per pose taken (:func:`gonio.adaptive.refine.plan_round`: the cells of
        the pool · n largest errors).
    """

    start_deg: np.ndarray
    fixed_s: float
    weight: float = 1.0
    pool: int = POOL


def round_motion(cfg, kin, weight: float = 1.0, pool: int = POOL) -> Motion:
    """The :class:`Motion` of the gantry ``cfg`` (``kin`` its kinematics): its reference pose's axis
    positions nearest home, its settle time and its reading time per pose; ``pool`` candidates per pose
    taken."""
    r = cfg.reference
    start = kin.inverse(*(np.radians([x]) for x in (r.theta_i_deg, 0.0, r.theta_o_deg, r.dphi_deg)))[0]
    if not np.all(np.isfinite(start)):
        start = np.asarray(kin.home_deg, dtype=np.float64)
    fixed = float(cfg.runner.settle_s + cfg.detector.exposure_s * cfg.detector.frames)
    return Motion(np.asarray(start, dtype=np.float64), fixed, float(weight), int(pool))


def cheapest_first(kin, motion: Motion, theta_i, theta_o, dphi, worth, n: int, phi_i=None) -> np.ndarray:
    """Indices of ``n`` of the candidate poses (θi, θo, Δφ as measured, φi = 0 unless ``phi_i`` gives it,
    φo = φi + Δφ; radians), in the order chosen (module docstring); ``worth`` (P,) their E_j. Candidates
    without a valid branch cost as if at the reference."""
    worth = np.asarray(worth, dtype=np.float64)
    p = worth.size
    n = min(int(n), p)
    ti = np.asarray(theta_i, dtype=np.float64)
    pi_ = np.zeros_like(ti) if phi_i is None else np.asarray(phi_i, dtype=np.float64)
    axes = kin.inverse(ti, pi_, np.asarray(theta_o, dtype=np.float64),
                       pi_ + np.asarray(dphi, dtype=np.float64), current_deg=motion.start_deg)
    axes = np.where(np.isfinite(axes), axes, motion.start_deg[None, :])
    metric = MoveMetric(kin.velocity_deg_s, kin.accel_deg_s2)
    reach = metric.time(motion.start_deg[None, :], axes)
    free = np.ones(p, dtype=bool)
    chosen = np.empty(n, dtype=np.int64)
    for k in range(n):
        gain = np.where(free, worth / (motion.fixed_s + reach) ** motion.weight, -np.inf)
        best = int(np.argmax(gain))
        chosen[k] = best
        free[best] = False
        reach = np.minimum(reach, metric.time(axes[best][None, :], axes))
    return chosen
