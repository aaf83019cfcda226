"""Microfacet distributions integrate to 1 over projected area, ∫ D(h)(h·N) dω_h = 1, and have the
shapes their definitions promise. Quadrature: composite Gauss-Legendre in θh with panels that follow
the peak (widths growing geometrically from the roughness), trapezoid rule in φh (exact for the
trigonometric polynomials an anisotropic D is made of, up to its decay)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gonio.sim.materials import microfacet as mf


def hemisphere_quadrature(width, jit, n_phi=1):
    """Nodes h (Array3f64 of ``jit``'s backend) and weights for ∫ g(h) dω_h; panels in θ at width·(1/4,
    1/2, 1, 2, …)."""
    Float64 = jit.Float64
    edges = [0.0] + [width * 2.0**j for j in range(-2, 12) if width * 2.0**j < math.pi / 2] + [math.pi / 2]
    x, w = np.polynomial.legendre.leggauss(48)
    panels = list(zip(edges[:-1], edges[1:], strict=True))
    theta = np.concatenate([0.5 * (b - a) * x + 0.5 * (b + a) for a, b in panels])
    w_theta = np.concatenate([0.5 * (b - a) * w for a, b in panels]) * np.sin(theta)
    phi = (np.arange(n_phi) + 0.5) * (2 * math.pi / n_phi)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    weights = (w_theta[:, None] * np.full(n_phi, 2 * math.pi / n_phi)).ravel()
    h = jit.Array3f64(Float64((np.sin(t) * np.cos(p)).ravel()), Float64((np.sin(t) * np.sin(p)).ravel()),
                  Float64(np.cos(t).ravel()))
    return h, weights


def projected_integral(d_values, h, weights):
    return float(np.sum(d_values.numpy() * h.z.numpy() * weights))


@pytest.mark.parametrize("m", [0.02, 0.2, 0.6, 1.5])
def test_beckmann_is_normalized(m, jit):
    h, w = hemisphere_quadrature(m, jit)
    assert projected_integral(mf.beckmann(h, jit.Float64(m)), h, w) == pytest.approx(1, abs=1e-9)


@pytest.mark.parametrize("m", [0.05, 0.3, 0.8, 1.4])
def test_blinn_is_normalized_and_halves_at_m(m, jit):
    c = mf.blinn_exponent(m)
    h, w = hemisphere_quadrature(m, jit)
    d = mf.blinn(h, jit.Float64(c), jit.Float64(mf.blinn_norm(c)))
    assert projected_integral(d, h, w) == pytest.approx(1, abs=1e-9)
    at = jit.Array3f64(math.sin(m), 0, math.cos(m))
    peak = mf.blinn(jit.Array3f64(0, 0, 1), jit.Float64(c), jit.Float64(1.0))
    assert mf.blinn(at, jit.Float64(c), jit.Float64(1.0))[0] == pytest.approx(0.5 * peak[0], rel=1e-12)


@pytest.mark.parametrize("m", [0.01, 0.1, 0.5, 1.0, 3.0])
def test_gaussian_is_normalized(m, jit):
    h, w = hemisphere_quadrature(min(m, 0.5), jit)
    d = mf.gaussian(h, jit.Float64(m), jit.Float64(mf.gaussian_norm(m)))
    assert projected_integral(d, h, w) == pytest.approx(1, abs=1e-9)
    # For narrow lobes the Gaussian approaches Beckmann's small-angle limit 1/(π m²) at its peak.
    if m <= 0.01:
        assert mf.gaussian_norm(m) == pytest.approx(1 / (math.pi * m * m), rel=1e-3)


@pytest.mark.parametrize("alpha_u,alpha_v", [(0.05, 0.05), (0.5, 0.5), (0.1, 0.4), (0.8, 0.2)])
def test_ggx_is_normalized(alpha_u, alpha_v, jit):
    h, w = hemisphere_quadrature(min(alpha_u, alpha_v), jit, n_phi=1 if alpha_u == alpha_v else 512)
    d = mf.ggx(h, jit.Float64(alpha_u), jit.Float64(alpha_v))
    # GGX has a long 1/tan⁴ tail; the quadrature resolves it to ~1e-7.
    assert projected_integral(d, h, w) == pytest.approx(1, abs=1e-6)


def test_v_groove_limits(jit):
    """G = 1 at normal incidence and view, and shadowing dominates at grazing light."""
    one = jit.Float64(1.0)
    assert mf.v_groove(one, one, one, one)[0] == 1
    n_h, n_i, n_o, v_h = jit.Float64(0.9), jit.Float64(0.05), jit.Float64(0.8), jit.Float64(0.5)
    assert mf.v_groove(n_h, n_i, n_o, v_h)[0] == pytest.approx(2 * 0.9 * 0.05 / 0.5)


def test_smith_ggx_g1_is_one_at_normal_incidence_and_zero_for_back_facets(jit):
    a = jit.Float64(0.3)
    up = jit.Array3f64(0, 0, 1)
    assert mf.smith_ggx_g1(up, up, a, a)[0] == 1
    v = jit.Array3f64(math.sin(1.2), 0, math.cos(1.2))
    back = jit.Array3f64(-math.sin(1.5), 0, math.cos(1.5))  # v·h < 0: v sees the facet's back
    assert mf.smith_ggx_g1(v, back, a, a)[0] == 0
    lam = mf.smith_ggx_lambda(v, a, a)[0]
    assert lam == pytest.approx(0.5 * (math.sqrt(1 + 0.09 * math.tan(1.2) ** 2) - 1), rel=1e-12)


def test_drjit_float32_distributions_are_finite_at_the_peak_and_zero_below(jit):
    Float = jit.Float
    h = jit.Array3f(Float([0.0, 0.0, 0.6]), Float([0.0, 0.0, 0.0]), Float([1.0, -1.0, -0.8]))
    for d in (mf.beckmann(h, Float(0.01)), mf.ggx(h, Float(0.01), Float(0.01)),
              mf.gaussian(h, Float(0.01), Float(mf.gaussian_norm(0.01))),
              mf.blinn(h, Float(mf.blinn_exponent(0.01)), Float(1.0))):
        values = d.numpy()
        assert np.isfinite(values[0]) and values[0] > 0 and values[1] == 0 and values[2] == 0
    assert mf.ggx(h, Float(0.01), Float(0.01)).numpy()[0] == pytest.approx(1e4 / math.pi, rel=1e-6)
