"""Directional albedo ∫ f cos θo dωo: Monte Carlo in Dr.Jit against independent numpy quadrature.

The Monte Carlo estimate draws stratified samples (an n × n grid of strata, each jittered by a seeded
PCG32) from two techniques and combines them with the balance heuristic (multi-sample MIS): cosine-
weighted directions, which cover diffuse and broad lobes, and directions ωo = reflect(ωi, h) with h
drawn from a cos^n θh lobe about N, which put samples in the mirror lobe that every glossy model here
has, down to grazing incidence. Both are generic: no sampler knows the model. Several independent
replicas give the standard error. The quadrature is Gauss-Legendre in cos θo times the trapezoid rule
in φo, over the numpy reference models.
"""

from __future__ import annotations

import functools
import math

import drjit as dr
import materials_ref as ref
import numpy as np
import pytest

from gonio.jit import array_types
from gonio.sim.materials import load

P = functools.partial
THETAS_DEG = np.arange(0.0, 86.0, 5.0)  # 0°, 5°, …, 85°


def _cosine_directions(u1, u2, vector):
    r, phi = dr.sqrt(u1), 2 * math.pi * u2
    return vector(r * dr.cos(phi), r * dr.sin(phi), dr.sqrt(1 - u1))


def albedo_mc(material, thetas_deg, backend, n_side=192, replicas=6, lobe_exponent=100.0, seed=1):
    """(mean, standard error) of the albedo, arrays of shape (len(thetas), 3), in float64 on ``backend``.

    ``replicas`` independent estimates of 2·``n_side``² samples each (half per technique); their
    spread gives the standard error of their mean (a per-sample variance would ignore what
    stratification gains).
    """
    t = array_types(backend)
    Float64, Array3f64 = t.Float64, t.Array3f64
    per_angle = n_side * n_side
    k = len(thetas_deg)
    size = 2 * per_angle * k * replicas
    index = dr.arange(t.UInt32, size)
    cell, block = index % per_angle, (index // per_angle) % k
    technique_h = ((index // (per_angle * k)) % 2) == 1
    rng = t.PCG32(size=size, initstate=seed)
    u1 = (Float64(cell % n_side) + rng.next_float64()) / n_side
    u2 = (Float64(cell // n_side) + rng.next_float64()) / n_side
    theta_i = dr.gather(Float64, Float64(np.radians(thetas_deg)), block)
    wi = Array3f64(dr.sin(theta_i), 0, dr.cos(theta_i))
    n = lobe_exponent
    # Technique h: cos θh = u1^(1/(n+1)) has density (n+1)/(2π) cos^n θh over half vectors.
    h = _cosine_directions(1 - dr.power(u1, 2 / (n + 1)), u2, Array3f64)
    wo = dr.select(technique_h, 2 * dr.dot(wi, h) * h - wi, _cosine_directions(u1, u2, Array3f64))
    above = wo.z > 0
    wo = dr.select(above, dr.normalize(wo), Array3f64(0, 0, 1))  # below: weight 0, any valid vector
    hh = dr.normalize(wi + wo)
    pdf_h = (n + 1) / (2 * math.pi) * dr.power(hh.z, n) / (4 * dr.dot(wo, hh))
    pdf = 0.5 * wo.z / math.pi + 0.5 * pdf_h
    weight = dr.select(above, wo.z / pdf, 0)
    samples = (material.eval_dr(wi, wo) * weight).numpy().T.reshape(replicas, 2, k, per_angle, 3)
    estimates = samples.mean(axis=(1, 3))
    return estimates.mean(axis=0), estimates.std(axis=0, ddof=1) / math.sqrt(replicas)


@functools.cache
def _gauss_legendre(n):
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1), 0.5 * w


def albedo_quadrature(reference, theta_i_deg, n=200):
    """∫ f cos θo dωo of a numpy reference model, shape (3,)."""
    mu, w_mu = _gauss_legendre(n)
    n_phi = 2 * n
    phi = (np.arange(n_phi) + 0.5) * (2 * np.pi / n_phi)
    mu_g, phi_g = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1 - mu_g**2)
    wo = np.stack([s * np.cos(phi_g), s * np.sin(phi_g), mu_g], axis=-1).reshape(-1, 3)
    t = np.radians(theta_i_deg)
    wi = np.broadcast_to([np.sin(t), 0.0, np.cos(t)], wo.shape).copy()
    values = (reference(wi, wo) * wo[:, 2:3]).reshape(n, n_phi, 3)
    return np.einsum("ijc,i->c", values, w_mu) * (2 * np.pi / n_phi)


def test_lambert_albedo_is_rho_d(backend):
    mean, se = albedo_mc(load("lambert:albedo=0.8/0.6/0.4"), [0.0, 45.0, 85.0], backend)
    assert se.max() < 2e-4
    np.testing.assert_allclose(mean, np.tile([0.8, 0.6, 0.4], (3, 1)), atol=1e-3)


CONSERVING = {
    "lambert:albedo=1": P(ref.lambert, albedo=1.0),
    "modified-phong:ks=1,ke=5": P(ref.cosine_lobe, ks=1, ke=5, half_vector=False, normalized=True),
    "modified-phong:ks=0.6,ke=60,rho_d=0.4": P(ref.cosine_lobe, ks=0.6, ke=60, rho_d=0.4, half_vector=False,
                                               normalized=True),
    "normalized-blinn-phong:ks=1,ke=5": P(ref.cosine_lobe, ks=1, ke=5, half_vector=True, normalized=True),
    "normalized-blinn-phong:ks=1,ke=100": P(ref.cosine_lobe, ks=1, ke=100, half_vector=True,
                                            normalized=True),
    "ggx:alpha=0.1,fresnel=none": P(ref.ggx, alpha_u=0.1, alpha_v=0.1),
    "ggx:alpha=0.6,fresnel=none,smith=correlated": P(ref.ggx, alpha_u=0.6, alpha_v=0.6, smith="correlated"),
    "ggx:alpha_u=0.1,alpha_v=0.4,metal=silver,rho_d=0.1,rho_s=0.9": P(
        ref.ggx, alpha_u=0.1, alpha_v=0.4, fresnel_form="conductor", eta=ref.METALS["silver"][0],
        k=ref.METALS["silver"][1], rho_d=0.1, rho_s=0.9),
    "cook-torrance:d=beckmann,m=0.1,fresnel=none,denom=4": P(ref.cook_torrance, d="beckmann", m=0.1,
                                                             denom="4"),
    "cook-torrance:d=beckmann,m=0.5,fresnel=none,denom=4": P(ref.cook_torrance, d="beckmann", m=0.5,
                                                             denom="4"),
    "cook-torrance:d=blinn,m=0.2,fresnel=none,denom=4": P(ref.cook_torrance, d="blinn", m=0.2, denom="4"),
    "cook-torrance:d=gaussian,m=0.3,fresnel=conductor,eta=0.01,k=100,denom=4": P(
        ref.cook_torrance, d="gaussian", m=0.3, fresnel_form="conductor", eta=0.01, k=100, denom="4"),
}


@pytest.mark.parametrize("spec", list(CONSERVING))
def test_energy_conserving_models_reflect_at_most_what_arrives(spec, backend):
    m = load(spec)
    assert m.energy_conserving
    mean, se = albedo_mc(m, THETAS_DEG, backend)
    assert se.max() < 2e-3  # precise enough for the bound below to mean something
    excess = mean - (1 + 3 * se)
    assert excess.max() <= 0, f"albedo {mean.max():.5f} at θi = {THETAS_DEG[excess.max(1).argmax()]}°"
    # The estimate is right, not just small: it matches the quadrature at normal incidence and at 60°.
    for row, theta in ((0, 0.0), (12, 60.0)):
        np.testing.assert_allclose(mean[row], albedo_quadrature(CONSERVING[spec], theta),
                                   atol=4 * se[row].max() + 2e-3)


def test_exact_blinn_phong_normalization_makes_normal_incidence_albedo_ks(backend):
    for ke in (0.0, 3.0, 40.0):
        mean, se = albedo_mc(load(f"normalized-blinn-phong:ks=0.8,ke={ke}"), [0.0], backend)
        assert mean[0, 0] == pytest.approx(0.8, abs=4 * se[0, 0] + 1e-4)


# The notes' forms that do not conserve energy, each at an angle where it reflects more than arrives:
# (spec, numpy reference, θi in degrees). The excess is computed by quadrature, never typed in.
EXCEEDING = [
    ("phong:ks=1,ke=10", P(ref.cosine_lobe, ks=1, ke=10, half_vector=False, normalized=False), 88.0),
    ("blinn-phong:ks=0.5,ke=10", P(ref.cosine_lobe, ks=0.5, ke=10, half_vector=True, normalized=False), 85.0),
    ("cook-torrance:d=beckmann,m=0.1,fresnel=none", P(ref.cook_torrance, d="beckmann", m=0.1), 0.0),
    ("cook-torrance:d=beckmann,m=0.5,fresnel=none", P(ref.cook_torrance, d="beckmann", m=0.5), 80.0),
    ("ward:rho_s=1,alpha=0.5", P(ref.ward, rho_d=0, rho_s=1, alpha_x=0.5, alpha_y=0.5), 89.9),
]


@pytest.mark.parametrize("spec,reference,theta", EXCEEDING, ids=[e[0] for e in EXCEEDING])
def test_notes_forms_exceed_unit_albedo_by_the_quadrature_amount(spec, reference, theta, backend):
    m = load(spec)
    assert not m.energy_conserving
    expected = albedo_quadrature(reference, theta, n=400)[0]
    assert expected > 1.1  # by at least 10 %: the excess is real, not quadrature noise
    mean, se = albedo_mc(m, [theta], backend)
    assert mean[0, 0] == pytest.approx(expected, rel=0.01)
    assert se[0, 0] < 0.005 * expected


def test_classic_phong_albedo_at_normal_incidence_and_growth_toward_grazing(backend):
    """At θi = 0, R(I) = N and the lobe integrates to ks·2π/(ke + 2) < 1; the 1/(I·N) factor then makes
    the albedo grow without bound toward grazing incidence."""
    mean, _ = albedo_mc(load("phong:ks=1,ke=10"), [0.0, 60.0, 80.0, 85.0, 88.0], backend)
    assert mean[0, 0] == pytest.approx(2 * math.pi / 12, rel=1e-3)
    assert np.all(np.diff(mean[:, 0]) > 0) and mean[-1, 0] > 1


def test_cook_torrance_pi_reflects_four_over_pi_times_the_modern_form(backend):
    same_samples = [albedo_mc(load(f"cook-torrance:d=beckmann,m=0.3,metal=gold,denom={d}"), [0.0, 70.0],
                              backend)[0] for d in ("pi", "4")]
    np.testing.assert_allclose(same_samples[0] / same_samples[1], 4 / math.pi, rtol=1e-12)


def test_ward_loses_energy_below_grazing_and_exceeds_near_it(backend):
    """Ward's 1/sqrt(cos θi cos θo) lets the albedo diverge as θi → 90°; below ~89° it stays < 1."""
    mean, _ = albedo_mc(load("ward:rho_s=1,alpha=0.5"), [0.0, 45.0, 85.0, 89.5, 89.9], backend)
    assert mean[:3, 0].max() < 1
    assert mean[-1, 0] > mean[-2, 0] > mean[-3, 0]
