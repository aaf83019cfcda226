"""The fit models the instrument's optics: the model averaged over the source and detector cones."""

import dataclasses
import functools
import json
import math

import numpy as np
import planned
import pytest

from gonio.cli import main
from gonio.config import load_config
from gonio.dataset import BRDF_NAME, aperture_cones, read_brdf, write_brdf
from gonio.fit import Aperture, FitData, fit
from gonio.lifecycle import run_campaign
from gonio.plan import build_plan
from gonio.sim.aperture import aperture_radiance_factor, seed_state
from gonio.sim.materials import load
from gonio.wiring import build_gantry

# The fits and the simulator's Monte Carlo run on every Dr.Jit backend (CUDA skipped without a device).
pytestmark = pytest.mark.usefixtures("backend")

SOURCE, DETECTOR = 0.5, 1.0   # the default config's cones (config/sim.toml)
COPPER = "ggx:alpha=0.15,metal=copper,rho_d=0.2,rho_s=0.8"


@functools.cache
def _dirs():
    plan = build_plan("iso:step=15,theta_max=75,order=raster", load_config())
    from gonio.geometry import sph_to_vec

    return sph_to_vec(plan.theta_i, plan.phi_i), sph_to_vec(plan.theta_o, plan.phi_o)


def _measured(spec, samples, seed=3):
    """What a calibrated reading of ``spec`` estimates, by the simulator's own Monte Carlo over the cones
    (gonio.sim.aperture) with ``samples`` pairs per pose: Ω_s·mean(f_r cos θi') over the white
    standard's Ω_s·c·cos θi (gonio.fit.aperture), and its standard error."""
    wi, wo = _dirs()
    factor, se = aperture_radiance_factor(load(spec), wi, wo, SOURCE, DETECTOR, samples,
                                          seed_state(seed, 9, 0, 0))
    scale = 2 * math.pi * (1 - math.cos(math.radians(SOURCE))) * (1 + math.cos(math.radians(SOURCE))) / 2
    return factor / (scale * wi[:, 2:3]), se / (scale * wi[:, 2:3])


def _truth(spec, name):
    key, _, channel = name.partition(".")
    value = load(spec).values()["alpha_u" if key == "alpha" else key]
    return value["RGB".index(channel)] if channel else value


def _z(result, spec):
    return {n: (p["value"] - _truth(spec, n)) / p["stddev"] for n, p in result.parameters.items()}


@pytest.mark.parametrize("spec, model", [(COPPER, "ggx:metal=copper"), ("lambert:albedo=0.6/0.5/0.4",
                                                                        "lambert")])
def test_fitted_through_the_cones_the_truth_is_within_3_sigma_where_the_point_model_is_off_by_far_more(spec,
                                                                                                   model):
    """Readings simulated through the default cones with 4096 aperture samples a pose: the GGX lobe's
    parameters fitted at the cones' axes are off by 4 σ (rho_d) to 47 σ (alpha); the model averaged
    over the cones recovers them within 1.7 σ. A Lambertian has nothing to smooth: both fits recover it,
    alike."""
    wi, wo = _dirs()
    value, sd = _measured(spec, 4096)
    point = _z(fit(FitData(wi, wo, value, sd), model, starts=2), spec)
    cones = _z(fit(FitData(wi, wo, value, sd, Aperture(SOURCE, DETECTOR)), model, starts=2), spec)
    assert max(abs(z) for z in cones.values()) < 3.0, cones
    if spec == COPPER:
        assert abs(point["alpha"]) > 10 and all(abs(point[f"rho_s.{c}"]) > 3 for c in "RGB"), point
    else:
        assert max(abs(z) for z in point.values()) < 3.0, point


