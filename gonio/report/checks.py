"""Checks of the calibrated samples of a campaign: reciprocity, energy, invalid values, noise.

- **Reciprocity** (:func:`reciprocity_pairs`): every pair of samples that Helmholtz reciprocity says must
  agree, f(ωi, ωo) = f(ωo, ωi), and that were *both* measured (campaigns planned without the reciprocity
  shortcut; with it, one of each pair is measured and the other is taken from it). Pairs are matched on
  the planned directions (isotropic data: (θi, θo, Δφ) against (θo, θi, −Δφ); the azimuth of a direction
  at the pole does not count). Per pair of luminances, z = (f₁ − f₂) / √(σ₁² + σ₂²). Flagged when more
  than :data:`RECIPROCITY_BEYOND_3` of the pairs lie beyond 3σ (0.27 % for honest Gaussian errors) and the
  median relative difference exceeds :data:`RECIPROCITY_RELATIVE`.
- **Energy** (:func:`albedo_check`): directional albedo ∫ f_r cos θo dωo against θi, every
  :data:`ALBEDO_STEP_DEG`, integrated over the measured part of the hemisphere (a lower bound where the
  coverage is below 1). Flagged where any channel exceeds 1.
- **Invalid values** (:func:`invalid_values`): samples with a negative or NaN f_r in any channel.
- **Noise** (:func:`noise_check`): the scatter of repeated readings against the standard error they
  state: the white-reference and dark readings against what their neighbours in time predict (the
  calibration's interpolation, :mod:`gonio.report.journal`), and the reciprocal pairs above. The rms of
  those z-scores is ≈ 1 when the stated stddev is honest; above :data:`NOISE_UNDERSTATED` the stated
  stddev is too small (every uncertainty derived from it is too optimistic), below
  :data:`NOISE_OVERSTATED` too large.
"""

from __future__ import annotations

import numpy as np

from gonio.brdf import MeasuredBRDF
from gonio.dataset import SampledBRDF
from gonio.slices import LUMA, albedo_slice, luminance

__all__ = ["reciprocity_pairs", "albedo_check", "invalid_values", "noise_check", "sample_angles",
           "RECIPROCITY_BEYOND_3", "RECIPROCITY_RELATIVE", "ALBEDO_STEP_DEG", "NOISE_UNDERSTATED",
           "NOISE_OVERSTATED", "NOISE_MIN_READINGS"]

RECIPROCITY_BEYOND_3 = 0.05
RECIPROCITY_RELATIVE = 0.01
ALBEDO_STEP_DEG = 5.0
NOISE_UNDERSTATED = 2.0
NOISE_OVERSTATED = 0.5
#: Fewest readings (or pairs) whose rms z is judged: the rms of a few honest z-scores strays far from 1
#: (below 0.5 for 3 of them one time in seven; for 8, one time in fifty).
NOISE_MIN_READINGS = 8
#: Planned angles are matched to this many decimals (degrees).
_DECIMALS = 2


def sample_angles(data: SampledBRDF) -> np.ndarray:
    """(N, 4) θi, φi, θo, φo in degrees: the planned directions where the file has them, else measured."""
    if data.planned is not None:
        return np.asarray(data.planned, np.float64).reshape(-1, 4)
    return np.stack([np.asarray(a, np.float64).ravel() for a in
                     (data.theta_i, data.phi_i, data.theta_o, data.phi_o)], axis=1)


def _luma(values: np.ndarray, channels) -> np.ndarray:
    return luminance(np.asarray(values, np.float64), tuple(channels))


def _luma_sd(stddev: np.ndarray, channels) -> np.ndarray:
    w2 = LUMA ** 2 if tuple(channels) == ("R", "G", "B") else np.eye(1, np.shape(stddev)[1])[0]
    return np.sqrt(np.asarray(stddev, np.float64) ** 2 @ w2)


