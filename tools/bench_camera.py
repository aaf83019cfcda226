"""The simulated camera's frame time and the frame processing time per pose.

- render: :meth:`gonio.sim.camera.SimCamera.render` of a 256×256 frame at 16 samples per pixel (the
  target: under 50 ms per warm frame with LLVM on 2 cores), for a Lambertian and a rough gold, on LLVM
  with ``--threads`` worker threads and on CUDA when a device is present. ``cold`` is the first frame of
  the process for that material (kernel tracing and compilation, or a load from Dr.Jit's on-disk kernel
  cache when it has seen the kernel before); ``warm`` the median of the following frames, each at a new
  pose and key (they reuse the kernel: pose and key are opaque).
- process: per pose, the work of :mod:`gonio.frames` on three bracketed frames of 256×256: merge,
  find the sample region, region mean with its stderr, auto-exposure for the next pose, and writing the
  merged frame to EXR (zip compression) with its hash. Median over poses.

Run: ``.venv/bin/python tools/bench_camera.py [--threads 2] [--frames 20]``.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import drjit as dr
import numpy as np

from gonio import frames
from gonio.sim.camera import CameraSettings, SimCamera
from gonio.sim.materials import load

MATERIALS = ("lambert:albedo=0.5", "ggx:alpha=0.2,metal=gold")


def _pose(i: int) -> tuple[float, float, float, float]:
    return 30.0, 0.0, 35.0 + (i % 20), 180.0


def bench_render(backend: str, n_frames: int) -> None:
    s = CameraSettings(width=256, height=256, samples_per_pixel=16)
    for spec in MATERIALS:
        cam = SimCamera(s, load(spec), backend=backend)
        t = time.perf_counter()
        cam.render(*_pose(0), 0.1, key=(0, 0))
        cold = time.perf_counter() - t
        times = []
        for i in range(1, n_frames + 1):
            t = time.perf_counter()
            cam.render(*_pose(i), 0.1, key=(i, 0))
            times.append(time.perf_counter() - t)
        warm = statistics.median(times)
        print(f"render  {backend:5s} {spec:28s} cold {cold * 1e3:7.1f} ms   warm {warm * 1e3:6.1f} ms"
              f"   (min {min(times) * 1e3:.1f})")


def bench_process(n_poses: int) -> None:
    s = CameraSettings(width=256, height=256, samples_per_pixel=4, black_level=0.002, read_sigma=2e-4,
                       shot_counts_per_unit=2e5, saturation=1.0)
    cam = SimCamera(s, load("ggx:alpha=0.2,metal=gold"), backend="llvm")
    exposure = 0.05
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(n_poses):
            pose = _pose(i)
            exposures = [exposure, 4 * exposure, 16 * exposure]
            shots = [cam.render(*pose, e, key=(i, k)) for k, e in enumerate(exposures)]
            t = time.perf_counter()
            rate, valid = frames.merge_brackets([f.pixels for f in shots], exposures, saturation=1.0,
                                                black_level=0.002)
            region = frames.find_sample_region(shots[0].pixels) & valid
            frames.region_mean(rate, region)
            exposure = frames.auto_exposure(shots[1].pixels, exposures[1], saturation=1.0, black_level=0.002,
                                            mask=region) / 4
            merged = frames.Frame(rate.astype(np.float32), shots[0].metadata)
            frames.write_exr(Path(tmp) / f"pose{i}.exr", merged)
            times.append(time.perf_counter() - t)
    print(f"process llvm  3-frame bracket, 256x256: median {statistics.median(times) * 1e3:.1f} ms per pose "
          f"(min {min(times) * 1e3:.1f}) over {n_poses} poses")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--threads", type=int, default=2, help="LLVM worker threads (default 2)")
    ap.add_argument("--frames", type=int, default=20, help="warm frames per material (default 20)")
    ap.add_argument("--poses", type=int, default=20, help="poses for the processing figure (default 20)")
    args = ap.parse_args()
    dr.set_thread_count(args.threads)
    print(f"LLVM threads: {args.threads}; CUDA: {'yes' if dr.has_backend(dr.JitBackend.CUDA) else 'no'}")
    bench_render("llvm", args.frames)
    if dr.has_backend(dr.JitBackend.CUDA):
        bench_render("cuda", args.frames)
    bench_process(args.poses)


if __name__ == "__main__":
    main()
