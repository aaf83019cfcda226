"""The Dr.Jit models agree with the independent numpy reference, and respect the horizon."""

from __future__ import annotations

import functools

import drjit as dr
import materials_ref as ref
import numpy as np
import pytest

from gonio.geometry import sph_to_vec
from gonio.sim.materials import fresnel, load
from gonio.sim.materials.base import positive_power

# Each test runs on every Dr.Jit backend (CUDA skipped without a device).
pytestmark = pytest.mark.usefixtures("backend")

P = functools.partial
GOLD, COPPER = ref.METALS["gold"], ref.METALS["copper"]

#: spec → the same material written with the numpy reference.
CASES = {
    "lambert:albedo=0.8/0.6/0.4": P(ref.lambert, albedo=(0.8, 0.6, 0.4)),
    "phong:ks=0.5,ke=20,rho_d=0.2": P(ref.cosine_lobe, ks=0.5, ke=20, rho_d=0.2, half_vector=False,
                                      normalized=False),
    "phong:ks=1,ke=0": P(ref.cosine_lobe, ks=1, ke=0, half_vector=False, normalized=False),
    "modified-phong:ks=0.6/0.5/0.4,ke=35.5,rho_d=0.3": P(ref.cosine_lobe, ks=(0.6, 0.5, 0.4), ke=35.5,
                                                         rho_d=0.3, half_vector=False, normalized=True),
    "blinn-phong:ks=0.5,ke=80": P(ref.cosine_lobe, ks=0.5, ke=80, half_vector=True, normalized=False),
    "normalized-blinn-phong:ks=0.7,ke=12,rho_d=0.1": P(ref.cosine_lobe, ks=0.7, ke=12, rho_d=0.1,
                                                       half_vector=True, normalized=True),
    "ward:rho_d=0.1,rho_s=0.05,alpha=0.15": P(ref.ward, rho_d=0.1, rho_s=0.05, alpha_x=0.15, alpha_y=0.15),
    "ward:rho_d=0.1,rho_s=0.2/0.1/0.05,alpha_x=0.1,alpha_y=0.3": P(ref.ward, rho_d=0.1,
                                                                    rho_s=(0.2, 0.1, 0.05),
                                                                    alpha_x=0.1, alpha_y=0.3),
    "cook-torrance:d=beckmann,m=0.2,metal=gold": P(ref.cook_torrance, d="beckmann", m=0.2,
                                                   fresnel_form="conductor", eta=GOLD[0], k=GOLD[1]),
    "cook-torrance:d=beckmann,m=0.05,metal=copper,rho_d=0.2": P(
        ref.cook_torrance, d="beckmann", m=0.05, fresnel_form="conductor", eta=COPPER[0], k=COPPER[1],
        rho_d=0.2),
    "cook-torrance:d=blinn,m=0.3,fresnel=dielectric,eta=1.5,denom=4": P(
        ref.cook_torrance, d="blinn", m=0.3, fresnel_form="dielectric", eta=1.5, denom="4"),
    "cook-torrance:d=gaussian,m=0.25,fresnel=dielectric,eta=0.67,rho_s=0.5": P(
        ref.cook_torrance, d="gaussian", m=0.25, fresnel_form="dielectric", eta=0.67, rho_s=0.5),
    "cook-torrance:d=gaussian,m=1.2,fresnel=none,denom=4": P(ref.cook_torrance, d="gaussian", m=1.2,
                                                             denom="4"),
    "cook-torrance:d=blinn,m=0.1,fresnel=conductor,eta=0.2/0.9/1.1,k=3.9/2.4/2.2": P(
        ref.cook_torrance, d="blinn", m=0.1, fresnel_form="conductor", eta=(0.2, 0.9, 1.1),
        k=(3.9, 2.4, 2.2)),
    "ggx:alpha=0.2,metal=gold": P(ref.ggx, alpha_u=0.2, alpha_v=0.2, fresnel_form="conductor",
                                  eta=GOLD[0], k=GOLD[1]),
    "ggx:alpha_u=0.05,alpha_v=0.4,metal=steel,smith=correlated,rho_d=0.1,rho_s=0.9": P(
        ref.ggx, alpha_u=0.05, alpha_v=0.4, fresnel_form="conductor", eta=ref.METALS["steel"][0],
        k=ref.METALS["steel"][1], smith="correlated", rho_d=0.1, rho_s=0.9),
    "ggx:alpha=0.5,fresnel=dielectric,eta=1.33": P(ref.ggx, alpha_u=0.5, alpha_v=0.5,
                                                   fresnel_form="dielectric", eta=1.33),
}
SPECS = list(CASES)
# float32 Dr.Jit against the float64 reference: the worst relative error over these cases is 4e-5
# (narrow lobes amplify the float32 rounding of the exponent: ke = 80, Beckmann m = 0.05); 2e-4 leaves
# a margin of 5 and still fails for any wrong formula, which errs by O(1).
FLOAT32_RTOL = 2e-4


@pytest.fixture(scope="module")
def pairs():
    return ref.random_pairs(np.random.default_rng(7), 4000)


