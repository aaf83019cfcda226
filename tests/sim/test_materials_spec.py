"""MATERIAL strings: normalization, per-channel values, the model flags, and every error naming its field
and the allowed range; and the checks on eval's numpy inputs."""

from __future__ import annotations

import doctest
import math

import numpy as np
import pytest

import gonio.sim.materials
from gonio.sim.materials import MODELS, CookTorranceEnergyConserving, load

EXAMPLES = [
    "lambert:albedo=0.8",
    "phong:ks=0.5,ke=20",
    "modified-phong:ks=0.5,ke=20,rho_d=0.3",
    "blinn-phong:ks=0.5,ke=20",
    "normalized-blinn-phong:ks=0.4/0.5/0.6,ke=20",
    "ward:rho_d=0.1,rho_s=0.05,alpha_x=0.1,alpha_y=0.3",
    "ward:rho_s=0.05,alpha=0.2",
    "cook-torrance:d=beckmann,m=0.2,fresnel=conductor,eta=0.37,k=2.82",
    "cook-torrance:d=beckmann,m=0.3,metal=gold,rho_d=0.1",
    "cook-torrance:d=blinn,m=0.3,fresnel=dielectric,eta=1.5,denom=4",
    "cook-torrance:d=gaussian,m=0.3,fresnel=none",
    "ggx:alpha=0.2,metal=gold",
    "ggx:alpha_u=0.1,alpha_v=0.3,eta=0.2/0.9/1.1,k=3.9/2.4/2.2,smith=correlated",
]


@pytest.mark.parametrize("spec", EXAMPLES)
def test_normalized_spec_round_trips(spec):
    m = load(spec)
    again = load(m.spec)
    assert again.spec == m.spec and type(again) is type(m)
    assert m.channels == ("R", "G", "B")
    wi, wo = np.array([[0.3, 0.1, math.sqrt(0.9)]]), np.array([[-0.4, 0.0, math.sqrt(0.84)]])
    assert np.array_equal(m.eval(wi, wo), again.eval(wi, wo))


def test_normalization_fills_defaults_and_canonical_numbers():
    assert load(" Lambert : albedo = 0.50 ").spec == "lambert:albedo=0.5"
    assert load("lambert:albedo=0.5/0.5/0.5").spec == "lambert:albedo=0.5"
    assert load("cook-torrance:m=0.2,metal=gold").spec == (
        "cook-torrance:d=beckmann,m=0.2,fresnel=conductor,metal=gold,denom=pi,rho_d=0,rho_s=1")
    assert load("ggx:alpha=2e-1,k=2.82,eta=0.37").spec == (
        "ggx:alpha=0.2,fresnel=conductor,eta=0.37,k=2.82,smith=separable,rho_d=0,rho_s=1")
    assert load("cook-torrance:m=0.2,eta=1.5").spec.startswith("cook-torrance:d=beckmann,m=0.2,"
                                                                "fresnel=dielectric,eta=1.5,")


def test_per_channel_values_reach_the_channels():
    m = load("lambert:albedo=0.8/0.6/0.4")
    value = m.eval(np.array([0.0, 0.0, 1.0]), np.array([0.6, 0.0, 0.8]), precision="float64")
    np.testing.assert_allclose(value, np.array([0.8, 0.6, 0.4]) / math.pi, rtol=1e-15)


def test_model_flags():
    flags = {name: (cls.reciprocal, cls.energy_conserving) for name, cls in MODELS.items()}
    assert flags == {
        "lambert": (True, True), "phong": (False, False), "modified-phong": (True, True),
        "blinn-phong": (False, False), "normalized-blinn-phong": (True, True), "ward": (True, False),
        "cook-torrance": (True, False), "ggx": (True, True), "merl": (True, False),
        "bsdf": (False, False),
    }
    modern = load("cook-torrance:m=0.2,metal=gold,denom=4")
    assert isinstance(modern, CookTorranceEnergyConserving) and modern.energy_conserving
    assert not load("cook-torrance:m=0.2,metal=gold").energy_conserving


