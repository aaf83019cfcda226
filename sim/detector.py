"""A simulated detector: the reflected radiance at the gantry's actual pose, rendered in Dr.Jit, plus
a linear sensor's noise.

Optics. The source subtends a cone of half-angle α_s around ωi and the detector sees a cone of half-angle
α_d around ωo. The detector measures the reflected radiance

    L = L_src ∫_{source cone} f_r(ωi', ωo') cos θi' dωi',   averaged uniformly over ωo' in the detector cone,

estimated by Monte Carlo: ``aperture_samples`` pairs (ωi', ωo') per pose, each uniform in its cone
(cos θ uniform in [cos α, 1] about the cone's axis), so L ≈ L_src · Ω_s · mean(f_r · cos θi'), with
Ω_s = 2π(1 − cos α_s). All poses of a batch are one Dr.Jit launch.

Sensor. signal = L · exposure_s (linear), plus ``dark_offset · exposure_s``; shot noise is Poisson on
``signal · shot_counts_per_unit`` counts, converted back to signal units; read noise is Gaussian with
σ = ``read_sigma`` per frame. Each is off when its setting is zero.

Seeding. Reading number n of a detector seeded with s draws its aperture samples (PCG32) and its noise
(numpy) from ``SeedSequence([s, stream, n])``: a campaign replays exactly from its seed, and the
Monte Carlo samples of one reading are independent of every other's.
"""

from __future__ import annotations

from collections.abc import Mapping

import drjit as dr
import numpy as np
from drjit.llvm import PCG32, Array3f, Float, UInt32, UInt64

from gonio.config import DetectorConfig
from gonio.protocols import Clock, DeviceFault, Reading

__all__ = ["SimDetector", "TARGETS", "aperture_radiance_factor"]

#: What can be under the beam: the sample, or the white reference standard.
TARGETS = ("sample", "reference")
#: Seed-sequence streams: one per use, so a call of one kind never shifts the samples of another.
_MC_STREAM, _NOISE_STREAM, _EXPECTED_STREAM = 0, 1, 2
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


