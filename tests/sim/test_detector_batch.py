"""Batched readings: many poses in one launch give, reading for reading and bit for bit, what the
one-pose ``measure`` gives with the same (seed, step, attempt); rows of a launch are independent."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.config import load_config, parse_config, with_sim_detector
from gonio.sim import detector as detector_module
from gonio.sim import materials
from gonio.sim.aperture import CHUNK_SAMPLES, aperture_factors, aperture_radiance_factor
from gonio.sim.gantry import SimGantry

# Each test runs on every Dr.Jit backend (CUDA skipped without a device).
pytestmark = pytest.mark.usefixtures("backend")

GLOSSY = "ggx:alpha=0.05,fresnel=conductor,eta=0.37,k=2.82"
NOISE = {"shot_counts_per_unit": 1e4, "read_sigma": 1e-3, "dark_offset": 0.5}


def _gantry(config: str, material: str, noise: dict, kind: str = "photodiode", seed: int = 7) -> SimGantry:
    data = load_config(config).model_dump()
    data["detector"]["sim"]["noise"].update(noise)
    data["detector"]["sim"]["half_angle_deg"] = 2.0
    data["light"]["sim"]["drift_per_hour"] = 0.5  # every reading sees another source radiance
    cfg = with_sim_detector(parse_config(data), kind)
    if cfg.drivers() != {"sim"}:
        pytest.skip(f"config {config} has real devices")
    gantry = SimGantry.from_config(cfg, material, seed=seed)
    gantry.connect()
    return gantry


def _plan(gantry: SimGantry, n: int, seed: int = 3):
    """n reachable poses (axis positions inside the limits) with a mix of targets, shutter states,
    exposures and frames, as a campaign has them."""
    rng = np.random.default_rng(seed)
    names = gantry.kinematics.axis_names
    lo = np.array([gantry.axes[a].cfg.min_deg for a in names])
    hi = np.array([gantry.axes[a].cfg.max_deg for a in names])
    axes = lo + (hi - lo) * rng.uniform(0.2, 0.8, (n, len(names)))
    targets = rng.choice(["sample", "reference"], n, p=[0.8, 0.2]).tolist()
    lit = rng.uniform(size=n) > 0.15  # some darks
    exposure = rng.choice([0.05, 0.1, 0.4], n).tolist()
    frames = rng.choice([1, 1, 3], n).tolist()
    keys = [(int(s), int(a)) for s, a in zip(rng.permutation(10 * n)[:n], rng.integers(0, 3, n), strict=True)]
    return axes, keys, targets, lit, exposure, frames


def _one_at_a_time(gantry: SimGantry, axes, keys, targets, lit, exposure, frames):
    """measure() pose by pose, the gantry driven there; returns the readings and what each saw."""
    readings, actual, sources, times = [], [], [], []
    for k, key in enumerate(keys):
        for name, target in zip(gantry.kinematics.axis_names, axes[k], strict=True):
            gantry.axes[name].move_to(target)
        gantry.clock.sleep(max(a.arrival_time_s() for a in gantry.axes.values()) - gantry.clock.now())
        gantry.light.set_on(bool(lit[k]))
        gantry.detector.set_target(targets[k])
        actual.append(gantry.detector.actual_axes_deg())
        sources.append(gantry.light.radiance())
        times.append(gantry.clock.now())
        readings.append(gantry.detector.measure(exposure[k], frames=frames[k], key=key))
    return readings, np.array(actual), sources, times


def _assert_same(batch, single):
    assert len(batch) == len(single)
    for b, s in zip(batch, single, strict=True):
        np.testing.assert_array_equal(b.signal, s.signal)
        np.testing.assert_array_equal(b.stderr, s.stderr)
        assert (b.exposure_s, b.frames) == (s.exposure_s, s.frames)
        assert b.extra.keys() == s.extra.keys()
        for name, value in s.extra.items():
            if isinstance(value, np.ndarray):
                np.testing.assert_array_equal(b.extra[name], value)
            else:
                assert b.extra[name] == value, name


@pytest.mark.parametrize("config, material, noise", [
    ("sim", GLOSSY, {}),
    ("sim", "cook-torrance:d=beckmann,m=0.3,metal=gold,rho_s=0.9/0.6/0.3", NOISE),
    ("sim", "lambert:albedo=0.5", NOISE),
    ("sample-stage", "ward:rho_d=0.1,rho_s=0.2,alpha_x=0.1,alpha_y=0.3", NOISE),
])
def test_a_batch_of_poses_is_bit_for_bit_what_measure_gives_one_pose_at_a_time(config, material, noise):
    single = _gantry(config, material, noise)
    axes, keys, targets, lit, exposure, frames = _plan(single, 40)
    readings, actual, sources, times = _one_at_a_time(single, axes, keys, targets, lit, exposure, frames)
    assert any(r.extra["target"] == "reference" for r in readings) and 0.0 in sources  # the mix is there
    batch = _gantry(config, material, noise)  # a new process would start from nothing, too
    got = batch.detector.measure_poses(actual, keys, exposure_s=exposure, frames=frames, targets=targets,
                                       sources=sources, times_s=times)
    _assert_same(got, readings)
    assert batch.clock.now() == 0.0  # the batch moves nothing and takes no gantry time


def test_the_batch_splits_into_launches_and_orders_its_readings_as_given(monkeypatch):
    g = _gantry("sim", GLOSSY, NOISE)
    axes, keys, targets, lit, exposure, frames = _plan(g, 23, seed=9)
    readings, actual, sources, times = _one_at_a_time(g, axes, keys, targets, lit, exposure, frames)
    monkeypatch.setattr(detector_module, "BATCH_ROWS", 4)  # 23 poses: several launches per target
    batch = _gantry("sim", GLOSSY, NOISE)
    got = batch.detector.measure_poses(actual, keys, exposure_s=exposure, frames=frames, targets=targets,
                                       sources=sources, times_s=times)
    _assert_same(got, readings)
    order = np.random.default_rng(1).permutation(23)  # another order: each reading is its key's
    again = _gantry("sim", GLOSSY, NOISE).detector.measure_poses(
        actual[order], [keys[k] for k in order], exposure_s=[exposure[k] for k in order],
        frames=[frames[k] for k in order], targets=[targets[k] for k in order],
        sources=[sources[k] for k in order])
    for k, r in zip(order, again, strict=True):
        np.testing.assert_array_equal(r.signal, readings[k].signal)
        np.testing.assert_array_equal(r.stderr, readings[k].stderr)


def test_a_spectrometer_batch_is_what_it_measures_one_pose_at_a_time():
    single = _gantry("sim", "ggx:alpha=0.2,metal=gold", NOISE, kind="spectrometer")
    axes, keys, targets, lit, exposure, frames = _plan(single, 6)
    readings, actual, sources, times = _one_at_a_time(single, axes, keys, targets, lit, exposure, frames)
    batch = _gantry("sim", "ggx:alpha=0.2,metal=gold", NOISE, kind="spectrometer")
    _assert_same(batch.detector.measure_poses(actual, keys, exposure_s=exposure, frames=frames,
                                              targets=targets, sources=sources, times_s=times), readings)


def test_defaults_are_the_detectors_settings_and_bad_arguments_name_the_field():
    g = _gantry("sim", "lambert:albedo=0.5", {})
    g.light.set_on(True)
    axes = np.tile(g.detector.actual_axes_deg(), (3, 1))
    r = g.detector.measure_poses(axes, [(0, 0), (1, 0), (2, 0)])
    assert [x.exposure_s for x in r] == [g.detector.cfg.exposure_s] * 3
    assert [x.extra["reading"] for x in r] == [0, 1, 2] and g.detector.measure(0.1).extra["reading"] == 3
    assert {x.extra["target"] for x in r} == {"sample"} and all(x.extra["t_s"] == 0.0 for x in r)
    bad = [
        (dict(axes_deg=axes[:, :3], keys=[(0, 0)] * 3), r"axes_deg: expected shape \(P, 4\)"),
        (dict(axes_deg=axes, keys=[(0, 0)] * 2), r"keys: expected one \(step, attempt\) per pose \(3\)"),
        (dict(axes_deg=axes, keys=[(0, -1)] * 3), r"key: must be \(step, attempt\)"),
        (dict(axes_deg=axes, keys=[(0, 0)] * 3, exposure_s=[0.1, 0.2]), r"exposure_s: expected one value"),
        (dict(axes_deg=axes, keys=[(0, 0)] * 3, exposure_s=0.0), r"exposure_s: must be in \(0, 3600\]"),
        (dict(axes_deg=axes, keys=[(0, 0)] * 3, frames=0), r"frames: must be an integer in \[1, 1000\]"),
        (dict(axes_deg=axes, keys=[(0, 0)] * 3, targets="wall"), r"target: 'wall' is not one of"),
        (dict(axes_deg=axes, keys=[(0, 0)] * 3, sources=[1.0, np.nan, 1.0]), r"sources: each source"),
    ]
    for kwargs, message in bad:
        with pytest.raises(ValueError, match=message):
            g.detector.measure_poses(kwargs.pop("axes_deg"), kwargs.pop("keys"), **kwargs)


# -- rows of one launch ---------------------------------------------------------------------------
@pytest.mark.parametrize("samples", [2, 256, 2 * CHUNK_SAMPLES + 37])
def test_each_row_of_a_launch_is_what_it_is_alone(samples, backend):
    """A row's samples come from its own (key, word, counter), and its sums are taken in sample order
    (in chunks of CHUNK_SAMPLES, added in order), so no other row of the launch changes a bit of it."""
    rng = np.random.default_rng(samples)
    n = 9
    wi = rng.normal(size=(n, 3))
    wi[:, 2] = np.abs(wi[:, 2])
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo = wi * np.array([-1.0, -1.0, 1.0])
    keys = rng.integers(0, 1 << 63, n, dtype=np.uint64)
    words = rng.integers(0, 1 << 32, n, dtype=np.uint64)
    counters = rng.integers(0, 20, n)
    m = materials.load("cook-torrance:d=beckmann,m=0.3,metal=gold")
    factor, se = aperture_factors(m, wi, wo, 1.0, 2.0, samples, keys, words, counters, backend)
    assert np.all(se > 0) and np.all(factor > 0)
    for k in (0, 4, n - 1):
        alone = aperture_factors(m, wi[k:k + 1], wo[k:k + 1], 1.0, 2.0, samples, keys[k:k + 1],
                                 words[k:k + 1], counters[k:k + 1], backend)
        np.testing.assert_array_equal(alone[0][0], factor[k])
        np.testing.assert_array_equal(alone[1][0], se[k])
    # One stream for all rows, counters 0..n-1: aperture_radiance_factor, pose p of any batch alike.
    shared = aperture_radiance_factor(m, wi, wo, 1.0, 2.0, samples, (int(keys[0]), int(words[0])), backend)
    rows = aperture_factors(m, wi[3:5], wo[3:5], 1.0, 2.0, samples, keys[[0, 0]], words[[0, 0]], [3, 4],
                            backend)
    np.testing.assert_array_equal(rows[0], shared[0][3:5])
    np.testing.assert_array_equal(rows[1], shared[1][3:5])


def test_row_streams_are_checked():
    m = materials.load("lambert:albedo=0.5")
    w = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    with pytest.raises(ValueError, match=r"keys: expected one per pose \(2\), got 1"):
        aperture_factors(m, w, w, 0.5, 1.0, 16, [1], [1, 2], [0, 1])
    with pytest.raises(ValueError, match=r"words: must be integers in \[0, 2\*\*32\)"):
        aperture_factors(m, w, w, 0.5, 1.0, 16, [1, 2], [1, 1 << 32], [0, 1])
    with pytest.raises(ValueError, match=r"counters: must be integers in \[0, 2\*\*32\)"):
        aperture_factors(m, w, w, 0.5, 1.0, 16, [1, 2], [1, 2], [0, -1])


class _Traced:
    """A material seen through ``eval_dr`` alone: aperture_factors traces its kernel on every call."""

    def __init__(self, material):
        self.eval_dr = material.eval_dr


@pytest.mark.parametrize("samples", [256, 2 * CHUNK_SAMPLES + 37])
def test_the_frozen_render_replays_the_traced_kernel_bit_for_bit_at_any_size(samples, backend):
    """A Material's aperture sums replay one recorded kernel (drjit.freeze) whose sizes come from its
    inputs: launches of 1, 9, 40 and again 9 rows give what the kernel traced anew gives, to the bit."""
    rng = np.random.default_rng(samples + 1)
    m = materials.load("ggx:alpha=0.2,metal=copper")
    for n in (1, 9, 40, 9):
        wi = rng.normal(size=(n, 3))
        wi[:, 2] = np.abs(wi[:, 2])
        wi /= np.linalg.norm(wi, axis=1, keepdims=True)
        wo = wi * np.array([-1.0, -1.0, 1.0])
        keys = rng.integers(0, 1 << 63, n, dtype=np.uint64)
        words = rng.integers(0, 1 << 32, n, dtype=np.uint64)
        counters = rng.integers(0, 20, n)
        frozen = aperture_factors(m, wi, wo, 0.5, 1.0, samples, keys, words, counters, backend)
        traced = aperture_factors(_Traced(m), wi, wo, 0.5, 1.0, samples, keys, words, counters, backend)
        assert frozen[0].shape == (n, 3) and np.all(frozen[0] > 0)
        np.testing.assert_array_equal(frozen[0], traced[0])
        np.testing.assert_array_equal(frozen[1], traced[1])


@pytest.mark.parametrize("config", ["sim", "sample-stage"])
def test_take_then_develop_is_measure_bit_for_bit_and_keeps_the_clock(config):
    """What a campaign does with a detector that reads in batches: take() at each pose as it is reached
    (lamp drifting, darks, the standard, several frames, noise), develop() them all at once: the readings
    measure() gives on a twin gantry, extra included, and the clock at the same time after each."""
    single, batch = _gantry(config, GLOSSY, NOISE), _gantry(config, GLOSSY, NOISE)
    axes, keys, targets, lit, exposure, frames = _plan(single, 25)
    want, _, _, _ = _one_at_a_time(single, axes, keys, targets, lit, exposure, frames)
    takes, clocks = [], []
    for k, key in enumerate(keys):
        for name, target in zip(batch.kinematics.axis_names, axes[k], strict=True):
            batch.axes[name].move_to(target)
        batch.clock.sleep(max(a.arrival_time_s() for a in batch.axes.values()) - batch.clock.now())
        batch.light.set_on(bool(lit[k]))
        batch.detector.set_target(targets[k])
        takes.append(batch.detector.take(exposure[k], frames=frames[k], key=key))
        clocks.append(batch.clock.now())
    assert clocks[-1] == single.clock.now()
    assert batch.detector.batch_readings() == detector_module.CAMPAIGN_CHUNK
    _assert_same(batch.detector.develop(takes), want)
