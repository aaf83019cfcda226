"""Least-squares fits of a material model to measured f_r, with the Jacobian from Dr.Jit's AD.

The model is evaluated by the simulator's own code, :meth:`Material.eval_params`, on float64 AD arrays
of the chosen Dr.Jit backend (:func:`gonio.jit.resolve_backend`: CUDA when present): the fit variables
are opaque size-1 arrays with gradients enabled, so one compiled kernel serves every iteration, and the
Jacobian's columns are forward-mode derivatives (one ``dr.forward_from`` per variable through the same
graph, all columns evaluated in one launch).

The instrument. A reading averages f_r over the cone the source subtends and the cone the detector sees
(:mod:`gonio.fit.aperture`). Where the data say what those cones are (:class:`FitData`'s ``aperture``:
a campaign folder or its brdf.h5, :func:`gonio.dataset.aperture_cones`), the model is evaluated as the
instrument measures it: at M = 16 quadrature directions per sample (the same for every sample), weighted
as the calibrated reading weights them, and summed per sample. The sum is taken in numpy after the one
launch (``dr.block_sum`` launched a kernel of its own per channel and call), for the residuals and the
Jacobian's columns alike, so the AD Jacobian is that of the averaged model. Where they are not
known, the model is evaluated at the measured directions (the cones' axes): a GGX lobe of α = 0.15
through 0.5° and 1° cones is then fitted 36 σ off in α and 10 σ in rho_s (BENCHMARKS.md).
A projected Levenberg-Marquardt on the p × p normal equations (:func:`_projected_lm`) takes the
residuals, that Jacobian and the bounds (scipy's ``least_squares(method="trf")`` is the alternative,
``jac="trf-ad"``, and with finite differences the speed baseline of ``tools/bench_fit.py``).

Loss
----
``chi2``: r = (f_model − f) / σ with σ the measured standard deviation: the maximum-likelihood loss for
independent Gaussian errors. It weights every sample by how well it is known, which makes the peak of
a glossy lobe (large values, large absolute error) and the dim tails count by their information, and
it makes JᵀJ the Fisher information, so the uncertainties follow from the data's own error bars.
``cos``: r = cos θi cos θo (f_model − f), the error in reflected radiance per unit irradiance (what a
renderer integrates), for data without standard deviations; the cosines keep the grazing samples,
where f_r of glossy models diverges, from dominating. ``auto`` is ``chi2`` when at least half the samples of
every channel have σ > 0 (a σ of 0, an f_r of exactly 0 in a simulation, is floored at the channel's
smallest positive σ), else ``cos``.

Uncertainties
-------------
Cov = (JᵀJ)⁻¹ s² at the optimum, in the fit variables, carried to the spec parameters through the
Jacobian of the map between them (the energy fraction). ``cos``: s² = Σr² / (n − p), the residual
variance. ``chi2``: s² = max(1, χ²/(n − p)): the measured σ are trusted, and inflated by the Birge
ratio when the model does not fit within them. Reported as one standard deviation; the tests check
that the truth lies within 2σ. A variable at a bound is flagged (``at_bound``): its interval is
one-sided and the quadratic approximation does not hold there. Errors shared between samples (a
white reference or a dark reading calibrates many samples) enter the covariance when the data come with
their campaign's journal (:mod:`gonio.fit.shared`, a sandwich estimator); a brdf.h5 alone is taken as
independent samples. The uncertainties are those of the averaged model where the cones are known; the
quadrature's own error (:mod:`gonio.fit.aperture`: ~3e-5 relative on an α = 0.15 lobe) is not in them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import drjit as dr
import numpy as np

from gonio.fit.aperture import Aperture
from gonio.fit.models import FitModel
from gonio.geometry import to_half_diff
from gonio.jit import array_types, exact_float64, resolve_backend

__all__ = ["FitData", "Problem", "LOSSES", "solve", "residual_statistics"]

LOSSES = ("auto", "chi2", "cos")
#: Structure figure: residuals binned by half angle θh and difference angle θd (degrees).
STRUCTURE_BIN_DEG = 10.0
#: misfit flag: more than this fraction of the residual is explained by the (θh, θd) bins ...
MISFIT_STRUCTURE = 0.5
#: ... and the residual is more than this fraction of the (weighted) data.
MISFIT_RELATIVE = 0.02


@dataclass
class FitData:
    """Measured samples: unit directions (N, 3), f_r (N, C) in sr⁻¹, and its stddev (N, C) or None;
    ``aperture``: the cones the values were measured through (:class:`gonio.fit.aperture.Aperture`), or
    None (the model is then evaluated at the directions themselves)."""

    wi: np.ndarray
    wo: np.ndarray
    value: np.ndarray
    stddev: np.ndarray | None = None
    aperture: Aperture | None = None

    def __post_init__(self):
        self.value = np.asarray(self.value, dtype=np.float64).reshape(len(self.wi), -1)
        if self.stddev is not None:
            self.stddev = np.asarray(self.stddev, dtype=np.float64).reshape(self.value.shape)


class Problem:
    """Residuals and their AD Jacobian for one model, data set, channel choice and loss, on the Dr.Jit
    ``backend`` (``"llvm"`` or ``"cuda"``; default :func:`gonio.jit.resolve_backend`)."""

    def __init__(self, model: FitModel, data: FitData, loss: str = "auto", backend: str | None = None):
        if loss not in LOSSES:
            raise ValueError(f"loss: must be one of {', '.join(LOSSES)}, got {loss!r}")
        self.backend = resolve_backend(backend)
        t = array_types(self.backend, ad=True)
        self._float, self._vector = t.Float64, t.Array3f64
        self.model = model
        keep = (data.wi[:, 2] > 0) & (data.wo[:, 2] > 0) & np.isfinite(data.value).all(axis=1)
        chans = list(model.channels)
        sd = None
        if data.stddev is not None:
            keep &= np.isfinite(data.stddev[:, chans]).all(axis=1)
            sd = data.stddev[keep][:, chans]
        usable = sd is not None and bool(np.all(np.any(sd > 0, axis=0))) and float(np.mean(sd > 0)) >= 0.5
        if loss == "auto":
            loss = "chi2" if usable else "cos"
        if loss == "chi2" and not usable:
            raise ValueError("loss 'chi2' needs a stddev > 0 for most samples of every channel; use 'cos'")
        self.loss = loss
        self.keep, self.shared, self.shared_weights = keep, None, None
        self.wi, self.wo = data.wi[keep], data.wo[keep]
        self.value = data.value[keep][:, chans]
        self.floored = 0
        if loss == "chi2":
            # A sample with σ = 0 (f_r exactly 0 in every Monte Carlo lane of a simulation) is taken to be
            # known as well as the best-known sample of its channel, not infinitely well.
            floor = np.array([np.min(col[col > 0]) for col in sd.T])
            self.floored = int(np.sum(sd <= 0))
            self.weight = 1.0 / np.maximum(sd, floor)
        else:
            self.weight = np.repeat((self.wi[:, 2] * self.wo[:, 2])[:, None], len(chans), axis=1)
        self.n_samples = int(keep.sum())
        if self.n_samples * len(chans) <= len(model.variables):
            raise ValueError(f"{self.n_samples} usable samples cannot fix {len(model.variables)} parameters")

        def vec(v):
            return self._vector(*(self._float(np.ascontiguousarray(v[:, j])) for j in range(3)))

        self.aperture = data.aperture
        if self.aperture is None:
            self._wi, self._wo, self._lane_weight = vec(self.wi), vec(self.wo), None
        else:   # M lanes per sample, summed with the quadrature's weights (gonio.fit.aperture)
            wi_q, wo_q, weight = self.aperture.expand(self.wi, self.wo)
            self._wi, self._wo, self._lane_weight = vec(wi_q), vec(wo_q), self._float(weight)
        self._y = [self._float(np.ascontiguousarray(self.value[:, k])) for k in range(len(chans))]
        self._w = [self._float(np.ascontiguousarray(self.weight[:, k])) for k in range(len(chans))]
        self.evaluations = 0
        self.jacobians = 0

    def _residual_dr(self, x, grad: bool):
        xs = [dr.opaque(self._float, float(t)) for t in x]
        if grad:
            for v in xs:
                dr.enable_grad(v)
        values = self.model.values(xs, colour=self._vector)
        f = self.model.base.eval_params(values, self._wi, self._wo)
        if self._lane_weight is not None:   # f_r · weight per lane; summed per sample by _per_sample
            return xs, [f[c] * self._lane_weight for c in self.model.channels]
        res = [(f[c] - y) * w for c, y, w in zip(self.model.channels, self._y, self._w, strict=True)]
        return xs, res

    def _per_sample(self, arrays, residual: bool) -> np.ndarray:
        """The arrays of :meth:`_residual_dr` (or their derivatives) as one vector, channel-major: the
        residuals themselves at the axes; with an aperture, each sample's M lanes summed here (module
        docstring), then the data subtracted (``residual``) and the weights applied."""
        if self._lane_weight is None:
            return np.concatenate([a.numpy() for a in arrays])
        out = []
        for k, a in enumerate(arrays):
            f = a.numpy().reshape(-1, self.aperture.points).sum(axis=1)
            out.append(((f - self.value[:, k]) if residual else f) * self.weight[:, k])
        return np.concatenate(out)

    def residuals(self, x) -> np.ndarray:
        """Weighted residuals (n = samples × channels, channel-major) at the fit vector ``x``."""
        self.evaluations += 1
        with dr.suspend_grad(), exact_float64(self._float):
            _, res = self._residual_dr(x, False)
            dr.eval(res)
            return self._per_sample(res, True)

    def jacobian(self, x) -> np.ndarray:
        """∂residuals/∂x, (n, p), by forward-mode AD: one traversal per variable, one kernel launch."""
        self.jacobians += 1
        with exact_float64(self._float):
            xs, res = self._residual_dr(x, True)
            cols = []
            flags = dr.ADFlag.ClearInterior | dr.ADFlag.ClearInput
            for v in xs:
                dr.forward_from(v, flags=flags)
                cols.append([dr.grad(r) for r in res])
                for r in res:
                    dr.clear_grad(r)
            dr.eval(cols)
        return np.stack([self._per_sample(col, False) for col in cols], axis=1)

    def set_shared(self, u: np.ndarray | None, weights: np.ndarray | None = None) -> None:
        """Errors shared between samples, used by :func:`covariance` with the ``chi2`` loss: U (N, C, M)
        of :func:`gonio.fit.shared.shared_errors` for all N samples and channels of the data; or, for
        channels converted from B measured ones (a spectrometer's bands fitted as RGB), U (N, B, M) of
        the measured channels and ``weights`` (B, C), channel c = Σ_b weights[b, c] · band b, each
        band's error its own (its own column per reading, never materialized as (N, C, M·B))."""
        if u is None or self.loss != "chi2":
            return
        if weights is None:
            self.shared = u[self.keep][:, list(self.model.channels), :]
            self.shared_weights = np.eye(len(self.model.channels))
        else:
            self.shared = u[self.keep]
            self.shared_weights = np.asarray(weights, dtype=np.float64)[:, list(self.model.channels)]

    def bounds(self):
        return ([v.lo for v in self.model.variables], [v.hi for v in self.model.variables])


def solve(problem: Problem, *, starts: int = 4, jac: str = "ad", max_nfev: int = 200) -> dict:
    """Fit from ``starts`` start vectors; the best (least loss) wins.

    Parameters
    ----------
    problem : Problem
    starts : int
        Number of starts (>= 1); see :meth:`FitModel.starts`.
    jac : {"ad", "trf-ad", "2-point"}
        ``ad``: the Dr.Jit Jacobian in a projected Levenberg-Marquardt (:func:`_projected_lm`);
        ``trf-ad``: the same Jacobian in scipy's ``least_squares(method="trf")``; ``2-point``: scipy's
        trf with finite differences (the speed baseline).
    max_nfev : int
        Iteration limit per start.

    Returns
    -------
    dict
        ``x`` (best fit vector), ``cost`` (Σ r² there), ``jacobian`` (AD, at ``x``), ``runs`` (per
        start: start vector, cost, function evaluations, status) and ``seconds``.
    """
    if starts < 1:
        raise ValueError(f"starts: must be >= 1, got {starts}")
    t0 = time.perf_counter()
    lo, hi = problem.bounds()
    runs, best = [], None
    jacobian = problem.jacobian if jac == "trf-ad" else jac
    for x0 in problem.model.starts(starts):
        if jac == "ad":
            x, cost, nfev, status = _projected_lm(problem, np.asarray(x0, dtype=np.float64), lo, hi, max_nfev)
            runs.append({"start": [float(t) for t in x0], "loss": cost, "nfev": nfev, "status": status})
            if best is None or cost < best[1]:
                best = (x, cost)
            continue
        from scipy.optimize import least_squares  # only the trf paths: its import costs ~0.5 s of CPU

        r = least_squares(problem.residuals, np.asarray(x0), jac=jacobian, bounds=(lo, hi), method="trf",
                          x_scale="jac", ftol=1e-12, xtol=1e-12, gtol=1e-12, max_nfev=max_nfev)
        cost = float(np.sum(r.fun ** 2))
        runs.append({"start": [float(t) for t in x0], "loss": cost, "nfev": int(r.nfev),
                     "status": int(r.status)})
        if best is None or cost < best[1]:
            best = (r.x, cost)
    x = best[0]
    return {"x": x, "cost": best[1], "runs": runs, "seconds": time.perf_counter() - t0}


def _projected_lm(problem: Problem, x, lo, hi, max_iter: int):
    """Levenberg-Marquardt on the p × p normal equations, with the bounds as an active set.

    scipy's trf spends most of a 10,000-sample fit in SVDs of the n × p Jacobian; the normal
    equations JᵀJ δ = −Jᵀr are p × p. Each step solves (JᵀJ + λ diag JᵀJ) δ = −Jᵀr over the free
    variables (those not at a bound with the gradient pushing outward), clips to the bounds, and is
    taken when the loss falls (λ shrinks) or refused (λ grows). Stops when the relative fall of the
    loss and the step are below 1e-12, or after ``max_iter`` Jacobians.
    Returns (x, loss, residual evaluations, status: 1 converged, 0 iteration limit).
    """
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    x = np.clip(x, lo, hi)
    r = problem.residuals(x)
    cost = float(r @ r)
    nfev, lam = 1, 1e-3
    for _ in range(max_iter):
        j = problem.jacobian(x)
        g = j.T @ r
        a = j.T @ j
        at_lo = (x <= lo) & (g > 0)
        at_hi = (x >= hi) & (g < 0)
        free = ~(at_lo | at_hi)
        if not free.any():
            return x, cost, nfev, 1
        af, gf = a[np.ix_(free, free)], g[free]
        diag = np.maximum(np.diag(af), 1e-300)
        while True:
            step = np.zeros_like(x)
            try:
                step[free] = np.linalg.solve(af + lam * np.diag(diag), -gf)
            except np.linalg.LinAlgError:
                step[free] = -gf / (diag * (1 + lam))
            trial = np.clip(x + step, lo, hi)
            rt = problem.residuals(trial)
            nfev += 1
            ct = float(rt @ rt)
            if ct <= cost:
                small = (cost - ct) <= 1e-12 * cost and \
                    np.all(np.abs(trial - x) <= 1e-10 * (np.abs(x) + 1e-10))
                x, r, cost = trial, rt, ct
                lam = max(lam / 10.0, 1e-12)
                if small:
                    return x, cost, nfev, 1
                break
            lam *= 10.0
            if lam > 1e12:
                return x, cost, nfev, 1
    return x, cost, nfev, 0


def covariance(problem: Problem, x: np.ndarray, residual: np.ndarray) -> tuple[np.ndarray, float]:
    """Covariance of the fit variables at ``x`` (module docstring) and the scale s² applied.

    With shared errors U (``problem.shared``, ``chi2`` only) the samples' covariance is
    C = diag(σ² − ΣU²) + U Uᵀ per channel, and the covariance of the weighted fit is the sandwich
    A⁻¹ Jᵀ W C W J A⁻¹ with A = Jᵀ W J, W = diag(1/σ²) (J: unweighted model Jacobian). Channels
    converted from measured ones (:meth:`Problem.set_shared`'s ``weights``) take one column per
    measured channel and reading, U_b · weights[b, c]; their U Uᵀ is summed band by band.
    """
    jac = problem.jacobian(x)
    n, p = jac.shape
    dof = max(n - p, 1)
    s2 = float(residual @ residual) / dof
    if problem.loss == "chi2":
        s2 = max(1.0, s2)
    a_inv = np.linalg.pinv(jac.T @ jac)
    if problem.shared is None:
        return a_inv * s2, s2
    n_s = problem.shared.shape[0]
    meat = np.zeros((p, p))
    for k in range(problem.shared_weights.shape[1]):
        rows = slice(k * n_s, (k + 1) * n_s)
        jk, w = jac[rows], problem.weight[:, k]
        shared_sq = np.zeros(n_s)
        for band in np.flatnonzero(problem.shared_weights[:, k]):
            # weighted shared errors (N, M) of this band's readings in channel k
            uw = problem.shared[:, band, :] * (problem.shared_weights[band, k] * w)[:, None]
            shared_sq += np.sum(uw * uw, axis=1)
            b = jk.T @ uw
            meat += b @ b.T
        independent = np.clip(1.0 - shared_sq, 1e-6, None)
        meat += (jk * independent[:, None]).T @ jk
    return a_inv @ meat @ a_inv * s2, s2


def residual_statistics(problem: Problem, residual: np.ndarray, p: int) -> dict:
    """Residual figures of a fit: counts, loss, χ²/dof, relative size and structure.

    ``structure`` is the adjusted fraction of Σr² that the means of the residuals in (θh, θd) bins of
    :data:`STRUCTURE_BIN_DEG` (per channel) explain: η² = Σ_b n_b r̄_b² / Σ r², corrected for the
    B/n that pure noise explains, (η² − B/n) / (1 − B/n). Independent noise gives ~0; a model of the
    wrong shape leaves residuals that agree within a bin, near 1. ``rms_relative`` = ‖r‖ / ‖w f‖, the
    misfit relative to the weighted data. ``misfit`` (the flag for reports) is structure >
    :data:`MISFIT_STRUCTURE` and rms_relative > :data:`MISFIT_RELATIVE`.
    """
    n = residual.size
    dof = max(n - p, 1)
    chi2 = float(residual @ residual)
    theta_h, _, theta_d, _ = to_half_diff(problem.wi, problem.wo)
    step = np.radians(STRUCTURE_BIN_DEG)
    cell = (np.floor(theta_h / step) * 100 + np.floor(theta_d / step)).astype(np.int64)
    c = len(problem.model.channels)
    cells = np.concatenate([cell + 10_000 * k for k in range(c)])
    _, inverse, counts = np.unique(cells, return_inverse=True, return_counts=True)
    sums = np.bincount(inverse, weights=residual)
    explained = float(np.sum(sums ** 2 / counts))
    bins = len(counts)
    eta2 = explained / chi2 if chi2 > 0 else 0.0
    structure = (eta2 - bins / n) / (1 - bins / n) if n > bins else float("nan")
    data = (problem.value * problem.weight).T.ravel()
    rel = float(np.sqrt(chi2 / max(float(data @ data), 1e-300)))
    return {"residuals": n, "parameters": p, "dof": n - p, "loss": chi2, "chi2_reduced": chi2 / dof,
            "rms": float(np.sqrt(chi2 / n)), "max_abs": float(np.max(np.abs(residual))),
            "rms_relative": rel, "structure": float(structure), "structure_bins": bins,
            "misfit": bool(structure > MISFIT_STRUCTURE and rel > MISFIT_RELATIVE)}
