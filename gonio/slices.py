"""Slices of a measured BRDF on regular pixel grids: what :mod:`gonio.plot` draws and writes as EXR.

Each slice is f_r (or a quantity made from it) evaluated through :mod:`gonio.brdf` at the directions
of a pixel grid that the slice's ``mapping`` states in words; the same words go into the EXR header
(``gonio:mapping``), so that anyone can recompute a pixel's directions. Rows run top to bottom as in the
image file; pixel (row r, column c) of an H × W slice has centre u = (c + 0.5)/W, v = (r + 0.5)/H.

=============== ==========================================================================================
kind            pixels
=============== ==========================================================================================
``polar``       row r: θi = ``rows_deg[r]`` at φi; column c: signed in-plane θo = −90° + 180°·u (positive
                on the specular side, φo = φi + 180°; negative on the light's side, φo = φi). f_r, sr⁻¹.
``hemisphere``  ωi given; ωo in the azimuthal equidistant projection seen from above: x = 2u − 1 (toward
                +x), y = 1 − 2v (toward +y), θo = 90°·√(x² + y²), φo = atan2(y, x); NaN outside the disc.
``merl``        θh = 90°·u, θd = 90°·(1 − v) (θd up), φd = 90°, φh = 0 (Rusinkiewicz angles). f_r.
``reciprocity`` θi = θmax·u (columns), θo = θmax·(1 − v) (rows, θo up), φi = given, φo = φi + 180°:
                relative difference (f(ωi, ωo) − f(ωo, ωi)) / ((f(ωi, ωo) + f(ωo, ωi))/2); NaN where
                θi > θo (the other half is the same with the opposite sign).
``albedo``      one row; column c: θi = ``cols_deg[c]``: directional albedo ∫ f_r cos θo dωo over the
                measured part of the hemisphere (midpoint rule, 1° in θo, 5° in φo); dimensionless.
=============== ==========================================================================================

Every slice is NaN where nothing was measured: where :mod:`gonio.brdf` has no value (its reason code), and
within the blocked cone (:func:`blocked_cone_deg`), where ωo lies closer to ωi than the gantry's
``clearance_deg`` (the light arm hides the detector there), whatever an interpolating engine would answer
(the ``scattered`` and ``local`` engines of a real gantry's or an adaptive campaign's data reach across it
from the samples around it; a lattice leaves it NaN by itself).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gonio.brdf import MeasuredBRDF, Reason
from gonio.geometry import from_half_diff, sph_to_vec

__all__ = ["Slice", "polar_slice", "hemisphere_slice", "merl_slice", "reciprocity_slice", "albedo_slice",
           "write_exr", "luminance", "blocked_cone_deg", "blocked", "blocked_deg", "grid_step", "polar_runs"]

#: Rec. 709 luminance weights of linear R, G, B (the house's RGB; also the Radiance export's).
LUMA = np.array([0.2126, 0.7152, 0.0722])


@dataclass
class Slice:
    """A slice: ``image`` (H, W, C) float64 in the units of ``quantity``, and how its pixels map."""

    kind: str
    image: np.ndarray
    channels: tuple
    quantity: str
    mapping: str
    attrs: dict = field(default_factory=dict)


def luminance(values: np.ndarray, channels) -> np.ndarray:
    """Y of (..., 3) linear R, G, B; the first channel of anything else."""
    values = np.asarray(values, dtype=np.float64)
    return values @ LUMA if tuple(channels) == ("R", "G", "B") else values[..., 0]


def _centres(n: int) -> np.ndarray:
    return (np.arange(n) + 0.5) / n


def blocked_cone_deg(b: MeasuredBRDF) -> float:
    """Half-angle (degrees) of the cone about ωi in which no ωo was measured: the gantry's
    ``kinematics.clearance_deg`` (the light arm or housing hides the detector there) as the campaign's
    config snapshot records it; 0 for data without one (nothing is assumed)."""
    from gonio.config import KinematicsConfig

    cfg = b.attrs.get("config")
    kin = cfg.get("kinematics") if isinstance(cfg, dict) else None
    if not isinstance(kin, dict):
        return 0.0
    # the snapshot leaves out what the config left at its default
    cone = kin.get("clearance_deg", KinematicsConfig.model_fields["clearance_deg"].default)
    try:
        cone = float(cone)
    except (TypeError, ValueError):
        return 0.0
    return cone if 0.0 < cone < 90.0 else 0.0


def blocked(b: MeasuredBRDF, wi, wo) -> np.ndarray:
    """bool, flattened as :meth:`~gonio.brdf.MeasuredBRDF.eval`: the pairs whose ωo lies within the blocked
    cone about ωi (:func:`blocked_cone_deg`), where nothing can have been measured."""
    cone = blocked_cone_deg(b)
    wi, wo = (np.asarray(w, dtype=np.float64) for w in np.broadcast_arrays(wi, wo))
    wi, wo = wi.reshape(-1, 3), wo.reshape(-1, 3)
    if cone == 0.0:
        return np.zeros(len(wi), dtype=bool)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.einsum("nk,nk->n", wi, wo) / (np.linalg.norm(wi, axis=1) * np.linalg.norm(wo, axis=1))
    return cos > np.cos(np.radians(cone) - 1e-9)  # a pose at the clearance itself is measured


def blocked_deg(b: MeasuredBRDF, ti, pi_, to, po) -> np.ndarray:
    """:func:`blocked` of pairs given as angles in degrees (broadcast and flattened)."""
    ti, pi_, to, po = (np.radians(np.asarray(a, dtype=np.float64)).ravel()
                       for a in np.broadcast_arrays(ti, pi_, to, po))
    return blocked(b, sph_to_vec(ti, pi_), sph_to_vec(to, po))


def _eval(b: MeasuredBRDF, ti, pi_, to, po) -> np.ndarray:
    """f_r, NaN where nothing was measured (the engine's gaps and the blocked cone)."""
    ev = b.eval_deg(ti, pi_, to, po)
    value = ev.value.copy()
    value[blocked_deg(b, ti, pi_, to, po)] = np.nan
    return value


def grid_step(b: MeasuredBRDF) -> float | None:
    """The lattice step (degrees) of an ``iso`` or ``full`` campaign: its in-plane samples are neighbours one
    step apart. None for other grids (their samples lie off any one plane)."""
    from gonio.plan.grids import parse_grid

    try:
        return parse_grid(str(b.attrs.get("grid", ""))).step_deg
    except ValueError:
        return None


def polar_runs(b, theta_i, phi_i, signed, row, samples, step):
    """The lines of one θi of an in-plane plot: a list of (x, Y) runs, each drawn as one unbroken line.

    On a stepped grid a run joins neighbouring measured samples only (``samples``: (signed θo, planned
    signed θo) rows; neighbours were planned one grid step apart), through the interpolant between them, so
    that a gap (the blocked cone about ωo = ωi, an infeasible pose) breaks the line instead of bridging
    it. Other grids: the stretches of ``row`` (the slice's values at ``signed``) where the interpolant has
    a value."""
    if step is None:
        return _finite_runs(signed, row)
    samples = np.unique(np.asarray(samples, dtype=np.float64).reshape(-1, 2), axis=0)
    samples = samples[np.argsort(samples[:, 1], kind="stable")]
    pieces = []
    for (xa, pa), (xb, pb) in zip(samples[:-1], samples[1:], strict=True):
        if not 0.0 <= pb - pa <= step * (1.0 + 1e-6) or xb <= xa:  # (the same pose read twice: joined)
            continue
        x = np.concatenate([[xa], signed[(signed > xa) & (signed < xb)], [xb]])
        ti = np.full_like(x, theta_i)
        pi_ = np.full_like(x, phi_i)
        po = np.where(x >= 0, phi_i + 180.0, phi_i)
        value = b.eval_deg(ti, pi_, np.abs(x), po).value.copy()
        value[blocked_deg(b, ti, pi_, np.abs(x), po)] = np.nan
        pieces.extend(_finite_runs(x, luminance(value, b.channels)))
    runs = []
    for x, y in pieces:  # one line through neighbouring pieces that share a sample
        if runs and runs[-1][0][-1] == x[0]:
            runs[-1] = (np.concatenate([runs[-1][0], x[1:]]), np.concatenate([runs[-1][1], y[1:]]))
        else:
            runs.append((x, y))
    return runs


def _finite_runs(x, y):
    """The maximal stretches of (x, y) where y is finite, as (x, y) pairs of at least two points."""
    ok = np.isfinite(y)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(np.int8), [0]])))
    return [(x[a:e], y[a:e]) for a, e in zip(edges[::2], edges[1::2], strict=True) if e - a >= 2]


