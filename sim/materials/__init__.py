"""Synthetic materials for the simulated gantry: BRDF models written once in Dr.Jit.

``load(spec)`` turns a MATERIAL string into a :class:`Material` whose ``eval(wi, wo)`` takes numpy unit
vectors of shape (..., 3) in the sample frame (N = +z, +x the reference direction; ωi toward the
light, ωo toward the detector) and returns f_r in sr⁻¹ of shape (..., 3) for the channels R, G, B,
without a cosine factor and 0 where either direction is at or below the horizon. ``eval_dr(wi, wo)``
is the same on Dr.Jit 3-vectors (LLVM float32 / float64, CUDA), for batched simulation.

MATERIAL grammar
----------------
``name:key=value,key=value,...`` (``name`` alone if the model needs no key). Names and words are case
insensitive and normalized to lower case; spaces around names and values are ignored. Numbers are
decimal (``0.2``, ``2e-1``), finite. Colour parameters (marked RGB) take one number for R, G and B or
three separated by ``/`` in the order R/G/B (``albedo=0.8/0.6/0.4``); each channel is range-checked.
Roughness ``m`` of the Blinn and Gaussian distributions is an angle in radians, as in the lecture notes
(the other roughnesses are slopes, without unit). ``merl:PATH`` takes the rest of the string as a path.
Through the daemon, ``merl:`` and ``bsdf:`` name a file of its materials folder, never a path
(:class:`.library.MaterialsFolder`).

The normalized ``spec`` lists every parameter the model used, defaults included, in the order below,
numbers in their shortest round-trip form: ``load(m.spec).spec == m.spec``. Unknown models, unknown or
inapplicable keys, missing required keys and values out of range raise ValueError naming the model,
the key and the allowed range.

======================== ================================================================ ==========
model                    keys: range [default]; "required" has no default                 class flags
======================== ================================================================ ==========
lambert                  albedo RGB [0, 1] required                                       R, E
phong                    ks RGB [0, 1] required; ke >= 0 required; rho_d RGB [0, 1] [0]   –
modified-phong           as phong; rho_d + ks <= 1 per channel                            R, E
blinn-phong              as phong                                                         –
normalized-blinn-phong   as phong; rho_d + ks <= 1 per channel                            R, E
ward                     rho_s RGB [0, 1] required; alpha > 0, or alpha_x > 0 and         R
                         alpha_y > 0, required; rho_d RGB [0, 1] [0]
cook-torrance            d: beckmann | blinn | gaussian [beckmann]; m required: > 0       R (E with
                         (blinn: 0 < m < π/2 rad); the Fresnel keys (one form required):  denom=4)
                         metal: gold | silver | copper | aluminium | steel, or fresnel: conductor
                         (eta RGB > 0, k RGB >= 0), dielectric (eta RGB > 0), none;
                         fresnel may be left out: metal or k → conductor, eta → dielectric;
                         denom: pi | 4 [pi]; rho_d RGB [0, 1] [0]; rho_s RGB [0, 1] [1];
                         denom=4 needs rho_d + rho_s <= 1 per channel
ggx                      alpha > 0, or alpha_u > 0 and alpha_v > 0, required; Fresnel     R, E
                         keys as cook-torrance (conductor: exact complex-index form);
                         smith: separable | correlated [separable]; rho_d RGB [0, 1] [0];
                         rho_s RGB [0, 1] [1]; rho_d + rho_s <= 1 per channel
merl                     merl:PATH, a MERL .binary table                                  R
bsdf                     bsdf:PATH, a Mitsuba 3 / pbrt-v4 measured-BSDF tensor file       –
======================== ================================================================ ==========

R: reciprocal, E: energy conserving (the class attributes ``reciprocal``, ``energy_conserving``).
Each model's module gives its formula and references.

Examples: ``lambert:albedo=0.8``, ``phong:ks=0.5,ke=20``, ``modified-phong:ks=0.5,ke=20,rho_d=0.3``,
``ward:rho_d=0.1,rho_s=0.05,alpha_x=0.1,alpha_y=0.3``, ``cook-torrance:d=beckmann,m=0.2,metal=gold``,
``cook-torrance:d=beckmann,m=0.2,fresnel=conductor,eta=0.37,k=2.82``,
``cook-torrance:d=blinn,m=0.3,fresnel=dielectric,eta=1.5,denom=4``, ``ggx:alpha=0.2,metal=gold``,
``merl:data/gold-metallic-paint.binary``.

Kernel reuse: parameters are uploaded once per array type as opaque Dr.Jit arrays, so calls with new
directions, batch sizes or parameter values reuse one compiled kernel per model configuration (see
:mod:`.base`). Inputs built from numpy should be 32-byte aligned (``Material.eval`` does this): Dr.Jit
maps numpy memory as it is and specializes the kernel to the alignment it finds.
"""

from __future__ import annotations

from .base import Material
from .bsdf_file import MeasuredTensor
from .cook_torrance import CookTorrance, CookTorranceEnergyConserving
from .ggx import GGX
from .lambert import Lambert
from .merl import Merl
from .phong import BlinnPhong, ModifiedPhong, NormalizedBlinnPhong, Phong
from .spec import split_spec
from .ward import Ward

__all__ = ["load", "Material", "MODELS", "Lambert", "Phong", "ModifiedPhong", "BlinnPhong",
           "NormalizedBlinnPhong", "Ward", "CookTorrance", "CookTorranceEnergyConserving", "GGX", "Merl",
           "MeasuredTensor"]

#: Model name → class; each class has ``parse(text)`` for the part of the spec after ``name:``.
MODELS = {cls.model: cls for cls in (Lambert, Phong, ModifiedPhong, BlinnPhong, NormalizedBlinnPhong,
                                     Ward, CookTorrance, GGX, Merl, MeasuredTensor)}


def load(spec: str) -> Material:
    """The material a MATERIAL string describes.

    Parameters
    ----------
    spec : str
        ``name:key=value,...`` (see the module docstring for every model's keys), or ``merl:PATH``.

    Returns
    -------
    Material
        With ``spec`` normalized, ``eval`` (numpy) and ``eval_dr`` (Dr.Jit).

    Raises
    ------
    ValueError
        Unknown model (the message lists the known ones), unknown or inapplicable key, missing required
        key, or a value out of its range (the message names the key and the range).

    Examples
    --------
    >>> import numpy as np
    >>> m = load("lambert:albedo=0.5")
    >>> m.spec
    'lambert:albedo=0.5'
    >>> m.eval(np.array([[0.0, 0.0, 1.0]]), np.array([[0.6, 0.0, 0.8]])).round(4)
    array([[0.1592, 0.1592, 0.1592]])
    """
    name, rest = split_spec(spec)
    cls = MODELS.get(name)
    if cls is None:
        raise ValueError(f"unknown material model {name!r} in {spec!r}; allowed: {', '.join(sorted(MODELS))}")
    return cls.parse(rest)
