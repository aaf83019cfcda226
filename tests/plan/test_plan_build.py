"""Building plans on the real kinematics of both shipped gantries."""

from __future__ import annotations

import json
import tomllib

import numpy as np
import pytest

from gonio.config import DEFAULT_CONFIG, load_config, parse_config
from gonio.kinematics import make_kinematics
from gonio.motion.trapezoid import move_time
from gonio.plan import STEP_DARK, STEP_POSE, STEP_REFERENCE, build_plan, format_plan, plan_summary

CONFIGS = {"two-arm": DEFAULT_CONFIG, "sample-stage": DEFAULT_CONFIG.parent / "sample-stage.toml"}


@pytest.fixture(params=list(CONFIGS))
def cfg(request):
    return load_config(CONFIGS[request.param])


def config_with(path, **changes):
    """A config read from `path` with dotted keys replaced, e.g. {"kinematics.clearance_deg": 30}."""
    data = tomllib.loads(path.read_text())
    for dotted, value in changes.items():
        *parents, key = dotted.split(".")
        node = data
        for p in parents:
            node = node.setdefault(p, {})
        node[key] = value
    return parse_config(data, str(path))


def walk_estimate(plan, cfg):
    """The campaign's duration recomputed step by step from the plan's data, with plain loops."""
    kin = make_kinematics(cfg)
    here = kin.home_deg.copy()
    reading = cfg.detector.exposure_s * cfg.detector.frames
    total = 0.0

    def move(a, b):
        return max(float(move_time(y - x, v, acc))
                   for x, y, v, acc in zip(a, b, kin.velocity_deg_s, kin.accel_deg_s2, strict=True))

    for kind, pose in zip(plan.step_kind, plan.step_pose, strict=True):
        if kind == STEP_DARK:
            total += reading
            continue
        target = plan.axes_deg[pose] if kind == STEP_POSE else plan.reference_axes_deg
        total += move(here, target) + cfg.runner.settle_s + reading
        here = target
    return total + move(here, kin.home_deg)


@pytest.mark.parametrize("grid", ["iso:step=20", "full:step=45", "merl:stride=15", "iso:step=30,mirror=true",
                                  "iso:step=15,reciprocity=false,order=raster"])
def test_plan_is_consistent(cfg, grid, planned):
    kin = make_kinematics(cfg)
    plan = planned(grid, cfg, kin)
    p = len(plan.theta_i)
    assert plan.axes_deg.shape == (p, 4) and plan.reference_axes_deg.shape == (4,)
    # Counts: every pose of the last shortcut stage is either planned or counted infeasible.
    stages = list(plan.counts)
    assert stages[-1] == "feasible" and plan.counts["feasible"] == p
    assert plan.counts[stages[-2]] == p + sum(plan.infeasible.values())
    assert all(v > 0 for v in plan.infeasible.values())
    # Steps: each pose exactly once, in motion order.
    assert plan.step_pose[plan.step_kind == STEP_POSE].tolist() == list(range(p))
    assert np.all(plan.step_pose[plan.step_kind != STEP_POSE] == -1)
    # Axis targets point where the poses say, and are within the limits.
    wi, wo = kin.directions(plan.axes_deg)
    for w, t, f in ((wi, plan.theta_i, plan.phi_i), (wo, plan.theta_o, plan.phi_o)):
        want = np.stack([np.sin(t) * np.cos(f), np.sin(t) * np.sin(f), np.cos(t)], axis=1)
        np.testing.assert_allclose(w, want, atol=1e-9)
    assert np.all(plan.axes_deg >= kin.limits_deg[:, 0] - 1e-9)
    assert np.all(plan.axes_deg <= kin.limits_deg[:, 1] + 1e-9)
    assert np.all(kin.feasibility(plan.theta_i, plan.phi_i, plan.theta_o, plan.phi_o) == 0)
    # The estimate is what walking the steps costs, and the bound is below it.
    assert plan.estimated_s == pytest.approx(walk_estimate(plan, cfg), rel=1e-9)
    assert 0 < plan.lower_bound_s <= plan.estimated_s
    assert plan.grid.startswith(grid.split(":")[0] + ":") and "theta_max=80" in plan.grid


