"""A brute-force replay of moves, independent of gonio's sweep check: dense time samples of each
axis's trapezoid and the collision rules written again from their definitions (plain numpy).

Used by the motion and plan tests to judge :meth:`Kinematics.sweep_clearance` and the planned paths.
"""

from __future__ import annotations

import numpy as np

# deg: the largest travel of any axis between two samples of a move.
STEP_DEG = 0.05
# deg: a sample counts as a collision only when it is past the rule by more than float noise.
NOISE_DEG = 1e-7


def trapezoid(t, start, target, v, a):
    """Positions (T, M) at times t (T, M) of rest-to-rest moves, from the profile's definition:
    accelerate at a to the peak speed min(v, sqrt(d a)), cruise, decelerate at a; hold the target."""
    d = np.abs(target - start)
    peak = np.minimum(v, np.sqrt(d * a))
    t_acc = peak / a
    dist_acc = 0.5 * a * t_acc**2
    t_cruise = np.where(peak > 0, (d - 2 * dist_acc) / np.where(peak > 0, peak, 1.0), 0.0)
    t_end = 2 * t_acc + t_cruise
    s = np.where(
        t < t_acc, 0.5 * a * t**2,
        np.where(t < t_acc + t_cruise, dist_acc + peak * (t - t_acc),
                 np.where(t < t_end, d - 0.5 * a * (t_end - t) ** 2, d)))
    return start + np.sign(target - start) * s


def collides(design: str, collision_deg: float, axes):
    """Whether positions (..., 4) break the design's collision rule (bool (...))."""
    if design == "two-arm":
        gap = np.mod(axes[..., 0] - axes[..., 2], 360.0)
        return np.minimum(gap, 360.0 - gap) < collision_deg - NOISE_DEG
    az, tilt = np.radians(axes[..., 2]), np.radians(axes[..., 3])
    detector = np.stack([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)], -1)
    to_support = np.degrees(np.arccos(np.clip(-detector[..., 1], -1.0, 1.0)))
    return to_support < collision_deg - NOISE_DEG


def replay(kin, start, end, step_deg: float = STEP_DEG, batch_samples: int = 400_000) -> np.ndarray:
    """Collisions found (bool (M,)) on moves (M, 4) -> (M, 4) sampled at least every ``step_deg`` of
    travel of the axis that travels most, both ends included, on every axis's own trapezoid.

    Moves are replayed in batches of similar length (the longest at most twice the shortest, at most
    ``batch_samples`` samples a batch), each move at its batch's longest count: never sparser than
    ``step_deg``, and no thousands of short moves padded to the count of a half-turn."""
    start = np.asarray(start, dtype=np.float64).reshape(-1, 4)
    end = np.asarray(end, dtype=np.float64).reshape(-1, 4)
    v, a = np.asarray(kin.velocity_deg_s), np.asarray(kin.accel_deg_s2)
    d = np.abs(end - start)
    peak = np.minimum(v, np.sqrt(d * a))
    cruise = np.where(peak > 0, (d - peak**2 / a) / np.where(peak > 0, peak, 1), 0)
    duration = np.max(2 * peak / a + cruise, 1)
    samples = np.maximum(np.ceil(np.max(d, axis=1) / step_deg).astype(int), 1) + 1
    hit = np.zeros(start.shape[0], dtype=bool)
    order = np.argsort(samples, kind="stable")
    counts = samples[order]
    lo = 0
    while lo < order.size:
        hi = lo + 1
        while (hi < order.size and counts[hi] <= 2 * counts[lo]
               and (hi + 1 - lo) * counts[hi] <= batch_samples):
            hi += 1
        idx = order[lo:hi]
        lo = hi
        k = int(counts[hi - 1])
        t = np.linspace(0.0, 1.0, k)[:, None] * duration[idx]
        pos = np.stack([trapezoid(t, start[idx, j], end[idx, j], v[j], a[j]) for j in range(4)], -1)
        hit[idx] = collides(kin.design, kin.arm_collision_deg, pos).any(axis=0)
    return hit


def planned_moves(kin, plan):
    """Every move the campaign makes, as (start (M, 4), end (M, 4)): home -> via points -> each moving
    step's target (darks stay) -> ... -> the park path home."""
    from gonio.plan import STEP_POSE, STEP_REFERENCE

    pts = [np.asarray(kin.home_deg, dtype=np.float64)]
    for s, kind in enumerate(plan.step_kind):
        if kind == STEP_POSE:
            target = plan.axes_deg[plan.step_pose[s]]
        elif kind == STEP_REFERENCE:
            target = plan.reference_axes_deg
        else:
            continue
        pts.extend(plan.via_deg.get(s, []))
        pts.append(target)
    pts.extend(plan.park_deg)
    pts = np.array(pts)
    return pts[:-1], pts[1:]
