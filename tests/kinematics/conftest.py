"""What every kinematic design must satisfy on a round trip, shared by the designs' tests."""

import numpy as np
import pytest

from gonio.geometry import sph_to_vec
from gonio.kinematics import OCCLUSION, OK
from gonio.kinematics.base import POLE_EPS, circular_distance_deg

# A direction closer than POLE_EPS to the pole is taken as the pole (its azimuth is free): the round
# trip is exact to that snap, and to round-off elsewhere.
_ATOL = max(1e-12, 1.5 * POLE_EPS)


def _round_trip(kin, ti, pi, to, po, current):
    """inverse -> forward reaches every pose the light arm does not hide (the shipped configs reach
    the whole hemisphere up to theta_max), within the limits. Returns (axes, ok) for design checks."""
    axes = kin.inverse(ti, pi, to, po, current_deg=current)
    codes = kin.feasibility(ti, pi, to, po)
    cos_sep = np.clip(np.sum(sph_to_vec(ti, pi) * sph_to_vec(to, po), -1), -1, 1)
    sep = np.degrees(np.arccos(cos_sep))
    clear_cut = np.abs(sep - kin.clearance_deg) > 1e-6
    np.testing.assert_array_equal((codes == OK)[clear_cut], (sep >= kin.clearance_deg)[clear_cut])
    np.testing.assert_array_equal(codes[codes != OK], OCCLUSION)
    ok = codes == OK
    np.testing.assert_array_equal(np.isnan(axes).any(axis=1), ~ok)
    lo, hi = kin.limits_deg.T
    assert np.all((axes[ok] >= lo) & (axes[ok] <= hi))
    wi, wo = kin.directions(axes[ok])
    np.testing.assert_allclose(wi, sph_to_vec(ti[ok], pi[ok]), atol=_ATOL)
    np.testing.assert_allclose(wo, sph_to_vec(to[ok], po[ok]), atol=_ATOL)
    bi, qi, bo, qo = kin.forward(axes[ok])
    np.testing.assert_allclose(bi, ti[ok], atol=_ATOL)
    np.testing.assert_allclose(bo, to[ok], atol=_ATOL)
    for q, t, p in ((qi, ti[ok], pi[ok]), (qo, to[ok], po[ok])):
        assert np.all((q >= 0.0) & (q < 2 * np.pi))
        moved = t > 1e-6  # the azimuth of a pole direction means nothing
        np.testing.assert_allclose(circular_distance_deg(np.degrees(q), np.degrees(p))[moved], 0.0, atol=1e-9)
    return axes, ok


@pytest.fixture(scope="session")
def check_round_trip():
    return _round_trip
