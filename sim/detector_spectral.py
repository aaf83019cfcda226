"""A simulated spectrometer: the point detector of :mod:`gonio.sim.detector` reading one channel per
wavelength band, from spectral materials (:mod:`gonio.sim.materials.spectral`).

The optics, the Monte Carlo over the source and detector cones, the sensor noise and the seeding are the
point detector's (same streams, same aperture directions for the same key): only the integrand differs,
f_r(ωi', ωo', λ) cos θi' at every band centre λ of ``[detector.sim.spectrometer]`` instead of the three
RGB values. The bands are narrow (a band's value is the spectral quantity at its centre).

Materials. :func:`spectral_material` turns the RGB MATERIAL string a campaign names into the spectral
material with the same physics where there is one: ``lambert:albedo=ρ`` (one value: a grey Lambertian,
ρ at every wavelength) and ``ggx:alpha=A,metal=M`` for the tabulated conductors (gold, silver, copper,
aluminium: a GGX rough conductor with the exact Fresnel of the tabulated η(λ), k(λ)). Other materials are
refused with the list of what a spectrometer can render.
"""

from __future__ import annotations

import numpy as np

from gonio.jit import resolve_backend
from gonio.sim.aperture import aperture_directions, check_seed_state
from gonio.sim.detector import SimDetector
from gonio.sim.materials.spectral import CONDUCTORS, SpectralConductor, SpectralLambert

__all__ = ["SpectrometerDetector", "spectral_material", "spectral_aperture_factor", "constant_reflectance"]


def constant_reflectance(value: float):
    """ρ(λ) = ``value`` at every wavelength (a grey standard or sample)."""
    value = float(value)

    def rho(wavelength_nm):
        return np.full(np.shape(wavelength_nm), value)

    return rho


def spectral_material(material):
    """The spectral material for a MATERIAL (string or loaded RGB material) that has one.

    Returns an object with ``eval(wi, wo, wavelength_nm, backend=None) -> (..., L)`` in sr⁻¹ (``backend``
    the Dr.Jit backend, as :mod:`gonio.sim.materials.spectral`'s). A material that already is spectral
    (has such an ``eval`` and no ``eval_dr``) is returned as it is.

    Raises
    ------
    ValueError
        The material has no spectral counterpart (the message says which ones have).
    """
    if hasattr(material, "eval") and not hasattr(material, "eval_dr"):
        return material
    from gonio.sim.materials import load

    m = load(material) if isinstance(material, str) else material
    allowed = ("the simulated spectrometer renders spectral materials: lambert:albedo=RHO (one value) or "
               f"ggx:alpha=A,metal=({'|'.join(CONDUCTORS)})")
    model = getattr(m, "model", "")
    if model == "lambert":
        albedo = np.atleast_1d(np.asarray(m.albedo, dtype=float))
        if np.ptp(albedo) != 0.0:
            raise ValueError(f"material '{m.spec}': an R/G/B albedo has no spectrum; {allowed}")
        return SpectralLambert(constant_reflectance(albedo[0]))
    if model == "ggx":
        keys = dict(kv.split("=", 1) for kv in m.spec.split(":", 1)[1].split(",") if "=" in kv)
        metal = keys.get("metal")
        plain = (m.alpha_u == m.alpha_v and m.smith == "separable"
                 and np.all(np.asarray(m.rho_d) == 0.0) and np.all(np.asarray(m.rho_s) == 1.0))
        if metal in CONDUCTORS and plain:
            return SpectralConductor(metal, m.alpha_u)
    raise ValueError(f"material '{getattr(m, 'spec', m)}': {allowed}")


