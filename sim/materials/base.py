"""The material interface shared by every model, and the Dr.Jit helpers the models are written with.

A material is evaluated over whole batches of direction pairs in the sample frame (N = +z). Models
write one Dr.Jit function, :meth:`Material._eval_dr`, that is generic in the array type: it derives its
types from its inputs, so the same code runs on LLVM and CUDA (:mod:`gonio.jit`), in float32 (the
simulation path) and float64 (the reference path of the tests and the fits).

Kernel reuse: every model parameter is uploaded once per array type as an *opaque* array
(:func:`drjit.opaque`), so Dr.Jit reads it from memory instead of baking its value into the generated
code. Calls with new directions, a new batch size or another material of the same model and
configuration (say gold and copper under the same Beckmann Cook-Torrance) therefore reuse one compiled
kernel; only a change of structure (another model, another D or Fresnel form) compiles a new one.

Per-call overhead: :meth:`Material.eval_dr` traces the model's few hundred array operations on every
call (~0.07 ms for GGX), which dominates below ~10⁵ directions. :meth:`Material.evaluate` (and
:meth:`Material.eval`, which goes through it) replays a frozen function (:func:`drjit.freeze`): the first
call of a material with arrays of one type traces and records the launch, later calls launch the
recorded kernel with the new inputs (~0.02 ms), the same kernel, so the same values bit for bit.
``eval_dr`` stays the way to compose a material into a larger kernel (the detector's, the camera's, a
fit's AD graph).
"""

from __future__ import annotations

import math
import threading
from typing import ClassVar

import drjit as dr
import numpy as np

from gonio.jit import array_types, exact_float64, resolve_backend, upload

__all__ = ["Material", "positive_power", "check_directions", "vector_type", "INV_PI"]

INV_PI = 1.0 / math.pi
# Rows whose length differs from 1 by more than this are rejected by Material.eval (not renormalized).
UNIT_TOLERANCE = 1e-4
_PRECISIONS = ("float32", "float64")


def positive_power(x, e):
    """``x**e`` for ``x > 0`` and 0 for ``x <= 0`` (a cosine lobe clipped at 90°), with ``e >= 0``.

    Written as exp(e·ln x) so that an opaque exponent does not specialize the kernel; the select
    keeps the NaN of the log of a negative number out of the result. Not exp2/log2 (nor dr.power,
    which uses them): Dr.Jit 1.5's float64 exp2 returns −inf for arguments in [−1024, −1023.5),
    where the power underflows.
    """
    return dr.select(x > 0, dr.exp(e * dr.log(x)), 0)


def check_directions(name: str, w) -> np.ndarray:
    """``w`` as a float64 array of unit vectors of shape (..., 3); raises ValueError naming ``name``."""
    w = np.asarray(w, dtype=np.float64)
    if w.ndim == 0 or w.shape[-1] != 3:
        raise ValueError(f"{name}: expected unit vectors of shape (..., 3), got shape {w.shape}")
    flat = w.reshape(-1, 3)
    bad = ~np.isfinite(flat).all(axis=1)
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{name}: row {row} is not finite: {flat[row].tolist()}")
    norm = np.linalg.norm(flat, axis=1)
    off = np.abs(norm - 1.0) > UNIT_TOLERANCE
    if off.any():
        row = int(np.flatnonzero(off)[0])
        raise ValueError(f"{name}: vectors must have unit length (within {UNIT_TOLERANCE}), row {row} has "
                         f"length {norm[row]:.6g}")
    return w


def vector_type(precision: str, backend: str):
    """The Dr.Jit 3-vector type of ``precision`` (``"float32"``, ``"float64"``) on ``backend``."""
    if precision not in _PRECISIONS:
        raise ValueError(f"precision must be one of {', '.join(_PRECISIONS)}, got {precision!r}")
    t = array_types(backend)
    return t.Array3f if precision == "float32" else t.Array3f64


