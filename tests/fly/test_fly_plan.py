"""Fly plans: lines of the grid swept at constant velocity, checked, estimated and bounded."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gonio.cli import main
from gonio.config import load_config
from gonio.kinematics import make_kinematics
from gonio.motion.metric import MoveMetric
from gonio.plan import build_plan
from gonio.plan.fly import (
    FLY_DUTY,
    FlyPlan,
    _bound,
    _entries_nearest,
    _entries_pairwise,
    _schedule,
    fly_plan,
)


@pytest.fixture(scope="module")
def two_arm():
    cfg = load_config(None)
    plan = build_plan("iso:step=10,order=fly", cfg)
    return cfg, make_kinematics(cfg), plan, fly_plan(plan, cfg)


def test_every_pose_read_once_on_its_planned_axes(two_arm):
    cfg, kin, plan, fp = two_arm
    poses = np.concatenate([ln.poses for ln in fp.lines])
    assert np.array_equal(np.sort(poses), np.arange(len(plan.theta_i)))
    for ln in fp.lines:
        assert np.allclose(ln.readings_deg(), plan.axes_deg[ln.poses], atol=1e-9)


def test_lines_sweep_one_axis_by_the_grid_step_within_limits(two_arm):
    cfg, kin, plan, fp = two_arm
    moving = [ln for ln in fp.lines if ln.moving]
    assert len(moving) > 20 and sum(ln.n for ln in moving) > 0.9 * len(plan.theta_i)
    for ln in moving:
        r = ln.readings_deg()
        still = np.delete(np.arange(r.shape[1]), ln.axis)
        assert np.ptp(r[:, still], axis=0).max() == 0.0
        assert abs(abs(ln.step_deg) - 10.0) < 1e-9
        assert 0 < ln.speed_deg_s <= kin.velocity_deg_s[ln.axis] + 1e-12
        # The blur (axis travel during one exposure) is FLY_DUTY of a step at top speed, less when slower.
        assert ln.speed_deg_s * ln.exposure_s <= FLY_DUTY * 10.0 + 1e-9
        lo, hi = kin.limits_deg[ln.axis]
        for end in (ln.start_deg, ln.end_deg):
            assert lo - 1e-9 <= end[ln.axis] <= hi + 1e-9
    # Run-up, sweep and run-down of every line are one clear move of one axis.
    starts = np.stack([ln.start_deg for ln in moving])
    ends = np.stack([ln.end_deg for ln in moving])
    assert kin.sweep_clearance(starts, ends)[0].all()


def test_readings_fall_in_the_constant_velocity_part(two_arm):
    cfg, kin, plan, fp = two_arm
    for ln in (ln for ln in fp.lines if ln.moving):
        mid = ln.mid_times()
        assert np.allclose(ln.position_at(mid), ln.readings_deg(), atol=1e-9)
        # At the start and the end of every exposure the axis already (still) moves at the line's speed
        # (the last exposure ends exactly where the run-down begins).
        h = 1e-6
        for edge in (mid - ln.exposure_s / 2 + 2 * h, mid + ln.exposure_s / 2 - 2 * h):
            v = (ln.position_at(edge + h) - ln.position_at(edge - h))[:, ln.axis] / (2 * h)
            assert np.allclose(np.abs(v), ln.speed_deg_s, rtol=1e-5)
        assert np.allclose(ln.position_at([0.0, ln.duration_s]), [ln.start_deg, ln.end_deg], atol=1e-9)


def test_lines_without_room_are_slowed_or_trimmed_with_a_reason(two_arm):
    cfg, kin, plan, fp = two_arm
    # Rings at Δφ = 10° start against the light's carriage (arm_collision_deg = 10°): no run-up there.
    notes = fp.timing["notes"]
    assert any("no room for its run-up" in n for n in notes)
    for ln in fp.lines:
        if ln.moving and ln.speed_deg_s < kin.velocity_deg_s[ln.axis]:
            assert ln.note.startswith("slower")
            # The top speed's run-up or run-down would not be clear.
            top = type(ln)(ln.poses, ln.axis, ln.first_deg, ln.step_deg, float(kin.velocity_deg_s[ln.axis]),
                           ln.accel_deg_s2, ln.exposure_s)
            lo, hi = kin.limits_deg[ln.axis]
            inside = lo <= top.start_deg[ln.axis] <= hi and lo <= top.end_deg[ln.axis] <= hi
            assert not (inside and kin.sweep_clearance(top.start_deg, top.end_deg)[0][0])


def test_fine_steps_trim_as_many_end_poses_as_the_run_up_needs():
    # At step 1 a ring starting at the other carriage needs 4 poses of room for half the top speed:
    # they are read stop-and-go and the rest of the ring is still swept.
    cfg = load_config(None)
    plan = build_plan("iso:step=1,theta_max=6,order=fly", cfg)
    fp = fly_plan(plan, cfg)
    swept = sum(ln.n for ln in fp.lines if ln.moving)
    assert swept > 0.9 * len(plan.theta_i)
    assert fp.estimated_s < plan.estimated_s / 5


def test_estimate_above_bound_for_any_order_of_the_lines(two_arm):
    cfg, kin, plan, fp = two_arm
    metric = MoveMetric(kin.velocity_deg_s, kin.accel_deg_s2)
    assert fp.lower_bound_s <= fp.estimated_s < plan.estimated_s
    rng = np.random.default_rng(7)
    for _ in range(3):
        lines = [fp.lines[k] for k in rng.permutation(len(fp.lines))]
        other = FlyPlan(lines, np.zeros(len(lines) + 1, dtype=bool), fp.reference_deg, fp.home_deg,
                        fp.settle_s, fp.reading_s)
        _schedule(other, kin, metric, fp.timing["reference_interval_s"])
        assert other.estimated_s > fp.estimated_s      # the serpentine's order is much better than chance
        assert _bound(other, kin, metric)[0] <= other.estimated_s
        # The bound does not depend on the order (it is over any order).
        assert _bound(other, kin, metric)[0] == pytest.approx(fp.lower_bound_s, rel=1e-9) or \
            other.checkpoint_before.sum() != fp.checkpoint_before.sum()


def test_entry_bound_by_nearest_search_equals_the_pairwise_one(two_arm):
    cfg, kin, plan, fp = two_arm
    ends = np.stack([[ln.readings_deg()[0], ln.readings_deg()[-1]] for ln in fp.lines])
    axis = np.array([ln.axis for ln in fp.lines])
    rest = np.stack([fp.reference_deg, fp.home_deg])
    v, a = np.asarray(kin.velocity_deg_s), np.asarray(kin.accel_deg_s2)
    pairwise = _entries_pairwise(ends, axis, rest, v, a)
    assert np.allclose(_entries_nearest(ends, axis, rest, v, a), pairwise, rtol=0, atol=1e-12)


def test_estimate_adds_up_its_parts(two_arm):
    cfg, kin, plan, fp = two_arm
    e = fp.timing["estimate"]
    lines = sum(ln.duration_s for ln in fp.lines if ln.moving)
    assert e["line_s"] == pytest.approx(lines)
    assert e["total_s"] == pytest.approx(e["line_s"] + e["transit_s"] + e["settle_s"] + e["reading_s"]
                                         + e["reference_s"])
    assert fp.checkpoint_before[0] and fp.checkpoint_before[-1]


def test_gonio_plan_reports_both_modes_with_their_bounds(capsys):
    assert main(["plan", "--grid", "iso:step=30"]) == 0
    text = capsys.readouterr().out
    assert "stop-and-go" in text and "fly" in text and "estimate / bound" in text
    assert main(["plan", "--grid", "iso:step=30,order=fly", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["grid"].endswith("order=fly")
    assert 0 < s["fly"]["lower_bound_s"] <= s["fly"]["estimated_s"]
    assert s["fly"]["readings"] == s["poses"]


def test_fly_on_merl_is_refused_naming_the_option(capsys):
    assert main(["plan", "--grid", "merl:stride=8,order=fly"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "order=fly" in err[0] and "merl" in err[0]


def test_gonio_simulate_runs_a_fly_campaign_and_refuses_another_in_its_folder(tmp_path, capsys):
    out = tmp_path / "c"
    args = ["simulate", "lambert:albedo=0.5", "--grid", "iso:step=30,order=fly", "--out", str(out), "--quiet"]
    assert main(args) == 0
    assert (out / "brdf.h5").is_file() and (out / "campaign.sqlite").is_file()
    capsys.readouterr()
    assert main(args[:-1] + ["--seed", "4"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "seed" in err[0]


def test_journal_commits_a_batch_all_or_none(tmp_path):
    from gonio.store import Journal, Measurement

    steps = {"kind": np.zeros(3, np.int8), "pose": np.arange(3), "axes_deg": np.zeros((3, 4)),
             **{f"{a}_deg": np.zeros(3) for a in ("theta_i", "phi_i", "theta_o", "phi_o")}}
    j = Journal.create(tmp_path / "j.sqlite", {"grid": "iso:step=30"}, steps)

    def m(step, shape=(3,)):
        return Measurement(step, 0, step, np.zeros(4), np.zeros(4), np.zeros(4), 1.0 + step, 1.0 + step,
                           0.1, 1, np.ones(3), np.ones(shape))

    with pytest.raises(Exception, match="stderr has shape"):
        j.commit_measurements([m(0), m(1, (2,))])    # the second row is bad: the first is not kept either
    assert j.done_count() == 0
    j.commit_measurements([m(0), m(1)])
    assert j.done_steps().tolist() == [0, 1] and j.next_step() == 2
    j.close()
