"""Benchmarks of planning and motion: build time, ordering time, and how close orders get to the bound.

Prints a Markdown report (paste it into BENCHMARKS.md, "Planning and motion"). Wall-clock times are
printed, never asserted: they depend on the machine and its load.

    .venv/bin/python tools/bench_plan.py            # everything (a few minutes)
    .venv/bin/python tools/bench_plan.py --quick    # skip iso:step=1 and the 20,000-pose tour
    .venv/bin/python tools/bench_plan.py --transit  # iso:step=1 and the swept-path check alone
    .venv/bin/python tools/bench_plan.py --bounds   # valid bound, reference share, gap to the exact optimum
    .venv/bin/python tools/bench_plan.py --exact    # gaps to Held-Karp on 200 subsets per gantry
    .venv/bin/python tools/bench_plan.py --subsets  # worst gap of tours on 8-12 (13-14) pose subsets, windows
    .venv/bin/python tools/bench_plan.py --orders   # serpentine vs tours (kicks, seeds) vs auto; bounds
    .venv/bin/python tools/bench_plan.py --cpu      # CPU s of the parts small plans and the tests lean on
    .venv/bin/python tools/bench_plan.py --digest   # a hash of every array and figure of reference plans

Figures:

- build time of ``build_plan(GRID, cfg)`` on both shipped gantries;
- motion ratio: the plan's pose-to-pose moves (within its runs between white references) over a lower
  bound on those of any order split into runs of the same lengths: the MST without its R - 1 longest
  edges (the degree bound above 25,000 poses); neither side counts the trips to the reference;
- total ratio: ``estimated_s / lower_bound_s`` (all moves, settle, exposures, dark and reference);
- raster ratio: pose-to-pose moves of the plan over those of ``order=raster`` (no serpentine, no tour);
- moves needing via points and runs re-solved because a move collided in transit (each plan's swept-path
  check of every move, :mod:`gonio.plan.transit`); ``--transit`` times ``iso:step=1`` alone;
- the swept-path check of a single move (``Kinematics.sweep_clear_one``, what the runner asks before
  every move, and ``safe_path`` around it) in µs, and the vectorized check per move on a million;
- 20,000 scattered poses: random reachable poses (seeded), nearest neighbour + 2-opt/Or-opt on their
  branches nearest home, timed, against the exact MST (motion only, and with each pose's settle and
  exposure added to both sides).
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from gonio.config import CONFIG_DIR, DEFAULT_CONFIG, load_config
from gonio.kinematics import make_kinematics
from gonio.motion.bound import mst_edge_times, neighbour_times
from gonio.motion.metric import MoveMetric
from gonio.motion.order import improve_tour, nearest_neighbour_tour, neighbour_lists, tour_time
from gonio.motion.refine import walk_costs
from gonio.plan import build_plan

CONFIGS = {"two-arm (sim.toml)": DEFAULT_CONFIG,
           "sample-stage (sample-stage.toml)": DEFAULT_CONFIG.parent / "sample-stage.toml"}


def motion_bound(plan, metric: MoveMetric) -> tuple[float, str]:
    """A lower bound on the pose-to-pose moves of any order of the plan's axis targets split into the
    plan's runs (R paths): the MST without its R - 1 longest edges, or, above 25,000 poses, the degree
    bound with 2R path ends."""
    runs = int(np.count_nonzero(plan.step_kind == 1)) - 1
    if len(plan.theta_i) <= 25_000:
        edges = np.sort(mst_edge_times(plan.axes_deg, metric))
        return float(edges[: len(edges) - (runs - 1)].sum()), "MST"
    nn1, nn2 = neighbour_times(plan.axes_deg, metric)
    return 0.5 * float(np.sum(nn1 + nn2)) - 0.5 * float(np.sort(nn2)[-2 * runs:].sum()), "degree"


def plan_rows(grids, quick: bool) -> list[str]:
    rows = ["| gantry | grid (order) | poses | build s | motion / bound | total est / bound "
            "| motion / raster's | via moves | re-solved runs |",
            "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    print("\n".join(rows), flush=True)
    for name, path in CONFIGS.items():
        cfg = load_config(path)
        kin = make_kinematics(cfg)
        metric = MoveMetric(kin.velocity_deg_s, kin.accel_deg_s2)
        for grid in grids:
            if quick and grid == "iso:step=1":
                continue
            t0 = time.perf_counter()
            plan = build_plan(grid, cfg, kin)
            built = time.perf_counter() - t0
            bound, kind = motion_bound(plan, metric)
            motion = plan.timing["pose_motion_s"]
            raster = ""
            if len(plan.theta_i) <= 200_000:
                rast = build_plan(grid + ",order=raster", cfg, kin)
                raster = f"{motion / rast.timing['pose_motion_s']:.3f}"
            rows.append(f"| {name} | `{grid}` ({plan.order}) | {len(plan.theta_i):,} | {built:.1f} | "
                        f"{motion / bound:.3f} ({kind}) | {plan.estimated_s / plan.lower_bound_s:.3f} | "
                        f"{raster} | {plan.timing['via_moves']} | {plan.timing['resolved_runs']} |")
            print(rows[-1], flush=True)
    return rows


def scattered_rows(n: int, seed: int) -> list[str]:
    rows = ["| gantry | poses | NN s | 2-opt/Or-opt s | MST s | tour / MST (motion) | NN / MST | "
            "tour / MST (with settle + exposure) |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
    print("\n".join(rows), flush=True)
    for name, path in CONFIGS.items():
        cfg = load_config(path)
        kin = make_kinematics(cfg)
        metric = MoveMetric(kin.velocity_deg_s, kin.accel_deg_s2)
        rng = np.random.default_rng(seed)
        tmax = np.radians(cfg.kinematics.theta_max_deg)
        # Directions uniform in solid angle up to theta_max; keep the reachable ones.
        m = 3 * n
        ti = np.arccos(1 - rng.uniform(0, 1 - np.cos(tmax), m))
        to = np.arccos(1 - rng.uniform(0, 1 - np.cos(tmax), m))
        pi_, po = rng.uniform(0, 2 * np.pi, m), rng.uniform(0, 2 * np.pi, m)
        ok = np.flatnonzero(kin.feasibility(ti, pi_, to, po) == 0)[:n]
        pts = kin.inverse(ti[ok], pi_[ok], to[ok], po[ok], current_deg=kin.home_deg)
        depot = kin.home_deg
        t0 = time.perf_counter()
        neigh = neighbour_lists(pts, metric)[0]
        nn = nearest_neighbour_tour(pts, metric, depot, neigh)
        t1 = time.perf_counter()
        tour = improve_tour(pts, nn, metric, depot, neigh)
        t2 = time.perf_counter()
        mst = float(mst_edge_times(pts, metric).sum())
        t3 = time.perf_counter()
        # The tour is closed (depot and back): compare its pose-to-pose part with the MST.
        path = float(np.sum(metric.time(pts[tour[:-1]], pts[tour[1:]])))
        nn_path = float(np.sum(metric.time(pts[nn[:-1]], pts[nn[1:]])))
        assert tour_time(pts, tour, metric, depot) <= tour_time(pts, nn, metric, depot) + 1e-9
        fixed = len(ok) * (cfg.runner.settle_s + cfg.detector.exposure_s * cfg.detector.frames)
        rows.append(f"| {name} | {len(ok):,} | {t1 - t0:.1f} | {t2 - t1:.1f} | {t3 - t2:.1f} | "
                    f"{path / mst:.3f} | {nn_path / mst:.3f} | {(path + fixed) / (mst + fixed):.3f} |")
        print(rows[-1], flush=True)
    return rows


def sweep_rows(seed: int) -> list[str]:
    """Single-move and vectorized costs of the swept-path check on the moves of a real plan."""
    from gonio.motion.safe import safe_path
    from gonio.plan.transit import step_targets

    rows = ["| gantry | sweep_clear_one µs (median of plan moves) | safe_path µs (direct clear) "
            "| sweep_clearance per move, 1e6 moves, µs |", "|---|---:|---:|---:|"]
    print("\n".join(rows), flush=True)
    for name, path in CONFIGS.items():
        cfg = load_config(path)
        kin = make_kinematics(cfg)
        plan = build_plan("iso:step=5", cfg, kin)
        t = step_targets(plan.step_kind, plan.step_pose, plan.axes_deg, plan.reference_axes_deg)
        t = t[~np.isnan(t).any(axis=1)]
        a, b = [r.tolist() for r in t[:-1]], [r.tolist() for r in t[1:]]
        per = []
        for x, y in zip(a, b, strict=True):
            t0 = time.perf_counter()
            kin.sweep_clear_one(x, y)
            per.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        for x, y in zip(t[:-1], t[1:], strict=True):
            safe_path(kin, x, y)
        sp = (time.perf_counter() - t0) / (len(t) - 1)
        rng = np.random.default_rng(seed)
        idx = rng.integers(0, len(t) - 1, 1_000_000)
        t0 = time.perf_counter()
        kin.sweep_clearance(t[idx], t[idx + 1])
        vec = (time.perf_counter() - t0) / idx.size
        rows.append(f"| {name} | {1e6 * float(np.median(per)):.1f} | {1e6 * sp:.1f} | {1e6 * vec:.2f} |")
        print(rows[-1], flush=True)
    return rows


def transit_rows() -> list[str]:
    """``build_plan("iso:step=1")`` with the swept-path check of every move, on both gantries."""
    rows = ["| gantry | poses | moves | build s | via moves | re-solved runs |",
            "|---|---:|---:|---:|---:|---:|"]
    print("\n".join(rows), flush=True)
    for name, path in CONFIGS.items():
        cfg = load_config(path)
        kin = make_kinematics(cfg)
        t0 = time.perf_counter()
        plan = build_plan("iso:step=1", cfg, kin)
        built = time.perf_counter() - t0
        moves = int(np.count_nonzero(plan.step_kind != 1)) + 1
        rows.append(f"| {name} | {len(plan.theta_i):,} | {moves:,} | {built:.1f} | "
                    f"{plan.timing['via_moves']} | {plan.timing['resolved_runs']} |")
        print(rows[-1], flush=True)
    return rows


def _with_reference(cfg, **ref):
    return cfg.model_copy(update={"reference": cfg.reference.model_copy(update=ref)})


def bound_rows() -> None:
    """Estimate over the valid bound (any order, any branches) and over the branch-fixed one, and the
    share of the dark + reference readings, by count (every 50) and by time (every_s equal to the count
    schedule's mean interval, and 300 s)."""
    from gonio.plan.schedule import STEP_REFERENCE
    rows = ["| gantry | grid | references | build s | refs | est / valid bound | est / branch-fixed bound "
            "| reference share |", "|---|---|---|---:|---:|---:|---:|---:|"]
    print("\n".join(rows), flush=True)
    for name, path in CONFIGS.items():
        cfg = load_config(path)
        kin = make_kinematics(cfg)
        for grid in ("iso:step=10", "iso:step=2", "iso:step=1"):
            base = build_plan(grid, cfg, kin)
            mean_s = base.estimated_s / np.count_nonzero(base.step_kind == STEP_REFERENCE)
            schedules = [("every 50 poses", _with_reference(cfg, every=50, every_s=None))]
            if grid != "iso:step=1":
                schedules += [(f"every_s {mean_s:.0f} (same interval)",
                               _with_reference(cfg, every=None, every_s=float(round(mean_s)))),
                              ("every_s 300 (shipped)", _with_reference(cfg, every=None, every_s=300.0))]
            for label, c in schedules:
                t0 = time.perf_counter()
                plan = build_plan(grid, c, kin)
                built = time.perf_counter() - t0
                tm = plan.timing
                row = (f"| {name} | `{grid}` | {label} | {built:.1f} | "
                       f"{np.count_nonzero(plan.step_kind == STEP_REFERENCE):,} | "
                       f"{plan.estimated_s / plan.lower_bound_s:.3f} | "
                       f"{plan.estimated_s / tm['branch_fixed_bound']['total_s']:.3f} | "
                       f"{tm['reference_s'] / plan.estimated_s:.3f} |")
                print(row, flush=True)


def exact_rows(seed: int, subsets: int = 200) -> None:
    """Held-Karp over orders x branches on random 8-10-pose subsets of iso:step=10 plans: how often the
    branch-fixed and the valid bound exceed the optimum, and the gap of NN + 2-opt/Or-opt (with DP
    branches) and of gonio.motion.refine to it."""
    import sys
    from pathlib import Path

    from gonio.motion.bound import motion_lower_bound
    from gonio.motion.chain import free_azimuth
    from gonio.motion.refine import refine_order
    from gonio.motion.relaxed import pose_branches, relaxed_campaign_bound
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "plan"))
    from exact import held_karp

    import gonio.plan.build as build
    print("| gantry | subsets | fixed bound > optimum | valid bound > optimum | optimum / valid bound (mean) "
          "| NN+2-opt gap mean (max) | refined gap mean (max) | refined optimal "
          "| planner's tour gap mean (max) | planner optimal |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for name, path in CONFIGS.items():
        cfg = load_config(path)
        kin = make_kinematics(cfg)
        metric = MoveMetric(kin.velocity_deg_s, kin.accel_deg_s2)
        plan = build_plan("iso:step=10", cfg, kin)
        ang = np.stack([plan.theta_i, plan.phi_i, plan.theta_o, plan.phi_o])
        ref, home = plan.reference_axes_deg, np.asarray(kin.home_deg, float)
        rng = np.random.default_rng(seed)
        old_above = new_above = optimal = 0
        ratio, g_old, g_new, g_plan = [], [], [], []
        for _ in range(subsets):
            idx = rng.choice(ang.shape[1], int(rng.integers(8, 11)), replace=False)
            sols = np.asarray(kin.solutions(*ang[:, idx], current_deg=home))
            opt = held_karp([x[~np.isnan(x[:, 0])] for x in sols], ref, ref, kin.velocity_deg_s,
                            kin.accel_deg_s2)
            lb = relaxed_campaign_bound(sols, free_azimuth(*ang[:, idx]), ref[None], home, metric, 0.0, 0.0,
                                        every=100, run_lengths=[idx.size])["move_s"]
            lb -= 2.0 * float(metric.time(home, ref))
            fixed = motion_lower_bound(plan.axes_deg[idx], ref, [idx.size], metric)["motion_s"]
            old_above += fixed > opt + 1e-9
            new_above += lb > opt + 1e-9
            ratio.append(opt / lb)
            b = pose_branches(sols)
            near = kin.inverse(*ang[:, idx], current_deg=home)
            start = improve_tour(near, nearest_neighbour_tour(near, metric, ref), metric, ref)
            g_old.append(float(walk_costs(b, start[None], ref, ref, metric)[0]) / opt - 1)
            g_new.append(refine_order(b, start, ref, ref, metric)[1] / opt - 1)
            optimal += g_new[-1] < 1e-9
            sub = tuple(ang[:, idx])
            seeds = build._tour_seeds(kin, sub, np.vstack([home, ref[None]]), metric)[:build.TOUR_SEED_TRIALS]
            g_plan.append(min(float(walk_costs(b, build._tour_order(kin, sub, p, nb, ref, home, metric)[None],
                                               ref, ref, metric)[0]) for p, nb in seeds) / opt - 1)
        print(f"| {name} | {subsets} | {old_above} | {new_above} | {np.mean(ratio):.3f} | "
              f"{100 * np.mean(g_old):.1f} % ({100 * np.max(g_old):.1f} %) | "
              f"{100 * np.mean(g_new):.2f} % ({100 * np.max(g_new):.1f} %) | {optimal} | "
              f"{100 * np.mean(g_plan):.2f} % ({100 * np.max(g_plan):.1f} %) | "
              f"{int(np.sum(np.asarray(g_plan) < 1e-9))} |", flush=True)


def _tour_gaps(kin, metric, angles, ref, home, sizes, count, seed, settings, exact_max) -> list[np.ndarray]:
    """Gaps (gonio / optimum - 1) of ``build._tour_order`` on ``count`` random subsets of ``sizes`` poses,
    under each of ``settings`` ((exact shortcut up to, refine kicks, refine window), patched into
    gonio.plan.build for the call), from and back to the reference; the optimum by Held-Karp."""
    import gonio.motion.exact as exact
    import gonio.plan.build as build

    rng = np.random.default_rng(seed)
    gaps = np.zeros((len(settings), count))
    names = ("EXACT_MAX_POSES", "TOUR_REFINE_KICKS", "TOUR_REFINE_WINDOW")
    saved = [getattr(build, x) for x in names], exact.EXACT_MAX_POSES
    exact.EXACT_MAX_POSES = exact_max
    try:
        for j in range(count):
            idx = rng.choice(angles.shape[1], int(rng.integers(sizes[0], sizes[1] + 1)), replace=False)
            sub = tuple(angles[:, idx])
            table = build._branch_table(kin, sub, home, ref)
            optimum = exact.exact_order(table, ref, ref, metric)[1]
            seeds = build._tour_seeds(kin, sub, np.vstack([home, ref[None]]), metric)[:build.TOUR_SEED_TRIALS]
            for i, setting in enumerate(settings):
                for x, value in zip(names, setting, strict=True):
                    setattr(build, x, value)
                orders = np.array([build._tour_order(kin, sub, p, nb, ref, home, metric) for p, nb in seeds])
                gaps[i, j] = float(walk_costs(table, orders, ref, ref, metric).min()) / optimum - 1.0
    finally:
        for x, value in zip(names, saved[0], strict=True):
            setattr(build, x, value)
        exact.EXACT_MAX_POSES = saved[1]
    return list(gaps)


def _gap_cells(g: np.ndarray) -> str:
    return (f"{100 * g.max():.2f} % | {int(np.sum(g > 0.01))} / {int(np.sum(g > 0.03))} | "
            f"{100 * np.median(g):.2f} % | {100 * np.percentile(g, 90):.2f} %")


def _window_gaps(plan, kin, metric, count, seed) -> np.ndarray:
    """Gaps of ``count`` random stretches of 8-12 consecutive poses of the plan (inside one run between
    references) to the Held-Karp optimum over the same poses between the same two positions."""
    from gonio.motion.exact import exact_order
    from gonio.plan.build import _branch_table
    from gonio.plan.schedule import STEP_POSE

    n = plan.theta_i.size
    steps = np.flatnonzero(plan.step_kind == STEP_POSE)
    starts = plan.step_pose[steps[plan.step_kind[steps - 1] != STEP_POSE]]
    ends = np.append(starts[1:], n)
    angles = np.stack([plan.theta_i, plan.phi_i, plan.theta_o, plan.phi_o])
    ref, home, axes = plan.reference_axes_deg, np.asarray(kin.home_deg, float), plan.axes_deg
    rng = np.random.default_rng(seed)
    gaps = np.zeros(count)
    for j in range(count):
        size = int(rng.integers(8, 13))
        run = int(rng.choice(np.flatnonzero(ends - starts >= size)))
        lo = int(rng.integers(starts[run], ends[run] - size + 1))
        hi = lo + size
        before = axes[lo - 1] if lo > starts[run] else ref
        after = axes[hi] if hi < ends[run] else ref
        walk = np.vstack([before, axes[lo:hi], after])
        # The plan's own positions are branches too (a free azimuth stays where the pose before left it).
        table = np.concatenate([_branch_table(kin, tuple(angles[:, lo:hi]), home, ref), axes[lo:hi, None]],
                               axis=1)
        optimum = exact_order(table, before, after, metric)[1]
        gaps[j] = float(np.sum(metric.time(walk[:-1], walk[1:]))) / optimum - 1.0
    return gaps


def subset_rows(seed: int, count: int = 40) -> None:
    """Tours on small pose sets against Held-Karp over orders x branches (gonio.motion.exact), worst
    case first: random 8-12-pose subsets of each grid's reachable poses, ordered by the planner on that
    subset alone (``build._tour_order``: the tour a plan of just those poses gets, from and back to the
    reference), three ways: as shipped (at most 12 poses solved exactly, so 0 by construction), with the
    exact shortcut off (the local search that orders tours of 13-24 poses: nearest neighbour, kicked
    2-opt/Or-opt, then 2-opt/Or-opt priced after the branch choice with TOUR_REFINE_KICKS restarts and
    exact windows), and that search as it was (8 restarts, no windows: the baseline); then 13-14-pose
    subsets (local search as shipped and as it was, Held-Karp raised to 14 poses for the comparison);
    then stretches of 8-12 consecutive poses of the full plan (order=tour) against the optimum between
    the same two positions."""
    import gonio.plan.build as build
    from gonio.plan.grids import enumerate_grid, parse_grid

    shipped = (build.EXACT_MAX_POSES, build.TOUR_REFINE_KICKS, build.TOUR_REFINE_WINDOW)
    search = (1,) + shipped[1:]
    before = (1, 8, 0)
    old = "local search before (8 kicks, no windows)"
    print("| gantry | grid | poses per subset | tour | subsets | worst gap | > 1 % / > 3 % | median "
          "| 90th pct |")
    print("|---|---|---|---|---:|---:|---:|---:|---:|")
    for name, path in CONFIGS.items():
        cfg = load_config(path)
        kin = make_kinematics(cfg)
        metric = MoveMetric(kin.velocity_deg_s, kin.accel_deg_s2)
        home = np.asarray(kin.home_deg, float)
        ref = build._reference_branches(kin, build._reference_angles(cfg), home)
        ref = ref[kin.free_component(ref) == kin.free_component(home)[0]]
        ref = ref[int(np.argmin(metric.time(home, ref)))]
        for grid in ("iso:step=10", "full:step=15"):
            poses = enumerate_grid(parse_grid(grid), cfg.kinematics.theta_max_deg)
            angles = np.stack([poses.theta_i, poses.phi_i, poses.theta_o, poses.phi_o])
            angles = angles[:, kin.feasibility(*angles) == 0]
            labels = ("planner (exact up to 12)", "local search alone", old)
            for label, g in zip(labels, _tour_gaps(kin, metric, angles, ref, home, (8, 12), count, seed,
                                                   (shipped, search, before), 12), strict=True):
                print(f"| {name} | `{grid}` | 8-12 | {label} | {count} | {_gap_cells(g)} |", flush=True)
            labels = ("local search alone", old)
            for label, g in zip(labels, _tour_gaps(kin, metric, angles, ref, home, (13, 14), count // 4, seed,
                                                   (search, before), 14), strict=True):
                print(f"| {name} | `{grid}` | 13-14 | {label} | {count // 4} | {_gap_cells(g)} |", flush=True)
            plan = build_plan(f"{grid},order=tour", cfg, kin)
            g = _window_gaps(plan, kin, metric, count, seed)
            print(f"| {name} | `{grid}` | 8-12 consecutive | the plan's own tour "
                  f"({plan.theta_i.size:,} poses) | {count} | {_gap_cells(g)} |", flush=True)


def order_rows() -> None:
    """Estimate / valid bound per order on the coarse grids, where the serpentine's row ends cost most:
    the serpentine, the tour without kicks (2-opt/Or-opt alone), the tour with them, both on the seeded
    branch sets (shipped), the kicked tour on the branches nearest home (the way before the seeds: the
    baseline), and what ``order=auto`` keeps; then auto's estimate over the bound without the Held-Karp
    Lagrangian (forest and degree bounds only: the bound before); planning seconds of each."""
    import gonio.motion.relaxed as relaxed
    import gonio.plan.build as build

    print("| gantry | grid | poses | serpentine | tour, no kicks | tour, kicked "
          "| kicked, nearest home (before) | auto keeps | auto / bound without Lagrangian (before) "
          "| planning s (serp. / no kicks / kicked / auto) |")
    print("|---|---|---:|---:|---:|---:|---:|---|---:|---|")
    kicks, seeds = build.TOUR_KICKS_PER_POSE, build._tour_seeds

    def nearest_home(kin, angles, _seeds, metric):
        return seeds(kin, angles, np.asarray(kin.home_deg, float)[None], metric)

    for name in ("sim.toml", "sample-stage.toml"):
        cfg = load_config(CONFIG_DIR / name)
        kin = make_kinematics(cfg)
        for grid in ("iso:step=15", "iso:step=10", "iso:step=5", "full:step=15"):
            ratios, secs = [], []
            for order, per_pose in (("serpentine", kicks), ("tour", 0), ("tour", kicks), ("auto", kicks)):
                build.TOUR_KICKS_PER_POSE = per_pose
                t0 = time.perf_counter()
                plan = build.build_plan(f"{grid},order={order}", cfg, kin)
                secs.append(time.perf_counter() - t0)
                ratios.append(plan.estimated_s / plan.lower_bound_s)
            build.TOUR_KICKS_PER_POSE = kicks
            build._tour_seeds = nearest_home
            try:
                before = build.build_plan(f"{grid},order=tour", cfg, kin)
            finally:
                build._tour_seeds = seeds
            steps, relaxed.LAGRANGE_STEPS = relaxed.LAGRANGE_STEPS, 0
            try:
                loose = build.build_plan(f"{grid},order=serpentine", cfg, kin).lower_bound_s
            finally:
                relaxed.LAGRANGE_STEPS = steps
            print(f"| {name.removesuffix('.toml')} | `{grid}` | {plan.theta_i.size:,} | "
                  + " | ".join(f"{r:.3f}" for r in ratios[:3])
                  + f" | {before.estimated_s / plan.lower_bound_s:.3f} | {plan.order} ({ratios[3]:.3f}) | "
                  + f"{plan.estimated_s / loose:.3f} | " + " / ".join(f"{t:.1f}" for t in secs) + " |",
                  flush=True)


def cpu_rows(seed: int) -> None:
    """CPU seconds (``time.process_time``, this process's threads) of what plans of a few poses (adaptive
    rounds, the tests' option matrix) and medium grids spend: whole plans, the branch-priced refinement
    of their 13-24-pose tours, and the valid bound of 8-29-pose sets. Run it against an older tree with
    ``PYTHONPATH=<that tree>`` to compare."""
    from gonio.motion.chain import free_azimuth
    from gonio.motion.refine import refine_order
    from gonio.motion.relaxed import pose_branches, relaxed_campaign_bound
    from gonio.plan.grids import enumerate_grid, parse_grid

    print("| gantry | what | CPU s |\n|---|---|---:|")
    for name, path in CONFIGS.items():
        cfg = load_config(path)
        kin = make_kinematics(cfg)
        metric = MoveMetric(kin.velocity_deg_s, kin.accel_deg_s2)
        for grid in ("iso:step=30,mirror=true", "merl:stride=15", "iso:step=15", "iso:step=10", "iso:step=5"):
            t0 = time.process_time()
            build_plan(grid, cfg, kin)
            print(f"| {name} | build_plan {grid} | {time.process_time() - t0:.2f} |", flush=True)
        poses = enumerate_grid(parse_grid("iso:step=10"), cfg.kinematics.theta_max_deg)
        angles = np.stack([poses.theta_i, poses.phi_i, poses.theta_o, poses.phi_o])
        angles = angles[:, kin.feasibility(*angles) == 0]
        home = np.asarray(kin.home_deg, float)
        rng = np.random.default_rng(seed)
        sets = [rng.choice(angles.shape[1], int(rng.integers(8, 30)), replace=False) for _ in range(50)]
        t_bound = t_refine = 0.0
        for idx in sets:
            sols = np.asarray(kin.solutions(*angles[:, idx], current_deg=home))
            t0 = time.process_time()
            relaxed_campaign_bound(sols, free_azimuth(*angles[:, idx]), home[None], home, metric, 0.1, 0.2,
                                   every=100, run_lengths=[idx.size])
            t1 = time.process_time()
            if idx.size >= 13 and not free_azimuth(*angles[:, idx]).any():
                refine_order(pose_branches(sols), np.arange(idx.size), home, home, metric, kicks=16,
                             window=11)
            t_bound, t_refine = t_bound + t1 - t0, t_refine + time.process_time() - t1
        print(f"| {name} | relaxed_campaign_bound, 50 sets of 8-29 poses | {t_bound:.2f} |")
        print(f"| {name} | refine_order (16 kicks, windows of 11) of those of 13-29 poses | {t_refine:.2f} |",
              flush=True)


DIGEST_GRIDS = ["iso:step=10", "iso:step=5", "full:step=15", "merl:stride=8", "iso:step=15",
                "iso:step=30,mirror=true", "iso:step=20,order=tour", "full:step=20", "iso:step=10,order=auto"]


def plan_digest(plan) -> str:
    """SHA-256 (16 hex digits) of every array, mapping and figure of a plan, in field order: equal
    digests before and after a change meant as a pure speed-up show the plans are the same bit for bit."""
    import hashlib
    from dataclasses import fields

    h = hashlib.sha256()
    for f in fields(plan):
        value = getattr(plan, f.name)
        h.update(f.name.encode())
        if isinstance(value, np.ndarray):
            h.update(np.ascontiguousarray(value).tobytes())
        elif isinstance(value, dict):
            for key in sorted(value, key=str):
                item = value[key]
                h.update(repr(key).encode())
                h.update(np.ascontiguousarray(item).tobytes() if isinstance(item, np.ndarray)
                         else repr(item).encode())
        else:
            h.update(repr(value).encode())
    return h.hexdigest()[:16]


def digest_rows(grids) -> None:
    """One line per gantry and grid: the plan's digest, estimate and bound (diff two trees' outputs)."""
    for name, path in CONFIGS.items():
        cfg = load_config(path)
        kin = make_kinematics(cfg)
        for grid in grids:
            plan = build_plan(grid, cfg, kin)
            print(f"{name}  {grid}  {plan_digest(plan)}  {plan.estimated_s!r}  {plan.lower_bound_s!r}",
                  flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="skip iso:step=1 and use 5,000 scattered poses")
    ap.add_argument("--seed", type=int, default=20240611)
    ap.add_argument("--bounds", action="store_true",
                    help="valid vs branch-fixed bound, reference share by count and by time, "
                         "gap to the exact optimum on 200 subsets, iso:step=1 build time")
    ap.add_argument("--exact", action="store_true",
                    help="only the gaps to the exact optimum on 200 random subsets per gantry")
    ap.add_argument("--subsets", action="store_true",
                    help="worst gap to the exact optimum of tours on 8-12 and 13-14-pose subsets and of "
                         "8-12-pose stretches of full tours")
    ap.add_argument("--orders", action="store_true",
                    help="estimate / bound of the serpentine, the tours (kicks, seeds), auto; the bound "
                         "without the Lagrangian")
    ap.add_argument("--transit", action="store_true",
                    help="only the swept-path figures: iso:step=1 build and the single-move check cost")
    ap.add_argument("--cpu", action="store_true",
                    help="CPU s of small and medium plans, tours' refinement and bounds of small sets")
    ap.add_argument("--digest", nargs="*", metavar="GRID",
                    help="only a digest of every array and figure of these plans on both gantries "
                         f"(default: {', '.join(DIGEST_GRIDS)})")
    args = ap.parse_args()
    if args.digest is not None:
        digest_rows(args.digest or DIGEST_GRIDS)
        return
    print(f"machine: {platform.machine()}, {os.cpu_count()} CPUs, python {platform.python_version()}, "
          f"numpy {np.__version__}; load average at start {os.getloadavg()[0]:.2f}\n")
    if args.bounds:
        bound_rows()
        print()
        exact_rows(args.seed)
        print(f"\nload average at end {os.getloadavg()[0]:.2f}")
        return
    if args.exact:
        exact_rows(args.seed)
        print(f"\nload average at end {os.getloadavg()[0]:.2f}")
        return
    if args.subsets:
        subset_rows(args.seed)
        print(f"\nload average at end {os.getloadavg()[0]:.2f}")
        return
    if args.orders:
        order_rows()
        print(f"\nload average at end {os.getloadavg()[0]:.2f}")
        return
    if args.cpu:
        cpu_rows(args.seed)
        print(f"\nload average at end {os.getloadavg()[0]:.2f}")
        return
    if args.transit:
        transit_rows()
        print()
        sweep_rows(args.seed)
        print(f"\nload average at end {os.getloadavg()[0]:.2f}")
        return
    grids = ["iso:step=15", "iso:step=5", "iso:step=2", "iso:step=1", "full:step=15", "full:step=10",
             "merl:stride=8", "merl:stride=4", "merl:stride=2"]
    plan_rows(grids, args.quick)
    print()
    scattered_rows(5000 if args.quick else 20000, args.seed)
    print()
    sweep_rows(args.seed)
    print(f"\nload average at end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
