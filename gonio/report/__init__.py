"""The campaign report (``gonio report``): one self-contained HTML page a lab reads to judge a measurement.

``report(folder, out)`` reads a finished campaign folder (its journal and its ``brdf.h5``) and writes a
page with a short summary of verdict lines at the top, then sections:

- **the campaign** (:mod:`gonio.report.journal`): gantry, grid, the shortcuts the plan used and the
  poses they saved, steps, campaign time against the plan's estimate, faults and retries from the
  journal's events;
- **calibration**: the white-reference and dark readings over campaign time (drift, and readings the
  calibration's cubic interpolation in time cannot absorb), the reference albedo (the standard's
  reflectance per channel where the campaign was calibrated with one);
- **data checks** (:mod:`gonio.report.checks`): reciprocity of the pairs measured both ways, directional
  albedo against θi (energy conservation), negative and NaN samples, and the scatter of repeated
  readings against the stddev they state;
- **fits** of several models side by side, ranked by error per degree of freedom, and **where each
  fails** (specular peak, Fresnel rise, grazing angles, body) from their residuals binned by angle
  (:mod:`gonio.report.models`).

Figures are PNGs embedded as base64 (:mod:`gonio.report.figures`); the page loads nothing else. The page is
written under a temporary name and renamed into place: an error leaves no file behind.

Example
-------
>>> r = report("runs/gold", "runs/gold/report.html")                        # doctest: +SKIP
>>> [m["model"] for m in r.fits][:2], r.flags                               # doctest: +SKIP
(['cook-torrance', 'ward'], {'reference': False, 'dark': False, ...})
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gonio.brdf import open_brdf
from gonio.dataset import BRDF_NAME, SampledBRDF, read_brdf
from gonio.formats import atomic_path
from gonio.report import checks, figures, journal
from gonio.report.models import DEFAULT_MODELS, REGIONS, fit_models, parse_models
from gonio.store import JOURNAL_NAME

__all__ = ["report", "build_report", "Report", "DEFAULT_MODELS", "REGIONS", "parse_models", "SUFFIXES"]

SUFFIXES = (".html", ".htm")


@dataclass
class Report:
    """What the report found (the page is :attr:`html`).

    Attributes
    ----------
    facts : dict
        :func:`gonio.report.journal.campaign_facts`, and ``reference_reflectance``: brdf.h5's white
        standard per channel (None where it was calibrated with the albedo alone).
    verdicts : list of (level, topic, text)
        The summary lines; level is ``ok``, ``flag``, ``note`` or ``info``.
    flags : dict of str to bool
        ``reference``, ``dark``, ``reciprocity``, ``albedo``, ``invalid``, ``noise``: what was flagged.
    fits : list of dict
        :func:`gonio.report.models.fit_models`, best first.
    adaptive : dict or None
        An adaptive campaign's ``pilot`` and ``rounds`` shares of poses with θh <= NEAR_SPECULAR_DEG.
    """

    folder: Path
    facts: dict
    reference: journal.Readings
    dark: journal.Readings
    pairs: dict
    albedo: dict
    invalid: dict
    noise: dict
    fits: list
    verdicts: list = field(default_factory=list)
    figures: dict = field(default_factory=dict)
    html: str = ""
    #: An adaptive campaign's share of pilot and round poses near the specular direction (None otherwise).
    adaptive: dict | None = None

    @property
    def flags(self) -> dict[str, bool]:
        return {"reference": bool(self.reference.flagged), "dark": bool(self.dark.flagged),
                "reciprocity": self.pairs["flag"], "albedo": self.albedo["flag"],
                "invalid": self.invalid["flag"], "noise": self.noise["flag"]}


def _check_folder(folder: Path) -> Path:
    if not folder.is_dir():
        raise ValueError(f"{folder}: no such campaign folder")
    if not (folder / JOURNAL_NAME).is_file():
        raise ValueError(f"{folder}: not a campaign folder (no {JOURNAL_NAME})")
    if not (folder / BRDF_NAME).is_file():
        raise ValueError(f"{folder}: not a finished campaign (no {BRDF_NAME}; it is written once every step "
                         "is measured)")
    return folder


def build_report(folder, models: list[str] | str | None = None, *, starts: int = 3) -> Report:
    """Everything the report says about the finished campaign in ``folder``, and its page.

    Parameters
    ----------
    folder : str or Path
        A finished campaign folder.
    models : list of str, str or None
        Fit MODELs (:mod:`gonio.fit.models`), or a comma-separated string of them; None:
        :data:`DEFAULT_MODELS`.
    starts : int
        Starts per fit (the best wins).

    Returns
    -------
    Report

    Raises
    ------
    ValueError
        Not a finished campaign, an unknown model.
    """
    names = parse_models(models if models is None or isinstance(models, str) else ",".join(models))
    folder = _check_folder(Path(folder))
    facts, measurements = journal.campaign_facts(folder)
    data: SampledBRDF = read_brdf(folder / BRDF_NAME)
    # the white standard per channel, where the campaign calibrated so (brdf.h5 records what it divided by)
    facts["reference_reflectance"] = data.attrs.get("reference_reflectance")
    if facts["steps"]["total"] != facts["measured"]:
        raise ValueError(f"{folder}: the campaign is incomplete ({facts['measured']}/"
                         f"{facts['steps']['total']} steps measured)")
    b = open_brdf(data)
    reference, dark = journal.calibration_readings(measurements)
    pairs = checks.reciprocity_pairs(data, b)
    albedo = checks.albedo_check(b)
    invalid = checks.invalid_values(data)
    noise = checks.noise_check(reference, dark, pairs)
    fits = fit_models(folder, names, starts=starts)
    rep = Report(folder, facts, reference, dark, pairs, albedo, invalid, noise, fits)
    rep.verdicts = _verdicts(rep)
    rep.figures = {"calibration": figures.calibration(reference, dark, facts["channels"]),
                   "overview": figures.overview(b, data), "albedo": figures.albedo(albedo),
                   "residuals": figures.residual_maps(fits)}
    if pairs["pairs"]:
        rep.figures["reciprocity"] = figures.reciprocity(pairs)
    if facts["adaptive"]:
        rep.figures["adaptive"] = figures.adaptive_poses(data, facts["adaptive"])
        rep.adaptive = _adaptive_share(data, facts["adaptive"])
    from gonio.report.html import render

    rep.html = render(rep)
    return rep


def report(folder, out, models: list[str] | str | None = None, *, starts: int = 3) -> Report:
    """Write the report of the finished campaign in ``folder`` to ``out`` (``.html``); see
    :func:`build_report`. Nothing is written unless the whole page is."""
    out = Path(out)
    if out.suffix.lower() not in SUFFIXES:
        raise ValueError(f"output {str(out)!r}: the report is an HTML page; end the name in .html")
    rep = build_report(folder, models, starts=starts)
    with atomic_path(out) as tmp:
        tmp.write_text(rep.html, encoding="utf-8")
    return rep


#: θh within which a pose counts as in the specular lobe's neighbourhood (the report's share of poses).
NEAR_SPECULAR_DEG = 10.0


def _adaptive_share(data: SampledBRDF, adaptive: dict) -> dict:
    """The share of the pilot's poses and of the rounds' with θh <= :data:`NEAR_SPECULAR_DEG`."""
    phase = figures.phases(data.step, adaptive)
    near = figures.half_angles_deg(data)[0] <= NEAR_SPECULAR_DEG
    return {"pilot": float(near[phase == 0].mean()) if np.any(phase == 0) else 0.0,
            "rounds": float(near[phase > 0].mean()) if np.any(phase > 0) else 0.0}


def _hms(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


def _verdicts(rep: Report) -> list[tuple[str, str, str]]:
    f, out = rep.facts, []
    est = f["estimated_s"]
    late = est > 0 and f["campaign_s"] > 1.2 * est
    events = f"{f['faults']} faults, {f['retries']} retries, {f['runs'] - 1} resumes"
    out.append(("note" if f["faults"] or f["retries"] or late else "ok", "campaign",
                f"{f['steps']['total']:,} steps ({f['poses']:,} poses) measured in {_hms(f['campaign_s'])} "
                f"of campaign time (plan estimate {_hms(est)}); {events}"))
    r = rep.reference
    if r.flagged:
        worst = [f"step {r.step[i]} ({100 * max(r.deviation[i], key=abs):+.0f} %)" for i in r.flagged]
        out.append(("flag", "white reference", f"{len(r.flagged)} of {len(r.step)} readings off the line "
                    f"through their neighbours: {', '.join(worst)}; the samples calibrated against them are "
                    "off too"))
    else:
        drift = 100 * max(r.drift, key=abs)
        out.append(("ok", "white reference", f"{len(r.step)} readings, consistent with their neighbours; "
                    f"drift {drift:+.2f} % over the campaign (corrected by interpolation)"))
    d = rep.dark
    out.append(("flag", "dark", f"{len(d.flagged)} of {len(d.step)} dark readings jump: steps "
                f"{', '.join(str(d.step[i]) for i in d.flagged)}") if d.flagged else
               ("ok", "dark", f"{len(d.step)} readings, no jumps"))
    p = rep.pairs
    if not p["applicable"]:
        out.append(("info", "reciprocity", "not checked: the campaign used the reciprocity shortcut (no pair "
                    "measured both ways)"))
    elif not p["pairs"]:
        out.append(("info", "reciprocity", "no pair has both members measured"))
    else:
        out.append(("flag" if p["flag"] else "ok", "reciprocity",
                    f"{p['pairs']} measured pairs, {100 * p['beyond_3']:.1f} % beyond ±3σ, median difference "
                    f"{100 * p['median_relative']:.2f} %"))
    a = rep.albedo
    out.append(("flag", "energy", f"directional albedo above 1 at θi = "
                f"{', '.join(f'{t:g}°' for t in a['over'])} (max {a['max']:.3f})") if a["flag"] else
               ("ok", "energy", f"directional albedo ≤ 1 at every θi (max {a['max']:.3f} at θi = "
                f"{a['at']:g}°)"))
    v = rep.invalid
    out.append(("flag", "values", f"{v['negative']} negative and {v['nan']} NaN samples of {v['samples']:,}")
               if v["flag"] else ("ok", "values", f"no negative or NaN values in {v['samples']:,} samples"))
    bad = [row for row in rep.noise["rows"] if row["tested"] and row["rms_z"] > checks.NOISE_UNDERSTATED]
    low = [row for row in rep.noise["rows"] if row["tested"] and row["rms_z"] < checks.NOISE_OVERSTATED]
    if bad:
        out.append(("flag", "noise", "stated stddev understated: " + "; ".join(
            f"{row['what'].split(':')[0]} scatter {row['rms_z']:.2g}×" for row in bad)))
    elif low:
        out.append(("note", "noise", "stated stddev larger than the scatter: " + "; ".join(
            f"{row['what'].split(':')[0]} {row['rms_z']:.2g}×" for row in low)))
    else:
        tested = [row for row in rep.noise["rows"] if row["tested"]]
        out.append(("ok" if tested else "info", "noise",
                    "repeat readings scatter as their stated stddev says" if tested else
                    "too few repeat readings with a stddev to compare"))
    ok = [m for m in rep.fits if m["result"] is not None]
    if ok:
        best = ok[0]
        ranking = ", ".join(f"{m['rank']}. {m['model']}" for m in ok)
        out.append(("ok" if not best["flagged"] else "note", "best model",
                    f"{best['model']} (χ²/dof {best['per_dof']:.3g}) {best['words']}; ranking: {ranking}"))
        for m in ok[1:]:
            if m["flagged"]:
                measured = [k for k, g in m["regions"].items() if g["n"]]
                where = "everywhere" if len(m["flagged"]) == len(measured) > 1 else \
                    ", ".join(REGIONS[k] for k in m["flagged"])
                out.append(("info", m["model"], f"fails {where} (χ²/dof {m['per_dof']:.3g})"))
    failed = [m for m in rep.fits if m["result"] is None]
    for m in failed:
        out.append(("note", m["model"], m["words"]))
    return out
