"""Benchmark: CPU time of planning a few grids, and a digest of every array of each plan.

The digest lets two versions of the planner be compared: a change meant only to make planning faster must
print the same digests (the same poses, order, branches, schedule and estimate, bit for bit). CPU time
(``time.process_time``, the median of ``--repeat`` builds) is what a busy machine inflates least.

Run: .venv/bin/python tools/bench_tour.py [--repeat 3]
"""

from __future__ import annotations

import argparse
import hashlib
import statistics
import time

import numpy as np

from gonio.config import load_config
from gonio.kinematics import make_kinematics
from gonio.plan import build_plan

CASES = (("sim", "iso:step=10"), ("sim", "iso:step=15,reciprocity=false"), ("sample-stage", "iso:step=15"))


def digest(plan) -> str:
    h = hashlib.sha256()
    for name, value in sorted(vars(plan).items()):
        if isinstance(value, np.ndarray):
            h.update(name.encode())
            h.update(np.ascontiguousarray(value).tobytes())
    return h.hexdigest()[:16]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    for config, grid in CASES:
        cfg = load_config(config)
        kin = make_kinematics(cfg)
        times, digests = [], set()
        for _ in range(args.repeat):
            t = time.process_time()
            plan = build_plan(grid, cfg, kin)
            times.append(time.process_time() - t)
            digests.add(digest(plan))
        assert len(digests) == 1, f"{config} {grid}: the plan differs between builds"
        median, least = statistics.median(times), min(times)
        print(f"{config:13s} {grid:32s} CPU median {median:6.2f} s, least {least:6.2f} s"
              f"  digest {digests.pop()}",
              flush=True)


if __name__ == "__main__":
    main()
