import numpy as np
import pytest

from gonio.calibrate import CalibrationError, calibrate
from gonio.store import Measurement


def _reading(step, kind, t, theta_i_deg, signal, stderr=None):
    s = np.asarray(signal, float)
    return Measurement(step=step, kind=kind, pose=step if kind == 0 else -1, commanded_deg=np.zeros(4),
                       actual_deg=np.zeros(4), angles_deg=np.array([theta_i_deg, 0.0, 30.0, 90.0]),
                       virtual_s=t, exposure_s=0.1, frames=1, signal=s,
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
    np.testing.assert_array_equal(cal.stddev, 0.0)


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
