"""Which isotropic poses a gantry can measure.

A pose (θi, θo, Δφ) is measured with φi = 0, φo = Δφ, as the uniform ``iso`` grids measure theirs
(:mod:`gonio.plan.grids`). When that is out of reach, occluded (ωi and ωo closer than the clearance, near
retro-reflection) or colliding, its Helmholtz twin (θo, θi, −Δφ) stands in when that one can be
reached; a pose counts as unreachable only when neither can (the rule :func:`gonio.plan.build.build_plan`
applies to a grid's classes).
"""

from __future__ import annotations

import numpy as np

__all__ = ["reachable_iso"]


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
    inside = (ti <= theta_max + 1e-12) & (to <= theta_max + 1e-12)
    direct = inside & (np.asarray(kin.feasibility(ti, zero, to, d)) == 0)
    twin_d = np.where(ti > 0, np.mod(-d, 2.0 * np.pi), 0.0)
    twin = inside & ~direct
    if twin.any():
        idx = np.flatnonzero(twin)
        twin[idx] = np.asarray(kin.feasibility(to[idx], zero[idx], ti[idx], twin_d[idx])) == 0
    dphi_kept = np.where(to > 0, d, 0.0)
    angles = (np.where(twin, to, ti), zero, np.where(twin, ti, to), np.where(twin, twin_d, dphi_kept))
    return direct | twin, angles
