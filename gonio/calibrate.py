"""Absolute BRDF from raw readings: dark subtraction and a white reference of known albedo.

A detector that sees reflected radiance reads S = K · f_r · cos θi (plus the dark signal D), where K
folds together the source's irradiance at normal incidence, the detector's responsivity and the
exposure. The white standard, a Lambertian of hemispherical reflectance ρ_ref, read at incidence
θi_ref, gives R − D = K · (ρ_ref / π) · cos θi_ref, so

    f_r = (S − D) / (R − D_R) · (ρ_ref / π) · cos θi_ref / cos θi      [sr⁻¹]

Dark and reference readings are taken periodically; each pose uses the dark interpolated linearly in
time between the dark readings around it, and K interpolated between the reference readings around
it, which tracks a slowly drifting source. Uncertainties add in quadrature (first order).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gonio.plan.schedule import STEP_DARK, STEP_POSE, STEP_REFERENCE
from gonio.store import Measurement

__all__ = ["CalibrationError", "Calibrated", "calibrate"]


class CalibrationError(ValueError):
    pass


@dataclass(frozen=True)
class Calibrated:
    angles_deg: np.ndarray   # (N, 4) actual θi, φi, θo, φo
    value: np.ndarray        # (N, C) f_r in sr⁻¹
    stddev: np.ndarray       # (N, C)
    steps: np.ndarray        # (N,) journal step of each sample
    poses: np.ndarray        # (N,) plan pose index


def _interp(t, tk, yk):
    """Per-channel linear interpolation in time, constant beyond the ends."""
    return np.stack([np.interp(t, tk, yk[:, c]) for c in range(yk.shape[1])], axis=1)


def calibrate(measurements: list[Measurement], reference_albedo: float) -> Calibrated:
    """Calibrated BRDF samples of every pose measurement in ``measurements``."""
    if not 0.0 < reference_albedo <= 1.0:
        raise CalibrationError(f"reference_albedo must be in (0, 1], got {reference_albedo}")
    kind = np.array([m.kind for m in measurements], dtype=np.int8)
    if not np.any(kind == STEP_DARK):
        raise CalibrationError("no dark reading in the journal: cannot subtract the dark signal")
    if not np.any(kind == STEP_REFERENCE):
        raise CalibrationError("no white-reference reading in the journal: cannot calibrate to sr^-1")
    t = np.array([m.virtual_s for m in measurements])
    sig = np.stack([m.signal for m in measurements])
    err = np.stack([m.stderr for m in measurements])
    theta_i = np.radians([m.angles_deg[0] for m in measurements])

    dk = kind == STEP_DARK
    dark = _interp(t, t[dk], sig[dk])
    dark_err = _interp(t, t[dk], err[dk])

    rk = kind == STEP_REFERENCE
    ref_net = sig[rk] - dark[rk]
    ref_cos = np.cos(theta_i[rk])[:, None]
    # K: signal per unit of f_r·cos θi.
    k_ref = ref_net / (reference_albedo / np.pi * ref_cos)
    if np.any(k_ref <= 0.0):
        raise CalibrationError("a white-reference reading is not above the dark signal: check the light "
                               "source and the reference standard")
    k_rel_err = np.hypot(err[rk], dark_err[rk]) / ref_net

    pk = kind == STEP_POSE
    k = _interp(t[pk], t[rk], k_ref)
    k_err = _interp(t[pk], t[rk], k_rel_err)
    cos_i = np.cos(theta_i[pk])[:, None]
    net = sig[pk] - dark[pk]
    value = net / (k * cos_i)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(net != 0.0, np.hypot(err[pk], dark_err[pk]) / np.abs(net), 0.0)
    stddev = np.abs(value) * np.hypot(rel, k_err) + np.where(net == 0.0, np.hypot(err[pk], dark_err[pk])
                                                             / (k * cos_i), 0.0)
    return Calibrated(
        angles_deg=np.stack([m.angles_deg for m, p in zip(measurements, pk, strict=True) if p]),
        value=value, stddev=stddev,
        steps=np.array([m.step for m in measurements])[pk],
        poses=np.array([m.pose for m in measurements])[pk])
