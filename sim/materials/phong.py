"""Cosine-power lobes: Phong and Blinn-Phong, as the lecture notes write them and energy-normalized.

With N = +z, I = ωi, V = ωo, R(I) = −I + 2(I·N)N and H = (I + V)/|I + V|:

========================== =============================================== ========== ============
model                      glossy term (added to ρd/π)                     reciprocal energy
========================== =============================================== ========== ============
``phong``                  ks (R(I)·V)^ke / (I·N)        (the notes)        no         no
``modified-phong``         ks (ke + 2)/(2π) (R(I)·V)^ke  (Lafortune)       yes        yes
``blinn-phong``            ks (H·N)^ke / (I·N)           (the notes)        no         no
``normalized-blinn-phong`` ks C(ke) (H·N)^ke                               yes        yes
========================== =============================================== ========== ============

The lobe is 0 where its cosine is negative (the notes warn that it would otherwise reach into the
material). The 1/(I·N) of the notes' forms makes them non-reciprocal, f(I, V)/f(V, I) = (V·N)/(I·N),
and lets the albedo grow without bound toward grazing incidence.

C(ke) of the normalized Blinn-Phong is exact, not the popular (ke + 8)/(8π): it makes the lobe's
directional albedo at normal incidence exactly ks,

    C(ke) = 1 / (8π [2 (1 − 2^(−(ke+4)/2)) / (ke + 4) − (1 − 2^(−(ke+2)/2)) / (ke + 2)]),

the reciprocal of ∫ (H·N)^ke cos θo dωo at θi = 0, where θh = θo/2 (C(0) = 1/π; C(ke) ≈ (ke + 6)/(8π)
for large ke). The albedo decreases from there toward grazing incidence (the tests check 0°…85°). The
(ke + 8)/(8π) form reflects up to 7.5 % more than arrives at normal incidence (at ke ≈ 10).
The modified Phong's (ke + 2)/(2π) is likewise exact at normal incidence, where R(I) = N.

Spec keys: ``ks`` (required, [0, 1], R/G/B), ``ke`` (required, >= 0), ``rho_d`` (diffuse albedo,
[0, 1], R/G/B, default 0). The energy-conserving forms also require rho_d + ks <= 1 per channel.

References
----------
B. T. Phong, "Illumination for Computer Generated Pictures", CACM 18(6), 1975.
J. F. Blinn, "Models of Light Reflection for Computer Synthesized Pictures", SIGGRAPH 1977.
E. Lafortune, Y. Willems, "Using the Modified Phong Reflectance Model for Physically Based
Rendering", KU Leuven report CW197, 1994.
"""

from __future__ import annotations

import math

import drjit as dr

from .base import INV_PI, Material, positive_power
from .spec import Params

__all__ = ["Phong", "ModifiedPhong", "BlinnPhong", "NormalizedBlinnPhong", "blinn_phong_norm"]


def blinn_phong_norm(ke: float) -> float:
    """C(ke): the (H·N)^ke lobe times C(ke) has directional albedo 1 at normal incidence."""
    a = 2.0 * (1.0 - 2.0 ** (-(ke + 4.0) / 2.0)) / (ke + 4.0)
    b = (1.0 - 2.0 ** (-(ke + 2.0) / 2.0)) / (ke + 2.0)
    return 1.0 / (8.0 * math.pi * (a - b))