ERRORS = [
    ("lamber:albedo=0.5", r"unknown material model 'lamber' .*allowed: blinn-phong, bsdf, cook-torrance, "
                          r"ggx, lambert, merl, modified-phong, normalized-blinn-phong, phong, ward"),
    ("lambert", r"lambert: parameter 'albedo' is required \(one number in \[0, 1\] or three as R/G/B\)"),
    ("lambert:albedo=1.2", r"lambert: parameter 'albedo' must be in \[0, 1\], got 1.2$"),
    ("lambert:albedo=0.5/1.5/0.2", r"parameter 'albedo' must be in \[0, 1\], got 1.5 in channel G"),
    ("lambert:albedo=0.5/0.2", r"'albedo' takes one number or three R/G/B numbers separated by '/'"),
    ("lambert:albedo=abc", r"'albedo' must be a number in \[0, 1\], got 'abc'"),
    ("lambert:albedo=nan", r"'albedo' must be a number in \[0, 1\], got 'nan'"),
    ("lambert:albedo=0.5,albedo=0.6", r"lambert: parameter 'albedo' is given twice"),
    ("lambert:albedo", r"lambert: item 1 'albedo' is not of the form key=value"),
    ("lambert:albedo=0.5,color=1", r"lambert: unknown parameter 'color'; allowed: albedo$"),
    ("phong:ks=0.5,ke=-1", r"phong: parameter 'ke' must be >= 0, got -1$"),
    ("phong:ks=0.5,ke=10/20/30", r"phong: parameter 'ke' takes one number, not R/G/B values"),
    ("phong:ks=0.5,ke=20,normalized=true", r"phong: unknown parameter 'normalized'; allowed: ks, ke, rho_d"),
    ("phong:ke=20", r"phong: parameter 'ks' is required"),
    ("modified-phong:ks=0.7,ke=20,rho_d=0.5",
     r"modified-phong: rho_d \+ ks must be <= 1 \(energy conservation\), got 1.2 in channel R"),
    ("cook-torrance:d=beckmann,m=-0.1,metal=gold", r"cook-torrance: parameter 'm' must be > 0, got -0.1"),
    ("cook-torrance:d=gaussian,m=0,metal=gold", r"parameter 'm' must be > 0 rad, got 0"),
    ("cook-torrance:d=blinn,m=1.6,metal=gold", r"'m' must be in \(0, 1.5708\) rad, got 1.6"),
    ("cook-torrance:d=phong,m=0.2,metal=gold", r"'d' must be one of beckmann, blinn, gaussian, got 'phong'"),
    ("cook-torrance:m=0.2,metal=brass",
     r"'metal' must be one of gold, silver, copper, aluminium, steel, got 'brass'"),
    ("cook-torrance:m=0.2", r"cook-torrance: say how the facets reflect: metal=NAME \(gold, silver, copper, "
                            r"aluminium, steel\), fresnel=conductor with eta and k, fresnel=dielectric"),
    ("cook-torrance:metal=gold", r"cook-torrance: parameter 'm' is required \(a number > 0\)"),
    ("cook-torrance:m=0.2,fresnel=conductor,eta=0.37", r"parameter 'k' is required \(one number >= 0"),
    ("cook-torrance:m=0.2,fresnel=conductor,eta=0,k=1", r"'eta' must be > 0, got 0"),
    ("cook-torrance:m=0.2,fresnel=conductor,eta=1,k=-1", r"'k' must be >= 0, got -1"),
    ("cook-torrance:m=0.2,fresnel=mirror",
     r"'fresnel' must be one of conductor, dielectric, none, got 'mirror'"),
    ("cook-torrance:m=0.2,metal=gold,eta=1.5", r"'eta' does not apply together with 'metal'"),
    ("cook-torrance:m=0.2,metal=gold,fresnel=dielectric",
     r"'fresnel' must be one of conductor when 'metal' is given, got 'dielectric'"),
    ("cook-torrance:m=0.2,fresnel=dielectric,eta=1.5,k=2", r"'k' does not apply with fresnel=dielectric"),
    ("cook-torrance:m=0.2,fresnel=none,eta=1.5", r"'eta' does not apply with fresnel=none"),
    ("cook-torrance:m=0.2,fresnel=none,denom=2", r"'denom' must be one of pi, 4, got '2'"),
    ("cook-torrance:m=0.2,fresnel=none,denom=4,rho_d=0.5",
     r"rho_d \+ rho_s must be <= 1 \(energy conservation with denom=4\), got 1.5 in channel R"),
    ("cook-torrance:m=0.2,fresnel=none,rho_s=1.1", r"'rho_s' must be in \[0, 1\], got 1.1"),
    ("ward:rho_s=0.1",
     r"ward: parameter 'alpha' \(> 0\) or both 'alpha_x' and 'alpha_y' \(> 0\) are required"),
    ("ward:rho_s=0.1,alpha=0.1,alpha_x=0.2", r"'alpha_x' does not apply together with 'alpha'"),
    ("ward:rho_s=0.1,alpha_x=0.2", r"ward: parameter 'alpha_y' is required \(a number > 0\)"),
    ("ward:rho_s=0.1,alpha=0", r"ward: parameter 'alpha' must be > 0, got 0"),
    ("ward:rho_s=0.1,alpha=0.1,rho_d=-0.1", r"ward: parameter 'rho_d' must be in \[0, 1\], got -0.1"),
    ("ggx:alpha=-0.2,metal=gold", r"ggx: parameter 'alpha' must be > 0, got -0.2"),
    ("ggx:alpha_u=0.1,alpha_v=0,metal=gold", r"ggx: parameter 'alpha_v' must be > 0, got 0"),
    ("ggx:alpha=0.2,metal=gold,smith=exact", r"'smith' must be one of separable, correlated, got 'exact'"),
    ("ggx:alpha=0.2,metal=gold,rho_d=0.3", r"ggx: rho_d \+ rho_s must be <= 1 \(energy conservation\)"),
]


