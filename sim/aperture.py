"""Monte Carlo over the source and detector cones: the simulated detectors' optics, batched over poses.

A detector at a pose sees the reflected radiance

    L = L_src ∫_{source cone} f_r(ωi', ωo') cos θi' dωi',   averaged uniformly over ωo' in the detector cone,

estimated from ``samples`` pairs (ωi', ωo') per pose, each uniform in its cone (cos θ uniform in
[cos α, 1] about the cone's axis): L ≈ L_src · Ω_s · mean(f_r · cos θi'), Ω_s = 2π(1 − cos α_s), with the
standard error Ω_s · s/√n from the sample variance s² of f_r · cos θi'.

Rows. :func:`aperture_factors` takes many poses ("rows") at once, each with its own random stream: a
Philox4x32 key, a 32-bit word and a 32-bit counter. Sample j of a row draws its four uniforms from the
counter (j, counter, word, 0) under the row's key, so a row's samples depend on its (key, word, counter)
alone, never on the other rows of the launch: one pose rendered alone and the same pose in a batch of
thousands give the same numbers, bit for bit. (A reading of a still pose is one row, counter 0; a reading
integrated over a motion is 16 rows sharing a key, counters 0..15; :func:`aperture_radiance_factor`
gives N poses one key and counters 0..N−1.)

Sums. Each row's Σx and Σx² (x = f_r · cos θi', per channel) are accumulated in float64 in the order of
the samples, in a loop per Dr.Jit lane: sample chunks of :data:`CHUNK_SAMPLES` are one lane each, summed
in order, and the chunks' sums are added in order. float64, because Σx² − (Σx)²/n cancels down to the
variance, which can be ~1e-10 of the squared mean (a Lambertian in a 0.5° cone), far below float32's
resolution: float32 sums gave 100x the true error there (tools/bench_detector.py). A fixed order, because
a sum's last bits depend on it: Dr.Jit's block reduction orders the additions its own way, which need
not be the same for one block as for one of many; here the order is a function of the sample count
alone, on every backend, for every batch.

All rows of a call are one kernel launch; the samples are generated, the material evaluated and the sums
taken in that kernel (no per-sample buffer).
"""

from __future__ import annotations

import math
import threading
import weakref

import drjit as dr
import numpy as np

from gonio.jit import array_types, resolve_backend, upload

__all__ = ["aperture_factors", "aperture_radiance_factor", "aperture_directions", "cone_directions",
           "seed_state", "check_seed_state", "CHUNK_SAMPLES", "MAX_SAMPLES"]

#: Samples one Dr.Jit lane sums in order: a row of more samples is split into chunks of this many.
CHUNK_SAMPLES = 1024
#: The most Monte Carlo samples per pose.
MAX_SAMPLES = 1 << 20


def seed_state(seed: int, stream: int, a: int, b: int) -> tuple[int, int]:
    """The Philox4x32 (key, word) of the stream named by ``np.random.SeedSequence([seed, stream, a, b])``:
    a 64-bit key and a 32-bit word."""
    key, word = np.random.SeedSequence([seed, stream, a, b]).generate_state(2, np.uint64)
    return int(key), int(word) >> 32


def check_seed_state(state) -> tuple[int, int]:
    """``state`` as (key, word), integers in [0, 2**64) and [0, 2**32); ValueError otherwise."""
    ok = (isinstance(state, tuple | list) and len(state) == 2
          and all(isinstance(k, int | np.integer) and not isinstance(k, bool) for k in state)
          and 0 <= state[0] < 1 << 64 and 0 <= state[1] < 1 << 32)
    if not ok:
        raise ValueError(f"seed_state: must be (key, word), integers in [0, 2**64) and [0, 2**32), "
                         f"got {state!r}")
    return int(state[0]), int(state[1])


def _check_samples(samples) -> int:
    whole = isinstance(samples, int | np.integer) and not isinstance(samples, bool)
    if not whole or not 2 <= samples <= MAX_SAMPLES:
        raise ValueError(f"samples: must be an integer in [2, {MAX_SAMPLES}], got {samples!r}")
    return int(samples)


def cone_directions(axis, one_minus_cos_max, u1, u2):
    """Directions uniform in solid angle within a cone around the unit vector(s) ``axis`` (a Dr.Jit
    3-vector; the result has its type), from uniforms ``u1``, ``u2``."""
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
    vector = type(axis)
    s = vector(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x)
    t = vector(b, sign + n.y * n.y * a, -n.y)
    return s * (sin_t * cos_p) + t * (sin_t * sin_p) + n * cos_t


def _one_minus_cos(half_angle_deg: float) -> float:
    return 1.0 - math.cos(math.radians(half_angle_deg))


def _axes_buffer(t, wi: np.ndarray, wo: np.ndarray):
    """Both cone axes of every pose in one float32 buffer, (N, 6) row-major: one input whatever N."""
    return upload(t.Float, np.hstack([wi, wo]), np.float32)


