"""Time-based checkpoints on a drifting simulated lamp: the campaign ends at the plan's estimate, every
interval between reference readings stays within reference.every_s, and the calibrated BRDF is as close
to the truth as with count-based checkpoints at about the same interval in seconds."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.calibrate import calibrate
from gonio.campaign import create_campaign, run_campaign
from gonio.config import CONFIG_DIR, load_config
from gonio.plan import STEP_REFERENCE, build_plan
from gonio.runner import State
from gonio.wiring import build_gantry

MATERIAL = "lambert:albedo=0.5"
GRID = "iso:step=30"


def _drifting(every: int, every_s: float | None):
    cfg = load_config(CONFIG_DIR / "sim.toml")
    light = cfg.light.model_copy(update={"sim": cfg.light.sim.model_copy(update={"drift_per_hour": 0.2})})
    ref = cfg.reference.model_copy(update={"every": every, "every_s": every_s})
    return cfg.model_copy(update={"light": light, "reference": ref})


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
    return cal, end, estimate, np.diff(times)


def test_time_checkpoints_calibrate_a_drifting_lamp_as_well_as_count_ones(tmp_path):
    count_cfg = _drifting(10, None)
    plan = build_plan(GRID, count_cfg)
    interval = plan.estimated_s / np.count_nonzero(plan.step_kind == STEP_REFERENCE)
    timed_cfg = _drifting(100_000, float(np.ceil(interval)))
    cal_c, end_c, est_c, gaps_c = _campaign(tmp_path / "count", count_cfg)
    cal_t, end_t, est_t, gaps_t = _campaign(tmp_path / "time", timed_cfg)
    assert end_c == pytest.approx(est_c, rel=1e-9)
    assert end_t == pytest.approx(est_t, rel=1e-9)
    assert np.all(gaps_t <= timed_cfg.reference.every_s + 1e-6)
    truth = 0.5 / np.pi
    err_c = np.max(np.abs(cal_c.value / truth - 1.0))
    err_t = np.max(np.abs(cal_t.value / truth - 1.0))
    assert err_t <= max(2.0 * err_c, 1e-3)
