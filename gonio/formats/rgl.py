"""A measured BSDF in a tensor file, as Mitsuba 3's ``measured`` plugin and pbrt-v4 read it.

Fields (Dupuy & Jakob, "An Adaptive Parameterization for Efficient Material Acquisition and Rendering",
SIGGRAPH Asia 2018; mitsuba3 ``src/bsdfs/measured.cpp``; shared/references/FORMATS.md):

==============  ==========================  =====================================================
field           shape, dtype                meaning
==============  ==========================  =====================================================
description     u8[L]                       free text (ours: JSON metadata)
jacobian        u8[1]                       1: the reader multiplies by D(m) / (4 σ(ωi))
theta_i         f32[Nθ]                     incidence polar angles, radians, increasing
phi_i           f32[Nφ]                     incidence azimuths, radians (Nφ = 1: isotropic)
ndf             f32[H, W]                   D(m), looked up bilinearly at u(m)
sigma           f32[H, W]                   σ(ω) = ∫ D(m) max(0, ω·m) dm, looked up at u(ωi)
vndf            f32[Nφ, Nθ, H, W]           density of the VNDF warp (shape only)
luminance       f32[Nφ, Nθ, N, N]           density of the luminance warp (shape only)
rgb / spectra   f32[Nφ, Nθ, C, N, N]        f·cos θo · 4σ(ωi) / D(m) at the warped grid points
wavelengths     f32[Nλ]                     nm (spectral files only; their presence makes a file
                                            spectral)
==============  ==========================  =====================================================

A unit square point u = (u_x, u_y) stands for the angles θ = u_x² π/2, φ = (2u_y − 1)π; arrays are
indexed [row = u_y, column = u_x]. For isotropic files the φ of m is taken relative to φi.

How a reader evaluates f·cos θo at (ωi, ωo): m = normalize(ωi + ωo); s = VNDF-warp⁻¹(u(m) | φi, θi)
(Mitsuba's continuous ``Marginal2D`` over the ``vndf`` slice, linearly blended between neighbouring θi
and φi slices); the value is the bilinear lookup of ``rgb``/``spectra`` at s (blended likewise), times
``ndf``(u(m)) / (4 ``sigma``(u(ωi))). So the values belong at the points s of a uniform N × N grid, and a
writer must find the m that the same warp sends each grid point to (:func:`warp_sample`). The luminance
warp only steers importance sampling.

Writing (:func:`build_measured`): a virtual gonio-reflectometer over any BRDF callable.

- NDF, estimated from the data: for a microfacet BRDF with Smith shadowing, retro-reflection gives
  f(ω, ω) = F · D(ω) / (4 σ(ω)²) (h = ω, G1(ω) = cos θ / σ(ω)), so D ∝ f(ω, ω) σ_D(ω)². That fixed point
  is found by iteration from D₀ = f(ω, ω), normalizing ∫ D(m) cos θm dm = 1 each time (after Dupuy et
  al., "Extracting Microfacet-based BRDF Parameters from Arbitrary Materials with Power Iterations",
  EGSR 2015). Directions where the data has no retro-reflection (beyond its largest θ) take the value of
  the nearest supported θ in the same azimuth row. D only shapes the warps and is divided out of the
  stored values, so the file reproduces the data at the grid points whatever D is; a good D makes the
  stored values smooth and the interpolation between them accurate.
- VNDF slice for ωi: D(m) max(0, ωi·m) times the Jacobian u_x sin θm of the u → m map.
- NDF from measured samples (:func:`retro_from_samples`), when the data are scattered samples (an adaptive
  campaign's) rather than a BRDF to probe at retro-reflection, which a gantry cannot measure (its
  occlusion cone): microfacet theory gives f(ωi, ωo) cos θi cos θo = F(θd) D(h) G(ωi, ωo) / 4, and near
  retro-reflection (small θd) F(θd) ≈ F(0) and G ≈ G1(h)², so f(h, h) ≈ f(ωi, ωo) cos θi cos θo / cos² θh.
  Each sample with θd <= :data:`NEAR_RETRO_DEG` gives one such value at its θh; f(ω, ω) of an isotropic
  material depends on θ alone, so a local line in (θh, log value) through the :data:`RETRO_NEIGHBOURS`
  samples nearest in θh is the profile the fixed point above starts from.
- Values: f(ωi, ωo)·cos θo·4σ(ωi)/D(m) with ωo the reflection of ωi about m; 0 where ωo is below the
  horizon or the BRDF has no value there (counted in the report). With ``theta_max_deg`` (the data's
  largest θ), an ωo beyond it takes f at the same azimuth on that limit (times its own cos θo): a 0
  there would be interpolated into the measured range next to it (bilinearly, up to a grid cell inside
  the limit); the report counts these cells as ``extended``.
"""

