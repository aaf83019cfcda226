"""Spectral materials: complex refractive indices from published tables and dispersion formulas, and BRDFs
evaluated per wavelength in Dr.Jit.

Data
----
Conductors (``CONDUCTORS``), tabulated n + ik against vacuum wavelength, interpolated linearly in
wavelength (the tables are smooth at their ~10–30 nm spacing in the visible):

- gold, silver, copper: P. B. Johnson and R. W. Christy, "Optical constants of the noble metals",
  Phys. Rev. B 6, 4370–4379 (1972), doi:10.1103/PhysRevB.6.4370.
- aluminium: A. D. Rakić, "Algorithm for the determination of intrinsic optical constants of metal
  films: application to aluminum", Appl. Opt. 34, 4755–4767 (1995), doi:10.1364/AO.34.004755.

The numbers are in ``data/*.csv`` (header lines cite the source), transcribed unchanged from the
refractiveindex.info database (public domain).

Dielectrics (``DIELECTRICS``), real index from a dispersion formula with λ in µm:

- Sellmeier n² = 1 + Σ B_j λ² / (λ² − C_j).
  ``bk7``: Schott N-BK7 catalogue constants (SCHOTT optical glass data sheet, N-BK7, n_d = 1.5168).
  ``fused-silica``: I. H. Malitson, "Interspecimen comparison of the refractive index of fused silica",
  J. Opt. Soc. Am. 55, 1205–1209 (1965), doi:10.1364/JOSA.55.001205 (n_d = 1.4585).
- Cauchy n = A + B/λ² + C/λ⁴ (:func:`cauchy`), for user-supplied constants.

Materials
---------
Each spectral material has ``eval(wi, wo, wavelength_nm, backend=None) -> (N, L)``: f_r in sr⁻¹ for N
direction pairs (sample frame, as :mod:`gonio.sim.materials`) at L wavelengths, one Dr.Jit launch over
N·L lanes in float64, on ``backend`` (:func:`gonio.jit.resolve_backend`: CUDA when present).

- :class:`SpectralLambert`: f = ρ(λ)/π.
- :class:`SpectralConductor`: a rough conductor, GGX microfacets (Smith separable masking) with the exact
  Fresnel of the spectral index, f = F(ωi·h; η(λ), k(λ)) · D G / (4 cos θi cos θo).
- :class:`SpectralDielectric`: a coated diffuse base, f = ρd(λ)/π + F_dielectric(ωi·h; η(λ)) · D G /
  (4 cos θi cos θo) (no energy exchange between the layers: a simple plastic).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import drjit as dr
import numpy as np

from gonio.jit import array_types, resolve_backend

from .base import check_directions
from .fresnel import conductor_exact, dielectric

__all__ = ["CONDUCTORS", "DIELECTRICS", "SpectralIndex", "conductor_index", "dielectric_index", "sellmeier",
           "cauchy", "SpectralLambert", "SpectralConductor", "SpectralDielectric"]

DATA_DIR = Path(__file__).with_name("data")
#: Conductor name → the CSV table of n, k (header cites the source).
CONDUCTORS = {
    "gold": "gold_johnson_christy_1972.csv",
    "silver": "silver_johnson_christy_1972.csv",
    "copper": "copper_johnson_christy_1972.csv",
    "aluminium": "aluminium_rakic_1995.csv",
}
#: Dielectric name → Sellmeier (B1, B2, B3), (C1, C2, C3) with C in µm² (sources in the module docstring).
DIELECTRICS = {
    "bk7": ((1.03961212, 0.231792344, 1.01046945), (0.00600069867, 0.0200179144, 103.560653)),
    "fused-silica": ((0.6961663, 0.4079426, 0.8974794), (0.0684043**2, 0.1162414**2, 9.896161**2)),
}


@dataclass(frozen=True)
class SpectralIndex:
    """A tabulated complex index n + ik: ``wavelength_nm`` ascending, ``n`` and ``k`` alike; ``source``."""

    wavelength_nm: np.ndarray
    n: np.ndarray
    k: np.ndarray
    source: str

    def at(self, wavelength_nm) -> tuple[np.ndarray, np.ndarray]:
        """(n, k) linearly interpolated at ``wavelength_nm`` (nm); outside the table raises ValueError."""
        wl = np.asarray(wavelength_nm, dtype=np.float64)
        lo, hi = self.wavelength_nm[0], self.wavelength_nm[-1]
        if wl.size and (wl.min() < lo or wl.max() > hi):
            raise ValueError(f"wavelength_nm: the table covers [{lo:g}, {hi:g}] nm, got "
                             f"[{wl.min():g}, {wl.max():g}] nm")
        return np.interp(wl, self.wavelength_nm, self.n), np.interp(wl, self.wavelength_nm, self.k)


def conductor_index(name: str) -> SpectralIndex:
    """The tabulated index of a conductor of :data:`CONDUCTORS` (e.g. ``"gold"``)."""
    if name not in CONDUCTORS:
        raise ValueError(f"conductor {name!r}: allowed: {', '.join(CONDUCTORS)}")
    path = DATA_DIR / CONDUCTORS[name]
    lines = path.read_text().splitlines()
    source = next(line[len("# Source: "):] for line in lines if line.startswith("# Source: "))
    header = 1 + sum(line.startswith("#") for line in lines)
    table = np.loadtxt(path, delimiter=",", comments="#", skiprows=header)
    return SpectralIndex(table[:, 0] * 1000.0, table[:, 1], table[:, 2], source)


def sellmeier(wavelength_nm, b, c_um2) -> np.ndarray:
    """Real index from the Sellmeier formula n² = 1 + Σ B_j λ²/(λ² − C_j), λ in µm, C_j in µm²."""
    lam2 = (np.asarray(wavelength_nm, dtype=np.float64) * 1e-3) ** 2
    return np.sqrt(1.0 + sum(bj * lam2 / (lam2 - cj) for bj, cj in zip(b, c_um2, strict=True)))


def cauchy(wavelength_nm, a: float, b_um2: float, c_um4: float = 0.0) -> np.ndarray:
    """Real index from Cauchy's formula n = A + B/λ² + C/λ⁴, λ in µm (B in µm², C in µm⁴)."""
    lam2 = (np.asarray(wavelength_nm, dtype=np.float64) * 1e-3) ** 2
    return a + b_um2 / lam2 + c_um4 / (lam2 * lam2)


