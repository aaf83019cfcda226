"""GGX (Trowbridge-Reitz) microfacet reflection as renderers use it (Mitsuba 3's ``roughconductor``).

    f = ρd/π + ρs · F(I·H) · D(H) · G(I, V, H) / (4 (N·I)(N·V))

- D: GGX, anisotropic with roughness ``alpha_u`` along the sample's x axis and ``alpha_v`` along y
  (``alpha`` for both), as Mitsuba's ``MicrofacetDistribution::eval``.
- G: Smith masking-shadowing of GGX. ``smith=separable`` (default) is the product G1(I)·G1(V), which
  is what Mitsuba 3's ``MicrofacetDistribution::G`` (and so ``roughconductor``) uses;
  ``smith=correlated`` is the height-correlated form 1/(1 + Λ(I) + Λ(V)) (Heitz 2014). G1 is 0 where a
  direction sees the back of the facet.
- F at the microfacet angle: for conductors the *exact* unpolarized reflectance with complex index
  η + ik, the formula of Mitsuba's ``fresnel_conductor`` (not the lecture notes' approximation, which
  Cook-Torrance uses); ``fresnel=dielectric`` and ``fresnel=none`` as in Cook-Torrance.

Energy: F <= 1 and Smith masking lose energy (no multiple scattering), so the albedo is <= ρs; the
model is energy conserving with ρd + ρs <= 1 (checked). Reciprocal; isotropic when αu = αv.

Spec: ``ggx:alpha=0.2,metal=gold``, ``ggx:alpha_u=0.1,alpha_v=0.3,fresnel=conductor,eta=0.2/0.9/1.1,
k=3.9/2.4/2.2,smith=correlated``. Keys: ``alpha`` or ``alpha_u`` and ``alpha_v`` (> 0, required),
``metal``/``fresnel``/``eta``/``k`` (as Cook-Torrance), ``smith`` (separable | correlated),
``rho_d`` ([0, 1], default 0), ``rho_s`` ([0, 1], default 1).

References
----------
B. Walter et al., "Microfacet Models for Refraction through Rough Surfaces", EGSR 2007.
E. Heitz, "Understanding the Masking-Shadowing Function in Microfacet-Based BRDFs", JCGT 3(2), 2014.
W. Jakob et al., Mitsuba 3: ``src/bsdfs/roughconductor.cpp``, ``include/mitsuba/render/microfacet.h``.
"""

from __future__ import annotations

import drjit as dr

from . import microfacet as mf
from .base import INV_PI, Material
from .fresnel import fresnel_term, read_fresnel
from .spec import Params

__all__ = ["GGX"]

SMITH_FORMS = ("separable", "correlated")


class GGX(Material):
    """GGX with Smith masking and exact conductor Fresnel (see the module docstring)."""

    model = "ggx"
    reciprocal = True
    energy_conserving = True
    KEYS = ("alpha", "alpha_u", "alpha_v", "fresnel", "metal", "eta", "k", "smith", "rho_d", "rho_s")
    EXAMPLES = ("ggx:alpha=0.2,metal=gold", "ggx:alpha=0.15,metal=copper,rho_d=0.2,rho_s=0.8",
                "ggx:alpha_u=0.1,alpha_v=0.3,fresnel=conductor,eta=0.2,k=3",
                "ggx:alpha=0.2,fresnel=dielectric,eta=1.5,smith=correlated", "ggx:alpha=0.2,fresnel=none")

    def __init__(self, spec: str, alpha_u: float, alpha_v: float, fresnel: str, fresnel_params: dict,
                 smith: str, rho_d, rho_s):
        super().__init__(spec, isotropic=alpha_u == alpha_v)
        self.alpha_u, self.alpha_v = alpha_u, alpha_v
        self.fresnel, self.fresnel_params = fresnel, fresnel_params
        self.smith, self.rho_d, self.rho_s = smith, rho_d, rho_s

    @classmethod
    def parse(cls, text: str) -> GGX:
        """Build from the part of the spec after ``ggx:``."""
        p = Params(cls.model, text, cls.KEYS)
        alpha_u, alpha_v = p.roughness("alpha", ("alpha_u", "alpha_v"))
        fresnel, fresnel_params = read_fresnel(p)
        smith = p.choice("smith", SMITH_FORMS, "separable")
        rho_d = p.colour("rho_d", 0.0)
        rho_s = p.colour("rho_s", 1.0)
        p.at_most_one({"rho_d": rho_d, "rho_s": rho_s}, "energy conservation")
        return cls(p.finish(), alpha_u, alpha_v, fresnel, fresnel_params, smith, rho_d, rho_s)

    def _parameters(self) -> dict:
        params = dict(self.fresnel_params)
        params.update(alpha_u=self.alpha_u, alpha_v=self.alpha_v, rho_d=self.rho_d,
                      rho_s_quarter=tuple(0.25 * r for r in self.rho_s))
        return params

    def values(self) -> dict:
        out = dict(self.fresnel_params)
        out.update(alpha_u=self.alpha_u, alpha_v=self.alpha_v, rho_d=self.rho_d, rho_s=self.rho_s)
        return out

    def _parameters_dr(self, v):
        p = {k: v[k] for k in self.fresnel_params}
        p.update(alpha_u=v["alpha_u"], alpha_v=v["alpha_v"], rho_d=v["rho_d"],
                 rho_s_quarter=0.25 * v["rho_s"])
        return p

    def _eval_dr(self, wi, wo, p):
        au, av = p["alpha_u"], p["alpha_v"]
        h = dr.normalize(wi + wo)
        if self.smith == "separable":
            g = mf.smith_ggx_g1(wi, h, au, av) * mf.smith_ggx_g1(wo, h, au, av)
        else:
            g = 1 / (1 + mf.smith_ggx_lambda(wi, au, av) + mf.smith_ggx_lambda(wo, au, av))
            g = dr.select((dr.dot(wi, h) > 0) & (dr.dot(wo, h) > 0), g, 0)
        f = fresnel_term(self.fresnel, dr.dot(wi, h), p, wi, exact_conductor=True)
        glossy = f * (mf.ggx(h, au, av) * g / (wi.z * wo.z))
        value = p["rho_d"] * INV_PI + p["rho_s_quarter"] * glossy
        return dr.select((wi.z > 0) & (wo.z > 0), value, 0)
