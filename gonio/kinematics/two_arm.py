"""The two-arm gantry: a fixed sample, a light arm and a detector arm on one azimuth ring.

Axes (degrees), in column order: ``light_azimuth``, ``light_tilt``, ``detector_azimuth``,
``detector_tilt``. The sample frame is the lab frame (the sample does not move). Each arm's carriage
rides the ring at its azimuth a (about the sample normal +z, counter-clockwise from +x seen from above);
its tilt t is the arm's polar angle from +z, and a negative tilt swings the arm over the zenith, so
(a, t) points along θ = |t|, φ = a (t ≥ 0) or φ = a + 180° (t < 0).

Inverse branches per arm: (φ + 360k, θ) and (φ + 180° + 360k, −θ) for every turn k that the azimuth
limits admit (limits of [−200°, 200°] admit two turns, so four branches per arm and S = 16 pairs).

Arm collision: both carriages ride the one ring, so their azimuths may not come within
``arm_collision_deg`` of each other (mod 360°), whatever the tilts. Flipping one arm over the zenith
moves its carriage by 180°, which is how most close-azimuth poses (Δφ near 0° or 180°) stay reachable.

In transit: the carriage azimuth difference d(t) = a_light(t) − a_detector(t) is piecewise quadratic in
t, so its range over a move is found exactly (:func:`~gonio.kinematics.sweep.difference_range`); the
move is clear when that range keeps ``arm_collision_deg`` from every multiple of 360°. The free
axis space falls into strips of d between consecutive multiples of 360° (the carriages' order around
the ring and the cable wrap): no motion leaves its strip (:meth:`TwoArm.free_component`).

Free azimuth: an arm at θ = 0 may sit at any azimuth. It keeps its current position (home when none
is given) when that is within its limits and clear of the other carriage, and otherwise moves the
shortest way to the nearest position that is on its side of the other carriage (it cannot pass it);
only when the limits leave no such position does it take the nearest clear one anywhere. When both
arms are at θ = 0, two branches are offered
(the light keeps its azimuth and the detector steps aside, or the other way round) and
:meth:`~gonio.kinematics.base.Kinematics.inverse` takes the quicker.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from gonio.kinematics.base import (
    DEG_TOL,
    POLE_EPS,
    Kinematics,
    arm_vector,
    azimuth_wraps,
    circular_distance_deg,
    nearest_allowed_azimuth,
    wrap_360,
)
from gonio.kinematics.sweep import difference_range, difference_range_scalar

if TYPE_CHECKING:  # type hints only: a design plugin is imported while gonio.config is
    from gonio.config import GonioConfig

__all__ = ["TwoArm", "arm_branches"]


def arm_branches(theta, phi, wraps) -> tuple[np.ndarray, np.ndarray]:
    """(azimuth, tilt) in degrees, each (N, 2K), of every way an arm can point along (θ, φ).

    Parameters
    ----------
    theta, phi : ndarray, shape (N,)
        The direction, radians.
    wraps : ndarray, shape (K,)
        The turns k to try (from :func:`~gonio.kinematics.base.azimuth_wraps`).

    Returns
    -------
    azimuth, tilt : ndarray, shape (N, 2K)
        The first K columns are (φ + 360k, θ); the last K the flipped (φ + 180° + 360k, −θ). At the
        pole (θ < 1e-9 rad) the tilt is exactly 0 and the azimuth is meaningless (the caller frees it).
    """
    theta_deg = np.where(theta < POLE_EPS, 0.0, np.degrees(theta))
    phi_deg = np.degrees(phi)
    base = np.stack([wrap_360(phi_deg), wrap_360(phi_deg + 180.0)], axis=1)
    azimuth = base[:, :, None] + 360.0 * wraps
    # + 0.0 turns the flipped tilt at the pole from −0.0 into 0.0.
    tilt = np.stack([theta_deg, -theta_deg + 0.0], axis=1)[:, :, None] + np.zeros_like(wraps)
    shape = (theta.shape[0], 2 * wraps.size)
    return azimuth.reshape(shape), tilt.reshape(shape)


class TwoArm(Kinematics):
    """Kinematics of the two-arm gantry (see the module docstring for frames, branches and rules).

    Parameters
    ----------
    cfg : GonioConfig
        A config whose ``kinematics.design`` is ``"two-arm"``.

    Examples
    --------
    >>> from gonio.config import load_config
    >>> kin = TwoArm(load_config())           # config/sim.toml
    >>> kin.inverse(np.radians(30), 0.0, np.radians(45), np.pi).round(6).tolist()
    [[0.0, 30.0, 180.0, 45.0]]
    """

    #: The axes this design drives, in the order of every axis array.
    axis_names = ("light_azimuth", "light_tilt", "detector_azimuth", "detector_tilt")

    def __init__(self, cfg: GonioConfig):
        super().__init__(cfg)
        self._wraps_light = azimuth_wraps(*self.limits_deg[0])
        self._wraps_detector = azimuth_wraps(*self.limits_deg[2])
        self.n_branches = 4 * len(self._wraps_light) * len(self._wraps_detector)

    def _branches(self, theta_i, phi_i, theta_o, phi_o, current):
        n = theta_i.shape[0]
        (lo_l, hi_l), (lo_d, hi_d) = self.limits_deg[0], self.limits_deg[2]
        col = self.arm_collision_deg
        az_l, tilt_l = arm_branches(theta_i, phi_i, self._wraps_light)
        az_d, tilt_d = arm_branches(theta_o, phi_o, self._wraps_detector)
        n_l, n_d = az_l.shape[1], az_d.shape[1]
        pole_l = theta_i < POLE_EPS
        pole_d = theta_o < POLE_EPS
        # Pair every light branch (axis 1) with every detector branch (axis 2).
        pair_l = np.repeat(az_l[:, :, None], n_d, axis=2)
        pair_d = np.repeat(az_d[:, None, :], n_l, axis=1)
        cur_l = current[:, 0, None, None]
        cur_d = current[:, 2, None, None]

        # One arm at the pole: it steps aside from the other's carriage (if it has to). Only those
        # poses are solved, so the common case pays nothing for the search.
        strip = np.floor((cur_l - cur_d) / 360.0)
        one = pole_l & ~pole_d
        pair_l[one] = self._aside(cur_l[one], az_d[one][:, None, :], strip[one], True)
        one = pole_d & ~pole_l
        pair_d[one] = self._aside(cur_d[one], az_l[one][:, :, None], strip[one], False)
        # Both at the pole: the two sign branches of the light arm coincide there, so its first half
        # carries "light stays, detector steps aside" and the second half the converse.
        both = pole_l & pole_d
        if both.any():
            keep_l = np.clip(cur_l[both], lo_l, hi_l)
            keep_d = np.clip(cur_d[both], lo_d, hi_d)
            aside_d = self._aside(cur_d[both], keep_l, strip[both], False)
            aside_l = self._aside(cur_l[both], keep_d, strip[both], True)
            light_stays = (np.arange(n_l) < n_l // 2)[None, :, None]
            pair_l[both] = np.where(light_stays, keep_l, aside_l)
            pair_d[both] = np.where(light_stays, aside_d, keep_d)
        az_l, az_d = pair_l, pair_d

        collides = circular_distance_deg(az_l, az_d) < col - DEG_TOL
        cands = np.stack(
            np.broadcast_arrays(az_l, tilt_l[:, :, None], az_d, tilt_d[:, None, :]), axis=-1
        )
        return cands.reshape(n, n_l * n_d, 4), collides.reshape(n, n_l * n_d)

    def _aside(self, current, other, strip, is_light):
        """Where a free carriage goes (broadcast shape of the inputs, degrees): the position nearest
        ``current`` that keeps clear of the other carriage at ``other`` and on the same side of it as
        now (strip k of the difference light − detector, from the current axes), since it cannot pass
        the other carriage on the way. When the limits leave no such position, the nearest clear one
        anywhere (the move there then needs the other carriage out of the way, or is refused)."""
        col = self.arm_collision_deg
        j = 0 if is_light else 2
        lo, hi = self.limits_deg[j]
        if is_light:   # a_light − other in [360k + col, 360k + 360 − col]
            low, high = other + 360.0 * strip + col, other + 360.0 * strip + 360.0 - col
        else:          # other − a_detector in the same band
            low, high = other - 360.0 * strip - 360.0 + col, other - 360.0 * strip - col
        low, high = np.maximum(low, lo), np.minimum(high, hi)
        fallback = nearest_allowed_azimuth(current, lo, hi, other, col)
        return np.where(low <= high, np.clip(current, low, np.maximum(low, high)), fallback)

    def _directions(self, axes_deg):
        return arm_vector(axes_deg[:, 0], axes_deg[:, 1]), arm_vector(axes_deg[:, 2], axes_deg[:, 3])

    @property
    def collision_rule(self) -> str:
        return (f"the light and detector carriages share one ring and may not come within "
                f"kinematics.arm_collision_deg = {self.arm_collision_deg:g}° of each other, nor pass")

    def coupled_axes(self, name: str) -> tuple[str, ...]:
        """The carriages share one ring: one that seeks its stop with its position unknown takes the
        other along, so their azimuth difference, and so their clearance, stays as it was."""
        pair = ("light_azimuth", "detector_azimuth")
        return tuple(n for n in pair if n != name) if name in pair else ()

    def free_component(self, axes_deg):
        """Strip k of the carriage difference d = a_light − a_detector: d in (360k, 360(k + 1))."""
        axes = np.asarray(axes_deg, dtype=np.float64).reshape(-1, 4)
        return np.floor((axes[:, 0] - axes[:, 2]) / 360.0).astype(np.int64)

    def box_clear(self, lo_deg, hi_deg) -> bool:
        """Exactly: the collision rule is the carriages' azimuth difference alone, whose range over the
        box is [lo_light − hi_detector, hi_light − lo_detector]."""
        lo, hi = (np.asarray(x, dtype=np.float64) for x in (lo_deg, hi_deg))
        if not (self.within_limits(lo[None])[0] and self.within_limits(hi[None])[0]):
            return False
        margin = _ring_margin(np.array([lo[0] - hi[2]]), np.array([hi[0] - lo[2]]), self.arm_collision_deg)
        return bool(margin[0] >= -DEG_TOL)

    def _sweep_margin(self, start, end):
        v, a = self.velocity_deg_s, self.accel_deg_s2
        lo, hi = difference_range(start[:, 0], end[:, 0], start[:, 2], end[:, 2], v[0], a[0], v[2], a[2])
        return _ring_margin(lo, hi, self.arm_collision_deg)

    def _sweep_margin_one(self, start, end):
        v, a = self._velocity_list, self._accel_list
        lo, hi = difference_range_scalar(start[0], end[0], start[2], end[2], v[0], a[0], v[2], a[2])
        # The smallest distance to a multiple of 360° over [lo, hi]: zero when one lies inside.
        if math.ceil(lo / 360.0) * 360.0 <= hi:
            sep = 0.0
        else:
            sep = min(min(x % 360.0, 360.0 - x % 360.0) for x in (lo, hi))
        return sep - self.arm_collision_deg


def _ring_margin(lo, hi, collision_deg):
    """Smallest carriage separation minus ``collision_deg`` over a difference range [lo, hi] (degrees)."""
    crosses = np.ceil(lo / 360.0) * 360.0 <= hi
    sep = np.minimum(circular_distance_deg(lo, 0.0), circular_distance_deg(hi, 0.0))
    return np.where(crosses, 0.0, sep) - collision_deg
