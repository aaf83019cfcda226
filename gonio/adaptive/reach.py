"""Which isotropic poses a gantry can measure.

A pose (θi, θo, Δφ) is measured with φi = 0, φo = Δφ, as the uniform ``iso`` grids measure theirs
(:mod:`gonio.plan.grids`). When that is out of reach, occluded (ωi and ωo closer than the clearance, near
retro-reflection) or colliding, its Helmholtz twin (θo, θi, −Δφ) stands in when that one can be
reached; a pose counts as unreachable only when neither can (the rule :func:`gonio.plan.build.build_plan`
applies to a grid's classes). An anisotropic pose (θi, φi, θo, φo) is measured as it is, its twin
(θo, φo, θi, φi) standing in the same way (:func:`reachable_pair`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["reachable_iso", "reachable_pair"]


def reachable_iso(kin, theta_i, theta_o, dphi, theta_max: float):
    """The measurable form of each isotropic pose.

    Parameters
    ----------
    kin : Kinematics
        ``gonio.kinematics.make_kinematics(cfg)``.
    theta_i, theta_o, dphi : array_like, shape (N,)
        Radians.
    theta_max : float
        Largest θ to measure, radians (at most the config's ``kinematics.theta_max_deg``).

    Returns
    -------
    ok : ndarray of bool, shape (N,)
        Whether the pose or its twin can be measured.
    angles : tuple of four ndarrays, shape (N,)
        (θi, φi, θo, φo) of the pose to drive to (the twin's where only it can be reached).
    """
    ti, to, d = (np.asarray(a, dtype=np.float64).ravel() for a in (theta_i, theta_o, dphi))
    zero = np.zeros_like(ti)
    twin_d = np.where(ti > 0, np.mod(-d, 2.0 * np.pi), 0.0)
    direct, twin = _reach(kin, (ti, zero, to, d), (to, zero, ti, twin_d), theta_max)
    dphi_kept = np.where(to > 0, d, 0.0)
    angles = (np.where(twin, to, ti), zero, np.where(twin, ti, to), np.where(twin, twin_d, dphi_kept))
    return direct | twin, angles


def reachable_pair(kin, theta_i, phi_i, theta_o, phi_o, theta_max: float):
    """:func:`reachable_iso` of anisotropic poses (θi, φi, θo, φo), radians: the pose itself or its twin
    (θo, φo, θi, φi); returns (ok, (θi, φi, θo, φo) to drive to)."""
    ti, pi_, to, po = (np.asarray(a, dtype=np.float64).ravel() for a in (theta_i, phi_i, theta_o, phi_o))
    direct, twin = _reach(kin, (ti, pi_, to, po), (to, po, ti, pi_), theta_max)
    return direct | twin, (np.where(twin, to, ti), np.where(twin, po, pi_), np.where(twin, ti, to),
                           np.where(twin, pi_, po))


def _reach(kin, direct_angles, twin_angles, theta_max):
    """(direct, twin): where the gantry reaches each pose itself, and where only its twin."""
    ti, to = direct_angles[0], direct_angles[2]
    inside = (ti <= theta_max + 1e-12) & (to <= theta_max + 1e-12)
    direct = inside & (np.asarray(kin.feasibility(*direct_angles)) == 0)
    twin = inside & ~direct
    if twin.any():
        idx = np.flatnonzero(twin)
        twin[idx] = np.asarray(kin.feasibility(*(a[idx] for a in twin_angles))) == 0
    return direct, twin