def test_reference_axes_point_at_the_reference_pose(cfg, planned):
    plan = planned("iso:step=15", cfg, make_kinematics(cfg))
    wi, wo = make_kinematics(cfg).directions(plan.reference_axes_deg)
    t, d = np.radians(cfg.reference.theta_o_deg), np.radians(cfg.reference.dphi_deg)
    np.testing.assert_allclose(wi[0], [0, 0, 1], atol=1e-9)  # θi = 0 in sim and sample-stage configs
    np.testing.assert_allclose(wo[0], [np.sin(t) * np.cos(d), np.sin(t) * np.sin(d), np.cos(t)], atol=1e-9)
    kind = plan.step_kind
    assert kind[0] == STEP_DARK and kind[1] == STEP_REFERENCE and kind[-1] == STEP_REFERENCE
    # The shipped configs schedule checkpoints by gantry time: none further apart than every_s.
    assert cfg.reference.every is None and cfg.reference.every_s == 300.0
    gaps = np.diff(plan.step_end_s[kind == STEP_REFERENCE])
    assert gaps.size >= 1 and gaps.max() <= cfg.reference.every_s
    # By count instead: runs of exactly `every` poses, the last one shorter.
    counted = build_plan("iso:step=15", cfg.model_copy(update={"reference": cfg.reference.model_copy(
        update={"every": 50, "every_s": None})}))
    runs = np.diff(np.flatnonzero(counted.step_kind == STEP_DARK)) - 2
    assert runs.max() == 50 and np.all(runs[:-1] == 50)


@pytest.mark.parametrize("grid", ["iso:step=30", "full:step=60"])
def test_reciprocity_plan_holds_one_of_each_pair(cfg, grid):
    on = build_plan(grid, cfg)
    off = build_plan(grid + ",reciprocity=false", cfg)

    def dirs(t, f):
        return [tuple(r) for r in np.round(np.stack([np.sin(t) * np.cos(f), np.sin(t) * np.sin(f), np.cos(t)],
                                                    axis=1), 7).tolist()]

    def pairs(plan, iso):
        if iso:  # rotate to φi = 0: an isotropic sample only sees Δφ
            return set(zip(dirs(plan.theta_i, 0 * plan.phi_i), dirs(plan.theta_o, plan.phi_o - plan.phi_i),
                           strict=True))
        return set(zip(dirs(plan.theta_i, plan.phi_i), dirs(plan.theta_o, plan.phi_o), strict=True))

    iso = grid.startswith("iso")
    kept, every = pairs(on, iso), pairs(off, iso)

    def swap(wi, wo):
        if not iso:
            return wo, wi
        # (θo, θi, −Δφ) with the light back at φ = 0
        ti, to = np.arccos(wi[2]), np.arccos(wo[2])
        dphi = np.arctan2(wo[1], wo[0])
        return (dirs(np.array([to]), np.array([0.0]))[0], dirs(np.array([ti]), np.array([-dphi]))[0])

    for wi, wo in every:
        assert (wi, wo) in kept or swap(wi, wo) in kept
    assert len(kept) == len(on.theta_i) < len(off.theta_i)


def test_serpentine_moves_less_than_raster(cfg, planned):
    serp = planned("iso:step=15,order=serpentine", cfg, make_kinematics(cfg))
    rast = build_plan("iso:step=15,order=raster", cfg)
    assert serp.timing["pose_motion_s"] < rast.timing["pose_motion_s"]
    assert serp.estimated_s < rast.estimated_s
    # The same poses either way.
    def key(p):
        return sorted(zip(np.round(p.theta_i, 9), np.round(p.theta_o, 9), np.round(p.phi_o, 9), strict=True))

    assert key(serp) == key(rast)


def test_merl_grid_uses_a_tour_and_beats_its_raster(cfg, planned):
    tour = planned("merl:stride=15", cfg, make_kinematics(cfg))
    assert tour.order == "tour" and tour.grid.endswith("order=tour")
    rast = build_plan("merl:stride=15,order=raster", cfg)
    assert tour.timing["pose_motion_s"] < rast.timing["pose_motion_s"]


