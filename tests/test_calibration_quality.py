"""Calibration to an absolute BRDF, end to end on the simulated gantry: a drifting lamp corrected by the
periodic references, mixed exposures and brackets, the white standard per channel or as a spectrum, and
spectral gold turned into colour."""

from __future__ import annotations

import numpy as np
import planned
import pytest

from gonio.calibrate import calibrate
from gonio.colour import bands_to_rgb, material_rgb
from gonio.config import ConfigError, load_config, parse_config
from gonio.dataset import read_brdf
from gonio.geometry import sph_to_vec
from gonio.lifecycle import run_campaign
from gonio.plan import STEP_REFERENCE
from gonio.runner import State
from gonio.sim.detector_spectral import spectral_material
from gonio.wiring import build_gantry

LAMBERT = "lambert:albedo=0.5"
GRID = "iso:step=20,theta_max=70,order=raster"  # no check here depends on the order; the tour plans longer


def _cfg(kind="photodiode", camera=None, light=None, reference=None, runner=None):
    d = load_config().model_dump(mode="python", exclude_unset=True)
    if runner:
        d["runner"].update(runner)
    d["detector"]["sim"]["kind"] = kind
    if kind == "spectrometer":
        d["detector"].pop("channels")
    if kind == "camera":  # frames not kept: the calibrated values are what this module checks (keeping
        # frames is test_detectors' subject); their EXR files and fsyncs were 40 % of each step's cost
        d["detector"]["sim"]["camera"] = {"save_frames": False, **(camera or {})}
    if light:
        d["light"]["sim"].update(light)
    if reference:
        d["reference"].update(reference)
    return parse_config(d)


def _run(tmp_path, cfg, material=LAMBERT, grid=GRID):
    c = planned.create(tmp_path, cfg, grid=grid, material=material, seed=4)
    state, _ = run_campaign(c, build_gantry(cfg, material, seed=4))
    assert state == State.DONE
    return c, read_brdf(tmp_path / "brdf.h5")


def test_a_drifting_lamp_is_corrected_by_the_periodic_references(tmp_path):
    """The lamp brightens by 50 % an hour, over a campaign slowed to ~40 min of gantry time (a 20 s settle
    per pose); references every 10 poses track it: the camera's calibrated Lambertian stays within 1 % of
    0.5/π, while calibrating against the first reference alone is off by over 5 %."""
    cfg = _cfg("camera", light={"drift_per_hour": 0.5}, reference={"every": 10}, runner={"settle_s": 20.0})
    c, b = _run(tmp_path, cfg)
    assert b.campaign_s.max() > 1800.0
    np.testing.assert_allclose(b.value, 0.5 / np.pi, rtol=0.01)
    ms = c.journal.measurements()
    first_ref = next(m.step for m in ms if m.kind == STEP_REFERENCE)
    only_first = [m for m in ms if m.kind != STEP_REFERENCE or m.step == first_ref]
    stale = calibrate(only_first, cfg.reference.albedo).value
    assert np.abs(stale / (0.5 / np.pi) - 1).max() > 0.05
    c.close()


def test_auto_exposure_and_brackets_calibrate_to_the_same_values_as_a_fixed_exposure(tmp_path):
    fixed_c, fixed = _run(tmp_path / "fixed", _cfg("camera"))
    # saturation 0.01: the standard reads ~7.5e-3 at 0.1 s, so the auto-exposure works near full scale
    auto_c, auto = _run(tmp_path / "auto", _cfg("camera", camera={"saturation": 0.01, "auto_exposure": True}))
    exposures = np.array([m.exposure_s for m in auto_c.journal.measurements()])
    assert exposures.max() > 1.5 * exposures.min()  # the exposures did differ from reading to reading
    # a bracket whose long exposure saturates the patch: merged, it still reads the right radiance
    bracket = {"saturation": 0.005, "brackets": [0.25, 1.0, 4.0]}
    br_c, br = _run(tmp_path / "br", _cfg("camera", camera=bracket))
    for other in (auto, br):
        np.testing.assert_allclose(other.value, fixed.value, rtol=0.01)
        np.testing.assert_allclose(other.value, 0.5 / np.pi, rtol=0.01)
    for c in (fixed_c, auto_c, br_c):
        c.close()


def test_a_white_standard_given_per_channel_is_what_the_calibration_divides_by(tmp_path):
    cfg = _cfg(reference={"reflectance": [0.99, 0.96, 0.9]})
    c, b = _run(tmp_path, cfg)
    np.testing.assert_allclose(b.value, 0.5 / np.pi, rtol=0.005)
    assert list(b.attrs["reference_reflectance"]) == [0.99, 0.96, 0.9]
    c.close()


