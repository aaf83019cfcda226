"""Independent numpy reference implementations of the material models, written from the formulas.

Nothing here calls ``gonio.sim.materials``: the tests compare the Dr.Jit models against these. Where
the models use a closed form or a fixed quadrature, this module integrates numerically with scipy
instead (the Blinn-Phong, Blinn and Gaussian normalizations), and it writes angles the way the notes
do (α = arccos(H·N), θt from Snell's law, the conductor Fresnel with complex arithmetic).

Every function takes ``wi``, ``wo`` of shape (N, 3), computes in their dtype (float64 for the tests,
float32 for the benchmark), and returns f_r of shape (N, 3) in sr⁻¹, 0 where either direction is at or
below the horizon. Colour parameters are sequences of three values (R, G, B).
"""

from __future__ import annotations

import math

import numpy as np

from gonio.geometry import merl_index, to_half_diff


def _quad(*args, **kw):
    """scipy.integrate.quad, imported on first use (not while every test process collects this module)."""
    from scipy.integrate import quad

    return quad(*args, **kw)


# The built-in metals, name → ((η R, G, B), (k R, G, B)), pinned here as numbers. They used to be the
# lecture notes' one (η, k) for all channels, which made gold grey; gold, silver, copper and aluminium
# are now per-channel values derived from spectral tables (Johnson & Christy 1972, Rakić 1995) under
# D65 in linear sRGB, re-derived independently in tests/test_colour.py. Steel keeps the notes' values.
METALS = {
    "gold": ((0.1433, 0.4955, 1.4767), (4.6725, 2.2501, 1.7785)),
    "silver": ((0.0574, 0.0549, 0.0431), (4.4877, 3.5555, 2.5902)),
    "copper": ((0.2371, 1.0448, 1.2968), (3.5125, 2.6262, 2.3634)),
    "aluminium": ((1.5025, 0.9853, 0.6059), (7.6484, 6.5535, 5.353)),
    "steel": ((2.485,) * 3, (3.433,) * 3),
}


# -- helpers --------------------------------------------------------------------------------------
def _rgb(x, dtype):
    return np.broadcast_to(np.asarray(x, dtype=dtype), (3,))


def _finish(wi, wo, value):
    above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    with np.errstate(invalid="ignore"):
        return np.where(above[:, None], value, 0).astype(wi.dtype)


def _half(wi, wo):
    h = wi + wo
    return h / np.linalg.norm(h, axis=1, keepdims=True)


def random_pairs(rng, n, specular_fraction=0.5, spread=0.15):
    """Direction pairs in the upper hemisphere: uniform, and a fraction with ωo near the mirror of ωi
    (within ``spread`` rad), so that narrow lobes are probed where they are not ~0."""
    def uniform(k):
        z = rng.uniform(1e-3, 1.0, k)
        phi = rng.uniform(0, 2 * np.pi, k)
        r = np.sqrt(1 - z * z)
        return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)

    wi, wo = uniform(n), uniform(n)
    k = int(n * specular_fraction)
    mirror = wi[:k] * np.array([-1.0, -1.0, 1.0])
    jitter = rng.normal(scale=spread, size=(k, 3))
    near = mirror + jitter - np.sum(jitter * mirror, axis=1, keepdims=True) * mirror
    near /= np.linalg.norm(near, axis=1, keepdims=True)
    near[:, 2] = np.abs(near[:, 2]) + 1e-3
    wo[:k] = near / np.linalg.norm(near, axis=1, keepdims=True)
    return wi, wo


# -- Lambert and the cosine lobes ---------------------------------------------------------------------
def lambert(wi, wo, albedo):
    return _finish(wi, wo, np.broadcast_to(_rgb(albedo, wi.dtype) / np.pi, wi.shape))


def blinn_phong_normalization(ke):
    """1 / (normal-incidence albedo of the (H·N)^ke lobe), by adaptive quadrature over θo."""
    albedo, _ = _quad(lambda t: np.cos(t / 2) ** ke * np.cos(t) * np.sin(t) * 2 * np.pi,
                               0, np.pi / 2, epsabs=1e-14, epsrel=1e-13)
    return 1.0 / albedo


def cosine_lobe(wi, wo, ks, ke, rho_d=0.0, *, half_vector, normalized):
    """Phong (R(I)·V) or Blinn-Phong (H·N) lobes, the notes' (÷ I·N) or the normalized forms."""
    dt = wi.dtype
    if half_vector:
        c = _half(wi, wo)[:, 2]
        norm = blinn_phong_normalization(ke) if normalized else 1.0
    else:
        r = -wi + 2 * wi[:, 2:3] * np.array([0, 0, 1], dtype=dt)  # R(I) = −I + 2(I·N)N
        c = np.sum(r * wo, axis=1)
        norm = (ke + 2) / (2 * np.pi) if normalized else 1.0
    with np.errstate(invalid="ignore", divide="ignore"):
        lobe = np.where(c > 0, np.abs(c) ** dt.type(ke), 0) * dt.type(norm)
        if not normalized:
            lobe = lobe / wi[:, 2]
    value = _rgb(rho_d, dt) / np.pi + _rgb(ks, dt) * lobe[:, None]
    return _finish(wi, wo, value)