def test_auto_keeps_the_quicker_of_serpentine_and_tour_on_iso_grids(cfg, planned):
    """On iso:step=15 (304 poses) the serpentine ends 8 % over the bound on both gantries; auto plans
    the tour too and keeps it, with the same poses; full grids keep the serpentine."""
    kin = make_kinematics(cfg)
    auto = planned("iso:step=15", cfg, kin)
    serp = planned("iso:step=15,order=serpentine", cfg, kin)
    tour = planned("iso:step=15,order=tour", cfg, kin)
    assert auto.order == "tour" and auto.grid.endswith("order=tour")
    assert auto.estimated_s == tour.estimated_s < serp.estimated_s
    assert tour.estimated_s < serp.estimated_s - 0.01 * serp.lower_bound_s  # 1.031 vs 1.077; 1.048 vs 1.074

    def key(p):
        return sorted(zip(np.round(p.theta_i, 9), np.round(p.theta_o, 9), np.round(p.phi_o, 9), strict=True))

    assert key(auto) == key(serp)
    assert build_plan("full:step=30", cfg).order == "serpentine"


def test_a_tour_is_ordered_on_the_seeded_branches_that_lie_closest_and_the_quickest_plan_kept(cfg):
    """Every seed (home, each reachable reference branch) gives one branch per pose; the tour is ordered
    on the sets that lie closest together and the quickest plan is kept, with its bound shared (the
    same pose set). On the sample stage the branches nearest home mix the two tilt signs: ordering
    on them alone is clearly slower."""
    import gonio.plan.build as build

    seeds, sets, plan, inner = build._tour_seeds, [], build.build_plan, {}

    def counted(*args):
        out = seeds(*args)
        sets.append(len(out))
        return out

    def seeded(*args, **kwargs):   # the plan of each seed, as the tour's own planning made it
        p = plan(*args, **kwargs)
        if kwargs.get("_tour_seed") is not None:
            inner[kwargs["_tour_seed"]] = p
        return p

    build._tour_seeds, build.build_plan = counted, seeded
    try:
        tour = build_plan("iso:step=15,order=tour", cfg)
    finally:
        build._tour_seeds, build.build_plan = seeds, plan
    trials = [build_plan("iso:step=15,order=tour", cfg, _tour_seed=i)
              for i in range(min(sets[0], build.TOUR_SEED_TRIALS))]
    assert tour.estimated_s == min(p.estimated_s for p in trials)
    assert all(p.lower_bound_s == tour.lower_bound_s for p in trials)
    # Each seed's plan within the tour's planning is the one planned alone for that seed.
    assert sorted(inner) == list(range(len(trials))) if len(trials) > 1 else not inner
    for i, p in inner.items():
        np.testing.assert_array_equal(p.axes_deg, trials[i].axes_deg)
        assert p.estimated_s == trials[i].estimated_s
    # several sets within the margin on the sample stage; on the two-arm gantry the next is 2.3 % apart
    assert sets[0] >= 2 if cfg.kinematics.design == "sample-stage" else sets[0] == 1
    # The seed trials against ordering on the branches nearest home (the former way).
    kin = make_kinematics(cfg)
    home = np.asarray(kin.home_deg, float)

    def home_only(kin, angles, _seeds, metric):
        return seeds(kin, angles, home[None], metric)

    build._tour_seeds = home_only
    try:
        near_home = build_plan("iso:step=15,order=tour", cfg)
    finally:
        build._tour_seeds = seeds
    assert tour.estimated_s <= near_home.estimated_s
    if cfg.kinematics.design == "sample-stage":
        assert tour.estimated_s < near_home.estimated_s - 2.0  # 321.1 s against 323.8 s


def test_plans_are_deterministic(cfg):
    a, b = build_plan("merl:stride=20", cfg), build_plan("merl:stride=20", cfg)
    np.testing.assert_array_equal(a.axes_deg, b.axes_deg)
    assert a.estimated_s == b.estimated_s and a.lower_bound_s == b.lower_bound_s


def test_grid_theta_max_above_the_config_counts_as_infeasible():
    cfg = load_config()
    plan = build_plan("iso:step=10,theta_max=90", cfg)
    assert plan.counts["reciprocity"] - plan.counts["feasible"] == sum(plan.infeasible.values())
    assert plan.infeasible["beyond_theta_max"] > 0
    assert np.degrees(max(plan.theta_i.max(), plan.theta_o.max())) <= 80 + 1e-9


