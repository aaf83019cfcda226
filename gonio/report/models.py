"""Several models fitted side by side, ranked, and where each one fails (model selection help).

Every model is fitted with :func:`gonio.fit.fit` (its default loss: χ² with the measured stddev) and
ranked by its error per degree of freedom, the loss over (residuals − parameters) (χ²/dof: ≈ 1 for a
model that fits within the noise). A model that fails to fit at all is listed last with its error.

Where a model fails is read from its residuals d = f_model − f_measured, binned by angle into four
disjoint regions; a sample belongs to the first that holds it:

============== ============================================= ==========================================
region         samples                                       what fails there
============== ============================================= ==========================================
specular peak  θh < :data:`PEAK_THETA_H_DEG` and              the lobe's height and width (the
               θd < :data:`FRESNEL_THETA_D_DEG`               microfacet distribution)
Fresnel rise   θd ≥ :data:`FRESNEL_THETA_D_DEG`               the rise of reflectance towards grazing
                                                             difference angles (the Fresnel term)
grazing        max(θi, θo) ≥ :data:`GRAZING_THETA_DEG`         shadowing and masking, the cosine falloff
body           everything else                               the diffuse part and the lobe's tails
============== ============================================= ==========================================

(θh, θd: Rusinkiewicz half and difference angles.) Per region and over all channels: ``bias`` =
Σd / Σf (the model is that much too high, or too low where negative), ``rms`` = √(Σd² / Σf²), and
``chi2`` = mean((d/σ)²). A region is flagged when its ``rms`` exceeds :data:`REGION_RELATIVE` *and*
its ``chi2`` exceeds :data:`REGION_CHI2` (the misfit is both large and far beyond the noise), with at
least :data:`REGION_MIN_SAMPLES` samples in it.
"""

from __future__ import annotations

import time

import numpy as np

from gonio.fit import FitData, fit, load_samples, parse_model
from gonio.geometry import to_half_diff
from gonio.sim.materials import load

__all__ = ["DEFAULT_MODELS", "REGIONS", "parse_models", "fit_models", "regions_of", "PEAK_THETA_H_DEG",
           "FRESNEL_THETA_D_DEG", "GRAZING_THETA_DEG", "REGION_RELATIVE", "REGION_CHI2", "REGION_MIN_SAMPLES"]

#: Each model as its material: a lobe with its diffuse part rho_d (most samples have one; the lobe alone,
#: NAME-lobe, ends at its bounds on such data: ward at its alpha bound, ggx with alpha 0.67 on data made
#: with 0.15); lambert alone beside them says how much a lobe adds. A pure metal gets rho_d ≈ 0.
DEFAULT_MODELS = ("lambert", "ward", "cook-torrance", "ggx")
PEAK_THETA_H_DEG = 10.0
FRESNEL_THETA_D_DEG = 60.0
GRAZING_THETA_DEG = 70.0
REGION_RELATIVE = 0.05
REGION_CHI2 = 9.0
REGION_MIN_SAMPLES = 3
#: Region names in order of precedence, and the words for them.
REGIONS = {"peak": "at the specular peak", "fresnel": "in the Fresnel rise", "grazing": "at grazing angles",
           "body": "in the body"}


def parse_models(text: str | None) -> list[str]:
    """``"ggx-lobe,ggx"`` → the model list (each checked by :func:`gonio.fit.parse_model`); None →
    :data:`DEFAULT_MODELS`. Raises ValueError naming ``--models`` and the bad entry."""
    if text is None:
        return list(DEFAULT_MODELS)
    # a comma also separates a model's own items (cook-torrance:d=blinn,fresnel=none): an item without
    # '=' or 'anisotropic' after a model with ':' starts the next model
    models: list[str] = []
    for part in (p.strip() for p in str(text).split(",")):
        if not part:
            continue
        if models and ":" in models[-1] and ("=" in part or part == "anisotropic") and ":" not in part:
            models[-1] += "," + part
        else:
            models.append(part)
    if not models:
        raise ValueError(f"--models: expected a comma-separated list of fit models, got {text!r}")
    if len(set(models)) != len(models):
        raise ValueError(f"--models: a model is listed twice in {text!r}")
    for m in models:
        try:
            parse_model(m)
        except ValueError as err:
            raise ValueError(f"--models: {err}") from None
    return models


def regions_of(data: FitData) -> dict[str, np.ndarray]:
    """Boolean masks (N,) of the four disjoint regions of the module docstring."""
    th, _, td, _ = to_half_diff(data.wi, data.wo)
    th, td = np.degrees(th), np.degrees(td)
    graz = np.degrees(np.arccos(np.clip(np.minimum(data.wi[:, 2], data.wo[:, 2]), -1.0, 1.0)))
    peak = (th < PEAK_THETA_H_DEG) & (td < FRESNEL_THETA_D_DEG)
    fresnel = td >= FRESNEL_THETA_D_DEG
    grazing = (graz >= GRAZING_THETA_DEG) & ~peak & ~fresnel
    return {"peak": peak, "fresnel": fresnel, "grazing": grazing, "body": ~(peak | fresnel | grazing)}


