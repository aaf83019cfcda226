"""Time-based checkpoints on a drifting simulated lamp: the campaign ends at the plan's estimate, every
interval between reference readings stays within reference.every_s, and the calibrated BRDF is as close
to the truth as with count-based checkpoints several times as frequent, although the lamp's drift
curves (warm-up and wander) so much that a straight line between the sparse references would not do."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.calibrate import calibrate
from gonio.campaign import create_campaign
from gonio.clock import VirtualClock
from gonio.config import CONFIG_DIR, load_config
from gonio.lifecycle import run_campaign
from gonio.plan import STEP_POSE, STEP_REFERENCE, build_plan
from gonio.runner import State
from gonio.sim.light import SimLight
from gonio.wiring import build_gantry

MATERIAL = "lambert:albedo=0.5"
GRID = "iso:step=15"  # order=auto: a tour here
# A lamp drifting on the scale of this short campaign (~330 s) as a real one does on a long one: it
# warms up by 3 % with a 3 min time constant, wanders by 1 % with a 9 min period and trends by -20 %/h.
LAMP = {"drift_per_hour": -0.2, "warmup_fraction": 0.03, "warmup_s": 180.0, "wander_fraction": 0.01,
        "wander_period_s": 540.0}
SPARSE_S = 90.0     # time-based checkpoints: about 5x as far apart as the count-based ones
DENSE_EVERY = 10


def _drifting(every: int | None, every_s: float | None):
    cfg = load_config(CONFIG_DIR / "sim.toml")
    light = cfg.light.model_copy(update={"sim": cfg.light.sim.model_copy(update=LAMP)})
    ref = cfg.reference.model_copy(update={"every": every, "every_s": every_s})
    # Enough aperture samples that the detector's own Monte Carlo error (~4e-5) is below the drift's.
    sim = cfg.detector.sim.model_copy(update={"aperture_samples": 4096})
    det = cfg.detector.model_copy(update={"sim": sim})
    return cfg.model_copy(update={"light": light, "reference": ref, "detector": det})


def _campaign(folder, cfg):
    c = create_campaign(folder, cfg, grid=GRID, material=MATERIAL, seed=1)
    state, _ = run_campaign(c, build_gantry(c.cfg, MATERIAL, seed=1))
    assert state == State.DONE
    ms = c.journal.measurements()
    cal = calibrate(ms, cfg.reference.albedo)
    end = c.journal.last_event("park")["campaign_s"]
    estimate = c.meta["estimated_s"]
    c.close()
    times = np.array([m.campaign_s for m in ms if m.kind == STEP_REFERENCE])
    return cal, end, estimate, times


def test_time_checkpoints_calibrate_a_curving_drift_as_well_as_dense_count_ones(tmp_path):
    dense_cfg = _drifting(DENSE_EVERY, None)
    sparse_cfg = _drifting(None, SPARSE_S)
    cal_d, end_d, est_d, refs_d = _campaign(tmp_path / "count", dense_cfg)
    cal_s, end_s, est_s, refs_s = _campaign(tmp_path / "time", sparse_cfg)
    assert end_d == pytest.approx(est_d, rel=1e-9)
    assert end_s == pytest.approx(est_s, rel=1e-9)
    assert np.all(np.diff(refs_s) <= SPARSE_S + 1e-6)
    assert refs_d.size >= 5 * refs_s.size          # the count schedule reads the reference far more often
    # The sparse schedule's plan spends far less on checkpoints.
    share = {k: build_plan(GRID, c).timing["reference_s"] / e
             for k, c, e in (("dense", dense_cfg, est_d), ("sparse", sparse_cfg, est_s))}
    assert share["sparse"] < 0.5 * share["dense"]

    # The drift is curved enough that a straight line between the sparse references misses it by far
    # more than the tolerance below (this is what makes the comparison a test of the interpolation).
    lamp = SimLight(sparse_cfg.light, VirtualClock())
    truth_at = np.vectorize(lamp.lamp_radiance)
    linear = np.interp(cal_s.campaign_s, refs_s, truth_at(refs_s)) / truth_at(cal_s.campaign_s) - 1.0

    truth = 0.5 / np.pi
    err_d = np.median(np.abs(cal_d.value / truth - 1.0))
    err_s = np.median(np.abs(cal_s.value / truth - 1.0))
    tolerance = max(1.5 * err_d, 1e-4)
    print(f"median error: dense {err_d:.2e}, sparse {err_s:.2e}; a straight line misses by "
          f"{np.median(np.abs(linear)):.2e}")
    assert np.median(np.abs(linear)) > 3.0 * tolerance
    assert err_s <= tolerance
    assert cal_s.value.shape[0] == np.count_nonzero(build_plan(GRID, sparse_cfg).step_kind == STEP_POSE)
