"""Benchmark: runner + journal overhead per pose, and a whole simulated campaign per pose.

1. Overhead: 20,000 poses on an *instant* gantry (axes arrive at once, the detector returns a constant),
   so what is timed is the runner's own work (state checks, move bookkeeping, position checks, forward
   kinematics) and the journal's commit of each step. Target: under 0.5 ms per pose.
2. The simulated gantry: the same runner on SimGantry (trapezoid axes on the virtual clock, Dr.Jit
   aperture integration per reading), for a few thousand poses, to show where the rest goes.

Run: .venv/bin/python tools/bench_runner.py [--poses 20000]
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
    def __init__(self, name, limits):
        self.name, self.limits_deg, self._p = name, limits, 0.0

    def connect(self): ...
    def close(self): ...
    def move_to(self, target_deg): self._p = float(target_deg)
    def position_deg(self): return self._p
    def is_moving(self): return False
    def stop(self): ...


class _InstantGantry:
    """Protocol-complete gantry with no physics: isolates the runner's and journal's own cost."""

    def __init__(self, cfg):
        self.name = "instant"
        self.kinematics = make_kinematics(cfg)
        self.axes = {a: _InstantAxis(a, (cfg.axes[a].min_deg, cfg.axes[a].max_deg)) for a in cfg.axis_names}
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
            def measure(self, exposure_s, frames=1): return reading

        self.light, self.detector = L(), D()

    def connect(self): ...
    def close(self): ...
    def set_target(self, target): ...
    def stop(self): ...
    def park(self): ...


def _steps(cfg, n_poses, every):
    kin = make_kinematics(cfg)
    rng = np.random.default_rng(0)
    ti, to = rng.uniform(0, np.radians(70), n_poses), rng.uniform(0, np.radians(70), n_poses)
    po = rng.uniform(np.radians(30), np.radians(330), n_poses)
    axes = kin.inverse(ti, np.zeros(n_poses), to, po)
    keep = ~np.isnan(axes).any(axis=1)
    axes, n = axes[keep], int(keep.sum())
    kind, pose = [], []
    for p in range(n):
        if p % every == 0:
            kind += [1, 2]
            pose += [-1, -1]
        kind.append(0)
        pose.append(p)
    kind, pose = np.array(kind, np.int8), np.array(pose)
    ax = np.where(pose[:, None] >= 0, axes[np.maximum(pose, 0)], kin.home_deg)
    z = np.zeros(len(kind))
    return {"kind": kind, "pose": pose, "theta_i_deg": z, "phi_i_deg": z, "theta_o_deg": z, "phi_o_deg": z,
            "axes_deg": ax}, n


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
    ap = argparse.ArgumentParser()
    ap.add_argument("--poses", type=int, default=20000)
    ap.add_argument("--sim-poses", type=int, default=2000)
    args = ap.parse_args()
    cfg = load_config()
    steps, n = _steps(cfg, args.poses, cfg.reference.every)
    with tempfile.TemporaryDirectory() as d:
        dt = _time(_InstantGantry(cfg), cfg, steps, d)
    print(f"runner + journal overhead: {n} poses ({len(steps['kind'])} steps) in {dt:.2f} s = "
          f"{1e3 * dt / n:.3f} ms per pose (target < 0.5 ms)")
    steps, n = _steps(cfg, args.sim_poses, cfg.reference.every)
    with tempfile.TemporaryDirectory() as d:
        g = build_gantry(cfg, "cook-torrance:d=beckmann,m=0.3,metal=gold", seed=1)
        g.connect()
        dt = _time(g, cfg, steps, d)
    print(f"simulated gantry (trapezoid axes, Dr.Jit apertures, {cfg.detector.sim.aperture_samples} samples "
          f"per reading): {n} poses in {dt:.2f} s = {1e3 * dt / n:.2f} ms per pose")


if __name__ == "__main__":
    main()