def aperture_radiance_factor(material, wi: np.ndarray, wo: np.ndarray, source_half_angle_deg: float,
                             detector_half_angle_deg: float, samples: int,
                             seed_state: tuple[int, int]) -> np.ndarray:
    """Reflected radiance per unit source radiance, for many poses in one Dr.Jit launch.

    Parameters
    ----------
    material
        Has ``eval_dr(wi, wo) -> Array3f``: f_r in sr⁻¹ (0 below the horizon), sample frame.
    wi, wo : ndarray, shape (N, 3)
        Unit vectors (sample frame) toward the centre of the source and of the detector's field.
    source_half_angle_deg, detector_half_angle_deg : float
        Half-angles (°) of the cone the source subtends and of the cone the detector sees.
    samples : int
        Monte Carlo samples per pose.
    seed_state : (int, int)
        PCG32 initial state and sequence (64-bit); lane k of the launch uses (state + k, seq + k).

    Returns
    -------
    ndarray, shape (N, 3)
        Ω_s · mean(f_r(ωi', ωo') · cos θi') per pose: L / L_src, dimensionless (sr⁻¹ · sr).
    """
    wi = np.asarray(wi, dtype=np.float64).reshape(-1, 3)
    wo = np.asarray(wo, dtype=np.float64).reshape(-1, 3)
    n = wi.shape[0]
    if n == 0:
        return np.zeros((0, 3))
    om_src = 1.0 - np.cos(np.radians(source_half_angle_deg))
    om_det = 1.0 - np.cos(np.radians(detector_half_angle_deg))

    def to_dr(v):
        return Array3f(*(Float(np.ascontiguousarray(v[:, k], dtype=np.float32)) for k in range(3)))

    pose = dr.arange(UInt32, n * samples) // samples
    wi_c = dr.gather(Array3f, to_dr(wi), pose)
    wo_c = dr.gather(Array3f, to_dr(wo), pose)
    # Opaque seeds and apertures: a new reading must not compile a new kernel.
    rng = PCG32(n * samples, initstate=dr.opaque(UInt64, seed_state[0]),
                initseq=dr.opaque(UInt64, seed_state[1]))
    wi_s = _cone_directions(wi_c, dr.opaque(Float, om_src), rng.next_float32(), rng.next_float32())
    wo_s = _cone_directions(wo_c, dr.opaque(Float, om_det), rng.next_float32(), rng.next_float32())
    fr_cos = material.eval_dr(wi_s, wo_s) * dr.maximum(wi_s.z, 0.0)
    sums = [dr.block_sum(fr_cos[k], samples) for k in range(3)]
    dr.eval(sums)
    mean = np.stack([np.asarray(s, dtype=np.float64) for s in sums], axis=1) / samples
    return 2.0 * np.pi * om_src * mean


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
        Campaign seed (see the module docstring).
    name : str
        Device name used in messages.
    """

    def __init__(self, cfg: DetectorConfig, *, light, axes: Mapping, kinematics, materials: Mapping,
                 clock: Clock, seed: int = 0, name: str = "detector"):
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
        self.name = name
        self.channels = tuple(cfg.channels)
        self.cfg = cfg
        self._light = light
        self._axes = axes
        self._kinematics = kinematics
        self._materials = dict(materials)
        self._clock = clock
        self._seed = int(seed)
        self._count = 0
        self._target = "sample"
        self._connected = False

    # -- the Detector protocol ----------------------------------------------------------------------
    def connect(self) -> None:
        self._connected = True

    def close(self) -> None:
        self._connected = False

    def measure(self, exposure_s: float, frames: int = 1) -> Reading:
        """Integrate ``frames`` frames of ``exposure_s`` seconds each at the current pose.

        The pose and the source radiance are those at the start of the integration; the clock then
        advances by exposure_s × frames. (The runner measures at rest, so motion blur is not modelled.)

        Returns
        -------
        Reading
            ``signal``: mean over the frames per channel (signal units); ``stderr``: the standard error
            of that mean (frames > 1), or for a single frame the standard deviation the noise model
            predicts (one frame cannot estimate its own spread). ``extra`` holds the target, the actual
            axis positions (°), the start time (s) and the reading number.
        """
        self._require_connected()
        exposure_s = _check_exposure(exposure_s)
        if isinstance(frames, bool) or not isinstance(frames, int | np.integer) or not 1 <= frames <= 1000:
            raise ValueError(f"frames: must be an integer in [1, 1000], got {frames!r}")
        t0 = self._clock.now()
        axes_deg = self.actual_axes_deg()
        source = self._light.radiance()
        n = self._count
        self._count += 1
        if source > 0.0:
            mc_seed = _seed_state(self._seed, _MC_STREAM, n)
            factor = self._radiance_factor(axes_deg[None, :], self._target, mc_seed)[0]
        else:
            factor = np.zeros(len(self.channels))  # shutter closed: skip the render
        clean = source * factor * exposure_s
        rng = np.random.default_rng(np.random.SeedSequence([self._seed, _NOISE_STREAM, n]))
        frame_values = self._noisy_frames(clean, exposure_s, int(frames), rng)
        mean = frame_values.mean(axis=0)
        if frames > 1:
            stderr = frame_values.std(axis=0, ddof=1) / np.sqrt(frames)
        else:
            stderr = self.noise_sigma(clean)
        self._clock.sleep(exposure_s * frames)
        extra = {"target": self._target, "axes_deg": dict(zip(self._kinematics.axis_names,
                                                              axes_deg.tolist(), strict=True)),
                 "t_s": t0, "reading": n}
        return Reading(signal=mean, stderr=stderr, exposure_s=exposure_s, frames=int(frames), extra=extra)

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
            with the shutter closed). The aperture samples are drawn from a fixed seed of this
            detector, so repeated calls return the same values.
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
        dark = self.cfg.noise.dark_offset * exposure_s
        if source == 0.0:
            return np.full((axes_deg.shape[0], len(self.channels)), dark)
        factor = self._radiance_factor(axes_deg, target, _seed_state(self._seed, _EXPECTED_STREAM, 0))
        return source * factor * exposure_s + dark

    def noise_sigma(self, clean_signal) -> np.ndarray:
        """Standard deviation (signal units) of one frame whose noise-free light signal is given."""
        noise = self.cfg.noise
        var = np.full(np.shape(clean_signal), noise.read_sigma**2, dtype=np.float64)
        if noise.shot_counts_per_unit > 0.0:
            var = var + np.asarray(clean_signal, dtype=np.float64) / noise.shot_counts_per_unit
        return np.sqrt(var)

    # -- internals ----------------------------------------------------------------------------------
    def _radiance_factor(self, axes_deg: np.ndarray, target: str, seed_state) -> np.ndarray:
        wi, wo = self._kinematics.directions(axes_deg)
        return aperture_radiance_factor(
            self._materials[target], wi, wo, self._light.half_angle_deg, self.cfg.half_angle_deg,
            self.cfg.aperture_samples, seed_state,
        )

    def _noisy_frames(self, clean: np.ndarray, exposure_s: float, frames: int, rng) -> np.ndarray:
        noise = self.cfg.noise
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


def _seed_state(seed: int, stream: int, counter: int) -> tuple[int, int]:
    state, seq = np.random.SeedSequence([seed, stream, counter]).generate_state(2, np.uint64)
    return int(state), int(seq)
