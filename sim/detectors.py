"""The kinds of simulated detector (``[detector.sim] kind``, ``gonio simulate --detector``).

Each is a :class:`SimDetectorKind`, the target of a :data:`gonio.registries.SIM_DETECTORS` entry: what its
config allows (``check``), the channels its readings have, and how the wiring builds it. Building imports
the detector's Dr.Jit code; the rest imports nothing heavy (the config asks it while it validates).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

__all__ = ["SimDetectorKind", "PHOTODIODE", "SPECTROMETER", "CAMERA"]


@dataclass(frozen=True)
class SimDetectorKind:
    """A kind of simulated detector.

    Attributes
    ----------
    build : callable
        ``build(cfg, sample, *, light, axes, kinematics, clock, seed, track_motion)``: the detector (a
        :class:`gonio.protocols.Detector`), rendering the material ``sample`` (a loaded material) and
        the white standard of ``cfg.reference`` (:func:`gonio.sim.standard.reference_material`).
        ``light`` has ``radiance()`` and ``half_angle_deg``; ``axes`` have ``true_position_deg()``.
    check : callable, optional
        ``check(detector_cfg)``: ValueError naming a ``[detector]`` setting this kind cannot take.
    channels : callable, optional
        ``channels(detector_cfg) -> (names, wavelengths_nm or None)``: where the kind names its channels
        itself (a spectrometer's bands); None: the config's ``channels``.
    """

    build: Callable
    check: Callable | None = None
    channels: Callable | None = None


def _photodiode(cfg, sample, *, light, axes, kinematics, clock, seed, track_motion):
    from gonio.sim.detector import SimDetector
    from gonio.sim.standard import reference_material

    return SimDetector(cfg.detector, light=light, axes=axes, kinematics=kinematics, clock=clock, seed=seed,
                       materials={"sample": sample, "reference": reference_material(cfg)},
                       track_motion=track_motion)


def _spectrometer(cfg, sample, *, light, axes, kinematics, clock, seed, track_motion):
    from gonio.sim.detector_spectral import SpectrometerDetector, spectral_material
    from gonio.sim.standard import reference_material

    return SpectrometerDetector(cfg.detector, light=light, axes=axes, kinematics=kinematics,
                                materials={"sample": spectral_material(sample),
                                           "reference": reference_material(cfg, spectral=True)},
                                clock=clock, seed=seed, track_motion=track_motion)


def _spectrometer_check(det) -> None:
    if "channels" in det.model_fields_set:
        raise ValueError("channels: a simulated spectrometer names its bands itself (e.g. 380nm, 390nm, "
                         "...); leave channels out and set [detector.sim.spectrometer] instead")


def _spectrometer_bands(det):
    bands = tuple(det.sim.spectrometer.wavelengths_nm())
    return tuple(f"{w:g}nm" for w in bands), bands


def _camera(cfg, sample, *, light, axes, kinematics, clock, seed, track_motion):
    from gonio.sim.detector_camera import CameraDetector, camera_settings
    from gonio.sim.standard import reference_material

    materials = {"sample": sample, "reference": reference_material(cfg)}
    return CameraDetector(cfg.detector, camera_settings(cfg.detector, cfg.light), light=light, axes=axes,
                          kinematics=kinematics, materials=materials, clock=clock, seed=seed)


def _camera_check(det) -> None:
    if det.frames > 32:
        raise ValueError(f"frames: the simulated camera averages at most 32 frames a reading, got "
                         f"{det.frames}")


PHOTODIODE = SimDetectorKind(_photodiode)
SPECTROMETER = SimDetectorKind(_spectrometer, check=_spectrometer_check, channels=_spectrometer_bands)
CAMERA = SimDetectorKind(_camera, check=_camera_check)
