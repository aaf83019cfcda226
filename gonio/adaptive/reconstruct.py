"""f_r anywhere from scattered isotropic samples, and how badly each sample is predicted by the others.

:class:`LocalFit` is moving least squares over the k nearest samples in an embedding of
:mod:`gonio.adaptive.domain`, weights (1 − (d/h)²)² with h just past the k-th neighbour, evaluated at the
query. Defaults, each measured by ``tools/bench_adaptive.py --engines`` on uniform and adaptive samples:

- domain ``iso`` (θi, θo cos Δφ, θo sin Δφ), the embedding of :mod:`gonio.brdf`'s scattered engine
  (the ``half`` domain left 1.2-17x more error at 1,156 poses, uniform or adaptive);
- the fitted quantity is log(f_r cos θi cos θo + ε) (ε: 1e-3 of the samples' median): a microfacet lobe's
  log is close to a quadratic bowl, and the cosines take out the 1/(cos θi cos θo) rise at grazing;
- anisotropic samples (φi measured) are fitted in the 4D ``pair`` domain, the same moving least
  squares with :data:`PAIR_NEIGHBOURS`;
- degree 2 (a local quadric, :data:`QUADRATIC_NEIGHBOURS` neighbours): a plane flattens the peak by
  h² f''/2; the quadric follows it. Where samples are sparse around a sharp peak a quadric can swing
  far past them (ggx α = 0.05 at 148 poses: 6.6 error without a bound), so its value is kept between
  half the least and twice the largest neighbour (:data:`SWING`). ``degree=1, transform="linear"`` is
  the method of gonio.brdf's scattered engine.

:func:`loo_residual` fits the same way to each sample's neighbours without that sample (nor its
reciprocal twin) and returns the sample minus that prediction, in f_r: large where f_r bends faster than
the samples around it resolve (a peak's flanks, a Fresnel rise, grazing), the signal refinement follows.

:class:`LocalEngine` is :class:`LocalFit` answering as :mod:`gonio.interpolate`'s engines do (gonio.brdf's
``local`` method, the one it takes for adaptive campaigns): values, standard deviations propagated
through the fit, a reason per query and exact hits.
"""

from __future__ import annotations

import numpy as np

from gonio.adaptive.domain import embed_pairs, embed_poses
from gonio.adaptive.samples import Samples

__all__ = ["LocalFit", "LocalEngine", "reconstruct", "loo_residual", "NEIGHBOURS", "QUADRATIC_NEIGHBOURS",
           "TRANSFORMS", "PAIR_NEIGHBOURS"]

#: Neighbours of a local plane (2.5 per fitted parameter in 3D, as gonio.brdf's scattered engine).
NEIGHBOURS = 10
#: Neighbours of a local quadric (10 parameters in 3D).
QUADRATIC_NEIGHBOURS = 24
#: Neighbours of a plane and of a quadric in the 4D ``pair`` domain (5 and 15 parameters, the same
#: 2.4-2.5 per parameter).
PAIR_NEIGHBOURS = (12, 36)
TRANSFORMS = ("linear", "log")
#: How far a quadric's value may leave its neighbours' range (:func:`_fit`).
SWING = 2.0
# Floor of the log transform, relative to the median of f_r cos θi cos θo.
_FLOOR = 1e-3
_CHUNK = 20_000


class LocalFit:
    """Moving least squares of ``samples`` (module docstring); ``eval(wi, wo)`` -> f_r (N, C)."""

    def __init__(self, samples: Samples, domain: str = "iso", transform: str = "log", degree: int = 2):
        from scipy.spatial import cKDTree

        if transform not in TRANSFORMS or degree not in (1, 2):
            raise ValueError(f"transform must be one of {TRANSFORMS} and degree 1 or 2, got {transform!r}, "
                             f"{degree!r}")
        self.domain, self.transform, self.degree = domain, transform, degree
        self.points, owner = samples.points(domain)
        cc = _cosines(samples.theta_i, samples.theta_o)
        self.floor = _FLOOR * max(float(np.median(samples.value * cc)), 1e-12)
        self.values = self._forward(samples.value * cc)[owner]
        self.tree = cKDTree(self.points)
        counts = PAIR_NEIGHBOURS if domain == "pair" else (NEIGHBOURS, QUADRATIC_NEIGHBOURS)
        self.k = min(counts[degree - 1], len(self.points))

    def eval(self, wi, wo) -> np.ndarray:
        wi, wo = np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64)
        q = embed_pairs(self.domain, wi, wo)
        out = np.empty((len(q), self.values.shape[1]))
        for start in range(0, len(q), _CHUNK):
            part = q[start:start + _CHUNK]
            dist, idx = self.tree.query(part, k=self.k)
            out[start:start + _CHUNK] = _fit(part, dist.reshape(len(part), -1), idx.reshape(len(part), -1),
                                             self.points, self.values, None, self.degree,
                                             self.transform == "log")
        return self._inverse(out) / (wi[:, 2] * wo[:, 2])[:, None]

    def _forward(self, x):
        return np.log(x + self.floor) if self.transform == "log" else x

    def _inverse(self, y):
        return np.clip(np.exp(y) - self.floor if self.transform == "log" else y, 0.0, None)


