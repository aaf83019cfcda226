"""The pilot: a coarse isotropic lattice that spans the whole domain the gantry reaches.

θi, θo take ``m`` values evenly from 0 to theta_max (so the pilot reaches the limit: a reconstruction
answers nothing past its largest θ), Δφ takes ``K`` even values over [0, 2π), K ≈ 4.5 (m − 1) so the
azimuthal spacing at θ = 80° roughly matches the polar one, with the uniform grids' reciprocity and
pole rules (:mod:`gonio.plan.grids`). Every such lattice holds the exact specular poses θo = θi,
Δφ = π (K is even), so the pilot sees every isotropic material's specular lobe at its peak whatever its
width; it also sees the diffuse floor, the Fresnel rise and the grazing poses that a specular-plane
scan alone misses (``tools/bench_adaptive.py --pilots`` compares the fractions of the budget).
"""

from __future__ import annotations

import numpy as np

from gonio.adaptive.reach import reachable_iso

__all__ = ["pilot_poses", "pilot_nodes", "lattice"]


def lattice(m: int, theta_max: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(θi, θo, Δφ) of the ``m``-node lattice (radians), one pose per reciprocal pair, the pole once."""
    k = max(2, 2 * round(2.25 * (m - 1)))
    a, b, c = (x.ravel() for x in np.meshgrid(np.arange(m), np.arange(m), np.arange(k), indexing="ij"))
    keep = (((a > 0) & (b > 0)) | (c == 0)) & ((a < b) | ((a == b) & (2 * c <= k)))
    theta = np.linspace(0.0, theta_max, m)
    return theta[a[keep]], theta[b[keep]], np.where(b[keep] > 0, c[keep] * 2.0 * np.pi / k, 0.0)


def pilot_nodes(kin, theta_max: float, budget: int) -> int:
    """``m`` of the densest lattice of at most ``budget`` reachable poses (at least 2)."""
    best = 2
    for m in range(2, 200):
        ok, _ = reachable_iso(kin, *lattice(m, theta_max), theta_max)
        if m > 2 and ok.sum() > budget:
            break
        best = m
    return best


def pilot_poses(kin, theta_max: float, budget: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The reachable poses (θi, θo, Δφ as measured, φi = 0) of the densest lattice of at most ``budget``
    reachable poses (at least the 2-node lattice: :func:`pilot_nodes`)."""
    ok, (ti, _, to, po) = reachable_iso(kin, *lattice(pilot_nodes(kin, theta_max, budget), theta_max),
                                        theta_max)
    return ti[ok], to[ok], po[ok]