def reciprocity_pairs(data: SampledBRDF, b: MeasuredBRDF) -> dict:
    """Measured reciprocal pairs and their differences (module docstring).

    Returns
    -------
    dict
        ``applicable`` (False when the campaign used the reciprocity shortcut), ``pairs`` (count),
        ``theta`` ((P, 2) θi, θo of each pair, degrees), ``z`` (P,), ``relative`` (P,) (f₁ − f₂) / mean,
        ``rms_z``, ``beyond_3`` (fraction), ``median_relative`` (of |relative|), ``worst``
        (θi, φi, θo, φo, relative of the largest |relative|, or None), ``flag``.
    """
    out = {"applicable": not b.symmetries["reciprocity"], "pairs": 0, "theta": np.zeros((0, 2)),
           "z": np.zeros(0), "relative": np.zeros(0), "rms_z": float("nan"), "beyond_3": 0.0,
           "median_relative": 0.0, "worst": None, "flag": False}
    if not out["applicable"]:
        return out
    ang = sample_angles(data)
    ok = np.isfinite(ang).all(axis=1) & np.isfinite(np.asarray(data.value)).all(axis=1)
    ti, pi_, to, po = (np.round(ang[:, k], _DECIMALS) for k in range(4))
    pi_ = np.where(ti == 0, 0.0, pi_)
    po = np.where(to == 0, 0.0, po)
    if b.symmetries["isotropy"]:
        dphi = np.where((ti == 0) | (to == 0), 0.0, np.round(np.mod(po - pi_, 360.0), _DECIMALS) % 360.0)
        keys = [(a, c, d) for a, c, d in zip(ti, to, dphi, strict=True)]
        partner = [(c, a, round((360.0 - d) % 360.0, _DECIMALS)) for a, c, d in keys]
    else:
        pi_ = np.round(np.mod(pi_, 360.0), _DECIMALS) % 360.0
        po = np.round(np.mod(po, 360.0), _DECIMALS) % 360.0
        keys = [(a, p, c, q) for a, p, c, q in zip(ti, pi_, to, po, strict=True)]
        partner = [(c, q, a, p) for a, p, c, q in keys]
    index = {k: i for i, k in enumerate(keys) if ok[i]}
    pairs = [(i, index[partner[i]]) for i in range(len(keys))
             if ok[i] and partner[i] in index and index[partner[i]] > i]
    if not pairs:
        return out
    i, j = np.array(pairs).T
    y = _luma(data.value, b.channels)
    s = _luma_sd(data.stddev, b.channels)
    diff = y[i] - y[j]
    var = s[i] ** 2 + s[j] ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(var > 0, diff / np.sqrt(var), np.nan)
        mean = 0.5 * (y[i] + y[j])
        rel = np.where(np.abs(mean) > 0, diff / np.abs(mean), 0.0)
    zf = z[np.isfinite(z)]
    w = int(np.argmax(np.abs(rel)))
    out.update(pairs=len(pairs), theta=np.stack([ang[i, 0], ang[i, 2]], axis=1), z=z, relative=rel,
               rms_z=float(np.sqrt(np.mean(zf ** 2))) if zf.size else float("nan"),
               beyond_3=float(np.mean(np.abs(zf) > 3.0)) if zf.size else 0.0,
               median_relative=float(np.median(np.abs(rel))),
               worst=(*(float(a) for a in ang[i[w]]), float(rel[w])))
    out["flag"] = bool(out["beyond_3"] > RECIPROCITY_BEYOND_3
                       and out["median_relative"] > RECIPROCITY_RELATIVE)
    return out


def albedo_check(b: MeasuredBRDF, phi_i_deg: float = 0.0) -> dict:
    """Directional albedo against θi (module docstring).

    Returns
    -------
    dict
        ``theta_i`` (degrees), ``albedo`` (T, C), ``coverage`` (T,), ``channels``, ``max`` (largest value),
        ``at`` (its θi), ``over`` (θi where a channel exceeds 1), ``flag``, ``phi_i_deg``.
    """
    top = min(b.theta_max_deg, 89.0)
    thetas = np.arange(0.0, top + 1e-9, ALBEDO_STEP_DEG)
    s = albedo_slice(b, thetas, phi_i_deg)
    alb = s.image[0]
    peak = int(np.unravel_index(np.argmax(alb), alb.shape)[0])
    over = thetas[(alb > 1.0).any(axis=1)]
    return {"theta_i": thetas, "albedo": alb, "coverage": np.asarray(s.attrs["coverage"]),
            "channels": b.channels, "max": float(alb.max()), "at": float(thetas[peak]),
            "over": over, "flag": bool(over.size), "phi_i_deg": phi_i_deg}


