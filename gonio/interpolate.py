"""Interpolation of sampled f_r in the domains of :mod:`gonio.brdf`: symmetry orbits, a multilinear
lattice and local linear regression over scattered samples.

The engines take coordinates of a domain (:func:`domain_coords`) and return, per query, the value, its
standard deviation, a :class:`Reason` code and whether the value is one sample as it is
(``eval(coords, workers=-1)``; ``workers`` is the thread count of the scattered engine's kd-tree search,
scipy's meaning, and :class:`gonio.brdf.MeasuredBRDF` passes 1 when it spreads chunks over threads itself).
What each engine does, and why, is described in :mod:`gonio.brdf`; this module is its machinery.
"""

from __future__ import annotations

import enum

import numpy as np

from gonio.geometry import TWO_PI, sph_to_vec, to_half_diff, to_isotropic

__all__ = ["Reason", "Lattice", "Scattered", "domain_coords"]

_HALF_PI = 0.5 * np.pi
# Lattice nodes hold at most this many cells; more and the data are treated as scattered.
_MAX_CELLS = 50_000_000
# A query within this fraction of a lattice spacing of a node is at the node (round trips of angles).
_SNAP_FRACTION = 1e-7


class Reason(enum.IntEnum):
    """Why a query has no value (``Evaluation.reason``)."""

    OK = 0
    #: A direction is not finite or has zero length.
    INVALID = 1
    #: θi or θo >= 90°.
    BELOW_HORIZON = 2
    #: Beyond the measured range (θ past the largest measured θ, or past the lattice).
    OUT_OF_RANGE = 3
    #: Inside the range, but the samples around the query are missing (a gap in the data).
    NO_DATA = 4


# -- domains ------------------------------------------------------------------------------------------
def domain_coords(kind: str, angles: np.ndarray, sym: dict) -> np.ndarray:
    """Coordinates (M, d) of (θi, φi, θo, φo) rows (radians) in a domain; azimuths in [0, period)."""
    ti, pi_, to, po = angles.T
    if kind == "iso":
        ti, to, dphi = to_isotropic(ti, pi_, to, po)
        return np.stack([ti, to, dphi], axis=1)
    if kind == "full":
        return np.stack([ti, np.where(ti > 0, np.mod(pi_, TWO_PI), 0.0), to,
                         np.where(to > 0, np.mod(po, TWO_PI), 0.0)], axis=1)
    th, _, td, pd = to_half_diff(sph_to_vec(ti, pi_), sph_to_vec(to, po))
    period = np.pi if sym["reciprocity"] else TWO_PI
    pd = np.mod(pd, period)
    return np.stack([np.sqrt(np.clip(th, 0.0, None) / _HALF_PI), td, np.where(pd >= period, 0.0, pd)], axis=1)


def _periods(kind: str, sym: dict) -> list:
    if kind == "iso":
        return [None, None, TWO_PI]
    if kind == "full":
        return [None, TWO_PI, None, TWO_PI]
    return [None, None, np.pi if sym["reciprocity"] else TWO_PI]


def _orbit(kind: str, coords: np.ndarray, sym: dict) -> tuple[np.ndarray, np.ndarray]:
    """Every member of each sample's symmetry class: (coords of the members, index of their sample)."""
    n = len(coords)
    members = [coords]
    if kind == "iso":
        ti, to, d = coords.T
        neg = np.mod(-d, TWO_PI)
        if sym["reciprocity"]:
            members.append(np.stack([to, ti, neg], axis=1))
        if sym["mirror"]:
            members.append(np.stack([ti, to, neg], axis=1))
        if sym["reciprocity"] and sym["mirror"]:
            members.append(np.stack([to, ti, d], axis=1))
    elif kind == "full" and sym["reciprocity"]:
        members.append(coords[:, [2, 3, 0, 1]])
    out = np.concatenate(members)
    for k, p in enumerate(_periods(kind, sym)):
        if p is not None:
            out[:, k] = np.mod(out[:, k], p)
            out[out[:, k] >= p - 1e-12, k] = 0.0
    return out, np.tile(np.arange(n), len(members))


# Per domain: (azimuth axis, the polar axes whose pole makes it irrelevant).
_POLE_AXES = {"iso": [(2, (0, 1))], "full": [(1, (0,)), (3, (2,))], "merl": []}


def _cluster(x: np.ndarray, tol: float) -> np.ndarray | None:
    """Sorted representative values of ``x`` (clusters no wider than ``tol``), or None if too many."""
    s = np.sort(x)
    if s.size == 0:
        return None
    starts = np.concatenate([[True], np.diff(s) > tol])
    if starts.sum() > 20_000:
        return None
    group = np.cumsum(starts) - 1
    return np.bincount(group, weights=s) / np.bincount(group)


