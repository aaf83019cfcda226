"""Benchmark: runner + journal overhead per pose, and a whole simulated campaign per pose.

1. Overhead: the poses of a real plan (``iso:step=3``, in plan order) on an *instant* gantry (axes arrive
   at once, the detector returns a constant), so what is timed is the runner's own work (state checks,
   limit checks and the swept-path check of every move, position checks, forward kinematics, halt-aware
   waits) and the journal's commit of each step. Target: under 0.5 ms per pose. Side by side, the same
   run with the swept-path planning replaced by the direct move shows what the safety check costs.
2. The simulated gantry: the same runner on SimGantry (trapezoid axes on the virtual clock, Dr.Jit
   aperture integration per reading), for a few thousand poses, to show where the rest goes.

Run: .venv/bin/python tools/bench_runner.py [--grid iso:step=3]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from gonio.clock import VirtualClock
from gonio.config import load_config
from gonio.kinematics import make_kinematics
from gonio.protocols import Reading
from gonio.runner import Runner, State
from gonio.store import Journal
from gonio.wiring import build_gantry


class _InstantAxis:
    def __init__(self, name, limits, home):
        self.name, self.limits_deg, self._p = name, limits, float(home)

    def connect(self): ...
    def close(self): ...
    def move_to(self, target_deg): self._p = float(target_deg)
    def position_deg(self): return self._p
    def is_moving(self): return False
    def stop(self): ...
    def fault(self): return None
    def clear_fault(self): ...


class _InstantGantry:
    """Protocol-complete gantry with no physics: isolates the runner's and journal's own cost."""

    def __init__(self, cfg):
        self.name = "instant"
        self.kinematics = make_kinematics(cfg)
        self.axes = {a: _InstantAxis(a, (cfg.axes[a].min_deg, cfg.axes[a].max_deg), cfg.axes[a].home_deg)
                     for a in cfg.axis_names}
        self.clock = VirtualClock()
        reading = Reading(signal=np.ones(3), stderr=np.zeros(3), exposure_s=0.1)

        class L:
            name = "light"
            def connect(self): ...
            def close(self): ...
            def set_on(self, on): ...
            def is_on(self): return True

        class D:
            name, channels = "det", ("R", "G", "B")
            def connect(self): ...
            def close(self): ...
            def measure(self, exposure_s, frames=1, *, key=None): return reading

        self.light, self.detector = L(), D()

    def connect(self): ...
    def close(self): ...
    def set_target(self, target): ...
    def stop(self): ...


def _steps(cfg, grid):
    from gonio.campaign import _steps_of
    from gonio.plan import build_plan

    plan = build_plan(grid, cfg)
    return _steps_of(plan, cfg), len(plan.theta_i)


def _time(gantry, cfg, steps, folder):
    j = Journal.create(Path(folder) / "c.sqlite", {"bench": True}, steps)
    r = Runner(gantry, j, cfg)
    t0 = time.perf_counter()
    state = r.run()
    dt = time.perf_counter() - t0
    assert state == State.DONE, r.fault
    j.close()
    return dt


def main() -> None:
    import gonio.executor as executor_module

    ap = argparse.ArgumentParser()
    ap.add_argument("--grid", default="iso:step=3")
    ap.add_argument("--sim-grid", default="iso:step=10")
    args = ap.parse_args()
    cfg = load_config()
    steps, n = _steps(cfg, args.grid)
    with tempfile.TemporaryDirectory() as d:
        dt = _time(_InstantGantry(cfg), cfg, steps, d)
    real = executor_module.safe_path
    executor_module.safe_path = lambda kin, start, target: np.asarray(target, float)[None, :]
    try:
        with tempfile.TemporaryDirectory() as d:
            dt_direct = _time(_InstantGantry(cfg), cfg, steps, d)
    finally:
        executor_module.safe_path = real
    print(f"runner + journal overhead, {args.grid}: {n} poses ({len(steps['kind'])} steps) in {dt:.2f} s = "
          f"{1e3 * dt / n:.3f} ms per pose (target < 0.5 ms); without the swept-path check "
          f"{1e3 * dt_direct / n:.3f} ms per pose, so the check costs {1e3 * (dt - dt_direct) / n:.3f} ms")
    steps, n = _steps(cfg, args.sim_grid)
    with tempfile.TemporaryDirectory() as d:
        g = build_gantry(cfg, "cook-torrance:d=beckmann,m=0.3,metal=gold", seed=1)
        g.connect()
        dt = _time(g, cfg, steps, d)
    print(f"simulated gantry, {args.sim_grid} (trapezoid axes, Dr.Jit apertures, "
          f"{cfg.detector.sim.aperture_samples} samples per reading): {n} poses in {dt:.2f} s = "
          f"{1e3 * dt / n:.2f} ms per pose")


if __name__ == "__main__":
    main()
