"""What a campaign's journal says about the measurement: the plan, the run, and the calibration readings.

:func:`campaign_facts` reads the plan (gantry, grid, shortcuts, counts), the run (campaign time against the
plan's estimate, resumes) and the events (faults, retries, pauses, halts). :func:`calibration_readings`
takes the white-reference and dark readings over campaign time and checks each one against what the
others predict for it: inside, the calibration's own interpolation through the readings around it (a
cubic through two on each side, :func:`gonio.calibrate.interpolation_weights`), at either end the line
through its two nearest neighbours. A reading off that prediction is one the calibration cannot absorb
(a lamp's smooth drift, even sparse in time, is absorbed):

- a white-reference reading is flagged when its net rate (dark subtracted) is more than
  :data:`REFERENCE_JUMP_RELATIVE` off that line *and* more than :data:`JUMP_Z` of its standard errors;
- a dark reading when it is off its line by more than :data:`DARK_JUMP_RELATIVE` of the median net
  reference rate (what a dark error does to a sample as bright as the standard) and more than
  :data:`JUMP_Z` standard errors.

The worst offender (its deviation over the leverage of its line: an extrapolated line counts less than an
interpolated one) is flagged first and left out of its neighbours' lines, then the check repeats, so a
single bad reading does not also condemn the good ones beside it. The same leave-one-out deviations of
the readings that pass, in units of their stated standard error, are the repeat-reading noise check of
:mod:`gonio.report.checks` (rms ≈ 1 when the stated stderr is honest).
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gonio.calibrate import SPACING_RATIO, interpolate_readings, interpolation_weights
from gonio.plan.schedule import STEP_DARK, STEP_POSE, STEP_REFERENCE
from gonio.store import JOURNAL_NAME, Journal

__all__ = ["campaign_facts", "calibration_readings", "Readings", "REFERENCE_JUMP_RELATIVE",
           "DARK_JUMP_RELATIVE", "JUMP_Z"]

#: A white-reference reading this far (relative) off what its neighbours predict is flagged ...
REFERENCE_JUMP_RELATIVE = 0.02
#: ... a dark reading this far off its line, relative to the median net reference rate ...
DARK_JUMP_RELATIVE = 0.01
#: ... when the deviation is also more than this many standard errors.
JUMP_Z = 5.0
#: Event kinds worth a line in the report (state changes and parks are routine).
NOTABLE_EVENTS = ("fault", "retry", "pause", "halt", "signal", "fault-cleared", "stopped")


def _utc(unix) -> str:
    if not unix:
        return "unknown"
    return _dt.datetime.fromtimestamp(float(unix), _dt.UTC).strftime("%Y-%m-%d %H:%M:%S UTC")


def campaign_facts(folder: Path) -> tuple[dict, list]:
    """The campaign as planned and run, and its journal's measurements.

    Returns
    -------
    facts : dict
        ``name``, ``what`` (material or sample), ``gantry``, ``design``, ``grid``, ``symmetries``,
        ``counts`` (poses before/after each shortcut), ``infeasible`` (by reason), ``poses``, ``steps``
        (by kind), ``campaign_s``, ``estimated_s``, ``lower_bound_s`` (None for an adaptive campaign),
        ``runs`` (1 + resumes),
        ``retries`` (extra attempts in the measurements), ``faults``, ``events`` (notable events:
        kind, campaign_s, step, message), ``reference_albedo``, ``seed``, ``created``,
        ``software_version``, ``channels``, ``adaptive`` (an adaptive campaign's pilot and rounds, the
        journal's meta; None for other grids).
    measurements : list of gonio.store.Measurement
    """
    j = Journal.open(folder / JOURNAL_NAME, readonly=True)
    try:
        meta = j.meta()
        steps = j.steps()
        measurements = j.measurements()
        events = j.events()
        campaign_s, _ = j.campaign_clock()
    finally:
        j.close()
    cfg = meta.get("config") or {}
    kinds = steps["kind"]
    notable = [{"kind": e["kind"], "campaign_s": e["campaign_s"], "step": e["step"],
                "message": e["message"] or ""} for e in events if e["kind"] in NOTABLE_EVENTS]
    facts = {
        "name": folder.resolve().name,
        "what": meta.get("material") or meta.get("sample") or "",
        "source": "simulated material" if meta.get("material") else "sample",
        "gantry": meta.get("gantry", ""),
        "design": (cfg.get("kinematics") or {}).get("design", ""),
        "grid": meta.get("grid", ""),
        "symmetries": dict(meta.get("symmetries", {})),
        "counts": dict(meta.get("counts", {})),
        "infeasible": dict(meta.get("infeasible", {})),
        "poses": int(meta.get("poses", 0)),
        "steps": {"total": int(len(kinds)), "pose": int(np.sum(kinds == STEP_POSE)),
                  "dark": int(np.sum(kinds == STEP_DARK)), "reference": int(np.sum(kinds == STEP_REFERENCE))},
        "measured": len(measurements),
        "campaign_s": float(campaign_s),
        "estimated_s": float(meta.get("estimated_s", 0.0)),
        "lower_bound_s": float(meta.get("lower_bound_s", 0.0)),
        "runs": max(1, sum(1 for e in events if e["kind"] == "state" and e["state"] == "running")),
        "retries": int(sum(m.attempts - 1 for m in measurements)),
        "faults": sum(1 for e in notable if e["kind"] == "fault"),
        "events": notable,
        "reference_albedo": float((cfg.get("reference") or {}).get("albedo", 0.99)),
        "seed": meta.get("seed"),
        "created": _utc(meta.get("created_unix")),
        "software_version": meta.get("software_version", ""),
        "channels": [str(c) for c in meta.get("channels", ())],
        "adaptive": meta.get("adaptive"),
    }
    adaptive = meta.get("adaptive")
    if adaptive:
        # The pilot's plan, then each round's: the estimate is their sum. Their bounds' sum is no bound
        # (each phase's plan starts at home and parks; the campaign goes on from one to the next): None.
        rounds = adaptive["rounds"]
        facts["estimated_s"] = adaptive["pilot_s"] + sum(r["estimated_s"] for r in rounds)
        facts["lower_bound_s"] = None
        facts["counts"] = {**{f"pilot {k}": v for k, v in facts["counts"].items()},
                           "with the rounds": facts["poses"]}
    return facts, measurements


@dataclass
class Readings:
    """One kind of calibration reading over campaign time, checked against its neighbours.

    Attributes
    ----------
    step : numpy.ndarray, shape (K,)
        Journal steps.
    time_s : numpy.ndarray, shape (K,)
        Campaign clock at each reading, seconds.
    rate, stderr : numpy.ndarray, shape (K, C)
        Signal per second of exposure (net of the dark for white references) and its standard error.
    deviation, z : numpy.ndarray, shape (K, C)
        Leave-one-out deviation from what the nearest readings in time that are not flagged predict
        (relative to the reference level ``scale``), and in standard errors; NaN where there are not
        enough readings.
    flagged : list of int
        Indices (into the K readings) of flagged readings, worst first.
    scale : numpy.ndarray, shape (C,)
        What ``deviation`` is relative to: the median net white-reference rate.
    """

    step: np.ndarray
    time_s: np.ndarray
    rate: np.ndarray
    stderr: np.ndarray
    scale: np.ndarray
    deviation: np.ndarray = field(default=None)
    z: np.ndarray = field(default=None)
    flagged: list = field(default_factory=list)

    @property
    def drift(self) -> np.ndarray:
        """Relative change (C,) from the first to the last reading that is not flagged."""
        keep = [k for k in range(len(self.step)) if k not in self.flagged]
        if len(keep) < 2:
            return np.zeros(self.rate.shape[1])
        return (self.rate[keep[-1]] - self.rate[keep[0]]) / self.scale


def _leave_one_out(r: Readings, skip: set) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Deviation of each reading from what the others (not in ``skip``) predict for it, in units of the
    reference level and of standard errors, and the leverage √(1 + Σa²) of that prediction (a·: its
    weights). Inside, the prediction is the calibration's cubic through two others on each side
    (:func:`gonio.calibrate.interpolation_weights`; 1.37), or the line between its two neighbours where
    there are fewer (1.22); at either end, the line through the two nearest (2.45)."""
    k_all, c = r.rate.shape
    dev = np.full((k_all, c), np.nan)
    z = np.full((k_all, c), np.nan)
    lev = np.ones(k_all)
    for k in range(k_all):
        others = [i for i in range(k_all) if i != k and i not in skip]
        if not others:
            continue
        # the nearest in time on each side where there is one, else the two nearest on one side
        before = [i for i in others if r.time_s[i] <= r.time_s[k]]
        after = [i for i in others if r.time_s[i] > r.time_s[k]]
        if before and after:
            # inside: the calibration's own interpolation through the others (a cubic where it can;
            # leaving this reading out doubles the interval around it, hence the doubled ratio)
            idx, w = interpolation_weights([r.time_s[k]], r.time_s[others], 2.0 * SPACING_RATIO)
            used = w[0] != 0.0
            if used.sum() == 4:
                pick = [others[i] for i in idx[0]]
                a = w[0]
            else:
                # Short of two on each side a lopsided quadratic would lean on one neighbour so much
                # that a bad reading there condemns this one first: the line between the two.
                i, j = before[-1], after[0]
                f = (r.time_s[k] - r.time_s[i]) / (r.time_s[j] - r.time_s[i])
                pick, a = [i, j], np.array([1.0 - f, f])
        else:
            pick = sorted(others, key=lambda i: abs(r.time_s[i] - r.time_s[k]))[:2]
            if len(pick) == 1 or r.time_s[pick[0]] == r.time_s[pick[1]]:
                a = np.full(len(pick), 1.0 / len(pick))
            else:
                (i, j) = pick
                w = (r.time_s[k] - r.time_s[i]) / (r.time_s[j] - r.time_s[i])
                a = np.array([1.0 - w, w])
        predicted = sum(a[n] * r.rate[i] for n, i in enumerate(pick))
        var = r.stderr[k] ** 2 + sum(a[n] ** 2 * r.stderr[i] ** 2 for n, i in enumerate(pick))
        d = r.rate[k] - predicted
        dev[k] = d / r.scale
        lev[k] = np.sqrt(1.0 + float(np.sum(a ** 2)))
        with np.errstate(divide="ignore", invalid="ignore"):
            z[k] = np.where(var > 0, d / np.sqrt(var), np.nan)
    return dev, z, lev


def _check(r: Readings, relative: float) -> Readings:
    """Flag readings off their neighbours' line (module docstring), worst first."""
    skip: set = set()
    while len(r.step) - len(skip) >= 3 and len(skip) < len(r.step) // 3 + 1:
        dev, z, lev = _leave_one_out(r, skip)
        bad = (np.abs(dev) > relative) & ~(np.abs(z) <= JUMP_Z)  # NaN z (no stderr) counts as significant
        # an extrapolated line is less sure than an interpolated one: a bad reading spoils the
        # extrapolation to its neighbours as much as their line misses it, and must be the one found
        score = (np.where(bad, np.abs(dev), 0.0) / lev[:, None]).max(axis=1)
        score[list(skip)] = 0.0
        worst = int(np.argmax(score))
        if score[worst] <= 0.0:
            break
        skip.add(worst)
        r.flagged.append(worst)
    r.deviation, r.z, _ = _leave_one_out(r, skip)
    if len(r.step) == 2:  # two readings: which one is off cannot be told, only that they disagree
        d = (r.rate[1] - r.rate[0]) / r.scale
        r.deviation = np.stack([-d, d])
    return r


def calibration_readings(measurements: list) -> tuple[Readings, Readings]:
    """The white-reference readings (net of the dark, interpolated in time as the calibration does) and
    the dark readings, each checked against its neighbours (module docstring)."""
    kind = np.array([m.kind for m in measurements], dtype=np.int8)
    t = np.array([m.campaign_s for m in measurements], dtype=np.float64)
    exposure = np.array([m.exposure_s for m in measurements], dtype=np.float64)[:, None]
    rate = np.stack([m.signal for m in measurements]) / exposure
    err = np.stack([m.stderr for m in measurements]) / exposure
    steps = np.array([m.step for m in measurements])
    dk, rk = kind == STEP_DARK, kind == STEP_REFERENCE
    if not dk.any() or not rk.any():
        raise ValueError("the journal holds no dark or no white-reference reading: nothing calibrated it")
    dark_at_ref, dark_err = interpolate_readings(t[rk], t[dk], rate[dk], err[dk])
    net = rate[rk] - dark_at_ref
    scale = np.median(net, axis=0)
    scale = np.where(np.abs(scale) > 0, np.abs(scale), 1.0)
    ref = _check(Readings(steps[rk], t[rk], net, np.hypot(err[rk], dark_err), scale), REFERENCE_JUMP_RELATIVE)
    dark = _check(Readings(steps[dk], t[dk], rate[dk], err[dk], scale), DARK_JUMP_RELATIVE)
    return ref, dark