def invalid_values(data: SampledBRDF) -> dict:
    """Samples with a negative or NaN f_r.

    Returns
    -------
    dict
        ``negative`` and ``nan`` (sample counts), ``negative_values`` and ``nan_values`` (value counts),
        ``samples`` (N), ``rows`` (for each bad sample: step, θi, φi, θo, φo, the channels and values),
        ``flag``.
    """
    value = np.asarray(data.value, np.float64)
    nan = ~np.isfinite(value)
    neg = np.isfinite(value) & (value < 0)
    bad = np.flatnonzero(nan.any(axis=1) | neg.any(axis=1))
    ang = sample_angles(data)
    channels = [str(c) for c in data.attrs.get("channels", [])] or [f"c{k}" for k in range(value.shape[1])]
    steps = data.step if data.step is not None else np.full(len(value), -1)
    rows = [{"step": int(steps[k]), "angles": [float(a) for a in ang[k]],
             "channels": [channels[c] for c in np.flatnonzero(nan[k] | neg[k])],
             "values": [float(v) for v in value[k][nan[k] | neg[k]]]} for k in bad]
    return {"negative": int(neg.any(axis=1).sum()), "nan": int(nan.any(axis=1).sum()),
            "negative_values": int(neg.sum()), "nan_values": int(nan.sum()), "samples": len(value),
            "rows": rows, "flag": bool(bad.size)}


def _rms(z: np.ndarray) -> tuple[float, int]:
    """rms of the finite z-scores (readings, or readings × channels) and how many readings have one:
    the channels of one reading share its sources of error, so they do not count apart."""
    z = np.asarray(z, np.float64)
    rows = z.reshape(z.shape[0], -1) if z.ndim else z.reshape(1, 1)
    finite = z[np.isfinite(z)]
    return (float(np.sqrt(np.mean(finite ** 2))) if finite.size else float("nan")), \
        int(np.isfinite(rows).any(axis=1).sum())


def noise_check(reference, dark, pairs: dict) -> dict:
    """Repeat readings against their stated standard errors (module docstring).

    Returns
    -------
    dict
        ``rows``: per source (``what``, ``rms_z``, ``n`` readings, ``tested`` (n at least
        :data:`NOISE_MIN_READINGS`), ``verdict``), and ``flag`` (a tested source whose rms z is above
        :data:`NOISE_UNDERSTATED`).
    """
    rows = []
    for what, r in (("white-reference readings against their neighbours' interpolation", reference),
                    ("dark readings against their neighbours' interpolation", dark)):
        keep = [k for k in range(len(r.step)) if k not in r.flagged]
        rms, n = _rms(r.z[keep]) if r.z is not None else (float("nan"), 0)
        rows.append({"what": what, "rms_z": rms, "n": n})
    if pairs["applicable"]:
        rms, n = _rms(pairs["z"])
        rows.append({"what": "reciprocal pairs: f(ωi, ωo) against f(ωo, ωi)", "rms_z": rms, "n": n})
    for row in rows:
        row["tested"] = row["n"] >= NOISE_MIN_READINGS
        if not row["tested"]:
            row["verdict"] = (f"too few readings with a stated stddev > 0 to tell ({row['n']}; "
                              f"{NOISE_MIN_READINGS} needed)")
        elif row["rms_z"] > NOISE_UNDERSTATED:
            row["verdict"] = f"scatter {row['rms_z']:.2g}× the stated stddev: the stddev is understated"
        elif row["rms_z"] < NOISE_OVERSTATED:
            row["verdict"] = f"scatter {row['rms_z']:.2g}× the stated stddev: the stddev is overstated"
        else:
            row["verdict"] = "consistent with the stated stddev"
    flag = any(r["tested"] and r["rms_z"] > NOISE_UNDERSTATED for r in rows)
    return {"rows": rows, "flag": flag}