class LocalEngine:
    """The default :class:`LocalFit` of isotropic, reciprocal samples as an engine of :mod:`gonio.brdf`
    (:class:`gonio.interpolate.Scattered`'s interface).

    ``coords`` (N, 3): (θi, θo, Δφ) radians, or (N, 4): (θi, φi, θo, φo) of anisotropic samples (fitted
    in the ``pair`` domain); ``value``, ``stddev`` (N, C) f_r; ``tol``: a query within it
    of a sample (in the embedding) returns that sample exactly. ``eval(coords)`` -> (value, stddev,
    reason, exact). The standard deviation is the fit's linear response to independent sample noise:
    the intercept in log space is Σ a_k y_k, so σ_y² = Σ a_k² σ_yk² with σ_yk = c_k σ_k / (f_k c_k + ε)
    (c: cos θi cos θo), and σ_f = e^y σ_y / c at the query (a value held at the :data:`SWING` bound
    keeps that σ). A query farther from its nearest sample than that sample's own k-th neighbour is
    :attr:`gonio.interpolate.Reason.NO_DATA` (a gap wider than the local spacing), as in ``scattered``.
    """

    def __init__(self, coords, value, stddev, tol: float):
        coords = np.asarray(coords, dtype=np.float64)
        ti, to, d, pi_ = _poses(coords)
        samples = Samples(ti, to, d, value, pi_)
        self.fit = LocalFit(samples, "pair" if coords.shape[1] == 4 else "iso")
        _, self.owner = samples.points(self.fit.domain)
        cc = _cosines(samples.theta_i, samples.theta_o)
        sd = np.asarray(stddev, dtype=np.float64).reshape(samples.value.shape)
        self.value, self.stddev = samples.value, sd
        self.sigma_log = (cc * sd / (samples.value * cc + self.fit.floor))[self.owner]
        k = min(self.fit.k + 1, len(self.fit.points))
        reach = self.fit.tree.query(self.fit.points, k=k)[0]
        self.reach = np.asarray(reach).reshape(len(self.fit.points), -1)[:, -1]
        self.snap = tol

    def eval(self, coords, workers: int = -1):
        from gonio.interpolate import Reason

        c = np.asarray(coords, dtype=np.float64).reshape(-1, 4 if self.fit.domain == "pair" else 3)
        ti, to, d, pi_ = _poses(c)
        q = embed_poses(self.fit.domain, ti, to, d, pi_)
        m, channels = len(q), self.value.shape[1]
        if m == 0:
            return np.zeros((0, channels)), np.zeros((0, channels)), np.zeros(0, np.uint8), np.zeros(0, bool)
        dist, idx = self.fit.tree.query(q, k=self.fit.k, workers=workers)
        dist, idx = dist.reshape(m, -1), idx.reshape(m, -1)
        y, hat = _fit(q, dist, idx, self.fit.points, self.fit.values, None, self.fit.degree, True, hat=True)
        sigma_y = np.sqrt(np.einsum("mk,mkc->mc", hat ** 2, self.sigma_log[idx] ** 2))
        cc = _cosines(ti, to)
        value = self.fit._inverse(y) / cc
        stddev = np.exp(y) * sigma_y / cc
        exact = dist[:, 0] <= self.snap
        nearest = self.owner[idx[:, 0]]
        value[exact], stddev[exact] = self.value[nearest[exact]], self.stddev[nearest[exact]]
        reason = np.where(dist[:, 0] > self.reach[idx[:, 0]], Reason.NO_DATA, Reason.OK).astype(np.uint8)
        return value, stddev, reason, exact & (reason == Reason.OK)


