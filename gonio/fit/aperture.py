"""The instrument's optics in a fit: the model averaged over the source and detector cones, as measured.

A gantry's detector does not read f_r at one pair of directions. The source subtends a cone of
half-angle α_s about ωi, the detector sees a cone of half-angle α_d about ωo, and the reading is
(:mod:`gonio.sim.aperture`, the simulator's optics, which are a real gantry's)

    S ∝ L_src Ω_s · E[f_r(ωi', ωo') cos θi'],   ωi' uniform in the source cone, ωo' in the detector cone.

The white standard (a Lambertian of reflectance ρ_ref) is read through the same optics at θi_ref:
S_ref ∝ L_src Ω_s (ρ_ref/π) · c cos θi_ref, with c = E[cos ∠(ωi', ωi)] = (1 + cos α_s)/2 (the mean of a
direction uniform in a cone is its axis times c, and z is linear in it). :mod:`gonio.calibrate` divides
by it and by cos θi, so the calibrated value estimates

    f_meas(ωi, ωo) = E[f_r(ωi', ωo') cos θi'] / (c cos θi)

(a cos θi'-weighted mean of f_r over both cones; a constant f_r comes back unchanged). A model fitted at
the cones' axes to these values is biased wherever f_r curves within a cone: a GGX lobe of α = 0.15
seen through the default cones (0.5°, 1°) is flattened by ~0.1 % at its peak, which moved the fitted
rho_s by 10 σ and alpha by 36 σ of a noise-free campaign's uncertainty (BENCHMARKS.md).

:class:`Aperture` evaluates f_meas with a fixed product quadrature, the same for every pose: in each cone
``rings`` Gauss-Legendre nodes in w = 1 − cos θ' (uniform in [0, 1 − cos α] for directions uniform in
solid angle) times ``spokes`` equally spaced azimuths from the plane of incidence (alternate rings turned
by half a spoke), mapped to directions as :func:`gonio.sim.aperture.cone_directions` maps the
simulator's uniform numbers, and every source point paired with every detector point: M = (rings ·
spokes)² directions per pose. The quadrature reproduces the cones' mean direction exactly, their second
moments up to a term of fourth order in the cone's angle, and has no source-detector correlation, so its
error is of fourth order in the cone's angle over the lobe's width. Measured against a (6 rings × 18
spokes)² quadrature at the 603 poses of ``iso:step=15,reciprocity=false``, the largest relative error of
the defaults (1 ring, 4 spokes, M = 16) on a GGX lobe is 3e-5 at α = 0.15, 1.5e-4 at α = 0.08, 8e-4 at
α = 0.05 (the model at the axes: 3 %, 11 %, 26 %); the Monte Carlo error of a simulated reading (256
aperture pairs) is ~1e-3 relative at the α = 0.15 lobe and grows as the lobe narrows. (2, 6), M = 144,
nine times the evaluations, gives 3.5e-6, 8.6e-5, 6.7e-4. tests/test_fit_aperture.py checks the defaults
against the simulator's Monte Carlo. A lobe narrower than the cones (α below ~0.02 with these) is not
resolved by 16 directions, nor its derivative: a fit start that overshoots to such a lobe crawls back
slowly (BENCHMARKS.md, "The instrument's cones in the fit").

Where the cones are not known (:class:`~gonio.fit.solve.FitData` given without them, a brdf.h5 of a real
sample without ``source_half_angle_deg``/``detector_half_angle_deg``), the fit evaluates the model at the
axes, as before, and says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gonio.geometry import vec_to_sph

__all__ = ["Aperture", "RINGS", "SPOKES"]

#: Default Gauss-Legendre nodes in 1 − cos θ' per cone.
RINGS = 1
#: Default azimuths per ring.
SPOKES = 4


@dataclass(frozen=True)
class Aperture:
    """The source and detector cones (half-angles in degrees) and the quadrature over them."""

    source_half_angle_deg: float
    detector_half_angle_deg: float
    rings: int = RINGS
    spokes: int = SPOKES

    def __post_init__(self):
        for name in ("source_half_angle_deg", "detector_half_angle_deg"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and 0.0 < v <= 10.0):
                raise ValueError(f"{name}: must be a number in (0, 10] degrees, got {v!r}")
        for name, lo in (("rings", 1), ("spokes", 2)):
            v = getattr(self, name)
            if not (isinstance(v, int) and lo <= v <= 64):
                raise ValueError(f"{name}: must be an integer in [{lo}, 64], got {v!r}")

    @property
    def points(self) -> int:
        """Directions per pose, M."""
        return (self.rings * self.spokes) ** 2

    def describe(self) -> str:
        return (f"source cone {self.source_half_angle_deg:g}°, detector cone "
                f"{self.detector_half_angle_deg:g}° ({self.points} directions per pose)")

    def to_json(self) -> dict:
        return {"source_half_angle_deg": self.source_half_angle_deg,
                "detector_half_angle_deg": self.detector_half_angle_deg, "rings": self.rings,
                "spokes": self.spokes, "points": self.points}

    def _nodes(self):
        """(u1, u2, weight) of one cone's points, weights summing to 1."""
        x, w = np.polynomial.legendre.leggauss(self.rings)
        u1 = np.repeat((x + 1.0) / 2.0, self.spokes)
        turn = np.arange(self.rings) % 2 * 0.5   # alternate rings turned by half a spoke
        u2 = ((np.arange(self.spokes)[None, :] + turn[:, None]) / self.spokes).ravel()
        return u1, u2, np.repeat(w / 2.0, self.spokes) / self.spokes

    def expand(self, wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The quadrature's directions of N poses, pose-major: wi', wo' (N·M, 3) and each lane's weight
        (N·M,), w_k · max(cos θi', 0) / (c cos θi), so that f_meas of pose p is the sum of f_r · weight
        over its M lanes (module docstring)."""
        wi = np.asarray(wi, np.float64).reshape(-1, 3)
        wo = np.asarray(wo, np.float64).reshape(-1, 3)
        n, m = wi.shape[0], self.points
        u1, u2, w = self._nodes()
        k = u1.size
        # lane (p, a, b): pose p, source point a, detector point b
        src = np.tile(np.repeat(np.arange(k), k), n)
        det = np.tile(np.tile(np.arange(k), k), n)
        pose = np.repeat(np.arange(n), m)
        wi_q = _cone(wi[pose], 1.0 - math.cos(math.radians(self.source_half_angle_deg)), u1[src], u2[src])
        wo_q = _cone(wo[pose], 1.0 - math.cos(math.radians(self.detector_half_angle_deg)), u1[det], u2[det])
        c = (1.0 + math.cos(math.radians(self.source_half_angle_deg))) / 2.0
        cos_i = wi[pose, 2]
        weight = np.divide(w[src] * w[det] * np.maximum(wi_q[:, 2], 0.0), c * cos_i,
                           out=np.zeros(n * m), where=cos_i > 0)   # a pose below the horizon: no reading
        return wi_q, wo_q, weight

    def evaluate(self, material, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """f_meas (N, C) of ``material`` (with ``eval(wi, wo, precision=...)``, e.g. a loaded MATERIAL) at
        the poses (wi, wo): what the instrument's calibrated reading of it estimates."""
        wi_q, wo_q, weight = self.expand(wi, wo)
        f = np.asarray(material.eval(wi_q, wo_q, precision="float64"), np.float64)
        return (f * weight[:, None]).reshape(-1, self.points, f.shape[1]).sum(axis=1)


def _cone(axis: np.ndarray, one_minus_cos_max: float, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Directions (K, 3) at polar angle arccos(1 − u1·(1 − cos α)) from the unit vectors ``axis`` (K, 3)
    and azimuth 2π·u2 from the axis's plane of incidence (u1, u2 uniform: uniform in solid angle, the
    map of :func:`gonio.sim.aperture.cone_directions` up to the azimuth's origin)."""
    theta, phi = vec_to_sph(axis)
    w = u1 * one_minus_cos_max
    sin_t = np.sqrt(w * (2.0 - w))   # from w, not 1 − cos: no cancellation in tiny cones
    along = np.stack([np.cos(theta) * np.cos(phi), np.cos(theta) * np.sin(phi), -np.sin(theta)], axis=1)
    across = np.stack([-np.sin(phi), np.cos(phi), np.zeros_like(phi)], axis=1)
    psi = 2.0 * np.pi * u2
    return (axis * (1.0 - w)[:, None] + along * (sin_t * np.cos(psi))[:, None]
            + across * (sin_t * np.sin(psi))[:, None])
