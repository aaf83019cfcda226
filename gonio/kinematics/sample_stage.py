"""The sample-stage gantry, in the manner of four-axis commercial gonio-photometers.

Axes (degrees), in column order: ``sample_rotation``, ``sample_tilt``, ``detector_azimuth``,
``detector_tilt``.

Frames. The lab frame has +z straight up, toward the light, which is fixed there; the tilt stage turns
about lab +y. The sample sits on a rotation stage (about its own normal) on the tilt stage, and at
rotation = tilt = 0 the sample frame is the lab frame. A sample-frame vector v is, in the lab,

    v_lab = R_y(tilt) · R_z(rotation) · v_sample

with R_z(a) counter-clockwise about +z seen from above and R_y(a) right-handed about +y, so a positive
tilt tips the sample normal toward lab +x. Seen from the sample the light is therefore at
θi = |tilt| and φi = 180° − rotation (tilt > 0) or φi = −rotation (tilt < 0). The detector arm turns
about lab +z (``detector_azimuth``, counter-clockwise from lab +x) and tilts to the polar angle
``detector_tilt`` from lab +z; a negative tilt swings it over the zenith, as for the two-arm gantry.

Inverse branches: tilt = +θi with rotation = 180° − φi + 360k, or tilt = −θi with rotation =
−φi + 360k; each puts the detector direction ωo at one lab direction (β, α), reached as
(α + 360k', β) or (α + 180° + 360k', −β). With the limits of config/sample-stage.toml that is
2·2 × 2·2 = 16 branches. The two tilt signs put the detector at lab directions a half turn apart about
lab z, and the detector may need to go below the lab horizon (β up to θi + θo): hence its tilt range.

Arm collision. The rotation and tilt stages are carried from the lab −y side by a support along the
tilt axis (a cantilevered tilt stage, which keeps the space under the sample free for the detector arm).
The detector may not come within ``arm_collision_deg`` of lab −y, where it would run into that support.
Because the other tilt sign moves the detector a half turn about lab z, away from the support, only a
pose whose tilt cannot flip (limits, or θi = 0) can be lost to it.

In transit: the support is fixed in the lab and so is the detector arm's mount, so only the two
detector axes matter. The angle from the detector to lab −y changes by at most |Δazimuth| + |Δtilt|
(degrees) as the axes move, which certifies a bisection of the move in time
(:func:`~gonio.kinematics.sweep.lipschitz_min`). The blocked regions are two small caps of axis space
(around azimuth −90°, tilt 90° and azimuth 90°, tilt −90° with the shipped limits), so the free axis
space is connected: a blocked move goes round a cap, e.g. by lowering the detector tilt first
(:meth:`SampleStage.detours`).

Free azimuths. At θi = 0 the rotation is free: it keeps its current value (home when none is given)
when that is within limits and keeps the detector clear of the support, else it turns the shortest way
to the nearest rotation that does. A detector straight overhead (only possible with clearance_deg = 0)
keeps its current azimuth, brought into the limits. The free rotation looks only at the support: with
a detector azimuth range narrower than a turn (not the shipped config), a pose with θi = 0 whose
detector falls outside that range is reported out of reach even if another rotation would bring it in.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from gonio.geometry import sph_to_vec, vec_to_sph
from gonio.kinematics.base import (
    DEG_TOL,
    POLE_EPS,
    Kinematics,
    angle_between,
    arm_vector,
    azimuth_wraps,
    nearest_allowed_azimuth,
    wrap_360,
)
from gonio.kinematics.sweep import lipschitz_min
from gonio.kinematics.two_arm import arm_branches

if TYPE_CHECKING:  # type hints only: a design plugin is imported while gonio.config is
    from gonio.config import GonioConfig

__all__ = ["SampleStage", "SUPPORT_LAB"]

#: Direction (lab frame) of the tilt-stage support the detector must keep clear of.
SUPPORT_LAB = np.array([0.0, -1.0, 0.0])
# Lab azimuth of the support, degrees: the detector's lab azimuth is φo + rotation when tilt = 0.
_SUPPORT_AZIMUTH_DEG = 270.0


def _rot_z(v, angle):
    c, s = np.cos(angle), np.sin(angle)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.stack(np.broadcast_arrays(c * x - s * y, s * x + c * y, z), axis=-1)


def _rot_y(v, angle):
    c, s = np.cos(angle), np.sin(angle)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.stack(np.broadcast_arrays(c * x + s * z, y, -s * x + c * z), axis=-1)


def sample_to_lab(v, rotation_deg, tilt_deg) -> np.ndarray:
    """Sample-frame vector(s) ``v`` (..., 3) in the lab: R_y(tilt) · R_z(rotation) · v (degrees)."""
    return _rot_y(_rot_z(np.asarray(v, dtype=np.float64), np.radians(rotation_deg)), np.radians(tilt_deg))


def lab_to_sample(v, rotation_deg, tilt_deg) -> np.ndarray:
    """Lab vector(s) ``v`` (..., 3) in the sample frame: R_z(−rotation) · R_y(−tilt) · v (degrees)."""
    return _rot_z(_rot_y(np.asarray(v, dtype=np.float64), -np.radians(tilt_deg)), -np.radians(rotation_deg))


class SampleStage(Kinematics):
    """Kinematics of the sample-stage gantry (see the module docstring for frames and rules).

    Parameters
    ----------
    cfg : GonioConfig
        A config whose ``kinematics.design`` is ``"sample-stage"``.

    Examples
    --------
    >>> from gonio.config import load_config
    >>> kin = SampleStage(load_config("config/sample-stage.toml"))
    >>> kin.inverse(np.radians(30), np.pi, np.radians(30), 0.0).round(6).tolist()   # specular, in x-z
    [[0.0, 30.0, 0.0, 60.0]]
    """

    #: The axes this design drives, in the order of every axis array.
    axis_names = ("sample_rotation", "sample_tilt", "detector_azimuth", "detector_tilt")

    def __init__(self, cfg: GonioConfig):
        super().__init__(cfg)
        self._wraps_rotation = azimuth_wraps(*self.limits_deg[0])
        self._wraps_detector = azimuth_wraps(*self.limits_deg[2])
        self.n_branches = 4 * len(self._wraps_rotation) * len(self._wraps_detector)

    def _free_rotation(self, theta_o, phi_o, current_rotation):
        """Rotation (N,) at θi = 0: the nearest to the current one that keeps the detector clear of
        the support. With tilt 0 the detector is at lab polar θo and lab azimuth φo + rotation, and
        its angle γ to lab −y obeys cos γ = sin θo · cos(φo + rotation − 270°): it collides on the
        arc |φo + rotation − 270°| < arccos(cos(arm_collision) / sin θo)."""
        cos_col = np.cos(np.radians(self.arm_collision_deg))
        s = np.sin(theta_o)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # s -> 0: the arc vanishes
            ratio = np.where(s > 0.0, cos_col / s, np.copysign(np.inf, cos_col))
        half = np.degrees(np.arccos(np.clip(ratio, -1.0, 1.0)))
        centre = _SUPPORT_AZIMUTH_DEG - np.degrees(phi_o)
        lo, hi = self.limits_deg[0]
        return nearest_allowed_azimuth(current_rotation, lo, hi, centre, half)

    def _branches(self, theta_i, phi_i, theta_o, phi_o, current):
        n = theta_i.shape[0]
        pole_i = theta_i < POLE_EPS
        theta_i_deg = np.where(pole_i, 0.0, np.degrees(theta_i))
        phi_i_deg = np.degrees(phi_i)

        # Sample stage: (sign, turn) -> rotation (N, 2, Kr); tilt (N, 2).
        tilt = np.stack([theta_i_deg, -theta_i_deg + 0.0], axis=1)
        rot_base = np.stack([wrap_360(180.0 - phi_i_deg), wrap_360(-phi_i_deg)], axis=1)
        rot_base[pole_i] = self._free_rotation(theta_o[pole_i], phi_o[pole_i], current[pole_i, 0])[:, None]
        rotation = rot_base[:, :, None] + 360.0 * self._wraps_rotation
        # A free rotation is one value, not one per turn.
        rotation = np.where(pole_i[:, None, None], rot_base[:, :, None], rotation)

        # The detector direction in the lab for each sign (turns of the rotation do not change it).
        wo = sph_to_vec(theta_o, phi_o)
        d_lab = sample_to_lab(wo[:, None, :], rot_base, tilt)            # (N, 2, 3)
        beta, alpha = vec_to_sph(d_lab)
        collides = angle_between(d_lab, SUPPORT_LAB) < np.radians(self.arm_collision_deg - DEG_TOL)

        az, det_tilt = arm_branches(beta.reshape(-1), alpha.reshape(-1), self._wraps_detector)
        lo_a, hi_a = self.limits_deg[2]
        overhead = (beta < POLE_EPS).reshape(-1, 1)
        cur_a = np.repeat(current[:, 2], 2)[:, None]
        az = np.where(overhead, np.clip(cur_a, lo_a, hi_a), az)
        n_det = az.shape[1]
        az = az.reshape(n, 2, 1, n_det)
        det_tilt = det_tilt.reshape(n, 2, 1, n_det)

        shape = (n, 2, len(self._wraps_rotation), n_det)
        cands = np.stack(
            [np.broadcast_to(a, shape) for a in (rotation[..., None], tilt[:, :, None, None], az, det_tilt)],
            axis=-1,
        )
        collides = np.broadcast_to(collides[:, :, None, None], shape)
        return cands.reshape(n, self.n_branches, 4), collides.reshape(n, self.n_branches)

    def _directions(self, axes_deg):
        rotation, tilt = axes_deg[:, 0], axes_deg[:, 1]
        light_lab = np.broadcast_to(np.array([0.0, 0.0, 1.0]), axes_deg[:, :3].shape)
        detector_lab = arm_vector(axes_deg[:, 2], axes_deg[:, 3])
        return lab_to_sample(light_lab, rotation, tilt), lab_to_sample(detector_lab, rotation, tilt)

    @property
    def collision_rule(self) -> str:
        return (f"the detector may not come within kinematics.arm_collision_deg = "
                f"{self.arm_collision_deg:g}° of the tilt-stage support (lab −y)")

    def support_margin(self, axes_deg) -> np.ndarray:
        """Angle (N,) in degrees from the detector arm to the support (lab −y), minus arm_collision_deg."""
        axes = np.asarray(axes_deg, dtype=np.float64).reshape(-1, 4)
        u = arm_vector(axes[:, 2], axes[:, 3])
        return np.degrees(np.arctan2(np.hypot(u[:, 0], u[:, 2]), -u[:, 1])) - self.arm_collision_deg

    def _support_margin_one(self, azimuth_deg: float, tilt_deg: float) -> float:
        a, t = math.radians(azimuth_deg), math.radians(tilt_deg)
        st = math.sin(t)
        return math.degrees(math.atan2(math.hypot(st * math.cos(a), math.cos(t)), -st * math.sin(a))) \
            - self.arm_collision_deg

    def _sweep_margin(self, start, end):
        return lipschitz_min(self.support_margin, start, end, self.velocity_deg_s, self.accel_deg_s2, (2, 3))

    def _sweep_margin_below(self, start, end, floor):
        return lipschitz_min(self.support_margin, start, end, self.velocity_deg_s, self.accel_deg_s2, (2, 3),
                             floor=floor)

    def _sweep_margin_one(self, start, end):
        # Most moves are proved clear by the bound over the whole move; only the others pay for numpy.
        g0 = self._support_margin_one(start[2], start[3])
        g1 = self._support_margin_one(end[2], end[3])
        bound = 0.5 * (g0 + g1 - abs(end[2] - start[2]) - abs(end[3] - start[3]))
        if bound >= 0.0:
            return min(bound, g0, g1)
        return float(self._sweep_margin(np.array([start]), np.array([end]))[0])

    def detours(self):
        """Detector tilts that keep it clear of the support at any azimuth: the zenith, and just inside
        and outside the band |tilt ∓ 90°| < arm_collision_deg where the support can be met."""
        lo, hi = self.limits_deg[3]
        gap = self.arm_collision_deg + 1.0
        values = [0.0, 90.0 - gap, -(90.0 - gap), 90.0 + gap, -(90.0 + gap)]
        return [(3, v) for v in values if lo <= v <= hi]
