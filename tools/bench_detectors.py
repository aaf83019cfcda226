"""Wall time per pose of whole simulated campaigns with each detector, and where a camera pose's time goes.

For each detector (``photodiode``, the RGB default; ``spectrometer``, 41 bands 380..780 nm every 10 nm;
``camera``, 64×64 at 16 samples per pixel, the config's default; ``camera+bracket``, the same with
auto-exposure and a 3-exposure bracket) the same campaign (``--grid``, default ``iso:step=15``, material
``ggx:alpha=0.3,metal=gold``) runs through :func:`gonio.campaign.run_campaign` (journal commits and the
final brdf.h5 included) in a fresh folder, ``--repeats`` times; the best run's wall time per step is
printed, and the overhead against the photodiode.

For the camera runs the time per step is split: ``render`` (SimCamera.render, all frames of the reading),
``reduce`` (the rest of the detector's reading: frame checks, the region mask, bracket merge,
auto-exposure, region mean), ``exr`` (the journal writing the frame to EXR with its hash, and fsync).

Run: ``.venv/bin/python tools/bench_detectors.py [--grid iso:step=15] [--repeats 2]``.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from gonio.campaign import create_campaign
from gonio.config import load_config, with_sim_detector
from gonio.lifecycle import run_campaign
from gonio.sim.camera import SimCamera
from gonio.sim.detector_camera import CameraDetector
from gonio.store import Journal
from gonio.wiring import build_gantry

MATERIAL = "ggx:alpha=0.3,metal=gold"


def _cfg(kind: str, camera: dict | None = None):
    return with_sim_detector(load_config(), kind, **({"camera": camera} if camera else {}))


class _Timer:
    """Cumulative seconds spent in a wrapped method."""

    def __init__(self, owner, name):
        self.owner, self.name, self.total = owner, name, 0.0
        self.original = getattr(owner, name)
        timer = self

        def wrapped(*args, **kwargs):
            t = time.perf_counter()
            try:
                return timer.original(*args, **kwargs)
            finally:
                timer.total += time.perf_counter() - t

        setattr(owner, name, wrapped)

    def restore(self):
        setattr(self.owner, self.name, self.original)


def run(label: str, cfg, grid: str, repeats: int) -> float:
    best = None
    for _ in range(repeats):
        timers = [_Timer(SimCamera, "render"), _Timer(CameraDetector, "measure"),
                  _Timer(Journal, "_write_frame")]
        try:
            with tempfile.TemporaryDirectory() as tmp:
                c = create_campaign(Path(tmp), cfg, grid=grid, material=MATERIAL, seed=1)
                steps = c.journal.step_count()
                gantry = build_gantry(cfg, MATERIAL, seed=1)
                t = time.perf_counter()
                run_campaign(c, gantry)
                wall = time.perf_counter() - t
                c.close()
        finally:
            for timer in timers:
                timer.restore()
        render, measure, exr = (timer.total for timer in timers)
        if best is None or wall < best[0]:
            best = (wall, render, measure - render, exr, steps)
    wall, render, reduce, exr, steps = best
    per = wall / steps * 1e3
    line = f"{label:16s} {steps:5d} steps  {per:7.2f} ms per step"
    if render > 0:
        line += (f"   (render {render / steps * 1e3:.2f}, reduce {reduce / steps * 1e3:.2f}, "
                 f"exr {exr / steps * 1e3:.2f} ms)")
    print(line, flush=True)
    return per


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grid", default="iso:step=15")
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} on {os.cpu_count()} CPUs; "
          f"grid {args.grid}; material {MATERIAL}")
    runs = {
        "photodiode": _cfg("photodiode"),
        "spectrometer": _cfg("spectrometer"),
        "camera": _cfg("camera"),
        "camera+bracket": _cfg("camera", {"saturation": 0.02, "auto_exposure": True,
                                          "brackets": [0.25, 1, 4]}),
    }
    base = None
    for label, cfg in runs.items():
        per = run(label, cfg, args.grid, args.repeats)
        if base is None:
            base = per
        else:
            print(f"{'':16s} overhead against the photodiode: {per - base:+.2f} ms per step "
                  f"({per / base:.1f}x)")
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