def polar_slice(b: MeasuredBRDF, thetas_i_deg, phi_i_deg: float = 0.0, width: int = 361) -> Slice:
    """f_r in the plane of incidence for each θi of ``thetas_i_deg`` (rows), signed θo (columns)."""
    rows = np.asarray(thetas_i_deg, dtype=np.float64)
    signed = -90.0 + 180.0 * _centres(width)
    ti, so = np.meshgrid(rows, signed, indexing="ij")
    po = np.where(so >= 0, phi_i_deg + 180.0, phi_i_deg)
    v = _eval(b, ti, phi_i_deg, np.abs(so), po).reshape(len(rows), width, -1)
    return Slice("polar", v, b.channels, "f_r [sr^-1]",
                 "row r: theta_i = rows_deg[r], phi_i given; column c: signed in-plane theta_o = -90 + "
                 "180*(c+0.5)/W deg, phi_o = phi_i+180 where >= 0 (specular side), phi_o = phi_i where < 0",
                 {"rows_deg": rows.tolist(), "phi_i_deg": float(phi_i_deg)})


def hemisphere_slice(b: MeasuredBRDF, theta_i_deg: float, phi_i_deg: float, size: int = 181) -> Slice:
    """f_r over ωo for one ωi, in the azimuthal equidistant projection of the hemisphere."""
    x = 2.0 * _centres(size) - 1.0
    xx, yy = np.meshgrid(x, -x)
    r = np.hypot(xx, yy)
    to = 90.0 * r
    po = np.degrees(np.arctan2(yy, xx))
    v = _eval(b, theta_i_deg, phi_i_deg, np.where(r < 1.0, to, np.nan), po).reshape(size, size, -1)
    return Slice("hemisphere", v, b.channels, "f_r [sr^-1]",
                 "x = 2(c+0.5)/W - 1 (+x right), y = 1 - 2(r+0.5)/H (+y up), theta_o = 90*sqrt(x^2+y^2) "
                 "deg, phi_o = atan2(y, x); NaN outside the disc",
                 {"theta_i_deg": float(theta_i_deg), "phi_i_deg": float(phi_i_deg)})


