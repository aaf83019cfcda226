"""A fly campaign on the simulated gantry: the detector integrates while the axes move.

Each reading of a sweep (:class:`gonio.plan.fly.FlyLine`) exposes over [m − e/2, m + e/2] around its
mid-time m. The simulated photodiode integrates over that motion, with no shortcut of evaluating at the
mid-point: ``TIME_SAMPLES`` times per reading, stratified uniformly over the exposure (one uniform draw
in each of equal slices), each put on the line's trajectory (from rest, speeding up, at top speed,
slowing down, at rest: :meth:`FlyLine.position_at`; a coordinated line's path through its poses:
:meth:`gonio.plan.flypath.PathLine.position_at`), turned into the pair of directions by the forward
kinematics, and
rendered with the aperture sampling of the stop-and-go detector
(:func:`gonio.sim.detector.aperture_radiance_factor`: ``aperture_samples / TIME_SAMPLES`` pairs in the
source and detector cones per time, so a reading has as many Monte Carlo lanes as a stop-and-go one).
The lamp's radiance is taken at each time (its drift runs on through the exposure).

The detector reads ``SUBFRAMES`` sub-reads per exposure (a photodiode read at ~1 kHz, as pgII does):
each sub-read integrates its slice of the exposure, with shot noise on its own signal and read noise
of its own, and the reading is their sum. Axis positions come from timestamped axis reads every
``AXIS_READ_S`` (a Dynamixel Sync Read), interpolated linearly to the exposure's mid-time; the
sample's angles are the forward kinematics of those positions (at the exposure's mid-time; where the
axis speeds up or slows down during it, the mean position differs from that by a·e²/24: 0.009° at
``iso:step=5`` on the two-arm gantry, 0.3° at ``step=30`` whose exposures blur over 15°; the blur term
carries the curvature it adds).

Uncertainty. ``stderr`` adds in quadrature: the Monte Carlo error of the aperture and time sampling,
the sensor's (the noise model's σ of the summed sub-reads), and the motion blur. The blur is a
deterministic bias, not noise: the reading estimates the mean of the response over the exposure's path
but is reported at the mid-time direction. For a response quadratic in time over the exposure,
a + b·τ + c·τ² (τ in exposures, c the curvature over one exposure), the mean over τ in [−½, ½] is c/12
above the mid-time value a. The error of a reading against the value at its direction is then
e = n + c/12 (n the noise, of variance σ², the other two terms), of mean square σ² + (c/12)²: the
variance to state, so the blur term is |c|/12. The true c is unknown; the quadratic fitted through the
sub-reads gives ĉ = c + ν, ν the noise it inherits from them (variance σ_c², from their stated noise;
its weights sum to zero, so ν is independent of the summed signal's noise when the sub-reads are alike).
As E[ĉ²] = c² + σ_c², the blur term stated is √max(ĉ² − σ_c², 0)/12: the unbiased estimate of the bias
squared, clipped at zero (a square is not negative; the clipping only adds). It is noisy reading to
reading (on a smooth material 30 % of the readings state some blur, the others none), but right on
average: the z-scores have unit rms through sharp peaks and on smooth materials alike. Stating |ĉ|/12,
or |ĉ|/12 with σ_c/12 added in quadrature (as before), counts the sub-read noise once or twice more
on top of σ, which already holds it; with 4 sub-reads σ_c/12 is 1.33 σ, so the latter stated ~2x the
errors seen (z rms 0.55 through sharp peaks; the blur was 85 % of the stderr on smooth materials, whose
bias is ~0). Two alternatives were measured and left: correcting the value by ĉ/12 (honest, but it adds
σ_c/12 = 1.33 σ of noise to every reading to remove a bias that is below the noise except on the
sharpest peaks: errors 1.66x larger), and taking c from the neighbouring readings of the sweep (2
exposures apart at fly speed, far less noisy): a specular peak at θ = 70° is about as narrow as that
spacing, and there the readings' second difference missed the curvature by hundreds of σ on the flanks
and a fourth-difference check of it was blind at the peak's top (weighed against the sub-reads by that
check: z rms 1.0, errors 1.2–1.3x larger). On a slope (no curvature) the term vanishes, and a reading
that does not move (a dark, a white reference, a pose read stop-and-go) states no blur at all. Tested
by z-scores against the stop-and-go reading of the same pose through sharp specular peaks, where the
blur exceeds the noise too, and in a calibrated campaign (``tests/fly``).

Seeding: every random number of a sweep (or checkpoint) comes from streams named by
``SeedSequence([seed, stream, first step])``, so a sweep computed again (a resumed campaign) is the
same, bit for bit, whatever came before it.
"""

