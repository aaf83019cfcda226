"""Directions in the sample frame, and the parameterizations that BRDF data uses.

Conventions (see DESIGN.md): +z is the sample normal, +x the sample's reference direction. θ is the
polar angle from +z, φ the azimuth counter-clockwise from +x seen from above. ωi points from the sample
toward the light, ωo toward the detector. All angles here are radians; arrays broadcast; vectors are
``(..., 3)`` float64 arrays.

Rusinkiewicz half/difference angles: the half vector h = (ωi + ωo)/|ωi + ωo| has angles (θh, φh); the
difference vector is ωi rotated by −φh about z and then by −θh about y, with angles (θd, φd).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

__all__ = [
    "TWO_PI",
    "MERL_SHAPE",
    "sph_to_vec",
    "from_half_diff_grid",
    "vec_to_sph",
    "wrap_2pi",
    "mirror_angles",
    "reflect",
    "half_vector",
    "to_half_diff",
    "from_half_diff",
    "merl_index",
    "merl_unindex",
    "merl_bin_centres",
    "merl_centre_angles",
    "canonical_reciprocal",
    "to_isotropic",
    "canonical_isotropic",
]

TWO_PI = 2.0 * np.pi
HALF_PI = 0.5 * np.pi
#: MERL table shape: θh bins (square-root mapping), θd bins, φd bins (φd folded into [0, π)).
MERL_SHAPE = (90, 90, 180)
# Angles closer than this are "the same" when canonicalizing (grid values come from degrees).
_ANGLE_EPS = 1e-9


def sph_to_vec(theta, phi) -> np.ndarray:
    """Unit vector(s) for polar angle ``theta`` and azimuth ``phi`` (radians)."""
    theta = np.asarray(theta, dtype=np.float64)
    phi = np.asarray(phi, dtype=np.float64)
    st = np.sin(theta)
    return np.stack(np.broadcast_arrays(st * np.cos(phi), st * np.sin(phi), np.cos(theta)), axis=-1)


def wrap_2pi(phi) -> np.ndarray:
    """Azimuth folded into [0, 2π)."""
    out = np.mod(np.asarray(phi, dtype=np.float64), TWO_PI)
    # np.mod can return exactly 2π for tiny negative inputs.
    return np.where(out >= TWO_PI, 0.0, out)


def vec_to_sph(v) -> tuple[np.ndarray, np.ndarray]:
    """(θ, φ) of vector(s) ``v`` of any non-zero length; φ in [0, 2π), and φ = 0 at the poles.

    θ is NaN for the zero vector (it has no direction).
    """
    v = np.asarray(v, dtype=np.float64)
    z = v[..., 2]
    rho = np.hypot(v[..., 0], v[..., 1])
    # No explicit normalization: atan2 of (ρ, z) is scale-free (a norm would underflow for |v| < 1e-154
    # and overflow for |v| > 1e154), and keeps full precision near the poles, where acos(z) loses it.
    n = np.hypot(rho, z)
    theta = np.where(n > 0.0, np.arctan2(rho, z), np.nan)
    phi = np.where(rho > 1e-15 * n, wrap_2pi(np.arctan2(v[..., 1], v[..., 0])), 0.0)
    return theta, phi


def mirror_angles(theta, phi) -> tuple[np.ndarray, np.ndarray]:
    """The mirror (specular) direction of (θ, φ): (θ, φ + π)."""
    return np.asarray(theta, dtype=np.float64), wrap_2pi(np.asarray(phi, dtype=np.float64) + np.pi)


def reflect(v) -> np.ndarray:
    """R(v) = −v + 2 (v·N) N with N = +z: the mirror direction of ``v``."""
    v = np.asarray(v, dtype=np.float64)
    return v * np.array([-1.0, -1.0, 1.0])


def half_vector(wi, wo) -> np.ndarray:
    """H = (ωi + ωo) / |ωi + ωo|. Undefined (NaN) for exactly opposite directions."""
    h = np.asarray(wi, dtype=np.float64) + np.asarray(wo, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        return h / np.linalg.norm(h, axis=-1, keepdims=True)


def _rot_z(v, angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1], v[..., 2]], axis=-1)


def _rot_y(v, angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * v[..., 0] + s * v[..., 2], v[..., 1], -s * v[..., 0] + c * v[..., 2]], axis=-1)


def to_half_diff(wi, wo) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rusinkiewicz angles (θh, φh, θd, φd) of direction pairs; φh, φd in [0, 2π)."""
    wi = np.asarray(wi, dtype=np.float64)
    h = half_vector(wi, wo)
    theta_h, phi_h = vec_to_sph(h)
    d = _rot_y(_rot_z(wi, -phi_h), -theta_h)
    theta_d, phi_d = vec_to_sph(d)
    return theta_h, phi_h, theta_d, phi_d


