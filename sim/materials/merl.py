"""A measured material from a MERL ``.binary`` table, looked up bin by bin in Dr.Jit.

File format (shared/references/FORMATS.md; read by :func:`gonio.formats.merl.read_merl`, shared with the
exporters): three little-endian int32 bin counts 90 (θh), 90 (θd),
180 (φd), then three float64 planes R, G, B of 1,458,000 values each, flat index
``iφd + 180·(iθd + 90·iθh)``. Values are scaled on read, R × 1/1500, G × 1.15/1500, B × 1.66/1500, to
f_r in sr⁻¹; a negative value means "no data" and evaluates to 0 (per channel).

The lookup is nearest-bin (no interpolation), with the bin rules of :func:`gonio.geometry.merl_index`
re-implemented in Dr.Jit (:func:`merl_index_dr`): Rusinkiewicz half/difference angles of the pair,
iθh = floor(sqrt(θh / (π/2)) · 90), iθd = floor(θd / (π/2) · 90), φd folded into [0, π) (reciprocity),
iφd = floor(φd / π · 180), each clamped to its range, then one :func:`drjit.gather` of the RGB triple.

The material is reciprocal and isotropic by construction of the table's parameterization (swapping ωi
and ωo moves φd by π, which the fold maps to the same bin); it is not declared energy conserving, since
that depends on the data.

Spec: ``merl:path/to/file.binary``: everything after ``merl:`` is the path, as given (relative paths
are resolved against the working directory when loading).
"""

from __future__ import annotations

import math

import drjit as dr
import numpy as np

from gonio.formats.merl import MERL_SCALE, read_merl
from gonio.geometry import MERL_SHAPE
from gonio.jit import exact_float64

from .base import Material

__all__ = ["Merl", "read_merl", "merl_index_dr", "MERL_SCALE"]


def merl_index_dr(wi, wo):
    """Flat MERL bin index (unsigned 32-bit Dr.Jit array) of direction pairs; the rules of
    :func:`gonio.geometry.merl_index` after :func:`gonio.geometry.to_half_diff` (float64 inputs traced
    with exact reciprocals: :func:`gonio.jit.exact_float64`)."""
    with exact_float64(wi):
        return _merl_index(wi, wo)


def _merl_index(wi, wo):
    scalar = dr.value_t(wi)
    uint = dr.uint32_array_t(scalar)
    n_th, n_td, n_pd = MERL_SHAPE
    h = dr.normalize(wi + wo)
    rho_h = dr.sqrt(h.x * h.x + h.y * h.y)
    theta_h = dr.atan2(rho_h, h.z)
    # Rotate ωi by −φh about z and by −θh about y, with the cosines and sines read off h itself.
    pole = rho_h > 0
    cos_ph = dr.select(pole, h.x / rho_h, 1)
    sin_ph = dr.select(pole, h.y / rho_h, 0)
    x1 = cos_ph * wi.x + sin_ph * wi.y
    y1 = cos_ph * wi.y - sin_ph * wi.x
    dx = h.z * x1 - rho_h * wi.z
    dz = rho_h * x1 + h.z * wi.z
    theta_d = dr.atan2(dr.sqrt(dx * dx + y1 * y1), dz)
    phi_d = dr.atan2(y1, dx)
    phi_d = dr.select(phi_d < 0, phi_d + math.pi, phi_d)
    phi_d = dr.select(phi_d >= math.pi, phi_d - math.pi, phi_d)

    def bin_of(u, n):
        return uint(dr.clip(dr.floor(u * n), 0, n - 1))

    i_th = bin_of(dr.sqrt(dr.maximum(theta_h, 0) * (2 / math.pi)), n_th)
    i_td = bin_of(theta_d * (2 / math.pi), n_td)
    i_pd = bin_of(phi_d * (1 / math.pi), n_pd)
    return i_pd + n_pd * (i_td + n_td * i_th)


class Merl(Material):
    """A MERL table material (see the module docstring).

    Attributes
    ----------
    path : str
        The file, as given in the spec.
    missing_bins : int
        Number of bins whose value is negative (no data) in at least one channel.
    """

    model = "merl"
    USAGE = "merl:PATH (a MERL .binary table; the nearest bin, no-data bins read as 0)"
    reciprocal = True
    energy_conserving = False

    def __init__(self, spec: str, path: str, table: np.ndarray):
        super().__init__(spec)
        self.path = path
        self.missing_bins = int(np.count_nonzero((table < 0).any(axis=0)))
        # Interleaved R, G, B per bin so that one gather fetches a triple; no data → 0.
        self._table = np.ascontiguousarray(np.where(table < 0, 0.0, table).T).reshape(-1)

    @classmethod
    def parse(cls, text: str) -> Merl:
        """Build from the part of the spec after ``merl:`` (the file path)."""
        path = text.strip()
        if not path:
            raise ValueError("merl: a file path is required, e.g. merl:path/to/file.binary")
        return cls(f"merl:{path}", path, read_merl(path))

    def _parameters(self) -> dict:
        return {"table": self._table}

    def _eval_dr(self, wi, wo, p):
        active = (wi.z > 0) & (wo.z > 0)
        value = dr.gather(type(wi), p["table"], merl_index_dr(wi, wo), active)
        return dr.select(active, value, 0)
