"""Fly scanning against stop-and-go: gantry time, bounds, planning time, and a whole simulated fly campaign.

For ``--grid`` (default ``iso:step=2``) on the default two-arm gantry: the stop-and-go plan (its estimate
and valid lower bound) and the fly plan over the same poses (:mod:`gonio.plan.fly`: estimate and its
bound), the planning wall time of each; then, for each material, a whole simulated fly campaign
(:class:`gonio.sim.fly.FlySimulator` over every sweep and checkpoint, calibrated with
:func:`gonio.calibrate.calibrate`): its gantry time (the campaign clock at the end, home included), the
wall time, the median and 95th percentile relative error against the material's own eval at the
measured angles, and the blur term's share of the stated stddev. ``--plan-only GRID`` adds the planning
times of another grid (e.g. ``iso:step=1``) without simulating it.

``--sharp-only`` prints only the z-scores of fly readings through sharp specular peaks (the blur term of
the stated stddev; also printed after the campaigns).

``--table`` prints, per grid and design (``iso:step=5`` and ``iso:step=2`` on the default two-arm gantry,
``iso:step=5`` and ``full:step=5`` on the sample stage; ``--table-grids CONFIG:GRID;...`` for others):
the physical floor (:func:`gonio.plan.fly.physical_floor`: every Δφ step swept once at top speed, no
stops; iso grids only), the fly bound, the fly estimate, the stop-and-go estimate, and the ratios; then
whether a simulated fly campaign's gantry time (``--sim``: the campaign clock of :class:`FlySimulator` at
the end, home included) equals the estimate.

Run: ``.venv/bin/python tools/bench_fly.py [--grid iso:step=2] [--plan-only iso:step=1] [--sharp-only]
[--table [--sim]]``; print ``uptime`` beside the figures (the machine is shared).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from gonio.calibrate import calibrate
from gonio.config import load_config
from gonio.geometry import sph_to_vec
from gonio.kinematics import make_kinematics
from gonio.plan import build_plan
from gonio.plan.fly import fly_plan, physical_floor
from gonio.plan.report import hms
from gonio.sim import materials
from gonio.sim.fly import FlySimulator

MATERIALS = ("lambert:albedo=0.5", "ward:rho_d=0.1,rho_s=0.05,alpha_x=0.1,alpha_y=0.3",
             "cook-torrance:d=beckmann,m=0.3,metal=gold")


def _plans(grid: str, cfg):
    t0 = time.perf_counter()
    plan = build_plan(grid, cfg)
    t1 = time.perf_counter()
    fp = fly_plan(plan, cfg)
    t2 = time.perf_counter()
    return plan, fp, t1 - t0, t2 - t1


def _report_plans(grid, plan, fp, t_plan, t_fly):
    print(f"{grid}: {len(plan.theta_i):,} poses")
    print(f"  stop-and-go  estimate {hms(plan.estimated_s)} ({plan.estimated_s:,.0f} s)  bound "
          f"{plan.lower_bound_s:,.0f} s  (estimate/bound {plan.estimated_s / plan.lower_bound_s:.3f})  "
          f"planned in {t_plan:.1f} s")
    print(f"  fly          estimate {hms(fp.estimated_s)} ({fp.estimated_s:,.0f} s)  bound "
          f"{fp.lower_bound_s:,.0f} s  (estimate/bound {fp.estimated_s / fp.lower_bound_s:.3f})  "
          f"planned in {t_fly:.1f} s more")
    print(f"  fly: {fp.timing['lines']:,} lines, {fp.timing['stop_and_go_readings']:,} stop-and-go readings, "
          f"{fp.timing['checkpoints']:,} checkpoints; gantry time {plan.estimated_s / fp.estimated_s:.1f}x "
          "less than stop-and-go")


def _sharp_peaks(cfg, spec: str = "ward:rho_d=0.1,rho_s=0.2,alpha=0.02", seeds=range(4)) -> None:
    """z-scores of fly readings through sharp specular peaks (Δφ sweeps at θi = θo = 30, 50, 70°, the
    speed and exposure of iso:step=2, the peak on a reading and between two) against what a stop-and-go
    reading of the same pose sees, over ``seeds``; and over the readings whose blur (the mean over the
    exposure's path against the value at the pose) exceeds their noise."""
    from gonio.plan.fly import FLY_DUTY, FlyLine
    from gonio.sim.aperture import aperture_radiance_factor

    m = materials.load(spec)
    src, det = cfg.light.sim.half_angle_deg, cfg.detector.sim.half_angle_deg
    z, big, loss = [], [], []
    for theta in (30.0, 50.0, 70.0):
        for start in (160.0, 161.0):
            line = FlyLine(np.arange(21), 2, np.array([0.0, theta, start, theta]), 2.0, 60.0, 120.0,
                           FLY_DUTY * 2.0 / 60.0)
            sims = [FlySimulator(cfg, spec, seed=s) for s in seeds]
            kin = sims[0].kin
            at = kin.directions(line.readings_deg())
            mid = aperture_radiance_factor(m, *at, src, det, 16384, (9, 0))[0]
            times = line.mid_times()[:, None] + line.exposure_s * ((np.arange(32) + 0.5) / 32 - 0.5)
            wi, wo = kin.directions(line.position_at(times).reshape(-1, 4))
            path = aperture_radiance_factor(m, wi, wo, src, det, 2048, (9, 1))[0].reshape(21, 32, -1).mean(1)
            if start == 160.0:
                loss.append(path[10, 1] / mid[10, 1] - 1.0)
            scale = cfg.light.sim.radiance * line.exposure_s
            for sim in sims:
                ms = sim.sweep(line, 0.0, int(theta))
                value, sd = (np.stack([getattr(x, k) for x in ms]) / scale for k in ("signal", "stderr"))
                noise = np.stack([x.extra["stderr_integration"] for x in ms]) / scale
                z.append((value - mid) / sd)
                big.append(np.abs(path - mid) > noise)
    z, big = np.concatenate(z).ravel(), np.concatenate(big).ravel()
    rms, rms_big = np.sqrt(np.mean(z**2)), np.sqrt(np.mean(z[big] ** 2))
    print(f"  sharp peaks ({spec}, 1° of travel per exposure, seeds {seeds.start}-{seeds.stop - 1}): "
          f"z-scores against the stop-and-go reading of the same pose: {z.size} values, rms {rms:.2f}, "
          f"max |z| {np.abs(z).max():.2f}, {100 * np.mean(np.abs(z) < 2):.0f} % within 2; where the blur "
          f"exceeds the noise ({big.sum()} values) rms {rms_big:.2f}, max |z| {np.abs(z[big]).max():.2f}; "
          "blur loss at the peak " + ", ".join(f"{100 * x:+.1f} %" for x in loss))


TABLE = "sim:iso:step=5;sim:iso:step=2;sample-stage:iso:step=5;sample-stage:full:step=5"


def _table(items: str, simulate: bool) -> None:
    """The floor / bound / estimate / stop-and-go table (see the module docstring)."""
    print("| design (config) | grid | poses | floor | fly bound | fly estimate | stop-and-go | fly / bound | "
          "fly / floor | stop-and-go / fly | lines (turnarounds swept) | stop-and-go readings | planning |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for item in items.split(";"):
        name, grid = item.split(":", 1)
        cfg = load_config(name)
        grid = grid if "order=" in grid else grid + ",order=fly"
        plan, fp, t_plan, t_fly = _plans(grid, cfg)
        try:
            floor, _ = physical_floor(plan, make_kinematics(cfg))
        except ValueError:   # defined for iso grids only
            floor = float("nan")
        turns = fp.timing["estimate"]["turnarounds"]
        print(f"| {cfg.kinematics.design} ({name}) | `{grid}` | {len(plan.theta_i):,} | "
              f"{'-' if floor != floor else f'{floor:,.0f} s'} | "
              f"{fp.lower_bound_s:,.0f} s | {fp.estimated_s:,.0f} s | {plan.estimated_s:,.0f} s | "
              f"{fp.estimated_s / fp.lower_bound_s:.3f} | "
              f"{'-' if floor != floor else f'{fp.estimated_s / floor:.3f}'} | "
              f"{plan.estimated_s / fp.estimated_s:.2f} | {fp.timing['lines']:,} ({turns:,}) | "
              f"{fp.timing['stop_and_go_readings']:,} | {t_plan:.1f} + {t_fly:.1f} s |")
        if simulate:
            ms = FlySimulator(cfg, "lambert:albedo=0.5", seed=1).campaign(fp)
            end = ms[-1].campaign_s + (fp.estimated_s - fp.checkpoints[-1][3] - fp.reading_s)
            print(f"|  | simulated campaign: gantry time {end:,.3f} s against the estimate "
                  f"{fp.estimated_s:,.3f} s ({end - fp.estimated_s:+.2e} s) |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grid", default="iso:step=2")
    ap.add_argument("--plan-only", default=None)
    ap.add_argument("--sharp-only", action="store_true", help="only the z-scores through sharp peaks")
    ap.add_argument("--table", action="store_true", help="only the floor/bound/estimate table")
    ap.add_argument("--table-grids", default=TABLE, help="CONFIG:GRID;... for --table")
    ap.add_argument("--sim", action="store_true", help="with --table: simulate each fly campaign")
    args = ap.parse_args()
    if args.table:
        _table(args.table_grids, args.sim)
        return
    cfg = load_config(None)
    if args.sharp_only:
        _sharp_peaks(cfg)
        return
    grid = args.grid if "order=" in args.grid else args.grid + ",order=fly"
    plan, fp, t_plan, t_fly = _plans(grid, cfg)
    _report_plans(grid, plan, fp, t_plan, t_fly)
    for spec in MATERIALS:
        t0 = time.perf_counter()
        ms = FlySimulator(cfg, spec, seed=1).campaign(fp)
        t1 = time.perf_counter()
        cal = calibrate(ms, cfg.reference.albedo)
        a = np.radians(cal.angles_deg)
        truth = materials.load(spec).eval(sph_to_vec(a[:, 0], a[:, 1]), sph_to_vec(a[:, 2], a[:, 3]))
        ok = truth > 1e-3 * truth.max()
        rel = np.abs(cal.value - truth)[ok] / truth[ok]
        poses = [m for m in ms if m.kind == 0]
        blur = np.stack([m.extra["stderr_blur"] for m in poses])
        se = np.stack([m.stderr for m in poses])
        share = blur[se > 0] / se[se > 0]
        # The campaign clock at the end of the last reading, plus the move home the plan ends with.
        end = ms[-1].campaign_s + (fp.estimated_s - fp.checkpoints[-1][3] - fp.reading_s)
        print(f"  {spec}: {len(cal.value):,} samples, simulated gantry time {hms(end)} ({end:,.0f} s, "
              f"{plan.estimated_s / end:.1f}x less than stop-and-go), wall {t1 - t0:.1f} s; median error "
              f"{100 * np.median(rel):.3f} %, 95th pct {100 * np.percentile(rel, 95):.3f} %; blur is "
              f"{100 * np.median(share):.0f} % of stderr (median), {100 * np.percentile(share, 95):.0f} % "
              "(95th pct)")
    _sharp_peaks(cfg)
    if args.plan_only:
        other = args.plan_only if "order=" in args.plan_only else args.plan_only + ",order=fly"
        _report_plans(other, *_plans(other, cfg))


if __name__ == "__main__":
    main()
