"""The fit's model of the instrument's cones: bias and CPU time, at the cones' axes and averaged over them.

Simulates (or reads) a campaign of ``ggx:alpha=0.15,metal=copper,rho_d=0.2,rho_s=0.8`` on
``iso:step=15,reciprocity=false`` (the default config: 0.5° source cone, 1° detector cone, 256 aperture
samples a reading, no sensor noise) and fits ``ggx:metal=copper`` to it three ways from the same samples:
at the cones' axes (the point model, what gonio fit did before), averaged over the cones with the default
quadrature (16 directions a sample) and with a finer one (144). Per row: each parameter's error in units
of its stated σ, χ²/dof, and the fit's CPU time (process time, median of ``--repeats`` after one
untimed warm-up fit per row, rows alternating).

    .venv/bin/python tools/bench_fit_aperture.py [--campaign FOLDER] [--repeats 5]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

from gonio.fit import Aperture, fit, load_samples
from gonio.sim.materials import load

TRUTH = "ggx:alpha=0.15,metal=copper,rho_d=0.2,rho_s=0.8"
MODEL = "ggx:metal=copper"
GRID = "iso:step=15,reciprocity=false"


def _truth(name: str) -> float:
    key, _, channel = name.partition(".")
    value = load(TRUTH).values()["alpha_u" if key == "alpha" else key]
    return value["RGB".index(channel)] if channel else value


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--campaign", type=Path,
                    help="a finished campaign of TRUTH on GRID (default: simulate one)")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    folder = args.campaign
    if folder is None:
        from gonio.cli import main as gonio

        folder = Path(tempfile.mkdtemp()) / "cu"
        gonio(["simulate", TRUTH, "--grid", GRID, "--out", str(folder), "--quiet"])
    data, _ = load_samples(folder)
    cones = data.aperture or Aperture(0.5, 1.0)
    rows = [("at the cones' axes (before)", None), (f"averaged, {cones.points} directions (default)", cones),
            ("averaged, 144 directions (2 rings x 6 spokes)", dataclasses.replace(cones, rings=2, spokes=6))]
    times: dict[str, list[float]] = {name: [] for name, _ in rows}
    results = {}
    for k in range(args.repeats + 1):
        for name, aperture in rows:
            d = dataclasses.replace(data, aperture=aperture)
            t = time.process_time()
            results[name] = fit(d, MODEL)
            if k:
                times[name].append(time.process_time() - t)
    print(f"{platform.node()}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}; "
          f"{len(data.wi)} samples of {TRUTH}, fitted with {MODEL}")
    names = list(results[rows[0][0]].parameters)
    print("| model | " + " | ".join(f"{n} (z)" for n in names) + " | χ²/dof | CPU s, median (best) |")
    print("|---|" + "---|" * (len(names) + 2))
    for name, _ in rows:
        r = results[name]
        zs = [f"{p['value']:.6g} ({(p['value'] - _truth(n)) / p['stddev']:+.1f})"
              for n, p in r.parameters.items()]
        t = times[name]
        print(f"| {name} | " + " | ".join(zs) + f" | {r.residual['chi2_reduced']:.3g} | "
              f"{statistics.median(t):.3f} ({min(t):.3f}) |")


if __name__ == "__main__":
    main()
