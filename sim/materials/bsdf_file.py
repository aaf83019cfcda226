"""A measured material from a tensor file (Mitsuba 3 / pbrt-v4 ``measured`` BSDF), evaluated in Dr.Jit.

So that a measured material can be measured again: ``bsdf:PATH`` loads a file written by
``gonio.export`` (or an RGL database file) and evaluates it the way Mitsuba 3's ``measured`` plugin does
(see :mod:`gonio.formats.rgl`): m = normalize(ωi + ωo), the VNDF warp inverted at u(m) with its tables
blended linearly between the neighbouring θi (and φi) slices, the bilinear lookup of the stored values at
the result, times D(m) / (4 σ(ωi)) when ``jacobian`` is set; f_r is that divided by cos θo. RGB files
give R, G, B directly; spectral files are read at 610, 550 and 465 nm (a coarse RGB, said in
``Measured.note``). Anisotropic files with a φi symmetry reduction (RGL's ``m_reduction``) are refused.

The material is as reciprocal as the data; it is not declared reciprocal or energy conserving.

Spec: ``bsdf:path/to/file.bsdf``: everything after ``bsdf:`` is the path.
"""

from __future__ import annotations

import math

import drjit as dr
import numpy as np

from gonio.formats.rgl import warp_tables
from gonio.formats.tensor import read_tensor

from .base import Material

__all__ = ["MeasuredTensor"]

_RGB_NM = (610.0, 550.0, 465.0)


class MeasuredTensor(Material):
    """A tensor-file measured BSDF (see the module docstring)."""

    model = "bsdf"
    USAGE = "bsdf:PATH (a Mitsuba 3 / pbrt-v4 measured-BSDF tensor file)"
    reciprocal = False
    energy_conserving = False

    def __init__(self, spec: str, path: str, fields: dict):
        theta = fields["theta_i"].astype(np.float64)
        phi = fields["phi_i"].astype(np.float64)
        isotropic = phi.size <= 2
        if not isotropic and abs((phi[-1] - phi[0]) - 2 * math.pi) > 1e-3:
            raise ValueError(f"bsdf: file {path!r} covers φi over {math.degrees(phi[-1] - phi[0]):.4g}°; "
                             "allowed: one φi (isotropic) or a full turn [-180°, 180°]")
        super().__init__(spec, isotropic=isotropic)
        self.path = path
        self.note = ""
        if "wavelengths" in fields:
            lam = fields["wavelengths"].astype(np.float64)
            spectra = fields["spectra"].astype(np.float64)
            rgb = np.stack([_interp_axis(spectra, lam, x) for x in _RGB_NM], axis=2)
            self.note = "spectral file read at 610/550/465 nm as R/G/B"
        else:
            rgb = fields["rgb"].astype(np.float64)
        n_p, n_t = fields["vndf"].shape[:2]
        data, cond, marg = warp_tables(fields["vndf"].astype(np.float64).reshape((n_p * n_t,) +
                                                                                   fields["vndf"].shape[2:]))
        self._shape = dict(n_p=phi.size if phi.size > 1 else 1, n_t=theta.size, h=data.shape[1],
                           w=data.shape[2], n=rgb.shape[-1], nh=fields["ndf"].shape[0],
                           nw=fields["ndf"].shape[1], sh=fields["sigma"].shape[0],
                           sw=fields["sigma"].shape[1],
                           iso=isotropic, jac=bool(fields["jacobian"][0]))
        # R, G, B interleaved per grid point so that one gather fetches a triple.
        self._tables = {
            "theta": theta, "phi": phi if phi.size > 1 else np.zeros(1),
            "data": data.ravel(), "cond": cond.ravel(), "marg": marg.ravel(),
            "rgb": np.ascontiguousarray(np.moveaxis(rgb, 2, -1)).ravel(),
            "ndf": fields["ndf"].astype(np.float64).ravel(),
            "sigma": fields["sigma"].astype(np.float64).ravel(),
        }

    @classmethod
    def parse(cls, text: str) -> MeasuredTensor:
        """Build from the part of the spec after ``bsdf:`` (the file path)."""
        path = text.strip()
        if not path:
            raise ValueError("bsdf: a file path is required, e.g. bsdf:path/to/file.bsdf")
        return cls.from_fields(f"bsdf:{path}", path, read_tensor(path))

    @classmethod
    def from_fields(cls, spec: str, path: str, fields: dict) -> MeasuredTensor:
        """Build from a tensor file's fields (``path``: what errors call the file)."""
        need = {"theta_i", "phi_i", "ndf", "sigma", "vndf", "jacobian"}
        missing = sorted(need - set(fields)) + ([] if {"rgb"} <= set(fields) or
                                               {"spectra", "wavelengths"} <= set(fields) else ["rgb"])
        if missing:
            raise ValueError(f"bsdf: file {path!r} lacks the measured-BSDF fields {', '.join(missing)}")
        return cls(spec, path, fields)

    def _parameters(self) -> dict:
        return dict(self._tables)

    def _eval_dr(self, wi, wo, p):
        s = self._shape
        scalar = dr.value_t(wi)
        uint = dr.uint32_array_t(scalar)
        active = (wi.z > 0) & (wo.z > 0)
        m = dr.normalize(wi + wo)
        th_i, ph_i = _elevation(wi), dr.atan2(wi.y, wi.x)
        th_m, ph_m = _elevation(m), dr.atan2(m.y, m.x)
        um_x, um_y = _u(th_m, ph_m - ph_i if s["iso"] else ph_m)
        ui_x, ui_y = _u(th_i, ph_i)
        jt, wt1 = _param(p["theta"], s["n_t"], th_i, uint, scalar)
        jp, wp1 = _param(p["phi"], s["n_p"], ph_i, uint, scalar)
        base = jp * s["n_t"] + jt
        st = 1 if s["n_t"] > 1 else 0
        sp = s["n_t"] if s["n_p"] > 1 else 0
        slices = [(base, (1 - wp1) * (1 - wt1)), (base + st, (1 - wp1) * wt1),
                  (base + sp, wp1 * (1 - wt1)), (base + sp + st, wp1 * wt1)]
        h, w = s["h"], s["w"]

        def look(table, size, index):
            return sum(dr.gather(scalar, table, sl * size + index, active) * wgt for sl, wgt in slices)

        # Continuous Marginal2D inversion (mitsuba3 include/mitsuba/core/distr_2d.h), slices blended.
        px_f = dr.clip(um_x, 0, 1) * (w - 1)
        py_f = dr.clip(um_y, 0, 1) * (h - 1)
        px = dr.minimum(uint(px_f), w - 2)
        py = dr.minimum(uint(py_f), h - 2)
        fx, fy = px_f - scalar(px), py_f - scalar(py)
        i00 = py * w + px
        v00, v10 = look(p["data"], h * w, i00), look(p["data"], h * w, i00 + 1)
        v01, v11 = look(p["data"], h * w, i00 + w), look(p["data"], h * w, i00 + w + 1)
        c0, c1 = (1 - fy) * v00 + fy * v01, (1 - fy) * v10 + fy * v11
        sx = fx * (c0 + 0.5 * fx * (c1 - c0))
        sx += (1 - fy) * look(p["cond"], h * w, i00) + fy * look(p["cond"], h * w, i00 + w)
        r0, r1 = look(p["cond"], h * w, py * w + w - 1), look(p["cond"], h * w, (py + 1) * w + w - 1)
        norm = (1 - fy) * r0 + fy * r1
        sx = dr.select(norm > 0, sx / norm, 0)
        sy = fy * (r0 + 0.5 * fy * (r1 - r0)) + look(p["marg"], h, py)
        # Bilinear lookup of the stored values at (sx, sy).
        n = s["n"]
        qx_f, qy_f = dr.clip(sx, 0, 1) * (n - 1), dr.clip(sy, 0, 1) * (n - 1)
        qx, qy = dr.minimum(uint(qx_f), n - 2), dr.minimum(uint(qy_f), n - 2)
        gx, gy = qx_f - scalar(qx), qy_f - scalar(qy)
        vec = type(wi)

        def texel(k):
            return sum(dr.gather(vec, p["rgb"], sl * (n * n) + k, active) * wgt for sl, wgt in slices)

        k00 = qy * n + qx
        value = ((1 - gy) * ((1 - gx) * texel(k00) + gx * texel(k00 + 1))
                 + gy * ((1 - gx) * texel(k00 + n) + gx * texel(k00 + n + 1)))
        if s["jac"]:
            d_m = _bilinear(p["ndf"], s["nh"], s["nw"], um_x, um_y, uint, scalar, active)
            sig = _bilinear(p["sigma"], s["sh"], s["sw"], ui_x, ui_y, uint, scalar, active)
            value *= dr.select(sig > 0, d_m / (4 * sig), 0)
        return dr.select(active, value / wo.z, 0)