# -- Ward --------------------------------------------------------------------------------------------
def ward(wi, wo, rho_d, rho_s, alpha_x, alpha_y):
    """The notes' Ward model with explicit half-vector angles (θh, φh)."""
    dt = wi.dtype
    h = _half(wi, wo)
    theta_h = np.arccos(np.clip(h[:, 2], -1, 1))
    phi_h = np.arctan2(h[:, 1], h[:, 0])
    with np.errstate(invalid="ignore", divide="ignore"):
        expo = -np.tan(theta_h) ** 2 * (np.cos(phi_h) ** 2 / alpha_x**2 + np.sin(phi_h) ** 2 / alpha_y**2)
        spec = np.exp(expo) / (4 * np.pi * alpha_x * alpha_y) / np.sqrt(wi[:, 2] * wo[:, 2])
    value = _rgb(rho_d, dt) / np.pi + _rgb(rho_s, dt) * spec[:, None].astype(dt)
    return _finish(wi, wo, value)


# -- Fresnel ---------------------------------------------------------------------------------------
def fresnel_conductor_notes(c, eta, k):
    """The notes' r∥², r⊥² for a conductor; ``c`` (N,), eta and k (3,) → (N, 3)."""
    c = c[:, None]
    e2 = eta**2 + k**2
    r_par = (e2 * c**2 - 2 * eta * c + 1) / (e2 * c**2 + 2 * eta * c + 1)
    r_perp = (e2 - 2 * eta * c + c**2) / (e2 + 2 * eta * c + c**2)
    return 0.5 * (r_par + r_perp)


def fresnel_conductor_complex(c, eta, k):
    """Exact Fresnel reflectance with complex index n = η + ik, by complex Snell's law."""
    n = (np.asarray(eta, np.float64) + 1j * np.asarray(k, np.float64))[None, :]
    ci = c.astype(np.float64)[:, None]
    ct = np.sqrt(1 - (1 - ci**2) / n**2)
    r_s = (ci - n * ct) / (ci + n * ct)
    r_p = (n * ci - ct) / (n * ci + ct)
    return (0.5 * (np.abs(r_s) ** 2 + np.abs(r_p) ** 2)).astype(c.dtype)


def fresnel_dielectric(c, eta):
    """The notes' r∥, r⊥ with ηi = 1, ηt = η, θt from Snell's law; total internal reflection → 1."""
    theta_i = np.arccos(np.clip(c, -1, 1))[:, None]
    s = np.sin(theta_i) / eta
    tir = s >= 1
    theta_t = np.arcsin(np.where(tir, 0, s))
    ci, ct = np.cos(theta_i), np.cos(theta_t)
    r_par = (eta * ci - ct) / (eta * ci + ct)
    r_perp = (ci - eta * ct) / (ci + eta * ct)
    return np.where(tir, 1, 0.5 * (r_par**2 + r_perp**2))


def fresnel(form, c, eta=None, k=None, *, exact=False):
    dt = c.dtype
    if form == "none":
        return np.ones((c.shape[0], 3), dtype=dt)
    if form == "dielectric":
        return fresnel_dielectric(c, _rgb(eta, dt))
    fn = fresnel_conductor_complex if exact else fresnel_conductor_notes
    return fn(c, _rgb(eta, dt), _rgb(k, dt))


# -- microfacet distributions ------------------------------------------------------------------------
def projected_integral(d_of_alpha):
    """∫ D(α) cos α dω over the hemisphere, by adaptive quadrature."""
    value, _ = _quad(lambda a: d_of_alpha(a) * np.cos(a) * np.sin(a) * 2 * np.pi, 0, np.pi / 2,
                              epsabs=1e-13, epsrel=1e-12, limit=200)
    return value


def d_beckmann(cos_alpha, m):
    """exp(−tan²α / m²) / (π m² cos⁴α), with tan²α = (1 − cos²α)/cos²α."""
    c2 = cos_alpha * cos_alpha
    return np.exp(-(1 - c2) / (c2 * m * m)) / (np.pi * m * m * c2 * c2)


def d_blinn(cos_alpha, m):
    """cos^c α with c = −ln 2 / ln cos m, normalized by quadrature."""
    c = -math.log(2) / math.log(math.cos(m))
    return cos_alpha**c / projected_integral(lambda a: np.cos(a) ** c)


