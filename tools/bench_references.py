"""Cheap references: what the dark + white-reference checkpoints cost, and how well they still correct a
drifting lamp, by count (a checkpoint every 50 poses) and by time (``reference.every_s``, the shipped
300 s), on the same grid.

    .venv/bin/python tools/bench_references.py                       # iso:step=2 on sim.toml
    .venv/bin/python tools/bench_references.py --grid iso:step=5 --config sample-stage

For each schedule: the plan's checkpoints, its estimate against the valid lower bound, and the share of
the campaign the checkpoints take (their readings, settles and detours). Then the drift correction:
along each plan's own timeline (``Plan.step_end_s``, the campaign clock a simulated run keeps; checked
against real runs by ``tests/plan/test_plan_drift.py``) a lamp with a warm-up, a wander and a trend
(``LAMP`` below) lights every reading; each pose reads a constant f_r, the references the standard, the
darks nothing, and ``gonio.calibrate.calibrate`` (the real code) turns them into f_r. Its relative error
against the truth is the drift correction's error: first noise-free (the interpolation's bias alone),
then with a relative sensor noise per reading (seeded), as a detector has. The baseline beside the
shipped cubic is the straight-line interpolation gonio used before, swapped into
``gonio.calibrate`` for its rows of the same run. No test asserts these figures.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

import gonio.calibrate as calibration
from gonio.clock import VirtualClock
from gonio.config import load_config
from gonio.plan import STEP_DARK, STEP_POSE, STEP_REFERENCE, build_plan
from gonio.sim.light import SimLight
from gonio.store import Measurement

#: A lamp switched on as the campaign starts: 5 % low at first, settling with a 10 min time constant,
#: wandering by 1 % with a 30 min period (room temperature), trending by -2 %/h (ageing).
LAMP = {"drift_per_hour": -0.02, "warmup_fraction": 0.05, "warmup_s": 600.0, "wander_fraction": 0.01,
        "wander_period_s": 1800.0}
NOISE = 1e-3          # relative sensor noise of one reading (a photodiode at 0.1 s)


def _linear(t, tk, yk, ek):
    """The straight-line interpolation of earlier gonio versions (constant beyond the ends)."""
    value = np.stack([np.interp(t, tk, yk[:, c]) for c in range(yk.shape[1])], axis=1)
    hi = np.clip(np.searchsorted(tk, t, side="right"), 1, len(tk) - 1)
    w = np.clip((t - tk[hi - 1]) / np.maximum(tk[hi] - tk[hi - 1], 1e-300), 0.0, 1.0)[:, None]
    return value, np.hypot((1.0 - w) * ek[hi - 1], w * ek[hi])


def drift_errors(plan, cfg, noise: float, seed: int = 1) -> np.ndarray:
    """Relative errors (P,) of the calibrated f_r of every pose when ``cfg``'s lamp drifts along
    ``plan``'s timeline (see the module docstring)."""
    lamp = SimLight(cfg.light.model_copy(update={"sim": cfg.light.sim.model_copy(update=LAMP)}),
                    VirtualClock())
    times = plan.step_end_s
    radiance = np.array([lamp.lamp_radiance(t) for t in times]) / cfg.light.sim.radiance
    kind = plan.step_kind
    rho = cfg.reference.albedo
    truth = 0.1                                        # f_r of every pose, sr^-1 (θi taken as 0)
    clean = np.where(kind == STEP_POSE, truth, np.where(kind == STEP_REFERENCE, rho / np.pi, 0.0)) * radiance
    rng = np.random.default_rng(seed)
    sigma = noise * np.where(kind == STEP_DARK, truth, clean)
    signal = clean + rng.normal(0.0, 1.0, clean.shape) * sigma
    zero = np.zeros(4)
    ms = [Measurement(step=i, kind=int(k), pose=int(p), commanded_deg=zero, actual_deg=zero,
                      angles_deg=zero, clock_s=float(t), campaign_s=float(t), exposure_s=1.0, frames=1,
                      signal=np.array([s]), stderr=np.array([max(e, 1e-30)]))
          for i, (k, p, t, s, e) in enumerate(zip(kind, plan.step_pose, times, signal, sigma, strict=True))]
    cal = calibration.calibrate(ms, rho)
    return cal.value[:, 0] / truth - 1.0


def _stats(e: np.ndarray) -> str:
    a = np.abs(e)
    return (f"{np.median(a):.1e} | {np.sqrt(np.mean(e * e)):.1e} | {np.percentile(a, 99):.1e} | "
            f"{a.max():.1e}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--grid", default="iso:step=2")
    ap.add_argument("--config", default="sim")
    args = ap.parse_args()
    print(f"load average at start: {os.getloadavg()[0]:.2f}; grid {args.grid}, config {args.config}; "
          f"lamp {LAMP}; sensor noise {NOISE:g} per reading\n")
    cfg = load_config(args.config)
    schedules = [("every 50 poses", {"every": 50, "every_s": None}),
                 ("every_s 300 (shipped)", {"every": None, "every_s": 300.0})]
    plans = {}
    print("| schedule | checkpoints | estimate | lower bound | est / bound | reference share | planning s |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for label, ref in schedules:
        c = cfg.model_copy(update={"reference": cfg.reference.model_copy(update=ref)})
        t0 = time.perf_counter()
        plan = build_plan(args.grid, c)
        built = time.perf_counter() - t0
        plans[label] = (plan, c)
        n_ref = int(np.count_nonzero(plan.step_kind == STEP_REFERENCE))
        print(f"| {label} | {n_ref:,} | {plan.estimated_s:,.0f} s | {plan.lower_bound_s:,.0f} s | "
              f"{plan.estimated_s / plan.lower_bound_s:.3f} | "
              f"{plan.timing['reference_s'] / plan.estimated_s:.1%} | {built:.1f} |", flush=True)

    print("\nDrift correction, relative error of the calibrated f_r over every pose:\n")
    print("| schedule | interpolation | readings | median abs | rms | 99th pct | max |")
    print("|---|---|---|---:|---:|---:|---:|")
    shipped = calibration._interp
    for label, (plan, c) in plans.items():
        for name, interp in (("cubic (shipped)", shipped), ("straight line (before)", _linear)):
            calibration._interp = interp
            try:
                for noisy, noise in (("noise-free", 0.0), (f"noise {NOISE:g}", NOISE)):
                    e = drift_errors(plan, c, noise)
                    print(f"| {label} | {name} | {noisy} | {_stats(e)} |", flush=True)
            finally:
                calibration._interp = shipped


if __name__ == "__main__":
    main()