@pytest.mark.parametrize("changes, grid, message", [
    # θ in {0, 5, 10}, 72 Δφ: 1·72 (θi < θo off the pole) + 2·37 (θi = θo, Δφ <= 180°) + 3 (pole) = 149
    # poses, all within 20° of each other.
    ({"kinematics.clearance_deg": 30.0}, "iso:step=5,theta_max=10",
     "none of the 149 poses can be reached (mostly occlusion: 149 of 149); the cause is "
     "kinematics.clearance_deg"),
    ({"axes.detector_tilt.min_deg": 85.0, "axes.detector_tilt.max_deg": 90.0,
      "axes.detector_tilt.home_deg": 87.0}, "iso:step=20,theta_max=60",
     "(mostly out_of_reach"),
    ({"reference.theta_o_deg": 85.0}, "iso:step=20",
     "reference pose (reference.theta_i_deg, theta_o_deg, dphi_deg = 0, 85, 180°) cannot be reached: "
     "beyond_theta_max (kinematics.theta_max_deg)"),
])
def test_impossible_plans_name_the_cause(changes, grid, message):
    cfg = config_with(DEFAULT_CONFIG, **changes)
    with pytest.raises(ValueError) as err:
        build_plan(grid, cfg)
    assert message in str(err.value)


def test_tour_is_refused_for_grids_too_large_for_it():
    with pytest.raises(ValueError, match="option 'order=tour' handles at most 50,000 poses, this grid has "
                                         "142,879; use order=serpentine"):
        build_plan("iso:step=2,order=tour", load_config())


def test_summary_and_report(cfg):
    plan = build_plan("iso:step=30", cfg)
    s = plan_summary(plan)
    assert {"poses", "estimated_s", "lower_bound_s", "counts", "infeasible", "grid", "symmetries",
            "steps"} <= set(s)
    assert s["poses"] == len(plan.theta_i)
    assert s["steps"]["total"] == len(plan.step_kind) == sum(s["steps"][k] for k in ("pose", "dark",
                                                                                      "reference"))
    assert s["symmetries"] == {"reciprocity": True, "isotropy": True, "mirror": False}
    json.dumps(s, allow_nan=False)  # strictly JSON
    text = format_plan(plan)
    h = int(round(plan.estimated_s))
    assert f"{h // 3600}:{h % 3600 // 60:02d}:{h % 60:02d}" in text
    assert f"{plan.estimated_s:,.1f} s" in text and f"{plan.lower_bound_s:,.1f} s" in text
    for stage, count in plan.counts.items():
        assert stage in text and f"{count:,}" in text
    for reason, count in plan.infeasible.items():
        assert reason in text and f"{count:,}" in text


def test_the_valid_bound_of_a_pose_set_is_computed_once_per_kinematics(monkeypatch):
    """Orders of the same poses share the bound (it does not depend on the order): computed once for a
    kinematics, the same figures to the last digit as a fresh computation, and a caller's copy."""
    import gonio.plan.build as build

    calls = []
    real = build.relaxed_campaign_bound
    monkeypatch.setattr(build, "relaxed_campaign_bound", lambda *a, **k: calls.append(1) or real(*a, **k))
    cfg = load_config(CONFIGS["sample-stage"])
    kin = make_kinematics(cfg)
    plans = [build_plan(f"iso:step=30,order={order}", cfg, kin) for order in ("serpentine", "raster", "tour")]
    assert len(calls) == 1
    plans[0].timing["lower_bound"]["total_s"] = -1.0       # the caller's own copy
    fresh = build_plan("iso:step=30,order=raster", cfg, make_kinematics(cfg))
    assert len(calls) == 2                                  # another kinematics: computed again
    for p in plans[1:]:
        assert p.timing["lower_bound"] == fresh.timing["lower_bound"]
        assert p.lower_bound_s == fresh.lower_bound_s
    build_plan("iso:step=45", cfg, kin)                      # other poses: their own bound
    assert len(calls) == 3
