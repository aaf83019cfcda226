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


def test_time_checkpoints_are_spread_evenly_with_no_more_of_them():
    """Cut greedily, 330 s of tour at every_s = 90 s left intervals of 72, 77, 76, 87 and 14 s; the
    calibration's cubic needs neighbouring intervals within SPACING_RATIO of each other. Balanced: as
    many checkpoints as the greedy cut, the longest interval shorter, every neighbour pair within it."""
    from gonio.calibrate import SPACING_RATIO
    from gonio.plan import checkpoints

    cfg = _with(load_config(CONFIG_DIR / "sim.toml"), every=None, every_s=90.0)
    kin = make_kinematics(cfg)
    metric = MoveMetric(kin.velocity_deg_s, kin.accel_deg_s2)
    plan = build_plan("iso:step=15,order=tour", cfg, kin)
    pose_steps = plan.step_kind == 0
    axes = plan.axes_deg
    reading = cfg.detector.exposure_s * cfg.detector.frames
    args = (axes, plan.reference_axes_deg[None], metric, cfg.runner.settle_s, reading, 10**9, 90.0)
    balanced = cut_runs(*args)
    floor = checkpoints.BALANCE_FLOOR
    try:
        checkpoints.BALANCE_FLOOR = 1.0  # no search below every_s: the greedy cut
        greedy = cut_runs(*args)
    finally:
        checkpoints.BALANCE_FLOOR = floor
    assert balanced.size == greedy.size >= 4

    def gaps(starts):
        # Each run's interval as cut_runs sees it: reference, the run's poses, dark, reference.
        ends = np.append(starts[1:], axes.shape[0]) - 1
        to_ref = metric.time(axes, plan.reference_axes_deg)
        inner = np.array([metric.time(axes[s:e], axes[s + 1:e + 1]).sum()
                          for s, e in zip(starts, ends, strict=True)])
        n = ends - starts + 1
        return to_ref[starts] + inner + to_ref[ends] + n * (cfg.runner.settle_s + reading)

    g_greedy, g_balanced = gaps(greedy), gaps(balanced)
    assert g_greedy.max() / g_greedy.min() > SPACING_RATIO          # the short last run
    assert np.all(g_balanced <= 90.0)
    assert g_balanced.max() < g_greedy.max()
    ratio = np.maximum(g_balanced[1:] / g_balanced[:-1], g_balanced[:-1] / g_balanced[1:])
    assert np.all(ratio <= SPACING_RATIO)
    assert np.count_nonzero(plan.step_kind == STEP_REFERENCE) == balanced.size + 1
    assert pose_steps.sum() == axes.shape[0]
