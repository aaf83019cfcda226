"""Fit reflectance models to the measured samples of a campaign (``gonio fit``).

``fit(source, model)`` fits a material model (:mod:`gonio.fit.models` for the MODEL grammar and the free
parameters) to the measured f_r of a campaign folder, a ``brdf.h5``, a
:class:`~gonio.dataset.SampledBRDF` or :class:`FitData`, at the directions actually measured (no
interpolation), averaged over the source and detector cones they were measured through where those are
known (:mod:`gonio.fit.aperture`). Gradients come from Dr.Jit's AD through the material code the simulator
renders with (:meth:`gonio.sim.materials.Material.eval_params`); the loss, the optimizer, the bounds and the
uncertainties are described in :mod:`gonio.fit.solve`.

The result's ``material`` is a MATERIAL string that ``gonio simulate`` and
``gonio.sim.materials.load`` accept; :meth:`FitResult.to_json` adds the parameters with their
standard uncertainties, the loss, the residual statistics and the degrees of freedom.

Example
-------
>>> r = fit("campaign-folder", "ggx")                                       # doctest: +SKIP
>>> r.material, r.parameters["alpha"]                                        # doctest: +SKIP
('ggx:fresnel=none,alpha=0.2,rho_d=0.3,rho_s=0.5', {'value': 0.2, 'stddev': 0.0004, ...})
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gonio.dataset import BRDF_NAME, SampledBRDF, aperture_cones, calibration_reference, read_brdf
from gonio.fit.aperture import Aperture
from gonio.fit.models import FIT_MODELS, FitModel, parse_model
from gonio.fit.shared import shared_errors
from gonio.fit.solve import LOSSES, FitData, Problem, covariance, residual_statistics, solve
from gonio.geometry import sph_to_vec
from gonio.sim.materials.spec import RGB

__all__ = ["fit", "FitResult", "FitData", "Aperture", "load_samples", "parse_channels", "parse_model",
           "FIT_MODELS",
           "LOSSES"]


def parse_channels(text: str | None, available=RGB) -> tuple[int, ...]:
    """``"R,G,B"`` (any non-empty subset, any case) → channel indices; None → all of ``available``."""
    if text is None:
        return tuple(range(len(available)))
    names = [t.strip().upper() for t in str(text).split(",") if t.strip()]
    bad = [n for n in names if n not in RGB[:len(available)]]
    if not names or bad or len(set(names)) != len(names):
        raise ValueError(f"channels: expected a comma-separated subset of {','.join(available)} without "
                         f"repeats, got {text!r}")
    return tuple(sorted(RGB.index(n) for n in names))


def load_samples(source) -> tuple[FitData, dict]:
    """The measured samples of a campaign folder, ``brdf.h5`` or SampledBRDF, and their attributes; the
    samples' ``aperture`` is the cones they were measured through where the attributes give them
    (:func:`gonio.dataset.aperture_cones`), else None."""
    data, attrs, _ = _load(source)
    return data, attrs


def _load(source) -> tuple[FitData, dict, tuple | None]:
    """:func:`load_samples`, and for a spectrometer's samples (fitted as RGB) the bands they were
    converted from: (values (N, B), stddev (N, B) or None, weights (B, 3)); None for RGB samples."""
    if isinstance(source, FitData):
        return source, {}, None
    origin = "the data's attributes"
    if not isinstance(source, SampledBRDF):
        path = Path(source)
        h5 = path / BRDF_NAME if path.is_dir() else path
        if not h5.is_file():
            raise ValueError(f"{source}: not a finished campaign (no {BRDF_NAME}; it is written when every "
                             "step is measured) nor a brdf.h5 file")
        source, origin = read_brdf(h5), f"{h5}: attribute"
    r = {k: np.radians(np.asarray(getattr(source, k), dtype=np.float64).ravel())
         for k in ("theta_i", "phi_i", "theta_o", "phi_o")}
    attrs = dict(source.attrs)
    value, stddev, bands = _as_rgb(np.asarray(source.value, np.float64), source.stddev, attrs)
    try:   # the cones the readings integrate, where the file says (gonio.fit.aperture)
        cones = aperture_cones(attrs)
        aperture = None if cones is None else Aperture(*cones)
    except ValueError as err:
        raise ValueError(f"{origin} {err}") from None
    data = FitData(sph_to_vec(r["theta_i"], r["phi_i"]), sph_to_vec(r["theta_o"], r["phi_o"]), value, stddev,
                   aperture)
    return data, attrs, bands


def _as_rgb(value, stddev, attrs):
    """The models are fitted in R, G, B: a spectrometer's bands (``wavelengths_nm``) are converted to
    linear sRGB under D65 (:func:`gonio.colour.bands_to_rgb`, linear in the bands), their variances
    carried through the same weights squared (bands taken as independent). RGB data pass unchanged.
    Returns (value, stddev, bands) as :func:`_load`."""
    wl = attrs.get("wavelengths_nm")
    if wl is None or value.shape[1] != len(wl):
        return value, stddev, None
    from gonio.colour import bands_to_rgb

    weights = bands_to_rgb(np.eye(len(wl)), np.asarray(wl, np.float64))   # (B, 3): row b = RGB of band b
    rgb = value @ weights
    sd = None if stddev is None else np.asarray(stddev, np.float64)
    attrs["fitted_from"] = f"{len(wl)} spectral bands as linear sRGB under D65"
    return rgb, None if sd is None else np.sqrt(sd ** 2 @ weights ** 2), (value, sd, weights)


@dataclass
class FitResult:
    """A fitted model.

    Attributes
    ----------
    material : str
        MATERIAL string of the best fit (``gonio.sim.materials.load`` accepts it).
    parameters : dict
        Per fitted spec parameter (``alpha``, ``rho_d.R``, ...): ``value``, ``stddev`` (one standard
        uncertainty, same unit as the parameter), ``lo``/``hi`` (bounds) and ``at_bound``.
    residual : dict
        :func:`gonio.fit.solve.residual_statistics`.
    aperture : Aperture or None
        The cones the model was averaged over (:mod:`gonio.fit.aperture`), or None: evaluated at the
        measured directions themselves.
    """

    model: str
    material: str
    channels: tuple[str, ...]
    loss: str
    parameters: dict
    residual: dict
    covariance: np.ndarray
    runs: list
    seconds: float
    samples: int
    source: dict = field(default_factory=dict)
    aperture: Aperture | None = None

    @property
    def dof(self) -> int:
        return int(self.residual["dof"])

    def to_json(self) -> dict:
        return {"model": self.model, "material": self.material, "channels": list(self.channels),
                "loss_kind": self.loss, "loss": self.residual["loss"], "degrees_of_freedom": self.dof,
                "samples": self.samples, "parameters": self.parameters,
                "uncertainty": "one standard deviation; (J^T J)^-1 s^2, see gonio.fit.solve",
                "residual": self.residual,
                "covariance": {"names": list(self.parameters), "matrix": self.covariance.tolist()},
                "starts": self.runs, "seconds": self.seconds, "source": self.source,
                "aperture": None if self.aperture is None else self.aperture.to_json()}

    def write(self, path) -> None:
        Path(path).write_text(json.dumps(self.to_json(), indent=2) + "\n")


def _spec_jacobian(model: FitModel, x: np.ndarray, names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Values of the reported spec parameters at ``x`` and their Jacobian w.r.t. ``x`` (central
    differences of the cheap variable → spec map, exact to ~1e-9 for these bilinear maps)."""

    def g(xv):
        vals = model.values(list(xv))
        out = []
        for v in model.variables:
            value = vals[v.key] if v.key in vals else vals[_iso_key(model, v.key)]
            out.append(value if v.channel is None else value[v.channel])
        return np.array(out, dtype=np.float64)

    y = g(x)
    jac = np.zeros((len(y), len(x)))
    for j in range(len(x)):
        h = 1e-7 * max(abs(x[j]), 1e-3)
        e = np.zeros(len(x))
        e[j] = h
        jac[:, j] = (g(x + e) - g(x - e)) / (2 * h)
    return y, jac