from __future__ import annotations

import numpy as np

from gonio.clock import VirtualClock
from gonio.fly.blur import motion_blur
from gonio.kinematics import make_kinematics
from gonio.plan.fly import FlyLine, FlyPlan, fly_steps
from gonio.plan.schedule import STEP_DARK, STEP_POSE, STEP_REFERENCE
from gonio.sim import materials as _materials
from gonio.sim.aperture import aperture_radiance_factor
from gonio.sim.light import SimLight
from gonio.sim.standard import reference_material
from gonio.store import Measurement

__all__ = ["TIME_SAMPLES", "SUBFRAMES", "AXIS_READ_S", "FlySimulator"]

#: Times per reading at which the motion is sampled (stratified over the exposure).
TIME_SAMPLES = 16
#: Sub-reads per exposure (the photodiode's own read rate); divides TIME_SAMPLES.
SUBFRAMES = 4
#: Seconds between timestamped axis reads.
AXIS_READ_S = 0.002
# Seed-sequence streams (apart from the stop-and-go detector's 0..4).
_MC, _NOISE, _TIMES = 20, 21, 22


class FlySimulator:
    """Readings of a fly campaign (:class:`gonio.plan.fly.FlyPlan`) on the simulated gantry of ``cfg``.

    Parameters
    ----------
    cfg : GonioConfig
        The simulated gantry: kinematics, lamp (radiance, drift, half-angle), detector (field
        half-angle, aperture samples, noise), white standard.
    material : str or material
        The sample (``gonio.sim.materials.load`` spec, or a loaded material with ``eval_dr``).
    seed : int
        Campaign seed.
    """

    def __init__(self, cfg, material, *, seed: int = 0, kin=None):
        self.cfg = cfg
        self.kin = kin if kin is not None else make_kinematics(cfg)
        self.sample = _materials.load(material) if isinstance(material, str) else material
        self.reference = reference_material(cfg)
        self.light = SimLight(cfg.light, VirtualClock())
        self.seed = int(seed)
        self.samples = max(2, cfg.detector.sim.aperture_samples // TIME_SAMPLES)

    def campaign(self, fp: FlyPlan) -> list[Measurement]:
        """Every reading of the campaign, in step order."""
        out: list[Measurement] = []
        for item in fly_steps(fp):
            out += self.item(fp, item)
        return out

    def item(self, fp: FlyPlan, item) -> list[Measurement]:
        """The readings of one entry of :func:`fly_steps` (a sweep, or a checkpoint's dark and reference)."""
        kind, k, step = item
        if kind == "line":
            return self.sweep(fp.lines[k], float(fp.line_start_s[k]), step)
        _, dark_t, dark_deg, ref_t = fp.checkpoints[k]
        still = _still_line(dark_deg, fp.reading_s)
        dark = self._read(still, dark_t, step, None, STEP_DARK, -1)
        ref = self._read(_still_line(fp.reference_deg, fp.reading_s), ref_t, step + 1, self.reference,
                         STEP_REFERENCE, -1)
        return dark + ref

    def sweep(self, line: FlyLine, t0: float, step: int) -> list[Measurement]:
        """The readings of one line whose run-up starts at campaign time ``t0``, steps from ``step``."""
        return self._read(line, t0, step, self.sample, STEP_POSE, line.poses)

    # -- internals ----------------------------------------------------------------------------------
    def _read(self, line: FlyLine, t0: float, step: int, material, kind: int, poses) -> list[Measurement]:
        cfg, kin = self.cfg, self.kin
        n, e = line.n, line.exposure_s
        mids = line.mid_times()
        rng_t = np.random.default_rng(np.random.SeedSequence([self.seed, _TIMES, step]))
        # Stratified times: one uniform draw in each of TIME_SAMPLES equal slices of every exposure.
        frac = (np.arange(TIME_SAMPLES)[None, :] + rng_t.random((n, TIME_SAMPLES))) / TIME_SAMPLES
        times = mids[:, None] + e * (frac - 0.5)                                    # (n, K)
        channels = len(cfg.detector.channels)
        if material is None:  # a dark: shutter closed
            clean = np.zeros((n, TIME_SAMPLES, channels))
            mc_var = np.zeros((n, TIME_SAMPLES, channels))
        else:
            pos = line.position_at(times).reshape(-1, len(kin.axis_names))
            wi, wo = kin.directions(pos)
            key, word = np.random.SeedSequence([self.seed, _MC, step]).generate_state(2, np.uint64)
            factor, factor_se = aperture_radiance_factor(
                material, wi, wo, self.light.half_angle_deg, cfg.detector.sim.half_angle_deg, self.samples,
                (int(key), int(word) >> 32), cfg.detector.sim.backend)
            radiance = np.array([self.light.lamp_radiance(t) for t in (t0 + times).ravel()])[:, None]
            # Signal per time sample as if it lasted the whole exposure (signal units).
            clean = (radiance * factor * e).reshape(n, TIME_SAMPLES, channels)
            mc_var = ((radiance * factor_se * e) ** 2).reshape(n, TIME_SAMPLES, channels)
        per = TIME_SAMPLES // SUBFRAMES
        # Each sub-read integrates its slice: the mean of its time samples times its share of e.
        sub_clean = clean.reshape(n, SUBFRAMES, per, channels).mean(axis=2) / SUBFRAMES
        sub_mc_var = mc_var.reshape(n, SUBFRAMES, per, channels).sum(axis=2) / (per * SUBFRAMES) ** 2
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, _NOISE, step]))
        sub = self._noisy(sub_clean, e / SUBFRAMES, rng)                            # (n, M, C)
        signal = sub.sum(axis=1)
        sub_noise_var = self._noise_var(sub_clean) + sub_mc_var
        # Only motion blurs: a reading at rest (dark, reference, a pose read stop-and-go) states none.
        blur_sd = motion_blur(sub, sub_noise_var) if line.moving else np.zeros_like(signal)
        mc_se = np.sqrt(mc_var.sum(axis=1)) / TIME_SAMPLES
        sensor_se = np.sqrt(self._noise_var(sub_clean).sum(axis=1))
        stderr = np.sqrt(mc_se**2 + sensor_se**2 + blur_sd**2)
        # Timestamped axis reads, interpolated to each exposure's mid-time.
        reads_t = np.arange(0.0, line.duration_s + AXIS_READ_S, AXIS_READ_S)
        reads = line.position_at(reads_t)
        actual = np.stack([np.interp(mids, reads_t, reads[:, a]) for a in range(reads.shape[1])], axis=1)
        angles = np.degrees(np.stack(kin.forward(actual), axis=1))
        planned = line.readings_deg()
        ends = t0 + mids + 0.5 * e
        pose_ids = np.full(n, -1) if kind != STEP_POSE else np.asarray(poses)
        return [Measurement(step=step + j, kind=kind, pose=int(pose_ids[j]), commanded_deg=planned[j],
                            actual_deg=actual[j], angles_deg=angles[j], clock_s=float(ends[j]),
                            campaign_s=float(ends[j]), exposure_s=e, frames=SUBFRAMES, signal=signal[j],
                            stderr=stderr[j],
                            extra={"mid_s": float(t0 + mids[j]), "speed_deg_s": line.speed_deg_s,
                                   "stderr_blur": blur_sd[j], "stderr_integration": mc_se[j],
                                   "stderr_sensor": sensor_se[j]})
                for j in range(n)]

    def _noise_var(self, clean):
        noise = self.cfg.detector.sim.noise
        var = np.full(np.shape(clean), noise.read_sigma**2)
        if noise.shot_counts_per_unit > 0.0:
            var = var + clean / noise.shot_counts_per_unit
        return var

    def _noisy(self, clean, exposure_s, rng):
        noise = self.cfg.detector.sim.noise
        values = clean.astype(np.float64)
        if noise.shot_counts_per_unit > 0.0:
            values = rng.poisson(values * noise.shot_counts_per_unit) / noise.shot_counts_per_unit
        values = values + noise.dark_offset * exposure_s
        if noise.read_sigma > 0.0:
            values = values + rng.normal(0.0, noise.read_sigma, size=values.shape)
        return values


def _still_line(axes_deg, exposure_s) -> FlyLine:
    return FlyLine(np.array([-1]), -1, np.asarray(axes_deg, dtype=np.float64).copy(), 0.0, 0.0, 1.0,
                   float(exposure_s))