class _CosineLobe(Material):
    """ρd/π + ks · norm · cos^ke(θ_lobe) [/ (I·N) for the notes' forms]."""

    KEYS = ("ks", "ke", "rho_d")
    #: True: the lobe is around H (cos = H·N); False: around R(I) (cos = R(I)·V).
    uses_half_vector = False

    def __init__(self, spec: str, ks, ke: float, rho_d):
        super().__init__(spec)
        self.ks, self.ke, self.rho_d = ks, ke, rho_d

    @classmethod
    def parse(cls, text: str) -> _CosineLobe:
        """Build from the part of the spec after ``name:``."""
        p = Params(cls.model, text, cls.KEYS)
        ks = p.colour("ks")
        ke = p.number("ke", lo=0.0)
        rho_d = p.colour("rho_d", 0.0)
        if cls.energy_conserving:
            p.at_most_one({"rho_d": rho_d, "ks": ks}, "energy conservation")
        return cls(p.finish(), ks, ke, rho_d)

    def norm(self) -> float:
        """Normalization of the lobe (1 for the notes' forms)."""
        return 1.0

    def norm_dr(self, ke):
        """:meth:`norm` for a Dr.Jit ``ke`` (differentiable)."""
        return 1.0

    def _parameters(self) -> dict:
        return {"ks_norm": tuple(k * self.norm() for k in self.ks), "ke": self.ke, "rho_d": self.rho_d}

    def values(self) -> dict:
        return {"ks": self.ks, "ke": self.ke, "rho_d": self.rho_d}

    def _parameters_dr(self, v):
        return {"ks_norm": v["ks"] * self.norm_dr(v["ke"]), "ke": v["ke"], "rho_d": v["rho_d"]}

    def _eval_dr(self, wi, wo, p):
        if self.uses_half_vector:
            cos_lobe = dr.normalize(wi + wo).z
        else:
            cos_lobe = wi.z * wo.z - wi.x * wo.x - wi.y * wo.y  # R(I)·V
        lobe = positive_power(cos_lobe, p["ke"])
        if not self.energy_conserving:
            lobe = lobe / wi.z
        f = p["rho_d"] * INV_PI + p["ks_norm"] * lobe
        return dr.select((wi.z > 0) & (wo.z > 0), f, 0)


class Phong(_CosineLobe):
    """The notes' Phong lobe f = ρd/π + ks (R(I)·V)^ke / (I·N): neither reciprocal nor energy
    conserving. Spec ``phong:ks=0.5,ke=20[,rho_d=0.1]``."""

    model = "phong"
    EXAMPLES = ("phong:ks=0.5,ke=20",)
    reciprocal = False
    energy_conserving = False


class ModifiedPhong(_CosineLobe):
    """Energy-normalized, reciprocal Phong f = ρd/π + ks (ke+2)/(2π) (R(I)·V)^ke.
    Spec ``modified-phong:ks=0.5,ke=20[,rho_d=0.1]`` with rho_d + ks <= 1."""

    model = "modified-phong"
    EXAMPLES = ("modified-phong:ks=0.5,ke=20,rho_d=0.3",)
    reciprocal = True
    energy_conserving = True

    def norm(self) -> float:
        return (self.ke + 2.0) / (2.0 * math.pi)

    def norm_dr(self, ke):
        return (ke + 2.0) / (2.0 * math.pi)


class BlinnPhong(_CosineLobe):
    """The notes' Blinn-Phong lobe f = ρd/π + ks (H·N)^ke / (I·N): neither reciprocal nor energy
    conserving. Spec ``blinn-phong:ks=0.5,ke=20[,rho_d=0.1]``."""

    model = "blinn-phong"
    EXAMPLES = ("blinn-phong:ks=0.5,ke=20",)
    reciprocal = False
    energy_conserving = False
    uses_half_vector = True


class NormalizedBlinnPhong(_CosineLobe):
    """Energy-normalized, reciprocal Blinn-Phong f = ρd/π + ks C(ke) (H·N)^ke (C: module docstring).
    Spec ``normalized-blinn-phong:ks=0.5,ke=20[,rho_d=0.1]`` with rho_d + ks <= 1."""

    model = "normalized-blinn-phong"
    EXAMPLES = ("normalized-blinn-phong:ks=0.5,ke=20",)
    reciprocal = True
    energy_conserving = True
    uses_half_vector = True

    def norm(self) -> float:
        return blinn_phong_norm(self.ke)

    def norm_dr(self, ke):
        ln2 = math.log(2.0)
        a = 2.0 * (1.0 - dr.exp(-0.5 * ln2 * (ke + 4.0))) / (ke + 4.0)
        b = (1.0 - dr.exp(-0.5 * ln2 * (ke + 2.0))) / (ke + 2.0)
        return 1.0 / (8.0 * math.pi * (a - b))
