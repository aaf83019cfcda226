"""Microfacet distributions D and masking-shadowing terms G, in Dr.Jit, with their normalizations.

Every D here is normalized over projected microfacet area, ∫ D(h) (h·N) dω_h = 1 over the hemisphere,
so that a microfacet model with the denominator 4 (N·I)(N·V) reflects at most what arrives:

- Beckmann: D(α) = exp(−tan²α / m²) / (π m² cos⁴α); normalized as written (m: RMS slope).
- Blinn: D(α) = (c + 2)/(2π) · cos^c α with c = −ln 2 / ln cos m, so that D halves at α = m
  (m an angle in radians, 0 < m < π/2); the lecture notes print the exponent without its minus sign.
  (c + 2)/(2π) is the exact normalization: ∫ cos^c α cos α dω = 2π/(c + 2).
- Gaussian (Torrance-Sparrow): D(α) = K(m) · exp(−(α/m)²) (m in radians), with K(m) computed once per
  m by Gauss-Legendre quadrature (:func:`gaussian_norm`), since the integral has no closed form.
- GGX / Trowbridge-Reitz: D(h) = 1 / (π αu αv (hx²/αu² + hy²/αv² + hz²)²); normalized as written.

α is the angle between h and N. Directions h at or below the horizon get D = 0.

References
----------
P. Slusallek, "Material Models" (lecture notes): Blinn, Torrance-Sparrow, Beckmann; V-groove G.
B. Walter et al., "Microfacet Models for Refraction through Rough Surfaces", EGSR 2007 (GGX, Smith G1).
E. Heitz, "Understanding the Masking-Shadowing Function in Microfacet-Based BRDFs", JCGT 3(2), 2014
(separable and height-correlated Smith forms).
"""

from __future__ import annotations

import math

import drjit as dr
import numpy as np

from .base import positive_power

__all__ = ["DISTRIBUTIONS", "beckmann", "blinn", "gaussian", "ggx", "v_groove", "smith_ggx_g1",
           "smith_ggx_lambda", "blinn_exponent", "blinn_norm", "gaussian_norm", "gaussian_norm_dr"]

DISTRIBUTIONS = ("beckmann", "blinn", "gaussian")
# Gauss-Legendre nodes per panel of the Gaussian normalization; the integrand is smooth and analytic,
# so two panels of 64 nodes reach double precision for every m.
_GL_NODES = 64


def blinn_exponent(m: float) -> float:
    """Exponent c = −ln 2 / ln cos m of the Blinn distribution (D halves at α = m, m in radians)."""
    return -math.log(2.0) / math.log(math.cos(m))


def blinn_norm(c: float) -> float:
    """(c + 2) / (2π): makes cos^c α integrate to 1 over projected microfacet area."""
    return (c + 2.0) / (2.0 * math.pi)


def gaussian_norm(m: float) -> float:
    """K(m) = 1 / (2π ∫₀^{π/2} exp(−(α/m)²) cos α sin α dα), by fixed-order Gauss-Legendre quadrature.

    The integral is split at min(8m, π/2): below it the Gaussian lives; above it the integrand is below
    e⁻⁶⁴ but is still integrated, so the constant is right for every m > 0.
    """
    split = min(8.0 * m, 0.5 * math.pi)
    x, w = np.polynomial.legendre.leggauss(_GL_NODES)
    total = 0.0
    for a, b in ((0.0, split), (split, 0.5 * math.pi)):
        if b > a:
            alpha = 0.5 * (b - a) * x + 0.5 * (b + a)
            total += 0.5 * (b - a) * float(np.sum(w * np.exp(-((alpha / m) ** 2)) * np.cos(alpha) *
                                                  np.sin(alpha)))
    return 1.0 / (2.0 * math.pi * total)


def gaussian_norm_dr(m):
    """:func:`gaussian_norm` for a Dr.Jit scalar array ``m`` (size 1), differentiable in ``m``.

    The same two Gauss-Legendre panels, each summed with ``dr.sum`` over an array of the nodes.
    """
    scalar = type(m)
    x, w = np.polynomial.legendre.leggauss(_GL_NODES)
    x, w = scalar(x), scalar(w)
    split = dr.minimum(8.0 * m, 0.5 * math.pi)
    total = 0.0
    for a, b in ((0.0, split), (split, 0.5 * math.pi)):
        alpha = 0.5 * (b - a) * x + 0.5 * (b + a)
        integrand = w * dr.exp(-dr.square(alpha / m)) * dr.cos(alpha) * dr.sin(alpha)
        total = total + 0.5 * (b - a) * dr.sum(integrand)
    return 1.0 / (2.0 * math.pi * total)


def _sin2(h):
    return h.x * h.x + h.y * h.y


def beckmann(h, m):
    """Beckmann D(h) for unit half vectors ``h`` and RMS slope ``m``; 0 for h.z <= 0."""
    cos2 = h.z * h.z
    # tan²α from the components: 1 − cos² would cancel catastrophically near the peak in float32.
    tan2 = _sin2(h) / cos2
    d = dr.exp(-tan2 / (m * m)) / (dr.pi * m * m * cos2 * cos2)
    return dr.select(h.z > 0, d, 0)


def blinn(h, c, norm):
    """Normalized Blinn D(h) = norm · cos^c α (``norm`` from :func:`blinn_norm`)."""
    return norm * positive_power(h.z, c)


def gaussian(h, m, norm):
    """Normalized Gaussian D(h) = norm · exp(−(α/m)²) (``norm`` from :func:`gaussian_norm`)."""
    alpha = dr.atan2(dr.sqrt(_sin2(h)), h.z)
    return dr.select(h.z > 0, norm * dr.exp(-dr.square(alpha / m)), 0)


def ggx(h, alpha_u, alpha_v):
    """GGX (Trowbridge-Reitz) D(h), anisotropic with roughness αu along x and αv along y."""
    s = dr.square(h.x / alpha_u) + dr.square(h.y / alpha_v) + h.z * h.z
    return dr.select(h.z > 0, 1 / (dr.pi * alpha_u * alpha_v * s * s), 0)


def v_groove(n_h, n_i, n_o, v_h):
    """Cook-Torrance V-groove G = min{1, 2(N·H)(N·V)/(V·H), 2(N·H)(N·I)/(V·H)}."""
    return dr.minimum(1, 2 * n_h * dr.minimum(n_o, n_i) / v_h)


def smith_ggx_lambda(v, alpha_u, alpha_v):
    """Smith Λ(v) of GGX: (−1 + sqrt(1 + α(v)² tan²θv)) / 2, α(v) the roughness projected on v."""
    tan2_alpha2 = (dr.square(alpha_u * v.x) + dr.square(alpha_v * v.y)) / (v.z * v.z)
    return 0.5 * (dr.sqrt(1 + tan2_alpha2) - 1)


def smith_ggx_g1(v, h, alpha_u, alpha_v):
    """Smith G1(v, h) = 1 / (1 + Λ(v)) of GGX; 0 where v sees the back of the facet h."""
    g1 = 1 / (1 + smith_ggx_lambda(v, alpha_u, alpha_v))
    return dr.select(dr.dot(v, h) * v.z > 0, g1, 0)
