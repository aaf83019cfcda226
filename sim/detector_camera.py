"""A simulated camera as the gantry's detector: a frame rendered by :mod:`gonio.sim.camera` at the actual
pose, reduced by :mod:`gonio.frames` to the mean radiance of the sample region per channel.

One reading (``measure``):

1. the pose from the axes' actual positions (forward kinematics), the light's radiance now (0 with the
   shutter closed: a dark frame, black level and noise only);
2. with ``auto_exposure``, a probe frame at the asked exposure sets the exposure (:func:`gonio.frames.
   auto_exposure`, the region's 99th-percentile channel at half the sensor's range);
3. ``frames`` frames at that exposure, averaged pixel by pixel; or with ``brackets`` (multiples of the
   exposure) one frame per multiple, merged into one HDR rate image (:func:`gonio.frames.merge_brackets`);
4. the sample region: the pixels whose centre ray hits the patch (exact geometry of the camera), eroded
   by ``erode_px``: the same region for darks, references and poses, so nothing depends on contrast;
5. ``signal`` = mean of (v − black level) over the region, at the reading's exposure (signal units, like
   the point detector: a rate times ``exposure_s``), ``stderr`` its standard error from the pixel noise
   (:func:`gonio.frames.region_mean`).

A frame that cannot be used (wrong size, NaN or infinite pixels, every pixel saturated, or, without
brackets, saturated pixels in the sample region, which would bias the mean low) raises a non-transient
:class:`gonio.protocols.DeviceFault` naming the frame and what is wrong: the runner latches it in the
journal. Never a zero in its place.

The frame (the mean frame, or the bracket's base exposure) goes to the journal in ``extra["frame"]`` with
the pose, exposure and key in its metadata; the journal writes it as EXR beside itself.

Seeding: frame f of bracket entry b of reading (step, attempt) is the camera's frame keyed (step,
1024·attempt + 32·b + f) (the probe: b = 31), so a resumed campaign replays every frame exactly.
"""

from __future__ import annotations

import math

import numpy as np

from gonio.frames import (
    Frame,
    FrameError,
    auto_exposure,
    check_frame,
    erode_disk,
    merge_brackets,
    region_mean,
)
from gonio.jit import resolve_backend
from gonio.protocols import Clock, DeviceFault, Reading
from gonio.sim.camera import CameraSettings, SimCamera
from gonio.sim.detector import TARGETS, SimDetector

__all__ = ["CameraDetector", "camera_settings"]

_PROBE = 31


def camera_settings(cfg, light_cfg) -> CameraSettings:
    """The :class:`CameraSettings` of ``[detector.sim.camera]`` lit as ``[light.sim]`` says."""
    c = cfg.sim.camera
    return CameraSettings(
        width=c.width, height=c.height, fov_deg=c.fov_deg, distance_m=c.distance_m,
        sample_size_m=c.sample_size_m, light_distance_m=c.light_distance_m,
        light_half_angle_deg=light_cfg.sim.half_angle_deg, radiance=light_cfg.sim.radiance,
        samples_per_pixel=c.samples_per_pixel, vignetting=c.vignetting, black_level=c.black_level,
        read_sigma=c.read_sigma, shot_counts_per_unit=c.shot_counts_per_unit,
        saturation=math.inf if c.saturation is None else c.saturation)