def _iso_key(model: FitModel, key: str) -> str:
    return {"ward": "alpha_x", "ggx": "alpha_u"}.get(model.name, key) if key == "alpha" else key


def fit(source, model: str, *, channels: str | None = None, loss: str = "auto", starts: int = 4,
        jac: str = "ad", backend: str | None = None) -> FitResult:
    """Fit ``model`` to the measured samples of ``source``.

    Parameters
    ----------
    source : str, Path, SampledBRDF or FitData
        A finished campaign folder, a ``brdf.h5``, data read with :func:`gonio.dataset.read_brdf`, or
        directions with values.
    model : str
        Fit MODEL, e.g. ``ggx``, ``ggx-lobe``, ``cook-torrance:d=blinn``, ``ward:anisotropic``
        (:mod:`gonio.fit.models`).
    channels : str, optional
        ``"R,G,B"`` or a subset: the channels whose data enter the loss; colour parameters are fitted
        per channel. Unfitted channels take the mean of the fitted ones in the MATERIAL string.
    loss : {"auto", "chi2", "cos"}
        See :mod:`gonio.fit.solve`.
    starts : int
        Number of starts (the best wins).
    jac : {"ad", "2-point"}
        Dr.Jit AD Jacobian (default) or scipy finite differences (for comparison).
    backend : {"llvm", "cuda"}, optional
        Dr.Jit backend of the model evaluations (default: :func:`gonio.jit.resolve_backend`, CUDA when
        present).

    Returns
    -------
    FitResult

    Raises
    ------
    ValueError
        Unknown model or channel, a source that is not a finished campaign, too few samples.
    """
    data, attrs, bands = _load(source)
    chan = parse_channels(channels, RGB[:data.value.shape[1]])
    m = parse_model(model, chan)
    if not m.variables:
        raise ValueError(f"model {m.text!r}: every parameter is held fixed; nothing to fit")
    problem = Problem(m, data, loss, backend)
    if problem.loss == "chi2" and isinstance(source, str | Path) and Path(source).is_dir():
        # the standard brdf.h5 was calibrated with (per channel where it was so given), when it says
        rho = calibration_reference(attrs)
        if bands is None:
            problem.set_shared(shared_errors(source, data.value, rho))
        elif bands[1] is not None:
            # a dark or reference reading's bands are read each with its own error, as the samples' are
            # (whose RGB stddev takes them as independent): one shared error per band and reading,
            # through the band's RGB weights
            problem.set_shared(shared_errors(source, bands[0], rho), weights=bands[2])
    best = solve(problem, starts=starts, jac=jac)
    x = best["x"]
    residual = problem.residuals(x)
    cov_x, _ = covariance(problem, x, residual)
    names = [v.name for v in m.variables]
    y, g = _spec_jacobian(m, x, names)
    cov = g @ cov_x @ g.T
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    parameters = {}
    for k, v in enumerate(m.variables):
        lo, hi = (0.0, 1.0) if v.fraction else (v.lo, v.hi)
        span = max(v.hi - v.lo, 1e-12)
        at = bool(min(x[k] - v.lo, v.hi - x[k]) <= 1e-6 * span)
        parameters[v.name] = {"value": float(y[k]), "stddev": float(sd[k]), "lo": lo, "hi": hi,
                              "at_bound": at}
    stats = residual_statistics(problem, residual, len(x))
    stats["shared_errors"] = 0 if problem.shared is None else int(problem.shared.shape[-1])
    stats["stddev_floored"] = problem.floored
    src = {k: attrs[k] for k in ("material", "sample", "grid", "seed") if k in attrs}
    if isinstance(source, str | Path):
        src["path"] = str(source)
    return FitResult(m.text, m.spec(x), tuple(RGB[c] for c in chan), problem.loss, parameters, stats,
                     cov, best["runs"], best["seconds"], problem.n_samples, src, problem.aperture)