def from_half_diff(theta_h, phi_h, theta_d, phi_d) -> tuple[np.ndarray, np.ndarray]:
    """(ωi, ωo) from Rusinkiewicz angles; the inverse of :func:`to_half_diff`."""
    d = sph_to_vec(theta_d, phi_d)
    theta_h, phi_h = np.broadcast_arrays(np.asarray(theta_h, float), np.asarray(phi_h, float))
    wi = _rot_z(_rot_y(d, theta_h), phi_h)
    h = sph_to_vec(theta_h, phi_h)
    wo = 2.0 * np.sum(wi * h, axis=-1, keepdims=True) * h - wi
    return wi, wo


def from_half_diff_grid(theta_h, theta_d, phi_d) -> tuple[np.ndarray, np.ndarray]:
    """(ωi, ωo) of every (θh, θd, φd) of a product grid, φh = 0: each of shape (H, D, P, 3) for 1-D
    ``theta_h`` (H,), ``theta_d`` (D,), ``phi_d`` (P,). The same numbers, bit for bit, as
    :func:`from_half_diff` of the grid's H·D·P points spelt out (the same operations on each), but the
    sines and cosines are taken once per grid line, not once per point: what MERL's table of
    1 458 000 bins needs (a MERL export, a merl grid)."""
    th, td, pd = (np.asarray(a, dtype=np.float64).reshape(-1) for a in (theta_h, theta_d, phi_d))
    st = np.sin(td)[:, None]                                  # sph_to_vec(θd, φd): (D, P)
    d0, d1 = st * np.cos(pd)[None, :], st * np.sin(pd)[None, :]
    d2 = np.broadcast_to(np.cos(td)[:, None], d0.shape)
    c, s = np.cos(th)[:, None, None], np.sin(th)[:, None, None]  # _rot_y(d, θh): (H, D, P)
    shape = (th.size, td.size, pd.size)
    y0, y1, y2 = c * d0 + s * d2, np.broadcast_to(d1, shape), -s * d0 + c * d2
    cz, sz = np.cos(0.0), np.sin(0.0)                         # _rot_z(·, φh = 0)
    wi = np.empty(shape + (3,))
    wi[..., 0], wi[..., 1], wi[..., 2] = cz * y0 - sz * y1, sz * y0 + cz * y1, y2
    sh = np.sin(th)                                           # sph_to_vec(θh, 0)
    h = np.stack([sh * np.cos(0.0), sh * np.sin(0.0), np.cos(th)], axis=-1)[:, None, None, :]
    wo = 2.0 * np.sum(wi * h, axis=-1, keepdims=True) * h - wi
    return wi, wo


#: rad: round-off allowed outside [0, π/2] for θh and θd (taken as the edge), beyond which merl_index refuses.
MERL_ANGLE_TOL = 1e-9


