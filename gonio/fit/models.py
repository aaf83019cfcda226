"""Fit models: which spec parameters of a material model are free, their bounds, and their starts.

A fit MODEL names a material model of :mod:`gonio.sim.materials` and means what the same name means as a
material: every numeric key of that material is fitted, its diffuse part ``rho_d`` included (a
``ward:`` material is ``rho_d/π`` plus the Ward lobe, so ``ward`` fits ``rho_d``, ``rho_s`` and
``alpha``). Keys can be held fixed, and a lobe fitted alone::

    MODEL   := NAME[:ITEM,...]                  the material NAME, every key free but those given
             | NAME-lobe[:ITEM,...]             its lobe alone: rho_d held at 0 (NAME:rho_d=0)
             | lambert+NAME[:ITEM,...]          the same as NAME (a Lambertian plus NAME is NAME's rho_d);
                                                NAME+lambert too
    ITEM    := key=value                        a structure choice or a value held fixed
             | anisotropic                      ward, ggx: fit alpha_x/alpha_y (alpha_u/alpha_v)

``NAME-lobe`` is a name of its own, not a material (``load("ward-lobe:...")`` fails): a fit of the lobe
alone prints the material it found, ``ward:rho_d=0,...``, which is honest only under a name that says
the diffuse part was left out. Before, ``ward`` meant the lobe alone and fitting a ``ward:`` material
with ``ward`` failed (χ²/dof 5e6) while ``lambert+ward`` recovered it.

Examples: ``lambert``, ``phong``, ``blinn-phong-lobe``, ``ward:anisotropic``,
``cook-torrance:d=gaussian``, ``cook-torrance:fresnel=dielectric``, ``ggx``, ``ggx-lobe:metal=gold``,
``ggx:alpha=0.2`` (only the weights are fitted).

Free parameters (each colour key has one free value per fitted channel):

================================ =================================================================
model                            free keys (bounds)
================================ =================================================================
lambert                          albedo [0, 1]
phong, blinn-phong, modified-    ks [0, 1], ke [0, 10⁴]
phong, normalized-blinn-phong
ward                             rho_s [0, 1], alpha [10⁻³, 1] (alpha_x, alpha_y: anisotropic)
cook-torrance                    m: beckmann [10⁻³, 2], blinn and gaussian [10⁻³, 1.5] rad; and
                                 by Fresnel form: none (the default) or metal=NAME → rho_s [0, 1];
                                 dielectric → eta [1.001, 5]; conductor → eta [0.02, 10], k [0, 20]
                                 (rho_s stays 1: it and the index both set the lobe's height)
ggx                              alpha [10⁻³, 2] (alpha_u, alpha_v: anisotropic); Fresnel as above
every NAME but lambert           rho_d [0, 1] in addition (NAME-lobe: rho_d = 0, not fitted)
================================ =================================================================

Energy conservation: where the model requires rho_d + w <= 1 per channel (w = ks for the normalized
cosine lobes, rho_s for ggx and for cook-torrance with denom=4) and both are free, the fit variable is
the fraction t = w / (1 − rho_d) in [0, 1], so that every point the optimizer visits is a valid
material; the reported values and uncertainties are those of rho_d and w.

Starts: a free rho_d starts at 0, the material's default (the lobe alone), and grows where the data
have a diffuse part. Started at 0.2, the χ² loss of a noise-free simulation of a pure metal (standard
deviations down to ~1e-30 sr⁻¹ in the lobe's far tails, where the diffuse guess is off by 26 orders of
magnitude) drove every start to a lobe narrowed onto its bound.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from gonio.sim.materials import load
from gonio.sim.materials.fresnel import METALS
from gonio.sim.materials.spec import RGB, format_number

__all__ = ["FIT_MODELS", "MATERIAL_MODELS", "LOBE_SUFFIX", "FitModel", "Variable", "parse_model"]

#: The material models a fit can name; each but lambert has a diffuse part rho_d and a lobe.
MATERIAL_MODELS = ("lambert", "phong", "modified-phong", "blinn-phong", "normalized-blinn-phong", "ward",
                   "cook-torrance", "ggx")
#: NAME + LOBE_SUFFIX: the lobe of NAME alone, rho_d held at 0.
LOBE_SUFFIX = "-lobe"
#: Every model name ``gonio fit`` takes: the materials, then their lobes alone.
FIT_MODELS = MATERIAL_MODELS + tuple(m + LOBE_SUFFIX for m in MATERIAL_MODELS[1:])
_COSINE_LOBES = ("phong", "modified-phong", "blinn-phong", "normalized-blinn-phong")
_STRUCTURE = {"cook-torrance": ("d", "fresnel", "metal", "denom"), "ggx": ("fresnel", "metal", "smith")}
#: Roughness key, its anisotropic pair, bounds and the range the starts are spread over (log-uniform).
_ROUGHNESS = {
    "ward": ("alpha", ("alpha_x", "alpha_y"), (1e-3, 1.0), (0.03, 0.5)),
    "ggx": ("alpha", ("alpha_u", "alpha_v"), (1e-3, 2.0), (0.03, 0.8)),
}
_CT_M = {"beckmann": (1e-3, 2.0), "blinn": (1e-3, 1.5), "gaussian": (1e-3, 1.5)}


@dataclass(frozen=True)
class Variable:
    """One fit variable: a spec key (and channel for a colour key), its bounds, its starts."""

    key: str
    channel: int | None
    lo: float
    hi: float
    #: (first, last) of the log-uniform spread of starts; None: start at ``start``.
    spread: tuple[float, float] | None = None
    start: float = 0.5
    #: True: the energy fraction t = w / (1 − rho_d) of ``key``, not the key's value itself.
    fraction: bool = False

    @property
    def name(self) -> str:
        return self.key if self.channel is None else f"{self.key}.{RGB[self.channel]}"


@dataclass
class FitModel:
    """A parsed fit MODEL (see the module docstring): the material's structure and its free variables.

    Attributes
    ----------
    text : str
        The MODEL as given, normalized (lower case, no spaces).
    name : str
        The material model.
    channels : tuple of int
        Fitted channels (0 = R, 1 = G, 2 = B).
    variables : list of Variable
        Fit variables in the order of the fit vector.
    base : Material
        The material at the first start; it fixes the structure (D, Fresnel form, Smith form).
    """

    text: str
    name: str
    channels: tuple[int, ...]
    items: dict = field(default_factory=dict)
    anisotropic: bool = False
    variables: list[Variable] = field(default_factory=list)
    energy: tuple[str, str] | None = None
    base: object = None

    # -- fit vector → spec values --------------------------------------------------------------
    def values(self, x, colour=None):
        """Every numeric key of the material (``base.values()`` keys) from the fit vector ``x``.

        ``x`` holds floats or Dr.Jit scalar arrays; ``colour(r, g, b)`` builds an RGB value (``tuple``
        for floats, the Dr.Jit 3-vector type for arrays). A colour channel that is not fitted takes
        the mean of the fitted ones (it does not enter the loss).
        """
        colour = colour or (lambda *c: tuple(c))
        fixed = self.base.values()
        per_key: dict[str, list] = {}
        scalars: dict[str, object] = {}
        for v, xv in zip(self.variables, x, strict=True):
            if v.channel is None:
                scalars[v.key] = xv
            else:
                per_key.setdefault(v.key, [None, None, None])[v.channel] = xv
        for key, chans in per_key.items():
            have = [c for c in chans if c is not None]
            mean = sum(have[1:], have[0]) / len(have) if len(have) > 1 else have[0]
            per_key[key] = [mean if c is None else c for c in chans]
        if self.energy is not None:
            d_key, w_key = self.energy
            if any(v.fraction for v in self.variables):
                per_key[w_key] = [t * (1.0 - d) for t, d in zip(per_key[w_key], per_key[d_key], strict=True)]
        out = {}
        for key, value in fixed.items():
            if key in per_key:
                out[key] = colour(*per_key[key])
            elif key in scalars:
                out[key] = scalars[key]
            elif key in ("alpha_u", "alpha_v", "alpha_x", "alpha_y") and "alpha" in scalars:
                out[key] = scalars["alpha"]
            else:
                out[key] = colour(*value) if isinstance(value, tuple) else value
        return out

    def spec(self, x) -> str:
        """The MATERIAL string of the fit vector ``x`` (floats), normalized by ``load``."""
        values = self.values([float(t) for t in x])
        try:
            return load(self._spec_text(values)).spec
        except ValueError:  # rounding to nearest pushed rho_d + w over 1: round the weight down
            return load(self._spec_text(values, down=True)).spec

    def _spec_text(self, values: dict, down: bool = False) -> str:
        items = [f"{k}={v}" for k, v in self.items.items() if k in _structure_keys(self.name)]

        def num(x, down=False):
            x = float(x)
            if x == 0.0:
                return "0"
            digits = 6 - int(math.floor(math.log10(abs(x)))) - 1
            scale = 10.0 ** digits
            # Energy weights may round down, so that rho_d + w <= 1 survives the rounding.
            return format_number((math.floor(x * scale) if down else round(x * scale)) / scale)

        def col(value, down=False):
            parts = [num(c, down) for c in value]
            return parts[0] if len(set(parts)) == 1 else "/".join(parts)

        w_key = self.energy[1] if self.energy else None
        pair = _ROUGHNESS[self.name][1] if self.name in _ROUGHNESS else ()
        for key, value in values.items():
            if key in ("eta", "k") and "metal" in self.items:
                continue
            if key in pair and not self.anisotropic:
                if key == pair[0]:
                    items.append(f"{_ROUGHNESS[self.name][0]}={num(value)}")
                continue
            if isinstance(value, tuple):
                items.append(f"{key}={col(value, down=down and key == w_key)}")
            else:
                items.append(f"{key}={num(value)}")
        return self.name + ":" + ",".join(items)

    def starts(self, count: int) -> list[list[float]]:
        """``count`` start vectors: spread variables at log-uniform quantiles, rotated per variable so
        that no two starts share a combination; weights at their start value."""
        spread = [v for v in self.variables if v.spread is not None]
        out = []
        for j in range(count):
            x, k = [], 0
            for v in self.variables:
                if v.spread is None:
                    x.append(min(max(v.start, v.lo), v.hi))
                    continue
                q = ((j + k * (count // max(len(spread), 1) + 1)) % count + 0.5) / count
                lo, hi = v.spread
                x.append(math.exp(math.log(lo) + q * (math.log(hi) - math.log(lo))))
                k += 1
            out.append(x)
        return out


def _structure_keys(name: str) -> tuple[str, ...]:
    return _STRUCTURE.get(name, ())


def _error(text: str, message: str) -> ValueError:
    return ValueError(f"model {text!r}: {message}")


def parse_model(text: str, channels=(0, 1, 2)) -> FitModel:
    """Parse a fit MODEL (module docstring) for the fitted ``channels`` (indices into R, G, B).

    Raises
    ------
    ValueError
        Unknown model (the message lists them), an item that is neither ``key=value`` of the model
        nor ``anisotropic``, a sum other than ``lambert+NAME``, a ``rho_d`` given where the model fits or
        fixes it itself, or fixed values the material rejects.
    """
    if not isinstance(text, str) or not text.strip():
        raise ValueError(f"model: expected NAME[:key=value,...], one of {', '.join(FIT_MODELS)}, "
                         f"optionally lambert+NAME; got {text!r}")
    norm = "".join(text.split()).lower()
    head, _, rest = norm.partition(":")
    terms = head.split("+")
    plus = False
    if len(terms) == 2 and "lambert" in terms and terms[0] != terms[1]:
        plus, name = True, terms[1] if terms[0] == "lambert" else terms[0]
    elif len(terms) == 1:
        name = terms[0]
    else:
        raise _error(norm, "sums other than lambert+NAME cannot be written as one MATERIAL string; "
                           f"allowed: NAME or lambert+NAME with NAME one of {', '.join(MATERIAL_MODELS[1:])}")
    if name not in FIT_MODELS:
        raise _error(norm, f"unknown model {name!r}; allowed: {', '.join(FIT_MODELS)}, "
                           "optionally as lambert+NAME")
    lobe = name.endswith(LOBE_SUFFIX)
    base = name.removesuffix(LOBE_SUFFIX)
    if plus and lobe:
        raise _error(norm, f"lambert+{name} is {base} (its lobe with a diffuse part); write {base}")
    items: dict[str, str] = {}
    anisotropic = False
    for item in rest.split(",") if rest else []:
        key, eq, value = item.partition("=")
        if not eq:
            if key == "anisotropic" and base in _ROUGHNESS:
                anisotropic = True
                continue
            raise _error(norm, f"item {item!r} is not key=value" +
                         ("" if base not in _ROUGHNESS else " or 'anisotropic'"))
        if key in items:
            raise _error(norm, f"key {key!r} is given twice")
        items[key] = value
    if plus and "rho_d" in items:
        raise _error(norm, "rho_d is what lambert+ fits; drop one of them")
    if lobe and "rho_d" in items:
        raise _error(norm, f"{name} holds rho_d at 0; to hold another value write {base}:rho_d=VALUE")
    # The material's rho_d is fitted unless the model holds it (the lobe alone, a value given).
    diffuse = base != "lambert" and not lobe and "rho_d" not in items
    _check_fixed(norm, base, items, tuple(channels), anisotropic, diffuse)
    m = FitModel(norm, base, tuple(channels), items, anisotropic)
    m.variables = _variables(m, diffuse)
    m.base = _base_material(m)
    return m


def _check_fixed(text: str, name: str, items: dict, channels, anisotropic: bool, diffuse: bool) -> None:
    """A value held fixed must lie within the bounds the fit gives that key when it is free: the model
    is then one the fit could have found (``ggx:alpha=5`` is a material, but no fit of ggx goes there)."""
    structure = {k: v for k, v in items.items() if k in _structure_keys(name)}
    free = FitModel(text, name, channels, structure, anisotropic)
    bounds = {v.key: (v.lo, v.hi) for v in _variables(free, diffuse)}
    for key, value in items.items():
        if key not in bounds:
            continue
        lo, hi = bounds[key]
        for part in value.split("/"):
            try:
                x = float(part)
            except ValueError:
                continue   # not a number: load() names it with the material's own message
            if not lo <= x <= hi:
                raise _error(text, f"{key}={value} is outside the range the fit uses for {key}, "
                                   f"[{format_number(lo)}, {format_number(hi)}]")


def _colour_vars(m: FitModel, key: str, lo=0.0, hi=1.0, start=0.5, fraction=False) -> list[Variable]:
    return [Variable(key, c, lo, hi, start=start, fraction=fraction) for c in m.channels]


def _variables(m: FitModel, diffuse: bool) -> list[Variable]:
    name, items = m.name, m.items
    out: list[Variable] = []
    if name == "lambert":
        return [] if "albedo" in items else _colour_vars(m, "albedo")
    weight = "ks" if name in _COSINE_LOBES else "rho_s"
    if name in _COSINE_LOBES:
        if "ke" not in items:
            out.append(Variable("ke", None, 0.0, 1e4, spread=(3.0, 300.0)))
    elif name in _ROUGHNESS:
        iso, pair, bounds, spread = _ROUGHNESS[name]
        if m.anisotropic:
            out += [Variable(k, None, *bounds, spread=spread) for k in pair if k not in items]
        elif iso not in items:
            out.append(Variable(iso, None, *bounds, spread=spread))
    elif "m" not in items:
        out.append(Variable("m", None, *_CT_M.get(items.get("d", "beckmann"), (1e-3, 2.0)),
                            spread=(0.03, 0.8)))
    free_weight = weight not in items
    if name in ("cook-torrance", "ggx"):
        form = "conductor" if "metal" in items else items.get("fresnel", "none")
        if "metal" not in items:
            items.setdefault("fresnel", form)
        if form == "dielectric" and "eta" not in items:
            out += [Variable("eta", c, 1.001, 5.0, spread=(1.2, 2.5)) for c in m.channels]
            free_weight = False
        elif form == "conductor" and "metal" not in items:
            if "eta" not in items:
                out += [Variable("eta", c, 0.02, 10.0, spread=(0.2, 2.0)) for c in m.channels]
            if "k" not in items:
                out += [Variable("k", c, 0.0, 20.0, spread=(1.0, 5.0)) for c in m.channels]
            free_weight = False
    energy = name in ("modified-phong", "normalized-blinn-phong", "ggx") or \
        (name == "cook-torrance" and items.get("denom") == "4")
    if energy:
        m.energy = ("rho_d", weight)
    if diffuse:
        out += _colour_vars(m, "rho_d", start=0.0)
    if free_weight:
        both = energy and diffuse
        out += _colour_vars(m, weight, start=0.5, fraction=both)
    elif weight not in items:
        items[weight] = "1"
    if not diffuse and "rho_d" not in items:
        items["rho_d"] = "0"
    return out


def _base_material(m: FitModel):
    """The material at the first start: validates the fixed items and fixes the structure."""
    x = m.starts(1)[0] if m.variables else []
    values = {}
    # Build from the items and the start values, then let load() validate everything.
    for v, xv in zip(m.variables, x, strict=True):
        if v.channel is None:
            values[v.key] = format_number(xv)
        else:
            values.setdefault(v.key, ["0.5"] * 3)[v.channel] = format_number(xv)
    if m.energy and any(v.fraction for v in m.variables):
        values[m.energy[1]] = ["0.4"] * 3
    text_items = dict(m.items)
    for key, value in values.items():
        text_items[key] = value if isinstance(value, str) else "/".join(value)
    if m.anisotropic and m.name in _ROUGHNESS:
        _, (a, b), _, _ = _ROUGHNESS[m.name]
        text_items.setdefault(a, text_items.get(b, "0.1"))
        text_items.setdefault(b, text_items.get(a, "0.1"))
    if "metal" in text_items:
        text_items.pop("fresnel", None)
    spec = m.name + ":" + ",".join(f"{k}={v}" for k, v in text_items.items())
    try:
        return load(spec)
    except ValueError as exc:
        raise _error(m.text, str(exc)) from None


def metal_names() -> tuple[str, ...]:
    return tuple(METALS)
