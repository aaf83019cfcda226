"""The measured BRDF of a campaign, evaluated at any direction pairs.

``open_brdf(source)`` opens a campaign folder, a ``brdf.h5`` (read with :func:`gonio.dataset.read_brdf`)
or a :class:`~gonio.dataset.SampledBRDF`, and returns a :class:`MeasuredBRDF` whose ``eval(wi, wo)`` and
``eval_deg(θi, φi, θo, φo)`` return f_r in sr⁻¹ (no cosine factor), its standard deviation, and per pair
a reason code that says why a value is missing (:class:`Reason`). Nothing is extrapolated: a pair the
data cannot support comes back NaN with its reason.

Symmetries
----------
Only the shortcuts the campaign declares (the ``symmetries`` attribute: ``reciprocity``, ``isotropy``,
``mirror``) are applied; an undeclared one is never assumed. Each measured sample stands for every member
of its class: with isotropy the data live in (θi, θo, Δφ = φo − φi), reciprocity adds (θo, θi, −Δφ), mirror
adds (θi, θo, −Δφ). Without isotropy the data live in the 4D (θi, φi, θo, φo), reciprocity adds
(θo, φo, θi, φi). At the pole (θ = 0) the azimuth of that direction is irrelevant, so a pole sample stands
for every azimuth.

Interpolation
-------------
Domains: ``iso`` (θi, θo, Δφ) for isotropic campaigns, ``full`` (θi, φi, θo, φo) for anisotropic ones,
and ``merl`` (√(θh/90°), θd, φd) for campaigns measured on a MERL grid (isotropic; φd taken modulo 180°
with reciprocity, 360° without).

- ``grid`` (chosen when the expanded samples lie on a tensor-product lattice of the domain, to within
  ``snap_deg``; every simulated campaign does): multilinear interpolation between the 2^d lattice nodes
  around the query, azimuths periodic. A query at a node returns that node's value exactly. If any node
  with a non-zero weight was not measured (infeasible pose, horizon, theta_max), the result is NaN with
  :attr:`Reason.NO_DATA`. Queries beyond the outermost nodes of a non-periodic axis are
  :attr:`Reason.OUT_OF_RANGE`, except in the ``merl`` domain, where a bin-centre node stands for its bin
  and so answers up to half a node spacing beyond it.
- ``scattered`` (anything else, e.g. real gantries whose read-back angles scatter around the plan):
  local linear regression (moving least squares) over the k nearest samples in the embedding
  (θi, θo cos Δφ, θo sin Δφ) (isotropic) or (θi cos φi, θi sin φi, θo cos φo, θo sin φo), which is smooth
  at the poles and periodic in azimuth; weights (1 − (d/h)²)² with h just past the k-th neighbour. A query
  farther from its nearest sample than that sample's own k-th neighbour is :attr:`Reason.NO_DATA` (a
  gap wider than the local sample spacing).
- ``local`` (chosen for ``adaptive`` campaigns; isotropic, reciprocal data only): a local quadric fitted
  to log(f_r cos θi cos θo + ε) over the 24 nearest samples in the same embedding
  (:class:`gonio.adaptive.reconstruct.LocalEngine`), its value held within a factor 2 of its neighbours'.
  An adaptive campaign crowds its samples into the lobe, where a plane through f_r flattens the peak:
  on noise-free adaptive samples of ggx α = 0.2 at 1,156 poses the scattered plane left 0.0384
  cosine-weighted relative L1 error, the log-quadric 0.0040 (BENCHMARKS.md, "Adaptive acquisition",
  ``--engines``). Its standard deviation is the fit's linear response to the samples' noise; its gaps
  are judged as ``scattered``'s.

The estimate is a linear combination Σ a_k f_k of measured values, so its standard deviation is
propagated as sqrt(Σ a_k² σ_k²) (independent measurement noise; interpolation error is not included).
Queries at or below the horizon (θ >= 90°) are :attr:`Reason.BELOW_HORIZON`; beyond the largest measured θ,
:attr:`Reason.OUT_OF_RANGE`.

Planned or measured angles
--------------------------
A ``brdf.h5`` of format version 2 holds both the measured directions (forward kinematics of the axis
positions read back, which carry the gantry's positioning error and float noise) and the planned ones.
``angles="auto"`` (the default) places each sample at its *planned* direction when every sample was
measured within ``plan_tolerance_deg`` (default 0.25°, angular distance of ωi and of ωo) of its plan:
the samples then lie exactly on the grid's lattice, a query at a planned direction pair, e.g.
``eval_deg(30, 0, 40, 180)`` on an ``iso:step=10`` campaign, returns that sample as measured
(``exact``), and queries between nodes interpolate on the lattice. A campaign that strayed farther
(``plan_deviation_deg`` says how far) and version 1 files use the measured directions (``scattered``
unless they happen to lie on a lattice). ``angles="measured"`` or ``"planned"`` forces the choice.
Queries themselves are never moved: only the samples are placed at their planned directions.
"""