def merl_index(theta_h, theta_d, phi_d) -> np.ndarray:
    """Flat MERL table index ``iφd + 180·(iθd + 90·iθh)`` of (θh, θd, φd).

    θh bins follow the square-root mapping (dense near the specular peak); φd is folded into [0, π) by
    reciprocity (φd and φd + π describe the same pair with ωi and ωo swapped).

    Raises
    ------
    ValueError
        For NaN or infinite angles, and for θh or θd outside [0, π/2] by more than round-off
        (``MERL_ANGLE_TOL``): the table has no bin for them, and none is made up.
    """
    nh, nd, nphi = MERL_SHAPE
    theta_h = np.asarray(theta_h, dtype=np.float64)
    theta_d = np.asarray(theta_d, dtype=np.float64)
    phi_d = np.asarray(phi_d, dtype=np.float64)
    for name, value in (("theta_h", theta_h), ("theta_d", theta_d), ("phi_d", phi_d)):
        if not np.all(np.isfinite(value)):
            raise ValueError(f"merl_index: {name} holds NaN or inf; give finite radians")
    for name, value in (("theta_h", theta_h), ("theta_d", theta_d)):
        bad = (value < -MERL_ANGLE_TOL) | (value > HALF_PI + MERL_ANGLE_TOL)
        if np.any(bad):
            worst = float(value[bad].flat[0]) if value.ndim else float(value)
            raise ValueError(f"merl_index: {name} = {worst:.6g} rad is outside [0, π/2] (the MERL table "
                             "covers the upper hemisphere only)")
    phi_d = np.mod(phi_d, np.pi)
    # Round-off at the edges only: π/2 itself belongs to the last bin, −1e-17 to the first.
    ih = np.minimum(np.floor(np.sqrt(np.clip(theta_h, 0.0, HALF_PI) / HALF_PI) * nh), nh - 1)
    id_ = np.minimum(np.floor(np.clip(theta_d, 0.0, HALF_PI) / HALF_PI * nd), nd - 1)
    ip = np.minimum(np.floor(phi_d / np.pi * nphi), nphi - 1)
    return (ip + nphi * (id_ + nd * ih)).astype(np.int64)


def merl_unindex(index) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bin numbers (iθh, iθd, iφd) of flat MERL indices."""
    nh, nd, nphi = MERL_SHAPE
    index = np.asarray(index, dtype=np.int64)
    return index // (nphi * nd), (index // nphi) % nd, index % nphi


def merl_bin_centres(i_theta_h, i_theta_d, i_phi_d) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(θh, θd, φd) at the centres of MERL bins (the θh centre is taken in the square-root domain)."""
    nh, nd, nphi = MERL_SHAPE
    u = (np.asarray(i_theta_h, dtype=np.float64) + 0.5) / nh
    theta_h = u * u * HALF_PI
    theta_d = (np.asarray(i_theta_d, dtype=np.float64) + 0.5) / nd * HALF_PI
    phi_d = (np.asarray(i_phi_d, dtype=np.float64) + 0.5) / nphi * np.pi
    return theta_h, theta_d, phi_d


