"""Benchmark: batch simulation past one machine (issue 24), three panels side by side.

1. workers: ``N`` materials (``ggx:alpha=0.02..0.5xN/2,metal=gold|copper``) × ``--grid`` through
   :func:`gonio.batch.run_batch`, on a local cluster of 1 and then 2 one-thread worker processes (each
   its own new store); wall time, materials per second, the speed-up, and the client's peak resident
   memory during the batch (VmHWM reset before it; the bounded map keeps one result per worker in
   flight, so it should not grow with N).
2. detector: CPU time per reading of the simulated photodiode (process CPU, Dr.Jit's threads included)
   for ``--poses`` still poses of a glossy material: :meth:`SimDetector.measure` one pose at a time (what
   a campaign does) against :meth:`SimDetector.measure_poses` (all poses per target in one launch),
   reading for reading the same values.
2b. campaign: what ``gonio simulate MATERIAL --grid GRID`` runs (the campaign lifecycle: the engine, the
   simulated gantry's motion on the virtual clock, the journal, the calibration and ``brdf.h5``), the
   plan made once, timed from the start of the run to ``brdf.h5``: process CPU per step (Dr.Jit's threads
   included), and the simulated detector's part of it (its ``measure``, ``take`` and ``develop`` calls),
   in three modes alternating ``--repeats`` times in one process (medians): before (one step a unit,
   ``chunk = 1``, and the render's kernel traced on every call, as campaigns ran before), one step a
   unit with the frozen kernel, and now (chunks, frozen kernel); the journals' readings compared bit
   for bit.
3. materials: GGX with a gold conductor Fresnel, our :meth:`Material.evaluate` (a frozen Dr.Jit
   function, float32, LLVM) against Mitsuba 3's ``roughconductor`` (``distribution=ggx``, ``material=Au``,
   ``llvm_ad_rgb``) ``eval`` on the same random direction pairs, 10^2 (per-call overhead) to 10^7;
   median of ``--repeats`` warm calls each, inputs already in memory, ``dr.eval`` and
   ``dr.sync_thread`` included. (Mitsuba's value includes cos θo, ours does not: one multiply.)
4. overhead: one ``Material.evaluate`` of 100 directions taken apart (medians of many calls): the checks,
   the frozen function's handling of its inputs, a kernel launch, the traced path for comparison.

Run: ``.venv/bin/python tools/bench_batch.py [--materials 200] [--grid iso:step=15] [--poses 300]
[--repeats 7] [--campaign-grid iso:step=10] [--threads N]
[--only workers|detector|campaign|materials|overhead]``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np


def _reset_peak() -> None:
    """Reset the process's peak resident set size (VmHWM) to its current size (Linux)."""
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")


