"""A simulated detector: the reflected radiance at the gantry's actual pose, rendered in Dr.Jit, plus
a linear sensor's noise.

Optics. The source subtends a cone of half-angle α_s around ωi and the detector sees a cone of half-angle
α_d around ωo. The detector measures the reflected radiance

    L = L_src ∫_{source cone} f_r(ωi', ωo') cos θi' dωi',   averaged uniformly over ωo' in the detector cone,

estimated by Monte Carlo: ``aperture_samples`` pairs (ωi', ωo') per pose, each uniform in its cone
(cos θ uniform in [cos α, 1] about the cone's axis), so L ≈ L_src · Ω_s · mean(f_r · cos θi'), with
Ω_s = 2π(1 − cos α_s). All poses of a batch are one Dr.Jit launch, which also returns the standard
error of each pose's mean, Ω_s · s/√n from the sample variance s² of f_r · cos θi' over its n samples
(sums and sums of squares accumulated in float64, so the variance survives the cancellation).

Sensor. signal = L · exposure_s (linear), plus ``dark_offset · exposure_s``; shot noise is Poisson on
``signal · shot_counts_per_unit`` counts, converted back to signal units; read noise is Gaussian with
σ = ``read_sigma`` per frame. Each is off when its setting is zero. All frames of one reading see the
same aperture samples (the pose does not change during a reading): only the sensor noise differs
between frames.

Motion. Given ``motion`` (a function from clock times to the axes' positions then: the trajectories of
an emulated gantry's servos), a reading whose axes move during the integration integrates over that
motion instead of taking the pose at its start: ``MOTION_TIMES`` times stratified uniformly over the
integration (one uniform draw in each of equal slices), the axes put where ``motion`` has them, turned
into directions by the forward kinematics and rendered with ``aperture_samples / MOTION_TIMES`` aperture
pairs each (as many Monte Carlo lanes as a still reading), the factors averaged. The light's radiance is
the one at the start. A still gantry (every time at the start pose) takes the still path, unchanged.
With ``track_motion`` (real axes seen through their read-backs: a dry run on hardware, see
:mod:`gonio.wiring`) and no ``motion`` given, the detector reads the axes again when the integration
ends and integrates along the straight line between the two read-backs, stamped when each was asked:
during a fly sweep the servo runs at constant speed, so the line is the path; a still gantry reads the
same twice and takes the still path.

Uncertainty. A reading's ``stderr`` is the standard error of its ``signal`` from both sources, added in
quadrature: the integration error L_src · Ω_s · s/√n · exposure_s (shared by all frames, so averaging
frames does not shrink it), and the sensor's, the spread of the frames over √frames (frames > 1) or the
noise model's σ (one frame cannot estimate its own spread).

Seeding. Every random number of a reading comes from streams named by ``np.random.SeedSequence([seed,
stream, a, b])``: the aperture samples from a Philox4x32 keyed by that stream's state, with counters
(sample, pose) so that every Monte Carlo lane is an independent draw, and the sensor noise from a numpy
generator. For ``measure(..., key=(step, attempt))``, (a, b) = (step, attempt): the same reading of
the same campaign is bit-identical whatever the process did before it, so a campaign resumed from its
journal in a new process replays an uninterrupted one, and a retried step draws fresh samples. Without
a key, (a, b) = (n, 0) on separate streams, n the number of readings this detector object has taken
(keyed or not) since it was built: reproducible within one process only. ``expected_signal`` has its
own fixed stream, so it returns the same values on every call.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import drjit as dr
import numpy as np
from drjit.llvm import Array3f, Array3f64, Float, Philox4x32, UInt32, UInt64

from gonio.config import DetectorConfig
from gonio.protocols import Clock, DeviceFault, Reading

__all__ = ["SimDetector", "TARGETS", "MOTION_TIMES", "aperture_radiance_factor"]

#: What can be under the beam: the sample, or the white reference standard.
TARGETS = ("sample", "reference")
#: Seed-sequence streams: one per use, so a call of one kind never shifts the samples of another.
#: Keyed readings, ``expected_signal``, and readings without a key (by reading number) each have their
#: own: SeedSequence pads short entropy with zeros, so [s, 0, n] would alias the key (n, 0).
_MC_STREAM, _NOISE_STREAM, _EXPECTED_STREAM, _MC_COUNTER_STREAM, _NOISE_COUNTER_STREAM = 0, 1, 2, 3, 4
#: The stratified times of a reading integrated over the motion (``motion``) draw from this stream.
_MOTION_STREAM = 5
#: Times per reading at which a moving gantry is sampled (stratified over the integration).
MOTION_TIMES = 16
#: Above this many expected counts numpy's Poisson sampler is replaced by its Gaussian limit.
_POISSON_MAX = 1e15


def _cone_directions(axis: Array3f, one_minus_cos_max: Float, u1: Float, u2: Float) -> Array3f:
    """Directions uniform in solid angle within a cone around the unit vector(s) ``axis``."""
    # w = 1 − cos θ is uniform in [0, 1 − cos α]; sin θ from w keeps float32 precision for tiny cones.
    w = u1 * one_minus_cos_max
    cos_t = 1.0 - w
    sin_t = dr.safe_sqrt(w * (2.0 - w))
    sin_p, cos_p = dr.sincos(2.0 * dr.pi * u2)
    # Orthonormal basis around the axis without a branch (Duff et al. 2017, JCGT 6(1)).
    n = axis
    sign = dr.copysign(1.0, n.z)
    a = -1.0 / (sign + n.z)
    b = n.x * n.y * a
    s = Array3f(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x)
    t = Array3f(b, sign + n.y * n.y * a, -n.y)
    return s * (sin_t * cos_p) + t * (sin_t * sin_p) + n * cos_t


def aperture_directions(wi: np.ndarray, wo: np.ndarray, source_half_angle_deg: float,
                        detector_half_angle_deg: float, samples: int, seed_state: tuple[int, int]):
    """The Monte Carlo directions of :func:`aperture_radiance_factor`: ``samples`` pairs (ωi', ωo') per
    pose, uniform in the source and detector cones, as Dr.Jit Array3f (N·samples lanes, pose-major).
    Lane (j, p) draws from the Philox4x32 counter (j, p, word, 0) under the key of ``seed_state``."""
    n = wi.shape[0]
    key, word = seed_state
    om_src = 1.0 - np.cos(np.radians(source_half_angle_deg))
    om_det = 1.0 - np.cos(np.radians(detector_half_angle_deg))
    lane = dr.arange(UInt32, n * samples)
    pose = lane // samples
    # Both axes of every pose in one buffer, (N, 6) row-major: one input whatever N.
    axes = Float(np.ascontiguousarray(np.hstack([wi, wo]), dtype=np.float32).ravel())
    wi_c = dr.gather(Array3f, axes, 2 * pose)
    wo_c = dr.gather(Array3f, axes, 2 * pose + 1)
    # A counter-based generator keyed per reading: lane (j, p) is the cipher of its own counter, so
    # neighbouring lanes are independent (PCG32 seeded with state + k, seq + k per lane is not: its
    # error came out up to 1.3x the independent-sample figure). Opaque key and apertures: a new
    # reading must not compile a new kernel.
    rng = Philox4x32(dr.opaque(UInt64, key), lane - pose * samples, pose, dr.opaque(UInt32, word))
    u1, u2, u3, u4 = rng.next_float32x4()
    wi_s = _cone_directions(wi_c, dr.opaque(Float, om_src), u1, u2)
    wo_s = _cone_directions(wo_c, dr.opaque(Float, om_det), u3, u4)
    return wi_s, wo_s


def _straight(t0: float, a_deg: np.ndarray, t1: float, b_deg: np.ndarray):
    """``motion(times)`` along the straight line from ``a_deg`` at ``t0`` to ``b_deg`` at ``t1``."""
    a = np.asarray(a_deg, dtype=np.float64)
    d = np.asarray(b_deg, dtype=np.float64) - a

    def motion(times) -> np.ndarray:
        return a + ((np.asarray(times, dtype=np.float64) - t0) / (t1 - t0))[:, None] * d
    return motion


def aperture_radiance_factor(material, wi: np.ndarray, wo: np.ndarray, source_half_angle_deg: float,
                             detector_half_angle_deg: float, samples: int,
                             seed_state: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Reflected radiance per unit source radiance and its Monte Carlo standard error, for many poses
    in one Dr.Jit launch.

    Parameters
    ----------
    material
        Has ``eval_dr(wi, wo) -> Array3f``: f_r in sr⁻¹ (0 below the horizon), sample frame.
    wi, wo : ndarray, shape (N, 3)
        Unit vectors (sample frame) toward the centre of the source and of the detector's field.
    source_half_angle_deg, detector_half_angle_deg : float
        Half-angles (°) of the cone the source subtends and of the cone the detector sees.
    samples : int
        Monte Carlo samples per pose, >= 2 (one sample cannot estimate its own error).
    seed_state : (int, int)
        A 64-bit Philox4x32 key and a 32-bit stream word. Sample j of pose p draws its four uniforms
        from the counter (j, p, word, 0) under that key: every lane is an independent draw, and the
        same (key, word) gives pose p the same samples in any batch.

    Returns
    -------
    factor : ndarray, shape (N, 3)
        Ω_s · mean(f_r(ωi', ωo') · cos θi') per pose: L / L_src, dimensionless (sr⁻¹ · sr).
    stderr : ndarray, shape (N, 3)
        Ω_s · s / √samples, s² the sample variance of f_r · cos θi' over the pose's samples: the
        standard error of ``factor`` from the integration alone.
    """
    wi = np.asarray(wi, dtype=np.float64).reshape(-1, 3)
    wo = np.asarray(wo, dtype=np.float64).reshape(-1, 3)
    if isinstance(samples, bool) or not isinstance(samples, int | np.integer) or not 2 <= samples <= 1 << 20:
        raise ValueError(f"samples: must be an integer in [2, {1 << 20}], got {samples!r}")
    key, word = _check_seed_state(seed_state)
    n = wi.shape[0]
    if n == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    if wo.shape[0] != n:
        raise ValueError(f"wo: expected {n} directions like wi, got {wo.shape[0]}")
    samples = int(samples)
    om_src = 1.0 - np.cos(np.radians(source_half_angle_deg))
    wi_s, wo_s = aperture_directions(wi, wo, source_half_angle_deg, detector_half_angle_deg, samples,
                                     (key, word))
    fr_cos = material.eval_dr(wi_s, wo_s) * dr.maximum(wi_s.z, 0.0)
    # float64 sums: Σx² − (Σx)²/n cancels down to the variance, which can be ~1e-10 of the squared
    # mean (a Lambertian in a 0.5° cone), far below float32's resolution: float32 sums gave 100x the
    # true error there (tools/bench_detector.py).
    x = Array3f64(fr_cos)
    x2 = x * x
    dr.eval(x, x2)  # one kernel for the samples; the block sums then only read memory
    s1, s2 = (np.stack([np.asarray(s, dtype=np.float64) for s in dr.block_sum(v, samples)], axis=1)
              for v in (x, x2))
    mean = s1 / samples
    # Rounding can leave a zero variance (a constant integrand) a hair below zero.
    var = np.maximum(s2 - s1 * mean, 0.0) / (samples - 1)
    omega = 2.0 * np.pi * om_src
    return omega * mean, omega * np.sqrt(var / samples)


