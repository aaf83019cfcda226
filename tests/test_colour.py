"""Spectral colour: conversions against colour-science's own, the spectral materials against closed forms,
and the built-in RGB metals against a re-derivation from the spectral tables."""

from __future__ import annotations

import numpy as np
import pytest

from gonio import colour as gc
from gonio.sim.materials import load
from gonio.sim.materials.fresnel import METALS
from gonio.sim.materials.spectral import (
    CONDUCTORS,
    SpectralConductor,
    SpectralDielectric,
    SpectralLambert,
    cauchy,
    conductor_index,
    dielectric_index,
)


class _ColourScience:
    """colour-science through gonio.colour, which imports it without changing numpy's print options (a bare
    import sets legacy="1.13" for the whole process, and other modules' doctests print arrays), on first
    use: not while every test process collects this module."""

    def __getattr__(self, name):
        if name.startswith("_"):  # what pytest probes each module attribute for while it collects
            raise AttributeError(name)
        return getattr(gc.colour_science(), name)


colour = _ColourScience()
Z = np.array([[0.0, 0.0, 1.0]])
# colour-science warns each time it aligns a distribution to the CMFs' grid; that is intended here.
# Each test runs on every Dr.Jit backend (CUDA skipped without a device).
pytestmark = [pytest.mark.filterwarnings("ignore::Warning:colour"),  # a category would import colour
              pytest.mark.usefixtures("backend")]


def _fresnel_complex(n, k):
    """Normal-incidence reflectance |(ñ − 1)/(ñ + 1)|² with the complex index ñ = n + ik."""
    nc = n + 1j * k
    return np.abs((nc - 1) / (nc + 1)) ** 2


def _colour_science_srgb(wavelength_nm, reflectance):
    sd = colour.SpectralDistribution(dict(zip(wavelength_nm, reflectance, strict=True)))
    xyz = colour.sd_to_XYZ(sd, colour.MSDS_CMFS[gc.OBSERVER], colour.SDS_ILLUMINANTS["D65"]) / 100.0
    return colour.XYZ_to_sRGB(xyz, apply_cctf_encoding=False)


@pytest.mark.parametrize("name", list(CONDUCTORS))
def test_normal_reflectance_in_srgb_matches_colour_science(name):
    table = conductor_index(name)
    wl = gc.WAVELENGTH_NM
    n, k = np.interp(wl, table.wavelength_nm, table.n), np.interp(wl, table.wavelength_nm, table.k)
    expected = _colour_science_srgb(wl, _fresnel_complex(n, k))
    np.testing.assert_allclose(gc.normal_reflectance_rgb(name), expected, atol=1e-3)


def test_gold_is_gold_in_srgb_from_the_spectral_table_itself():
    # colour-science on the table's own reflectances, interpolated its way onto 5 nm: still yellow.
    table = conductor_index("gold")
    sd = colour.SpectralDistribution(dict(zip(table.wavelength_nm, _fresnel_complex(table.n, table.k),
                                              strict=True)))
    sd = sd.interpolate(colour.SpectralShape(305, 890, 5)).trim(colour.SpectralShape(380, 780, 5))
    rgb = _colour_science_srgb(sd.wavelengths, sd.values)
    assert rgb[0] > rgb[1] > rgb[2]
    np.testing.assert_allclose(gc.normal_reflectance_rgb("gold"), rgb, atol=0.02)


@pytest.mark.parametrize("space", gc.SPACES)
@pytest.mark.parametrize("illuminant", ["D65", "A"])
def test_white_lambertian_is_neutral(space, illuminant):
    white = SpectralLambert(lambda wl: np.ones_like(wl))
    rgb = gc.material_rgb(white, Z, Z, space=space, illuminant=illuminant)[0]
    np.testing.assert_allclose(rgb * np.pi, 1.0, atol=1e-3)


def test_spectral_to_xyz_matches_sd_to_xyz_integration():
    wl = gc.WAVELENGTH_NM
    refl = 0.5 + 0.4 * np.sin(wl / 37.0)
    sd = colour.SpectralDistribution(dict(zip(wl, refl, strict=True)))
    shape = colour.SpectralShape(380, 780, 5)
    cmfs = colour.MSDS_CMFS[gc.OBSERVER].copy().align(shape)
    expected = colour.sd_to_XYZ(sd, cmfs, colour.SDS_ILLUMINANTS["D65"].copy().align(shape),
                                method="Integration") / 100.0
    np.testing.assert_allclose(gc.spectral_to_XYZ(refl), expected, rtol=1e-6)
    with pytest.raises(ValueError, match="last axis must hold 81 samples"):
        gc.spectral_to_XYZ(refl[:-1])


def test_acescg_is_the_srgb_colour_in_ap1():
    xyz = gc.spectral_to_XYZ(np.linspace(0.2, 0.8, gc.WAVELENGTH_NM.size))
    aces = gc.XYZ_to_linear_rgb(xyz, "ACEScg")
    back = colour.RGB_to_XYZ(aces, "ACEScg", illuminant=colour.CCS_ILLUMINANTS[gc.OBSERVER]["D65"],
                             chromatic_adaptation_transform="CAT02")
    np.testing.assert_allclose(back, xyz, atol=2e-4)
    with pytest.raises(ValueError, match="space: 'P3' is not one of sRGB, ACEScg"):
        gc.XYZ_to_linear_rgb(xyz, "P3")


