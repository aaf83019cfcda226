"""Ward's (1992) model, isotropic and anisotropic, as the lecture notes write it.

    f = ρd/π + ρs / sqrt((I·N)(V·N)) · exp(−tan²θh (cos²φh/σx² + sin²φh/σy²)) / (4π σx σy)

with (θh, φh) the angles of H = (I + V)/|I + V| in the sample frame; σx along the sample's x axis (the
reference direction), σy along y. The isotropic model is σx = σy = σ. In components,
tan²θh cos²φh = (Hx/Hz)² and tan²θh sin²φh = (Hy/Hz)².

It is reciprocal but not energy conserving: the 1/sqrt((I·N)(V·N)) factor makes the albedo exceed ρs
toward grazing incidence (and the Gaussian in tan θh is normalized only for small σ).

Spec: ``ward:rho_s=0.05,alpha=0.1[,rho_d=0.1]`` or ``ward:rho_s=0.05,alpha_x=0.1,alpha_y=0.3``.
Keys: ``rho_s`` (required, [0, 1], R/G/B), ``rho_d`` ([0, 1], R/G/B, default 0), and either
``alpha`` (σ, > 0) or both ``alpha_x`` and ``alpha_y`` (σx, σy, > 0; RMS surface slopes).

References
----------
G. J. Ward, "Measuring and Modeling Anisotropic Reflection", SIGGRAPH 1992.
"""

from __future__ import annotations

import math

import drjit as dr

from .base import INV_PI, Material
from .spec import Params

__all__ = ["Ward"]


class Ward(Material):
    """Ward's isotropic or anisotropic model (see the module docstring)."""

    model = "ward"
    reciprocal = True
    energy_conserving = False
    KEYS = ("rho_d", "rho_s", "alpha", "alpha_x", "alpha_y")
    EXAMPLES = ("ward:rho_d=0.1,rho_s=0.05,alpha=0.1", "ward:rho_d=0.1,rho_s=0.05,alpha_x=0.1,alpha_y=0.3")

    def __init__(self, spec: str, rho_d, rho_s, alpha_x: float, alpha_y: float):
        super().__init__(spec, isotropic=alpha_x == alpha_y)
        self.rho_d, self.rho_s, self.alpha_x, self.alpha_y = rho_d, rho_s, alpha_x, alpha_y

    @classmethod
    def parse(cls, text: str) -> Ward:
        """Build from the part of the spec after ``ward:``."""
        p = Params(cls.model, text, cls.KEYS)
        rho_d = p.colour("rho_d", 0.0)
        rho_s = p.colour("rho_s")
        alpha_x, alpha_y = p.roughness("alpha", ("alpha_x", "alpha_y"))
        return cls(p.finish(), rho_d, rho_s, alpha_x, alpha_y)

    def _parameters(self) -> dict:
        ax, ay = self.alpha_x, self.alpha_y
        return {"rho_d": self.rho_d, "inv_ax": 1.0 / ax, "inv_ay": 1.0 / ay,
                "rho_s_norm": tuple(r / (4.0 * math.pi * ax * ay) for r in self.rho_s)}

    def values(self) -> dict:
        return {"rho_d": self.rho_d, "rho_s": self.rho_s, "alpha_x": self.alpha_x, "alpha_y": self.alpha_y}

    def _parameters_dr(self, v):
        ax, ay = v["alpha_x"], v["alpha_y"]
        return {"rho_d": v["rho_d"], "inv_ax": 1.0 / ax, "inv_ay": 1.0 / ay,
                "rho_s_norm": v["rho_s"] / (4.0 * math.pi * ax * ay)}

    def _eval_dr(self, wi, wo, p):
        h = wi + wo  # the exponent is a ratio of components, so H need not be normalized
        exponent = (dr.square(h.x * p["inv_ax"]) + dr.square(h.y * p["inv_ay"])) / (h.z * h.z)
        glossy = dr.exp(-exponent) * dr.rsqrt(wi.z * wo.z)
        f = p["rho_d"] * INV_PI + p["rho_s_norm"] * glossy
        return dr.select((wi.z > 0) & (wo.z > 0), f, 0)