def merl_slice(b: MeasuredBRDF, size: int = 180, phi_d_deg: float = 90.0) -> Slice:
    """f_r over (θh, θd) at one φd, the image slice of MERL-style data."""
    th = np.radians(90.0 * _centres(size))
    td = np.radians(90.0 * (1.0 - _centres(size)))
    h, d = np.meshgrid(th, td)
    wi, wo = from_half_diff(h.ravel(), 0.0, d.ravel(), np.radians(phi_d_deg))
    v = b.eval(wi, wo).value.copy()
    v[blocked(b, wi, wo)] = np.nan
    v = v.reshape(size, size, -1)
    return Slice("merl", v, b.channels, "f_r [sr^-1]",
                 "theta_h = 90*(c+0.5)/W deg, theta_d = 90*(1 - (r+0.5)/H) deg (theta_d up), "
                 "phi_h = 0, phi_d given (Rusinkiewicz half/difference angles)",
                 {"phi_d_deg": float(phi_d_deg)})


def reciprocity_slice(b: MeasuredBRDF, phi_i_deg: float = 0.0, size: int = 121) -> Slice:
    """Relative reciprocity residual over (θi, θo) in the plane of incidence (specular side).

    Raises
    ------
    ValueError
        When the campaign used the reciprocity shortcut: its data cannot show a residual.
    """
    if b.symmetries["reciprocity"]:
        raise ValueError("reciprocity: this campaign used the reciprocity shortcut (each (wi, wo) stands "
                         "for (wo, wi) too), so it holds no residual to show; measure with a grid option "
                         "reciprocity=false, e.g. iso:step=10,reciprocity=false")
    top = b.theta_max_deg
    ti = top * _centres(size)
    to = top * (1.0 - _centres(size))
    a, c = np.meshgrid(ti, to)
    po = phi_i_deg + 180.0
    f = _eval(b, a, phi_i_deg, c, po)
    g = _eval(b, c, po, a, phi_i_deg)
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = (f - g) / (0.5 * (f + g))
    rel[(a > c).ravel()] = np.nan
    return Slice("reciprocity", rel.reshape(size, size, -1), b.channels,
                 "relative difference (f(wi,wo) - f(wo,wi)) / mean",
                 "theta_i = theta_max*(c+0.5)/W deg, theta_o = theta_max*(1 - (r+0.5)/H) deg (theta_o up), "
                 "phi_i given, phi_o = phi_i + 180; NaN where theta_i > theta_o",
                 {"theta_max_deg": float(top), "phi_i_deg": float(phi_i_deg)})


def albedo_slice(b: MeasuredBRDF, thetas_i_deg, phi_i_deg: float = 0.0, *, fill: bool = False) -> Slice:
    """Directional albedo ∫ f_r cos θo dωo against θi, over the measured part of the hemisphere.

    ``attrs["coverage"]`` is, per θi, the fraction of the projected solid angle (π) whose f_r exists:
    the albedo shown is a lower bound where it is below 1. With ``fill``, each cell where nothing was
    measured (the occlusion gap around retro-reflection, θo beyond theta_max) takes the least f_r
    measured on its θo ring (on the nearest ring with a measurement where its own has none, e.g. beyond
    theta_max): an estimate over the whole
    hemisphere that is exact for a diffuse sample and adds no peak that was not measured (a glossy
    sample's gaps get its diffuse level; its specular peak counts only where it was measured).
    """
    return albedo_slices(b, thetas_i_deg, phi_i_deg, fills=(fill,))[0]