class SimDetector:
    """A simulated detector satisfying :class:`gonio.protocols.Detector`.

    Parameters
    ----------
    cfg : gonio.config.DetectorConfig
        Channels (must be 3: the materials are RGB), field half-angle (°), aperture samples, noise.
    light : gonio.sim.light.SimLight
        The source: its radiance now (0 with the shutter closed) and its half-angle (°).
    axes : Mapping[str, gonio.sim.axis.SimAxis]
        The gantry's axes; their *actual* shaft angles (``true_position_deg``), never the commanded
        ones, give the pose.
    kinematics
        ``axis_names`` and ``directions(axes_deg (N, n_axes)) -> (wi, wo)``.
    materials : Mapping[str, material]
        The material for each of :data:`TARGETS`.
    clock : gonio.protocols.Clock
        ``measure`` advances it by the integration time, exposure_s × frames.
    seed : int
        Campaign seed, >= 0: with the key of each reading it names every random number drawn (see the
        module docstring).
    name : str
        Device name used in messages.
    """

    def __init__(self, cfg: DetectorConfig, *, light, axes: Mapping, kinematics, materials: Mapping,
                 clock: Clock, seed: int = 0, name: str = "detector", track_motion: bool = False):
        if len(cfg.channels) != 3:
            raise ValueError(
                f"detector.channels: the simulated detector renders RGB materials and needs exactly "
                f"3 channels, got {len(cfg.channels)} ({', '.join(cfg.channels)})"
            )
        missing = [t for t in TARGETS if t not in materials]
        if missing:
            raise ValueError(f"materials: missing a material for {', '.join(missing)}")
        missing = [a for a in kinematics.axis_names if a not in axes]
        if missing:
            raise ValueError(f"axes: missing the axes {', '.join(missing)} that the kinematics drives")
        if not isinstance(seed, int | np.integer) or seed < 0:
            raise ValueError(f"seed: must be an integer >= 0, got {seed!r}")
        if cfg.sim.aperture_samples < 2:
            raise ValueError(
                f"detector.aperture_samples: the simulated detector needs at least 2 to estimate its "
                f"integration error, got {cfg.sim.aperture_samples}"
            )
        self.name = name
        self.channels = tuple(cfg.channels)
        self.cfg = cfg
        self._light = light
        self._axes = axes
        self._kinematics = kinematics
        self._materials = dict(materials)
        self._clock = clock
        self._seed = int(seed)
        self._track_motion = bool(track_motion)
        self._count = 0
        self._target = "sample"
        self._connected = False

    # -- the Detector protocol ----------------------------------------------------------------------
    def connect(self) -> None:
        self._connected = True

    def close(self) -> None:
        self._connected = False

    def measure(self, exposure_s: float, frames: int = 1, *,
                key: tuple[int, int] | None = None,
                motion: Callable[[np.ndarray], np.ndarray] | None = None) -> Reading:
        """Integrate ``frames`` frames of ``exposure_s`` seconds each at the current pose.

        The pose and the source radiance are those at the start of the integration; the clock then
        advances by exposure_s × frames. With ``motion``, a pose that moves during the integration is
        integrated over (see the module docstring).

        Parameters
        ----------
        exposure_s : float
            Exposure of each frame (s), in (0, 3600].
        frames : int
            Frames to average, in [1, 1000]. They share the reading's aperture samples.
        key : (int, int), optional
            (step, attempt), both >= 0: the aperture samples and the sensor noise come from streams
            keyed by (seed, step, attempt), so the reading does not depend on anything this process
            did before. Without it the streams are keyed by this detector's reading number.
        motion : callable, optional
            ``motion(times) -> positions``: clock times (K,) to axis positions (K, n_axes), in
            ``kinematics.axis_names`` order (an emulated gantry's servo trajectories).

        Returns
        -------
        Reading
            ``signal``: mean over the frames per channel (signal units). ``stderr``: its standard
            error, the integration (Monte Carlo) error and the sensor's added in quadrature. The
            sensor's is the spread of the frames over √frames when frames > 1 (it measures only the
            sensor noise: every frame has the same aperture samples), or for a single frame the
            standard deviation the noise model predicts (one frame cannot estimate its own spread).
            ``extra`` holds the target, the actual axis positions (°), the start time (s), the
            reading number, the key, and the two parts of ``stderr`` (``stderr_integration``,
            ``stderr_sensor``).
        """
        self._require_connected()
        exposure_s = _check_exposure(exposure_s)
        if isinstance(frames, bool) or not isinstance(frames, int | np.integer) or not 1 <= frames <= 1000:
            raise ValueError(f"frames: must be an integer in [1, 1000], got {frames!r}")
        key = _check_key(key)
        t0 = self._clock.now()
        axes_deg = self.actual_axes_deg()
        source = self._light.radiance()
        n = self._count
        self._count += 1
        if key is None:
            mc_id, noise_id = (_MC_COUNTER_STREAM, n, 0), (_NOISE_COUNTER_STREAM, n, 0)
        else:
            mc_id, noise_id = (_MC_STREAM, *key), (_NOISE_STREAM, *key)
        path = None
        slept = False
        if source > 0.0 and motion is None and self._track_motion:
            # Real axes seen through their read-backs: where they stand at the end too, and the
            # straight line between (a sweep runs at constant speed; a still gantry reads the same).
            self._clock.sleep(exposure_s * frames)
            slept = True
            t1 = self._clock.now()
            end_deg = self.actual_axes_deg()
            if not np.array_equal(end_deg, axes_deg) and t1 > t0:
                motion = _straight(t0, axes_deg, t1, end_deg)
        if source > 0.0 and motion is not None:
            rng_t = np.random.default_rng(np.random.SeedSequence([self._seed, _MOTION_STREAM, *mc_id]))
            frac = (np.arange(MOTION_TIMES) + rng_t.random(MOTION_TIMES)) / MOTION_TIMES
            times = t0 + exposure_s * frames * frac
            path = np.asarray(motion(times), dtype=np.float64).reshape(MOTION_TIMES, -1)
            if np.array_equal(path, np.broadcast_to(axes_deg, path.shape)):
                path = None  # still: the exact still reading
        if path is not None:
            per = max(2, self.cfg.sim.aperture_samples // MOTION_TIMES)
            factors, ses = self._radiance_factor(path, self._target, _seed_state(self._seed, *mc_id), per)
            factor, factor_se = factors.mean(axis=0), np.sqrt((ses**2).sum(axis=0)) / MOTION_TIMES
        elif source > 0.0:
            factor, factor_se = self._radiance_factor(axes_deg[None, :], self._target,
                                                      _seed_state(self._seed, *mc_id))
            factor, factor_se = factor[0], factor_se[0]
        else:
            # Shutter closed: skip the render; no light, no integration error.
            factor = factor_se = np.zeros(len(self.channels))
        clean = source * factor * exposure_s
        rng = np.random.default_rng(np.random.SeedSequence([self._seed, *noise_id]))
        frame_values = self._noisy_frames(clean, exposure_s, int(frames), rng)
        mean = frame_values.mean(axis=0)
        if frames > 1:
            sensor_se = frame_values.std(axis=0, ddof=1) / np.sqrt(frames)
        else:
            sensor_se = self.noise_sigma(clean)
        integration_se = source * factor_se * exposure_s
        stderr = np.hypot(integration_se, sensor_se)
        if not slept:
            self._clock.sleep(exposure_s * frames)
        extra = {"target": self._target, "axes_deg": dict(zip(self._kinematics.axis_names,
                                                              axes_deg.tolist(), strict=True)),
                 "t_s": t0, "reading": n, "key": key, "moving": path is not None,
                 "stderr_integration": integration_se, "stderr_sensor": sensor_se}
        return Reading(signal=mean, stderr=stderr, exposure_s=exposure_s, frames=int(frames), extra=extra)

    def read_on_the_fly(self, exposure_s: float, *, key: tuple[int, int] | None = None) -> Reading:
        """One frame of ``exposure_s`` s while the axes may move (:class:`gonio.protocols.ReadsOnTheFly`):
        it integrates from the request, along the axes' motion where it tracks it."""
        return self.measure(exposure_s, 1, key=key)

    def describe(self) -> dict:
        """What this detector is, for the journal (:class:`gonio.protocols.Describes`)."""
        return {"name": self.name, "driver": "sim", "identity": f"simulated {self.cfg.sim.kind}",
                "firmware": None, "units": "signal", "settings": {"channels": list(self.channels),
                                                                  "seed": self._seed}}

    # -- simulation-only ----------------------------------------------------------------------------
    @property
    def target(self) -> str:
        """What is under the beam: one of :data:`TARGETS`."""
        return self._target

    def set_target(self, target: str) -> None:
        if target not in TARGETS:
            raise ValueError(f"target: {target!r} is not one of {', '.join(repr(t) for t in TARGETS)}")
        self._target = target

    def actual_axes_deg(self) -> np.ndarray:
        """Actual shaft angles (°) of the axes now, in ``kinematics.axis_names`` order."""
        return np.array([self._axes[a].true_position_deg() for a in self._kinematics.axis_names])

    def expected_signal(self, axes_deg, target: str | None = None, exposure_s: float | None = None,
                        ) -> np.ndarray:
        """Noise-free readings for many poses in one Dr.Jit launch: the mean of what ``measure`` gives.

        Parameters
        ----------
        axes_deg : array_like, shape (N, n_axes)
            Axis positions (°), columns in ``kinematics.axis_names`` order.
        target : str, optional
            One of :data:`TARGETS` (default: the current target).
        exposure_s : float, optional
            Exposure (s); default ``cfg.exposure_s``.

        Returns
        -------
        ndarray, shape (N, C)
            (L_src · L/L_src + dark_offset) · exposure_s per channel, with the source radiance now (0
            with the shutter closed). The aperture samples come from this detector's fixed
            ``expected_signal`` stream, so repeated calls return the same values (and pose p of a
            batch gets the same samples whatever the batch).
        """
        self._require_connected()
        target = self._target if target is None else target
        if target not in TARGETS:
            raise ValueError(f"target: {target!r} is not one of {', '.join(repr(t) for t in TARGETS)}")
        exposure_s = _check_exposure(self.cfg.exposure_s if exposure_s is None else exposure_s)
        n_axes = len(self._kinematics.axis_names)
        axes_deg = np.asarray(axes_deg, dtype=np.float64)
        if axes_deg.ndim != 2 or axes_deg.shape[1] != n_axes:
            raise ValueError(f"axes_deg: expected shape (N, {n_axes}), got {axes_deg.shape}")
        source = self._light.radiance()
        dark = self.cfg.sim.noise.dark_offset * exposure_s
        if source == 0.0:
            return np.full((axes_deg.shape[0], len(self.channels)), dark)
        factor, _ = self._radiance_factor(axes_deg, target, _seed_state(self._seed, _EXPECTED_STREAM, 0, 0))
        return source * factor * exposure_s + dark

    def noise_sigma(self, clean_signal) -> np.ndarray:
        """Standard deviation (signal units) of one frame whose noise-free light signal is given."""
        noise = self.cfg.sim.noise
        var = np.full(np.shape(clean_signal), noise.read_sigma**2, dtype=np.float64)
        if noise.shot_counts_per_unit > 0.0:
            var = var + np.asarray(clean_signal, dtype=np.float64) / noise.shot_counts_per_unit
        return np.sqrt(var)

    # -- internals ----------------------------------------------------------------------------------
    def _radiance_factor(self, axes_deg: np.ndarray, target: str, seed_state,
                         samples: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(factor, stderr) per pose of ``axes_deg`` (K, n_axes), ``samples`` aperture pairs each
        (default ``aperture_samples``)."""
        wi, wo = self._kinematics.directions(axes_deg)
        return aperture_radiance_factor(
            self._materials[target], wi, wo, self._light.half_angle_deg, self.cfg.sim.half_angle_deg,
            self.cfg.sim.aperture_samples if samples is None else samples, seed_state,
        )

    def _noisy_frames(self, clean: np.ndarray, exposure_s: float, frames: int, rng) -> np.ndarray:
        noise = self.cfg.sim.noise
        values = np.broadcast_to(clean, (frames, clean.size)).astype(np.float64)
        if noise.shot_counts_per_unit > 0.0:
            counts = values * noise.shot_counts_per_unit
            # numpy's Poisson sampler needs lam < ~1e18; far below that the Gaussian limit is exact.
            big = counts > _POISSON_MAX
            drawn = rng.poisson(np.where(big, 0.0, counts)).astype(np.float64)
            drawn = np.where(big, rng.normal(counts, np.sqrt(counts)), drawn)
            values = drawn / noise.shot_counts_per_unit
        values = values + noise.dark_offset * exposure_s
        if noise.read_sigma > 0.0:
            values = values + rng.normal(0.0, noise.read_sigma, size=values.shape)
        return values

    def _require_connected(self) -> None:
        if not self._connected:
            raise DeviceFault(self.name, "not connected: call connect() first", transient=False)


def _check_exposure(exposure_s) -> float:
    value = float(exposure_s)
    if not 0.0 < value <= 3600.0:
        raise ValueError(f"exposure_s: must be in (0, 3600] s, got {exposure_s!r}")
    return value


def _check_key(key) -> tuple[int, int] | None:
    if key is None:
        return None
    ok = (isinstance(key, tuple | list) and len(key) == 2
          and all(isinstance(k, int | np.integer) and not isinstance(k, bool) and k >= 0 for k in key))
    if not ok:
        raise ValueError(f"key: must be (step, attempt), two integers >= 0, got {key!r}")
    return int(key[0]), int(key[1])


def _check_seed_state(seed_state) -> tuple[int, int]:
    ok = (isinstance(seed_state, tuple | list) and len(seed_state) == 2
          and all(isinstance(k, int | np.integer) and not isinstance(k, bool) for k in seed_state)
          and 0 <= seed_state[0] < 1 << 64 and 0 <= seed_state[1] < 1 << 32)
    if not ok:
        raise ValueError(f"seed_state: must be (key, word), integers in [0, 2**64) and [0, 2**32), "
                         f"got {seed_state!r}")
    return int(seed_state[0]), int(seed_state[1])


def _seed_state(seed: int, stream: int, a: int, b: int) -> tuple[int, int]:
    """The Philox4x32 (key, word) of stream ``stream`` for (a, b): (step, attempt) or (n, 0)."""
    key, word = np.random.SeedSequence([seed, stream, a, b]).generate_state(2, np.uint64)
    return int(key), int(word) >> 32