class CameraDetector:
    """A simulated camera satisfying :class:`gonio.protocols.Detector` (see the module docstring).

    Parameters
    ----------
    cfg : gonio.config.DetectorConfig
        ``sim.kind = "camera"``; ``sim.camera`` holds the camera and its processing.
    settings : CameraSettings
        Geometry and sensor (:func:`camera_settings`).
    light
        ``radiance()`` now (0 with the shutter closed).
    axes, kinematics, materials, clock, seed, name
        As :class:`gonio.sim.detector.SimDetector`'s (RGB materials for ``"sample"`` and ``"reference"``).
    backend : {"llvm", "cuda"}, optional
        Dr.Jit backend of the renderer (default: ``cfg.sim.backend``, else
        :func:`gonio.jit.resolve_backend`).
    """

    def __init__(self, cfg, settings: CameraSettings, *, light, axes, kinematics, materials, clock: Clock,
                 seed: int = 0, name: str = "detector", backend: str | None = None):
        if len(cfg.channels) != 3:
            raise ValueError(f"detector.channels: the camera renders RGB, so 3 channels, got "
                             f"{list(cfg.channels)}")
        missing = [t for t in TARGETS if t not in materials]
        if missing:
            raise ValueError(f"materials: missing a material for {', '.join(missing)}")
        self.name = name
        self.channels = tuple(cfg.channels)
        self.cfg = cfg
        self.settings = settings
        self._light = light
        self._axes = axes
        self._kinematics = kinematics
        self._clock = clock
        self.backend = resolve_backend(cfg.sim.backend if backend is None else backend)
        self._cameras = {t: SimCamera(settings, materials[t], seed=seed, backend=self.backend)
                         for t in TARGETS}
        self._target = "sample"
        self._connected = False
        self._count = 0

    # -- the Detector protocol ----------------------------------------------------------------------
    def connect(self) -> None:
        self._connected = True

    def close(self) -> None:
        self._connected = False

    def measure(self, exposure_s: float, frames: int = 1, *, key: tuple[int, int] | None = None) -> Reading:
        """One reading at the current pose (module docstring). ``extra`` holds the frame (``frame``), the
        target, the pose (°), the region's pixel count and the exposures of the bracket."""
        if not self._connected:
            raise DeviceFault(self.name, "not connected: call connect() first")
        exposure_s = float(exposure_s)
        if not 0.0 < exposure_s <= 3600.0:
            raise ValueError(f"exposure_s: must be in (0, 3600] s, got {exposure_s!r}")
        if isinstance(frames, bool) or not isinstance(frames, int | np.integer) or not 1 <= frames <= 32:
            raise ValueError(f"frames: must be an integer in [1, 32] for the camera, got {frames!r}")
        step, attempt = (self._count, 0) if key is None else (int(key[0]), int(key[1]))
        self._count += 1
        try:
            return self._measure(exposure_s, int(frames), step, attempt)
        except FrameError as err:
            raise DeviceFault(self.name, f"step {step}: {err}", transient=False) from None

    # -- simulation-only (what is under the beam, and the actual pose: as the point detector) ---------
    target = SimDetector.target
    set_target = SimDetector.set_target
    actual_axes_deg = SimDetector.actual_axes_deg

    def describe(self) -> dict:
        """What this detector is, for the journal (:class:`gonio.protocols.Describes`)."""
        return {"name": self.name, "driver": "sim", "identity": "simulated camera", "firmware": None,
                "units": "signal", "settings": {"channels": list(self.channels)}}

    def pose_deg(self) -> tuple[float, float, float, float]:
        """(θi, φi, θo, φo) in degrees at the axes' actual positions."""
        wi, wo = self._kinematics.directions(self.actual_axes_deg()[None, :])
        out = []
        for w in (wi[0], wo[0]):
            out += [math.degrees(math.acos(min(1.0, max(-1.0, float(w[2]))))),
                    math.degrees(math.atan2(float(w[1]), float(w[0])))]
        return tuple(out)

    def region(self, theta_o_deg: float, phi_o_deg: float) -> np.ndarray:
        """The sample region (H, W) seen from (θo, φo): the patch's pixels, eroded by ``erode_px``."""
        mask = self._cameras["sample"].sample_mask(theta_o_deg, phi_o_deg)
        return erode_disk(mask, self.cfg.sim.camera.erode_px)

    # -- internals ----------------------------------------------------------------------------------
    def _frame(self, pose, exposure_s: float, step: int, attempt: int, entry: int, f: int,
               source: float) -> np.ndarray:
        cam = self._cameras[self._target]
        frame = cam.render(*pose, exposure_s, key=(step, 1024 * attempt + 32 * entry + f),
                           source_radiance=source)
        s = self.settings
        return check_frame(frame.pixels, shape=(s.height, s.width), saturation=s.saturation,
                           name=f"frame ({exposure_s:g} s)")

    def _measure(self, exposure_s: float, frames: int, step: int, attempt: int) -> Reading:
        s, c = self.settings, self.cfg.sim.camera
        pose = self.pose_deg()
        if pose[0] >= 90.0 or pose[2] >= 90.0:
            raise FrameError(f"pose θi = {pose[0]:.2f}°, θo = {pose[2]:.2f}°: the camera sees the patch "
                             "only from above the horizon")
        source = float(self._light.radiance())
        mask = self.region(pose[2], pose[3])
        if int(mask.sum()) < 2:
            raise FrameError(f"the sample region holds {int(mask.sum())} pixel(s) after eroding "
                             f"{c.erode_px} px: move the camera closer or narrow its field of view")
        t0 = self._clock.now()
        total_s = 0.0
        if c.auto_exposure and source > 0.0:
            probe = self._frame(pose, exposure_s, step, attempt, _PROBE, 0, source)
            total_s += exposure_s
            exposure_s = auto_exposure(probe, exposure_s, saturation=s.saturation, black_level=s.black_level,
                                       mask=mask, limits_s=(1e-6, 3600.0))
        if c.brackets:
            times = [exposure_s * b for b in c.brackets]
            shots = [self._frame(pose, t, step, attempt, j, 0, source) for j, t in enumerate(times)]
            total_s += sum(times)
            rate, _ = merge_brackets(shots, times, saturation=s.saturation, black_level=s.black_level)
            mean, se, n = region_mean(rate, mask)
            mean, se = mean * exposure_s, se * exposure_s
            saved = shots[0]
        else:
            shots = [self._frame(pose, exposure_s, step, attempt, 0, f, source) for f in range(frames)]
            total_s += exposure_s * frames
            saved = np.mean(shots, axis=0) if frames > 1 else shots[0]
            sat = (np.asarray(saved) >= s.saturation).any(axis=2) & mask
            if sat.any():
                raise FrameError(f"frame ({exposure_s:g} s): {int(sat.sum())} of {int(mask.sum())} pixels of "
                                 "the sample region are saturated; shorten the exposure, or use "
                                 "auto_exposure or brackets")
            mean, se, n = region_mean(saved, mask, black_level=s.black_level)
        self._clock.sleep(total_s)
        meta = {"theta_i_deg": pose[0], "phi_i_deg": pose[1], "theta_o_deg": pose[2], "phi_o_deg": pose[3],
                "exposure_s": exposure_s, "key": [step, attempt], "target": self._target,
                "black_level": s.black_level,
                "saturation": None if math.isinf(s.saturation) else s.saturation,
                "brackets": list(c.brackets), "frames": frames,
                "camera": {k: v for k, v in s.as_dict().items() if k != "saturation"}}
        extra = {"target": self._target, "pose_deg": list(pose), "region_pixels": n, "t_s": t0,
                 "key": [step, attempt], "exposures_s": [exposure_s * b for b in c.brackets] or [exposure_s]}
        if c.save_frames:
            extra["frame"] = Frame(np.asarray(saved, np.float32), meta)
        return Reading(signal=np.asarray(mean, float), stderr=np.asarray(se, float), exposure_s=exposure_s,
                       frames=frames, extra=extra)