from __future__ import annotations

import json
from functools import lru_cache

import numpy as np

from gonio.geometry import to_half_diff

__all__ = ["warp_sample", "warp_invert", "warp_tables", "estimate_ndf", "retro_from_samples",
           "build_measured", "eval_measured", "rgb_to_spectrum", "u_to_angles", "angles_to_u",
           "NEAR_RETRO_DEG", "RETRO_NEIGHBOURS"]

_HALF_PI = 0.5 * np.pi
_LUMA = np.array([0.2126, 0.7152, 0.0722])
#: Largest θd (degrees) of a sample that stands for retro-reflection in :func:`retro_from_samples`. On
#: adaptive campaigns of ggx α = 0.2 gold (600 / 1,156 / 2,299 poses), the NDF's error against the true
#: GGX D was 20 % / 2.7 % / 4.5 % with 10° (too few samples), 2.9 % / 0.40 % / 0.36 % with 20°, 0.61 % /
#: 0.53 % / 0.62 % with 30°, and through the reconstruction's f̂(ω, ω), extrapolated into the gantry's
#: occlusion cone, 3.6 % / 0.82 % / 0.94 % (``tools/bench_adaptive.py --export``). 30° is steadier on
#: few samples, but Fresnel and shadowing drift in: the export of an ``iso:step=5`` campaign of ggx
#: α = 0.35 read by Mitsuba left 1.10 % with 30° and 0.52 % with 20° (the test of
#: tests/formats/test_tensor_mitsuba.py), iso:step=5 of α = 0.2 2.23 % and 2.08 %.
NEAR_RETRO_DEG = 20.0
#: Samples nearest in θh that each point of the retro-reflection profile is fitted to.
RETRO_NEIGHBOURS = 8


def u_to_angles(u):
    """(θ, φ) radians of unit-square points u (..., 2) = (u_x, u_y)."""
    u = np.asarray(u, dtype=np.float64)
    return u[..., 0] ** 2 * _HALF_PI, (2.0 * u[..., 1] - 1.0) * np.pi


def angles_to_u(theta, phi):
    """Unit-square points (..., 2) of (θ, φ) radians; u_y wrapped into [0, 1)."""
    ux = np.sqrt(np.clip(np.asarray(theta, dtype=np.float64), 0.0, None) / _HALF_PI)
    uy = (np.asarray(phi, dtype=np.float64) + np.pi) / (2.0 * np.pi)
    return np.stack([ux, uy - np.floor(uy)], axis=-1)


def warp_tables(density: np.ndarray):
    """Normalized data, conditional and marginal CDFs of a continuous Marginal2D warp.

    Parameters
    ----------
    density : array_like, shape (..., H, W)
        Non-negative densities over the unit square (bilinear between nodes), one per leading index.

    Returns
    -------
    data, cond, marg : numpy.ndarray, shapes (..., H, W), (..., H, W), (..., H)
        In patch units, normalized so that each slice integrates to 1 (the tables Mitsuba builds).
    """
    d = np.asarray(density, dtype=np.float64)
    steps = np.cumsum(0.5 * (d[..., :-1] + d[..., 1:]), axis=-1)
    cond = np.concatenate([np.zeros(d.shape[:-1] + (1,)), steps], axis=-1)
    rows = cond[..., -1]
    marg = np.concatenate([np.zeros(rows.shape[:-1] + (1,)), np.cumsum(0.5 * (rows[..., :-1] + rows[..., 1:]),
                                                                        axis=-1)], axis=-1)
    total = marg[..., -1:]
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(total > 0, 1.0 / total, 0.0)
    return d * scale[..., None], cond * scale[..., None], marg * scale