def dielectric_index(name: str, wavelength_nm) -> np.ndarray:
    """Real index of a dielectric of :data:`DIELECTRICS` at ``wavelength_nm`` (nm), by Sellmeier."""
    if name not in DIELECTRICS:
        raise ValueError(f"dielectric {name!r}: allowed: {', '.join(DIELECTRICS)}")
    return sellmeier(wavelength_nm, *DIELECTRICS[name])


# -- materials -------------------------------------------------------------------------------------------
def _lanes(wi, wo, wavelength_nm, backend: str | None):
    """Direction pairs and wavelengths as N·L Dr.Jit lanes (pair-major), float64 on ``backend``;
    also the scalar type, so that the caller uploads its per-band values alike."""
    t = array_types(resolve_backend(backend))
    wi, wo = np.broadcast_arrays(check_directions("wi", wi), check_directions("wo", wo))
    shape = wi.shape[:-1]
    wi, wo = wi.reshape(-1, 3), wo.reshape(-1, 3)
    wl = np.atleast_1d(np.asarray(wavelength_nm, dtype=np.float64))
    n, n_wl = wi.shape[0], wl.size
    lane = dr.arange(t.UInt32, n * n_wl)
    pair, band = lane // n_wl, lane % n_wl

    def gather(v):
        return dr.gather(t.Array3f64, t.Float64(np.ascontiguousarray(v).ravel()), pair)

    return gather(wi), gather(wo), band, shape + (n_wl,), wl, t.Float64


def _per_band(scalar, values, band):
    """Per-band float64 values (one per wavelength) gathered onto the lanes."""
    return dr.gather(scalar, scalar(np.asarray(values, dtype=np.float64)), band)


def _ggx_lobe(wi, wo, alpha: float):
    """D G / (4 cos θi cos θo) of isotropic GGX with separable Smith masking, and cos θd = ωi·h."""
    h = dr.normalize(wi + wo)
    a2 = alpha * alpha
    cos_h2 = h.z * h.z
    d = a2 / (dr.pi * dr.square(cos_h2 * (a2 - 1.0) + 1.0))

    def g1(w):
        c2 = w.z * w.z
        return 2.0 / (1.0 + dr.safe_sqrt(1.0 + a2 * (1.0 - c2) / c2))

    above = (wi.z > 0) & (wo.z > 0)
    lobe = d * g1(wi) * g1(wo) / (4.0 * wi.z * wo.z)
    return dr.select(above, lobe, 0.0), dr.maximum(dr.dot(wi, h), 0.0), above