from __future__ import annotations

import json
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gonio.dataset import BRDF_NAME, SampledBRDF, read_brdf
from gonio.geometry import sph_to_vec, vec_to_sph
from gonio.interpolate import Lattice, Reason, Scattered, domain_coords

__all__ = ["Reason", "Evaluation", "MeasuredBRDF", "open_brdf", "read_symmetries", "DOMAINS", "METHODS",
           "ANGLES"]

DOMAINS = ("iso", "full", "merl")
METHODS = ("auto", "grid", "scattered", "local")
#: Which directions place the samples (module docstring, "Planned or measured angles").
ANGLES = ("auto", "planned", "measured")
_HALF_PI = 0.5 * np.pi
# Queries are answered in chunks of this many pairs, spread over the CPU cores (the engines' NumPy and
# kd-tree work releases the GIL): the per-chunk arrays stay a few MB each.
_CHUNK = 1 << 15
_THREADS = max(1, min(8, os.cpu_count() or 1))


@dataclass(frozen=True)
class Evaluation:
    """The answer to a query of N direction pairs.

    Attributes
    ----------
    value, stddev : numpy.ndarray, shape (N, C), float64
        f_r and its standard deviation in sr⁻¹ (no cosine factor); NaN where ``reason != 0``.
    reason : numpy.ndarray, shape (N,), uint8
        :class:`Reason` codes.
    exact : numpy.ndarray, shape (N,), bool
        True where the value is one measured sample as it is (the query coincides with a measured pair,
        up to the campaign's symmetries), False where it is interpolated or missing.
    """

    value: np.ndarray
    stddev: np.ndarray
    reason: np.ndarray
    exact: np.ndarray


def read_symmetries(attrs: dict) -> dict[str, bool]:
    """The shortcuts a dataset declares: ``reciprocity``, ``isotropy``, ``mirror`` (False when absent).

    Accepts the attribute as a dict or a JSON string; ``isotropy`` falls back to the grid kind (``iso``
    and ``merl`` grids are isotropic) when the dataset does not say.
    """
    raw = attrs.get("symmetries", {})
    if isinstance(raw, bytes):
        raw = raw.decode()
    if isinstance(raw, str):
        try:
            raw = json.loads(raw) if raw.strip() else {}
        except json.JSONDecodeError as exc:
            raise ValueError(f"brdf attribute 'symmetries': not JSON ({exc.msg}); expected e.g. "
                             '{"reciprocity": true, "isotropy": true, "mirror": false}') from exc
    out = {k: bool(raw.get(k, False)) for k in ("reciprocity", "isotropy", "mirror")}
    if "isotropy" not in raw:
        out["isotropy"] = _grid_kind(attrs) in ("iso", "merl")
    return out


def _grid_kind(attrs: dict) -> str:
    grid = attrs.get("grid", "")
    grid = grid.decode() if isinstance(grid, bytes) else str(grid)
    return grid.partition(":")[0].strip().lower()