@pytest.mark.parametrize("name", list(CONDUCTORS))
def test_builtin_metals_are_the_rederived_per_channel_values(name):
    eta, k = gc.effective_rgb_conductor(name)
    np.testing.assert_allclose(METALS[name][0], eta, rtol=2e-3, atol=2e-4)
    np.testing.assert_allclose(METALS[name][1], k, rtol=2e-3, atol=2e-4)
    # F0 of the built-in numbers is the spectral colour at normal incidence, channels above the
    # metal's largest spectral reflectance (gold's red) clipped to it.
    e, kk = np.asarray(METALS[name][0]), np.asarray(METALS[name][1])
    f0 = ((e - 1) ** 2 + kk**2) / ((e + 1) ** 2 + kk**2)
    table = conductor_index(name)
    n, kt = table.at(gc.WAVELENGTH_NM)
    cap = _fresnel_complex(n, kt).max()
    np.testing.assert_allclose(f0, np.minimum(gc.normal_reflectance_rgb(name), cap), atol=5e-4)


@pytest.mark.parametrize("spec", ["ggx:alpha=0.2,metal=gold", "cook-torrance:d=beckmann,m=0.2,metal=gold",
                                  "ggx:alpha=0.3,metal=copper"])
def test_rgb_gold_and_copper_are_coloured(spec):
    theta = np.radians([0.0, 20.0, 40.0, 60.0])
    wi = np.stack([np.sin(theta), 0 * theta, np.cos(theta)], axis=1)
    wo = wi * np.array([-1.0, -1.0, 1.0])  # the mirror directions, where the lobe peaks
    f = load(spec).eval(wi, wo)
    assert (f[:, 0] > f[:, 1]).all() and (f[:, 1] > f[:, 2]).all()


def test_rgb_gold_follows_the_spectral_gold_in_colour():
    # A rough spectral gold converted to sRGB, and the RGB built-in with the same GGX lobe: same
    # chromaticity near the specular peak within a few per cent (the RGB model is an approximation).
    theta = np.radians([0.0, 30.0, 50.0])
    wi = np.stack([np.sin(theta), 0 * theta, np.cos(theta)], axis=1)
    wo = wi * np.array([-1.0, -1.0, 1.0])
    spectral = gc.material_rgb(SpectralConductor("gold", alpha=0.2), wi, wo)
    rgb = load("ggx:alpha=0.2,metal=gold").eval(wi, wo, precision="float64")
    # Green and blue are exact at normal incidence; red is clipped to a physical reflectance.
    np.testing.assert_allclose(rgb[:, 1:] / spectral[:, 1:], 1.0, rtol=0.03)
    assert (rgb[:, 0] <= spectral[:, 0]).all()


def test_spectral_conductor_at_normal_incidence_is_f0_times_the_ggx_peak():
    alpha = 0.3
    m = SpectralConductor("silver", alpha=alpha)
    wl = np.array([400.0, 500.0, 600.0, 700.0])
    n, k = m.index.at(wl)
    expected = _fresnel_complex(n, k) / (4 * np.pi * alpha**2)  # D(0) = 1/(π α²), G = 1
    np.testing.assert_allclose(m.eval(Z, Z, wl)[0], expected, rtol=1e-10)
    below = np.array([[0.0, 0.6, -0.8]])
    assert (m.eval(below, Z, wl) == 0).all()


def test_sellmeier_glasses_match_their_catalogue_indices():
    # n_d at the helium d line (587.56 nm): Schott N-BK7 1.5168; fused silica (Malitson 1965) 1.4585.
    assert dielectric_index("bk7", 587.56) == pytest.approx(1.5168, abs=1e-4)
    assert dielectric_index("fused-silica", 587.56) == pytest.approx(1.4585, abs=1e-4)
    assert cauchy(500.0, 1.5, 0.005) == pytest.approx(1.5 + 0.005 / 0.25)


def test_spectral_dielectric_reflects_its_fresnel_at_normal_incidence():
    alpha = 0.25
    m = SpectralDielectric("bk7", alpha=alpha, reflectance=lambda wl: np.full_like(wl, 0.5))
    wl = np.array([450.0, 650.0])
    eta = dielectric_index("bk7", wl)
    expected = ((eta - 1) / (eta + 1)) ** 2 / (4 * np.pi * alpha**2) + 0.5 / np.pi
    np.testing.assert_allclose(m.eval(Z, Z, wl)[0], expected, rtol=1e-10)


def test_errors_name_what_is_wrong():
    with pytest.raises(ValueError, match="conductor 'tin': allowed: gold, silver, copper, aluminium"):
        conductor_index("tin")
    with pytest.raises(ValueError, match=r"wavelength_nm: the table covers \[300.9, 892\] nm"):
        conductor_index("gold").at([250.0])
    with pytest.raises(ValueError, match="illuminant: 'D99'"):
        gc.spectral_to_XYZ(np.ones(gc.WAVELENGTH_NM.size), "D99")