def _solve_linear(c0, c1, s):
    """t in [0, 1] with ∫₀ᵗ ((1 − τ) c0 + τ c1) dτ = s (Mitsuba's continuous inversion)."""
    const = np.abs(c0 - c1) < 1e-4 * (c0 + c1)
    with np.errstate(invalid="ignore", divide="ignore"):
        quad = (c0 - np.sqrt(np.maximum(c0 * c0 - 2.0 * s * (c0 - c1), 0.0))) / (c0 - c1)
        lin = 2.0 * s / (c0 + c1)
    t = np.where(const, lin, quad)
    return np.clip(np.nan_to_num(t), 0.0, 1.0)


def warp_sample(density: np.ndarray, s) -> np.ndarray:
    """Mitsuba's continuous ``Marginal2D::sample`` over one density slice, in float64.

    Parameters
    ----------
    density : array_like, shape (H, W)
    s : array_like, shape (M, 2)
        Points (x, y) of the unit square.

    Returns
    -------
    numpy.ndarray, shape (M, 2)
        The warped points u.
    """
    data, cond, marg = warp_tables(density)
    h, w = data.shape
    s = np.asarray(s, dtype=np.float64).reshape(-1, 2)
    sx, sy = s[:, 0].copy(), s[:, 1].copy()
    row = np.clip(np.searchsorted(marg, sy, side="left") - 1, 0, h - 2)
    sy = sy - marg[row]
    r0, r1 = cond[row, -1], cond[row + 1, -1]
    ty = _solve_linear(r0, r1, sy)
    sx = sx * ((1.0 - ty) * r0 + ty * r1)
    # Largest column whose interpolated conditional CDF is below sx (binary search, per sample).
    lo, hi = np.zeros(len(sx), dtype=np.int64), np.full(len(sx), w - 2, dtype=np.int64)
    while np.any(lo < hi):
        mid = (lo + hi + 1) // 2
        below = (1.0 - ty) * cond[row, mid] + ty * cond[row + 1, mid] < sx
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid - 1)
    col = lo
    sx = sx - ((1.0 - ty) * cond[row, col] + ty * cond[row + 1, col])
    c0 = (1.0 - ty) * data[row, col] + ty * data[row + 1, col]
    c1 = (1.0 - ty) * data[row, col + 1] + ty * data[row + 1, col + 1]
    tx = _solve_linear(c0, c1, sx)
    return np.stack([(col + tx) / (w - 1), (row + ty) / (h - 1)], axis=1)


def _blend(table, slices, weights, *idx):
    """Σ_j weights[:, j] · table[slices[:, j], *idx] (linear blending of parameter slices)."""
    out = 0.0
    for j in range(slices.shape[1]):
        out = out + weights[:, j] * table[(slices[:, j],) + idx]
    return out


