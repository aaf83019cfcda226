"""Lambert: the ideal diffuse reflector, f = ρd/π."""

from __future__ import annotations

import drjit as dr

from .base import INV_PI, Material
from .spec import Params

__all__ = ["Lambert"]


class Lambert(Material):
    """f_r = ρd / π in sr⁻¹, the same for every pair of directions above the horizon.

    Spec: ``lambert:albedo=RHO`` with ρd (``albedo``, required) in [0, 1], one value or R/G/B.
    Its directional albedo is ρd at every angle of incidence.
    """

    model = "lambert"
    reciprocal = True
    energy_conserving = True
    KEYS = ("albedo",)
    EXAMPLES = ("lambert:albedo=0.8", "lambert:albedo=0.8/0.6/0.4")

    def __init__(self, spec: str, albedo):
        super().__init__(spec)
        self.albedo = albedo

    @classmethod
    def parse(cls, text: str) -> Lambert:
        """Build from the part of the spec after ``lambert:``."""
        p = Params(cls.model, text, cls.KEYS)
        albedo = p.colour("albedo")
        return cls(p.finish(), albedo)

    def _parameters(self) -> dict:
        return {"albedo": self.albedo}

    def values(self) -> dict:
        return {"albedo": self.albedo}

    def _parameters_dr(self, v):
        return {"albedo": v["albedo"]}

    def _eval_dr(self, wi, wo, p):
        return dr.select((wi.z > 0) & (wo.z > 0), p["albedo"] * INV_PI, 0)