@lru_cache(maxsize=1)
def merl_centre_angles() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(θi, φi, θo, φo) of the centre of every MERL bin (φh = 0), radians, in the table's flat order: the
    :func:`vec_to_sph` of :func:`from_half_diff_grid` of :func:`merl_bin_centres` of every bin (what a MERL
    export evaluates). Computed once per process (1,458,000 pairs; 47 MB kept); the arrays are read-only.

    Computed a few θh rows at a time (the same operations on each element, so the same numbers bit for
    bit): the whole table's ωi and ωo and their temporaries (35 MB each) were pages the kernel zeroed
    afresh for every array, more system time than the arithmetic took."""
    theta_h, theta_d, phi_d = merl_bin_centres(*map(np.arange, MERL_SHAPE))
    nh, per_row = MERL_SHAPE[0], MERL_SHAPE[1] * MERL_SHAPE[2]
    angles = tuple(np.empty(nh * per_row) for _ in range(4))
    for lo in range(0, nh, _MERL_ROWS):
        hi = min(lo + _MERL_ROWS, nh)
        wi, wo = (w.reshape(-1, 3) for w in from_half_diff_grid(theta_h[lo:hi], theta_d, phi_d))
        for out, part in zip(angles, (*vec_to_sph(wi), *vec_to_sph(wo)), strict=True):
            out[lo * per_row:hi * per_row] = part
    for a in angles:
        a.flags.writeable = False
    return angles


#: θh rows of the MERL table per block of :func:`merl_centre_angles`: 97,200 pairs, a few MB per temporary.
_MERL_ROWS = 6


def _key_less(a, b):
    """Lexicographic a < b over tuples of equal-shape arrays, with angle tolerance."""
    less = np.zeros(np.broadcast(*a, *b).shape, dtype=bool)
    equal = np.ones_like(less)
    for x, y in zip(a, b, strict=True):
        less |= equal & (x < y - _ANGLE_EPS)
        equal &= np.abs(x - y) <= _ANGLE_EPS
    return less


def _collapse_pole(theta, phi):
    """φ in [0, 2π), with 0 at the pole and for φ within the tolerance below 2π (which *is* φ = 0)."""
    phi = wrap_2pi(phi)
    phi = np.where(phi >= TWO_PI - _ANGLE_EPS, 0.0, phi)
    return np.where(np.asarray(theta) <= _ANGLE_EPS, 0.0, phi)


def canonical_reciprocal(theta_i, phi_i, theta_o, phi_o):
    """Canonical representative of {(ωi, ωo), (ωo, ωi)} under Helmholtz reciprocity.

    Keeps the ordering whose (θi, φi) is lexicographically smallest; φ is folded into [0, 2π) and set
    to 0 at the pole. Returns (θi, φi, θo, φo, swapped).
    """
    ti, to = np.asarray(theta_i, float), np.asarray(theta_o, float)
    pi_, po = _collapse_pole(ti, phi_i), _collapse_pole(to, phi_o)
    swap = _key_less((to, po), (ti, pi_))
    return (np.where(swap, to, ti), np.where(swap, po, pi_), np.where(swap, ti, to),
            np.where(swap, pi_, po), swap)


def to_isotropic(theta_i, phi_i, theta_o, phi_o):
    """(θi, θo, Δφ = φo − φi) with Δφ in [0, 2π); Δφ = 0 where either direction is at the pole."""
    ti, to = np.asarray(theta_i, float), np.asarray(theta_o, float)
    dphi = wrap_2pi(np.asarray(phi_o, float) - np.asarray(phi_i, float))
    pole = (ti <= _ANGLE_EPS) | (to <= _ANGLE_EPS)
    return ti, to, np.where(pole, 0.0, dphi)


def canonical_isotropic(theta_i, theta_o, dphi, reciprocity: bool = True, mirror: bool = False):
    """Canonical (θi, θo, Δφ) of an isotropic configuration.

    Reciprocity identifies (θi, θo, Δφ) with (θo, θi, −Δφ): θi <= θo is kept (and Δφ <= π when the
    two are equal). ``mirror`` identifies Δφ with −Δφ (a BRDF symmetric about the plane of incidence):
    Δφ in [0, π]. Δφ is 0 where either direction is at the pole.
    """
    ti, to = np.broadcast_arrays(np.asarray(theta_i, float), np.asarray(theta_o, float))
    d = wrap_2pi(dphi)
    d = np.where((ti <= _ANGLE_EPS) | (to <= _ANGLE_EPS), 0.0, d)
    neg = wrap_2pi(-d)
    if mirror:
        d = np.minimum(d, neg)
        neg = d
    if reciprocity:
        swap = ti > to + _ANGLE_EPS
        same = np.abs(ti - to) <= _ANGLE_EPS
        ti, to = np.where(swap, to, ti), np.where(swap, ti, to)
        d = np.where(swap, neg, np.where(same, np.minimum(d, neg), d))
    d = np.where(d >= TWO_PI - _ANGLE_EPS, 0.0, d)
    return ti, to, d