def aperture_directions(wi: np.ndarray, wo: np.ndarray, source_half_angle_deg: float,
                        detector_half_angle_deg: float, samples: int, seed_state: tuple[int, int],
                        backend: str | None = None):
    """The Monte Carlo directions of :func:`aperture_radiance_factor`, as Dr.Jit Array3f of ``backend``:
    ``samples`` pairs (ωi', ωo') per pose, N·samples lanes, pose-major. Lane (j, p) draws from the
    Philox4x32 counter (j, p, word, 0) under the key of ``seed_state``: the samples of row p of
    :func:`aperture_factors` with that key and word and counter p."""
    t = array_types(resolve_backend(backend))
    n = wi.shape[0]
    key, word = seed_state
    lane = dr.arange(t.UInt32, n * samples)
    pose = lane // samples
    axes = _axes_buffer(t, wi, wo)
    wi_c = dr.gather(t.Array3f, axes, 2 * pose)
    wo_c = dr.gather(t.Array3f, axes, 2 * pose + 1)
    # Opaque key and apertures: a new reading must not compile a new kernel.
    rng = t.Philox4x32(dr.opaque(t.UInt64, key), lane - pose * samples, pose, dr.opaque(t.UInt32, word))
    u1, u2, u3, u4 = rng.next_float32x4()
    wi_s = cone_directions(wi_c, dr.opaque(t.Float, _one_minus_cos(source_half_angle_deg)), u1, u2)
    wo_s = cone_directions(wo_c, dr.opaque(t.Float, _one_minus_cos(detector_half_angle_deg)), u3, u4)
    return wi_s, wo_s


