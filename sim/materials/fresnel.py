"""Fresnel reflectance of a smooth interface for unpolarized light, in Dr.Jit.

Three forms, all evaluated at the microfacet angle (cos θ = ωo·H = ωi·H) by the microfacet models:

- :func:`conductor_notes`: the conductor formula of the lecture notes (Slusallek, "Material Models"),
  F = (r∥² + r⊥²)/2 with
  r∥² = ((η²+k²)cos²θ − 2η cos θ + 1) / ((η²+k²)cos²θ + 2η cos θ + 1) and
  r⊥² = ((η²+k²) − 2η cos θ + cos²θ) / ((η²+k²) + 2η cos θ + cos²θ).
  It is exact at normal incidence and an approximation elsewhere (it assumes η² + k² ≫ sin²θ).
- :func:`conductor_exact`: the exact reflectance of a conductor with complex index η + ik, the form
  Mitsuba 3 uses (``fresnel_conductor``, after K. D. Moeller, *Optics*, 1988).
- :func:`dielectric`: the notes' r∥ = (ηt cos θi − ηi cos θt)/(ηt cos θi + ηi cos θt),
  r⊥ = (ηi cos θi − ηt cos θt)/(ηi cos θi + ηt cos θt) with ηi = 1 (light arrives from outside),
  ηt = η and Snell's law sin θt = sin θi / η; total internal reflection (possible for η < 1) gives 1.

Indices are per channel (RGB vectors); ``cos_theta`` is a scalar array broadcast over the channels.

References
----------
P. Slusallek, Computer Graphics, "Material Models" (lecture notes), conductor and dielectric Fresnel.
W. Jakob et al., Mitsuba 3, ``include/mitsuba/render/fresnel.h``.
"""

from __future__ import annotations

import drjit as dr

__all__ = ["METALS", "FRESNEL_FORMS", "conductor_notes", "conductor_exact", "dielectric", "read_fresnel",
           "fresnel_term"]

#: Built-in conductors: name → ((η_R, η_G, η_B), (k_R, k_G, k_B)), per linear-sRGB channel under D65.
#: gold, silver, copper (Johnson & Christy 1972) and aluminium (Rakić 1995) are derived from the
#: spectral tables in ``data/`` by :func:`gonio.colour.effective_rgb_conductor`: F0 per channel is the
#: colour of the spectral reflectance at normal incidence (gold's red, 1.04 in linear sRGB, clipped at
#: its largest spectral reflectance, 0.975), and k per channel follows the spectral Fresnel over angle.
#: (The lecture notes' single (η, k) for all three channels made gold grey.) ``tests/test_colour.py``
#: re-derives these numbers. steel keeps the notes' grey (η, k): no spectral table ships for it.
METALS = {
    "gold": ((0.1433, 0.4955, 1.4767), (4.6725, 2.2501, 1.7785)),
    "silver": ((0.0574, 0.0549, 0.0431), (4.4877, 3.5555, 2.5902)),
    "copper": ((0.2371, 1.0448, 1.2968), (3.5125, 2.6262, 2.3634)),
    "aluminium": ((1.5025, 0.9853, 0.6059), (7.6484, 6.5535, 5.353)),
    "steel": ((2.485,) * 3, (3.433,) * 3),
}
FRESNEL_FORMS = ("conductor", "dielectric", "none")


def conductor_notes(cos_theta, eta, k):
    """Unpolarized conductor reflectance, the lecture notes' formula (see module docstring)."""
    c = type(eta)(cos_theta)
    c2 = c * c
    e2 = eta * eta + k * k
    two_eta_c = 2 * eta * c
    r_par = (e2 * c2 - two_eta_c + 1) / (e2 * c2 + two_eta_c + 1)
    r_perp = (e2 - two_eta_c + c2) / (e2 + two_eta_c + c2)
    return 0.5 * (r_par + r_perp)


def conductor_exact(cos_theta, eta, k):
    """Unpolarized reflectance of a conductor with complex index η + ik, exact (Mitsuba 3's form)."""
    c = type(eta)(cos_theta)
    c2 = c * c
    s2 = 1 - c2
    t1 = eta * eta - k * k - s2
    a2b2 = dr.safe_sqrt(t1 * t1 + 4 * eta * eta * k * k)
    a = dr.safe_sqrt(0.5 * (a2b2 + t1))
    t2 = 2 * c * a
    r_s = (a2b2 + c2 - t2) / (a2b2 + c2 + t2)
    t3 = a2b2 * c2 + s2 * s2
    t4 = t2 * s2
    r_p = r_s * (t3 - t4) / (t3 + t4)
    return 0.5 * (r_s + r_p)


def dielectric(cos_theta, eta):
    """Unpolarized reflectance of a dielectric interface from outside (ηi = 1) into index η."""
    ci = type(eta)(cos_theta)
    sin2_t = (1 - ci * ci) / (eta * eta)
    ct = dr.safe_sqrt(1 - sin2_t)
    r_par = (eta * ci - ct) / (eta * ci + ct)
    r_perp = (ci - eta * ct) / (ci + eta * ct)
    return dr.select(sin2_t >= 1, 1, 0.5 * (r_par * r_par + r_perp * r_perp))


_FRESNEL_RULE = ("say how the facets reflect: metal=NAME (" + ", ".join(METALS) + "), fresnel=conductor "
                 "with eta and k, fresnel=dielectric with eta, or fresnel=none")


def read_fresnel(p) -> tuple[str, dict]:
    """Read the Fresnel keys of a microfacet spec: ``fresnel``, ``metal``, ``eta``, ``k``.

    ``metal=NAME`` means a conductor with the per-channel (η, k) of :data:`METALS`; otherwise
    ``fresnel`` says the form, and when it is omitted it follows from the keys given: ``k`` →
    conductor, ``eta`` alone → dielectric.
    One of them must be given (``fresnel=none`` for F = 1).

    Returns
    -------
    (form, parameters) : str, dict
        form is one of :data:`FRESNEL_FORMS`; parameters has RGB tuples ``eta`` and ``k`` as needed.
    """
    p.rule(_FRESNEL_RULE)
    if p.has("metal"):
        p.reject(("eta", "k"), "together with 'metal' (the metal sets eta and k)")
        p.choice("fresnel", ("conductor",), "conductor", context="when 'metal' is given")
        metal = p.choice("metal", tuple(METALS))
        eta, k = METALS[metal]
        return "conductor", {"eta": eta, "k": k}
    if not p.has("fresnel") and not p.has("eta") and not p.has("k"):
        raise p.error(_FRESNEL_RULE)
    default = "conductor" if p.has("k") else "dielectric" if p.has("eta") else None
    form = p.choice("fresnel", FRESNEL_FORMS, default)
    if form == "none":
        p.reject(("eta", "k"), "with fresnel=none")
        return form, {}
    eta = p.colour("eta", lo=0.0, hi=None, lo_open=True)
    if form == "dielectric":
        p.reject(("k",), "with fresnel=dielectric")
        return form, {"eta": eta}
    return form, {"eta": eta, "k": p.colour("k", lo=0.0, hi=None)}


def fresnel_term(form: str, cos_theta, p: dict, like, exact_conductor: bool):
    """F per channel (a vector of the type of ``like``) for the form chosen by :func:`read_fresnel`."""
    if form == "none":
        return type(like)(1)
    if form == "dielectric":
        return dielectric(cos_theta, p["eta"])
    conductor = conductor_exact if exact_conductor else conductor_notes
    return conductor(cos_theta, p["eta"], p["k"])