def open_brdf(source, *, method: str = "auto", snap_deg: float = 1e-4, angles: str = "auto",
              plan_tolerance_deg: float = 0.25) -> MeasuredBRDF:
    """Open a measured BRDF for queries.

    Parameters
    ----------
    source : str, Path or SampledBRDF
        A campaign folder (holding ``brdf.h5``), a ``brdf.h5`` file, or data already read.
    method : {"auto", "grid", "scattered", "local"}
        Interpolation (module docstring); ``auto`` takes ``local`` for an adaptive campaign, else ``grid``
        when the data lie on a lattice.
    snap_deg : float
        Degrees; samples this close to a lattice value count as on it (> 0).
    angles : {"auto", "planned", "measured"}
        Place samples at their planned or measured directions (module docstring).
    plan_tolerance_deg : float
        Degrees (> 0); ``auto`` takes the planned directions when no sample strayed farther from them.

    Returns
    -------
    MeasuredBRDF

    Examples
    --------
    >>> b = open_brdf("campaign-folder")                                  # doctest: +SKIP
    >>> ev = b.eval_deg([30.0], [0.0], [30.0], [180.0])                    # doctest: +SKIP
    >>> ev.value, ev.stddev, ev.reason                                     # doctest: +SKIP
    """
    if isinstance(source, SampledBRDF):
        data = source
    else:
        path = Path(source)
        if path.is_dir():
            path = path / BRDF_NAME
        if not path.is_file():
            raise ValueError(f"brdf source {str(source)!r}: no such campaign folder or {BRDF_NAME} file")
        data = read_brdf(path)
    return MeasuredBRDF(data, method=method, snap_deg=snap_deg, angles=angles,
                        plan_tolerance_deg=plan_tolerance_deg)


