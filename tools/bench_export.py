"""Export and query figures: 1e5 scattered samples resampled onto the MERL grid (ours vs scipy's
Delaunay LinearNDInterpolator on the same coordinates, time, CPU time, peak memory and accuracy), MERL
export of a stride-1 campaign's brdf.h5, tensor export, f_r queries per second, brdf.h5 write/read, and
each plot kind. Every figure is printed with the 1-minute load average at the time.
Run: ``.venv/bin/python tools/bench_export.py [--repeats N]`` (the resample is timed N times, best and
all reported: the machine is shared, so the best is the code's figure and the spread is the load's)."""

from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.interpolate import LinearNDInterpolator

from gonio.brdf import Reason, open_brdf
from gonio.dataset import SampledBRDF, read_brdf, write_brdf
from gonio.export import export
from gonio.geometry import (
    from_half_diff,
    merl_bin_centres,
    merl_unindex,
    sph_to_vec,
    to_isotropic,
    vec_to_sph,
)
from gonio.sim.materials import load

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from brdf_samples import sampled  # noqa: E402

SPEC = "ggx:alpha=0.3,metal=gold"


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def _now() -> str:
    """The 1-minute load average, printed next to each figure (the machine is shared)."""
    return f"load {os.getloadavg()[0]:.2f}"


def _peak_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _timed(fn):
    """(result, wall s, CPU s of every thread of the process)."""
    w, c = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w, time.process_time() - c


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    print(f"load average at start: {_load()} ({os.cpu_count()} CPUs)")
    out = Path(tempfile.mkdtemp())

    # First, so that the peak memory printed after it is the resample's (plus generating its data).
    rng = np.random.default_rng(0)
    n = 100_000
    th = np.arccos(1 - rng.random((2, n)))
    ph = rng.random((2, n)) * 2 * np.pi
    wi, wo = sph_to_vec(th[0], ph[0]), sph_to_vec(th[1], ph[1])
    v = load(SPEC).eval(wi, wo, precision="float64")
    ti, pi_ = vec_to_sph(wi)
    to, po = vec_to_sph(wo)
    scat = SampledBRDF(*(np.degrees(a) for a in (ti, pi_, to, po)), v, 0 * v,
                       {"symmetries": {"reciprocity": True, "isotropy": True, "mirror": False}})
    runs = []
    for _ in range(max(1, args.repeats)):
        rep, wall, cpu = _timed(lambda: export(scat, "merl", out / "scat.binary"))
        runs.append((wall, cpu, _now()))
    ours = min(r[0] for r in runs)
    print(f"resample 1e5 scattered -> MERL (ours, kNN local linear, open + eval + write): best {ours:.2f} s; "
          f"runs (wall s / CPU s / load): {'; '.join(f'{w:.2f} / {c:.2f} / {ld}' for w, c, ld in runs)}  "
          f"[{rep}]")
    print(f"  peak RSS after it (data generation + resample): {_peak_mib():.0f} MiB")
    sb, wall, cpu = _timed(lambda: open_brdf(scat))
    print(f"  of which open_brdf (orbit, kd-tree, reach): {wall:.2f} s wall, {cpu:.2f} s CPU ({_now()})")
    # scipy Delaunay on the same (θi, θo, Δφ) points with the same reciprocity copies, same queries
    a, b, d = to_isotropic(ti, pi_, to, po)
    pts = np.concatenate([np.stack([a, b, d], 1), np.stack([b, a, np.mod(-d, 2 * np.pi)], 1)])
    vals = np.concatenate([v, v])
    idx = np.arange(1_458_000)
    q_wi, q_wo = from_half_diff(*(lambda h, dd, p: (h, 0.0, dd, p))(*merl_bin_centres(*merl_unindex(idx))))
    up = (q_wi[:, 2] > 0) & (q_wo[:, 2] > 0)
    qa, qpa = vec_to_sph(q_wi[up])
    qb, qpb = vec_to_sph(q_wo[up])
    q = np.stack(to_isotropic(qa, qpa, qb, qpb), 1)
    theirs, scipy_s, scipy_cpu = _timed(lambda: LinearNDInterpolator(pts, vals)(q))
    print(f"resample, scipy LinearNDInterpolator (Delaunay) on the same data: {scipy_s:.2f} s wall, "
          f"{scipy_cpu:.2f} s CPU ({_now()}; ours is {scipy_s / ours:.1f}x faster)")
    truth = load(SPEC).eval(q_wi[up], q_wo[up], precision="float64")
    mine = sb.eval(q_wi[up], q_wo[up]).value
    for name, est in (("ours", mine), ("scipy", theirs)):
        ok = np.isfinite(est).all(axis=1)
        err = np.abs(est[ok] - truth[ok]).sum() / truth[ok].sum()
        print(f"  accuracy ({name}): {ok.mean():.1%} of the upper-hemisphere bins filled, weighted L1 error "
              f"{err:.1%} against the material")

    data = sampled(SPEC, "merl:stride=1", theta_max_deg=90.0)
    _, w_s, _ = _timed(lambda: write_brdf(out / "s1.h5", data))
    _, r_s, _ = _timed(lambda: read_brdf(out / "s1.h5"))
    print(f"brdf.h5 v2 of the stride-1 grid ({len(data.theta_i)} samples): write {w_s:.2f} s, read "
          f"{r_s:.2f} s, {(out / 's1.h5').stat().st_size / 2**20:.0f} MiB ({_now()})")
    rep, wall, cpu = _timed(lambda: export(out / "s1.h5", "merl", out / "s1.binary"))
    print(f"MERL export of a merl:stride=1 campaign's brdf.h5 ({len(data.theta_i)} samples; read + lattice + "
          f"eval + write): {wall:.2f} s wall, {cpu:.2f} s CPU ({_now()})  [{rep}]")

    iso = sampled(SPEC, "iso:step=5")
    rep, wall, cpu = _timed(lambda: export(iso, "bsdf", out / "t.bsdf"))
    print(f"tensor (.bsdf) export of iso:step=5: {wall:.2f} s wall, {cpu:.2f} s CPU ({_now()})  [{rep}]")
    rep, wall, cpu = _timed(lambda: export(iso, "bsdf-spectral", out / "s.bsdf"))
    print(f"tensor (.bsdf, spectral) export of iso:step=5: {wall:.2f} s wall, {cpu:.2f} s CPU ({_now()})")

    b = open_brdf(iso)
    q_wi, q_wo = sph_to_vec(th[0][:n], ph[0][:n]), sph_to_vec(th[1][:n], ph[1][:n])
    for name, brdf in (("grid", b), ("scattered", sb)):
        brdf.eval(q_wi[:1000], q_wo[:1000])
        ev, dt, cpu = _timed(lambda brdf=brdf: brdf.eval(q_wi, q_wo))
        print(f"f_r queries ({name}, {brdf.domain}, {n} random pairs): {n / dt:,.0f} per second wall, "
              f"{n / cpu:,.0f} per CPU second ({np.mean(ev.reason == Reason.OK):.0%} supported; {_now()})")
    from gonio.plot import plot
    from gonio.registries import PLOT_KINDS

    for kind in PLOT_KINDS:
        if kind == "reciprocity":
            continue  # needs a campaign without the reciprocity shortcut; same cost as merl
        _, wall, _ = _timed(lambda kind=kind: plot(iso, kind, out / f"{kind}.png"))
        print(f"plot {kind} of iso:step=5 (PNG): {wall:.2f} s ({_now()})")
    print(f"load average at end: {_load()}")
    print(f"peak RSS: {_peak_mib():.0f} MiB")


if __name__ == "__main__":
    main()