def _peak_mib() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def bench_workers(n: int, grid: str) -> None:
    from gonio.batch import read_materials, run_batch
    from gonio.batch.cluster import connect
    from gonio.config import load_config

    half = max(1, n // 2)
    materials = read_materials(f"ggx:alpha=0.02..0.5x{half},metal=gold|copper" if half > 1 else
                               "ggx:alpha=0.2,metal=gold|copper")
    cfg = load_config()
    walls = {}
    for workers in (1, 2):
        _reset_peak()
        client, cluster, threads = connect(workers=workers)
        try:
            with tempfile.TemporaryDirectory() as d:
                t = time.perf_counter()
                s = run_batch(materials, grid=grid, seed=0, cfg=cfg, out=Path(d) / "b.zarr", client=client,
                              threads=threads)
                walls[workers] = time.perf_counter() - t
                assert s.written == len(materials) and not s.failed, s.failed
        finally:
            client.close()
            cluster.close()
        print(f"workers {workers}: {len(materials)} materials x {grid} in {walls[workers]:.1f} s "
              f"({len(materials) / walls[workers]:.2f} materials/s); client peak RSS during the batch "
              f"{_peak_mib():.0f} MiB")
    print(f"speed-up 2 workers / 1 worker: {walls[1] / walls[2]:.2f}x "
          f"(load average at the end {os.getloadavg()[0]:.2f})")


def bench_detector(poses: int) -> None:
    from gonio.config import load_config
    from gonio.sim.gantry import SimGantry

    gantry = SimGantry.from_config(load_config(), "ggx:alpha=0.1,metal=gold", seed=3)
    gantry.connect()
    names = gantry.kinematics.axis_names
    rng = np.random.default_rng(1)
    lo = np.array([gantry.axes[a].cfg.min_deg for a in names])
    hi = np.array([gantry.axes[a].cfg.max_deg for a in names])
    axes = lo + (hi - lo) * rng.uniform(0.2, 0.8, (poses, len(names)))
    keys = [(k, 0) for k in range(poses)]
    gantry.light.set_on(True)
    gantry.detector.set_target("sample")
    gantry.detector.measure(0.1, key=(10**6, 0))        # compile the kernels first (both ways share them)
    gantry.detector.measure_poses(axes[:2], [(10**6 + 1, 0), (10**6 + 2, 0)], exposure_s=0.1)
    one, actual = [], []
    cpu = 0.0
    for k in range(poses):
        for name, target in zip(names, axes[k], strict=True):
            gantry.axes[name].move_to(target)
        gantry.clock.sleep(max(a.arrival_time_s() for a in gantry.axes.values()) - gantry.clock.now())
        actual.append(gantry.detector.actual_axes_deg())
        c = time.process_time()
        one.append(gantry.detector.measure(0.1, key=keys[k]))
        cpu += time.process_time() - c
    c = time.process_time()
    batch = gantry.detector.measure_poses(np.array(actual), keys, exposure_s=0.1)
    cpu_batch = time.process_time() - c
    same = all(np.array_equal(a.signal, b.signal) for a, b in zip(one, batch, strict=True))
    print(f"detector, {poses} poses: measure() one at a time {1e3 * cpu / poses:.3f} ms CPU per reading, "
          f"measure_poses() {1e3 * cpu_batch / poses:.3f} ms CPU per reading "
          f"({cpu / max(cpu_batch, 1e-9):.1f}x); readings identical: {same}")


class _Traced:
    """The sample's material seen through ``eval_dr`` alone: the detector traces its kernel on every
    render, as it did before the kernel was frozen (sim/aperture.py)."""

    def __init__(self, material):
        self.eval_dr = material.eval_dr


def _campaign_once(cfg, request, material, planned, folder: Path, chunk: int | None, traced: bool = False):
    """One simulated campaign through the lifecycle in ``folder``: (CPU s of the whole run, CPU s in the
    detector, steps, readings as bytes)."""
    from gonio.lifecycle import campaign_gantry, open_or_create, run_campaign

    c, _ = open_or_create(folder, cfg, request, spec=material.spec, plan=lambda: planned)
    gantry = campaign_gantry(c, _Traced(material) if traced else material)
    det = gantry.detector
    if chunk is not None:
        det.chunk = chunk
    spent = [0.0]

    def timed(fn):
        def call(*args, **kw):
            t = time.process_time()
            try:
                return fn(*args, **kw)
            finally:
                spent[0] += time.process_time() - t
        return call

    for name in ("measure", "take", "develop"):
        setattr(det, name, timed(getattr(det, name)))
    t = time.process_time()
    state, _ = run_campaign(c, gantry)
    cpu = time.process_time() - t
    assert state == "done", state
    steps = c.journal.step_count()
    readings = [(m.signal.tobytes(), m.stderr.tobytes()) for m in c.journal.measurements()]
    c.close()
    return cpu, spent[0], steps, readings


def bench_campaign(grid: str, repeats: int) -> None:
    from gonio.config import load_config
    from gonio.lifecycle import Request, check_request, plan_request
    from gonio.sim.detector import CAMPAIGN_CHUNK

    cfg = load_config()
    request = Request(grid, material="ggx:alpha=0.1,metal=gold", seed=3)
    material = check_request(cfg, request)
    planned = plan_request(cfg, request)
    modes = {"before: one step a unit, kernel traced": (1, True),
             "one step a unit, kernel frozen": (1, False),
             f"now: chunks of <= {CAMPAIGN_CHUNK}, kernel frozen": (None, False)}
    runs = {m: [] for m in modes}
    readings = {}
    with tempfile.TemporaryDirectory() as d:
        _campaign_once(cfg, request, material, planned, Path(d) / "warm", None)   # kernels compiled
        for r in range(repeats):
            for k, (mode, (chunk, traced)) in enumerate(modes.items()):
                cpu, det, steps, readings[mode] = _campaign_once(cfg, request, material, planned,
                                                                 Path(d) / f"{r}-{k}", chunk, traced)
                runs[mode].append((cpu / steps, det / steps))
    load = os.getloadavg()[0]
    print(f"campaign, gonio simulate {request.material} --grid {grid}: {steps} steps, median of {repeats} "
          f"(load average at the end {load:.2f})")
    for mode, rows in runs.items():
        total = statistics.median(r[0] for r in rows)
        det = statistics.median(r[1] for r in rows)
        print(f"  {mode:<40} whole run {1e3 * total:6.3f} ms CPU per step, detector {1e3 * det:6.3f} ms")
    first, *others = readings.values()
    print(f"  readings identical in every mode: {all(o == first for o in others)}")


def _median_call(fn, repeats: int) -> float:
    fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def bench_materials(repeats: int, sizes) -> None:
    import drjit as dr
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    from drjit.llvm import Array3f

    from gonio.sim.materials import load

    ours = load("ggx:alpha=0.2,metal=gold")
    theirs = mi.load_dict({"type": "roughconductor", "distribution": "ggx", "alpha": 0.2, "material": "Au"})
    ctx = mi.BSDFContext()
    rng = np.random.default_rng(5)
    print("materials: size, ours (Material.evaluate), Mitsuba roughconductor eval, ours / Mitsuba")
    for n in sizes:
        n = int(n)
        d = rng.normal(size=(2, n, 3))
        d[..., 2] = np.abs(d[..., 2])
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        d = d.astype(np.float32)
        wi, wo = Array3f(*d[0].T), Array3f(*d[1].T)
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
        si.wi = mi.Vector3f(*d[0].T)
        mwo = mi.Vector3f(*d[1].T)
        dr.eval(wi, wo, si, mwo)

        def run_ours(wi=wi, wo=wo):
            v = ours.evaluate(wi, wo)
            dr.eval(v)
            dr.sync_thread()

        def run_theirs(si=si, mwo=mwo):
            v = theirs.eval(ctx, si, mwo)
            dr.eval(v)
            dr.sync_thread()

        a, b = _median_call(run_ours, repeats), _median_call(run_theirs, repeats)
        print(f"  {n:>10,d}: {1e3 * a:9.3f} ms  {1e3 * b:9.3f} ms  {a / b:5.2f}")


def bench_overhead(repeats: int) -> None:
    """Where a small call's time goes: ``Material.evaluate`` of 100 direction pairs taken apart (median
    of many calls each, so that a preemption on a loaded machine does not count)."""
    import drjit as dr
    from drjit.llvm import Array3f

    from gonio.sim.materials import load

    m = load("ggx:alpha=0.2,metal=gold")
    rng = np.random.default_rng(5)
    d = rng.normal(size=(2, 100, 3))
    d[..., 2] = np.abs(d[..., 2])
    d = (d / np.linalg.norm(d, axis=-1, keepdims=True)).astype(np.float32)
    wi, wo = Array3f(*d[0].T), Array3f(*d[1].T)
    dr.eval(wi, wo)
    params = m.dr_parameters(Array3f)
    add_in = dr.freeze(lambda a, b, p: a + b)
    add = dr.freeze(lambda a, b: a + b)
    one = dr.freeze(lambda a: a + 1.0)
    v = m.evaluate(wi, wo)

    n = max(200, 40 * repeats)

    def median_us(fn):
        for _ in range(20):
            fn()
        times = []
        for _ in range(n):
            t = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t)
        return 1e6 * statistics.median(times)

    rows = [
        ("Material.evaluate + dr.eval + dr.sync_thread (the materials panel's call)",
         lambda: (dr.eval(m.evaluate(wi, wo)), dr.sync_thread())),
        ("Material.evaluate alone (frozen GGX replayed)", lambda: m.evaluate(wi, wo)),
        ("  its checks: dr.grad_enabled x2 and the cached dr_parameters",
         lambda: (dr.grad_enabled(wi), dr.grad_enabled(wo), m.dr_parameters(Array3f))),
        ("  a frozen a+b with the same inputs (6 direction arrays + 14 parameter arrays)",
         lambda: add_in(wi, wo, params)),
        ("  a frozen a+b of the 6 direction arrays alone", lambda: add(wi, wo)),
        ("  a frozen a+1 of one array", lambda: one(wi.x)),
        ("  a traced a+1 of one array, evaluated (kernel cache hit)", lambda: dr.eval(wi.x + 1.0)),
        ("  dr.eval of an evaluated result", lambda: dr.eval(v)),
        ("eval_dr traced and evaluated (no freeze)", lambda: dr.eval(m.eval_dr(wi, wo))),
    ]
    print("overhead of one call at 100 directions (µs, median):")
    for label, fn in rows:
        print(f"  {median_us(fn):8.1f}  {label}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--materials", type=int, default=200)
    ap.add_argument("--grid", default="iso:step=15")
    ap.add_argument("--poses", type=int, default=300)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--sizes", type=float, nargs="+", default=[1e2, 1e5, 1e6, 1e7])
    ap.add_argument("--campaign-grid", default="iso:step=10")
    ap.add_argument("--threads", type=int, help="Dr.Jit threads (default: Dr.Jit's, one per core)")
    ap.add_argument("--only", choices=("workers", "detector", "campaign", "materials", "overhead"))
    a = ap.parse_args()
    print(f"load average at the start: {os.getloadavg()[0]:.2f}")
    if a.threads is not None:
        import drjit as dr

        dr.set_thread_count(a.threads)
    if a.only in (None, "detector"):
        bench_detector(a.poses)
    if a.only in (None, "campaign"):
        bench_campaign(a.campaign_grid, a.repeats)
    if a.only in (None, "materials"):
        bench_materials(a.repeats, a.sizes)
    if a.only in (None, "overhead"):
        bench_overhead(a.repeats)
    if a.only in (None, "workers"):
        bench_workers(a.materials, a.grid)


if __name__ == "__main__":
    main()