def warp_invert(tables, u, slices=None, weights=None) -> np.ndarray:
    """Mitsuba's continuous ``Marginal2D::invert``, optionally blending parameter slices.

    Parameters
    ----------
    tables : tuple
        ``warp_tables`` of a stack of slices (S, H, W) (or of one slice (H, W)).
    u : array_like, shape (M, 2)
    slices, weights : array_like, shape (M, J), optional
        Slice indices and blending weights per point (default: slice 0 with weight 1).
    """
    data, cond, marg = (t if t.ndim == 3 else t[None] for t in (tables[0], tables[1], tables[2][..., None]))
    marg = marg[..., 0]
    u = np.asarray(u, dtype=np.float64).reshape(-1, 2)
    m = len(u)
    if slices is None:
        slices, weights = np.zeros((m, 1), dtype=np.int64), np.ones((m, 1))
    _, h, w = data.shape
    pos = np.clip(u, 0.0, 1.0) * np.array([w - 1, h - 1])
    px = np.minimum(pos[:, 0].astype(np.int64), w - 2)
    py = np.minimum(pos[:, 1].astype(np.int64), h - 2)
    fx, fy = pos[:, 0] - px, pos[:, 1] - py
    v00, v10 = _blend(data, slices, weights, py, px), _blend(data, slices, weights, py, px + 1)
    v01, v11 = _blend(data, slices, weights, py + 1, px), _blend(data, slices, weights, py + 1, px + 1)
    c0, c1 = (1 - fy) * v00 + fy * v01, (1 - fy) * v10 + fy * v11
    sx = fx * (c0 + 0.5 * fx * (c1 - c0))
    sx = sx + (1 - fy) * _blend(cond, slices, weights, py, px)
    sx = sx + fy * _blend(cond, slices, weights, py + 1, px)
    r0, r1 = _blend(cond, slices, weights, py, w - 1), _blend(cond, slices, weights, py + 1, w - 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        sx = sx / ((1 - fy) * r0 + fy * r1)
    sy = fy * (r0 + 0.5 * fy * (r1 - r0)) + _blend(marg, slices, weights, py)
    return np.stack([np.nan_to_num(sx), sy], axis=1)


def _bilinear(table, u, slices=None, weights=None):
    """Bilinear lookup of table (S, H, W) or (H, W) at unit-square points u (M, 2), clamped."""
    t = table if table.ndim == 3 else table[None]
    m = len(u)
    if slices is None:
        slices, weights = np.zeros((m, 1), dtype=np.int64), np.ones((m, 1))
    _, h, w = t.shape
    pos = np.clip(u, 0.0, 1.0) * np.array([w - 1, h - 1])
    px = np.minimum(pos[:, 0].astype(np.int64), w - 2)
    py = np.minimum(pos[:, 1].astype(np.int64), h - 2)
    fx, fy = pos[:, 0] - px, pos[:, 1] - py
    top = (1 - fx) * _blend(t, slices, weights, py, px) + fx * _blend(t, slices, weights, py, px + 1)
    bottom = ((1 - fx) * _blend(t, slices, weights, py + 1, px)
              + fx * _blend(t, slices, weights, py + 1, px + 1))
    return (1 - fy) * top + fy * bottom


def _param_weights(values, x):
    """Mitsuba's ``interpolate_weights`` along one parameter: (index of the lower slice, its weight)."""
    values = np.asarray(values, dtype=np.float64)
    if values.size == 1:
        return np.zeros(len(x), dtype=np.int64), np.ones(len(x)), np.zeros(len(x))
    j = np.clip(np.searchsorted(values, x, side="left") - 1, 0, values.size - 2)
    w1 = np.clip((x - values[j]) / (values[j + 1] - values[j]), 0.0, 1.0)
    return j, 1.0 - w1, w1


def _sph(theta, phi):
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=-1)


def _node_angles(shape):
    h, w = shape
    ux, uy = np.meshgrid(np.linspace(0, 1, w), np.linspace(0, 1, h))
    theta, phi = u_to_angles(np.stack([ux, uy], axis=-1))
    return theta, phi, ux


def _quadrature(shape):
    """Directions (H·W, 3), weights (H·W,) of the trapezoid rule over the u grid (solid angle)."""
    h, w = shape
    theta, phi, ux = _node_angles(shape)
    wx = np.full(w, 1.0 / (w - 1))
    wx[[0, -1]] *= 0.5
    wy = np.full(h, 1.0 / (h - 1))
    wy[[0, -1]] *= 0.5
    jac = 2.0 * np.pi ** 2 * ux * np.sin(theta)
    weight = (wy[:, None] * wx[None, :]) * jac
    # The last row (φ = π) repeats the first (φ = −π): count that azimuth once.
    weight[0] += weight[-1]
    weight[-1] = 0.0
    return _sph(theta, phi).reshape(-1, 3), weight.reshape(-1)