def _result(value, shape) -> np.ndarray:
    dr.eval(value)
    return np.asarray(value.numpy(), dtype=np.float64).reshape(shape)


class SpectralLambert:
    """f_r = ρ(λ)/π in sr⁻¹; ``reflectance(wavelength_nm) -> ρ`` in [0, 1]."""

    def __init__(self, reflectance):
        self.reflectance = reflectance

    def eval(self, wi, wo, wavelength_nm, backend: str | None = None) -> np.ndarray:
        """f_r in sr⁻¹, shape (..., L) for directions (..., 3) and L wavelengths (nm)."""
        wi, wo, band, shape, wl, scalar = _lanes(wi, wo, wavelength_nm, backend)
        rho = _per_band(scalar, self.reflectance(wl), band)
        return _result(dr.select((wi.z > 0) & (wo.z > 0), rho / math.pi, 0.0), shape)


class SpectralConductor:
    """A rough conductor: GGX (roughness ``alpha`` > 0, a slope) with the exact spectral Fresnel.

    Parameters
    ----------
    index : str or SpectralIndex
        A name of :data:`CONDUCTORS` or a table.
    alpha : float
        GGX roughness (dimensionless slope), > 0.
    """

    def __init__(self, index, alpha: float):
        self.index = conductor_index(index) if isinstance(index, str) else index
        if not alpha > 0.0:
            raise ValueError(f"alpha: must be > 0, got {alpha!r}")
        self.alpha = float(alpha)

    def fresnel_normal(self, wavelength_nm) -> np.ndarray:
        """Reflectance at normal incidence, ((n − 1)² + k²)/((n + 1)² + k²), per wavelength."""
        n, k = self.index.at(wavelength_nm)
        return ((n - 1.0) ** 2 + k * k) / ((n + 1.0) ** 2 + k * k)

    def eval(self, wi, wo, wavelength_nm, backend: str | None = None) -> np.ndarray:
        """f_r in sr⁻¹, shape (..., L) for directions (..., 3) and L wavelengths (nm)."""
        wi, wo, band, shape, wl, scalar = _lanes(wi, wo, wavelength_nm, backend)
        n, k = self.index.at(wl)
        lobe, cos_d, _ = _ggx_lobe(wi, wo, self.alpha)
        f = conductor_exact(cos_d, _per_band(scalar, n, band), _per_band(scalar, k, band))
        return _result(f * lobe, shape)


class SpectralDielectric:
    """A smooth-coated diffuse base: ρd(λ)/π plus a GGX lobe with the dielectric Fresnel of η(λ).

    Parameters
    ----------
    index : str or callable
        A name of :data:`DIELECTRICS`, or ``eta(wavelength_nm) -> n``.
    alpha : float
        GGX roughness of the coat, > 0.
    reflectance : callable, optional
        ``rho_d(wavelength_nm)`` of the base, in [0, 1]; default 0 (a bare dielectric).
    """

    def __init__(self, index, alpha: float, reflectance=None):
        if isinstance(index, str):
            name = index
            dielectric_index(name, 550.0)  # validates the name

            def index(wl):
                return dielectric_index(name, wl)
        self.eta = index
        if not alpha > 0.0:
            raise ValueError(f"alpha: must be > 0, got {alpha!r}")
        self.alpha = float(alpha)
        self.reflectance = reflectance

    def eval(self, wi, wo, wavelength_nm, backend: str | None = None) -> np.ndarray:
        """f_r in sr⁻¹, shape (..., L) for directions (..., 3) and L wavelengths (nm)."""
        wi, wo, band, shape, wl, scalar = _lanes(wi, wo, wavelength_nm, backend)
        eta = _per_band(scalar, self.eta(wl), band)
        lobe, cos_d, above = _ggx_lobe(wi, wo, self.alpha)
        f = dielectric(cos_d, eta) * lobe
        if self.reflectance is not None:
            f = f + dr.select(above, _per_band(scalar, self.reflectance(wl), band) / math.pi, 0.0)
        return _result(f, shape)
