import numpy as np
import pytest

from gonio.calibrate import CalibrationError, calibrate
from gonio.store import Measurement


def _reading(step, kind, t, theta_i_deg, signal, stderr=None, exposure_s=0.1):
    s = np.asarray(signal, float)
    return Measurement(step=step, kind=kind, pose=step if kind == 0 else -1, commanded_deg=np.zeros(4),
                       actual_deg=np.zeros(4), angles_deg=np.array([theta_i_deg, 0.0, 30.0, 90.0]),
                       clock_s=t, campaign_s=t, exposure_s=exposure_s, frames=1, signal=s,
                       stderr=np.zeros_like(s) if stderr is None else np.asarray(stderr, float))


def test_recovers_brdf_through_dark_and_drifting_source():
    """Synthetic readings from S = K(t)·f·cosθi + D(t): calibration returns f exactly, although the
    source drifts linearly and the dark signal changes between dark readings."""
    rho = 0.99
    K = lambda t: 1000.0 * (1 + 0.01 * t)  # noqa: E731
    D = lambda t: 5.0 + 0.1 * t  # noqa: E731
    f = np.array([[0.2, 0.3, 0.4], [1.5, 1.0, 0.5], [0.05, 0.05, 0.05]])
    ms, step = [], 0

    def add(kind, t, ti, sig):
        nonlocal step
        ms.append(_reading(step, kind, t, ti, sig))
        step += 1

    add(1, 0.0, 0.0, [D(0.0)] * 3)
    add(2, 1.0, 10.0, np.full(3, K(1.0) * rho / np.pi * np.cos(np.radians(10.0)) + D(1.0)))
    for i, (t, ti) in enumerate([(2.0, 20.0), (3.0, 45.0), (4.0, 70.0)]):
        add(0, t, ti, K(t) * f[i] * np.cos(np.radians(ti)) + D(t))
    add(2, 5.0, 10.0, np.full(3, K(5.0) * rho / np.pi * np.cos(np.radians(10.0)) + D(5.0)))
    add(1, 6.0, 10.0, [D(6.0)] * 3)
    cal = calibrate(ms, rho)
    np.testing.assert_allclose(cal.value, f, rtol=1e-12)
    assert cal.steps.tolist() == [2, 3, 4]
    assert cal.campaign_s.tolist() == [2.0, 3.0, 4.0]
    np.testing.assert_array_equal(cal.stddev, 0.0)


def test_mixed_exposures_calibrate_to_the_truth():
    """A pose read at 0.25 s against darks at 0.05 s and references at 0.1 s: every reading is a rate
    (a dark current grows with the exposure), so f comes out exact, not 2.5x too bright."""
    rho, k_rate, dark_rate = 0.99, 2000.0, 40.0
    f = np.array([0.2, 0.3, 0.4])
    ti = 30.0

    def sig(rate, exposure):
        return np.full(3, rate * exposure) if np.ndim(rate) == 0 else rate * exposure

    ms = [
        _reading(0, 1, 0.0, 0.0, sig(dark_rate, 0.05), exposure_s=0.05),
        _reading(1, 2, 1.0, 0.0, sig(k_rate * rho / np.pi + dark_rate, 0.1), exposure_s=0.1),
        _reading(2, 0, 2.0, ti, sig(k_rate * f * np.cos(np.radians(ti)) + dark_rate, 0.25), exposure_s=0.25),
        _reading(3, 0, 3.0, ti, sig(k_rate * f * np.cos(np.radians(ti)) + dark_rate, 0.02), exposure_s=0.02),
    ]
    cal = calibrate(ms, rho)
    np.testing.assert_allclose(cal.value, [f, f], rtol=1e-12)


def test_time_that_goes_backwards_is_refused_with_the_steps():
    ms = [_reading(0, 1, 0.0, 0.0, [1.0]), _reading(1, 2, 5.0, 0.0, [101.0]),
          _reading(2, 0, 3.0, 0.0, [51.0]), _reading(3, 2, 6.0, 0.0, [101.0])]
    with pytest.raises(CalibrationError, match=r"goes backwards from step 1 \(5.000 s\) to step 2"):
        calibrate(ms, 1.0)


def test_interpolated_reference_carries_its_own_uncertainty():
    """Halfway between two references of relative error e each, K has relative error e/√2."""
    ms = [_reading(0, 1, 0.0, 0.0, [0.0], [0.0]), _reading(1, 2, 0.0, 0.0, [100.0], [1.0]),
          _reading(2, 0, 1.0, 0.0, [50.0], [0.0]), _reading(3, 2, 2.0, 0.0, [100.0], [1.0])]
    cal = calibrate(ms, 1.0)
    np.testing.assert_allclose(cal.value[0, 0], 0.5 / np.pi)
    np.testing.assert_allclose(cal.stddev[0, 0], 0.5 / np.pi * 0.01 / np.sqrt(2.0))


