"""Cook-Torrance as in the lecture notes: a microfacet lobe with V-groove masking over a diffuse base.

    f = ρd/π + ρs · F(V·H) · D(H) · G / (π (N·V)(N·I))           (denom=pi, the notes; default)
    f = ρd/π + ρs · F(V·H) · D(H) · G / (4 (N·V)(N·I))           (denom=4, the modern form)

- D: ``d=beckmann`` (RMS slope m > 0), ``d=blinn`` (D halves at α = m, 0 < m < π/2 rad) or
  ``d=gaussian`` (exp(−(α/m)²), m > 0 rad); all normalized over projected microfacet area,
  ∫ D(h)(h·N) dω_h = 1 (see :mod:`.microfacet`).
- G = min{1, 2(N·H)(N·V)/(V·H), 2(N·H)(N·I)/(V·H)} (V-grooves).
- F: the notes' unpolarized Fresnel at the microfacet angle cos θ = V·H: their conductor formula
  (``metal=gold|silver|copper|aluminium|steel``, per-channel η, k from spectral tables, or
  ``fresnel=conductor,eta=…,k=…``), their dielectric formula
  with Snell's law and total internal reflection (``fresnel=dielectric,eta=…``), or F = 1
  (``fresnel=none``); see :mod:`.fresnel`.
- ρd (``rho_d``, default 0) and ρs (``rho_s``, default 1) are the notes' diffuse and glossy weights
  (f = κd ρd + κg ρg), in [0, 1], R/G/B.

The form with π is what the notes (and Cook & Torrance 1982) print; it reflects 4/π times the modern
form and so more than arrives wherever the modern form's albedo exceeds π/4. With denom=4, F <= 1 and
the V-groove G keep the albedo <= ρs, so that model is energy conserving when ρd + ρs <= 1 (checked).

Spec: ``cook-torrance:d=beckmann,m=0.2,metal=gold``,
``cook-torrance:d=beckmann,m=0.2,fresnel=conductor,eta=0.37,k=2.82,denom=4,rho_d=0.1,rho_s=0.9``.

References
----------
R. L. Cook, K. E. Torrance, "A Reflectance Model for Computer Graphics", ACM TOG 1(1), 1982.
P. Slusallek, "Material Models" (lecture notes).
"""

from __future__ import annotations

import math

import drjit as dr

from . import microfacet as mf
from .base import INV_PI, Material
from .fresnel import fresnel_term, read_fresnel
from .spec import Params

__all__ = ["CookTorrance", "CookTorranceEnergyConserving"]

DENOMINATORS = {"pi": 1.0 / math.pi, "4": 0.25}


class CookTorrance(Material):
    """Cook-Torrance with the notes' denominator π(N·V)(N·I) (see the module docstring)."""

    model = "cook-torrance"
    reciprocal = True
    energy_conserving = False
    KEYS = ("d", "m", "fresnel", "metal", "eta", "k", "denom", "rho_d", "rho_s")
    EXAMPLES = ("cook-torrance:d=beckmann,m=0.2,metal=gold",
                "cook-torrance:d=blinn,m=0.3,fresnel=dielectric,eta=1.5,denom=4",
                "cook-torrance:d=gaussian,m=0.2,fresnel=conductor,eta=0.37,k=2.82,rho_d=0.1",
                "cook-torrance:d=beckmann,m=0.3,fresnel=none")

    def __init__(self, spec: str, distribution: str, m: float, fresnel: str, fresnel_params: dict,
                 denom: str, rho_d, rho_s):
        super().__init__(spec)
        self.distribution, self.m, self.fresnel = distribution, m, fresnel
        self.fresnel_params, self.denom, self.rho_d, self.rho_s = fresnel_params, denom, rho_d, rho_s

    @classmethod
    def parse(cls, text: str) -> CookTorrance:
        """Build from the part of the spec after ``cook-torrance:``; denom=4 gives the subclass."""
        p = Params(cls.model, text, cls.KEYS)
        distribution = p.choice("d", mf.DISTRIBUTIONS, "beckmann")
        if distribution == "blinn":
            m = p.number("m", lo=0.0, hi=0.5 * math.pi, lo_open=True, hi_open=True, unit="rad")
        else:
            m = p.number("m", lo=0.0, lo_open=True, unit="rad" if distribution == "gaussian" else "")
        fresnel, fresnel_params = read_fresnel(p)
        denom = p.choice("denom", tuple(DENOMINATORS), "pi")
        rho_d = p.colour("rho_d", 0.0)
        rho_s = p.colour("rho_s", 1.0)
        klass = CookTorranceEnergyConserving if denom == "4" else CookTorrance
        if klass.energy_conserving:
            p.at_most_one({"rho_d": rho_d, "rho_s": rho_s}, "energy conservation with denom=4")
        return klass(p.finish(), distribution, m, fresnel, fresnel_params, denom, rho_d, rho_s)

    def _parameters(self) -> dict:
        params = dict(self.fresnel_params)
        params.update(rho_d=self.rho_d, rho_s_scale=tuple(r * DENOMINATORS[self.denom] for r in self.rho_s))
        if self.distribution == "blinn":
            c = mf.blinn_exponent(self.m)
            params.update(c=c, d_norm=mf.blinn_norm(c))
        elif self.distribution == "gaussian":
            params.update(m=self.m, d_norm=mf.gaussian_norm(self.m))
        else:
            params.update(m=self.m)
        return params

    def values(self) -> dict:
        out = dict(self.fresnel_params)
        out.update(m=self.m, rho_d=self.rho_d, rho_s=self.rho_s)
        return out

    def _parameters_dr(self, v):
        p = {k: v[k] for k in self.fresnel_params}
        m = v["m"]
        p.update(rho_d=v["rho_d"], rho_s_scale=v["rho_s"] * DENOMINATORS[self.denom])
        if self.distribution == "blinn":
            c = -math.log(2.0) / dr.log(dr.cos(m))
            p.update(c=c, d_norm=(c + 2.0) / (2.0 * math.pi))
        elif self.distribution == "gaussian":
            p.update(m=m, d_norm=mf.gaussian_norm_dr(m))
        else:
            p.update(m=m)
        return p

    def _distribution(self, h, p):
        if self.distribution == "blinn":
            return mf.blinn(h, p["c"], p["d_norm"])
        if self.distribution == "gaussian":
            return mf.gaussian(h, p["m"], p["d_norm"])
        return mf.beckmann(h, p["m"])

    def _eval_dr(self, wi, wo, p):
        n_i, n_o = wi.z, wo.z
        h = dr.normalize(wi + wo)
        v_h = dr.dot(wo, h)
        g = mf.v_groove(h.z, n_i, n_o, v_h)
        f = fresnel_term(self.fresnel, v_h, p, wi, exact_conductor=False)
        glossy = f * (self._distribution(h, p) * g / (n_i * n_o))
        value = p["rho_d"] * INV_PI + p["rho_s_scale"] * glossy
        return dr.select((n_i > 0) & (n_o > 0), value, 0)


class CookTorranceEnergyConserving(CookTorrance):
    """Cook-Torrance with the modern denominator 4(N·V)(N·I) (``denom=4``); ρd + ρs <= 1."""

    energy_conserving = True