class MeasuredBRDF:
    """Queries of a sampled BRDF (see the module docstring for the interpolation and the symmetries).

    Attributes
    ----------
    attrs : dict
        The dataset's attributes.
    channels : tuple of str
        Channel names (C of them).
    symmetries : dict of str to bool
        The shortcuts applied.
    domain : str
        ``"iso"``, ``"full"`` or ``"merl"``.
    method : str
        ``"grid"``, ``"scattered"`` or ``"local"``.
    theta_max_deg : float
        Largest measured θ (θi or θo), degrees.
    angles : str
        ``"planned"`` or ``"measured"``: the directions the samples are placed at.
    plan_deviation_deg : float or None
        Largest angular distance between a sample's measured and planned ωi or ωo, degrees (None when
        the dataset has no planned directions).
    """

    def __init__(self, data: SampledBRDF, *, method: str = "auto", snap_deg: float = 1e-4,
                 angles: str = "auto", plan_tolerance_deg: float = 0.25):
        if method not in METHODS:
            raise ValueError(f"method: must be one of {', '.join(METHODS)}, got {method!r}")
        if angles not in ANGLES:
            raise ValueError(f"angles: must be one of {', '.join(ANGLES)}, got {angles!r}")
        if not snap_deg > 0:
            raise ValueError(f"snap_deg: must be > 0 degrees, got {snap_deg}")
        if not plan_tolerance_deg > 0:
            raise ValueError(f"plan_tolerance_deg: must be > 0 degrees, got {plan_tolerance_deg}")
        measured = np.stack([np.asarray(a, dtype=np.float64).ravel() for a in
                             (data.theta_i, data.phi_i, data.theta_o, data.phi_o)], axis=1)
        planned = None if data.planned is None else np.asarray(data.planned, np.float64).reshape(-1, 4)
        self.plan_deviation_deg = None if planned is None else _deviation_deg(measured, planned)
        if angles == "planned" and planned is None:
            raise ValueError("angles 'planned': the dataset has no planned directions (a brdf.h5 of format "
                             "version 1?); use 'measured' or 'auto'")
        use_plan = planned is not None and (angles == "planned" or (
            angles == "auto" and self.plan_deviation_deg <= plan_tolerance_deg))
        self.angles = "planned" if use_plan else "measured"
        angles = np.radians(planned if use_plan else measured)
        value = np.asarray(data.value, dtype=np.float64).reshape(len(angles), -1)
        stddev = np.asarray(data.stddev, dtype=np.float64).reshape(value.shape)
        keep = np.isfinite(angles).all(axis=1) & np.isfinite(value).all(axis=1)
        angles, value, stddev = angles[keep], value[keep], np.nan_to_num(stddev[keep])
        if len(angles) == 0:
            raise ValueError("brdf: the dataset holds no finite samples")
        self.attrs = dict(data.attrs)
        channels = self.attrs.get("channels")
        self.channels = tuple(str(c) for c in channels) if channels is not None and len(channels) == \
            value.shape[1] else (("R", "G", "B") if value.shape[1] == 3 else
                                 tuple(f"c{i}" for i in range(value.shape[1])))
        self.symmetries = read_symmetries(self.attrs)
        self.theta_max_deg = float(np.degrees(max(angles[:, 0].max(), angles[:, 2].max())))
        self.n_samples = len(angles)
        self._snap = np.radians(snap_deg)
        self._theta_max = np.radians(self.theta_max_deg) + self._snap
        self._engine = None
        if method == "local" or (method == "auto" and _grid_kind(self.attrs) == "adaptive"):
            self._local(angles, value, stddev)
            return
        kinds = ["merl"] if _grid_kind(self.attrs) == "merl" and self.symmetries["isotropy"] else []
        kinds.append("iso" if self.symmetries["isotropy"] else "full")
        if method in ("auto", "grid"):
            for kind in kinds:
                coords = domain_coords(kind, angles, self.symmetries)
                lattice = Lattice.build(kind, coords, value, stddev, self.symmetries, self._snap)
                if lattice is not None:
                    self.domain, self.method, self._engine = kind, "grid", lattice
                    break
            if self._engine is None and method == "grid":
                raise ValueError("method 'grid': the samples do not lie on a lattice of the "
                                 f"{kinds[-1]} domain (within snap_deg={snap_deg}); "
                                 "use 'scattered' or 'auto'")
        if self._engine is None:
            self.domain, self.method = kinds[-1], "scattered"
            coords = domain_coords(self.domain, angles, self.symmetries)
            self._engine = Scattered(self.domain, coords, value, stddev, self.symmetries, self._snap)

    def _local(self, angles, value, stddev) -> None:
        """The ``local`` engine (:class:`gonio.adaptive.reconstruct.LocalEngine`): reciprocal samples without
        mirror symmetry (what the fit assumes), isotropic ones in (θi, θo, Δφ), anisotropic ones in 4D
        (θi, φi, θo, φo)."""
        from gonio.adaptive.reconstruct import LocalEngine

        if not self.symmetries["reciprocity"] or self.symmetries["mirror"]:
            raise ValueError(f"method 'local': fits reciprocal samples without mirror symmetry; this dataset "
                             f"declares {self.symmetries}: use 'scattered' or 'grid'")
        self.domain = "iso" if self.symmetries["isotropy"] else "full"
        self.method = "local"
        self._engine = LocalEngine(domain_coords(self.domain, angles, self.symmetries), value, stddev,
                                   self._snap)

    def __repr__(self) -> str:
        return (f"MeasuredBRDF({self.n_samples} samples, domain={self.domain!r}, method={self.method!r}, "
                f"angles={self.angles!r}, symmetries={self.symmetries})")

    # -- queries ---------------------------------------------------------------------------------
    def eval(self, wi, wo) -> Evaluation:
        """f_r at direction pairs given as vectors.

        Parameters
        ----------
        wi, wo : array_like, shape (..., 3)
            Directions in the sample frame (ωi toward the light, ωo toward the detector); any non-zero
            length (they are normalized). Broadcast against each other and flattened.

        Returns
        -------
        Evaluation
            Of the N = prod(shape[:-1]) pairs, in C-order.
        """
        wi, wo = np.broadcast_arrays(np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64))
        if wi.shape[-1:] != (3,):
            raise ValueError(f"wi, wo: expected vectors of shape (..., 3), got shape {wi.shape}")
        ti, pi_ = vec_to_sph(wi.reshape(-1, 3))
        to, po = vec_to_sph(wo.reshape(-1, 3))
        return self._eval(ti, pi_, to, po)

    def eval_deg(self, theta_i, phi_i, theta_o, phi_o) -> Evaluation:
        """f_r at direction pairs given as angles in degrees (arrays broadcast and are flattened)."""
        arrays = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in
                                       (theta_i, phi_i, theta_o, phi_o)))
        return self.eval_rad(*(np.radians(a.ravel()) for a in arrays))

    def eval_rad(self, theta_i, phi_i, theta_o, phi_o) -> Evaluation:
        """f_r at direction pairs given as angles in radians (arrays broadcast and are flattened)."""
        ti, pi_, to, po = (a.ravel() for a in np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in
                                                                    (theta_i, phi_i, theta_o, phi_o))))
        bad = ~(np.isfinite(ti) & np.isfinite(pi_) & np.isfinite(to) & np.isfinite(po)) | (ti < 0) | (to < 0)
        ti, to = np.where(bad, np.nan, ti), np.where(bad, np.nan, to)
        return self._eval(ti, np.nan_to_num(pi_), to, np.nan_to_num(po))

    def _eval(self, ti, pi_, to, po) -> Evaluation:
        n, c = ti.size, len(self.channels)
        value = np.full((n, c), np.nan)
        stddev = np.full((n, c), np.nan)
        reason = np.full(n, Reason.OK, dtype=np.uint8)
        exact = np.zeros(n, dtype=bool)
        invalid = ~(np.isfinite(ti) & np.isfinite(to))
        reason[invalid] = Reason.INVALID
        with np.errstate(invalid="ignore"):
            horizon = ~invalid & ((ti >= _HALF_PI) | (to >= _HALF_PI))
            reason[horizon] = Reason.BELOW_HORIZON
            far = (reason == Reason.OK) & ((ti > self._theta_max) | (to > self._theta_max))
        reason[far] = Reason.OUT_OF_RANGE
        todo = np.flatnonzero(reason == Reason.OK)

        def chunk(start):
            sel = todo[start:start + _CHUNK]
            angles = np.stack([ti[sel], pi_[sel], to[sel], po[sel]], axis=1)
            coords = domain_coords(self.domain, angles, self.symmetries)
            v, s, r, e = self._engine.eval(coords, workers=1 if threads > 1 else -1)
            value[sel], stddev[sel], reason[sel], exact[sel] = v, s, r, e

        starts = range(0, todo.size, _CHUNK)
        threads = min(_THREADS, len(starts))
        if threads > 1:
            with ThreadPoolExecutor(threads) as pool:
                list(pool.map(chunk, starts))  # list(): re-raise any error here
        else:
            for start in starts:
                chunk(start)
        miss = reason != Reason.OK
        value[miss] = np.nan
        stddev[miss] = np.nan
        return Evaluation(value, stddev, reason, exact & ~miss)


def _deviation_deg(measured: np.ndarray, planned: np.ndarray) -> float:
    """Largest angular distance (degrees) between measured and planned ωi or ωo over finite rows."""
    ok = np.isfinite(measured).all(axis=1) & np.isfinite(planned).all(axis=1)
    if not ok.any():
        return 0.0
    m, p = np.radians(measured[ok]), np.radians(planned[ok])
    worst = 0.0
    for t, f in ((0, 1), (2, 3)):
        a, b = sph_to_vec(m[:, t], m[:, f]), sph_to_vec(p[:, t], p[:, f])
        # atan2(|a × b|, a · b): accurate for the tiny angles that matter here (acos is not)
        ang = np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.sum(a * b, axis=1))
        worst = max(worst, float(np.degrees(ang.max())))
    return worst