def test_uncertainty_propagates():
    ms = [_reading(0, 1, 0.0, 0.0, [1.0], [0.0]), _reading(1, 2, 1.0, 0.0, [1.0 + 100.0], [0.0]),
          _reading(2, 0, 2.0, 0.0, [1.0 + 50.0], [1.0])]
    cal = calibrate(ms, 1.0)
    # f = 50/100 / π; relative error of the net pose signal is 1/50
    np.testing.assert_allclose(cal.value[0, 0], 0.5 / np.pi)
    np.testing.assert_allclose(cal.stddev[0, 0], 0.5 / np.pi / 50.0)


def test_missing_dark_or_reference_is_an_error():
    pose = _reading(1, 0, 1.0, 0.0, [1.0])
    with pytest.raises(CalibrationError, match="no dark"):
        calibrate([_reading(0, 2, 0.0, 0.0, [1.0]), pose], 0.99)
    with pytest.raises(CalibrationError, match="no white-reference"):
        calibrate([_reading(0, 1, 0.0, 0.0, [1.0]), pose], 0.99)
    with pytest.raises(CalibrationError, match=r"reference_albedo must be in \(0, 1\]"):
        calibrate([pose], 1.5)
    with pytest.raises(CalibrationError, match="not above the dark"):
        calibrate([_reading(0, 1, 0.0, 0.0, [5.0]), _reading(1, 2, 1.0, 0.0, [5.0]), pose], 0.99)


def test_simulated_readings_at_mixed_exposures_calibrate_to_the_material():
    """Darks, references and poses read by the simulated detector at four different exposures, with a
    dark current and shot noise: the calibrated Lambertian comes out ρ/π within its stated stddev."""
    from gonio.config import load_config, parse_config
    from gonio.wiring import build_gantry

    data = load_config().model_dump(mode="json", exclude_defaults=True)
    data.setdefault("detector", {}).setdefault("sim", {})["noise"] = {"dark_offset": 3.0,
                                                                      "shot_counts_per_unit": 2000.0}
    data.setdefault("light", {}).setdefault("sim", {})["radiance"] = 1e7
    cfg = parse_config(data)
    g = build_gantry(cfg, "lambert:albedo=0.4", seed=7)
    g.connect()
    kin = g.kinematics
    ms = []

    def read(kind, target, axes, exposure):
        for axis, x in zip(g.axes.values(), axes, strict=True):
            axis.move_to(float(x))
        g.wait_until_still()
        g.light.set_on(kind != 1)
        g.set_target(target)
        r = g.detector.measure(exposure, key=(len(ms), 1))
        ti, pi_, to, po = kin.forward(np.asarray(axes, float)[None, :])
        ms.append(Measurement(step=len(ms), kind=kind, pose=len(ms) if kind == 0 else -1,
                              commanded_deg=np.asarray(axes, float), actual_deg=np.asarray(axes, float),
                              angles_deg=np.degrees([ti[0], pi_[0], to[0], po[0]]), clock_s=g.clock.now(),
                              campaign_s=g.clock.now(), exposure_s=r.exposure_s, frames=1,
                              signal=r.signal, stderr=r.stderr))

    ref = [0.0, 0.0, 180.0, 45.0]
    read(1, "sample", ref, 0.05)
    read(2, "reference", ref, 0.1)
    for axes, exposure in (([0.0, 30.0, 180.0, 40.0], 0.4), ([0.0, 60.0, 150.0, 20.0], 0.02),
                           ([0.0, 45.0, 160.0, 60.0], 0.25)):
        read(0, "sample", axes, exposure)
    read(2, "reference", ref, 0.1)
    read(1, "sample", ref, 0.2)
    cal = calibrate(ms, cfg.reference.albedo)
    z = (cal.value - 0.4 / np.pi) / cal.stddev
    assert np.all(np.abs(z) < 4.0), z
    np.testing.assert_allclose(cal.value, 0.4 / np.pi, rtol=0.02)
    # Without dividing by the exposure the 0.4 s pose would be 4x too bright: the test has teeth.
    assert ms[2].exposure_s / ms[1].exposure_s == 4.0


# -- the white standard per channel, the textbook formula, readings with a shape ------------------------
def test_the_textbook_formula_with_the_reference_at_the_poses_incidence():
    """θi_ref = θi: f_r = ρ_ref/π · (S − S_dark)/(S_ref − S_dark), channel by channel, with ρ_ref per
    channel (a standard that is slightly yellow)."""
    rho = np.array([0.99, 0.97, 0.93])
    ti, k, d = 35.0, 800.0, 3.0
    f = np.array([0.1, 0.2, 0.3])
    s_ref = k * rho / np.pi * np.cos(np.radians(ti)) + d
    s = k * f * np.cos(np.radians(ti)) + d
    ms = [_reading(0, 1, 0.0, ti, [d] * 3), _reading(1, 2, 1.0, ti, s_ref), _reading(2, 0, 2.0, ti, s)]
    cal = calibrate(ms, rho)
    np.testing.assert_allclose(cal.value[0], rho / np.pi * (s - d) / (s_ref - d), rtol=1e-14)
    np.testing.assert_allclose(cal.value[0], f, rtol=1e-12)
    # one number for all channels would call the blue channel 6 % too dark
    assert calibrate(ms, 0.99).value[0, 2] == pytest.approx(f[2] * 0.99 / 0.93, rel=1e-12)