class Lattice:
    """Multilinear interpolation on a tensor-product lattice (NaN where a node was not measured)."""

    def __init__(self, nodes, periods, edges, values, stddev):
        self.nodes, self.periods, self.edges = nodes, periods, edges
        self.shape = tuple(len(n) for n in nodes)
        values = values.reshape(-1, values.shape[-1])
        self.missing = np.isnan(values).any(axis=1)
        # What eval weighs, made finite once (np.nan_to_num: 0 for a node not measured, which ``missing``
        # marks) rather than at each of its 2^d corners a call
        self.values = np.nan_to_num(values)
        self.variance = np.nan_to_num((stddev ** 2).reshape(values.shape))
        self.strides = np.cumprod((1,) + self.shape[::-1])[:-1][::-1]

    @classmethod
    def build(cls, kind, coords, value, stddev, sym, tol):
        pts, owner = _orbit(kind, coords, sym)
        periods = _periods(kind, sym)
        pole = np.zeros(len(pts), dtype=bool)
        for _, polar in _POLE_AXES[kind]:
            for a in polar:
                pole |= pts[:, a] <= tol
        nodes = []
        for k in range(pts.shape[1]):
            azimuth_of = [pol for az, pol in _POLE_AXES[kind] if az == k]
            sel = np.ones(len(pts), dtype=bool)
            if azimuth_of:
                for a in azimuth_of[0]:
                    sel &= pts[:, a] > tol
                if not sel.any():
                    sel = np.ones(len(pts), dtype=bool)
            axis = _cluster(pts[sel, k], tol)
            if axis is None:
                return None
            if periods[k] is not None and axis.size > 1 and axis[-1] - axis[0] > periods[k] - tol:
                axis = axis[:-1]  # the last cluster is the first one across the period
            nodes.append(axis)
        if np.prod([len(a) for a in nodes], dtype=np.float64) > _MAX_CELLS:
            return None
        # Index of every member on each axis; members off the lattice mean the data are not a lattice.
        index = np.empty(pts.shape, dtype=np.int64)
        for k, axis in enumerate(nodes):
            x = pts[:, k]
            j = np.clip(np.searchsorted(axis, x), 0, len(axis) - 1)
            j_lo = np.clip(j - 1, 0, len(axis) - 1)
            j = np.where(np.abs(axis[j_lo] - x) < np.abs(axis[j] - x), j_lo, j)
            err = np.abs(axis[j] - x)
            if periods[k] is not None:
                wrap = np.abs(x - (axis[0] + periods[k])) <= tol
                j, err = np.where(wrap, 0, j), np.where(wrap, 0.0, err)
                index[:, k] = j
                if not np.all((err <= tol) | pole):
                    return None
            else:
                index[:, k] = j
                if not np.all(err <= tol):
                    return None
        # A pole sample stands for every azimuth of the direction at the pole.
        for az, polar in _POLE_AXES[kind]:
            at_pole = np.zeros(len(index), dtype=bool)
            for a in polar:
                at_pole |= nodes[a][index[:, a]] <= tol
            if at_pole.any():
                n_az = len(nodes[az])
                rep = np.repeat(np.flatnonzero(at_pole), n_az)
                extra = index[rep]
                extra[:, az] = np.tile(np.arange(n_az), int(at_pole.sum()))
                index = np.concatenate([index[~at_pole], extra])
                owner = np.concatenate([owner[~at_pole], owner[rep]])
        shape = tuple(len(a) for a in nodes)
        flat = np.ravel_multi_index(tuple(index.T), shape)
        # One sample counts once per node: distinct (node, sample) pairs, as one sorted int64 key (a sort
        # and a mask: np.unique takes 14x longer on 1e6 keys with NumPy 2.4).
        n_owner = int(owner.max()) + 1
        key = np.sort(flat * n_owner + owner)
        key = key[np.concatenate([[True], key[1:] != key[:-1]])]
        flat, owner = key // n_owner, key % n_owner
        size = int(np.prod(shape))
        count = np.bincount(flat, minlength=size).astype(np.float64)
        c = value.shape[1]

        def total(x):  # per node, channel by channel (bincount: 5x faster than np.add.at)
            return np.stack([np.bincount(flat, weights=x[:, j], minlength=size) for j in range(c)], axis=1)

        sums, var = total(value[owner]), total(stddev[owner] ** 2)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = sums / count[:, None]
            sd = np.sqrt(var) / count[:, None]
        mean[count == 0] = np.nan
        sd[count == 0] = np.nan
        spacing = [np.min(np.diff(a)) if len(a) > 1 else 0.0 for a in nodes]
        edges = [0.5 * s if kind == "merl" and p is None else tol
                 for s, p in zip(spacing, periods, strict=True)]
        return cls(nodes, periods, edges, mean.reshape(shape + (c,)), sd.reshape(shape + (c,)))

    def eval(self, coords, workers: int = -1):
        m, d = coords.shape
        lo = np.zeros((m, d), dtype=np.int64)
        hi = np.zeros((m, d), dtype=np.int64)
        t = np.zeros((m, d))
        out = np.zeros(m, dtype=bool)
        for k in range(d):
            axis, p, x = self.nodes[k], self.periods[k], coords[:, k]
            n = len(axis)
            if n == 1:
                if p is None:
                    out |= np.abs(x - axis[0]) > self.edges[k]
                continue
            if p is not None:
                ext = np.concatenate([[axis[-1] - p], axis, [axis[0] + p]])
                j = np.clip(np.searchsorted(ext, np.mod(x, p), side="right") - 1, 0, n)
                x0, x1 = ext[j], ext[j + 1]
                lo[:, k], hi[:, k] = np.mod(j - 1, n), np.mod(j, n)
                tk = (np.mod(x, p) - x0) / (x1 - x0)
            else:
                out |= (x < axis[0] - self.edges[k]) | (x > axis[-1] + self.edges[k])
                j = np.clip(np.searchsorted(axis, x, side="right") - 1, 0, n - 2)
                lo[:, k], hi[:, k] = j, j + 1
                tk = (x - axis[j]) / (axis[j + 1] - axis[j])
            tk = np.clip(tk, 0.0, 1.0)
            tk = np.where(tk < _SNAP_FRACTION, 0.0, np.where(tk > 1 - _SNAP_FRACTION, 1.0, tk))
            t[:, k] = tk
        c = self.values.shape[1]
        value = np.zeros((m, c))
        var = np.zeros((m, c))
        gap = np.zeros(m, dtype=bool)
        used = np.zeros(m, dtype=np.int64)
        for corner in range(1 << d):
            bits = [(corner >> k) & 1 for k in range(d)]
            w = np.ones(m)
            flat = np.zeros(m, dtype=np.int64)
            for k, b in enumerate(bits):
                w = w * (t[:, k] if b else 1.0 - t[:, k])
                flat += (hi[:, k] if b else lo[:, k]) * self.strides[k]
            live = w > 0
            if not live.any():
                continue
            used += live
            gap |= live & self.missing[flat]
            wv = np.where(live, w, 0.0)[:, None]
            value += wv * self.values[flat]
            var += wv * wv * self.variance[flat]
        reason = np.where(out, Reason.OUT_OF_RANGE, np.where(gap, Reason.NO_DATA, Reason.OK)).astype(np.uint8)
        return value, np.sqrt(var), reason, (used == 1) & (reason == Reason.OK)