def test_a_spectral_white_standard_is_read_at_the_spectrometers_bands(tmp_path):
    table = {"wavelength_nm": [350.0, 550.0, 800.0], "reflectance": [0.90, 0.98, 0.99]}
    cfg = _cfg("spectrometer", reference={"spectrum": table})
    material = "ggx:alpha=0.3,metal=gold"
    c, b = _run(tmp_path, cfg, material, "iso:step=30")
    wl = np.asarray(b.attrs["wavelengths_nm"])
    np.testing.assert_allclose(b.attrs["reference_reflectance"], np.interp(wl, table["wavelength_nm"],
                                                                           table["reflectance"]))
    wi = sph_to_vec(np.radians(b.theta_i), np.radians(b.phi_i))
    wo = sph_to_vec(np.radians(b.theta_o), np.radians(b.phi_o))
    truth = spectral_material(material).eval(wi, wo, wl)
    ok = truth > 1e-2 * truth.max()
    assert np.median(np.abs(b.value[ok] / truth[ok] - 1)) < 0.005
    c.close()


def test_a_white_standard_that_does_not_fit_the_detector_is_refused():
    with pytest.raises(ConfigError, match="reference.reflectance: 3 values for the detector's 41 channels"):
        _cfg("spectrometer", reference={"reflectance": [0.99, 0.98, 0.97]})
    with pytest.raises(ConfigError, match="the table covers"):
        _cfg("spectrometer", reference={"spectrum": {"wavelength_nm": [400, 700], "reflectance": [0.9, 0.9]}})


def test_a_spectral_gold_campaign_is_gold_coloured_in_srgb(tmp_path):
    material = "ggx:alpha=0.3,metal=gold"
    c, b = _run(tmp_path, _cfg("spectrometer"), material, "iso:step=30")
    rgb = bands_to_rgb(b.value, b.attrs["wavelengths_nm"])
    assert (rgb[:, 0] > rgb[:, 1]).all() and (rgb[:, 1] > rgb[:, 2]).all()
    # and it is the colour of the tabulated gold seen at those angles (the 10 nm bands resampled to 5 nm)
    wi = sph_to_vec(np.radians(b.theta_i), np.radians(b.phi_i))
    wo = sph_to_vec(np.radians(b.theta_o), np.radians(b.phi_o))
    want = material_rgb(spectral_material(material), wi, wo)
    ok = want[:, 1] > 1e-2 * want[:, 1].max()
    np.testing.assert_allclose(rgb[ok], want[ok], rtol=0.02)
    c.close()


def test_with_sensor_noise_the_camera_stddev_accounts_for_the_error(tmp_path):
    """Black level, read and shot noise: the calibrated Lambertian scatters by ~0.4 %, and its stated
    stddev (pixel noise of pose, dark and reference frames, carried through the calibration) explains
    that scatter: the rms of error/stddev is near 1, neither far below (stddev inflated) nor above."""
    sensor = {"black_level": 0.001, "read_sigma": 2e-4, "shot_counts_per_unit": 1e6, "saturation": 0.02}
    c, b = _run(tmp_path, _cfg("camera", camera=sensor))
    c.close()
    err = b.value - 0.5 / np.pi
    z = err / b.stddev
    assert 0.5 < np.sqrt(np.mean(z**2)) < 1.5
    assert np.abs(err).max() / (0.5 / np.pi) > 0.003  # the noise is really there


def test_the_standards_own_angular_response_enters_the_calibration(tmp_path):
    """A standard that reflects 3 % less than an ideal diffuser at its reading angles (response 0.97, as
    its certificate would say): with the response the calibrated Lambertian is right, without it 3 % off."""
    cfg = _cfg(reference={"response": 0.97})
    c, b = _run(tmp_path, cfg)
    np.testing.assert_allclose(b.value, 0.5 / np.pi, rtol=0.005)
    np.testing.assert_allclose(b.attrs["reference_reflectance"], [0.99 * 0.97] * 3)
    ideal = calibrate(c.journal.measurements(), cfg.reference.albedo).value
    np.testing.assert_allclose(ideal / b.value, 1 / 0.97, rtol=1e-12)
    c.close()
    with pytest.raises(ConfigError, match="reference.response: the simulated standard would reflect"):
        _cfg(reference={"response": 1.02})
