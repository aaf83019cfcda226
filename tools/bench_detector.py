"""The simulated detector's Monte Carlo: independence of its lanes, honesty of its stderr, its kernel.

Four checks, each printed as a small table (deterministic: every number below is seeded):

- lanes: many independent estimates of one pose (replicate poses of a batch under a few keys, the
  shape of ``test_aperture_error_is_that_of_independent_samples``); the ratio of their spread to the
  independent-sample prediction s/√n (1 is honest). ``sequential-pcg32`` is the sampler this module
  used before: one PCG32 per lane seeded (state + k, seq + k), lane k = p·n + j; ``philox`` is
  :func:`gonio.sim.detector.aperture_radiance_factor` now.
- stderr: keyed readings of :class:`~gonio.sim.detector.SimDetector` (default apertures, 256 samples,
  the poses of ``test_reported_stderr_matches_the_spread_of_readings``); spread of the readings over
  their mean reported stderr, and over the mean sensor-only part (what ``stderr`` was before).
- float32: the standard error of a nearly constant integrand (Lambertian, θi = 0, α_s = 0.5°), exact
  against float64 block sums (now) and float32 block sums (what a naive port would do).
- kernels: JIT kernels per reading, distinct kernel hashes over readings with different keys and poses,
  and the median wall time of one ``measure`` (informative only; nothing asserts it).

Run: ``.venv/bin/python tools/bench_detector.py`` (``--estimates 1600`` for the lanes check,
``--readings 400`` for the stderr check).
"""

from __future__ import annotations

import argparse
import statistics
import time

import drjit as dr
import numpy as np
from drjit.llvm import PCG32, Array3f, Float, UInt32, UInt64

from gonio.config import load_config, parse_config
from gonio.sim import materials
from gonio.sim.aperture import aperture_radiance_factor, cone_directions
from gonio.sim.gantry import SimGantry

SHARP = "ggx:alpha=0.05,metal=gold"
LANE_CASES = [("lambert:albedo=0.5", (30.0, 45.0), 0.5, 256),
              ("ggx:alpha=0.1,metal=gold", (30.0, 36.0), 3.0, 1024)]
STDERR_POSES = [("lambert:albedo=0.5", 30.0, 45.0), (SHARP, 30.0, 30.0), (SHARP, 30.0, 34.0)]
NOISE = {"shot_counts_per_unit": 2e5, "read_sigma": 3e-3}


def _in_plane(theta_deg: float, phi_deg: float) -> np.ndarray:
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


def _lane_values(material, wi, wo, half_angle_deg, rng) -> np.ndarray:
    """f_r · cos θi' of every lane (float32 kernel), as float64 (lanes, 3), cones of one half-angle."""
    om = dr.opaque(Float, 1.0 - np.cos(np.radians(half_angle_deg)))
    wi_s = cone_directions(wi, om, rng.next_float32(), rng.next_float32())
    wo_s = cone_directions(wo, om, rng.next_float32(), rng.next_float32())
    x = material.eval_dr(wi_s, wo_s) * dr.maximum(wi_s.z, 0.0)
    return np.stack([np.asarray(x[k], dtype=np.float64) for k in range(3)], axis=1)


def sequential_pcg32(material, wi, wo, half_angle_deg, samples, seed_state):
    """The sampler before: (factor, stderr) per pose, lane k seeded (state + k, seq + k)."""
    n = wi.shape[0]
    pose = dr.arange(UInt32, n * samples) // samples

    def gather(v):
        columns = (Float(np.ascontiguousarray(v[:, k], np.float32)) for k in range(3))
        return dr.gather(Array3f, Array3f(*columns), pose)

    rng = PCG32(n * samples, initstate=dr.opaque(UInt64, seed_state[0]),
                initseq=dr.opaque(UInt64, seed_state[1]))
    x = _lane_values(material, gather(wi), gather(wo), half_angle_deg, rng).reshape(n, samples, 3)
    omega = 2.0 * np.pi * (1.0 - np.cos(np.radians(half_angle_deg)))
    return omega * x.mean(axis=1), omega * x.std(axis=1, ddof=1) / np.sqrt(samples)


def lanes(estimates: int) -> None:
    print("lanes: spread of independent estimates / (s/√n)   [1 = independent samples]")
    keys = 4
    replicates = estimates // keys
    states = np.random.SeedSequence(99).generate_state(2 * keys, np.uint32).reshape(keys, 2)
    for spec, (ti, to), alpha, samples in LANE_CASES:
        material = materials.load(spec)
        wi = np.tile(_in_plane(ti, 0.0), (replicates, 1))
        wo = np.tile(_in_plane(to, 180.0), (replicates, 1))
        row = []
        for name, fn in (("sequential-pcg32", sequential_pcg32), ("philox", None)):
            est, se = [], []
            for s in states:
                state = (int(s[0]) << 32 | 7, int(s[1]))
                if fn is None:
                    f, e = aperture_radiance_factor(material, wi, wo, alpha, alpha, samples, state)
                else:
                    f, e = fn(material, wi, wo, alpha, samples, (state[0], state[1] << 32 | 5))
                est.append(f)
                se.append(e)
            est, se = np.concatenate(est), np.concatenate(se)
            ratio = est.std(axis=0, ddof=1) / np.sqrt(np.mean(se**2, axis=0))
            row.append(f"{name} {ratio[0]:.3f}")
        print(f"  {spec:28s} θi={ti:g}° θo={to:g}° α={alpha:g}° n={samples:5d} "
              f"({estimates} estimates): " + ", ".join(row))


