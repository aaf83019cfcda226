"""Frame processing on rendered frames: the camera's region mean against the point detector, brackets
against single exposures, auto-exposure, darks, bad frames, EXR round trips."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gonio import frames
from gonio.sim.aperture import aperture_radiance_factor
from gonio.sim.camera import CameraSettings, SimCamera
from gonio.sim.materials import load

LAMBERT = load("lambert:albedo=0.7")


def _unit(theta_deg, phi_deg):
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([[math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)]])


@pytest.mark.parametrize("pose", [(0.0, 0.0, 30.0, 180.0), (30.0, 0.0, 45.0, 180.0),
                                  (50.0, 40.0, 20.0, 250.0)])
def test_lambertian_region_mean_matches_the_point_detector(pose):
    s = CameraSettings(width=128, height=128, samples_per_pixel=16, light_half_angle_deg=1.0)
    frame = SimCamera(s, LAMBERT, backend="llvm").render(*pose, exposure_s=0.1, key=(0, 0))
    region = frames.find_sample_region(frame.pixels)
    mean, stderr, n = frames.region_mean(frame.pixels, region, exposure_s=0.1)
    factor, factor_se = aperture_radiance_factor(LAMBERT, _unit(*pose[:2]), _unit(*pose[2:]),
                                                 s.light_half_angle_deg, 1.0, 8192, (11, 12))
    np.testing.assert_allclose(mean, s.radiance * factor[0], rtol=0.01)
    assert n > 1000 and (stderr < 1e-3 * mean).all()


def test_found_region_lies_inside_the_patch():
    cam = SimCamera(CameraSettings(width=96, height=96, samples_per_pixel=8), LAMBERT, backend="llvm")
    frame = cam.render(20.0, 0.0, 40.0, 180.0, 1.0, key=(0, 0))
    region = frames.find_sample_region(frame.pixels, erode_px=1)
    patch = cam.sample_mask(40.0, 180.0)
    assert not (region & ~patch).any() and region.sum() > 0.8 * patch.sum()


def _glossy_camera(**sensor):
    s = CameraSettings(width=96, height=96, samples_per_pixel=16, **sensor)
    return SimCamera(s, load("ggx:alpha=0.15,metal=gold"), seed=4, backend="llvm")


def test_erode_disk_is_scikit_image_erosion_by_a_disk():
    """frames.erode_disk (the simulated camera's region, without scikit-image's morphology and the
    scipy.spatial it imports) against skimage.morphology.erosion(mask, disk(r)), pixel for pixel: random
    masks full and sparse, touching the frame's border, radii from 0 to beyond the frame's size."""
    from skimage import morphology

    rng = np.random.default_rng(3)
    for shape in [(1, 1), (1, 7), (5, 6), (40, 33)]:
        for radius in range(0, 8):
            for p in (0.5, 0.9, 1.0):
                mask = rng.random(shape) < p
                expected = morphology.erosion(mask, morphology.disk(radius))
                assert np.array_equal(frames.erode_disk(mask, radius), expected), (shape, radius, p)
    patch = np.zeros((20, 20), dtype=bool)
    patch[5:15, 4:16] = True
    assert np.count_nonzero(frames.erode_disk(patch, 2)) == 6 * 8     # 2 px off each side
    with pytest.raises(ValueError, match="radius"):
        frames.erode_disk(patch, -1)


def test_bracket_merge_agrees_with_a_single_unsaturated_exposure():
    sensor = dict(black_level=0.002, read_sigma=2e-4, shot_counts_per_unit=2e5, saturation=1.0)
    cam = _glossy_camera(**sensor)
    pose = (30.0, 0.0, 33.0, 180.0)  # near the mirror direction: a bright highlight on the patch
    peak = float(cam.radiance(*pose).max())
    exposures = [0.3 / peak, 1.2 / peak, 4.8 / peak]  # the longer two saturate the highlight
    shots = [cam.render(*pose, t, key=(k, 0)) for k, t in enumerate(exposures)]
    assert frames.saturation_mask(shots[2].pixels, 1.0).any()
    rate, valid = frames.merge_brackets([f.pixels for f in shots], exposures, saturation=1.0,
                                        black_level=0.002)
    region = frames.find_sample_region(shots[0].pixels) & valid
    merged, merged_se, _ = frames.region_mean(rate, region)
    single, single_se, _ = frames.region_mean(shots[0].pixels, region, exposure_s=exposures[0],
                                              black_level=0.002, saturation=1.0)
    assert np.all(np.abs(merged - single) < 4 * np.hypot(merged_se, single_se) + 2e-3 * single)
    # Unsaturated pixels of the long exposure alone are ignored at the clip: the merged highlight is
    # the short exposure's, not the clip level over the exposure.
    hot = frames.saturation_mask(shots[2].pixels, 1.0) & region
    np.testing.assert_allclose(rate[hot].mean(axis=0),
                               ((shots[0].pixels[hot] - 0.002) / exposures[0]).mean(axis=0), rtol=0.05)


def test_saturated_pixels_are_left_out_of_the_mean():
    cam = _glossy_camera(saturation=1.0)
    pose = (30.0, 0.0, 33.0, 180.0)
    from scipy import ndimage

    region = ndimage.binary_erosion(cam.sample_mask(33.0, 180.0), iterations=2)  # given, not found
    t = 1.0 / float(np.median(cam.radiance(*pose)[region].max(axis=1)))  # about half the region clips
    frame = cam.render(*pose, t, key=(0, 0))
    sat = frames.saturation_mask(frame.pixels, 1.0)
    assert (sat & region).any()
    mean, _, n = frames.region_mean(frame.pixels, region, exposure_s=t, saturation=1.0)
    use = region & ~sat
    assert n == use.sum()
    np.testing.assert_allclose(mean, (frame.pixels[use] / t).mean(axis=0), rtol=1e-6)


def test_auto_exposure_puts_the_region_at_the_target():
    cam = _glossy_camera(saturation=1.0)
    pose = (30.0, 0.0, 40.0, 180.0)
    t0 = 0.05 / float(cam.radiance(*pose).max())  # a dim first frame, 5 % of full scale
    first = cam.render(*pose, t0, key=(0, 0))
    region = frames.find_sample_region(first.pixels)
    t = frames.auto_exposure(first.pixels, t0, saturation=1.0, mask=region, target=0.5)
    second = cam.render(*pose, t, key=(1, 0))
    level = np.percentile(second.pixels[region].max(axis=1), 99.0)
    assert level == pytest.approx(0.5, rel=0.05)
    # Too bright: most of the region clipped, so the level is unknown; step down by 4.
    over = cam.render(*pose, 100 * t, key=(2, 0))
    assert frames.auto_exposure(over.pixels, 100 * t, saturation=1.0, mask=region) == pytest.approx(25 * t)


def test_dark_frames_subtract_the_offset_and_dark_signal():
    s = CameraSettings(width=48, height=48, samples_per_pixel=4, black_level=0.05)
    cam = SimCamera(s, LAMBERT, backend="llvm")
    frame = cam.render(0.0, 0.0, 30.0, 180.0, 0.5, key=(0, 0))
    dark = np.full_like(frame.pixels, 0.05)
    net = frames.subtract_dark(frame.pixels, dark)
    np.testing.assert_allclose(net, cam.radiance(0.0, 0.0, 30.0, 180.0, seed_state=_state(cam)) * 0.5,
                               rtol=1e-5, atol=1e-7)
    with pytest.raises(frames.FrameError, match=r"frame: the dark frame has shape \(2, 2, 3\)"):
        frames.subtract_dark(frame.pixels, np.zeros((2, 2, 3)))


def _state(cam):
    from gonio.sim.aperture import seed_state
    from gonio.sim.camera import _RENDER_STREAM

    return seed_state(cam.seed, _RENDER_STREAM, 0, 0)


@pytest.mark.parametrize(("pixels", "kwargs", "message"), [
    (np.zeros((4, 4)), {}, r"frame: expected an image of shape \(H, W, 3\), got shape \(4, 4\)"),
    (np.zeros((4, 5, 3)), {"shape": (4, 4)}, r"frame: expected 4x4 pixels \(W x H\), got 5x4"),
    (np.where(np.arange(48).reshape(4, 4, 3) == 7, np.nan, 0.0), {},
     r"frame: 1 pixel\(s\) are NaN or infinite \(first at row 0, column 2\)"),
    (np.ones((4, 4, 3)), {"saturation": 1.0},
     r"frame: every pixel is saturated \(>= 1\); shorten the exposure"),
])
def test_bad_frames_raise_one_line(pixels, kwargs, message):
    with pytest.raises(frames.FrameError, match=message) as info:
        frames.check_frame(pixels, **kwargs)
    assert "\n" not in str(info.value)


def test_a_bracket_saturated_everywhere_is_refused():
    with pytest.raises(frames.FrameError, match="brackets: every pixel is saturated in every exposure"):
        frames.merge_brackets([np.ones((4, 4, 3))] * 2, [1.0, 2.0], saturation=1.0)
    with pytest.raises(frames.FrameError, match="no contrast"):
        frames.find_sample_region(np.zeros((8, 8, 3)))


def test_exr_round_trip_keeps_pixels_metadata_and_hash(tmp_path):
    import OpenImageIO as oiio

    cam = SimCamera(CameraSettings(width=40, height=30, samples_per_pixel=2), LAMBERT, backend="llvm")
    frame = cam.render(10.0, 0.0, 20.0, 90.0, 0.25, key=(1, 0))
    path = tmp_path / "f.exr"
    digest = frames.write_exr(path, frame)
    back = frames.read_exr(path)
    assert np.array_equal(back.pixels, frame.pixels) and back.pixels.shape == (30, 40, 3)
    assert back.metadata["exposure_s"] == 0.25 and back.metadata["theta_o_deg"] == 20.0
    assert back.metadata["camera"]["width"] == 40 and digest == frames.content_hash(frame.pixels)
    # Rewrite the pixels under the old header: the hash no longer matches.
    spec = oiio.ImageSpec(40, 30, 3, oiio.FLOAT)
    spec.attribute("gonio:sha256", digest)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec) and out.write_image(np.zeros((30, 40, 3), np.float32))
    out.close()
    with pytest.raises(frames.FrameError, match="content hash mismatch"):
        frames.read_exr(path)
