"""One refinement round: where the next poses go, as a pure function of the samples so far.

Each sample owns a cell (the poses nearer to it than to any other sample, in the embedding of
:mod:`gonio.adaptive.domain`). A cell's share of the benchmark's error is estimated as

    E_j = |r_j| · m_j,

with r_j the sample's leave-one-out residual (:func:`gonio.adaptive.reconstruct.loo_residual`, summed over
channels: how far f_r there departs from what the reconstruction makes of its neighbours alone, i.e. the
reconstruction's error at the local spacing; large on the peak's flanks, on a Fresnel rise, at grazing)
and m_j the cell's weight in the error: the measure of uniformly random direction pairs in the cell,
times cos θi cos θo. m_j is the volume of a ball of radius ρ_j / 2 (ρ_j: the distance to the nearest
other sample) times the pair density there, estimated from a seeded cloud of uniformly random pairs
(their count within a radius that holds :data:`DENSITY_NEIGHBOURS` of them).

The ``n`` cells of largest E_j each get one new pose (fewer cells than ``n``: the largest get more, in
turn): of :data:`TRIALS` seeded points in the ball of radius ρ_j around the sample, the one farthest from
every sample and every pose chosen before it in the round, among those the gantry can reach
(:func:`gonio.adaptive.reach.reachable_iso`) and within theta_max. Whatever cannot be placed so (no
reachable trial) is taken, farthest first, from the reachable uniform cloud, so a round returns exactly
``n`` poses whenever the reachable domain holds them, and fewer (none at all) where the gantry's reach,
its occlusion cone and theta_max leave no more new poses: the caller decides what that means (an
adaptive campaign ends, :func:`gonio.adaptive.plan.next_round`).

With a motion cost (:class:`gonio.adaptive.motion.Motion`), the ``motion.pool`` · n cells of largest E_j
are placed so, and n of those poses are taken by E_j per second of gantry time
(:func:`gonio.adaptive.motion.cheapest_first`).

The same round places anisotropic poses in the ``pair`` domain (:mod:`gonio.adaptive.domain`, 4D:
balls, volumes and trial points in its dimension; reach by :func:`gonio.adaptive.reach.reachable_pair`);
it then returns (θi, φi, θo, φo).

Purity: the only inputs are the samples, ``n``, the gantry (its reach), theta_max, the domain and a
seed; random numbers come from ``numpy.random.default_rng([seed, len(samples)])``; nothing reads a clock
or a global state (the seeded uniform cloud is remembered per process, a pure function of theta_max, the
seed and the domain). The same inputs give the same poses, bit for bit, which is what lets a resume replay a
round from the journal.
"""

from __future__ import annotations

import functools

import numpy as np

from gonio.adaptive.domain import embed_pairs, poses_of
from gonio.adaptive.error import random_pairs
from gonio.adaptive.motion import Motion, cheapest_first
from gonio.adaptive.reach import reachable_iso, reachable_pair
from gonio.adaptive.reconstruct import loo_residual
from gonio.adaptive.samples import Samples

__all__ = ["plan_round", "cell_errors", "spacing", "TRIALS", "CLOUD", "DENSITY_NEIGHBOURS", "CELLS", "LOO",
           "PAIR_CELLS", "PAIR_LOO"]

#: Seeded trial points per refined cell.
TRIALS = 32
#: Uniformly random pairs that measure the pair density (and stand by as fallback poses).
CLOUD = 40_000
#: Cloud points within the radius at which the density around a sample is estimated.
DENSITY_NEIGHBOURS = 24
#: The embedding the cells and trial points live in (:mod:`gonio.adaptive.domain`). With the log-quadric
#: residuals, (θi, θo, Δφ) cells left 14-42 % less error than half/difference ones at 1,156 poses
#: (``tools/bench_adaptive.py --engines``); with planes fitted to f_r it was the other way round.
CELLS = "iso"
#: The fit whose leave-one-out residuals rate the cells: (domain, transform, degree) of
#: :class:`gonio.adaptive.reconstruct.LocalFit`; the reconstruction's own. At 1,156 poses (measured with
#: half/difference cells) it left 30 % less error than planes fitted to f_r in the half/difference
#: domain on cook-torrance and lambert+ggx, 20 % less on ggx α = 0.2 and 35 % more on ggx α = 0.05.
LOO = ("iso", "log", 2)
#: The cells and the fit of anisotropic rounds: the same, in the 4D ``pair`` domain.
PAIR_CELLS, PAIR_LOO = "pair", ("pair", *LOO[1:])


