"""Checkpoints by gantry time: every interval between reference readings within reference.every_s."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.config import CONFIG_DIR, load_config
from gonio.kinematics import make_kinematics
from gonio.motion.estimate import step_move_times
from gonio.motion.metric import MoveMetric
from gonio.plan import STEP_DARK, STEP_REFERENCE, build_plan
from gonio.plan.checkpoints import cut_runs, intervals
from gonio.plan.transit import step_targets


def _with(cfg, **ref):
    return cfg.model_copy(update={"reference": cfg.reference.model_copy(update=ref)})


@pytest.mark.parametrize("name", ["sim.toml", "sample-stage.toml"])
def test_time_checkpoints_keep_every_interval_and_the_estimate_is_exact(name):
    cfg = load_config(CONFIG_DIR / name)
    kin = make_kinematics(cfg)
    metric = MoveMetric(kin.velocity_deg_s, kin.accel_deg_s2)
    count = build_plan("iso:step=15", _with(cfg, every=50, every_s=None), kin)
    timed = build_plan("iso:step=15", _with(cfg, every=None, every_s=120.0), kin)
    targets = step_targets(timed.step_kind, timed.step_pose, timed.axes_deg, timed.reference_axes_deg)
    reading = cfg.detector.exposure_s * cfg.detector.frames
    step_s = (step_move_times(targets, kin.home_deg, metric) + reading
              + np.where(timed.step_kind != STEP_DARK, cfg.runner.settle_s, 0.0))
    gaps = intervals(np.cumsum(step_s), timed.step_kind, STEP_REFERENCE)
    assert gaps.size == np.count_nonzero(timed.step_kind == STEP_REFERENCE) - 1
    assert np.all(gaps <= 120.0 + 1e-6)
    assert timed.via_deg == {}
    # A campaign ends with a checkpoint: the park leaves from the reference.
    assert timed.step_kind[-1] == STEP_REFERENCE
    end = float(np.cumsum(step_s)[-1]) + float(metric.time(timed.reference_axes_deg, kin.home_deg))
    assert end == pytest.approx(timed.estimated_s, rel=1e-12)
    n_refs = [np.count_nonzero(p.step_kind == STEP_REFERENCE) for p in (timed, count)]
    assert n_refs[0] < n_refs[1]
    assert timed.timing["reference_s"] < count.timing["reference_s"]
    assert timed.lower_bound_s <= timed.estimated_s


def test_cut_runs_ends_runs_where_the_detour_is_least():
    metric = MoveMetric([60.0], [120.0])
    # Poses walk away from the reference at 0° and back: the cheap place to stop is near 0°.
    axes = np.concatenate([np.arange(0, 100, 10), np.arange(100, -1, -10)]).astype(float)[:, None]
    starts = cut_runs(axes, np.zeros((1, 1)), metric, 0.0, 0.0, every=1000, every_s=1e9)
    assert starts.tolist() == [0]
    with pytest.raises(ValueError, match="reference.every_s"):
        cut_runs(axes, np.zeros((1, 1)), metric, 0.2, 0.1, every=1000, every_s=0.5)