@pytest.mark.parametrize("spec", SPECS)
def test_float64_path_matches_numpy_reference(spec, pairs):
    wi, wo = pairs
    expected = CASES[spec](wi, wo)
    got = load(spec).eval(wi, wo, precision="float64")
    assert np.count_nonzero(expected[:, 0] > 1e-3) > 100  # the pairs probe the lobe, not only zeros
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-300)


@pytest.mark.parametrize("spec", SPECS)
def test_float32_path_matches_numpy_reference(spec, pairs):
    wi, wo = pairs
    expected = CASES[spec](wi, wo)
    got = load(spec).eval(wi, wo)
    # Values below float32's normal range are flushed; compare on a floor far below any visible value.
    floor = 1e-6 * expected.max()
    np.testing.assert_allclose(got, expected, rtol=FLOAT32_RTOL, atol=floor * FLOAT32_RTOL)


@pytest.mark.parametrize("spec", SPECS)
def test_zero_at_and_below_the_horizon_nonnegative_above(spec, rng):
    m = load(spec)
    n = 2000
    up = sph_to_vec(rng.uniform(0, np.pi / 2 - 1e-3, n), rng.uniform(0, 2 * np.pi, n))
    down = sph_to_vec(rng.uniform(np.pi / 2 + 1e-6, np.pi, n), rng.uniform(0, 2 * np.pi, n))
    grazing = sph_to_vec(np.full(n, np.pi / 2), rng.uniform(0, 2 * np.pi, n))
    grazing[:, 2] = 0.0  # exactly in the plane (cos(π/2) rounds to 6e-17)
    for wi, wo in ((up, down), (down, up), (down, down), (up, grazing), (grazing, up)):
        assert np.array_equal(m.eval(wi, wo, precision="float64"), np.zeros((n, 3)))
    values = m.eval(up, sph_to_vec(rng.uniform(0, np.pi / 2 - 1e-3, n), rng.uniform(0, 2 * np.pi, n)))
    assert np.isfinite(values).all() and (values >= 0).all()


def test_exact_conductor_fresnel_matches_complex_snell_and_notes_at_normal_incidence(vector_type, to_dr):
    cos_theta = np.linspace(1e-3, 1.0, 200)
    scalar = dr.value_t(vector_type)
    tol = 1e-12 if dr.type_v(scalar) == dr.VarType.Float64 else 1e-5
    # The metals are per channel (R, G, B), so each channel of the result has its own (η, k).
    for eta, k in ref.METALS.values():
        c = scalar(cos_theta)
        rgb = vector_type(*eta), vector_type(*k)
        exact = fresnel.conductor_exact(c, *rgb).numpy().T
        notes = fresnel.conductor_notes(c, *rgb).numpy().T
        expected = ref.fresnel_conductor_complex(cos_theta, eta, k)
        np.testing.assert_allclose(exact, expected, rtol=tol * 10, atol=tol)
        # The notes' formula is exact at normal incidence, ((η−1)² + k²)/((η+1)² + k²) ...
        eta, k = np.asarray(eta), np.asarray(k)
        normal = ((eta - 1) ** 2 + k**2) / ((eta + 1) ** 2 + k**2)
        np.testing.assert_allclose(notes[-1], normal, rtol=tol * 10)
        # ... and an approximation elsewhere: it differs from the exact value at some angle.
        assert np.abs(notes - exact).max() > 1e-4


def test_dielectric_fresnel_limits():
    c = np.array([1.0, 0.5, 1e-6])
    f = fresnel.dielectric(dr.llvm.Float64(c), dr.llvm.Array3f64(1.5, 1.0, 0.5)).numpy().T
    assert f[0, 0] == pytest.approx((0.5 / 2.5) ** 2, rel=1e-12)  # ((η−1)/(η+1))² at normal incidence
    assert np.allclose(f[:, 1], 0)  # index-matched: nothing reflected
    assert f[2, 0] == pytest.approx(1, abs=1e-5)  # grazing: everything reflected
    assert f[1, 2] == 1.0  # η = 0.5, θ = 60° > asin(0.5): total internal reflection


def test_cosine_power_underflows_to_zero_in_both_precisions(vector_type):
    """(7.3e-6)^60 underflows below the smallest float64; it must come out 0, not −inf (Dr.Jit 1.5's
    float64 exp2 returns −inf there, which the lobe must not inherit)."""
    scalar = dr.value_t(vector_type)
    x = scalar([7.29575365e-06, 0.5, 0.0, -0.3])
    values = positive_power(x, dr.opaque(scalar, 60.0)).numpy()
    assert 0 <= float(values[0]) < 1e-300 and values[2] == 0 and values[3] == 0
    assert values[1] == pytest.approx(0.5**60, rel=1e-5)
    lobe = load("modified-phong:ks=0.6,ke=60,rho_d=0.4")
    wi = sph_to_vec(np.radians([55.0]), [0.0])
    wo = np.array([[0.3718257, 0.7614116, 0.53103485]])
    wo /= np.linalg.norm(wo)
    assert np.allclose(lobe.eval(wi, wo, precision="float64"), 0.4 / np.pi, rtol=1e-12)