def cell_errors(samples: Samples, theta_max: float, domain: str = CELLS, seed: int = 0,
                loo: tuple = LOO) -> np.ndarray:
    """E_j of every sample (module docstring), shape (N,)."""
    from scipy.spatial import cKDTree

    points, owner = samples.points(domain)
    n = len(samples)
    near = spacing(cKDTree(points), points, owner, n)
    cloud = _cloud_tree(float(theta_max), int(seed), domain)
    radius = cloud.query(points[:n], k=DENSITY_NEIGHBOURS)[0][:, -1]
    dim = points.shape[1]
    density = DENSITY_NEIGHBOURS / (CLOUD * radius ** dim)  # per unit volume, up to a constant
    weight = np.cos(samples.theta_i) * np.cos(samples.theta_o)
    mass = density * (0.5 * near) ** dim * weight
    return np.abs(loo_residual(samples, *loo)).sum(axis=1) * mass


def plan_round(samples: Samples, n: int, kin, theta_max: float, domain: str = CELLS, seed: int = 0,
               loo: tuple = LOO, motion: Motion | None = None) -> tuple[np.ndarray, ...]:
    """The next ``n`` poses (θi, θo, Δφ as measured, φi = 0; radians; in the ``pair`` domain
    (θi, φi, θo, φo)), in the order chosen; fewer when
    the reachable domain holds no more new poses (module docstring). With ``motion``, a pool of
    ``motion.pool`` · n poses is placed so and ``n`` of them are taken by their error per second of gantry
    time (:func:`gonio.adaptive.motion.cheapest_first`).

    Raises
    ------
    ValueError
        When ``n`` is negative.
    """
    from scipy.spatial import cKDTree

    if n < 0:
        raise ValueError(f"n: must be >= 0, got {n}")
    columns = 4 if domain == "pair" else 3
    if n == 0:
        return tuple(np.zeros(0) for _ in range(columns))
    rng = np.random.default_rng([seed, len(samples)])
    points, owner = samples.points(domain)
    tree = cKDTree(points)
    near = spacing(tree, points, owner, len(samples))
    score = cell_errors(samples, theta_max, domain, seed, loo)
    m = n if motion is None else motion.pool * n
    # Cells by decreasing error; ties by sample index (lexsort is stable), cycled when m exceeds them.
    order = np.lexsort((np.arange(len(samples)), -score))
    cells = order[np.arange(m) % len(order)]
    # Trial points uniform in the ball of radius ρ_j around each chosen cell's sample.
    dim = points.shape[1]
    direction = rng.normal(size=(m, TRIALS, dim))
    direction /= np.linalg.norm(direction, axis=2, keepdims=True)
    radius = near[cells][:, None] * rng.uniform(0.0, 1.0, (m, TRIALS)) ** (1.0 / dim)
    trial = points[cells][:, None, :] + direction * radius[:, :, None]
    poses = _measurable(kin, trial.reshape(-1, dim), theta_max, domain)
    ok = poses[0].reshape(m, TRIALS)
    gap = tree.query(trial.reshape(-1, dim))[0].reshape(m, TRIALS)
    chosen: list[np.ndarray] = []
    chosen_poses: list[tuple[float, ...]] = []
    worth: list[float] = []
    for c in range(m):
        d = np.where(ok[c], gap[c], -1.0)
        if chosen:
            apart = np.linalg.norm(trial[c][:, None, :] - np.asarray(chosen)[None], axis=2).min(axis=1)
            d = np.minimum(d, apart)
        best = int(np.argmax(d))
        if d[best] <= 0.0:
            continue
        chosen.append(trial[c, best])
        chosen_poses.append(tuple(p.reshape(m, TRIALS)[c, best] for p in poses[1:]))
        worth.append(float(score[cells[c]]))
    if motion is not None and len(chosen_poses) > n:
        pool = np.asarray(chosen_poses, dtype=np.float64)
        if domain == "pair":
            keep = cheapest_first(kin, motion, pool[:, 0], pool[:, 2], pool[:, 3] - pool[:, 1],
                                  np.asarray(worth), n, phi_i=pool[:, 1])
        else:
            keep = cheapest_first(kin, motion, pool[:, 0], pool[:, 1], pool[:, 2], np.asarray(worth), n)
        chosen = [chosen[k] for k in keep]
        chosen_poses = [chosen_poses[k] for k in keep]
    if len(chosen) < n:
        chosen_poses += _fallback(samples, np.asarray(chosen).reshape(-1, dim), n - len(chosen), kin,
                                  theta_max, domain, seed, tree)
    out = np.asarray(chosen_poses, dtype=np.float64).reshape(-1, columns)
    return tuple(out[:, c].copy() for c in range(columns))