def test_the_quadrature_agrees_with_the_simulators_monte_carlo_within_its_error():
    """16 directions a pose against 16384 Monte Carlo pairs: differences of the size of the Monte Carlo
    error (rms z 0.98), while the model at the axes is off by up to 140 of it at the lobe (rms 13); and
    against a (3 rings × 8 spokes)² quadrature, below 1e-4 relative everywhere (1e-5)."""
    wi, wo = _dirs()
    value, sd = _measured(COPPER, 1 << 14)
    material = load(COPPER)
    quad = Aperture(SOURCE, DETECTOR).evaluate(material, wi, wo)
    point = material.eval(wi, wo, precision="float64")
    assert np.sqrt(np.mean(((quad - value) / sd) ** 2)) < 1.2
    assert np.sqrt(np.mean(((point - value) / sd) ** 2)) > 5
    fine = Aperture(SOURCE, DETECTOR, rings=3, spokes=8).evaluate(material, wi, wo)
    assert np.max(np.abs(quad / fine - 1)) < 1e-4


def test_a_constant_brdf_comes_back_unchanged_and_bad_cones_are_refused():
    wi, wo = _dirs()
    f = Aperture(10.0, 10.0).evaluate(load("lambert:albedo=0.5"), wi, wo)   # c = 0.992
    assert np.allclose(f, 0.5 / np.pi, rtol=1e-12)
    for bad in (0.0, -1.0, 11.0, float("nan"), "1"):
        with pytest.raises(ValueError, match=r"source_half_angle_deg: must be a number in \(0, 10\]"):
            Aperture(bad, 1.0)


def test_the_cones_come_from_brdf_h5_attributes_or_an_older_files_config_snapshot():
    assert aperture_cones({"source_half_angle_deg": 0.25, "detector_half_angle_deg": 2}) == (0.25, 2.0)
    old = {"material": "lambert:albedo=0.5", "config": {"detector": {"sim": {"half_angle_deg": 3.0}}}}
    assert aperture_cones(old) == (SOURCE, 3.0)   # the snapshot leaves the defaults out
    assert aperture_cones({**old, "config": {}}) == (SOURCE, DETECTOR)
    camera = {"material": "lambert:albedo=0.5", "config": {"detector": {"sim": {"kind": "camera"}}}}
    assert aperture_cones(camera) is None          # a camera's pixels see other cones
    assert aperture_cones({"sample": "tile", "config": {}}) is None   # a real sample: not known
    assert aperture_cones({}) is None
    with pytest.raises(ValueError, match="detector_half_angle_deg: must be a number"):
        aperture_cones({"source_half_angle_deg": 0.5, "detector_half_angle_deg": "wide"})


def test_cli_fit_of_a_campaign_says_it_averaged_over_its_cones_and_of_a_bare_file_that_it_did_not(tmp_path,
                                                                                                   capsys):
    cfg = load_config()
    c = planned.create(tmp_path / "c", cfg, grid="iso:step=45", material="lambert:albedo=0.5", seed=1)
    try:
        run_campaign(c, build_gantry(c.cfg, "lambert:albedo=0.5", seed=1))
    finally:
        c.close()
    data = read_brdf(tmp_path / "c" / BRDF_NAME)
    assert (data.attrs["source_half_angle_deg"], data.attrs["detector_half_angle_deg"]) == (SOURCE,
                                                                                             DETECTOR)
    assert main(["fit", str(tmp_path / "c"), "--model", "lambert", "--out", str(tmp_path / "f.json")]) == 0
    err = capsys.readouterr().err
    assert "model averaged over the cones the readings integrate: source cone 0.5°, detector cone 1° " \
           "(16 directions per pose)" in err
    assert json.loads((tmp_path / "f.json").read_text())["aperture"]["points"] == 16
    attrs = {k: v for k, v in data.attrs.items() if "half_angle" not in k}
    write_brdf(tmp_path / "bare.h5", dataclasses.replace(data, attrs={**attrs, "material": ""}))
    assert main(["fit", str(tmp_path / "bare.h5"), "--model", "lambert"]) == 0
    err = capsys.readouterr().err
    assert "model evaluated at the measured directions: the source and detector cones" in err
    bad = {**data.attrs, "source_half_angle_deg": 45.0}
    write_brdf(tmp_path / "bad.h5", dataclasses.replace(data, attrs=bad))
    assert main(["fit", str(tmp_path / "bad.h5"), "--model", "lambert"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert f"{tmp_path / 'bad.h5'}: attribute source_half_angle_deg: must be a number in (0, 10] degrees, " \
           "got 45.0" in err
