"""Spectral to colour: spectral BRDFs and reflectances to CIE XYZ and linear RGB, and the per-channel
(RGB) conductors that the built-in ``metal=NAME`` materials use.

Conversion. A spectral quantity q(λ) (a reflectance, or a BRDF in sr⁻¹) lit by an illuminant S(λ) has

    X = Σ q(λ) S(λ) x̄(λ) Δλ / Σ S(λ) ȳ(λ) Δλ        (Y, Z alike with ȳ, z̄)

so a perfect white reflector has Y = 1 and a white Lambertian (q = 1/π sr⁻¹) has Y = 1/π: the colour
keeps the unit of q. The CIE 1931 2° observer and the CIE illuminants are colour-science's tables
(``colour.MSDS_CMFS``, ``colour.SDS_ILLUMINANTS``) on a 5 nm grid over [380, 780] nm. XYZ goes to
linear (not gamma-encoded) RGB of ``sRGB`` (D65 white) or ``ACEScg`` (ACES white) with
``colour.XYZ_to_RGB``, the illuminant's white chromatically adapted (CAT02) to the space's white, so
a perfect white maps to (1, 1, 1) in either space.

RGB conductors. :func:`effective_rgb_conductor` turns a tabulated spectral index (Johnson & Christy 1972
for gold, silver and copper; Rakić 1995 for aluminium: see :mod:`gonio.sim.materials.spectral`) into
one (η, k) per linear-sRGB channel under D65: the spectral reflectance at normal incidence,
converted to linear sRGB, fixes F0 per channel (where that colour lies outside what a conductor can
reflect, as gold's red channel does at 1.04, the channel is clipped at the largest spectral reflectance
at that angle, 0.975 for gold at normal incidence: the other channels stay exact, the luminance drops by
~1.3 %); k is then chosen so that the exact conductor
Fresnel of (η(F0, k), k) follows the channel's spectrally converted reflectance F_c(θ) over all angles
(least squares weighted by sin θ cos θ, the projected solid angle), and η is the root of
((η − 1)² + k²)/((η + 1)² + k²) = F0 below the discriminant's edge. The built-in metals of
:mod:`gonio.sim.materials.fresnel` carry these numbers (``tests/test_colour.py`` re-derives them).

References
----------
CIE 015:2018, Colorimetry, 4th ed. (tristimulus values, normalization to the illuminant).
IEC 61966-2-1:1999 (sRGB); Academy S-2014-004 (ACEScg, AP1 primaries).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from gonio.jit import array_types, resolve_backend
from gonio.sim.materials.fresnel import conductor_exact
from gonio.sim.materials.spectral import conductor_index

__all__ = ["colour_science", "SPACES", "OBSERVER", "WAVELENGTH_NM", "cmf_weights", "spectral_to_XYZ",
           "XYZ_to_linear_rgb", "spectral_to_rgb", "bands_to_XYZ", "bands_to_rgb", "material_rgb",
           "normal_reflectance_rgb", "effective_rgb_conductor"]

#: RGB spaces: name in colour-science's registry; the output is linear (no transfer function).
SPACES = ("sRGB", "ACEScg")
OBSERVER = "CIE 1931 2 Degree Standard Observer"
#: The wavelength grid of the conversion (nm).
WAVELENGTH_NM = np.arange(380.0, 781.0, 5.0)


@lru_cache(maxsize=1)
def colour_science():
    """colour-science, imported on first use (its import, plotting and matplotlib included, costs ~1.4 s of
    CPU, which importing this module does not). It sets numpy's print options (legacy="1.13") when
    imported: the process keeps its own."""
    with np.printoptions():
        import colour
    return colour


def _check_space(space: str) -> str:
    if space not in SPACES:
        raise ValueError(f"space: {space!r} is not one of {', '.join(SPACES)}")
    return space


@lru_cache(maxsize=8)
def _weights(illuminant: str) -> tuple[np.ndarray, np.ndarray]:
    colour = colour_science()
    if illuminant not in colour.SDS_ILLUMINANTS:
        raise ValueError(f"illuminant: {illuminant!r} is not a CIE illuminant colour-science knows "
                         f"(e.g. D65, D50, A)")
    shape = colour.SpectralShape(WAVELENGTH_NM[0], WAVELENGTH_NM[-1], 5.0)
    cmfs = colour.MSDS_CMFS[OBSERVER].copy().align(shape).values          # (L, 3)
    s = colour.SDS_ILLUMINANTS[illuminant].copy().align(shape).values     # (L,)
    w = s[:, None] * cmfs / np.sum(s * cmfs[:, 1])
    white = w.sum(axis=0)
    return w, white / white[1]


def cmf_weights(illuminant: str = "D65") -> np.ndarray:
    """Weights W (L, 3) with XYZ = Σ_λ q(λ) W(λ) on :data:`WAVELENGTH_NM` (see the module docstring)."""
    return _weights(illuminant)[0].copy()


def spectral_to_XYZ(values, illuminant: str = "D65") -> np.ndarray:
    """CIE XYZ (1931 2°) of spectral values sampled on :data:`WAVELENGTH_NM`.

    Parameters
    ----------
    values : array_like, shape (..., L)
        A reflectance (dimensionless) or a BRDF (sr⁻¹) per wavelength of :data:`WAVELENGTH_NM`.
    illuminant : str
        A CIE illuminant of colour-science (``"D65"``, ``"D50"``, ``"A"``, ...).

    Returns
    -------
    ndarray, shape (..., 3)
        X, Y, Z in the unit of ``values`` (a perfect white reflector has Y = 1).
    """
    values = np.asarray(values, dtype=np.float64)
    if values.shape[-1:] != WAVELENGTH_NM.shape:
        raise ValueError(f"values: the last axis must hold {WAVELENGTH_NM.size} samples ({WAVELENGTH_NM[0]:g}"
                         f"..{WAVELENGTH_NM[-1]:g} nm by 5 nm), got shape {values.shape}")
    return values @ _weights(illuminant)[0]


def XYZ_to_linear_rgb(XYZ, space: str = "sRGB", illuminant: str = "D65") -> np.ndarray:
    """Linear RGB of ``space`` from XYZ seen under ``illuminant`` (adapted to the space's white, CAT02)."""
    _check_space(space)
    white = _weights(illuminant)[1]
    xy = white[:2] / white.sum()
    return np.asarray(colour_science().XYZ_to_RGB(np.asarray(XYZ, dtype=np.float64), space, illuminant=xy,
                                        chromatic_adaptation_transform="CAT02", apply_cctf_encoding=False))


def spectral_to_rgb(values, space: str = "sRGB", illuminant: str = "D65") -> np.ndarray:
    """Linear RGB (..., 3) of spectral values (..., L) on :data:`WAVELENGTH_NM`, in their unit."""
    return XYZ_to_linear_rgb(spectral_to_XYZ(values, illuminant), space, illuminant)


def bands_to_XYZ(values, wavelengths_nm, illuminant: str = "D65") -> np.ndarray:
    """CIE XYZ (..., 3) of spectral values (..., B) read at band centres ``wavelengths_nm`` (a
    spectrometer's channels, e.g. 380..780 nm every 10 nm), resampled linearly onto
    :data:`WAVELENGTH_NM`; the bands must cover it. Y is in the unit of ``values``."""
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    if wl.ndim != 1 or values.shape[-1:] != wl.shape or wl.size < 2 or np.any(np.diff(wl) <= 0):
        raise ValueError(f"wavelengths_nm: ascending, one per value on the last axis; got {wl.size} for "
                         f"shape {values.shape}")
    if wl[0] > WAVELENGTH_NM[0] or wl[-1] < WAVELENGTH_NM[-1]:
        raise ValueError(f"wavelengths_nm: the bands [{wl[0]:g}, {wl[-1]:g}] nm must cover "
                         f"[{WAVELENGTH_NM[0]:g}, {WAVELENGTH_NM[-1]:g}] nm")
    flat = values.reshape(-1, wl.size)
    resampled = np.stack([np.interp(WAVELENGTH_NM, wl, v) for v in flat]).reshape(*values.shape[:-1], -1)
    return spectral_to_XYZ(resampled, illuminant)


def bands_to_rgb(values, wavelengths_nm, space: str = "sRGB", illuminant: str = "D65") -> np.ndarray:
    """Linear RGB (..., 3) of spectral values (..., B) at band centres (see :func:`bands_to_XYZ`)."""
    return XYZ_to_linear_rgb(bands_to_XYZ(values, wavelengths_nm, illuminant), space, illuminant)


def material_rgb(material, wi, wo, space: str = "sRGB", illuminant: str = "D65") -> np.ndarray:
    """Linear RGB f_r (sr⁻¹) of a spectral material (:mod:`gonio.sim.materials.spectral`).

    Parameters
    ----------
    material
        Has ``eval(wi, wo, wavelength_nm) -> (..., L)`` in sr⁻¹.
    wi, wo : array_like, shape (..., 3)
        Unit vectors in the sample frame.
    space, illuminant : str
        One of :data:`SPACES`; a CIE illuminant.

    Returns
    -------
    ndarray, shape (..., 3)
        f_r per channel in sr⁻¹.
    """
    return spectral_to_rgb(material.eval(wi, wo, WAVELENGTH_NM), space, illuminant)


def _fresnel_exact(cos_theta: np.ndarray, eta, k) -> np.ndarray:
    """Exact conductor reflectance (Dr.Jit, float64, on :func:`gonio.jit.resolve_backend`'s backend) for
    every (cos θ, λ) pair: shape (T, L)."""
    Float64 = array_types(resolve_backend()).Float64
    c = np.repeat(cos_theta, np.size(eta))
    e = np.tile(np.atleast_1d(eta), cos_theta.size)
    kk = np.tile(np.atleast_1d(k), cos_theta.size)
    out = conductor_exact(Float64(c), Float64(e), Float64(kk))
    return np.asarray(out.numpy(), dtype=np.float64).reshape(cos_theta.size, -1)


def normal_reflectance_rgb(name: str, space: str = "sRGB", illuminant: str = "D65") -> np.ndarray:
    """Linear RGB of a tabulated conductor's reflectance at normal incidence (dimensionless)."""
    n, k = conductor_index(name).at(WAVELENGTH_NM)
    return spectral_to_rgb(_fresnel_exact(np.ones(1), n, k)[0], space, illuminant)


def _eta_from_f0(f0: float, k: float) -> float:
    # ((η−1)² + k²) = F0((η+1)² + k²)  ⇔  (1−F0)η² − 2(1+F0)η + (1−F0)(1+k²) = 0; smaller root.
    a, b = 1.0 - f0, 1.0 + f0
    disc = max(b * b - a * a * (1.0 + k * k), 0.0)
    return (b - np.sqrt(disc)) / a


RGBTriple = tuple[float, float, float]


def effective_rgb_conductor(name: str, space: str = "sRGB", illuminant: str = "D65",
                            angles: int = 90) -> tuple[RGBTriple, RGBTriple]:
    """Per-channel (η, k) of a tabulated conductor (see the module docstring for the method).

    Parameters
    ----------
    name : str
        A conductor of :data:`gonio.sim.materials.spectral.CONDUCTORS`.
    space, illuminant : str
        The RGB space (:data:`SPACES`) and the CIE illuminant of the colour matching.
    angles : int
        Angles of incidence in [0°, 90°) the fit uses (midpoints of equal steps).

    Returns
    -------
    (eta, k) : two (R, G, B) tuples
        With F(0°) per channel equal to the spectral reflectance's colour at normal incidence (a channel
        above the largest spectral reflectance clipped to it: see the module docstring).

    Raises
    ------
    ValueError
        If a channel's normal-incidence reflectance is not in (0, 1) (no real conductor matches it).
    """
    n, k = conductor_index(name).at(WAVELENGTH_NM)
    theta = (np.arange(angles) + 0.5) * (0.5 * np.pi / angles)
    cos_t = np.concatenate([[1.0], np.cos(theta)])
    spectra = _fresnel_exact(cos_t, n, k)                                      # (1 + T, L)
    target = spectral_to_rgb(spectra, space, illuminant)                       # (1 + T, 3)
    # Gamut: gold's saturated yellow puts linear-sRGB red above 1, which no conductor reflects. Clip
    # each angle's channels at that angle's largest spectral reflectance (a bound the real metal
    # obeys); the other channels stay exact. (Desaturating toward the grey of equal luminance instead
    # kept Y but lifted gold's blue F0 from 0.36 to 0.46: a paler gold than the data.)
    target = np.minimum(target, spectra.max(axis=1, keepdims=True))
    weight = np.sin(theta) * np.cos(theta)
    from scipy.optimize import minimize_scalar

    etas, ks = [], []
    for c in range(3):
        f0 = float(target[0, c])
        if not 0.0 < f0 < 1.0:
            raise ValueError(f"{name}: channel {'RGB'[c]} reflects {f0:.4f} at normal incidence in {space}, "
                             f"outside (0, 1)")
        k_max = 2.0 * np.sqrt(f0) / (1.0 - f0)  # the discriminant's edge

        def cost(kc, f0=f0, c=c):
            f = _fresnel_exact(cos_t[1:], _eta_from_f0(f0, kc), kc)[:, 0]
            return float(np.sum(weight * (f - target[1:, c]) ** 2))

        kc = float(minimize_scalar(cost, bounds=(0.0, k_max), method="bounded",
                                   options={"xatol": 1e-6}).x)
        etas.append(float(_eta_from_f0(f0, kc)))
        ks.append(kc)
    return tuple(etas), tuple(ks)
