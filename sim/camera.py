"""A simulated camera on the detector arm: what an imaging detector sees of the lit sample, rendered in
Dr.Jit.

Scene (sample frame, metres; +z the sample normal). The sample is a flat square patch of side
``sample_size_m`` centred at the origin, edges along x and y, with its material; everything else is
black (a dark surround). The light is a disc of radiance ``radiance`` facing the sample, centred at
``light_distance_m`` · ωi, of radius such that it subtends ``light_half_angle_deg`` from the patch
centre (the cone the point detector's source has). The camera is a pinhole at ``distance_m`` · ωo looking
at the origin, with a vertical field of view ``fov_deg``; image up is the direction of decreasing θ
(toward the sample normal), so the patch appears upright for every pose.

Per pixel, ``samples_per_pixel`` primary rays jittered over the pixel; each that hits the patch at P picks
a point Q uniform on the light disc and scores the one-sample estimate of the reflected radiance

    L(P → camera) = L_src ∫_disc f_r(ωi', ωo') cos θi' dω  ≈  L_src f_r cos θi' cos θ_Q A / |Q − P|²,

ωi' = (Q − P)/|Q − P|, ωo' toward the pinhole, θ_Q the angle at the disc, A its area. A pixel is the mean
of its samples (a ray off the patch scores 0), so pixels along the patch's edges hold a partial coverage.

Sensor. value = L · exposure_s · v (v = cos⁴ of the ray's angle to the optical axis with ``vignetting``,
else 1), then shot noise (Poisson on ``shot_counts_per_unit`` counts per unit), read noise (Gaussian,
σ = ``read_sigma``), plus ``black_level``, clipped at ``saturation`` (the full-scale reading). Frames are
float32 HDR arrays (H, W, 3) in signal units, like the point detector's readings.

Seeding, as in :mod:`gonio.sim.detector`: a frame keyed (step, attempt) draws every random number from
streams named by ``np.random.SeedSequence([seed, stream, step, attempt])``: a Philox4x32 keyed by the
render stream's state, with counters (sample, pixel), so every lane is an independent draw, and a numpy
generator for the sensor noise. The same key gives the same frame bit for bit on one backend.

Backends: one kernel, built from the array types of the backend chosen at run time
(:func:`gonio.jit.resolve_backend`: ``"llvm"``, or ``"cuda"`` when a CUDA device is present). Pose, light
and seed are opaque: new poses and keys reuse the compiled kernel.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, fields
from functools import lru_cache

import drjit as dr
import numpy as np

from gonio.frames import Frame
from gonio.jit import array_types, resolve_backend
from gonio.sim.aperture import seed_state

__all__ = ["CameraSettings", "SimCamera"]

_RENDER_STREAM, _NOISE_STREAM = 10, 11


@lru_cache(maxsize=32)
def _settings_dict(settings: CameraSettings) -> dict:
    return {f.name: getattr(settings, f.name) for f in fields(settings)}


@dataclass(frozen=True)
class CameraSettings:
    """Geometry, light and sensor of the simulated camera (lengths in m, angles in °).

    Attributes
    ----------
    width, height : int
        Image size in pixels, each in [1, 8192].
    fov_deg : float
        Full vertical field of view, in (0, 120).
    distance_m : float
        Pinhole to sample centre, > 0.
    sample_size_m : float
        Side of the square sample patch, > 0.
    light_distance_m : float
        Light disc centre to sample centre, > 0.
    light_half_angle_deg : float
        Half-angle the light disc subtends from the sample centre, in (0, 10].
    radiance : float
        Radiance of the light disc (arbitrary but consistent units), > 0.
    samples_per_pixel : int
        Monte Carlo samples per pixel, in [1, 4096].
    vignetting : bool
        Apply the natural cos⁴ fall-off toward the image corners.
    black_level, read_sigma, shot_counts_per_unit : float
        Sensor offset, read noise σ (signal units) and counts per signal unit for shot noise (0: none).
    saturation : float
        Full-scale reading (signal units, black level included): values clip here. inf: never.
    """

    width: int = 256
    height: int = 256
    fov_deg: float = 12.0
    distance_m: float = 0.5
    sample_size_m: float = 0.05
    light_distance_m: float = 1.0
    light_half_angle_deg: float = 0.5
    radiance: float = 1000.0
    samples_per_pixel: int = 16
    vignetting: bool = False
    black_level: float = 0.0
    read_sigma: float = 0.0
    shot_counts_per_unit: float = 0.0
    saturation: float = math.inf

    def as_dict(self) -> dict:
        """The settings as a new dict, field name to value (each a scalar): what a frame's metadata
        carries (made once per settings, not per frame as ``dataclasses.asdict``'s deep copy was)."""
        return dict(_settings_dict(self))

    def __post_init__(self):
        for name, lo, hi in (("width", 1, 8192), ("height", 1, 8192), ("samples_per_pixel", 1, 4096)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or not lo <= v <= hi:
                raise ValueError(f"camera.{name}: must be an integer in [{lo}, {hi}], got {v!r}")
        checks = (("fov_deg", 0.0, 120.0, True), ("light_half_angle_deg", 0.0, 10.0, False))
        for name, lo, hi, hi_open in checks:
            v = float(getattr(self, name))
            if not (lo < v and (v < hi if hi_open else v <= hi)):
                bracket = ")" if hi_open else "]"
                raise ValueError(f"camera.{name}: must be in ({lo:g}, {hi:g}{bracket} °, got {v!r}")
        for name in ("distance_m", "sample_size_m", "light_distance_m", "radiance", "saturation"):
            v = float(getattr(self, name))
            if not v > 0.0:
                raise ValueError(f"camera.{name}: must be > 0, got {v!r}")
        for name in ("black_level", "read_sigma", "shot_counts_per_unit"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"camera.{name}: must be finite and >= 0, got {v!r}")
        if self.saturation <= self.black_level:
            raise ValueError(f"camera.saturation: must exceed black_level ({self.black_level:g}), "
                             f"got {self.saturation!r}")
        half_diag = self.sample_size_m / math.sqrt(2.0)
        for name in ("distance_m", "light_distance_m"):
            if getattr(self, name) <= 2.0 * half_diag:
                raise ValueError(f"camera.{name}: must exceed the sample's diagonal ({2 * half_diag:g} m), "
                                 f"got {getattr(self, name)!r}")


def _unit(theta_deg: float, phi_deg: float) -> np.ndarray:
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def _tangents(theta_deg: float, phi_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """(e_θ, e_φ): unit tangents of increasing θ and φ, defined at θ = 0 too (by φ)."""
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return (np.array([math.cos(t) * math.cos(p), math.cos(t) * math.sin(p), -math.sin(t)]),
            np.array([-math.sin(p), math.cos(p), 0.0]))


def _check_pose(theta_i_deg, phi_i_deg, theta_o_deg, phi_o_deg) -> tuple[float, float, float, float]:
    pose = tuple(float(v) for v in (theta_i_deg, phi_i_deg, theta_o_deg, phi_o_deg))
    for name, v in zip(("theta_i_deg", "theta_o_deg"), (pose[0], pose[2]), strict=True):
        if not 0.0 <= v < 90.0:
            raise ValueError(f"{name}: must be in [0°, 90°), got {v!r}")
    for name, v in zip(("phi_i_deg", "phi_o_deg"), (pose[1], pose[3]), strict=True):
        if not math.isfinite(v):
            raise ValueError(f"{name}: must be finite, got {v!r}")
    return pose


def _radiance(s: CameraSettings, material, t, params, o, f, r, u, lc, la, lb, lw, half, scale, key, word):
    """The mean pixel radiance (Array3f, one lane per pixel, row-major) of :meth:`SimCamera.radiance` from
    its opaque inputs: camera origin and frame (o, f, r, u), light centre, disc axes and direction (lc, la,
    lb, lw), the patch's half side, the light's radiance scale and the Philox key and word; ``params``: the
    material's :meth:`~gonio.sim.materials.Material.dr_parameters` (None: ``eval_dr``)."""
    Float, UInt32, Array3f = t.Float, t.UInt32, t.Array3f
    spp, n_pix = s.samples_per_pixel, s.width * s.height
    pixel = dr.arange(UInt32, n_pix)
    px, py = Float(pixel % s.width), Float(pixel // s.width)

    def one_sample(j):
        # Lane (sample j, pixel) draws from the Philox counter (j, pixel, word, 0) under the key.
        u1, u2, u3, u4 = t.Philox4x32(key, j, pixel, word).next_float32x4()
        x = (px + u1) * (2.0 / s.width) - 1.0
        y = 1.0 - (py + u2) * (2.0 / s.height)
        d = dr.normalize(f + x * r + y * u)
        p = o + (-o.z / d.z) * d
        on_patch = (d.z < 0) & (dr.abs(p.x) <= half) & (dr.abs(p.y) <= half)
        # A uniform point on the light disc (polar mapping: √u3 for uniform area).
        rad = dr.sqrt(u3)
        sin_p, cos_p = dr.sincos(2.0 * dr.pi * u4)
        to_light = lc + (rad * cos_p) * la + (rad * sin_p) * lb - p
        dist2 = dr.squared_norm(to_light)
        wi_s = to_light * dr.rsqrt(dist2)
        wo_s = dr.normalize(o - p)
        weight = scale * dr.maximum(wi_s.z, 0.0) * dr.maximum(dr.dot(wi_s, lw), 0.0) / dist2
        if s.vignetting:
            weight = weight * dr.square(dr.square(dr.dot(d, f)))
        fr = material.eval_dr(wi_s, wo_s) if params is None else material.eval_with(wi_s, wo_s, params)
        return dr.select(on_patch, fr * weight, 0.0)

    # One lane per pixel, its samples in a symbolic loop: one kernel, no per-sample buffers.
    def body(j, acc):
        return j + 1, acc + one_sample(j)

    _, total = dr.while_loop((UInt32(0), Array3f(0.0)), lambda j, acc: j < spp, body)
    return total * (1.0 / spp)


class SimCamera:
    """A simulated imaging detector (see the module docstring).

    Parameters
    ----------
    settings : CameraSettings
        Geometry, light and sensor.
    material
        A :mod:`gonio.sim.materials` material (``eval_dr(wi, wo)`` on Dr.Jit 3-vectors, RGB, sr⁻¹).
    seed : int
        Campaign seed, >= 0; with each frame's key it names every random number drawn.
    backend : {"llvm", "cuda"}, optional
        Dr.Jit backend; default :func:`gonio.jit.resolve_backend` (``GONIO_BACKEND``, else CUDA when
        present, else LLVM).
    """

    def __init__(self, settings: CameraSettings, material, *, seed: int = 0, backend: str | None = None):
        if not isinstance(seed, int | np.integer) or isinstance(seed, bool) or seed < 0:
            raise ValueError(f"seed: must be an integer >= 0, got {seed!r}")
        self.settings = settings
        self.material = material
        self.seed = int(seed)
        self.backend = resolve_backend(backend)
        self._t = array_types(self.backend)
        self._count = 0
        # The pixel radiance as a frozen Dr.Jit function (drjit.freeze): the first frame traces and
        # records the kernel, later frames replay it with new inputs (pose, light, key), the same kernel,
        # so the same values bit for bit, without tracing it again in Python (tools/bench_camera.py).
        # A material without eval_with (not a gonio Material) is traced on every frame.
        self._frozen = None
        if hasattr(material, "eval_with"):
            t = self._t

            def radiance(params, *inputs):
                return _radiance(settings, material, t, params, *inputs)
            self._frozen = (dr.freeze(radiance), threading.Lock())

    # -- geometry ---------------------------------------------------------------------------------
    def _camera_frame(self, theta_o_deg, phi_o_deg):
        s = self.settings
        wo = _unit(theta_o_deg, phi_o_deg)
        e_theta, _ = _tangents(theta_o_deg, phi_o_deg)
        forward = -wo
        up = -e_theta
        right = np.cross(forward, up)
        tan_half = math.tan(math.radians(0.5 * s.fov_deg))
        return s.distance_m * wo, forward, right * tan_half * s.width / s.height, up * tan_half

    def sample_mask(self, theta_o_deg: float, phi_o_deg: float) -> np.ndarray:
        """Pixels whose centre ray hits the sample patch, shape (H, W), bool (numpy, exact geometry)."""
        s = self.settings
        _check_pose(0.0, 0.0, theta_o_deg, phi_o_deg)
        origin, f, r, u = self._camera_frame(theta_o_deg, phi_o_deg)
        x = (np.arange(s.width) + 0.5) / s.width * 2.0 - 1.0
        y = 1.0 - (np.arange(s.height) + 0.5) / s.height * 2.0
        d = f + x[None, :, None] * r + y[:, None, None] * u
        t = -origin[2] / d[..., 2]
        p = origin + t[..., None] * d
        half = 0.5 * s.sample_size_m
        return (d[..., 2] < 0) & (np.abs(p[..., 0]) <= half) & (np.abs(p[..., 1]) <= half)

    # -- rendering --------------------------------------------------------------------------------
    def radiance(self, theta_i_deg: float, phi_i_deg: float, theta_o_deg: float, phi_o_deg: float,
                 seed_state: tuple[int, int] = (0, 0), source_radiance: float | None = None) -> np.ndarray:
        """Noise-free pixel radiance, (H, W, 3) float32, with the Philox (key, word) ``seed_state``.

        Vignetting (when on) is included: this is what reaches the sensor per unit exposure.
        ``source_radiance`` (>= 0) replaces ``settings.radiance`` (a drifting lamp; 0: shutter closed).
        """
        pose = _check_pose(theta_i_deg, phi_i_deg, theta_o_deg, phi_o_deg)
        s, t = self.settings, self._t
        source = s.radiance if source_radiance is None else float(source_radiance)
        if not (math.isfinite(source) and source >= 0.0):
            raise ValueError(f"source_radiance: must be finite and >= 0, got {source_radiance!r}")
        if source == 0.0:
            return np.zeros((s.height, s.width, 3), np.float32)
        Float, UInt32, UInt64, Array3f = t.Float, t.UInt32, t.UInt64, t.Array3f
        origin, fwd, right, up = self._camera_frame(pose[2], pose[3])
        wi = _unit(pose[0], pose[1])
        light_a, light_b = _tangents(pose[0], pose[1])
        tan_a = math.tan(math.radians(s.light_half_angle_deg))
        light_r = s.light_distance_m * tan_a

        def vec(v):
            return Array3f(*(dr.opaque(Float, float(c)) for c in v))

        inputs = (vec(origin), vec(fwd), vec(right), vec(up), vec(s.light_distance_m * wi),
                  vec(light_a * light_r), vec(light_b * light_r), vec(wi),
                  dr.opaque(Float, 0.5 * s.sample_size_m),
                  dr.opaque(Float, source * math.pi * light_r * light_r),
                  dr.opaque(UInt64, seed_state[0]), dr.opaque(UInt32, seed_state[1]))
        if self._frozen is not None:   # a Material: its parameters are inputs of the frozen kernel
            with self._frozen[1]:      # a frozen function keeps its recordings in itself: one call at a time
                value = self._frozen[0](self.material.dr_parameters(Array3f), *inputs)
                return self._to_numpy(value)
        return self._to_numpy(_radiance(s, self.material, t, None, *inputs))

    def _to_numpy(self, value) -> np.ndarray:
        s = self.settings
        dr.eval(value)
        return np.stack([np.asarray(c.numpy(), dtype=np.float32) for c in (value.x, value.y, value.z)],
                        axis=-1).reshape(s.height, s.width, 3)

    def render(self, theta_i_deg: float, phi_i_deg: float, theta_o_deg: float, phi_o_deg: float,
               exposure_s: float, *, key: tuple[int, int] | None = None,
               source_radiance: float | None = None) -> Frame:
        """One frame of the sample at a pose (°), through the sensor.

        Parameters
        ----------
        theta_i_deg, phi_i_deg, theta_o_deg, phi_o_deg : float
            Light and camera directions (°), θ in [0, 90).
        exposure_s : float
            Exposure (s), in (0, 3600].
        key : (int, int), optional
            (step, attempt), each >= 0: the frame's random numbers come from streams keyed by (seed,
            step, attempt). Without it, by this camera's frame number (reproducible in one process).
        source_radiance : float, optional
            The light's radiance now (>= 0; 0: shutter closed, a dark frame); default
            ``settings.radiance``.

        Returns
        -------
        gonio.frames.Frame
            ``pixels`` (H, W, 3) float32 in signal units; ``metadata`` with the pose (°), exposure (s),
            key, seed, backend, and the settings.
        """
        exposure_s = float(exposure_s)
        if not 0.0 < exposure_s <= 3600.0:
            raise ValueError(f"exposure_s: must be in (0, 3600] s, got {exposure_s!r}")
        if key is None:
            a, b = self._count, 1 << 31
        else:
            ok = isinstance(key, tuple | list) and len(key) == 2 and all(
                isinstance(k, int | np.integer) and not isinstance(k, bool) and k >= 0 for k in key)
            if not ok:
                raise ValueError(f"key: must be (step, attempt), two integers >= 0, got {key!r}")
            a, b = int(key[0]), int(key[1])
        self._count += 1
        s = self.settings
        pose = _check_pose(theta_i_deg, phi_i_deg, theta_o_deg, phi_o_deg)
        clean = self.radiance(*pose, seed_state=seed_state(self.seed, _RENDER_STREAM, a, b),
                              source_radiance=source_radiance)
        if s.shot_counts_per_unit > 0.0 or s.read_sigma > 0.0:
            signal = clean.astype(np.float64) * exposure_s
            rng = np.random.default_rng(np.random.SeedSequence([self.seed, _NOISE_STREAM, a, b]))
            if s.shot_counts_per_unit > 0.0:
                signal = rng.poisson(signal * s.shot_counts_per_unit) / s.shot_counts_per_unit
            if s.read_sigma > 0.0:
                signal = signal + rng.normal(0.0, s.read_sigma, size=signal.shape)
        else:  # noise-free: stay in float32, in place
            signal = clean
            signal *= np.float32(exposure_s)
        signal += s.black_level
        signal = np.minimum(signal, s.saturation, dtype=np.float32)
        meta = {"theta_i_deg": pose[0], "phi_i_deg": pose[1], "theta_o_deg": pose[2], "phi_o_deg": pose[3],
                "exposure_s": exposure_s, "key": None if key is None else [a, b], "seed": self.seed,
                "backend": self.backend, "black_level": s.black_level, "saturation": s.saturation,
                "camera": s.as_dict()}
        return Frame(signal, meta)