def _interp_axis(spectra, lam, x):
    j = int(np.clip(np.searchsorted(lam, x) - 1, 0, lam.size - 2)) if lam.size > 1 else 0
    if lam.size == 1:
        return spectra[:, :, 0]
    t = float(np.clip((x - lam[j]) / (lam[j + 1] - lam[j]), 0.0, 1.0))
    return (1 - t) * spectra[:, :, j] + t * spectra[:, :, j + 1]


def _elevation(d):
    # Mitsuba's stable form of acos(cos θ).
    dist = dr.sqrt(d.x * d.x + d.y * d.y + (d.z - 1) * (d.z - 1))
    return 2 * dr.safe_asin(0.5 * dist)


def _u(theta, phi):
    ux = dr.sqrt(dr.maximum(theta, 0) * (2 / math.pi))
    uy = (phi + math.pi) * (0.5 / math.pi)
    return ux, uy - dr.floor(uy)


def _param(values, count, x, uint, scalar):
    """Lower slice index and upper weight along one parameter (Mitsuba's interpolate_weights)."""
    if count == 1:
        return uint(0), scalar(0)
    below = uint(0)
    for k in range(count):
        below += dr.select(dr.gather(scalar, values, k) < x, uint(1), uint(0))
    j = dr.minimum(dr.maximum(below, 1) - 1, count - 2)
    p0, p1 = dr.gather(scalar, values, j), dr.gather(scalar, values, j + 1)
    return j, dr.clip((x - p0) / (p1 - p0), 0, 1)


def _bilinear(table, h, w, ux, uy, uint, scalar, active):
    px_f, py_f = dr.clip(ux, 0, 1) * (w - 1), dr.clip(uy, 0, 1) * (h - 1)
    px, py = dr.minimum(uint(px_f), w - 2), dr.minimum(uint(py_f), h - 2)
    fx, fy = px_f - scalar(px), py_f - scalar(py)
    i = py * w + px

    def g(k):
        return dr.gather(scalar, table, k, active)

    return (1 - fy) * ((1 - fx) * g(i) + fx * g(i + 1)) + fy * ((1 - fx) * g(i + w) + fx * g(i + w + 1))