@pytest.mark.parametrize("spec,message", ERRORS, ids=[e[0] for e in ERRORS])
def test_errors_name_the_field_and_the_allowed_range(spec, message):
    with pytest.raises(ValueError, match=message):
        load(spec)


def test_spec_must_be_a_string():
    with pytest.raises(ValueError, match="material spec must be a string"):
        load(None)


@pytest.fixture
def lambert():
    return load("lambert:albedo=0.5")


def test_eval_accepts_broadcast_and_n_d_inputs(lambert):
    wo = np.tile([0.0, 0.6, 0.8], (2, 5, 1))
    out = lambert.eval(np.array([0.0, 0.0, 1.0]), wo)
    assert out.shape == (2, 5, 3) and out.dtype == np.float64
    np.testing.assert_allclose(out, 0.5 / math.pi, rtol=1e-7)
    assert lambert.eval(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0, 3)


@pytest.mark.parametrize("wi,wo,kwargs,message", [
    (np.zeros((4, 2)), np.zeros((4, 3)), {}, r"wi: expected unit vectors of shape \(\.\.\., 3\), got shape"),
    ([[0, 0, 1.0]], [[0, 0, 1.0], [np.nan, 0, 1.0]], {}, r"wo: row 1 is not finite"),
    ([[0, 0, 1.1]], [[0, 0, 1.0]], {},
     r"wi: vectors must have unit length \(within 0.0001\), row 0 has length 1.1"),
    ([[0, 0, 1.0]], [[0, 0, 1.0]], {"precision": "float16"}, r"precision must be one of float32, float64"),
])
def test_eval_rejects_bad_directions(lambert, wi, wo, kwargs, message):
    with pytest.raises(ValueError, match=message):
        lambert.eval(wi, wo, **kwargs)


def test_docstring_examples_run():
    assert doctest.testmod(gonio.sim.materials).failed == 0
