"""The samples a round is planned from.

An isotropic pose is (θi, θo, Δφ = φo − φi), measured with φi = 0. Helmholtz reciprocity makes
(θi, θo, Δφ) and (θo, θi, −Δφ) the same pose of the BRDF. An anisotropic sample also has its φi
(``phi_i``; φo = φi + Δφ), and its twin is (θo, φo, θi, φi).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gonio.adaptive.domain import embed_poses

__all__ = ["Samples", "pair_weight"]

_TWO_PI = 2.0 * np.pi


@dataclass(frozen=True)
class Samples:
    """Measured isotropic samples (radians; f_r in sr⁻¹, no cosine factor).

    Attributes
    ----------
    theta_i, theta_o, dphi : ndarray, shape (N,)
        The poses, Δφ in [0, 2π).
    value : ndarray, shape (N, C)
        f_r per channel.
    phi_i : ndarray, shape (N,)
        φi of each pose (zeros when not given: the isotropic domains ignore it, ``pair`` reads it).
    """

    theta_i: np.ndarray
    theta_o: np.ndarray
    dphi: np.ndarray
    value: np.ndarray
    phi_i: np.ndarray | None = None

    def __post_init__(self):
        if self.phi_i is None:
            object.__setattr__(self, "phi_i", np.zeros(np.size(self.theta_i)))
        for name in ("theta_i", "theta_o", "dphi", "phi_i"):
            array = np.ascontiguousarray(getattr(self, name), dtype=np.float64).ravel()
            object.__setattr__(self, name, array)
        value = np.asarray(self.value, dtype=np.float64)
        object.__setattr__(self, "value", value.reshape(self.theta_i.size, -1))
        if not self.theta_i.size == self.theta_o.size == self.dphi.size == self.phi_i.size:
            raise ValueError("samples: theta_i, theta_o, dphi and phi_i must have the same length")

    def __len__(self) -> int:
        return int(self.theta_i.size)

    @property
    def poses(self) -> np.ndarray:
        """(N, 3) rows of (θi, θo, Δφ)."""
        return np.stack([self.theta_i, self.theta_o, self.dphi], axis=1)

    def points(self, domain: str) -> tuple[np.ndarray, np.ndarray]:
        """Embedded points of the samples in ``domain`` (:mod:`gonio.adaptive.domain`) and the sample of
        each: in ``iso`` each sample and its reciprocal twin (2N points), in ``half`` (invariant under
        reciprocity) each sample once, in ``pair`` each sample (θi, φi, θo, φo) and its twin
        (θo, φo, θi, φi)."""
        n = len(self)
        if domain == "pair":
            po = self.phi_i + self.dphi
            ti = np.concatenate([self.theta_i, self.theta_o])
            to = np.concatenate([self.theta_o, self.theta_i])
            pi_ = np.concatenate([self.phi_i, po])
            d = np.concatenate([self.dphi, -self.dphi])
            return embed_poses(domain, ti, to, d, pi_), np.tile(np.arange(n), 2)
        if domain == "half":
            return embed_poses(domain, self.theta_i, self.theta_o, self.dphi), np.arange(n)
        ti = np.concatenate([self.theta_i, self.theta_o])
        to = np.concatenate([self.theta_o, self.theta_i])
        d = np.concatenate([self.dphi, np.where(self.theta_i > 0, np.mod(-self.dphi, _TWO_PI), 0.0)])
        return embed_poses(domain, ti, to, d), np.tile(np.arange(n), 2)

    def extended(self, theta_i, theta_o, dphi, value, phi_i=None) -> Samples:
        """These samples followed by new ones (``phi_i``: theirs, zeros when not given)."""
        new_phi = np.zeros(np.size(theta_i)) if phi_i is None else np.ravel(phi_i)
        return Samples(np.concatenate([self.theta_i, np.ravel(theta_i)]),
                       np.concatenate([self.theta_o, np.ravel(theta_o)]),
                       np.concatenate([self.dphi, np.ravel(dphi)]),
                       np.concatenate([self.value, np.asarray(value, dtype=np.float64).reshape(
                           -1, self.value.shape[1])]),
                       np.concatenate([self.phi_i, new_phi]))


def pair_weight(theta_i, theta_o) -> np.ndarray:
    """How much a pose counts in the benchmark's error (:mod:`gonio.adaptive.error`): directions drawn
    uniformly on the hemisphere have density sin θ per unit θ, and the error weights f_r by cos θi cos θo."""
    return np.sin(theta_i) * np.cos(theta_i) * np.sin(theta_o) * np.cos(theta_o)