def spectral_aperture_factor(material, wi: np.ndarray, wo: np.ndarray, wavelength_nm,
                             source_half_angle_deg: float, detector_half_angle_deg: float, samples: int,
                             seed_state: tuple[int, int], backend: str | None = None,
                             ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`gonio.sim.detector.aperture_radiance_factor` for a spectral material: (factor, stderr), each
    (N, L) for L wavelengths, from the same aperture directions (same ``seed_state``: same samples), on
    the Dr.Jit ``backend`` (default :func:`gonio.jit.resolve_backend`)."""
    wi = np.asarray(wi, dtype=np.float64).reshape(-1, 3)
    wo = np.asarray(wo, dtype=np.float64).reshape(-1, 3)
    wl = np.atleast_1d(np.asarray(wavelength_nm, dtype=np.float64))
    if isinstance(samples, bool) or not isinstance(samples, int | np.integer) or not 2 <= samples <= 1 << 20:
        raise ValueError(f"samples: must be an integer in [2, {1 << 20}], got {samples!r}")
    key, word = check_seed_state(seed_state)
    n = wi.shape[0]
    if n == 0:
        return np.zeros((0, wl.size)), np.zeros((0, wl.size))
    samples = int(samples)
    backend = resolve_backend(backend)
    wi_s, wo_s = aperture_directions(wi, wo, source_half_angle_deg, detector_half_angle_deg, samples,
                                     (key, word), backend)
    wi_np = np.stack([np.asarray(c.numpy(), dtype=np.float64) for c in (wi_s.x, wi_s.y, wi_s.z)], axis=1)
    wo_np = np.stack([np.asarray(c.numpy(), dtype=np.float64) for c in (wo_s.x, wo_s.y, wo_s.z)], axis=1)
    # float32 directions renormalized in float64 (the materials check unit length)
    wi_np /= np.linalg.norm(wi_np, axis=1, keepdims=True)
    wo_np /= np.linalg.norm(wo_np, axis=1, keepdims=True)
    x = material.eval(wi_np, wo_np, wl, backend=backend) * np.maximum(wi_np[:, 2], 0.0)[:, None]
    x = x.reshape(n, samples, wl.size)
    mean = x.mean(axis=1)
    var = x.var(axis=1, ddof=1)
    omega = 2.0 * np.pi * (1.0 - np.cos(np.radians(source_half_angle_deg)))
    return omega * mean, omega * np.sqrt(var / samples)


class SpectrometerDetector(SimDetector):
    """A simulated spectrometer satisfying :class:`gonio.protocols.Detector`: one channel per band.

    Parameters are :class:`gonio.sim.detector.SimDetector`'s; ``materials`` maps each target to a
    spectral material (see :func:`spectral_material`). ``channels`` are the band names
    (``cfg.channel_names``), ``wavelengths_nm`` their centres.
    """

    def __init__(self, cfg, *, light, axes, kinematics, materials, clock, seed: int = 0,
                 name: str = "detector", track_motion: bool = False, backend: str | None = None):
        super().__init__(cfg, light=light, axes=axes, kinematics=kinematics,
                         materials={t: spectral_material(m) for t, m in materials.items()}, clock=clock,
                         seed=seed, name=name, track_motion=track_motion, backend=backend)
        wl = cfg.wavelengths_nm
        if wl is None:
            raise ValueError("detector.sim.kind: a SpectrometerDetector needs kind = 'spectrometer'")
        self.wavelengths_nm = np.asarray(wl, dtype=np.float64)
        self.channels = tuple(cfg.channel_names)
        # It renders stream by stream (one launch per reading), so developing readings together gains
        # nothing: a campaign reads it one step a unit.
        self.chunk = 1

    def _render(self, axes_deg: np.ndarray, target: str, keys, words, counters,
                samples: int | None = None):
        """:meth:`SimDetector._render` of the spectral integrand: rows of one stream at a time, counters
        0, 1, ... within it (a still reading is one row; a reading over a motion 16 rows of one key)."""
        wi, wo = self._kinematics.directions(axes_deg)
        factor = np.zeros((len(keys), len(self.channels)))
        factor_se = np.zeros_like(factor)
        lo = 0
        while lo < len(keys):
            hi = lo + 1
            while hi < len(keys) and (keys[hi], words[hi]) == (keys[lo], words[lo]):
                hi += 1
            if not np.array_equal(counters[lo:hi], np.arange(hi - lo)):
                raise ValueError("counters: the spectrometer renders the rows of one stream with counters "
                                 "0, 1, ...")
            factor[lo:hi], factor_se[lo:hi] = spectral_aperture_factor(
                self._materials[target], wi[lo:hi], wo[lo:hi], self.wavelengths_nm,
                self._light.half_angle_deg, self.cfg.sim.half_angle_deg,
                self.cfg.sim.aperture_samples if samples is None else samples,
                (int(keys[lo]), int(words[lo])), self.backend)
            lo = hi
        return factor, factor_se