def aperture_factors(material, wi: np.ndarray, wo: np.ndarray, source_half_angle_deg: float,
                     detector_half_angle_deg: float, samples: int, keys, words, counters,
                     backend: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Reflected radiance per unit source radiance, and its Monte Carlo standard error, for many poses
    (rows), each with its own random stream, in one Dr.Jit launch.

    Parameters
    ----------
    material
        Has ``eval_dr(wi, wo) -> Array3f``: f_r in sr⁻¹ (0 below the horizon), sample frame.
    wi, wo : ndarray, shape (N, 3)
        Unit vectors (sample frame) toward the centre of the source and of the detector's field.
    source_half_angle_deg, detector_half_angle_deg : float
        Half-angles (°) of the cone the source subtends and of the cone the detector sees.
    samples : int
        Monte Carlo samples per row, in [2, :data:`MAX_SAMPLES`] (one sample cannot estimate its error).
    keys, words, counters : array_like, shape (N,)
        Per row: the 64-bit Philox4x32 key, the 32-bit word and the 32-bit counter of its stream
        (module docstring): row r's sample j draws from the counter (j, counters[r], words[r], 0) under
        keys[r].
    backend : {"llvm", "cuda"}, optional
        Dr.Jit backend (default: :func:`gonio.jit.resolve_backend`).

    Returns
    -------
    factor : ndarray, shape (N, 3)
        Ω_s · mean(f_r(ωi', ωo') · cos θi') per row: L / L_src, dimensionless (sr⁻¹ · sr).
    stderr : ndarray, shape (N, 3)
        Ω_s · s / √samples, s² the sample variance of f_r · cos θi' over the row's samples: the
        standard error of ``factor`` from the integration alone.
    """
    wi = np.asarray(wi, dtype=np.float64).reshape(-1, 3)
    wo = np.asarray(wo, dtype=np.float64).reshape(-1, 3)
    samples = _check_samples(samples)
    n = wi.shape[0]
    if wo.shape[0] != n:
        raise ValueError(f"wo: expected {n} directions like wi, got {wo.shape[0]}")
    keys, words, counters = (np.asarray(v).reshape(-1) for v in (keys, words, counters))
    for name, v, bits in (("keys", keys, 64), ("words", words, 32), ("counters", counters, 32)):
        if v.shape != (n,):
            raise ValueError(f"{name}: expected one per pose ({n}), got {v.size}")
        if n and (v.dtype.kind not in "iu" or v.min() < 0 or int(v.max()) >= 1 << bits):
            raise ValueError(f"{name}: must be integers in [0, 2**{bits}), one per pose")
    if n == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    backend = resolve_backend(backend)
    t = array_types(backend)
    chunks = -(-samples // CHUNK_SAMPLES)
    # Opaque apertures and sample count: another reading, pose count or detector reuses the kernel.
    # Every lane's row and first sample come in as arrays of the lane count: a replay of the frozen
    # kernel takes its sizes from its inputs (a count computed in Python would be baked into it).
    lane_row = np.repeat(np.arange(n, dtype=np.uint32), chunks)
    lane_start = np.tile(np.arange(chunks, dtype=np.uint32) * CHUNK_SAMPLES, n)
    inputs = (_axes_buffer(t, wi, wo), upload(t.UInt64, keys, np.uint64),
              upload(t.UInt32, words, np.uint32), upload(t.UInt32, counters, np.uint32),
              upload(t.UInt32, lane_row, np.uint32), upload(t.UInt32, lane_start, np.uint32),
              dr.opaque(t.Float, _one_minus_cos(source_half_angle_deg)),
              dr.opaque(t.Float, _one_minus_cos(detector_half_angle_deg)), dr.opaque(t.UInt32, samples))
    frozen = _frozen_sums(material, backend)
    if frozen is not None:   # a Material: its parameters are inputs of the frozen kernel
        with frozen[1]:      # a frozen function keeps its recordings in itself: one call at a time
            s1, s2 = frozen[0](material.dr_parameters(t.Array3f), *inputs)
            s1, s2 = _sums_to_numpy(s1, s2, n, chunks)
    else:                    # anything else with eval_dr: traced on every call
        s1, s2 = _sums_to_numpy(*_sums(material, t, None, *inputs), n, chunks)
    mean = s1 / samples
    # Rounding can leave a zero variance (a constant integrand) a hair below zero.
    var = np.maximum(s2 - s1 * mean, 0.0) / (samples - 1)
    omega = 2.0 * np.pi * _one_minus_cos(source_half_angle_deg)
    return omega * mean, omega * np.sqrt(var / samples)


#: material -> backend -> (the frozen kernel of its sums, its lock); dropped with the material.
_FROZEN: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_FROZEN_LOCK = threading.Lock()


def _frozen_sums(material, backend: str):
    """The per-lane sums of :func:`aperture_factors` for ``material`` on ``backend`` as a frozen Dr.Jit
    function (:func:`drjit.freeze`): the first call traces and records the launch, later calls replay it
    with new inputs of any size, so a chunk of a campaign costs ~0.2 ms of launch instead of ~1 ms of
    tracing (tools/bench_batch.py --only campaign), the same kernel, so the same values bit for bit.
    None for a material that is not a :class:`~gonio.sim.materials.Material` (no ``eval_with``) or that
    cannot be a weak dictionary key (unhashable): it is traced on every call."""
    if not hasattr(material, "eval_with"):
        return None
    with _FROZEN_LOCK:
        try:
            per = _FROZEN.setdefault(material, {})
        except TypeError:
            return None
        if backend not in per:
            t, ref = array_types(backend), weakref.ref(material)   # the cache must not keep it alive

            def sums(*inputs):
                return _sums(ref(), t, *inputs)
            per[backend] = (dr.freeze(sums), threading.Lock())
        return per[backend]


def _sums_to_numpy(s1, s2, n: int, chunks: int):
    return (_chunk_totals(np.stack([np.asarray(c, dtype=np.float64) for c in s], axis=1), n, chunks)
            for s in (s1, s2))


def _sums(material, t, params, axes, keys, words, counters, row, start, om_src, om_det, samples):
    """Σx and Σx² (Array3f64, one per lane) of x = f_r · cos θi' over each lane's samples, lane = (row,
    chunk of :data:`CHUNK_SAMPLES` from sample ``start``) in row-major order (module docstring);
    ``params``: the material's :meth:`~gonio.sim.materials.Material.dr_parameters` (None: ``eval_dr``)."""
    wi_c = dr.gather(t.Array3f, axes, 2 * row)
    wo_c = dr.gather(t.Array3f, axes, 2 * row + 1)
    key, word, counter = (dr.gather(type(v), v, row) for v in (keys, words, counters))
    end = dr.minimum(start + CHUNK_SAMPLES, samples)

    def body(j, s1, s2):
        u1, u2, u3, u4 = t.Philox4x32(key, j, counter, word).next_float32x4()
        wi_s = cone_directions(wi_c, om_src, u1, u2)
        wo_s = cone_directions(wo_c, om_det, u3, u4)
        f = material.eval_dr(wi_s, wo_s) if params is None else material.eval_with(wi_s, wo_s, params)
        x = t.Array3f64(f * dr.maximum(wi_s.z, 0.0))
        return j + 1, s1 + x, s2 + x * x

    zero = t.Float64(start) * 0.0   # +0.0 on every lane, sized by an input
    _, s1, s2 = dr.while_loop((start, t.Array3f64(zero), t.Array3f64(zero)), lambda j, s1, s2: j < end, body)
    return s1, s2


def _chunk_totals(sums: np.ndarray, n: int, chunks: int) -> np.ndarray:
    """Per row, its chunks' sums (n·chunks, 3) added in chunk order: (n, 3)."""
    per = sums.reshape(n, chunks, 3)
    total = per[:, 0]
    for c in range(1, chunks):
        total = total + per[:, c]
    return total


def aperture_radiance_factor(material, wi: np.ndarray, wo: np.ndarray, source_half_angle_deg: float,
                             detector_half_angle_deg: float, samples: int, seed_state: tuple[int, int],
                             backend: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`aperture_factors` of N poses sharing one stream: ``seed_state`` = (key, word), pose p with
    counter p (sample j of pose p draws from the counter (j, p, word, 0)), so the same (key, word) gives
    pose p the same samples in any batch. Returns (factor, stderr), each (N, 3)."""
    key, word = check_seed_state(seed_state)
    n = np.asarray(wi).reshape(-1, 3).shape[0]
    return aperture_factors(material, wi, wo, source_half_angle_deg, detector_half_angle_deg, samples,
                            np.full(n, key, dtype=np.uint64), np.full(n, word, dtype=np.uint32),
                            np.arange(n, dtype=np.uint32), backend)
