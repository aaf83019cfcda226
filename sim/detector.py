"""A simulated detector: the reflected radiance at the gantry's actual pose, rendered in Dr.Jit, plus
a linear sensor's noise.

Optics. The source subtends a cone of half-angle α_s around ωi and the detector sees a cone of half-angle
α_d around ωo; the reflected radiance over both cones is estimated by Monte Carlo with its standard error
(:mod:`gonio.sim.aperture`: ``aperture_samples`` pairs per pose, float64 sums in sample order). Every
pose of a batch is one row of one Dr.Jit launch, with its own random stream.

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
stream, a, b])``: the aperture samples from a Philox4x32 keyed by that stream's state (a still pose is
row counter 0 of :func:`gonio.sim.aperture.aperture_factors`; a reading over a motion has rows 0..15
under one key), and the sensor noise from a numpy generator. For ``measure(..., key=(step, attempt))``,
(a, b) = (step, attempt): the same reading of the same campaign is bit-identical whatever the process
did before it, so a campaign resumed from its journal in a new process replays an uninterrupted one,
and a retried step draws fresh samples. Without a key, (a, b) = (n, 0) on separate streams, n the number
of readings this detector object has taken (keyed or not) since it was built: reproducible within one
process only. ``expected_signal`` has its own fixed stream, so it returns the same values on every call.

Batches. Where the poses are known in advance (a simulation: every pose of a plan), :meth:`SimDetector.
measure_poses` renders the still readings of many poses in one launch per target: reading for reading
bit-identical to what :meth:`SimDetector.measure` gives with the same key, pose, source radiance,
exposure and frames (the same rows, the same per-reading sensor code), at a fraction of the CPU time
(``tools/bench_batch.py --only detector``).

Campaigns. A campaign learns its poses only by moving there, so it takes its readings in two halves
(:class:`gonio.protocols.ReadsInBatches`): :meth:`SimDetector.take` at each pose notes what
:meth:`measure` would read there (the actual axes, the source radiance, the target, the start time, the
reading number and the key) and advances the clock by the integration, and :meth:`SimDetector.develop`
renders a chunk of such takes in one launch per target: each reading bit for bit the one ``measure``
would have returned at its pose (the random streams are keyed per reading, never per launch), so how a
campaign is chunked never changes a value. A detector that integrates along the axes' read-backs
(``track_motion``) measures at once in ``take`` (the end of its integration is not known before), and
says so with :meth:`SimDetector.batch_readings` = 1.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from gonio.config import DetectorConfig
from gonio.jit import resolve_backend
from gonio.protocols import Clock, DeviceFault, Reading
from gonio.sim.aperture import aperture_factors, aperture_radiance_factor, seed_state

__all__ = ["SimDetector", "Take", "TARGETS", "MOTION_TIMES", "BATCH_ROWS", "CAMPAIGN_CHUNK",
           "aperture_radiance_factor"]

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
#: Poses per Dr.Jit launch of :meth:`SimDetector.measure_poses` (bounds the launch's memory).
BATCH_ROWS = 16384
#: Readings a campaign takes before developing them in one launch (:meth:`SimDetector.batch_readings`):
#: a chunk spreads the launch's fixed cost (tools/bench_batch.py --only campaign), and a chunk
#: is what a crash loses and redoes (bit for bit the same).
CAMPAIGN_CHUNK = 64
#: Above this many expected counts numpy's Poisson sampler is replaced by its Gaussian limit.
_POISSON_MAX = 1e15


def _straight(t0: float, a_deg: np.ndarray, t1: float, b_deg: np.ndarray):
    """``motion(times)`` along the straight line from ``a_deg`` at ``t0`` to ``b_deg`` at ``t1``."""
    a = np.asarray(a_deg, dtype=np.float64)
    d = np.asarray(b_deg, dtype=np.float64) - a

    def motion(times) -> np.ndarray:
        return a + ((np.asarray(times, dtype=np.float64) - t0) / (t1 - t0))[:, None] * d
    return motion


@dataclass(frozen=True)
class Take:
    """A still reading taken but not rendered yet (:meth:`SimDetector.take`): what
    :meth:`SimDetector.measure` saw at its start, or the reading itself where it was measured at once."""

    axes_deg: np.ndarray
    target: str
    source: float
    exposure_s: float
    frames: int
    t_s: float
    reading: int
    key: tuple[int, int] | None
    mc_id: tuple[int, int, int]
    noise_id: tuple[int, int, int]
    done: Reading | None = None


class SimDetector:
    """A simulated detector satisfying :class:`gonio.protocols.Detector` and
    :class:`gonio.protocols.ReadsInBatches`.

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
    backend : {"llvm", "cuda"}, optional
        Dr.Jit backend of the render; default ``cfg.sim.backend``, else :func:`gonio.jit.resolve_backend`
        (``GONIO_BACKEND``, else CUDA when present).
    """

    def __init__(self, cfg: DetectorConfig, *, light, axes: Mapping, kinematics, materials: Mapping,
                 clock: Clock, seed: int = 0, name: str = "detector", track_motion: bool = False,
                 backend: str | None = None):
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
        self.backend = resolve_backend(cfg.sim.backend if backend is None else backend)
        self._light = light
        self._axes = axes
        self._kinematics = kinematics
        self._materials = dict(materials)
        self._clock = clock
        self._seed = int(seed)
        self._track_motion = bool(track_motion)
        self._count = 0
        #: Readings a campaign takes before developing them (:meth:`batch_readings`); 1: one at a time.
        #: Never changes a value, only how many steps a unit of the campaign holds.
        self.chunk = CAMPAIGN_CHUNK
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
            reading number, the key, whether the axes moved, the Dr.Jit backend that rendered it,
            and the two parts of ``stderr`` (``stderr_integration``, ``stderr_sensor``).
        """
        self._require_connected()
        exposure_s = _check_exposure(exposure_s)
        frames = _check_frames(frames)
        key = _check_key(key)
        t0 = self._clock.now()
        axes_deg = self.actual_axes_deg()
        source = self._light.radiance()
        n = self._count
        self._count += 1
        mc_id, noise_id = self._streams(n, key)
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
        key_word = seed_state(self._seed, *mc_id)
        if path is not None:
            per = max(2, self.cfg.sim.aperture_samples // MOTION_TIMES)
            factors, ses = self._render(path, self._target, *_one_stream(key_word, MOTION_TIMES), per)
            factor, factor_se = factors.mean(axis=0), np.sqrt((ses**2).sum(axis=0)) / MOTION_TIMES
        elif source > 0.0:
            factor, factor_se = self._render(axes_deg[None, :], self._target, *_rows([key_word]))
            factor, factor_se = factor[0], factor_se[0]
        else:
            # Shutter closed: skip the render; no light, no integration error.
            factor = factor_se = np.zeros(len(self.channels))
        reading = self._reading(factor, factor_se, source, exposure_s, frames, noise_id, {
            "target": self._target, "axes_deg": self._named(axes_deg), "t_s": t0, "reading": n, "key": key,
            "moving": path is not None})
        if not slept:
            self._clock.sleep(exposure_s * frames)
        return reading

    def measure_poses(self, axes_deg, keys, *, exposure_s: float | Sequence[float] | None = None,
                      frames: int | Sequence[int] | None = None, targets: str | Sequence[str] | None = None,
                      sources: float | Sequence[float] | None = None,
                      times_s: float | Sequence[float] | None = None) -> list[Reading]:
        """The keyed readings of many still poses at once: what :meth:`measure` would give at each.

        For a simulation whose poses are known in advance (a whole plan): the poses of each target are
        rendered in one Dr.Jit launch (in launches of :data:`BATCH_ROWS`), and reading k is bit for bit
        the reading ``measure(exposure_s[k], frames[k], key=keys[k])`` takes with the axes at
        ``axes_deg[k]``, the target ``targets[k]`` under the beam and the source at ``sources[k]``
        (the same random streams, the same sensor code). Nothing moves and the clock does not advance;
        the reading numbers advance as ``len(keys)`` readings would. A reading whose axes move during
        its integration is :meth:`measure`'s alone.

        Parameters
        ----------
        axes_deg : array_like, shape (P, n_axes)
            Actual axis positions (°) at each reading, columns in ``kinematics.axis_names`` order.
        keys : array_like, shape (P, 2)
            (step, attempt) of each reading, integers >= 0.
        exposure_s, frames, targets, sources, times_s : scalar or sequence of P, optional
            Exposure (s; default ``cfg.exposure_s``), frames (default ``cfg.frames``), target (one of
            :data:`TARGETS`; default the current one), source radiance at the reading's start (>= 0;
            0: shutter closed; default the light's radiance now) and start time (s, kept in ``extra``;
            default the clock now), each one for all or one per reading.

        Returns
        -------
        list of Reading
            As :meth:`measure`'s, in the order of ``keys``.
        """
        self._require_connected()
        n_axes = len(self._kinematics.axis_names)
        axes_deg = np.asarray(axes_deg, dtype=np.float64)
        if axes_deg.ndim != 2 or axes_deg.shape[1] != n_axes:
            raise ValueError(f"axes_deg: expected shape (P, {n_axes}), got {axes_deg.shape}")
        p = axes_deg.shape[0]
        keys = [_check_key(tuple(k)) if isinstance(k, tuple | list | np.ndarray) else _check_key(k)
                for k in keys]
        if len(keys) != p:
            raise ValueError(f"keys: expected one (step, attempt) per pose ({p}), got {len(keys)}")
        exposure = [_check_exposure(e) for e in _each("exposure_s", exposure_s, self.cfg.exposure_s, p)]
        frame_counts = [_check_frames(f) for f in _each("frames", frames, self.cfg.frames, p)]
        targets = [_check_target(t) for t in _each("targets", targets, self._target, p)]
        sources = [float(r) for r in _each("sources", sources, None, p)] if sources is not None else \
            [self._light.radiance()] * p
        if any(not (np.isfinite(r) and r >= 0.0) for r in sources):
            raise ValueError("sources: each source radiance must be finite and >= 0")
        times = [float(t) for t in _each("times_s", times_s, self._clock.now(), p)]
        first = self._count
        self._count += p
        return self.develop([
            Take(axes_deg[k], targets[k], sources[k], exposure[k], frame_counts[k], times[k], first + k,
                 keys[k], (_MC_STREAM, *keys[k]), (_NOISE_STREAM, *keys[k])) for k in range(p)])

    # -- readings taken now, rendered later (gonio.protocols.ReadsInBatches) -------------------------
    def batch_readings(self) -> int:
        """Readings worth developing together: :attr:`chunk` (1 where ``track_motion`` makes :meth:`take`
        measure at once)."""
        return 1 if self._track_motion else self.chunk

    def take(self, exposure_s: float, frames: int = 1, *, key: tuple[int, int] | None = None) -> Take:
        """:meth:`measure` at the current pose, its render left to :meth:`develop`: the pose, the source
        radiance, the target and the start time are noted now, the reading number and the streams
        assigned now, and the clock advances by the integration as ``measure``'s does. With
        ``track_motion`` the reading is measured at once (its path is known only at its end)."""
        self._require_connected()
        if self._track_motion:
            reading = self.measure(exposure_s, frames, key=key)
            x = reading.extra
            return Take(np.array(list(x["axes_deg"].values())), x["target"], 0.0, reading.exposure_s,
                        reading.frames, x["t_s"], x["reading"], x["key"], (), (), done=reading)
        exposure_s = _check_exposure(exposure_s)
        frames = _check_frames(frames)
        key = _check_key(key)
        n = self._count
        self._count += 1
        mc_id, noise_id = self._streams(n, key)
        taken = Take(self.actual_axes_deg(), self._target, self._light.radiance(), exposure_s, frames,
                     self._clock.now(), n, key, mc_id, noise_id)
        self._clock.sleep(exposure_s * frames)
        return taken

    def develop(self, takes: Sequence[Take]) -> list[Reading]:
        """The readings of ``takes`` (from :meth:`take`, in any number), in order: the lit ones of each
        target rendered in one launch (launches of :data:`BATCH_ROWS`), each bit for bit what
        :meth:`measure` would have returned when it was taken."""
        takes = list(takes)
        factor = np.zeros((len(takes), len(self.channels)))
        factor_se = np.zeros_like(factor)
        for target in TARGETS:
            lit = [k for k, t in enumerate(takes) if t.done is None and t.target == target and t.source > 0.0]
            for lo in range(0, len(lit), BATCH_ROWS):
                part = lit[lo:lo + BATCH_ROWS]
                axes = np.array([takes[k].axes_deg for k in part])
                words = [seed_state(self._seed, *takes[k].mc_id) for k in part]
                factor[part], factor_se[part] = self._render(axes, target, *_rows(words))
        return [t.done if t.done is not None else self._reading(
            factor[k], factor_se[k], t.source, t.exposure_s, t.frames, t.noise_id, {
                "target": t.target, "axes_deg": self._named(t.axes_deg), "t_s": t.t_s, "reading": t.reading,
                "key": t.key, "moving": False}) for k, t in enumerate(takes)]

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
        self._target = _check_target(target)

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
        target = _check_target(self._target if target is None else target)
        exposure_s = _check_exposure(self.cfg.exposure_s if exposure_s is None else exposure_s)
        n_axes = len(self._kinematics.axis_names)
        axes_deg = np.asarray(axes_deg, dtype=np.float64)
        if axes_deg.ndim != 2 or axes_deg.shape[1] != n_axes:
            raise ValueError(f"axes_deg: expected shape (N, {n_axes}), got {axes_deg.shape}")
        source = self._light.radiance()
        dark = self.cfg.sim.noise.dark_offset * exposure_s
        if source == 0.0:
            return np.full((axes_deg.shape[0], len(self.channels)), dark)
        stream = seed_state(self._seed, _EXPECTED_STREAM, 0, 0)
        factor, _ = self._render(axes_deg, target, *_one_stream(stream, axes_deg.shape[0]))
        return source * factor * exposure_s + dark

    def noise_sigma(self, clean_signal) -> np.ndarray:
        """Standard deviation (signal units) of one frame whose noise-free light signal is given."""
        noise = self.cfg.sim.noise
        var = np.full(np.shape(clean_signal), noise.read_sigma**2, dtype=np.float64)
        if noise.shot_counts_per_unit > 0.0:
            var = var + np.asarray(clean_signal, dtype=np.float64) / noise.shot_counts_per_unit
        return np.sqrt(var)

    # -- internals ----------------------------------------------------------------------------------
    @staticmethod
    def _streams(n: int, key: tuple[int, int] | None) -> tuple[tuple[int, int, int], tuple[int, int, int]]:
        """(aperture, noise) stream ids of reading number ``n`` with ``key`` (module docstring)."""
        if key is None:
            return (_MC_COUNTER_STREAM, n, 0), (_NOISE_COUNTER_STREAM, n, 0)
        return (_MC_STREAM, *key), (_NOISE_STREAM, *key)

    def _render(self, axes_deg: np.ndarray, target: str, keys, words, counters,
                samples: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(factor, stderr) per pose of ``axes_deg`` (K, n_axes), each pose a row of
        :func:`gonio.sim.aperture.aperture_factors` with its stream (keys, words, counters), ``samples``
        aperture pairs each (default ``aperture_samples``)."""
        wi, wo = self._kinematics.directions(axes_deg)
        return aperture_factors(
            self._materials[target], wi, wo, self._light.half_angle_deg, self.cfg.sim.half_angle_deg,
            self.cfg.sim.aperture_samples if samples is None else samples, keys, words, counters,
            self.backend)

    def _reading(self, factor: np.ndarray, factor_se: np.ndarray, source: float, exposure_s: float,
                 frames: int, noise_id: tuple[int, int, int], extra: dict) -> Reading:
        """The reading of a rendered pose through the sensor: the one code path of every reading."""
        clean = source * factor * exposure_s
        noise = self.cfg.sim.noise
        # The generator is drawn from only with shot or read noise (building it costs more than a render).
        rng = np.random.default_rng(np.random.SeedSequence([self._seed, *noise_id])) \
            if noise.shot_counts_per_unit > 0.0 or noise.read_sigma > 0.0 else None
        frame_values = self._noisy_frames(clean, exposure_s, frames, rng)
        mean = frame_values.mean(axis=0)
        if frames > 1:
            sensor_se = frame_values.std(axis=0, ddof=1) / np.sqrt(frames)
        else:
            sensor_se = self.noise_sigma(clean)
        integration_se = source * factor_se * exposure_s
        stderr = np.hypot(integration_se, sensor_se)
        extra.update(backend=self.backend, stderr_integration=integration_se, stderr_sensor=sensor_se)
        return Reading(signal=mean, stderr=stderr, exposure_s=exposure_s, frames=frames, extra=extra)

    def _named(self, axes_deg: np.ndarray) -> dict:
        return dict(zip(self._kinematics.axis_names, axes_deg.tolist(), strict=True))

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


def _check_frames(frames) -> int:
    if isinstance(frames, bool) or not isinstance(frames, int | np.integer) or not 1 <= frames <= 1000:
        raise ValueError(f"frames: must be an integer in [1, 1000], got {frames!r}")
    return int(frames)


def _check_target(target) -> str:
    if target not in TARGETS:
        raise ValueError(f"target: {target!r} is not one of {', '.join(repr(t) for t in TARGETS)}")
    return target


def _each(name: str, value, default, n: int) -> list:
    """``value`` for each of ``n`` readings: a scalar (or None: ``default``) for all, or a sequence of n."""
    if value is None:
        return [default] * n
    if isinstance(value, str) or np.ndim(value) == 0:
        return [value] * n
    values = list(value)
    if len(values) != n:
        raise ValueError(f"{name}: expected one value or one per pose ({n}), got {len(values)}")
    return values


def _rows(key_words: list[tuple[int, int]]):
    """Rows of their own streams, counter 0 each: (keys, words, counters) of :meth:`SimDetector._render`."""
    keys = np.array([k for k, _ in key_words], dtype=np.uint64)
    words = np.array([w for _, w in key_words], dtype=np.uint32)
    return keys, words, np.zeros(len(key_words), dtype=np.uint32)


def _one_stream(key_word: tuple[int, int], n: int):
    """n rows sharing one stream, counters 0..n−1 (a reading over a motion, ``expected_signal``)."""
    key, word = key_word
    return np.full(n, key, dtype=np.uint64), np.full(n, word, dtype=np.uint32), np.arange(n, dtype=np.uint32)