def test_the_cosine_of_the_references_incidence_enters_and_the_viewing_angle_does_not():
    """References read at θi_ref = 0 and at 60°: both give the same f_r (cos θi_ref corrects it); poses
    read at any θo with the same θi give the same f_r for a Lambertian (no cos θo: the detector sees
    radiance)."""
    rho, k = 0.99, 500.0
    f = np.full(3, 0.5 / np.pi)
    out = []
    for ti_ref in (0.0, 60.0):
        ms = [_reading(0, 1, 0.0, 0.0, np.zeros(3)),
              _reading(1, 2, 1.0, ti_ref, np.full(3, k * rho / np.pi * np.cos(np.radians(ti_ref))))]
        for step, to in enumerate((0.0, 40.0, 80.0), start=2):
            m = _reading(step, 0, float(step), 50.0, k * f * np.cos(np.radians(50.0)))
            ms.append(Measurement(**{**m.__dict__, "angles_deg": np.array([50.0, 0.0, to, 180.0])}))
        out.append(calibrate(ms, rho).value)
    np.testing.assert_allclose(out[0], np.broadcast_to(f, (3, 3)), rtol=1e-12)
    np.testing.assert_allclose(out[1], out[0], rtol=1e-12)


def test_reference_reflectance_must_fit_the_channels():
    ms = [_reading(0, 1, 0.0, 0.0, np.zeros(3)), _reading(1, 2, 1.0, 0.0, np.ones(3))]
    with pytest.raises(CalibrationError, match="2 values for readings of 3 channels"):
        calibrate(ms, [0.9, 0.9])
    with pytest.raises(CalibrationError, match=r"in \(0, 1\]"):
        calibrate(ms, [0.9, 1.2, 0.9])


def test_readings_with_a_shape_calibrate_channel_by_channel():
    shape = (2, 3)
    k, d = 100.0, 1.0
    f = np.arange(1, 7, dtype=float).reshape(shape) / 20
    ms = [_reading(0, 1, 0.0, 0.0, np.full(shape, d)),
          _reading(1, 2, 1.0, 0.0, np.full(shape, k * 0.99 / np.pi + d)),
          _reading(2, 0, 2.0, 0.0, k * f + d)]
    np.testing.assert_allclose(calibrate(ms, 0.99).value[0], f.ravel(), rtol=1e-12)


def test_drift_interpolation_is_a_local_cubic_that_falls_back_across_long_gaps():
    from gonio.calibrate import interpolate_readings, interpolation_weights

    tk = np.array([0.0, 10.0, 20.0, 30.0, 40.0, 1000.0, 1010.0, 1020.0])
    t = np.linspace(-5.0, 1025.0, 400)
    idx, w = interpolation_weights(t, tk)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-12)
    # A cubic drift inside the first block is followed exactly where two readings stand on each side.
    cubic = lambda x: 1.0 + 1e-3 * x - 4e-5 * x**2 + 2e-6 * x**3  # noqa: E731
    y = cubic(tk)[:, None]
    value, _ = interpolate_readings(t, tk, y, np.zeros_like(y))
    inner = (t >= 10.0) & (t <= 30.0)
    np.testing.assert_allclose(value[inner, 0], cubic(t[inner]), rtol=1e-12)
    # A straight line everywhere, constant beyond the ends.
    line = (2.0 + 0.01 * tk)[:, None]
    value, _ = interpolate_readings(t, tk, line, np.zeros_like(line))
    np.testing.assert_allclose(value[:, 0], 2.0 + 0.01 * np.clip(t, 0.0, 1020.0), rtol=1e-12)
    # Across the 960 s pause nothing on the far side is used, and inside it only its two ends.
    near = (t > 20.0) & (t < 40.0)
    assert np.all(np.isin(idx[near][w[near] != 0.0], [1, 2, 3, 4]))
    gap = (t > 40.0) & (t < 1000.0)
    assert np.all(np.isin(idx[gap][w[gap] != 0.0], [4, 5]))
    # Standard errors add as the weights say.
    e = np.full((tk.size, 1), 0.1)
    _, sd = interpolate_readings(np.array([25.0]), tk, line, e)
    assert sd[0, 0] == pytest.approx(0.1 * np.sqrt(2 * (1 / 16) ** 2 + 2 * (9 / 16) ** 2), rel=1e-12)
