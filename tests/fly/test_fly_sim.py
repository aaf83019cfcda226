"""Fly campaigns on the simulated gantry: motion-integrating readings, calibration, blur in stddev,
one journal transaction per sweep and resume."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.calibrate import calibrate
from gonio.campaign import open_campaign
from gonio.config import load_config
from gonio.dataset import read_brdf
from gonio.fly import create_fly_campaign, fly_plan_of, run_fly_campaign
from gonio.geometry import sph_to_vec
from gonio.plan import build_plan
from gonio.plan.fly import FLY_DUTY, FlyLine, fly_plan, fly_steps
from gonio.sim import materials
from gonio.sim.detector import aperture_radiance_factor
from gonio.sim.fly import FlySimulator
from gonio.sim.gantry import reference_material

# Fine steps (the density of iso:step=2) over a small cap of angles: cheap, yet the blur is that of
# a real fine campaign.
GRID = "iso:step=2,theta_max=16,order=fly"
SHARP = "ward:rho_d=0.1,rho_s=0.2,alpha=0.02"


@pytest.fixture(scope="module")
def fine():
    cfg = load_config(None)
    plan = build_plan(GRID, cfg)
    return cfg, plan, fly_plan(plan, cfg)


def _truth(cfg, spec, cal, aperture: bool):
    """The material at each sample's angles: its point value, or what a stop-and-go reading of the pose
    gives once calibrated like the fly readings (4096 samples): its average over the source and detector
    cones, over the white standard's at the reference pose (cos θi over the source cone is 2e-5 below
    that of the cone's centre at normal incidence, which calibrating against the reference cancels: the
    stderr of a diffuse reading is ~1e-6)."""
    m = materials.load(spec)
    a = np.radians(cal.angles_deg)
    wi, wo = sph_to_vec(a[:, 0], a[:, 1]), sph_to_vec(a[:, 2], a[:, 3])
    if not aperture:
        return m.eval(wi, wo)
    src, det = cfg.light.sim.half_angle_deg, cfg.detector.sim.half_angle_deg
    factor, _ = aperture_radiance_factor(m, wi, wo, src, det, 4096, (11, 0))
    r = cfg.reference
    ref = np.radians([r.theta_i_deg, 0.0, r.theta_o_deg, r.dphi_deg])
    white, _ = aperture_radiance_factor(reference_material(cfg), sph_to_vec(ref[:1], ref[1:2]),
                                        sph_to_vec(ref[2:3], ref[3:]), src, det, 4096, (11, 1))
    return cfg.reference.albedo / np.pi * factor / white * np.cos(ref[0]) / np.cos(a[:, 0])[:, None]


@pytest.mark.parametrize("spec", ["lambert:albedo=0.5", "ward:rho_d=0.1,rho_s=0.05,alpha_x=0.1,alpha_y=0.3",
                                  "cook-torrance:d=beckmann,m=0.3,metal=gold"])
def test_calibrated_fly_readings_match_the_material(fine, spec):
    cfg, plan, fp = fine
    cal = calibrate(FlySimulator(cfg, spec, seed=1).campaign(fp), cfg.reference.albedo)
    assert len(cal.value) == len(plan.theta_i)
    truth = _truth(cfg, spec, cal, aperture=False)
    rel = np.abs(cal.value - truth) / truth
    assert np.median(rel) < 0.01


def _through_peak(theta_deg):
    """A Δφ sweep of the detector carriage through the specular direction at θi = θo = theta_deg, at
    the fly speed and exposure of an iso:step=2 campaign (60°/s, a degree of travel per exposure)."""
    return FlyLine(np.arange(21), 2, np.array([0.0, theta_deg, 160.0, theta_deg]), 2.0, 60.0, 120.0,
                   FLY_DUTY * 2.0 / 60.0)


def test_blur_is_integrated_over_the_motion_not_the_mid_point():
    cfg = load_config(None)
    sim = FlySimulator(cfg, SHARP, seed=4)
    sim.samples = 1024   # a quieter reading than a campaign's, to see the blur against it
    line = _through_peak(50.0)
    ms = sim.sweep(line, 0.0, 0)
    j = 10   # Δφ = 180°: the peak
    scale = cfg.light.sim.radiance * line.exposure_s
    fly, se = ms[j].signal[1] / scale, ms[j].extra["stderr_integration"][1] / scale
    m = materials.load(SHARP)

    def factor(pos, n):
        wi, wo = sim.kin.directions(pos)
        return aperture_radiance_factor(m, wi, wo, cfg.light.sim.half_angle_deg,
                                        cfg.detector.sim.half_angle_deg, n, (9, 0))[0][:, 1]

    times = line.mid_times()[j] + line.exposure_s * ((np.arange(64) + 0.5) / 64 - 0.5)
    mean_over_path = factor(line.position_at(times), 4096).mean()
    at_mid = factor(line.readings_deg()[j:j + 1], 65536)[0]
    # The reading is the mean over the exposure's path, not the value at its mid-point ...
    assert abs(fly - mean_over_path) < 3 * se
    assert abs(at_mid - mean_over_path) > 6 * se
    # ... and its blur term is of the size of that difference.
    blur = ms[j].extra["stderr_blur"][1] / scale
    assert 0.3 < blur / abs(at_mid - mean_over_path) < 3


def test_blur_stated_honestly_through_sharp_peaks():
    cfg = load_config(None)
    sim = FlySimulator(cfg, SHARP, seed=5)
    m = materials.load(SHARP)
    z = []
    for theta in (30.0, 50.0, 70.0):
        ms = sim.sweep(_through_peak(theta), 0.0, int(theta))
        scale = cfg.light.sim.radiance * ms[0].exposure_s
        wi, wo = sim.kin.directions(np.stack([x.actual_deg for x in ms]))
        truth = aperture_radiance_factor(m, wi, wo, cfg.light.sim.half_angle_deg,
                                         cfg.detector.sim.half_angle_deg, 16384, (9, 0))[0]
        value, sd = (np.stack([getattr(x, k) for x in ms]) / scale for k in ("signal", "stderr"))
        z.append((value - truth) / sd)
    z = np.concatenate(z)
    # Against the stop-and-go reading of the same pose: never more than 3 sigma off, and the stddev not
    # inflated beyond twice what the errors show.
    assert np.abs(z).max() < 3
    assert 0.35 < np.sqrt(np.mean(z**2)) < 1.5


def test_blur_stated_honestly_on_a_sharp_peak(fine):
    cfg, plan, fp = fine
    cal = calibrate(FlySimulator(cfg, SHARP, seed=2).campaign(fp), cfg.reference.albedo)
    # Against what a stop-and-go reading of the same pose sees (the apertures blur both alike), the
    # fly readings' errors are explained by their stddev: z-scores of unit size, on the peak too.
    truth = _truth(cfg, SHARP, cal, aperture=True)
    z = (cal.value - truth) / cal.stddev
    assert 0.5 < np.sqrt(np.mean(z**2)) < 1.5
    assert np.mean(np.abs(z) < 2) > 0.9
    top = np.argsort(-truth[:, 1])[:50]
    assert np.sqrt(np.mean(z[top] ** 2)) < 2.0
    # ... and the blur is a visible part of the stddev there (not hidden in a generous constant).
    rel_sd = cal.stddev[top, 1] / truth[top, 1]
    assert np.median(rel_sd) > 0.001


def test_positions_from_timestamped_reads_at_mid_exposure(fine):
    cfg, plan, fp = fine
    sim = FlySimulator(cfg, "lambert:albedo=0.5", seed=1)
    line = next(ln for ln in fp.lines if ln.moving)
    ms = sim.sweep(line, 5.0, 0)
    actual = np.stack([m.actual_deg for m in ms])
    assert np.allclose(actual, line.readings_deg(), atol=1e-9)
    planned = np.degrees(np.stack([plan.theta_i, plan.phi_i, plan.theta_o, plan.phi_o], axis=1))[line.poses]
    got = np.stack([m.angles_deg for m in ms])
    assert np.allclose(got[:, [0, 2]], planned[:, [0, 2]], atol=1e-7)
    dphi = np.mod(got[:, 3] - got[:, 1] - (planned[:, 3] - planned[:, 1]) + 180, 360) - 180
    assert np.allclose(dphi, 0, atol=1e-7)
    ends = np.array([m.campaign_s for m in ms])
    assert np.allclose(ends, 5.0 + line.mid_times() + line.exposure_s / 2)


def test_campaign_resumes_from_the_next_sweep_and_equals_an_uninterrupted_one(tmp_path):
    cfg = load_config(None)
    spec, grid = "ward:rho_d=0.1,rho_s=0.05,alpha_x=0.1,alpha_y=0.3", "iso:step=15,order=fly"
    whole = create_fly_campaign(tmp_path / "a", cfg, grid=grid, material=spec, seed=3)
    run_fly_campaign(whole, FlySimulator(whole.cfg, spec, seed=3))
    whole.close()

    class Crash(Exception):
        pass

    def crash(done, total):
        if done == 7:
            raise Crash

    c = create_fly_campaign(tmp_path / "b", cfg, grid=grid, material=spec, seed=3)
    with pytest.raises(Crash):
        run_fly_campaign(c, FlySimulator(c.cfg, spec, seed=3), on_sweep=crash)
    items = fly_steps(fly_plan_of(c))
    # Seven whole sweeps or checkpoints are in the journal, nothing of the eighth.
    assert c.journal.done_count() == items[7][2]
    c.close()
    c = open_campaign(tmp_path / "b")
    run_fly_campaign(c, FlySimulator(c.cfg, spec, seed=3))
    c.close()
    from gonio.cli.campaigns import campaign_status

    assert campaign_status(tmp_path / "b")["state"] == "done"
    a, b = read_brdf(tmp_path / "a" / "brdf.h5"), read_brdf(tmp_path / "b" / "brdf.h5")
    assert len(a.value) > 200
    for name in ("value", "stddev", "theta_i", "phi_i", "theta_o", "phi_o", "campaign_s", "step", "pose"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert a.attrs["grid"].endswith("order=fly")
