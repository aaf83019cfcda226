"""Export and query figures: MERL export of a stride-1 grid, 1e5 scattered samples resampled onto the
MERL grid (ours vs scipy's Delaunay LinearNDInterpolator on the same coordinates), tensor export, and f_r
queries per second. Run: ``.venv/bin/python tools/bench_export.py``."""

from __future__ import annotations

import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.interpolate import LinearNDInterpolator

from gonio.brdf import Reason, open_brdf
from gonio.dataset import SampledBRDF
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

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "formats"))
from conftest import sampled  # noqa: E402

SPEC = "ggx:alpha=0.3,metal=gold"


def main() -> None:
    out = Path(tempfile.mkdtemp())
    data = sampled(SPEC, "merl:stride=1", theta_max_deg=90.0)
    t = time.perf_counter()
    rep = export(data, "merl", out / "s1.binary")
    print(f"MERL export, stride-1 grid ({len(data.theta_i)} samples): "
          f"{time.perf_counter() - t:.2f} s  [{rep}]")

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
    t = time.perf_counter()
    rep = export(scat, "merl", out / "scat.binary")
    ours = time.perf_counter() - t
    print(f"resample 1e5 scattered -> MERL (ours, kNN local linear): {ours:.2f} s  [{rep}]")
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
    t = time.perf_counter()
    LinearNDInterpolator(pts, vals)(q)
    scipy_s = time.perf_counter() - t
    print(f"resample, scipy LinearNDInterpolator (Delaunay) on the same data: {scipy_s:.2f} s "
          f"(ours is {scipy_s / ours:.1f}x faster)")

    iso = sampled(SPEC, "iso:step=5")
    t = time.perf_counter()
    rep = export(iso, "bsdf", out / "t.bsdf")
    print(f"tensor (.bsdf) export of iso:step=5: {time.perf_counter() - t:.2f} s  [{rep}]")

    b = open_brdf(iso)
    q_wi, q_wo = sph_to_vec(th[0][:n], ph[0][:n]), sph_to_vec(th[1][:n], ph[1][:n])
    for name, brdf in (("grid", b), ("scattered", open_brdf(scat))):
        brdf.eval(q_wi[:1000], q_wo[:1000])
        t = time.perf_counter()
        ev = brdf.eval(q_wi, q_wo)
        dt = time.perf_counter() - t
        print(f"f_r queries ({name}, {brdf.domain}): {n / dt:,.0f} per second "
              f"({np.mean(ev.reason == Reason.OK):.0%} supported)")
    print(f"peak RSS: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")


if __name__ == "__main__":
    main()