@lru_cache(maxsize=2)
def _ndf_operators(shape):
    """The quadrature's directions (H·W, 3), its projected-area operator P (H·W, H·W), P[j, k] =
    max(0, ωj·ωk) wk, and cos θk wk (H·W,): the same for every estimate of one shape (P of the default
    48 × 48 costs 0.1 s and 42 MB), so made once per shape and kept read-only."""
    dirs, quad = _quadrature(shape)
    ops = dirs, np.maximum(dirs @ dirs.T, 0.0) * quad[None, :], dirs[:, 2] * quad
    for a in ops:
        a.flags.writeable = False
    return ops


def estimate_ndf(retro, shape=(48, 48), iterations=8):
    """NDF and projected area σ from retro-reflection values (see the module docstring).

    Parameters
    ----------
    retro : callable
        ``retro(w)`` for unit vectors w (M, 3): the luminance of f_r(w, w) in sr⁻¹, NaN where unknown.
    shape : (int, int)
        (H, W) of the ``ndf`` and ``sigma`` tables.
    iterations : int
        Fixed-point iterations.

    Returns
    -------
    ndf, sigma : numpy.ndarray, shape (H, W), float64
        D(m) normalized so that ∫ D cos θm dm = 1, and σ(ω) = ∫ D(m) max(0, ω·m) dm.
    """
    dirs, proj, cos_w = _ndf_operators(tuple(int(n) for n in shape))
    f = np.asarray(retro(dirs), dtype=np.float64).reshape(shape)
    theta = _node_angles(shape)[0]
    for r in range(shape[0]):  # unknown retro-reflection: the nearest supported θ of the same row
        ok = np.isfinite(f[r]) & (theta[r] < _HALF_PI)
        if ok.any():
            f[r] = np.interp(theta[r], theta[r][ok], f[r][ok])
        else:
            f[r] = np.nan
    if not np.isfinite(f).any() or np.nanmax(f) <= 0:
        f = np.ones(shape)
    f = np.where(np.isfinite(f), f, np.nanmean(f))
    f = np.maximum(f, 1e-6 * f.max())
    d = f.reshape(-1)
    for _ in range(iterations):
        d = d / (cos_w @ d)
        sigma = proj @ d
        d = f.reshape(-1) * sigma ** 2
    d = d / (cos_w @ d)
    return d.reshape(shape), (proj @ d).reshape(shape)


def retro_from_samples(wi, wo, value, theta_d_max_deg: float = NEAR_RETRO_DEG,
                       neighbours: int = RETRO_NEIGHBOURS):
    """``retro(w)`` for :func:`estimate_ndf` from measured isotropic samples (module docstring), or None
    when fewer than ``neighbours`` samples lie within ``theta_d_max_deg`` of retro-reflection.

    Parameters
    ----------
    wi, wo : array_like, shape (N, 3)
        The samples' unit vectors.
    value : array_like, shape (N, C)
        f_r (sr⁻¹); R, G, B weigh by luminance, other channel counts are averaged. Samples with a value
        that is not finite or not above 0 are left out.
    """
    from scipy.spatial import cKDTree

    wi, wo = np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64)
    v = np.asarray(value, dtype=np.float64)
    lum = v @ _LUMA if v.shape[1] == 3 else v.mean(axis=1)
    theta_h, _, theta_d, _ = to_half_diff(wi, wo)
    retro = lum * wi[:, 2] * wo[:, 2] / np.cos(theta_h) ** 2
    keep = (theta_d <= np.radians(theta_d_max_deg)) & np.isfinite(retro) & (retro > 0)
    if keep.sum() < neighbours:
        return None
    x, y = theta_h[keep], np.log(retro[keep])
    k = int(neighbours)
    tree = cKDTree(x[:, None])

    def profile(w):
        q = np.arccos(np.clip(np.asarray(w, dtype=np.float64)[:, 2], -1.0, 1.0))
        idx = tree.query(q[:, None], k=k)[1].reshape(len(q), k)
        xs, ys = x[idx], y[idx]
        dx = xs - xs.mean(axis=1, keepdims=True)
        var = (dx * dx).sum(axis=1)
        slope = np.where(var > 1e-12, (dx * (ys - ys.mean(axis=1, keepdims=True))).sum(axis=1)
                         / np.maximum(var, 1e-12), 0.0)
        out = np.exp(ys.mean(axis=1) + slope * (q - xs.mean(axis=1)))
        return np.where(q <= x.max(), out, np.nan)  # no line past the last sample: estimate_ndf extends

    return profile


