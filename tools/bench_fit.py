"""Fit speed: Dr.Jit AD Jacobian against scipy's finite differences, side by side in one run.

Data: N direction pairs (default 10,000), uniform on the upper hemisphere (seeded), of
``ggx:alpha=0.2,fresnel=none,rho_d=0.3/0.25/0.2,rho_s=0.5/0.55/0.6`` evaluated in float64, with 1 %
multiplicative Gaussian noise and that 1 % as stddev (so the ``chi2`` loss applies). Both fits use the
same residual function (the model through Dr.Jit, weighted by 1/σ), the same bounds and starts.
Rows: gonio.fit's default (the AD Jacobian in a projected Levenberg-Marquardt on the p × p normal
equations), the AD Jacobian in ``scipy.optimize.least_squares(method="trf")``, and the baseline, trf with
``jac="2-point"`` finite differences. One untimed warm-up fit per method compiles the
kernels first; then each method is timed ``--repeats`` times, alternating, and the median is reported.

    .venv/bin/python tools/bench_fit.py [--n 10000] [--starts 4] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

import numpy as np

from gonio.fit import FitData, parse_model
from gonio.fit.solve import Problem, solve
from gonio.sim.materials import load

TRUTH = "ggx:alpha=0.2,fresnel=none,rho_d=0.3/0.25/0.2,rho_s=0.5/0.55/0.6"


def _data(n: int, seed: int = 7) -> FitData:
    rng = np.random.default_rng(seed)

    def hemisphere():
        v = rng.normal(size=(n, 3))
        v[:, 2] = np.abs(v[:, 2]) + 1e-3
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    wi, wo = hemisphere(), hemisphere()
    f = load(TRUTH).eval(wi, wo, precision="float64")
    noisy = f * (1.0 + 0.01 * rng.standard_normal(f.shape))
    return FitData(wi, wo, noisy, 0.01 * f + 1e-6)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=10_000)
    ap.add_argument("--starts", type=int, default=4)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    data = _data(args.n)
    model = parse_model("lambert+ggx")
    rows = {}
    methods = ("ad", "trf-ad", "2-point")
    for jac in methods:  # warm-up: compile every kernel
        solve(Problem(model, data), starts=1, jac=jac)
    times = {jac: [] for jac in methods}
    for _ in range(args.repeats):
        for jac in methods:
            problem = Problem(model, data)
            t0 = time.perf_counter()
            best = solve(problem, starts=args.starts, jac=jac)
            times[jac].append(time.perf_counter() - t0)
            rows[jac] = (best, problem.evaluations, problem.jacobians)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs; load average "
          f"{os.getloadavg()[0]:.2f}")
    print(f"data: {args.n} samples x 3 channels of {TRUTH} (+1 % noise), model lambert+ggx "
          f"({len(model.variables)} parameters), {args.starts} starts, median of {args.repeats}")
    print("| Jacobian | fit s, median (best) | residual evals | Jacobian evals | loss | alpha |")
    print("|---|---|---|---|---|---|")
    for jac, label in (("ad", "gonio.fit: Dr.Jit forward-mode AD, projected LM (p x p normal equations)"),
                       ("trf-ad", "Dr.Jit forward-mode AD in scipy least_squares trf"),
                       ("2-point", "baseline: scipy least_squares trf, 2-point finite differences")):
        best, nfev, njev = rows[jac]
        t = times[jac]
        print(f"| {label} | {statistics.median(t):.3f} ({min(t):.3f}) | {nfev} | {njev} | "
              f"{best['cost']:.6g} | "
              f"{best['x'][0]:.6f} |")
    ratio = statistics.median(times["2-point"]) / statistics.median(times["ad"])
    print(f"speed-up of gonio.fit over the finite-difference baseline: {ratio:.1f}x (median)")


if __name__ == "__main__":
    main()
