"""Absolute BRDF from raw readings: dark subtraction and a white reference of known albedo.

Every reading is first turned into a rate, signal / exposure_s, so that poses, darks and references read
at different exposures compare (the detector is linear and its dark signal is a dark current, which
grows with the exposure; a camera's black level is taken off by the detector itself).

Geometry. The source, of radiance L_src subtending Ω_s, gives the sample the irradiance
E(θi) = L_src Ω_s cos θi. A detector whose field lies wholly on the sample (the photodiode's cone, the
camera's region of interest: each sees radiance, not intensity) reads

    S = R_d · L_o = R_d · f_r(ωi, ωo) · E(θi) = K · f_r(ωi, ωo) · cos θi          (+ the dark rate D)

with K = R_d L_src Ω_s (R_d the responsivity): the viewing angle θo does not enter, because the radiance
of each point is what is read and the field stays on the sample (no cos θo; a detector that saw the
whole sample would read intensity and need one). The white standard, a Lambertian of reflectance ρ_ref
(per channel: a number, a value per channel, or a spectral table read at the bands), has
f_ref = ρ_ref/π at every pair of angles for an ideal diffuser (a real one's own angular response at the
angles it is read at, ``[reference] response``, multiplies ρ_ref: the caller passes ρ_ref · response),
and read at incidence θi_ref it gives S_ref − D = K · (ρ_ref/π) · cos θi_ref, so

    f_r = ρ_ref/π · (S − S_dark)/(S_ref − S_dark) · cos θi_ref / cos θi          [sr⁻¹]

(with θi_ref = θi this is the textbook ρ_ref/π · (S − S_dark)/(S_ref − S_dark)).

Dark and reference readings are taken periodically; each pose uses the dark and K interpolated in
campaign time from the readings around it, which tracks a drifting source: a cubic through the two
readings around the pose and the next one on either side (a straight line would miss a curving drift,
a lamp's warm-up or wander, by (Δt²/8)·|d²K/dt²| between references Δt apart; the cubic's error is of
order Δt⁴, which lets references be sparse in time and cheap). The campaign clock (``Measurement.campaign_s``)
continues across resumes; a journal whose clock goes backwards is refused, since interpolating on it
would silently mix up which references bracket which poses.

Uncertainty (first order, independent errors): an interpolated quantity Σ w_j·y_j has variance
Σ w_j²·σ_j²; the relative errors of the net pose signal and of K add in quadrature.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gonio.plan.schedule import STEP_DARK, STEP_POSE, STEP_REFERENCE
from gonio.store import Measurement

__all__ = ["CalibrationError", "Calibrated", "calibrate", "calibrate_with_shifts", "reference_rho",
           "interpolation_weights", "interpolate_readings", "SPACING_RATIO"]

#: The drift interpolation uses a reading beyond the two around a pose only when the interval to it is
#: within this factor of theirs.
SPACING_RATIO = 2.0


class CalibrationError(ValueError):
    pass


@dataclass(frozen=True)
class Calibrated:
    angles_deg: np.ndarray   # (N, 4) actual θi, φi, θo, φo
    value: np.ndarray        # (N, C) f_r in sr⁻¹
    stddev: np.ndarray       # (N, C)
    steps: np.ndarray        # (N,) journal step of each sample
    poses: np.ndarray        # (N,) plan pose index
    campaign_s: np.ndarray   # (N,) campaign clock at each sample's reading


def interpolation_weights(t, tk, ratio: float = None) -> tuple[np.ndarray, np.ndarray]:
    """How the drift correction interpolates readings taken at the times ``tk`` (K,), sorted, at the
    times ``t`` (N,): indices (N, 4) into the readings and their weights (N, 4), each row summing to 1.

    A cubic through the two readings around each time and one more on either side, constant beyond the
    ends. The outer two readings take part only when their interval is within a factor ``ratio``
    (default :data:`SPACING_RATIO`) of the bracketing one (at the ends of the campaign, or across a long pause
    before a resume, fewer readings are used: a quadratic or a straight line). The weights are those of
    the Lagrange polynomial through the readings used, so it reproduces a constant or a linear drift
    exactly and a smooth one to the fourth order in the interval.
    """
    ratio = SPACING_RATIO if ratio is None else float(ratio)
    t = np.asarray(t, dtype=np.float64)
    tk = np.asarray(tk, dtype=np.float64)
    k = tk.size
    if k == 1:
        return np.zeros((t.size, 4), dtype=np.int64), np.tile([1.0, 0.0, 0.0, 0.0], (t.size, 1))
    t = np.clip(t, tk[0], tk[-1])
    hi = np.clip(np.searchsorted(tk, t, side="right"), 1, k - 1)
    lo = hi - 1
    nodes = np.stack([lo - 1, lo, hi, hi + 1], axis=1)
    span = tk[hi] - tk[lo]
    use = np.ones(nodes.shape, dtype=bool)
    for col, inner in ((0, lo), (3, hi)):
        inside = (nodes[:, col] >= 0) & (nodes[:, col] < k)
        gap = np.abs(tk[np.clip(nodes[:, col], 0, k - 1)] - tk[inner])
        use[:, col] = inside & (gap <= ratio * span) & (ratio * gap >= span) & (span > 0.0)
    use[:, 2] &= span > 0.0                      # two readings at one time: take the first
    idx = np.clip(nodes, 0, k - 1)
    tn = tk[idx]
    weights = np.zeros(nodes.shape)
    for j in range(4):
        w = np.where(use[:, j], 1.0, 0.0)
        for m in range(4):
            if m != j:
                with np.errstate(divide="ignore", invalid="ignore"):
                    factor = np.where(use[:, m], (t - tn[:, m]) / (tn[:, j] - tn[:, m]), 1.0)
                w = w * np.where(use[:, j], factor, 1.0)
        weights[:, j] = np.where(use[:, j], w, 0.0)
    return idx, weights


def interpolate_readings(t, tk, yk, ek):
    """Values ``yk`` (K, C) with standard errors ``ek`` (K, C), read at the times ``tk``, interpolated at
    the times ``t`` (N,) as :func:`interpolation_weights` says. Returns (value, stddev), each (N, C)."""
    return _interpolated(interpolation_weights(t, tk), yk, ek)


def _interpolated(weighting, yk, ek):
    idx, weights = weighting
    value = np.einsum("nj,njc->nc", weights, yk[idx])
    stddev = np.sqrt(np.einsum("nj,njc->nc", weights**2, ek[idx] ** 2))
    return value, stddev


def reference_rho(reference, detector: dict):
    """(ρ_ref, per_channel) of the white standard: its reflectance per channel of ``detector`` (a
    journal's descriptor) where the config's ``reference`` gives a reflectance per channel, a spectrum or a
    response other than 1 (per_channel True), else its albedo (one number)."""
    per_channel = (reference.reflectance is not None or reference.spectrum is not None
                   or reference.response != 1.0)
    if per_channel:
        return reference.reference_fr(detector["channels"], detector["wavelengths_nm"]), True
    return reference.albedo, False


def calibrate(measurements: list[Measurement], reference_albedo) -> Calibrated:
    """Calibrated BRDF samples of every pose measurement in ``measurements`` (in step order).

    ``reference_albedo``: the white standard's reflectance ρ_ref, one number or one per channel (C,).
    Readings of any shape are flattened to their channels (a spectrometer's bands)."""
    return _Readings(measurements, reference_albedo).calibrated()


def calibrate_with_shifts(measurements: list[Measurement], reference_albedo,
                          expect: np.ndarray | None = None) -> tuple[Calibrated, np.ndarray | None]:
    """:func:`calibrate`, and how its values move when each dark and white-reference reading's signal is
    moved by its own standard error: U of shape (N, C, M), column m the change of every sample's f_r for
    the m-th such reading (in step order; M may be 0). Each column is exactly what :func:`calibrate`
    gives with that one reading moved, minus the unmoved values; the readings are gathered and the
    interpolation weights found once, not once per column. With ``expect``, U is None (and not
    computed) unless the calibrated values reproduce ``expect`` (rtol 1e-9, atol 1e-12)."""
    readings = _Readings(measurements, reference_albedo)
    base = readings.calibrated()
    if expect is not None and (base.value.shape != np.shape(expect)
                               or not np.allclose(base.value, expect, rtol=1e-9, atol=1e-12)):
        return base, None
    columns = []
    for i in np.flatnonzero((readings.kind == STEP_DARK) | (readings.kind == STEP_REFERENCE)):
        rate = readings.rate.copy()
        rate[i] = (readings.signal[i] + readings.signal_err[i]) / readings.exposure[i]
        columns.append(readings.values(rate)[0] - base.value)
    n, c = base.value.shape
    return base, np.stack(columns, axis=-1) if columns else np.zeros((n, c, 0))


class _Readings:
    """The readings of a journal as arrays (rates, errors, times), checked, with the drift
    interpolation's weights: what :func:`calibrate` computes on."""

    def __init__(self, measurements: list[Measurement], reference_albedo):
        rho = np.asarray(reference_albedo, dtype=np.float64)
        if rho.ndim > 1 or not np.all((rho > 0.0) & (rho <= 1.0)):
            raise CalibrationError(f"reference_albedo must be in (0, 1], one value or one per channel, got "
                                   f"{reference_albedo}")
        if measurements and rho.ndim == 1 and rho.size != np.size(measurements[0].signal):
            raise CalibrationError(f"reference_albedo: {rho.size} values for readings of "
                                   f"{np.size(measurements[0].signal)} channels")
        self.reference_albedo = float(rho) if rho.ndim == 0 else rho
        self.measurements = measurements
        kind = self.kind = np.array([m.kind for m in measurements], dtype=np.int8)
        if not np.any(kind == STEP_DARK):
            raise CalibrationError("no dark reading in the journal: cannot subtract the dark signal")
        if not np.any(kind == STEP_REFERENCE):
            raise CalibrationError("no white-reference reading in the journal: cannot calibrate to sr^-1")
        t = self.t = np.array([m.campaign_s for m in measurements], dtype=np.float64)
        back = np.flatnonzero(np.diff(t) < 0.0)
        if back.size:
            i = int(back[0])
            raise CalibrationError(
                f"campaign time goes backwards from step {measurements[i].step} ({t[i]:.3f} s) to step "
                f"{measurements[i + 1].step} ({t[i + 1]:.3f} s): the drift correction cannot order these "
                "readings (a journal of gonio < 0.2 that was resumed?)")
        exposure = self.exposure = np.array([m.exposure_s for m in measurements], dtype=np.float64)[:, None]
        if not np.all(exposure > 0.0):
            raise CalibrationError("a reading has exposure_s <= 0: cannot turn it into a rate")
        self.signal = np.stack([np.ravel(m.signal) for m in measurements])
        self.signal_err = np.stack([np.ravel(m.stderr) for m in measurements])
        self.rate = self.signal / exposure
        self.err = self.signal_err / exposure
        self.theta_i = np.radians([m.angles_deg[0] for m in measurements])
        self.dk, self.rk, self.pk = kind == STEP_DARK, kind == STEP_REFERENCE, kind == STEP_POSE
        self.dark_weighting = interpolation_weights(t, t[self.dk])
        self.k_weighting = interpolation_weights(t[self.pk], t[self.rk])

    def values(self, rate: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(value, stddev), each (N, C), of the pose readings for the rates ``rate`` of every reading."""
        dk, rk, pk, err = self.dk, self.rk, self.pk, self.err
        dark, dark_err = _interpolated(self.dark_weighting, rate[dk], err[dk])
        ref_net = rate[rk] - dark[rk]
        ref_cos = np.cos(self.theta_i[rk])[:, None]
        # K: signal rate per unit of f_r·cos θi.
        k_ref = ref_net / (self.reference_albedo / np.pi * ref_cos)
        if np.any(k_ref <= 0.0):
            raise CalibrationError("a white-reference reading is not above the dark signal: check the light "
                                   "source and the reference standard")
        k_ref_err = k_ref * np.hypot(err[rk], dark_err[rk]) / ref_net
        k, k_err = _interpolated(self.k_weighting, k_ref, k_ref_err)
        cos_i = np.cos(self.theta_i[pk])[:, None]
        net = rate[pk] - dark[pk]
        net_err = np.hypot(err[pk], dark_err[pk])
        value = net / (k * cos_i)
        # σ_f² = (σ_net / (K cos))² + (f σ_K / K)²: well defined also where the net signal is 0.
        stddev = np.hypot(net_err / (k * cos_i), value * k_err / k)
        return value, stddev

    def calibrated(self) -> Calibrated:
        value, stddev = self.values(self.rate)
        pk, t, measurements = self.pk, self.t, self.measurements
        return Calibrated(
            angles_deg=np.stack([m.angles_deg for m, p in zip(measurements, pk, strict=True) if p]),
            value=value, stddev=stddev,
            steps=np.array([m.step for m in measurements])[pk],
            poses=np.array([m.pose for m in measurements])[pk],
            campaign_s=t[pk])
