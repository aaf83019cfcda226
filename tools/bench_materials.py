"""Throughput of the material models: Dr.Jit (float32, LLVM) against the numpy float32 reference.

Model: Cook-Torrance with Beckmann D, V-groove G and the notes' conductor Fresnel (gold), the
simulation's workhorse: ``cook-torrance:d=beckmann,m=0.2,metal=gold``. The numpy side is the test
suite's independent reference (tests/sim/materials_ref.py) run on float32 arrays.

Every measurement runs in a subprocess of its own, so that "cold" really is cold and peak memory is
clean:

- Dr.Jit cold (no cache): a fresh process whose $HOME is an empty temporary directory, so neither the
  in-memory nor the on-disk kernel cache (``$HOME/.drjit``) holds the kernel; the first ``eval_dr``
  includes tracing, code generation and LLVM compilation.
- Dr.Jit cold (disk cache): a fresh process with the disk cache the previous one left, i.e. what a
  second run of ``gonio simulate`` sees.
- Dr.Jit warm: later calls in the same process (median of the repeats); inputs are Dr.Jit arrays
  already in memory, as in the simulated detector; timing includes ``dr.eval`` and ``dr.sync_thread``.
- numpy cold / warm: the first call in a fresh process, then the median of the repeats.
- Peak memory: the peak resident set size (VmHWM, reset through /proc/self/clear_refs once the inputs
  exist) over all the calls, minus the resident size then, i.e. what evaluation adds on top of its
  inputs (output, temporaries, compiled kernel); for numpy also the tracemalloc peak of one call.

Run: ``.venv/bin/python tools/bench_materials.py`` (``--sizes 1e6 1e7``, ``--repeats 5``,
``--threads N`` for N Dr.Jit worker threads; numpy's element-wise arithmetic is single-threaded).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

SPEC = "cook-torrance:d=beckmann,m=0.2,metal=gold"
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TARGET_SPEEDUP = 40.0


# -- measurements inside a worker process ------------------------------------------------------------
def _rss_kib(field: str) -> int:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(field + ":"):
                return int(line.split()[1])
    raise RuntimeError(f"{field} not in /proc/self/status")


class _PeakRss:
    """Peak RSS from construction to :meth:`mib` minus the RSS at construction, MiB."""

    def __init__(self):
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")  # resets VmHWM to the current RSS
        self.before = _rss_kib("VmRSS")

    def mib(self) -> float:
        return (_rss_kib("VmHWM") - self.before) / 1024.0


def _directions(n: int, seed: int):
    """Uniform directions on the upper hemisphere, made and evaluated in Dr.Jit (as the simulated
    detector makes them: Dr.Jit-allocated, aligned memory), float32."""
    import drjit as dr
    from drjit.llvm import PCG32, Array3f

    rng = PCG32(size=n, initstate=seed)
    z = rng.next_float32()
    phi = rng.next_float32() * 6.2831855
    r = dr.sqrt(1 - z * z)
    w = Array3f(r * dr.cos(phi), r * dr.sin(phi), z)
    dr.eval(w)
    return w


def _to_numpy(w):
    import numpy as np

    return np.ascontiguousarray(np.stack([c.numpy() for c in (w.x, w.y, w.z)], axis=1))


def worker_drjit(n: int, repeats: int, threads: int) -> dict:
    import drjit as dr

    from gonio.sim.materials import load

    if threads:
        dr.set_thread_count(threads)

    m = load(SPEC)
    wi, wo = _directions(n, 1), _directions(n, 2)
    dr.sync_thread()

    def run():
        out = m.eval_dr(wi, wo)
        dr.eval(out)
        dr.sync_thread()
        return out

    peak = _PeakRss()  # over every call: Dr.Jit keeps freed buffers in its allocation cache
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        dr.kernel_history_clear()
        t = time.perf_counter()
        run()
        cold = time.perf_counter() - t
        kernels = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
    warm = []
    for _ in range(repeats):
        t = time.perf_counter()
        run()
        warm.append(time.perf_counter() - t)
    return {"cold_s": cold, "warm_s": warm, "peak_mib": peak.mib(),
            "compile_ms": sum(k.get("backend_time", 0.0) for k in kernels),
            "disk_cache_hit": all(k.get("cache_disk", False) for k in kernels),
            "memory_cache_hit": all(k.get("cache_hit", False) for k in kernels)}


def worker_numpy(n: int, repeats: int, threads: int) -> dict:
    import tracemalloc

    import numpy as np

    sys.path.insert(0, os.path.join(ROOT, "tests", "sim"))
    import materials_ref as ref

    wi, wo = _to_numpy(_directions(n, 1)), _to_numpy(_directions(n, 2))
    assert wi.dtype == np.float32
    eta, k = ref.METALS["gold"]

    def run():
        out = ref.cook_torrance(wi, wo, d="beckmann", m=0.2, fresnel_form="conductor", eta=eta, k=k)
        assert out.dtype == np.float32
        return out

    peak = _PeakRss()
    t = time.perf_counter()
    run()
    cold = time.perf_counter() - t
    warm = []
    for _ in range(repeats):
        t = time.perf_counter()
        run()
        warm.append(time.perf_counter() - t)
    peak_mib = peak.mib()
    tracemalloc.start()
    run()
    traced = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    return {"cold_s": cold, "warm_s": warm, "peak_mib": peak_mib, "tracemalloc_mib": traced}


# -- the driver ------------------------------------------------------------------------------------
def run_worker(kind: str, n: int, repeats: int, threads: int, home: str | None) -> dict:
    env = dict(os.environ)
    if home is not None:
        env["HOME"] = home
    cmd = [sys.executable, os.path.abspath(__file__), "--worker", kind, "--n", str(n),
           "--repeats", str(repeats), "--threads", str(threads)]
    out = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True, cwd=ROOT)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=float, nargs="+", default=[1e6, 1e7])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, default=0,
                        help="Dr.Jit worker threads (default 0: Dr.Jit's choice, one per core)")
    parser.add_argument("--worker", choices=["drjit", "numpy"], help=argparse.SUPPRESS)
    parser.add_argument("--n", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker = worker_drjit if args.worker == "drjit" else worker_numpy
        result = worker(args.n, args.repeats, args.threads)
        print(json.dumps(result))
        return

    import drjit
    import numpy

    print(f"# bench_materials: {SPEC}")
    print(f"python {sys.version.split()[0]}, numpy {numpy.__version__}, drjit {drjit.__version__}, "
          f"{os.cpu_count()} CPUs, Dr.Jit threads: {args.threads or 'default (one per core)'}, "
          f"load average {os.getloadavg()[0]:.2f} at start")
    print()
    print(f"| N | implementation | cold s | warm s, median of {args.repeats} (best) | evals/s warm median "
          "| peak +MiB | notes |")
    print("|---|---|---|---|---|---|---|")
    for size in args.sizes:
        n = int(size)
        with tempfile.TemporaryDirectory(prefix="drjit-home-") as home:
            cold = run_worker("drjit", n, args.repeats, args.threads, home)
            disk = run_worker("drjit", n, args.repeats, args.threads, home)
        npy = run_worker("numpy", n, args.repeats, args.threads, None)
        # Both processes' warm runs count: they time the same kernel.
        dr_runs = cold["warm_s"] + disk["warm_s"]
        dr_warm, np_warm = statistics.median(dr_runs), statistics.median(npy["warm_s"])
        dr_best, np_best = min(dr_runs), min(npy["warm_s"])
        print(f"| {n:.0e} | Dr.Jit float32 LLVM | {cold['cold_s']:.3f} (no cache; LLVM compile "
              f"{cold['compile_ms']:.0f} ms) / {disk['cold_s']:.3f} (disk cache) | {dr_warm:.4f} "
              f"({dr_best:.4f}) | {n / dr_warm:.3g} | {cold['peak_mib']:.0f} | disk-cache run hit: "
              f"{disk['disk_cache_hit']} |")
        print(f"| {n:.0e} | numpy float32 reference | {npy['cold_s']:.3f} | {np_warm:.4f} ({np_best:.4f}) | "
              f"{n / np_warm:.3g} | {npy['peak_mib']:.0f} (tracemalloc {npy['tracemalloc_mib']:.0f}) | |")
        warm_ratio, best_ratio = np_warm / dr_warm, np_best / dr_best
        cold_ratio = npy["cold_s"] / cold["cold_s"]
        verdict = "meets" if warm_ratio >= TARGET_SPEEDUP else "MISSES"
        print(f"| {n:.0e} | speed-up | {cold_ratio:.1f}x cold (no cache) | {warm_ratio:.0f}x median "
              f"({best_ratio:.0f}x best) | | | median {verdict} the {TARGET_SPEEDUP:.0f}x target |")
    print()
    print(f"load average {os.getloadavg()[0]:.2f} at end")


if __name__ == "__main__":
    main()
