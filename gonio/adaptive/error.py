"""The benchmark's error of a reconstruction: cosine-weighted relative L1 against the true f_r at
random direction pairs.

Pairs are drawn uniformly (seeded) on the hemisphere for ωi and for ωo independently, keeping pairs
with both θ at most ``theta_max`` (a gantry measures nothing beyond its own limit, so neither a uniform
nor an adaptive campaign can answer there). The error is Σ |f̂ − f| cos θi cos θo / Σ f cos θi cos θo,
summed over pairs and channels; a pair the reconstruction leaves without a value (NaN) counts as f̂ = 0.
"""

from __future__ import annotations

import numpy as np

__all__ = ["random_pairs", "weighted_l1"]


def random_pairs(n: int, theta_max: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` direction pairs (ωi, ωo), each (n, 3), uniform on the hemisphere cap θ <= theta_max."""
    rng = np.random.default_rng(seed)
    lo = np.cos(theta_max)

    def cap(m):
        z = rng.uniform(lo, 1.0, m)
        phi = rng.uniform(0.0, 2.0 * np.pi, m)
        r = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
        return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)

    return cap(n), cap(n)


def weighted_l1(estimate, truth, wi, wo) -> tuple[float, float]:
    """(relative L1 error, fraction of pairs answered) of ``estimate`` (n, C) against ``truth`` (n, C)."""
    est = np.asarray(estimate, dtype=np.float64)
    true = np.asarray(truth, dtype=np.float64).reshape(est.shape)
    w = (np.asarray(wi)[:, 2] * np.asarray(wo)[:, 2])[:, None]
    answered = np.isfinite(est).all(axis=1)
    err = np.abs(np.where(np.isfinite(est), est, 0.0) - true) * w
    return float(err.sum() / (true * w).sum()), float(answered.mean())
