"""The simulated camera: geometry against closed forms, keyed determinism, the sensor model, backends."""

from __future__ import annotations

import math

import drjit as dr
import numpy as np
import pytest

from gonio.sim.camera import CameraSettings, SimCamera
from gonio.sim.materials import load

LAMBERT = load("lambert:albedo=0.5")
SMALL = CameraSettings(width=96, height=96, samples_per_pixel=8)


def test_lambertian_under_a_disc_light_at_normal_incidence_reflects_rho_sin2_alpha(backend):
    # A disc of radiance L subtending α gives an irradiance π L sin²α at the centre (exactly), so a
    # Lambertian of albedo ρ has radiance ρ L sin²α. Central pixels see points within ~1 mm of the
    # centre, where the irradiance differs from that by < 1e-5.
    s = CameraSettings(width=64, height=64, samples_per_pixel=64, light_half_angle_deg=2.0)
    cam = SimCamera(s, LAMBERT, backend=backend)
    img = cam.radiance(0.0, 0.0, 40.0, 180.0, seed_state=(5, 6))
    centre = img[28:36, 28:36].reshape(-1, 3)
    want = 0.5 * s.radiance * math.sin(math.radians(2.0)) ** 2
    np.testing.assert_allclose(centre.mean(axis=0), want, rtol=2e-3)


@pytest.mark.parametrize("pose", [(0.0, 0.0, 0.0, 0.0), (30.0, 0.0, 45.0, 180.0), (20.0, 90.0, 60.0, 300.0)])
def test_the_patch_is_centred_and_as_large_as_its_projection(pose, backend):
    cam = SimCamera(SMALL, LAMBERT, backend=backend)
    mask = cam.sample_mask(pose[2], pose[3])
    rows, cols = np.nonzero(mask)
    # The patch centre is on the optical axis: the mask is centred within a pixel or so (perspective
    # shifts the centroid of a tilted square by a little).
    assert abs(rows.mean() - 47.5) < 1.5 and abs(cols.mean() - 47.5) < 1.0
    # Its area in pixels: the patch's solid angle seen from the pinhole, over a pixel's, to first order
    # (side a, distance D, tilt θo): (a/D)² cos θo / (2 tan(fov/2)/H)².
    pixel = 2 * math.tan(math.radians(SMALL.fov_deg / 2)) / SMALL.height
    want = (SMALL.sample_size_m / SMALL.distance_m) ** 2 * math.cos(math.radians(pose[2])) / pixel**2
    assert mask.sum() == pytest.approx(want, rel=0.03)
    frame = cam.render(*pose, exposure_s=1.0, key=(0, 0))
    lit = frame.pixels.sum(axis=2) > 0
    from scipy import ndimage

    # A dark surround: lit pixels are those of the patch and the partly covered ones around it.
    assert not (lit & ~ndimage.binary_dilation(mask, np.ones((3, 3), bool))).any()
    assert lit[mask].all()


def test_keyed_frames_are_reproducible_and_keys_differ(backend):
    s = CameraSettings(width=32, height=32, samples_per_pixel=4, read_sigma=1e-3, shot_counts_per_unit=1e4)
    a = SimCamera(s, LAMBERT, seed=7, backend=backend)
    b = SimCamera(s, LAMBERT, seed=7, backend=backend)
    b.render(10.0, 0.0, 20.0, 180.0, 0.1)  # unkeyed use must not shift keyed frames
    fa = a.render(10.0, 0.0, 20.0, 180.0, 0.1, key=(3, 1))
    fb = b.render(10.0, 0.0, 20.0, 180.0, 0.1, key=(3, 1))
    assert np.array_equal(fa.pixels, fb.pixels)
    assert not np.array_equal(fa.pixels, a.render(10.0, 0.0, 20.0, 180.0, 0.1, key=(3, 2)).pixels)
    assert fa.metadata["key"] == [3, 1] and fa.metadata["exposure_s"] == 0.1
    assert fa.metadata["theta_o_deg"] == 20.0 and fa.metadata["camera"]["width"] == 32


def test_vignetting_is_cos4_of_the_ray_angle(backend):
    plain = SimCamera(SMALL, LAMBERT, backend=backend)
    vig = SimCamera(CameraSettings(**{**SMALL.__dict__, "vignetting": True}), LAMBERT, backend=backend)
    a = plain.radiance(0.0, 0.0, 0.0, 0.0, seed_state=(1, 1))[..., 0]
    b = vig.radiance(0.0, 0.0, 0.0, 0.0, seed_state=(1, 1))[..., 0]
    inside = np.zeros_like(a, bool)
    inside[30:66, 30:66] = True  # well inside the patch (it spans pixels ~25..71; no partial pixels)
    t = math.tan(math.radians(SMALL.fov_deg / 2))
    c = (np.arange(96) + 0.5) / 96 * 2 - 1
    r2 = (c[None, :] ** 2 + c[:, None] ** 2) * t * t
    cos4 = 1.0 / (1.0 + r2) ** 2
    np.testing.assert_allclose(b[inside] / a[inside], cos4[inside], rtol=2e-4)


