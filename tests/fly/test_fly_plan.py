"""Fly plans: lines of the grid swept rest to rest at top speed, checked, estimated and bounded."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from gonio.cli import main
from gonio.config import load_config
from gonio.kinematics import make_kinematics
from gonio.motion.metric import MoveMetric
from gonio.motion.trapezoid import move_time
from gonio.plan import build_plan
from gonio.plan.fly import (
    FLY_DUTY,
    FlyPlan,
    _bound,
    _entries_nearest,
    _entries_pairwise,
    _least_traverse_s,
    _schedule,
    fly_plan,
    physical_floor,
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


def test_readings_at_their_poses_never_faster_than_the_top_speed(two_arm):
    cfg, kin, plan, fp = two_arm
    for ln in (ln for ln in fp.lines if ln.moving):
        mid = ln.mid_times()
        assert np.allclose(ln.position_at(mid), ln.readings_deg(), atol=1e-9)
        # Every exposure lies in the line's time, none overlaps the next, and during each the axis is
        # never faster than the line's top speed (the blur bound); long lines reach it.
        e = ln.exposure_s
        assert mid[0] - e / 2 >= -1e-12 and mid[-1] + e / 2 <= ln.duration_s + 1e-12
        assert np.all(np.diff(mid) >= e - 1e-12)
        t = mid[:, None] + e * np.linspace(-0.5, 0.5, 9)[None, :]
        h = 1e-6
        v = np.abs(ln.position_at(t + h) - ln.position_at(t - h))[..., ln.axis] / (2 * h)
        assert v.max() <= ln.speed_deg_s * (1 + 1e-6)
        if ln.span_deg > ln.speed_deg_s**2 / ln.accel_deg_s2:
            assert v.max() == pytest.approx(ln.speed_deg_s, rel=1e-6)
        # Rest to rest between its end poses, at most a_max on the way.
        assert np.allclose(ln.position_at([0.0, ln.duration_s]), [ln.start_deg, ln.end_deg], atol=1e-9)
        ts = np.linspace(0.0, ln.duration_s, 400)
        x = ln.position_at(ts)[:, ln.axis]
        acc = np.abs(np.diff(x, 2)) / (ts[1] - ts[0]) ** 2
        assert acc.max() <= ln.accel_deg_s2 * (1 + 1e-6)
        assert np.allclose(ln.time_at(ln.readings_deg()[:, ln.axis]), mid, atol=1e-9)


def _turnaround_path(fp, kin, k, samples=400):
    """Positions (samples, A) and times of the swept turnaround into line k, from line k − 1's last
    reading to line k's first, computed independently: the sweeping axis on the lines' own profiles,
    the other axes on their rest-to-rest trapezoids from the end of the last exposure."""
    from gonio.motion.trapezoid import position_at

    p, q = fp.lines[k - 1], fp.lines[k]
    t0 = fp.line_start_s[k - 1] + p.mid_times()[-1]
    t1 = fp.line_start_s[k] + q.mid_times()[0]
    ts = np.linspace(t0, t1, samples)
    a, b = p.readings_deg()[-1], q.first_deg
    v, acc = np.asarray(kin.velocity_deg_s), np.asarray(kin.accel_deg_s2)
    begin = t0 + 0.5 * p.exposure_s
    out = np.empty((samples, a.size))
    for i, t in enumerate(ts):
        here = p.position_at(t - fp.line_start_s[k - 1]) if t < fp.line_start_s[k] else \
            q.position_at(t - fp.line_start_s[k])
        for x in range(a.size):
            if x != p.axis:
                here[x] = position_at(max(t - begin, 0.0), a[x], b[x], v[x], acc[x])
        out[i] = here
    return ts, out


def test_turnarounds_are_swept_certified_and_hide_the_change(two_arm):
    cfg, kin, plan, fp = two_arm
    turns = [k for k in range(len(fp.lines)) if fp.swept_turn(k)]
    assert len(turns) > 10 and fp.timing["estimate"]["turnarounds"] == len(turns)
    v, acc = np.asarray(kin.velocity_deg_s), np.asarray(kin.accel_deg_s2)
    lo, hi = np.asarray(kin.limits_deg).T
    for k in turns:
        p, q = fp.lines[k - 1], fp.lines[k]
        assert p.axis == q.axis and p.step_deg * q.step_deg < 0 and p.tail == q.lead > 0
        assert p.end_deg[p.axis] == pytest.approx(q.start_deg[q.axis], abs=1e-12)
        # The change of the other axes, begun when p's last exposure ends, is over when q's first begins,
        # and q starts once p has come to rest.
        change = np.delete(move_time(np.abs(q.first_deg - p.readings_deg()[-1]), v, acc), p.axis).max()
        assert fp.cross[k] == pytest.approx(change)
        p_end = fp.line_start_s[k - 1] + p.mid_times()[-1] + 0.5 * p.exposure_s
        q_begin = fp.line_start_s[k] + q.mid_times()[0] - 0.5 * q.exposure_s
        assert q_begin - p_end >= change - 1e-9
        assert fp.line_start_s[k] >= fp.line_start_s[k - 1] + p.duration_s - 1e-9
        # Every position on the way, sampled independently of the planner's box check, is clear.
        _, path = _turnaround_path(fp, kin, k)
        assert np.all((path >= lo - 1e-9) & (path <= hi + 1e-9))
        assert all(kin.sweep_clear_one(x, x)[0] for x in path[::8])
        # Swept, the two lines take less time than run rest to rest with the change between them.
        swept = fp.line_start_s[k] - fp.line_start_s[k - 1] + q.duration_s
        assert swept < replace(p, tail=0.0).duration_s + change + replace(q, lead=0.0).duration_s - 0.05


@pytest.mark.parametrize("name", ["sim", "sample-stage"])
def test_box_clear_is_never_wrong_about_a_colliding_box(name):
    """A box certified clear has no colliding or out-of-limit position among 9^4 on a grid through it
    (the two-arm check is exact: it also certifies boxes that touch the other carriage's clearance)."""
    kin = make_kinematics(load_config(name))
    rng = np.random.default_rng(3)
    lo_lim, hi_lim = np.asarray(kin.limits_deg).T
    certified = refused = 0
    for _ in range(80):
        centre = rng.uniform(lo_lim, hi_lim)
        half = rng.uniform(0.0, 15.0, size=centre.size)
        lo, hi = centre - half, centre + half
        grid = np.stack(np.meshgrid(*[np.linspace(a, b, 9) for a, b in zip(lo, hi, strict=True)]),
                        axis=-1).reshape(-1, centre.size)
        # Every position at rest, checked at once (sweep_clearance is sweep_clear_one vectorized: the
        # kinematics tests hold them equal).
        truth = bool(kin.sweep_clearance(grid, grid)[0].all())
        if kin.box_clear(lo, hi):
            certified += 1
            assert truth
        else:
            refused += 1
    assert certified > 5 and refused > 5


def test_least_traverse_time():
    v, a = 60.0, 120.0
    for d in (0.5, 5.0, 29.9, 30.0, 175.0):
        assert _least_traverse_s(d, v, a, 0.0, 0.0) == pytest.approx(float(move_time(d, v, a)))
        assert _least_traverse_s(d, v, a, v, v) == pytest.approx(d / v)
        # From v, slowing to a stop at the end: the last stretch is a deceleration from the speed there.
        t = _least_traverse_s(d, v, a, v, 0.0)
        assert d / v < t < float(move_time(d, v, a))
        mid = _least_traverse_s(d, v, a, 20.0, 40.0)
        assert _least_traverse_s(d, v, a, v, v) <= mid <= _least_traverse_s(d, v, a, 0.0, 0.0)
        assert mid == pytest.approx(_least_traverse_s(d, v, a, 40.0, 20.0))


def test_physical_floor_sweeps_every_dphi_step_once_at_top_speed(two_arm):
    cfg, kin, plan, fp = two_arm
    floor, steps = physical_floor(plan, kin)
    # On the two-arm gantry a Δφ step of 10° turns one azimuth carriage (60°/s): 1/6 s each.
    assert floor == pytest.approx(steps * 10.0 / 60.0)
    # Recounted here: per ring off the poles, its Δφ values one step apart around the circle.
    ti, to = (np.round(np.degrees(x), 6) for x in (plan.theta_i, plan.theta_o))
    dphi = np.round(np.mod(np.degrees(plan.phi_o - plan.phi_i), 360.0), 6) % 360.0
    count = 0
    for ring in {(a, b) for a, b in zip(ti, to, strict=True) if a > 0 and b > 0}:
        d = np.sort(dphi[(ti == ring[0]) & (to == ring[1])])
        gaps = np.mod(np.roll(d, -1) - d, 360.0)
        count += int(np.sum(np.abs(gaps - 10.0) < 1e-6)) - (1 if d.size == 2 else 0)
    assert steps == count
    assert fp.lower_bound_s > floor and fp.estimated_s < 1.5 * floor
    # A full grid can be swept along Δφ or along φ: Δφ arcs bound nothing there.
    full = build_plan("full:step=45,order=fly", cfg)
    with pytest.raises(ValueError, match="iso grids"):
        physical_floor(full, kin)


def test_no_pose_read_stop_and_go_or_slowed_for_want_of_room(two_arm):
    cfg, kin, plan, fp = two_arm
    # Rings at Δφ = 10° start against the light's carriage (arm_collision_deg = 10°) and end near the
    # azimuth limit: their lines start at rest on their first pose, at the top speed between the ends.
    assert fp.timing["stop_and_go_readings"] == sum(1 for ln in fp.lines if not ln.moving)
    for ln in fp.lines:
        if ln.moving:
            assert ln.speed_deg_s == kin.velocity_deg_s[ln.axis]
            # At rest on its first pose, or its run-up within a turnaround's run-out, and at the end.
            sign = np.sign(ln.step_deg)
            assert np.allclose(ln.start_deg + sign * ln.lead * (np.arange(4) == ln.axis),
                               plan.axes_deg[ln.poses[0]], atol=1e-12)
            assert np.allclose(ln.end_deg - sign * ln.tail * (np.arange(4) == ln.axis),
                               ln.readings_deg()[-1], atol=1e-12)
    against = [ln for ln in fp.lines if ln.moving and ln.axis == 2
               and abs(abs(ln.readings_deg()[:, 2] - ln.first_deg[0]).min() - 10.0) < 1e-9]
    assert against
    # Every pose off the poles is swept: only poses that start no run are read stop-and-go.
    stills = [ln for ln in fp.lines if not ln.moving]
    assert len(stills) < 0.02 * len(plan.theta_i)


def test_fine_steps_sweep_rings_that_start_at_the_other_carriage():
    # At step 1 a ring starting at the other carriage has no room for a run-up: it is swept from rest.
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
    moves = np.array([np.arange(4) == ln.axis for ln in fp.lines])
    rest = np.stack([fp.reference_deg, fp.home_deg])
    v, a = np.asarray(kin.velocity_deg_s), np.asarray(kin.accel_deg_s2)
    pairwise = _entries_pairwise(ends, moves, rest, v, a)
    assert np.allclose(_entries_nearest(ends, moves, rest, v, a), pairwise, rtol=0, atol=1e-12)


def test_estimate_adds_up_its_parts(two_arm):
    cfg, kin, plan, fp = two_arm
    e = fp.timing["estimate"]
    lines = sum(ln.duration_s for ln in fp.lines if ln.moving)
    assert e["line_s"] == pytest.approx(lines)
    assert e["total_s"] == pytest.approx(e["line_s"] + e["transit_s"] + e["turn_s"] + e["settle_s"]
                                         + e["reading_s"] + e["reference_s"])
    assert fp.checkpoint_before[0] and fp.checkpoint_before[-1]


def test_gonio_plan_reports_both_modes_with_their_bounds(capsys):
    assert main(["plan", "--grid", "iso:step=30"]) == 0
    text = capsys.readouterr().out
    assert "stop-and-go" in text and "fly" in text and "estimate / bound" in text
    assert "swept turnarounds" in text
    assert main(["plan", "--grid", "iso:step=30,order=fly", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["grid"].endswith("order=fly")
    assert 0 < s["fly"]["lower_bound_s"] <= s["fly"]["estimated_s"]
    assert s["fly"]["readings"] == s["poses"]
    assert s["fly"]["motion"] == 2 and s["fly"]["coordinated_lines"] == 0
    assert s["fly"]["estimate"]["turnarounds"] >= 1


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
