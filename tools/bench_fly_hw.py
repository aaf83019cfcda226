"""Fly scanning through the drivers: the emulated two-arm Dynamixel gantry, fly against stop-and-go.

For ``--grid`` (default ``iso:step=15``) on ``emulated-two-arm-dynamixel`` (dynamixel-sdk and pyserial
over ptys to the emulators, on a SyncedVirtualClock, so gantry time is the emulated servos' own), a
stop-and-go campaign and a fly campaign (:mod:`gonio.fly.hardware`) of the same material: each one's
gantry time (the campaign clock at the end, park included) and the plan's estimate, the wall time in
all and per reading (what the drivers, the pty round trips and the emulators' Dr.Jit renders cost per
reading on this machine), the Sync Reads per fly reading and the wall time of one stamped Sync Read and
of one photodiode read, and the fly values against the stop-and-go
ones: z-scores with both stated uncertainties plus the simulated gantry's stop-and-go stddev (the
emulated serial power meter states none of its own).

Run: ``.venv/bin/python tools/bench_fly_hw.py [--grid iso:step=15]``; print ``uptime`` beside the
figures (the machine is shared).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from gonio.campaign import create_campaign
from gonio.config import load_config
from gonio.dataset import read_brdf
from gonio.lifecycle import run_campaign
from gonio.plan.report import hms
from gonio.runner import State
from gonio.sim.emulators.gantry import EmulatedGantry
from gonio.sim.emulators.link import SyncedVirtualClock
from gonio.store import JOURNAL_NAME, Journal
from gonio.wiring import build_gantry

MATERIAL = "cook-torrance:d=beckmann,m=0.3,metal=gold"
TWIN = "emulated-two-arm-dynamixel"


def _campaign(folder: Path, grid: str, fly: bool) -> dict:
    clock = SyncedVirtualClock()
    with EmulatedGantry(load_config(TWIN), MATERIAL, clock=clock, any_port=True, referenced=True) as emu:
        cfg = emu.config()
        c = create_campaign(folder, cfg, grid=grid, material=None, sample="gold")
        reads, spent = [0, 0], [0.0, 0.0]   # stamped Sync Reads, detector reads: count, wall s
        gantry = build_gantry(cfg, clock=clock)
        stamped, measure = gantry.stamped_positions, gantry.detector.measure

        def counted():
            reads[0] += 1
            t = time.perf_counter()
            try:
                return stamped()
            finally:
                spent[0] += time.perf_counter() - t

        def timed(*a, **kw):
            reads[1] += 1
            t = time.perf_counter()
            try:
                return measure(*a, **kw)
            finally:
                spent[1] += time.perf_counter() - t

        gantry.stamped_positions, gantry.detector.measure = counted, timed
        t0 = time.perf_counter()
        state, runner = run_campaign(c, gantry)
        wall = time.perf_counter() - t0
        meta = c.meta
        c.close()
        assert state == State.DONE, runner.fault
    j = Journal.open(folder / JOURNAL_NAME, readonly=True)
    try:
        readings = j.done_count()
    finally:
        j.close()
    return {"gantry_s": runner.campaign_s(), "estimate_s": meta["estimated_s"], "wall_s": wall,
            "readings": readings, "sync_reads": reads[0], "poses": meta["poses"],
            "sync_read_ms": 1e3 * spent[0] / max(reads[0], 1), "detector_reads": reads[1],
            "detector_read_ms": 1e3 * spent[1] / max(reads[1], 1),
            "brdf": read_brdf(folder / "brdf.h5")}


def _rows(b):
    """Sample order by planned pose (θi, θo, Δφ), the same in every campaign of the grid."""
    ti, pi, to, po = b.planned.T
    keys = np.round(np.stack([ti, to, np.mod(po - pi, 360.0)], axis=1), 6)
    return np.lexsort(keys.T[::-1]), keys


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grid", default="iso:step=15")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        sg = _campaign(Path(tmp) / "sg", args.grid, fly=False)
        fly = _campaign(Path(tmp) / "fly", args.grid + ",order=fly", fly=True)
        cfg = load_config("sim")
        c = create_campaign(Path(tmp) / "sim", cfg, grid=args.grid, material=MATERIAL)
        run_campaign(c, build_gantry(cfg, MATERIAL))
        c.close()
        sim = read_brdf(Path(tmp) / "sim" / "brdf.h5")
    print(f"{TWIN}, {args.grid}, {MATERIAL}: {fly['poses']} poses")
    for name, r in (("stop-and-go", sg), ("fly", fly)):
        per_ms = 1e3 * r["wall_s"] / r["readings"]
        print(f"  {name:<12} gantry {hms(r['gantry_s'])} ({r['gantry_s']:.1f} s,"
              f" plan {r['estimate_s']:.0f} s)"
              f"  wall {r['wall_s']:.2f} s for {r['readings']} readings = {per_ms:.1f} ms per reading")
    print(f"  fly / stop-and-go gantry time: {fly['gantry_s'] / sg['gantry_s']:.3f} "
          f"({sg['gantry_s'] / fly['gantry_s']:.2f}x less)")
    per = fly["sync_reads"] / fly["poses"]
    print(f"  fly: {fly['sync_reads']} stamped Sync Reads ({per:.1f} per reading, "
          f"{fly['sync_read_ms']:.2f} ms wall each), {fly['detector_reads']} photodiode reads "
          f"({fly['detector_read_ms']:.1f} ms wall each, the emulator's render included; stop-and-go "
          f"{sg['detector_read_ms']:.1f} ms)")
    a, b, s = fly["brdf"], sg["brdf"], sim
    (ia, ka), (ib, kb), (i_s, ks) = _rows(a), _rows(b), _rows(s)
    assert np.array_equal(ka[ia], kb[ib]) and np.array_equal(ka[ia], ks[i_s])
    va, sa = a.value[ia, 0], a.stddev[ia, 0]
    vb, sd_sim = b.value[ib, 0], s.stddev.mean(axis=1)[i_s]
    sd = np.sqrt(2 * sd_sim**2 + sa**2 + b.stddev[ib, 0] ** 2)
    ok = vb > 1e-3 * vb.max()  # as tools/bench_fly.py: values above 1e-3 of the maximum
    z = (va - vb)[ok] / sd[ok]
    rel = np.abs(va - vb)[ok] / vb[ok]
    print(f"  {ok.sum()} of {ok.size} samples above 1e-3 of the largest value compared")
    blur = np.median(sa[ok] / va[ok])
    print(f"  fly vs stop-and-go (both through the drivers): rms z {np.sqrt(np.mean(z**2)):.2f}, max |z| "
          f"{np.abs(z).max():.2f}; relative difference median {100 * np.median(rel):.2f} %, 95th percentile "
          f"{100 * np.percentile(rel, 95):.2f} %; fly stddev / value median {100 * blur:.2f} %")


if __name__ == "__main__":
    main()