def reconstruct(samples: Samples, **options) -> LocalFit:
    """The reconstruction the benchmark scores (:class:`LocalFit` with its defaults unless overridden)."""
    return LocalFit(samples, **options)


def loo_residual(samples: Samples, domain: str = "iso", transform: str = "log",
                 degree: int = 2) -> np.ndarray:
    """Each sample minus the local fit to its neighbours without it, f_r (N, C)."""
    fit = LocalFit(samples, domain, transform, degree)
    n = len(samples)
    k = min(fit.k + 2, len(fit.points))
    dist, idx = fit.tree.query(fit.points[:n], k=k)
    dist, idx = dist.reshape(n, -1), idx.reshape(n, -1)
    _, owner = samples.points(domain)
    own = owner[idx] == np.arange(n)[:, None]
    pred = fit._inverse(_fit(fit.points[:n], dist, idx, fit.points, fit.values, own, degree,
                             transform == "log"))
    return samples.value - pred / _cosines(samples.theta_i, samples.theta_o)


def _poses(coords):
    """(θi, θo, Δφ, φi) of rows (θi, θo, Δφ) or (θi, φi, θo, φo)."""
    if coords.shape[1] == 4:
        return coords[:, 0], coords[:, 2], coords[:, 3] - coords[:, 1], coords[:, 1]
    return coords[:, 0], coords[:, 1], coords[:, 2], np.zeros(len(coords))


def _cosines(theta_i, theta_o):
    return (np.cos(theta_i) * np.cos(theta_o))[:, None]


def _fit(q, dist, idx, points, values, drop, degree, log=False, hat=False):
    """Value at each query of the weighted local polynomial through its neighbours ``idx`` (those where
    ``drop`` is true get no weight); with ``hat``, also each neighbour's weight a_k in the fitted
    intercept Σ a_k y_k (m, k), before the bound."""
    d = dist if drop is None else np.where(drop, 0.0, dist)
    h = d.max(axis=1, keepdims=True) * 1.05 + 1e-12
    w = (1.0 - (dist / h) ** 2) ** 2
    if drop is not None:
        w = np.where(drop, 0.0, w)
    x = (points[idx] - q[:, None, :]) / h[:, :, None]
    cols = [np.ones(x.shape[:2] + (1,)), x]
    if degree == 2:
        dim = x.shape[2]
        cols.append(np.stack([x[:, :, i] * x[:, :, j] for i in range(dim) for j in range(i, dim)], axis=2))
    design = np.concatenate(cols, axis=2)
    normal = np.einsum("nk,nki,nkj->nij", w, design, design)
    normal += 1e-6 * (np.trace(normal, axis1=1, axis2=2)[:, None, None] + 1e-12) * np.eye(design.shape[2])
    near = values[idx]
    rhs = np.einsum("nk,nki,nkc->nic", w, design, near)
    if hat:   # also the first row of normal⁻¹ Dᵀ W (normal is symmetric), in the same solve
        e0 = np.zeros((len(q), design.shape[2], 1))
        e0[:, 0] = 1.0
        both = np.linalg.solve(normal, np.concatenate([rhs, e0], axis=2))
        fitted = both[:, 0, :-1]
        a = w * np.einsum("nki,ni->nk", design, both[:, :, -1])
    else:
        fitted = np.linalg.solve(normal, rhs)[:, 0, :]
    if degree == 1:
        return (fitted, a) if hat else fitted
    # A quadric may swing far past its data where they are sparse around a sharp peak: keep it between
    # the least neighbour over SWING and the largest times SWING (log), or within the neighbours' range
    # widened by SWING - 1 of it on each side (linear).
    live = w[:, :, None] > 0
    lo = np.where(live, near, np.inf).min(axis=1)
    hi = np.where(live, near, -np.inf).max(axis=1)
    if log:
        bounded = np.clip(fitted, lo - np.log(SWING), hi + np.log(SWING))
    else:
        bounded = np.clip(fitted, lo - (SWING - 1.0) * (hi - lo), hi + (SWING - 1.0) * (hi - lo))
    return (bounded, a) if hat else bounded
