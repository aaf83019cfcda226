"""Helmholtz reciprocity and isotropy: which models have them, and by how much the others break them."""

from __future__ import annotations

import materials_ref as ref
import numpy as np
import pytest

from gonio.geometry import sph_to_vec
from gonio.sim.materials import load

# Each test runs on every Dr.Jit backend (CUDA skipped without a device).
pytestmark = pytest.mark.usefixtures("backend")

RECIPROCAL = [
    "lambert:albedo=0.7",
    "modified-phong:ks=0.5,ke=20,rho_d=0.2",
    "normalized-blinn-phong:ks=0.5,ke=40",
    "ward:rho_d=0.1,rho_s=0.2,alpha=0.2",
    "ward:rho_s=0.2,alpha_x=0.05,alpha_y=0.3",
    "cook-torrance:d=beckmann,m=0.2,metal=gold",
    "cook-torrance:d=blinn,m=0.3,fresnel=dielectric,eta=1.5,denom=4",
    "cook-torrance:d=gaussian,m=0.2,fresnel=conductor,eta=0.2/0.9/1.1,k=3.9/2.4/2.2",
    "ggx:alpha=0.3,metal=copper",
    "ggx:alpha_u=0.05,alpha_v=0.3,metal=silver,smith=correlated",
]
NOT_RECIPROCAL = ["phong:ks=0.5,ke=20", "blinn-phong:ks=0.5,ke=20"]
ISOTROPIC = [s for s in RECIPROCAL + NOT_RECIPROCAL if "alpha_x" not in s and "alpha_u" not in s]


def rotate_z(w, angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * w[:, 0] - s * w[:, 1], s * w[:, 0] + c * w[:, 1], w[:, 2]], axis=1)


@pytest.fixture(scope="module")
def pairs():
    return ref.random_pairs(np.random.default_rng(11), 3000)


def relative_difference(a, b):
    scale = np.maximum(np.abs(a), np.abs(b))
    return np.abs(a - b) / np.where(scale > 0, scale, 1)


@pytest.mark.parametrize("spec", RECIPROCAL)
def test_reciprocal_models_are_symmetric(spec, pairs):
    m = load(spec)
    assert m.reciprocal
    wi, wo = pairs
    forward, backward = m.eval(wi, wo, precision="float64"), m.eval(wo, wi, precision="float64")
    assert np.count_nonzero(forward[:, 0] > 1e-3) > 100
    assert relative_difference(forward, backward).max() < 1e-5


@pytest.mark.parametrize("spec", NOT_RECIPROCAL)
def test_notes_phong_forms_are_not_reciprocal(spec):
    """Their 1/(I·N) makes f(I, V)/f(V, I) = (V·N)/(I·N): 5.67 for light at 80° and detector at 10°."""
    m = load(spec)
    assert not m.reciprocal
    wi = sph_to_vec(np.radians([80.0]), [0.0])
    wo = sph_to_vec(np.radians([10.0]), [np.pi])  # in the plane of incidence, inside both lobes
    ratio = m.eval(wi, wo, precision="float64")[0, 0] / m.eval(wo, wi, precision="float64")[0, 0]
    assert ratio == pytest.approx(np.cos(np.radians(10)) / np.cos(np.radians(80)), rel=1e-9)
    assert ratio > 5


@pytest.mark.parametrize("spec", ISOTROPIC)
def test_isotropic_models_ignore_rotation_about_the_normal(spec, pairs):
    m = load(spec)
    assert m.isotropic
    wi, wo = pairs
    base = m.eval(wi, wo, precision="float64")
    for angle in (0.3, np.pi / 2, 2.0, 4.5):
        turned = m.eval(rotate_z(wi, angle), rotate_z(wo, angle), precision="float64")
        assert relative_difference(base, turned).max() < 1e-9


@pytest.mark.parametrize("model,keys", [("ward:rho_s=0.2", ("alpha_x", "alpha_y")),
                                        ("ggx:metal=gold", ("alpha_u", "alpha_v"))])
def test_anisotropic_models_turn_with_the_sample(model, keys, pairs):
    """Rotating both directions by 90° about N is the same as swapping the two roughnesses, and
    anything else changes the value (by far more than rounding)."""
    a, b = keys
    m = load(f"{model},{a}=0.05,{b}=0.3")
    swapped = load(f"{model},{a}=0.3,{b}=0.05")
    assert not m.isotropic
    wi, wo = pairs
    base = m.eval(wi, wo, precision="float64")
    turned = m.eval(rotate_z(wi, np.pi / 2), rotate_z(wo, np.pi / 2), precision="float64")
    assert relative_difference(turned, swapped.eval(wi, wo, precision="float64")).max() < 1e-9
    assert relative_difference(base, turned).max() > 0.5
    # Rotating by 180° maps the x and y axes onto themselves: the value must not change.
    half_turn = m.eval(rotate_z(wi, np.pi), rotate_z(wo, np.pi), precision="float64")
    assert relative_difference(base, half_turn).max() < 1e-9