def _gantry(spec: str, noise: dict) -> SimGantry:
    data = load_config().model_dump()
    data["detector"]["sim"]["noise"].update(noise)
    gantry = SimGantry.from_config(parse_config(data), spec, seed=3)
    gantry.connect()
    gantry.light.set_on(True)
    return gantry


def _move(gantry: SimGantry, theta_i: float, theta_o: float) -> None:
    targets = {"light_azimuth": 0.0, "light_tilt": theta_i,
               "detector_azimuth": 180.0, "detector_tilt": theta_o}
    for name, target in targets.items():
        gantry.axes[name].move_to(target)
    gantry.clock.sleep(max(a.arrival_time_s() for a in gantry.axes.values()) - gantry.clock.now())


def stderr(readings: int) -> None:
    print("stderr: spread of keyed readings / mean reported stderr   [quality bar: 0.8 .. 1.25]")
    for noise, frames in (({}, 1), (NOISE, 4)):
        for spec, ti, to in STDERR_POSES:
            gantry = _gantry(spec, noise)
            _move(gantry, ti, to)
            rs = [gantry.detector.measure(0.1, frames=frames, key=(step, 0)) for step in range(readings)]
            signal = np.array([r.signal for r in rs])
            spread = signal.std(axis=0, ddof=1)[0]
            now = np.mean([r.stderr[0] for r in rs])
            sensor = np.mean([r.extra["stderr_sensor"][0] for r in rs])
            before = f"{spread / sensor:.3f}" if sensor > 0 else "inf (stderr 0)"
            print(f"  {'sensor noise' if noise else 'no noise':12s} frames={frames} {spec:20s} "
                  f"θi={ti:g}° θo={to:g}°: rel. spread {spread / signal.mean(axis=0)[0]:.2e}, "
                  f"now {spread / now:.3f}, sensor-only {before}")


def float32_sums() -> None:
    print("float32: standard error of a nearly constant integrand (Lambertian, θi = 0, α = 0.5°, n = 4096)")
    material = materials.load("lambert:albedo=0.5")
    n, alpha = 4096, 0.5
    om = 1.0 - np.cos(np.radians(alpha))
    exact = 2.0 * np.pi * om * 0.5 / np.pi * om / np.sqrt(12.0 * n)
    wi, wo = np.array([[0.0, 0.0, 1.0]]), np.array([[-0.5, 0.0, np.sqrt(0.75)]])
    _, now = aperture_radiance_factor(material, wi, wo, alpha, 1.0, n, (2024, 11))
    rng = PCG32(n, initstate=dr.opaque(UInt64, 2024), initseq=dr.opaque(UInt64, 11))
    one = dr.zeros(UInt32, n)
    x = _lane_values(material, dr.gather(Array3f, Array3f(*(Float(v) for v in wi[0])), one),
                     dr.gather(Array3f, Array3f(*(Float(v) for v in wo[0])), one), alpha, rng)
    x32 = Float(np.ascontiguousarray(x[:, 0], np.float32))
    s1, s2 = (float(np.asarray(dr.block_sum(v, n))[0]) for v in (x32, x32 * x32))
    var32 = (s2 - s1 * s1 / n) / (n - 1)
    naive = 2.0 * np.pi * om * np.sqrt(max(var32, 0.0) / n)
    print(f"  exact {exact:.4e}; float64 sums (now) {now[0, 0]:.4e} ({now[0, 0] / exact:.3f}x); "
          f"float32 sums {naive:.4e} ({naive / exact:.0f}x)")


def kernels(repeats: int = 50) -> None:
    print("kernels: one measure() per reading, new key and pose each time")
    gantry = _gantry(SHARP, {})
    _move(gantry, 30.0, 30.0)
    gantry.detector.measure(0.1, key=(0, 0))
    was = dr.flag(dr.JitFlag.KernelHistory)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    times = []
    try:
        dr.kernel_history()
        for step in range(1, repeats + 1):
            _move(gantry, 30.0, 30.0 + 0.1 * step)
            t0 = time.perf_counter()
            gantry.detector.measure(0.1, key=(step, 0))
            times.append(time.perf_counter() - t0)
        jit = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, was)
    print(f"  {len(jit) / repeats:g} JIT kernel(s) per reading, {len({k['hash'] for k in jit})} distinct "
          f"over {repeats} readings, all cache hits: {all(k['cache_hit'] for k in jit)}; "
          f"median measure() {1e3 * statistics.median(times):.2f} ms")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--estimates", type=int, default=1600, help="lanes check: estimates per case")
    parser.add_argument("--readings", type=int, default=200, help="stderr check: readings per pose")
    args = parser.parse_args()
    lanes(args.estimates)
    stderr(args.readings)
    float32_sums()
    kernels()


if __name__ == "__main__":
    main()