def d_gaussian(cos_alpha, m):
    """exp(−(α/m)²), normalized by quadrature (split at 8m so quad sees the narrow peak)."""
    alpha = np.arccos(np.clip(cos_alpha, -1, 1))
    split = min(8 * m, np.pi / 2)
    total = 0.0
    for a, b in ((0, split), (split, np.pi / 2)):
        total += _quad(lambda t: np.exp(-((t / m) ** 2)) * np.cos(t) * np.sin(t) * 2 * np.pi, a, b,
                                epsabs=1e-15, epsrel=1e-12)[0]
    return np.exp(-((alpha / m) ** 2)) / total


def d_ggx(h, alpha_u, alpha_v):
    """GGX with the angles of h: 1 / (π αu αv cos⁴θ (1 + tan²θ (cos²φ/αu² + sin²φ/αv²))²)."""
    theta = np.arccos(np.clip(h[:, 2], -1, 1))
    phi = np.arctan2(h[:, 1], h[:, 0])
    t2 = np.tan(theta) ** 2
    denom = 1 + t2 * (np.cos(phi) ** 2 / alpha_u**2 + np.sin(phi) ** 2 / alpha_v**2)
    return 1 / (np.pi * alpha_u * alpha_v * np.cos(theta) ** 4 * denom**2)


# -- Cook-Torrance and GGX -----------------------------------------------------------------------------
def cook_torrance(wi, wo, d, m, fresnel_form="none", eta=None, k=None, denom="pi", rho_d=0.0, rho_s=1.0):
    """The notes' Cook-Torrance: ρd/π + ρs F D G / (π or 4 (N·V)(N·I)), V-groove G."""
    dt = wi.dtype
    h = _half(wi, wo)
    n_h, n_i, n_o = h[:, 2], wi[:, 2], wo[:, 2]
    v_h = np.sum(wo * h, axis=1)
    dfun = {"beckmann": d_beckmann, "blinn": d_blinn, "gaussian": d_gaussian}[d]
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        dist = np.where(n_h > 0, dfun(n_h, m), 0).astype(dt)
        g = np.minimum(1, np.minimum(2 * n_h * n_o / v_h, 2 * n_h * n_i / v_h))
        scale = np.pi if denom == "pi" else 4.0
        glossy = fresnel(fresnel_form, v_h, eta, k) * (dist * g / (scale * n_o * n_i))[:, None]
    value = _rgb(rho_d, dt) / np.pi + _rgb(rho_s, dt) * glossy
    return _finish(wi, wo, value)


def smith_g1_ggx(v, h, alpha_u, alpha_v):
    """Walter et al. G1 = 2 / (1 + sqrt(1 + α(φ)² tan²θ)), α(φ)² = cos²φ αu² + sin²φ αv²."""
    theta = np.arccos(np.clip(v[:, 2], -1, 1))
    phi = np.arctan2(v[:, 1], v[:, 0])
    a2 = np.cos(phi) ** 2 * alpha_u**2 + np.sin(phi) ** 2 * alpha_v**2
    g1 = 2 / (1 + np.sqrt(1 + a2 * np.tan(theta) ** 2))
    return np.where(np.sum(v * h, axis=1) * v[:, 2] > 0, g1, 0)


def ggx(wi, wo, alpha_u, alpha_v, fresnel_form="none", eta=None, k=None, smith="separable", rho_d=0.0,
        rho_s=1.0):
    """GGX with Smith masking and the exact (complex-index) conductor Fresnel, denominator 4."""
    dt = wi.dtype
    h = _half(wi, wo)
    with np.errstate(invalid="ignore", divide="ignore"):
        if smith == "separable":
            g = smith_g1_ggx(wi, h, alpha_u, alpha_v) * smith_g1_ggx(wo, h, alpha_u, alpha_v)
        else:
            lam = [1 / smith_g1_ggx(v, v, alpha_u, alpha_v) - 1 for v in (wi, wo)]
            g = np.where((np.sum(wi * h, 1) > 0) & (np.sum(wo * h, 1) > 0), 1 / (1 + lam[0] + lam[1]), 0)
        dist = np.where(h[:, 2] > 0, d_ggx(h, alpha_u, alpha_v), 0)
        f = fresnel(fresnel_form, np.sum(wi * h, axis=1), eta, k, exact=True)
        glossy = f * (dist * g / (4 * wi[:, 2] * wo[:, 2]))[:, None]
    value = _rgb(rho_d, dt) / np.pi + _rgb(rho_s, dt) * glossy.astype(dt)
    return _finish(wi, wo, value)


# -- MERL --------------------------------------------------------------------------------------------
def merl(wi, wo, table):
    """Nearest-bin lookup in a scaled (3, 1458000) table with gonio.geometry; negative → 0."""
    theta_h, _, theta_d, phi_d = to_half_diff(wi, wo)
    values = table[:, merl_index(theta_h, theta_d, phi_d)].T
    return _finish(wi, wo, np.where(values < 0, 0, values))