def _region_stats(d: np.ndarray, f: np.ndarray, sd: np.ndarray, masks: dict) -> dict:
    floor = np.nanmin(np.where(sd > 0, sd, np.nan)) if np.any(sd > 0) else 1.0
    z2 = (d / np.maximum(sd, floor)) ** 2
    out = {}
    for name, m in masks.items():
        n = int(m.sum())
        if n == 0:
            out[name] = {"n": 0, "bias": float("nan"), "rms": float("nan"), "chi2": float("nan"),
                         "flag": False}
            continue
        fs, ds = f[m], d[m]
        denom = max(float(np.sum(np.abs(fs))), 1e-300)
        bias = float(np.sum(ds) / denom)
        rms = float(np.sqrt(np.sum(ds ** 2) / max(float(np.sum(fs ** 2)), 1e-300)))
        chi2 = float(np.mean(z2[m]))
        out[name] = {"n": n, "bias": bias, "rms": rms, "chi2": chi2,
                     "flag": bool(n >= REGION_MIN_SAMPLES and rms > REGION_RELATIVE and chi2 > REGION_CHI2)}
    return out


def _words(regions: dict) -> str:
    """Where a model fails, in words: each flagged region with the direction of the misfit."""
    bad = [k for k, r in regions.items() if r["flag"]]
    if not bad:
        worst = max((r["rms"] for r in regions.values() if r["n"]), default=0.0)
        return f"fits in every region (within {100 * worst:.2g} % rms)"
    parts = []
    for k in bad:
        r = regions[k]
        if abs(r["bias"]) >= 0.5 * r["rms"]:
            side = "high" if r["bias"] > 0 else "low"
            parts.append(f"{REGIONS[k]} (too {side} by {100 * abs(r['bias']):.0f} %)")
        else:
            parts.append(f"{REGIONS[k]} (off by {100 * r['rms']:.0f} % rms, both ways)")
    every = len(bad) == len([r for r in regions.values() if r["n"]]) and len(bad) > 1
    return ("fails everywhere: " if every else "fails ") + ", ".join(parts)


def fit_models(source, models: list[str], *, starts: int = 3) -> list[dict]:
    """Fit each model to the campaign ``source`` and rank them (module docstring).

    Returns
    -------
    list of dict, best first
        ``model``, ``rank`` (1 = best; None when the fit failed), ``result`` (FitResult or None),
        ``error`` (str or None), ``per_dof`` (loss / dof), ``regions`` (per region: n, bias, rms, chi2,
        flag), ``flagged`` (region names), ``words``, ``relative`` (model − data) / data per sample
        (data floored at 1 % of its largest luminance), and ``theta_h``/``theta_d`` (degrees) of the
        samples for the residual maps.
    """
    data, _ = load_samples(source)
    keep = np.isfinite(data.value).all(axis=1) & (data.wi[:, 2] > 0) & (data.wo[:, 2] > 0)
    wi, wo = data.wi[keep], data.wo[keep]
    f = data.value[keep]
    sd = np.zeros_like(f) if data.stddev is None else np.nan_to_num(data.stddev[keep])
    kept = FitData(wi, wo, f, sd)
    masks = regions_of(kept)
    th, _, td, _ = to_half_diff(wi, wo)
    floor = 0.01 * max(float(np.max(np.abs(f))), 1e-300)
    out = []
    for model in models:
        t0 = time.perf_counter()
        row = {"model": model, "result": None, "error": None, "per_dof": float("inf"), "regions": {},
               "flagged": [], "words": "", "relative": None, "theta_h": np.degrees(th),
               "theta_d": np.degrees(td), "seconds": 0.0}
        try:
            r = fit(source, model, starts=starts)
        except ValueError as err:
            row["error"] = str(err)
            row["words"] = f"the fit failed: {err}"
            out.append(row)
            continue
        # the model as the fit saw it: averaged over the cones where the data gave them
        fm = load(r.material).eval(wi, wo, precision="float64") if r.aperture is None else \
            r.aperture.evaluate(load(r.material), wi, wo)
        d = fm - f
        row.update(result=r, per_dof=float(r.residual["chi2_reduced"]), seconds=time.perf_counter() - t0)
        row["regions"] = _region_stats(d, f, sd, masks)
        row["flagged"] = [k for k, v in row["regions"].items() if v["flag"]]
        row["words"] = _words(row["regions"])
        row["relative"] = (d / np.maximum(np.abs(f), floor)).mean(axis=1)
        out.append(row)
    out.sort(key=lambda r: (r["result"] is None, r["per_dof"]))
    for k, r in enumerate(out):
        r["rank"] = k + 1 if r["result"] is not None else None
    return out