class Material:
    """A BRDF model with its parameters.

    Attributes
    ----------
    spec : str
        The normalized MATERIAL string (every parameter, defaults included); ``load(spec)`` rebuilds it.
    channels : tuple of str
        Always ``("R", "G", "B")``.
    reciprocal : bool
        f(ωi, ωo) = f(ωo, ωi) holds for the model (class attribute).
    energy_conserving : bool
        The directional albedo ∫ f cos θo dωo is <= 1 for every ωi and every accepted parameter set
        (class attribute).
    isotropic : bool
        f is unchanged by rotating both directions about the normal.
    """

    model: ClassVar[str] = ""
    reciprocal: ClassVar[bool] = True
    energy_conserving: ClassVar[bool] = False
    #: Specs that together read every key of the model (the catalogue lists keys from them; tested).
    EXAMPLES: ClassVar[tuple[str, ...]] = ()
    #: The spec's form where it is not key=value (a file path), e.g. ``merl:PATH``.
    USAGE: ClassVar[str] = ""
    channels = ("R", "G", "B")

    def __init__(self, spec: str, *, isotropic: bool = True):
        self.spec = spec
        self.isotropic = isotropic
        self._dr_cache: dict[type, dict] = {}
        self._frozen = None
        self._frozen_lock = threading.Lock()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.spec!r})"

    # -- what a model supplies ------------------------------------------------------------------
    def _parameters(self) -> dict:
        """Parameter values to upload: a float (one value) or a 3-tuple (R, G, B) per name."""
        raise NotImplementedError

    def _eval_dr(self, wi, wo, p: dict):
        """f_r for unit direction arrays ``wi``, ``wo`` with parameters ``p`` (opaque arrays)."""
        raise NotImplementedError

    def values(self) -> dict:
        """The model's numeric spec parameters: a float or an (R, G, B) tuple per canonical key.

        Canonical keys are the anisotropic forms (``alpha_u``/``alpha_v``, ``alpha_x``/``alpha_y``) and
        ``eta``/``k`` for a ``metal``; models without free numbers (tables) return ``{}``.
        """
        return {}

    def _parameters_dr(self, v: dict) -> dict:
        """What :meth:`_parameters` derives, from :meth:`values`-shaped Dr.Jit arrays ``v`` (AD-safe)."""
        raise NotImplementedError(f"{self.model}: no differentiable parameter path")

    # -- the interface --------------------------------------------------------------------------
    def dr_parameters(self, vector_type) -> dict:
        """The model's parameters as opaque arrays for ``vector_type`` (e.g. Array3f), cached.

        Floats become opaque arrays of the scalar type (``dr.value_t``), 3-tuples opaque RGB vectors,
        numpy arrays (tables) opaque arrays of the scalar type.
        """
        cached = self._dr_cache.get(vector_type)
        if cached is None:
            scalar = dr.value_t(vector_type)
            cached = {}
            for name, value in self._parameters().items():
                if isinstance(value, tuple):
                    cached[name] = vector_type(*(dr.opaque(scalar, float(v)) for v in value))
                elif isinstance(value, np.ndarray):
                    cached[name] = dr.opaque(scalar(value))
                else:
                    cached[name] = dr.opaque(scalar, float(value))
            self._dr_cache[vector_type] = cached
        return cached

    def eval_dr(self, wi, wo):
        """f_r in sr⁻¹ for batches of direction pairs, in Dr.Jit.

        Parameters
        ----------
        wi, wo : Dr.Jit 3-vector (e.g. ``drjit.llvm.Array3f``, ``Array3f64``, ``drjit.cuda.Array3f``)
            Unit vectors in the sample frame: ωi toward the light, ωo toward the detector. Not checked
            (this is the hot path); both must have the same type.

        Returns
        -------
        Dr.Jit 3-vector of the type of ``wi``
            f_r per channel (R, G, B) in sr⁻¹; 0 where either direction is at or below the horizon.
        """
        with exact_float64(wi):
            return self._eval_dr(wi, wo, self.dr_parameters(type(wi)))

    def eval_with(self, wi, wo, params: dict):
        """:meth:`eval_dr` with ``params`` = :meth:`dr_parameters` passed in: how a frozen function that
        evaluates the material inside a larger kernel (the detectors' aperture sums) names them as its
        inputs, so that a replay reads them as the recording did."""
        with exact_float64(wi):
            return self._eval_dr(wi, wo, params)

    def evaluate(self, wi, wo):
        """:meth:`eval_dr`, evaluated, through a frozen function (module docstring): the same values
        bit for bit, without tracing the model again after the first call.

        Parameters
        ----------
        wi, wo : Dr.Jit 3-vector
            As for :meth:`eval_dr` (evaluated or not; inputs with gradients enabled take the traced
            path, since the recording holds no derivative).

        Returns
        -------
        Dr.Jit 3-vector of the type of ``wi``, evaluated
            f_r per channel (R, G, B) in sr⁻¹.
        """
        if dr.grad_enabled(wi) or dr.grad_enabled(wo):
            out = self.eval_dr(wi, wo)
            dr.eval(out)
            return out
        params = self.dr_parameters(type(wi))
        # A frozen function keeps its recordings in the object: one call at a time (daemon threads).
        with self._frozen_lock, exact_float64(wi):
            if self._frozen is None:
                self._frozen = dr.freeze(self._eval_dr)
            return self._frozen(wi, wo, params)

    def eval_params(self, v: dict, wi, wo):
        """f_r like :meth:`eval_dr`, with the spec parameters given as Dr.Jit arrays (e.g. for AD).

        Parameters
        ----------
        v : dict
            Every key of :meth:`values`: a Dr.Jit scalar array (e.g. ``drjit.llvm.ad.Float64`` of size 1)
            for a number, a 3-vector of the type of ``wi`` for an RGB parameter. Gradients enabled on
            them flow to the result. The structure (model, D, Fresnel form, Smith form) is this
            material's; only the numbers come from ``v``. Values are not range-checked.
        wi, wo : Dr.Jit 3-vector
            As for :meth:`eval_dr`.

        Returns
        -------
        Dr.Jit 3-vector of the type of ``wi``
            f_r per channel in sr⁻¹.
        """
        with exact_float64(wi):
            return self._eval_dr(wi, wo, self._parameters_dr(v))

    def eval(self, wi, wo, *, precision: str = "float32", backend: str | None = None) -> np.ndarray:
        """f_r in sr⁻¹ for numpy direction pairs, evaluated with :meth:`eval_dr`.

        Parameters
        ----------
        wi, wo : array_like, shape (..., 3)
            Unit vectors in the sample frame (broadcast against each other); rows that are not finite
            or not of unit length (within 1e-4) raise ValueError.
        precision : {"float32", "float64"}
            Dr.Jit precision: float32 is the simulation path, float64 the reference path.
        backend : {"llvm", "cuda"}, optional
            Dr.Jit backend (default: :func:`gonio.jit.resolve_backend`, CUDA when present).

        Returns
        -------
        numpy.ndarray, shape (..., 3), float64
            f_r per channel (R, G, B) in sr⁻¹, without the cosine factor.
        """
        vtype = vector_type(precision, resolve_backend(backend))
        wi, wo = np.broadcast_arrays(check_directions("wi", wi), check_directions("wo", wo))
        shape = wi.shape[:-1]
        flat_i, flat_o = wi.reshape(-1, 3), wo.reshape(-1, 3)
        if flat_i.shape[0] == 0:
            return np.zeros(shape + (3,))
        scalar = dr.value_t(vtype)
        dtype = np.float32 if precision == "float32" else np.float64

        def to_dr(v):
            return vtype(*(upload(scalar, v[:, j], dtype) for j in range(3)))

        result = self.evaluate(to_dr(flat_i), to_dr(flat_o))
        # Per channel: Array3f.numpy() would run a small export kernel specialized to the batch size.
        channels = [np.asarray(c.numpy(), dtype=np.float64) for c in (result.x, result.y, result.z)]
        return np.stack(channels, axis=-1).reshape(shape + (3,))
