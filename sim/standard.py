"""The simulated white standard: the Lambertian reflector a simulated detector renders for a reference
reading, as ``[reference]`` of the gantry config describes it."""

from __future__ import annotations

import numpy as np

from gonio.config import GonioConfig
from gonio.sim import materials as _materials

__all__ = ["reference_material"]


def reference_material(cfg: GonioConfig, spectral: bool = False):
    """The simulated white standard: a Lambertian of ``reference.albedo``, or of ``reference.reflectance``
    per channel, or of ``reference.spectrum`` (spectral: ρ(λ) at every band; RGB: its linear sRGB), times
    ``reference.response`` (so that at its reading angles it reflects as the config says)."""
    ref, det = cfg.reference, cfg.detector
    g = ref.response
    if spectral:
        from gonio.sim.materials.spectral import SpectralLambert

        if ref.spectrum is not None:
            return SpectralLambert(lambda wl: ref.spectrum.at(wl) * g)
        if ref.reflectance is not None:
            bands, rho = np.asarray(det.wavelengths_nm, float), np.asarray(ref.reflectance, float) * g
            return SpectralLambert(lambda wl: np.interp(wl, bands, rho))
        return SpectralLambert(lambda wl: np.full(np.shape(wl), ref.albedo * g))
    if ref.reflectance is None and ref.spectrum is None and g == 1.0:
        return _materials.load(f"lambert:albedo={ref.albedo!r}")
    rho = ref.reference_fr(det.channel_names, det.wavelengths_nm)
    if np.any(rho > 1.0):
        raise ValueError(f"reference.response: the simulated standard would reflect ρ·response = "
                         f"{float(rho.max()):g} > 1 of the light it receives")
    return _materials.load("lambert:albedo=" + "/".join(repr(float(r)) for r in rho))