class Scattered:
    """Local linear regression over the k nearest samples in a pole-free embedding.

    The fit is solved in closed form around the weighted centroid of the neighbours: with weights w,
    offsets X (neighbour − query, in units of the support radius h), W = Σw, centroid μ = ΣwX/W and
    centred moments C = Σw(X − μ)(X − μ)ᵀ + λI, the fitted value at the query is Σ a_k f_k with
    a_k = w_k (1/W − (X_k − μ)ᵀ C⁻¹ μ): the intercept of the weighted least-squares plane (λ, a relative
    1e-6, keeps degenerate neighbourhoods solvable). In 3D (isotropic data) C⁻¹μ is the adjugate
    formula; no per-query LAPACK call.
    """

    def __init__(self, kind, coords, value, stddev, sym, tol):
        from scipy.spatial import cKDTree

        pts, owner = _orbit(kind, coords, sym)
        self.kind = kind
        points = self._embed(pts)
        # The samples are stored in a kd-tree's own leaf order, so that the points of a leaf are neighbours
        # in memory: in the order the data came in (random, for a real gantry's scatter) every leaf visited
        # is a cache miss. The neighbour searches get 1.3x (queries in grid order) to 2.6x (each sample's
        # reach, below) faster for the price of a second tree build (~0.1 s per 2e5 samples).
        order = cKDTree(points).indices
        self.points = np.ascontiguousarray(points[order])
        owner = owner[order]
        self.values = value[owner]
        self.variance = stddev[owner] ** 2
        # Per-coordinate and per-channel copies: gathering (m, k) blocks from 1-D arrays is several times
        # faster than gathering (m, k, d) rows, and each product below stays a flat (m, k) array.
        self._coord = np.ascontiguousarray(self.points.T)
        self._value_t = np.ascontiguousarray(self.values.T)
        self._variance_t = np.ascontiguousarray(self.variance.T)
        self.tree = cKDTree(self.points)
        # 3(d + 1) − 2 neighbours: 2.5 per fitted parameter in 3D, enough for a stable plane, and fewer
        # than the 4(d + 1) − 2 first used (the neighbour search dominates the cost).
        self.k = min(len(self.points), 3 * (self.points.shape[1] + 1) - 2)
        # Local support radius of each sample: the distance to its k-th neighbour (the data's own scale
        # there), so that dense and sparse regions are both judged by their spacing.
        reach = self.tree.query(self.points, k=min(self.k + 1, len(self.points)), workers=-1)[0]
        self.reach = np.asarray(reach).reshape(len(self.points), -1)[:, -1]
        self.snap = tol

    def _embed(self, c):
        if self.kind == "iso":
            return np.stack([c[:, 0], c[:, 1] * np.cos(c[:, 2]), c[:, 1] * np.sin(c[:, 2])], axis=1)
        return np.stack([c[:, 0] * np.cos(c[:, 1]), c[:, 0] * np.sin(c[:, 1]),
                         c[:, 2] * np.cos(c[:, 3]), c[:, 2] * np.sin(c[:, 3])], axis=1)

    def eval(self, coords, workers: int = -1):
        q = self._embed(coords)
        m, d = q.shape
        if m == 0:
            c = self.values.shape[1]
            return np.zeros((0, c)), np.zeros((0, c)), np.zeros(0, np.uint8), np.zeros(0, bool)
        # Queries answered in a spatial order (cells of a 32^3 grid): neighbouring queries then visit the
        # same leaves while they are in cache (random queries: 1.8x faster searches; queries already in
        # grid order lose ~5 %). Results go back to the callers' order at the end.
        span = np.ptp(q, axis=0) + 1e-300
        cell = np.minimum(((q - q.min(axis=0)) / span * 32).astype(np.int64), 31)
        order = np.lexsort(cell.T[::-1])
        q = q[order]
        dist, idx = self.tree.query(q, k=self.k, workers=workers)
        dist, idx = dist.reshape(m, -1), idx.reshape(m, -1)
        inv_h = 1.0 / (dist[:, -1:] * 1.05 + 1e-12)
        w = 1.0 - (dist * inv_h) ** 2
        w *= w
        # offsets in units of h, one (m, k) array per coordinate
        x = [(self._coord[i][idx] - q[:, i:i + 1]) * inv_h for i in range(d)]
        wx = [w * xi for xi in x]
        total = w.sum(axis=1)
        mu = np.stack([wxi.sum(axis=1) for wxi in wx], axis=1) / total[:, None]
        cov = np.empty((m, d, d))
        for i in range(d):
            for j in range(i, d):
                cov[:, i, j] = cov[:, j, i] = np.einsum("mk,mk->m", wx[i], x[j])
        ridge = 1e-6 * (total + np.trace(cov, axis1=1, axis2=2))
        cov -= total[:, None, None] * mu[:, :, None] * mu[:, None, :]
        cov[:, np.arange(d), np.arange(d)] += ridge[:, None]
        z = _solve_spd(cov, mu)
        lever = -np.einsum("md,md->m", mu, z)[:, None]
        for i in range(d):
            lever = lever + x[i] * z[:, i:i + 1]
        hat = w * ((1.0 / total)[:, None] - lever)
        exact = dist[:, 0] <= self.snap
        if exact.any():
            hat[exact] = 0.0
            hat[exact, 0] = 1.0
        hat2 = hat * hat
        value = np.stack([np.einsum("mk,mk->m", hat, v[idx]) for v in self._value_t], axis=1)
        var = np.stack([np.einsum("mk,mk->m", hat2, v[idx]) for v in self._variance_t], axis=1)
        reason = np.where(dist[:, 0] > self.reach[idx[:, 0]], Reason.NO_DATA, Reason.OK).astype(np.uint8)
        back = np.empty_like(order)
        back[order] = np.arange(m)
        return value[back], np.sqrt(var)[back], reason[back], (exact & (reason == Reason.OK))[back]


def _solve_spd(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x with a x = b for stacks of small symmetric positive-definite systems, a (m, d, d), b (m, d);
    closed form (adjugate over determinant) for d = 3."""
    if a.shape[1] != 3:
        return np.linalg.solve(a, b[:, :, None])[:, :, 0]
    p, q, r = a[:, 0, 0], a[:, 0, 1], a[:, 0, 2]
    s, t, u = a[:, 1, 1], a[:, 1, 2], a[:, 2, 2]
    c00, c01, c02 = s * u - t * t, r * t - q * u, q * t - r * s
    c11, c12, c22 = p * u - r * r, q * r - p * t, p * s - q * q
    det = p * c00 + q * c01 + r * c02
    x0 = c00 * b[:, 0] + c01 * b[:, 1] + c02 * b[:, 2]
    x1 = c01 * b[:, 0] + c11 * b[:, 1] + c12 * b[:, 2]
    x2 = c02 * b[:, 0] + c12 * b[:, 1] + c22 * b[:, 2]
    return np.stack([x0, x1, x2], axis=1) / det[:, None]
