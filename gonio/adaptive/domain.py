"""Embeddings of the isotropic pose domain in which distances are measured and planes are fitted.

- ``iso``: (θi, θo cos Δφ, θo sin Δφ), the embedding of :mod:`gonio.interpolate`'s scattered engine.
  A glossy lobe is a thin tube around the specular line θo = θi, Δφ = π there.
- ``half``: Rusinkiewicz half/difference angles, (√(θh · π/2), θd cos 2φd, θd sin 2φd). A microfacet
  lobe depends mostly on θh (the facet distribution) and slowly on θd (Fresnel, masking), so it is a
  slab near θh = 0; the square root stretches that slab (as MERL's table does) so the same number of
  neighbours resolves it. 2φd makes the embedding invariant under Helmholtz reciprocity (ωi ↔ ωo turns φd
  into φd + π) and smooth at θd = 0, where φd is irrelevant.
- ``pair``: the anisotropic domain (θi, φi, θo, φo), each direction in azimuthal-equidistant
  coordinates: (θi cos φi, θi sin φi, θo cos φo, θo sin φo). It is ``iso``'s metric with φi free: θ
  linear in the radius (no pole singularity, distances close to the angles between directions on each
  hemisphere), a chart of the whole (ωi, ωo) domain in 4D (the tree's and the fit's dimension). A glossy
  lobe is a thin tube around the specular plane (the second pair of coordinates minus the first's); an
  anisotropic one is elliptic around it, which a local quadric in these coordinates follows. Reciprocity
  is not built in (a sample and its twin are two points, as in ``iso``); isotropy is not assumed.
"""

from __future__ import annotations

import numpy as np

from gonio.geometry import from_half_diff, sph_to_vec, to_half_diff, vec_to_sph

__all__ = ["DOMAINS", "embed_pairs", "embed_poses", "poses_of"]

DOMAINS = ("iso", "half", "pair")
_TWO_PI = 2.0 * np.pi
_H = 0.5 * np.pi


def embed_pairs(domain: str, wi, wo) -> np.ndarray:
    """(N, 3) points of direction pairs (unit vectors (N, 3))."""
    wi, wo = np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64)
    if domain == "pair":
        ti, pi_ = vec_to_sph(wi)
        to, po = vec_to_sph(wo)
        return embed_poses("pair", ti, to, np.mod(po - pi_, _TWO_PI), pi_)
    if domain == "iso":
        ti, pi_ = vec_to_sph(wi)
        to, po = vec_to_sph(wo)
        return embed_poses("iso", ti, to, np.where(to > 0, np.mod(po - pi_, _TWO_PI), 0.0))
    th, _, td, pd = to_half_diff(wi, wo)
    return np.stack([np.sqrt(np.clip(th, 0.0, None) * _H), td * np.cos(2 * pd), td * np.sin(2 * pd)], axis=-1)


def embed_poses(domain: str, theta_i, theta_o, dphi, phi_i=0.0) -> np.ndarray:
    """(N, 3) points of poses (θi, θo, Δφ), radians ((N, 4) in ``pair``, where φi counts: the other
    domains are isotropic and ignore it)."""
    ti, to, d, pi_ = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64).ravel()
                                           for a in (theta_i, theta_o, dphi, phi_i)))
    if domain == "pair":
        po = pi_ + d
        return np.stack([ti * np.cos(pi_), ti * np.sin(pi_), to * np.cos(po), to * np.sin(po)], axis=-1)
    if domain == "iso":
        return np.stack([ti, to * np.cos(d), to * np.sin(d)], axis=-1)
    zero = np.zeros_like(ti)
    return embed_pairs(domain, sph_to_vec(ti, zero), sph_to_vec(to, d))


def poses_of(domain: str, points) -> tuple[np.ndarray, ...]:
    """(θi, θo, Δφ) of embedded points (N, 3); Δφ in [0, 2π) and 0 where θo = 0. In the ``half`` domain
    a point may lie below the horizon (θ >= π/2): callers check θ against their limit. In ``pair``
    (points (N, 4)): (θi, φi, θo, φo), φ in [0, 2π) and 0 at the pole."""
    if domain == "pair":
        p = np.asarray(points, dtype=np.float64).reshape(-1, 4)
        out = []
        for x, y in ((p[:, 0], p[:, 1]), (p[:, 2], p[:, 3])):
            theta = np.hypot(x, y)
            phi = np.mod(np.arctan2(y, x), _TWO_PI)
            out += [theta, np.where((theta > 0) & (phi < _TWO_PI), phi, 0.0)]
        return tuple(out)
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if domain == "iso":
        ti, to = p[:, 0], np.hypot(p[:, 1], p[:, 2])
        d = np.mod(np.arctan2(p[:, 2], p[:, 1]), _TWO_PI)
        return ti.copy(), to, np.where((to > 0) & (d < _TWO_PI), d, 0.0)
    th = np.clip(p[:, 0], 0.0, None) ** 2 / _H
    td = np.hypot(p[:, 1], p[:, 2])
    pd = 0.5 * np.arctan2(p[:, 2], p[:, 1])
    wi, wo = from_half_diff(th, np.zeros_like(th), td, pd)
    ti, pi_ = vec_to_sph(wi)
    to, po = vec_to_sph(wo)
    d = np.mod(po - pi_, _TWO_PI)
    return ti, to, np.where((to > 1e-12) & (ti > 1e-12) & (d < _TWO_PI), d, 0.0)