def rgb_to_spectrum(rgb, wavelengths_nm):
    """A spectrum per RGB triple by a fixed linear basis: three smooth bumps (blue 450, green 540, red
    620 nm and beyond) that sum to 1 at every wavelength, so grey stays flat. Shape (..., 3) → (..., Nλ)."""
    lam = np.asarray(wavelengths_nm, dtype=np.float64)
    b = 1.0 / (1.0 + np.exp((lam - 495.0) / 12.0))
    r = 1.0 / (1.0 + np.exp(-(lam - 585.0) / 12.0))
    g = np.clip(1.0 - b - r, 0.0, None)
    basis = np.stack([r, g, b], axis=0)
    basis = basis / basis.sum(axis=0, keepdims=True)
    return np.asarray(rgb, dtype=np.float64) @ basis


def build_measured(fr, *, theta_i_deg, phi_i_deg=(0.0,), resolution=32, ndf_shape=(48, 48),
                   spectral_nm=None, description: dict | None = None, retro_fr=None,
                   theta_max_deg: float | None = None):
    """The fields of a measured-BSDF tensor file, made by evaluating a BRDF where the reader will look.

    Parameters
    ----------
    fr : callable
        ``fr(wi, wo)`` for unit vectors (M, 3) → f_r in sr⁻¹, shape (M, 3) (R, G, B); NaN where unknown.
    theta_i_deg : sequence of float
        Incidence polar angles (degrees, increasing; start at 0, the reader clamps beyond the last).
    phi_i_deg : sequence of float
        Incidence azimuths (degrees). One value: an isotropic file. Several: should span [−180, 180].
    resolution : int
        N of the N × N value grid per incidence.
    ndf_shape : (int, int)
        (H, W) of ``ndf``, ``sigma`` and the ``vndf`` slices.
    spectral_nm : sequence of float, optional
        Wavelengths (nm) of a spectral file (``spectra`` + ``wavelengths``); RGB (``rgb``) when None.
    description : dict, optional
        Metadata written as JSON into ``description``.
    retro_fr : callable, optional
        ``retro_fr(w)`` → f_r(w, w), shape (M, 3), for the NDF estimate (default: ``fr(w, w)``); lets a
        caller tell the NDF probes from the value grid's queries.
    theta_max_deg : float, optional
        The data's largest θ: ωo beyond it take f at the same azimuth on the limit (module docstring).

    Returns
    -------
    fields : dict of str to numpy.ndarray
        Ready for :func:`gonio.formats.tensor.write_tensor`.
    counts : dict
        ``points`` (grid points), ``filled`` (with a value), ``empty`` (below the horizon or no data),
        ``extended`` (filled from the ``theta_max_deg`` limit, part of ``filled``).
    """
    theta_i = np.radians(np.asarray(theta_i_deg, dtype=np.float64))
    phi_i = np.radians(np.asarray(phi_i_deg, dtype=np.float64))
    isotropic = phi_i.size == 1
    if isotropic:
        phi_i = np.zeros(1)

    def retro(w):
        v = fr(w, w) if retro_fr is None else retro_fr(w)
        return v @ np.array([0.2126, 0.7152, 0.0722]) if v.shape[1] == 3 else v.mean(axis=1)

    ndf, sigma = estimate_ndf(retro, ndf_shape)
    ndf32, sigma32 = ndf.astype(np.float32), sigma.astype(np.float32)
    n = resolution
    sx, sy = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    grid = np.stack([sx.ravel(), sy.ravel()], axis=1)
    m_theta, m_phi, ux = _node_angles(ndf_shape)
    m_nodes = _sph(m_theta, m_phi)
    vndf = np.zeros((phi_i.size, theta_i.size) + tuple(ndf_shape))
    values = np.zeros((phi_i.size, theta_i.size, 3, n, n))
    filled = extended = 0
    limit = _HALF_PI if theta_max_deg is None else min(_HALF_PI, np.radians(float(theta_max_deg)))
    for a, p in enumerate(phi_i):
        for j, t in enumerate(theta_i):
            wi = _sph(t, p)
            # Isotropic files take φm relative to φi; with φi = 0 the node directions are the same.
            vndf[a, j] = ndf * np.maximum(m_nodes @ wi, 0.0) * ux * np.sin(m_theta)
            u_m = warp_sample(vndf[a, j], grid)
            th_m, ph_m = u_to_angles(u_m)
            m = _sph(th_m, ph_m + (p if isotropic else 0.0))
            dot = m @ wi
            wo = 2.0 * dot[:, None] * m - wi
            ok = (wo[:, 2] > 0) & (dot > 0)
            beyond = ok & (wo[:, 2] < np.cos(limit))
            f = np.full((len(grid), 3), np.nan)
            if ok.any():
                f[ok] = fr(np.broadcast_to(wi, (int(ok.sum()), 3)), _at_most(wo[ok], limit))
            d_m = _bilinear(ndf32.astype(np.float64), u_m)
            s_i = _bilinear(sigma32.astype(np.float64), angles_to_u(t, p)[None])[0]
            with np.errstate(invalid="ignore", divide="ignore"):
                v = f * (wo[:, 2:3] * 4.0 * s_i / d_m[:, None])
            good = ok & np.isfinite(v).all(axis=1) & (d_m > 0)
            filled += int(good.sum())
            extended += int((good & beyond).sum())
            values[a, j] = np.where(good[:, None], v, 0.0).T.reshape(3, n, n)
    lum = np.einsum("c,pjcyx->pjyx", np.array([0.2126, 0.7152, 0.0722]), values)
    lum = np.maximum(lum, 1e-4 * lum.max(axis=(2, 3), keepdims=True) + 1e-12)
    meta = json.dumps(description or {}, sort_keys=True)
    fields = {
        "description": np.frombuffer(meta.encode("utf-8"), dtype=np.uint8).copy(),
        "jacobian": np.array([1], dtype=np.uint8),
        "theta_i": theta_i.astype(np.float32),
        "phi_i": phi_i.astype(np.float32),
        "ndf": ndf32,
        "sigma": sigma32,
        "vndf": vndf.astype(np.float32),
        "luminance": lum.astype(np.float32),
    }
    if spectral_nm is None:
        fields["rgb"] = values.astype(np.float32)
    else:
        lam = np.asarray(spectral_nm, dtype=np.float64)
        spec = rgb_to_spectrum(np.moveaxis(values, 2, -1), lam)
        fields["spectra"] = np.moveaxis(spec, -1, 2).astype(np.float32)
        fields["wavelengths"] = lam.astype(np.float32)
    points = values.shape[0] * values.shape[1] * n * n
    return fields, {"points": points, "filled": filled, "empty": points - filled, "extended": extended}


