"""The pilot: a coarse isotropic lattice that spans the whole domain the gantry reaches.

θi, θo take ``m`` values evenly from 0 to theta_max (so the pilot reaches the limit: a reconstruction
answers nothing past its largest θ), Δφ takes ``K`` even values over [0, 2π), K ≈ 4.5 (m − 1) so the
azimuthal spacing at θ = 80° roughly matches the polar one, with the uniform grids' reciprocity and
pole rules (:mod:`gonio.plan.grids`). Every such lattice holds the exact specular poses θo = θi,
Δφ = π (K is even), so the pilot sees every isotropic material's specular lobe at its peak whatever its
width; it also sees the diffuse floor, the Fresnel rise and the grazing poses that a specular-plane
scan alone misses (``tools/bench_adaptive.py --pilots`` compares the fractions of the budget).

The anisotropic pilot (:func:`pilot_pairs`) is the coarsest uniform 4D grid, ``full:step=S``
(:mod:`gonio.plan.grids`, reciprocity only), of the densest step in :data:`PAIR_STEPS` with at most
``budget`` reachable poses. Where the lobe lies in φ is what an anisotropic material does not tell
in advance; a full lattice holds the specular pose of every (θi, φi) node it has (φo = φi + π is on
it: the steps divide 180°), so it sees the lobe at each sampled azimuth, and its floor, rise and
grazing poses as the isotropic pilot does.
"""

from __future__ import annotations

import numpy as np

from gonio.adaptive.reach import reachable_iso, reachable_pair

__all__ = ["pilot_poses", "pilot_nodes", "lattice", "pilot_pairs", "pair_lattice", "PAIR_STEPS"]

#: Steps (degrees) of the anisotropic pilot's ``full`` grid, coarsest first (each divides 180°).
PAIR_STEPS = (60.0, 45.0, 36.0, 30.0, 22.5, 20.0, 18.0, 15.0, 12.0, 10.0)


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


def pair_lattice(step: float, theta_max: float) -> tuple[np.ndarray, ...]:
    """(θi, φi, θo, φo) of ``full:step=S`` up to theta_max (radians; one pose per reciprocal pair)."""
    from gonio.plan.grids import enumerate_grid, parse_grid

    grid = enumerate_grid(parse_grid(f"full:step={step:g}"), float(np.degrees(theta_max)))
    keep = (grid.theta_i <= theta_max + 1e-12) & (grid.theta_o <= theta_max + 1e-12)
    angles = (grid.theta_i, grid.phi_i, grid.theta_o, grid.phi_o)
    return tuple(np.asarray(a, np.float64)[keep] for a in angles)


def pilot_pairs(kin, theta_max: float, budget: int) -> tuple[float, tuple[np.ndarray, ...]]:
    """(step, the reachable poses (θi, φi, θo, φo) as measured) of the densest :func:`pair_lattice` of at
    most ``budget`` reachable poses (the coarsest of :data:`PAIR_STEPS` with 2 or more at least)."""
    best = None
    for step in PAIR_STEPS:
        ok, angles = reachable_pair(kin, *pair_lattice(step, theta_max), theta_max)
        if best is not None and best[1][0].size >= 2 and ok.sum() > budget:
            break
        best = step, tuple(a[ok] for a in angles)
    return best