@functools.lru_cache(maxsize=8)
def _cloud(theta_max: float, seed: int, domain: str) -> np.ndarray:
    """The seeded uniform cloud of :data:`CLOUD` pairs embedded in ``domain`` (read-only). It depends on
    these three alone, so the rounds of a campaign draw it once per process, not once a round."""
    wi, wo = random_pairs(CLOUD, theta_max, seed)
    cloud = embed_pairs(domain, wi, wo)
    cloud.flags.writeable = False
    return cloud


@functools.lru_cache(maxsize=8)
def _cloud_tree(theta_max: float, seed: int, domain: str):
    """A k-d tree over :func:`_cloud` (queries only), built once per process."""
    from scipy.spatial import cKDTree

    return cKDTree(_cloud(theta_max, seed, domain))


def spacing(tree, points, owner, n: int) -> np.ndarray:
    """ρ_j: each of the first ``n`` points' distance to the nearest point of another sample (a pose on the
    specular line θo = θi, Δφ = π is its own reciprocal twin: that copy does not count)."""
    k = min(3, len(points))
    dist, idx = tree.query(points[:n], k=k)
    dist, idx = dist.reshape(n, -1), idx.reshape(n, -1)
    other = np.where(owner[idx] != np.arange(n)[:, None], dist, np.inf).min(axis=1)
    return np.where(np.isfinite(other), other, 0.0)


def _measurable(kin, points, theta_max, domain):
    """(ok, θi, θo, Δφ as measured) of embedded points; (ok, θi, φi, θo, φo) in ``pair``."""
    if domain == "pair":
        ti, pi_, to, po = poses_of(domain, points)
        inside = (ti <= theta_max) & (to <= theta_max)
        ok, angles = reachable_pair(kin, np.where(inside, ti, 0.0), pi_, np.where(inside, to, 0.0), po,
                                    theta_max)
        return (ok & inside, *angles)
    ti, to, d = poses_of(domain, points)
    inside = (ti >= 0.0) & (to >= 0.0) & (ti <= theta_max) & (to <= theta_max)
    ok, (mti, _, mto, mpo) = reachable_iso(kin, np.where(inside, ti, 0.0), np.where(inside, to, 0.0), d,
                                           theta_max)
    return ok & inside, mti, mto, mpo


def _fallback(samples, chosen, count, kin, theta_max, domain, seed, tree):
    """Up to ``count`` reachable poses of the uniform cloud, farthest from the samples and each other
    first (fewer when the cloud holds no more reachable poses apart from every sample)."""
    from scipy.spatial import cKDTree

    cloud = _cloud(float(theta_max), int(seed) + 1, domain)
    ok, *angles = _measurable(kin, cloud, theta_max, domain)
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return []
    gap = tree.query(cloud[idx])[0]
    if len(chosen):
        gap = np.minimum(gap, cKDTree(chosen).query(cloud[idx])[0])
    out = []
    for _ in range(count):
        best = int(np.argmax(gap))
        if gap[best] <= 0.0:
            break
        out.append(tuple(a[idx[best]] for a in angles))
        gap = np.minimum(gap, np.linalg.norm(cloud[idx] - cloud[idx[best]], axis=1))
    return out