def _at_most(w, limit):
    """Unit vectors (M, 3) with θ above ``limit`` moved onto it along their azimuth."""
    over = w[:, 2] < np.cos(limit)
    if not over.any():
        return w
    out = w.copy()
    rho = np.hypot(w[over, 0], w[over, 1])[:, None]
    out[over, :2] = w[over, :2] / np.where(rho > 0, rho, 1.0) * np.sin(limit)
    out[over, 2] = np.cos(limit)
    return out


def eval_measured(fields: dict, wi, wo, wavelengths_nm=None) -> np.ndarray:
    """f·cos θo of a measured-BSDF tensor file at direction pairs, the way Mitsuba 3 evaluates it.

    Parameters
    ----------
    fields : dict
        As read by :func:`gonio.formats.tensor.read_tensor`.
    wi, wo : array_like, shape (M, 3)
        Unit vectors.
    wavelengths_nm : array_like, optional
        For spectral files: the wavelengths to evaluate (default: the file's own).

    Returns
    -------
    numpy.ndarray, shape (M, C)
        f·cos θo (sr⁻¹) per channel (R, G, B or wavelength); 0 below the horizon.
    """
    wi = np.asarray(wi, dtype=np.float64).reshape(-1, 3)
    wo = np.asarray(wo, dtype=np.float64).reshape(-1, 3)
    theta_v = fields["theta_i"].astype(np.float64)
    phi_v = fields["phi_i"].astype(np.float64)
    isotropic = phi_v.size <= 2
    spectral = "wavelengths" in fields
    spectra = (fields["spectra"] if spectral else fields["rgb"]).astype(np.float64)
    m = wi + wo
    m = m / np.linalg.norm(m, axis=1, keepdims=True)
    th_i = 2.0 * np.arcsin(np.clip(0.5 * np.linalg.norm(wi - [0, 0, 1], axis=1), 0, 1))
    ph_i = np.arctan2(wi[:, 1], wi[:, 0])
    th_m = 2.0 * np.arcsin(np.clip(0.5 * np.linalg.norm(m - [0, 0, 1], axis=1), 0, 1))
    ph_m = np.arctan2(m[:, 1], m[:, 0])
    u_m = angles_to_u(th_m, ph_m - ph_i if isotropic else ph_m)
    u_wi = angles_to_u(th_i, ph_i)
    jp, wp0, wp1 = _param_weights(phi_v, ph_i)
    jt, wt0, wt1 = _param_weights(theta_v, th_i)
    n_t = theta_v.size
    stride_p = n_t if phi_v.size > 1 else 0
    stride_t = 1 if n_t > 1 else 0
    slices = np.stack([jp * n_t + jt, jp * n_t + jt + stride_t, (jp * n_t + jt) + stride_p,
                       (jp * n_t + jt) + stride_p + stride_t], axis=1)
    weights = np.stack([wp0 * wt0, wp0 * wt1, wp1 * wt0, wp1 * wt1], axis=1)
    vndf = fields["vndf"].astype(np.float64).reshape((-1,) + fields["vndf"].shape[2:])
    sample = warp_invert(warp_tables(vndf), u_m, slices, weights)
    n_c = spectra.shape[2]
    flat = spectra.reshape((-1,) + spectra.shape[2:])
    if spectral:
        lam = fields["wavelengths"].astype(np.float64) if wavelengths_nm is None else \
            np.asarray(wavelengths_nm, dtype=np.float64)
        out = np.empty((len(wi), lam.size))
        for k, x in enumerate(lam):
            jl, wl0, wl1 = _param_weights(fields["wavelengths"].astype(np.float64), np.full(len(wi), x))
            a = wl0 * _bilinear_channel(flat, jl, sample, slices, weights) + \
                wl1 * _bilinear_channel(flat, np.minimum(jl + 1, n_c - 1), sample, slices, weights)
            out[:, k] = a
    else:
        out = np.stack([_bilinear_channel(flat, np.full(len(wi), c), sample, slices, weights)
                        for c in range(n_c)], axis=1)
    if fields["jacobian"][0]:
        out = out * (_bilinear(fields["ndf"].astype(np.float64), u_m)
                     / (4.0 * _bilinear(fields["sigma"].astype(np.float64), u_wi)))[:, None]
    active = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    return np.where(active[:, None], out, 0.0)


def _bilinear_channel(flat, channel, u, slices, weights):
    """Bilinear lookup of ``flat[slice, channel]`` (S, C, N, N) per point, blended over slices."""
    out = 0.0
    _, _, h, w = flat.shape
    pos = np.clip(u, 0.0, 1.0) * np.array([w - 1, h - 1])
    px = np.minimum(pos[:, 0].astype(np.int64), w - 2)
    py = np.minimum(pos[:, 1].astype(np.int64), h - 2)
    fx, fy = pos[:, 0] - px, pos[:, 1] - py
    for j in range(slices.shape[1]):
        s = np.clip(slices[:, j], 0, flat.shape[0] - 1)
        v = ((1 - fy) * ((1 - fx) * flat[s, channel, py, px] + fx * flat[s, channel, py, px + 1])
             + fy * ((1 - fx) * flat[s, channel, py + 1, px] + fx * flat[s, channel, py + 1, px + 1]))
        out = out + weights[:, j] * v
    return out