def albedo_slices(b: MeasuredBRDF, thetas_i_deg, phi_i_deg: float = 0.0, *,
                  fills: tuple[bool, ...] = (False, True)) -> list[Slice]:
    """:func:`albedo_slice` with each ``fill`` of ``fills``, in that order, from one evaluation of ``b``
    per θi (the albedo plot draws the measured part and the whole hemisphere)."""
    cols = np.asarray(thetas_i_deg, dtype=np.float64)
    dt, dp = 1.0, 5.0
    to = np.arange(0.0, 90.0, dt) + dt / 2
    po = np.arange(0.0, 360.0, dp) + dp / 2
    t, p = (a.ravel() for a in np.meshgrid(to, po, indexing="ij"))
    # cos θo dω over a cell: cos θ sin θ dθ dφ
    w = np.cos(np.radians(t)) * np.sin(np.radians(t)) * np.radians(dt) * np.radians(dp)
    out = np.zeros((len(fills), 1, len(cols), len(b.channels)))
    coverage = np.zeros(len(cols))
    for k, ti in enumerate(cols):
        ev = b.eval_deg(ti, phi_i_deg, t, phi_i_deg + p)
        measured = (ev.reason == Reason.OK) & ~blocked_deg(b, ti, phi_i_deg, t, phi_i_deg + p)
        coverage[k] = w[measured].sum() / np.pi
        for j, fill in enumerate(fills):
            value, ok = ev.value, measured
            if fill and ok.any() and not ok.all():
                value, ok = _ring_minimum_fill(value, ok, len(to)), np.ones_like(ok)
            out[j, 0, k] = (w[ok, None] * value[ok]).sum(axis=0)
    slices = []
    for j, fill in enumerate(fills):
        rule = ("sum over every cell of f_r cos(theta_o) dw, a cell where nothing was measured taking the "
                "least f_r measured on its theta_o ring (or the nearest ring measured)" if fill else
                "sum over the measured cells of f_r cos(theta_o) dw")
        slices.append(Slice("albedo", out[j], b.channels, "directional albedo (dimensionless)",
                            f"one row; column c: theta_i = cols_deg[c] deg at phi_i; value = {rule}, "
                            "midpoint rule with 1 deg in theta_o and 5 deg in phi_o",
                            {"cols_deg": cols.tolist(), "phi_i_deg": float(phi_i_deg),
                             "coverage": coverage.tolist()}))
    return slices


def _ring_minimum_fill(value: np.ndarray, ok: np.ndarray, rings: int) -> np.ndarray:
    """``value`` (rings·azimuths, C) of cells ordered ring by ring, its unmeasured cells (``~ok``) set to
    the least measured value on their ring, or on the nearest ring with a measured cell."""
    v = value.reshape(rings, -1, value.shape[-1]).copy()
    good = ok.reshape(rings, -1)
    measured = np.flatnonzero(good.any(axis=1))
    least = {r: np.where(good[r][:, None], v[r], np.inf).min(axis=0) for r in measured}
    for r in range(rings):
        nearest = int(measured[np.argmin(np.abs(measured - r))])
        v[r][~good[r]] = least[nearest]
    return v.reshape(value.shape)


def write_exr(path: str | Path, s: Slice, meta: dict) -> Path:
    """Write a slice as a float32 OpenEXR image (one channel per BRDF channel) with its mapping, units
    and ``meta`` in the header; atomically (a temporary name in the same folder renamed into place).

    Raises
    ------
    ValueError
        OpenImageIO is not installed, or the file cannot be written.
    """
    try:
        import OpenImageIO as oiio
    except ImportError:
        raise ValueError("EXR output needs OpenImageIO (pip install OpenImageIO); write .png or .pdf "
                         "instead") from None
    path = Path(path)
    if not path.parent.is_dir():
        raise ValueError(f"output {str(path)!r}: folder {str(path.parent)!r} does not exist")
    h, w, c = s.image.shape
    spec = oiio.ImageSpec(w, h, c, oiio.FLOAT)
    spec.channelnames = tuple(str(x) for x in s.channels)
    header = {"gonio:kind": s.kind, "gonio:quantity": s.quantity, "gonio:mapping": s.mapping,
              **{f"gonio:{k}": v for k, v in s.attrs.items()}, **{f"gonio:{k}": v for k, v in meta.items()}}
    for key, val in header.items():
        # floats as text: an EXR float attribute is float32, and readers must recover the exact mapping
        spec.attribute(key, val if isinstance(val, str | int) else repr(val))
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.partial{path.suffix}")
    out = oiio.ImageOutput.create(str(tmp))
    try:
        if out is None or not out.open(str(tmp), spec) or \
                not out.write_image(np.ascontiguousarray(s.image, dtype=np.float32)):
            raise ValueError(f"output {str(path)!r}: cannot write EXR ({oiio.geterror() or 'unknown error'})")
        out.close()
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path