def test_sensor_black_level_read_noise_and_saturation(backend):
    s = CameraSettings(width=64, height=64, samples_per_pixel=4, black_level=0.01, read_sigma=2e-3,
                       saturation=0.02)
    frame = SimCamera(s, LAMBERT, backend=backend).render(0.0, 0.0, 30.0, 180.0, 10.0, key=(0, 0))
    px = frame.pixels.astype(np.float64)
    surround = px[:4].ravel()
    assert surround.mean() == pytest.approx(0.01, abs=3e-4)
    assert surround.std(ddof=1) == pytest.approx(2e-3, rel=0.1)
    assert px.max() == np.float32(0.02)  # the lit patch clips at full scale
    assert (px[28:36, 28:36] == np.float32(0.02)).all()


def test_a_gold_highlight_is_gold(backend):
    s = CameraSettings(width=64, height=64, samples_per_pixel=8)
    cam = SimCamera(s, load("ggx:alpha=0.2,metal=gold"), backend=backend)
    img = cam.radiance(30.0, 0.0, 30.0, 180.0)
    r, g, b = img[24:40, 24:40].reshape(-1, 3).mean(axis=0)
    assert r > g > b > 0


def test_settings_errors_name_the_field(backend):
    with pytest.raises(ValueError, match=r"camera.width: must be an integer in \[1, 8192\], got 0"):
        CameraSettings(width=0)
    with pytest.raises(ValueError, match=r"camera.saturation: must exceed black_level"):
        CameraSettings(black_level=2.0, saturation=1.0)
    with pytest.raises(ValueError, match=r"camera.distance_m: must exceed the sample's diagonal"):
        CameraSettings(distance_m=0.05)
    cam = SimCamera(SMALL, LAMBERT, backend=backend)
    with pytest.raises(ValueError, match=r"theta_o_deg: must be in \[0°, 90°\), got 95.0"):
        cam.render(0.0, 0.0, 95.0, 0.0, 1.0)
    with pytest.raises(ValueError, match=r"key: must be \(step, attempt\)"):
        cam.render(0.0, 0.0, 45.0, 0.0, 1.0, key=(1, -1))


@pytest.mark.skipif(not dr.has_backend(dr.JitBackend.CUDA), reason="no CUDA device")
def test_cuda_renders_what_llvm_renders():
    pose = (30.0, 0.0, 45.0, 180.0)
    material = load("ggx:alpha=0.3,metal=copper")
    llvm = SimCamera(SMALL, material, backend="llvm").radiance(*pose, seed_state=(9, 9))
    cuda = SimCamera(SMALL, material, backend="cuda").radiance(*pose, seed_state=(9, 9))
    # Same Philox lanes, same arithmetic; only the rounding of the math functions may differ.
    np.testing.assert_allclose(cuda, llvm, rtol=1e-4, atol=1e-7 * float(llvm.max()))


class _Traced:
    """A material seen only through eval_dr (no eval_with): the camera traces its kernel on every frame."""

    def __init__(self, material):
        self.material = material

    def eval_dr(self, wi, wo):
        return self.material.eval_dr(wi, wo)


@pytest.mark.parametrize("vignetting", [False, True])
def test_the_frozen_render_replays_the_traced_kernel_bit_for_bit(vignetting, backend):
    """A gonio Material's frames replay one recorded kernel (drjit.freeze) with new poses, keys and light:
    every pixel equals the kernel traced afresh for that frame, frame after frame."""
    s = CameraSettings(width=40, height=24, samples_per_pixel=4, vignetting=vignetting)
    material = load("ggx:alpha=0.2,metal=gold")
    frozen = SimCamera(s, material, backend=backend)
    traced = SimCamera(s, _Traced(material), backend=backend)
    poses = [(10.0, 0.0, 20.0, 180.0), (30.0, 45.0, 35.0, 170.0), (0.0, 0.0, 60.0, 90.0),
             (45.0, 10.0, 5.0, 0.0)]
    for i, pose in enumerate(poses):
        a = frozen.radiance(*pose, seed_state=(7919 * i + 1, i), source_radiance=1.0 + i)
        b = traced.radiance(*pose, seed_state=(7919 * i + 1, i), source_radiance=1.0 + i)
        assert a.dtype == b.dtype == np.float32 and a.any()
        np.testing.assert_array_equal(a, b)
