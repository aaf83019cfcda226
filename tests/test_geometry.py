"""Property tests for gonio.geometry: round trips, Rusinkiewicz angles, MERL binning, canonical forms.

Hypothesis runs derandomized (the same examples on every run). Every angle strategy mixes uniform
floats with the awkward values explicitly: the pole (θ = 0 exactly, subnormal and tiny θ), grazing
(θ at and just below π/2), φ at 0 and just below 2π. Where an angle is undefined (φ at a pole, φd where
θd = 0, φh where θh = 0) or ill-conditioned, the tests compare the vectors the angles describe.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from gonio import geometry as g

SETTINGS = settings(derandomize=True, max_examples=300, deadline=None)

PI = math.pi
HALF_PI = 0.5 * math.pi
TWO_PI = 2.0 * math.pi
NH, ND, NPHI = 90, 90, 180
MERL_SIZE = NH * ND * NPHI
# Vector comparisons: a few ulps of 1, and vec_to_sph sets φ = 0 below ρ = 1e-15 (error up to ~1e-15).
ATOL = 4e-15

THETA_SPECIAL = [
    0.0, 5e-324, 1e-300, 1e-15, 1e-12, 1e-8, 1e-4,
    HALF_PI - 1e-8, HALF_PI - 1e-12, math.nextafter(HALF_PI, 0.0), HALF_PI,
]
PHI_SPECIAL = [
    0.0, 5e-324, 1e-12, HALF_PI, math.nextafter(PI, 0.0), PI, 1.5 * PI,
    TWO_PI - 1e-12, math.nextafter(TWO_PI, 0.0),
]


def _angle(lo, hi, specials, exclude_max=False):
    return st.one_of(
        st.sampled_from([s for s in specials if lo <= s <= hi and not (exclude_max and s >= hi)]),
        st.floats(lo, hi, exclude_max=exclude_max, allow_nan=False, allow_infinity=False),
    )


theta_hemi = _angle(0.0, HALF_PI, THETA_SPECIAL)
theta_sphere = st.one_of(theta_hemi, _angle(0.0, PI, [PI, math.nextafter(PI, 0.0), PI - 1e-12]))
phi_any = _angle(0.0, TWO_PI, PHI_SPECIAL, exclude_max=True)
# Rusinkiewicz angles: θd = π/2 exactly means ωo = −ωi (no half vector); it has its own test.
theta_d_open = _angle(0.0, HALF_PI, THETA_SPECIAL[:-1], exclude_max=True)
direction = st.tuples(theta_hemi, phi_any)


def circ(a, b):
    """Distance between two azimuths, modulo 2π."""
    return abs((a - b + PI) % TWO_PI - PI)


def vec(theta, phi):
    """Plain scalar (θ, φ) -> unit vector, independent of the module."""
    return np.array([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)])


def rot_z(v, angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ v


def pair_conditioning(wi, wo):
    """|ωi + ωo| = 2 cos θd: the half vector (and everything built on it) loses precision as it → 0."""
    return float(np.linalg.norm(wi + wo))


# ---------------------------------------------------------------------------------------------------
# Spherical angles <-> vectors
# ---------------------------------------------------------------------------------------------------


@SETTINGS
@given(theta_sphere, phi_any)
def test_sph_vec_round_trip_from_angles(theta, phi):
    v = g.sph_to_vec(theta, phi)
    assert v.shape == (3,)
    np.testing.assert_allclose(v, vec(theta, phi), rtol=0, atol=ATOL)
    assert abs(np.linalg.norm(v) - 1.0) <= 4e-16
    t2, p2 = g.vec_to_sph(v)
    assert 0.0 <= p2 < TWO_PI
    assert abs(t2 - theta) <= ATOL + ATOL * theta
    if math.sin(theta) > 1e-6:
        assert circ(p2, phi) <= ATOL / math.sin(theta) + ATOL
    # Always well defined, including at the poles where φ is not: the vector itself.
    np.testing.assert_allclose(g.sph_to_vec(t2, p2), v, rtol=0, atol=ATOL)


@SETTINGS
@given(st.tuples(*[st.floats(-1e3, 1e3, allow_nan=False)] * 3), st.sampled_from([1e-200, 1.0, 1e200]))
def test_sph_vec_round_trip_from_vectors(xyz, scale):
    v = np.array(xyz)
    assume(np.linalg.norm(v) > 1e-6)
    unit = v / np.linalg.norm(v)
    # Any length: the direction is all that matters (no under/overflow in a norm at 1e±200).
    theta, phi = g.vec_to_sph(v * scale)
    assert 0.0 <= theta <= PI and 0.0 <= phi < TWO_PI
    np.testing.assert_allclose(g.sph_to_vec(theta, phi), unit, rtol=0, atol=ATOL)


def test_sph_vec_poles_and_grazing_exact():
    assert np.array_equal(g.sph_to_vec(0.0, 0.0), [0.0, 0.0, 1.0])
    for v, theta in [([0, 0, 1], 0.0), ([0, 0, 5], 0.0), ([0, 0, -1], PI), ([1, 0, 0], HALF_PI),
                     ([0, -2, 0], HALF_PI)]:
        t, p = g.vec_to_sph(np.array(v, float))
        assert t == theta
        assert 0.0 <= p < TWO_PI
    # A zero vector has no direction.
    assert np.isnan(g.vec_to_sph(np.zeros(3))[0])
    # φ is 0 at the poles by convention.
    assert g.vec_to_sph(np.array([0.0, 0.0, 1.0]))[1] == 0.0
    assert g.vec_to_sph(np.array([0.0, 0.0, -1.0]))[1] == 0.0
    assert g.vec_to_sph(np.array([0.0, -1.0, 0.0]))[1] == 1.5 * PI
    # φ just below 0 wraps to just below 2π (never to 2π itself).
    assert g.vec_to_sph(np.array([1.0, -1e-12, 0.0]))[1] == pytest.approx(TWO_PI - 1e-12, abs=ATOL)
    assert g.vec_to_sph(np.array([1.0, -1e-300, 0.0]))[1] < TWO_PI


@SETTINGS
@given(st.floats(-1e4, 1e4, allow_nan=False))
def test_wrap_2pi(phi):
    w = float(g.wrap_2pi(phi))
    assert 0.0 <= w < TWO_PI
    assert circ(w, phi) <= 1e-11


def test_vectorized_shapes_broadcast():
    theta = np.linspace(0.0, HALF_PI, 7)[:, None]
    phi = np.linspace(0.0, TWO_PI, 5, endpoint=False)[None, :]
    v = g.sph_to_vec(theta, phi)
    assert v.shape == (7, 5, 3)
    t, p = g.vec_to_sph(v)
    assert t.shape == p.shape == (7, 5)
    th, ph, td, pd = g.to_half_diff(v, v[::-1])
    assert th.shape == (7, 5)
    wi, wo = g.from_half_diff(th, ph, td, pd)
    assert wi.shape == wo.shape == (7, 5, 3)
    assert g.merl_index(th, td, pd).shape == (7, 5)


# ---------------------------------------------------------------------------------------------------
# Mirror direction, reflect, half vector
# ---------------------------------------------------------------------------------------------------


@SETTINGS
@given(theta_sphere, phi_any)
def test_mirror_direction_is_reflect(theta, phi):
    v = g.sph_to_vec(theta, phi)
    tm, pm = g.mirror_angles(theta, phi)
    assert tm == theta and 0.0 <= pm < TWO_PI
    assert circ(pm, phi + PI) <= ATOL
    r = g.reflect(v)
    np.testing.assert_allclose(g.sph_to_vec(tm, pm), r, rtol=0, atol=ATOL)
    # A reflection about the normal: keeps z and length, negates the tangential part, is an involution.
    assert r[2] == v[2] and np.array_equal(r[:2], -v[:2])
    assert np.array_equal(g.reflect(r), v)
    # Its half vector with the original is the normal (above the horizon, away from grazing).
    if math.cos(theta) > 1e-12:
        np.testing.assert_allclose(g.half_vector(v, r), [0.0, 0.0, 1.0], rtol=0, atol=ATOL)
        th, _, td, _ = g.to_half_diff(v, r)
        assert th <= ATOL and abs(td - theta) <= 1e-12


@SETTINGS
@given(direction, direction)
def test_half_vector_bisects(di, do):
    wi, wo = vec(*di), vec(*do)
    cond = pair_conditioning(wi, wo)
    assume(cond > 1e-9)
    tol = ATOL / cond + ATOL
    h = g.half_vector(wi, wo)
    assert abs(np.linalg.norm(h) - 1.0) <= ATOL
    # Equal angles with ωi and ωo, in their plane, and half of the angle between them.
    cos_i, cos_o = float(wi @ h), float(wo @ h)
    assert abs(cos_i - cos_o) <= tol
    assert abs(float(np.cross(wi, wo) @ h)) <= tol
    angle_io = math.atan2(np.linalg.norm(np.cross(wi, wo)), float(wi @ wo))
    angle_ih = math.atan2(np.linalg.norm(np.cross(wi, h)), cos_i)
    assert abs(2.0 * angle_ih - angle_io) <= 1e-12 / cond
    # ωi·h == ωo·h == cos θd.
    _, _, theta_d, _ = g.to_half_diff(wi, wo)
    assert abs(math.cos(theta_d) - cos_i) <= tol and abs(math.cos(theta_d) - cos_o) <= tol
    # Reflecting ωi about h gives ωo.
    np.testing.assert_allclose(2.0 * cos_i * h - wi, wo, rtol=0, atol=1e-14 / cond)


def test_half_vector_opposite_is_nan():
    h = g.half_vector([0.0, 0.0, 1.0], [0.0, 0.0, -1.0])
    assert np.all(np.isnan(h))


# ---------------------------------------------------------------------------------------------------
# Rusinkiewicz half/difference angles
# ---------------------------------------------------------------------------------------------------


@SETTINGS
@given(direction, direction)
def test_half_diff_round_trip_from_vectors(di, do):
    wi, wo = vec(*di), vec(*do)
    cond = pair_conditioning(wi, wo)
    assume(cond > 1e-9)
    th, ph, td, pd = g.to_half_diff(wi, wo)
    # Both directions above the horizon: so is h, and θd <= π/2 always.
    assert 0.0 <= th <= HALF_PI + ATOL and 0.0 <= td <= HALF_PI + ATOL
    assert 0.0 <= ph < TWO_PI and 0.0 <= pd < TWO_PI
    wi2, wo2 = g.from_half_diff(th, ph, td, pd)
    np.testing.assert_allclose(wi2, wi, rtol=0, atol=ATOL)
    np.testing.assert_allclose(wo2, wo, rtol=0, atol=1e-14 / cond)
    # The half vector really is at (θh, φh).
    np.testing.assert_allclose(g.sph_to_vec(th, ph), g.half_vector(wi, wo), rtol=0, atol=ATOL)


@SETTINGS
@given(theta_hemi, phi_any, theta_d_open, phi_any)
def test_half_diff_round_trip_from_angles(th, ph, td, pd):
    wi, wo = g.from_half_diff(th, ph, td, pd)
    assert abs(np.linalg.norm(wi) - 1.0) <= ATOL and abs(np.linalg.norm(wo) - 1.0) <= ATOL
    cos_d = math.cos(td)
    # The defining relations, checked on the vectors (well defined everywhere).
    h = vec(th, ph)
    np.testing.assert_allclose(g.half_vector(wi, wo), h, rtol=0, atol=ATOL / cos_d)
    assert abs(float(wi @ h) - cos_d) <= ATOL and abs(float(wo @ h) - cos_d) <= ATOL
    # d = R_y(−θh) R_z(−φh) ωi, written with explicit matrices.
    c, s = math.cos(-th), math.sin(-th)
    d = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]) @ rot_z(wi, -ph)
    np.testing.assert_allclose(d, vec(td, pd), rtol=0, atol=ATOL)

    th2, ph2, td2, pd2 = g.to_half_diff(wi, wo)
    # θh and θd are always defined; their accuracy degrades as ωo → −ωi (θd → π/2).
    assert abs(th2 - th) <= ATOL / cos_d + ATOL
    assert abs(td2 - td) <= ATOL / cos_d + ATOL
    # φh only where θh is well away from the pole; φd only where both θh and θd are (at θh = 0 the
    # convention φh = 0 moves the whole azimuth into φd).
    sin_h, sin_d = math.sin(th), math.sin(td)
    if sin_h > 1e-6:
        assert circ(ph2, ph) <= ATOL / (sin_h * cos_d)
        if sin_d > 1e-6:
            assert circ(pd2, pd) <= ATOL / (sin_h * sin_d * cos_d)
    elif sin_d > 1e-6:
        # h at (or within 1e-6 of) the pole: only φh + φd is meaningful.
        assert circ(ph2 + pd2, ph + pd) <= 4.0 * (th + th2) / sin_d + 1e-12
    # Vectors: the angles that came back describe the same pair.
    wi2, wo2 = g.from_half_diff(th2, ph2, td2, pd2)
    np.testing.assert_allclose(wi2, wi, rtol=0, atol=ATOL)
    np.testing.assert_allclose(wo2, wo, rtol=0, atol=ATOL / cos_d)


@SETTINGS
@given(theta_hemi, phi_any, phi_any)
def test_half_diff_degenerate_theta_d_half_pi(th, ph, pd):
    """θd = π/2 is ωo = −ωi: from_half_diff still gives that pair; the half vector is undefined."""
    wi, wo = g.from_half_diff(th, ph, HALF_PI, pd)
    np.testing.assert_allclose(wo, -wi, rtol=0, atol=ATOL)


def test_half_diff_poles_exact():
    z = np.array([0.0, 0.0, 1.0])
    assert [float(a) for a in g.to_half_diff(z, z)] == [0.0, 0.0, 0.0, 0.0]
    # Normal incidence, grazing exit in +x: h at 45° toward +x, θd = 45°.
    th, ph, td, pd = g.to_half_diff(z, np.array([1.0, 0.0, 0.0]))
    assert th == pytest.approx(PI / 4, abs=ATOL) and ph == 0.0
    assert td == pytest.approx(PI / 4, abs=ATOL)
    assert circ(pd, PI) <= ATOL  # ωi leans toward −x in the half frame
    # Specular pair: θh = 0, and then φh = 0 by convention and φd carries φi.
    wi = vec(0.7, 2.0)
    th, ph, td, pd = g.to_half_diff(wi, g.reflect(wi))
    assert th <= ATOL and ph == 0.0 and td == pytest.approx(0.7, abs=ATOL)
    assert circ(pd, 2.0) <= ATOL


@SETTINGS
@given(direction, direction)
def test_swap_maps_phi_d_to_phi_d_plus_pi(di, do):
    """Reciprocity in Rusinkiewicz angles: (ωo, ωi) has the same h and θd, and φd + π."""
    wi, wo = vec(*di), vec(*do)
    cond = pair_conditioning(wi, wo)
    assume(cond > 1e-9)
    th, ph, td, pd = g.to_half_diff(wi, wo)
    th2, ph2, td2, pd2 = g.to_half_diff(wo, wi)
    assert th2 == th and ph2 == ph  # same half vector, bit for bit
    assert abs(td2 - td) <= ATOL / cond + ATOL
    np.testing.assert_allclose(g.sph_to_vec(td2, pd2), g.reflect(g.sph_to_vec(td, pd)), rtol=0,
                               atol=1e-14 / cond)
    if math.sin(td) > 1e-6:
        assert circ(pd2, pd + PI) <= 1e-14 / (cond * math.sin(td))
    # Hence MERL folds φd into [0, π): the pair and its swap share one bin (away from bin edges).
    if math.sin(td) > 1e-6 and not _near_merl_edge(th, td, pd, 1e-9):
        assert g.merl_index(th, td, pd) == g.merl_index(th2, td2, pd2)


@SETTINGS
@given(direction, direction, st.one_of(st.sampled_from([PI, -PI, TWO_PI, 1e-12, HALF_PI]),
                                       st.floats(-10.0, 10.0, allow_nan=False)))
def test_isotropy_rotation_changes_phi_h_only(di, do, alpha):
    wi, wo = vec(*di), vec(*do)
    cond = pair_conditioning(wi, wo)
    assume(cond > 1e-9)
    th, ph, td, pd = g.to_half_diff(wi, wo)
    th2, ph2, td2, pd2 = g.to_half_diff(rot_z(wi, alpha), rot_z(wo, alpha))
    assert abs(th2 - th) <= ATOL / cond + ATOL
    assert abs(td2 - td) <= ATOL / cond + ATOL
    sin_h = math.sin(th)
    if sin_h > 1e-6:
        assert circ(ph2, ph + alpha) <= 1e-14 / (sin_h * cond)
        if math.sin(td) > 1e-6:
            assert circ(pd2, pd) <= 1e-14 / (sin_h * math.sin(td) * cond)
    # Everywhere, including θh = 0 where the split between φh and φd is a convention: the angles with
    # φh shifted back by α describe the original pair.
    wi2, wo2 = g.from_half_diff(th2, ph2 - alpha, td2, pd2)
    np.testing.assert_allclose(wi2, wi, rtol=0, atol=1e-14)
    np.testing.assert_allclose(wo2, wo, rtol=0, atol=1e-14 / cond)


# ---------------------------------------------------------------------------------------------------
# MERL binning, against a plain re-derivation from FORMATS.md (scalar Python per sample)
# ---------------------------------------------------------------------------------------------------


def ref_merl_index(theta_h, theta_d, phi_d):
    """FORMATS.md, MERL section, written out plainly; φd given in [0, 2π)."""
    i_h = math.floor(math.sqrt(theta_h / (math.pi / 2)) * 90)
    i_h = min(max(i_h, 0), 89)
    i_d = math.floor(theta_d / (math.pi / 2) * 90)
    i_d = min(max(i_d, 0), 89)
    # Reciprocity fold into [0, π): φd and φd + π are the same pair with ωi and ωo swapped.
    if phi_d >= math.pi:
        phi_d -= math.pi
    i_p = math.floor(phi_d / math.pi * 180)
    i_p = min(max(i_p, 0), 179)
    return i_p + 180 * (i_d + 90 * i_h)


def ref_half_diff(wi, wo):
    """The MERL reader's std_coords_to_half_diff_coords, in scalar math: φ in (−π, π] from atan2."""
    hx, hy, hz = (wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2])
    n = math.sqrt(hx * hx + hy * hy + hz * hz)
    hx, hy, hz = hx / n, hy / n, hz / n
    theta_h = math.acos(max(-1.0, min(1.0, hz)))
    phi_h = math.atan2(hy, hx)
    # ωi rotated by −φh about z ...
    c, s = math.cos(-phi_h), math.sin(-phi_h)
    x1, y1, z1 = c * wi[0] - s * wi[1], s * wi[0] + c * wi[1], wi[2]
    # ... then by −θh about y.
    c, s = math.cos(-theta_h), math.sin(-theta_h)
    x2, y2, z2 = c * x1 + s * z1, y1, -s * x1 + c * z1
    theta_d = math.acos(max(-1.0, min(1.0, z2)))
    phi_d = math.atan2(y2, x2)
    return theta_h, phi_h, theta_d, phi_d


def ref_merl_index_signed(theta_h, theta_d, phi_d):
    """The reader's own fold for φd in (−π, π]: φd < 0 → φd + π, then clamp to 0..179."""
    if phi_d < 0.0:
        phi_d += math.pi
    i_p = min(max(math.floor(phi_d / math.pi * 180), 0), 179)
    return i_p + 180 * (ref_merl_index(theta_h, theta_d, 0.0) // 180)


def _near_merl_edge(theta_h, theta_d, phi_d, tol, tol_phi=None):
    """Whether moving any of the three angles by up to its tolerance changes its bin (φd edges modulo π)."""
    tol_phi = tol if tol_phi is None else tol_phi
    here = ref_merl_index(max(theta_h, 0.0), max(theta_d, 0.0), phi_d % TWO_PI)
    moves = ((tol, 0, 0), (-tol, 0, 0), (0, tol, 0), (0, -tol, 0), (0, 0, tol_phi), (0, 0, -tol_phi))
    for dh, dd, dp in moves:
        moved = ref_merl_index(max(theta_h + dh, 0.0), max(theta_d + dd, 0.0), (phi_d + dp) % TWO_PI)
        if moved != here:
            return True
    return False


merl_theta_h = st.one_of(
    theta_hemi,
    st.integers(0, NH).map(lambda k: (k / NH) ** 2 * HALF_PI),  # bin edges of the square-root mapping
)
merl_theta_d = st.one_of(theta_hemi, st.integers(0, ND).map(lambda k: k / ND * HALF_PI))
merl_phi_d = st.one_of(phi_any, st.integers(0, 2 * NPHI - 1).map(lambda k: k / NPHI * PI))


@SETTINGS
@given(merl_theta_h, merl_theta_d, merl_phi_d)
def test_merl_index_matches_formats_md(th, td, pd):
    i = g.merl_index(th, td, pd)
    assert i.dtype == np.int64
    assert 0 <= int(i) < MERL_SIZE
    assert int(i) == ref_merl_index(th, td, pd)
    # φd and φd + π share the bin (the fold), exactly for φd in [0, π).
    if pd < PI:
        assert int(g.merl_index(th, td, pd + PI)) == int(i) or _near_merl_edge(th, td, pd, 1e-12)
    ih, id_, ip = g.merl_unindex(i)
    assert 0 <= ih < NH and 0 <= id_ < ND and 0 <= ip < NPHI
    assert ip + NPHI * (id_ + ND * ih) == i


def test_merl_index_batch_matches_formats_md():
    rng = np.random.default_rng(1)
    th = rng.uniform(0, HALF_PI, 20000) ** 1.0
    td = rng.uniform(0, HALF_PI, 20000)
    pd = rng.uniform(0, TWO_PI, 20000)
    got = g.merl_index(th, td, pd)
    want = [ref_merl_index(a, b, c) for a, b, c in zip(th.tolist(), td.tolist(), pd.tolist(), strict=True)]
    assert got.tolist() == want


def test_merl_index_extremes_stay_in_range():
    # Exactly at the top edges (θ = π/2, φd → π): clamped into the last bins, never out of the table.
    assert int(g.merl_index(HALF_PI, HALF_PI, math.nextafter(PI, 0.0))) == MERL_SIZE - 1
    assert int(g.merl_index(HALF_PI, HALF_PI, math.nextafter(TWO_PI, 0.0))) == MERL_SIZE - 1
    assert int(g.merl_index(0.0, 0.0, 0.0)) == 0
    assert int(g.merl_index(0.0, 0.0, PI)) == 0  # folded: φd = π is φd = 0 with ωi, ωo swapped
    # Slightly out-of-range input (rounding from upstream) is clamped to the edge bins.
    assert int(g.merl_index(-1e-17, -1e-17, -1e-17)) in (0, NPHI - 1)
    assert 0 <= int(g.merl_index(HALF_PI + 1e-12, HALF_PI + 1e-12, TWO_PI)) < MERL_SIZE


@pytest.mark.parametrize("args, field", [
    ((HALF_PI + 1e-3, 0.1, 0.0), "theta_h"), ((0.1, -0.01, 0.0), "theta_d"),
    ((float("nan"), 0.1, 0.0), "theta_h"), ((0.1, 0.1, float("inf")), "phi_d"),
])
def test_merl_index_refuses_angles_the_table_has_no_bin_for(args, field):
    with pytest.raises(ValueError, match=f"merl_index: {field}"):
        g.merl_index(*args)


@SETTINGS
@given(direction, direction)
def test_merl_index_of_vectors_matches_reference_reader(di, do):
    """The whole path ωi, ωo → MERL index, against the MERL reader's own computation in scalar math."""
    wi, wo = vec(*di), vec(*do)
    assume(pair_conditioning(wi, wo) > 1e-6)
    th, _, td, pd = ref_half_diff(wi, wo)
    want = ref_merl_index_signed(th, td, pd)
    got = int(g.merl_index(*[g.to_half_diff(wi, wo)[k] for k in (0, 2, 3)]))
    if min(th, td) < 1e-6:
        # φd is undefined at θd = 0, and at θh = 0 it depends on the φh convention (the reader's atan2
        # of rounding noise, our φh = 0). An isotropic BRDF does not depend on it there: compare the
        # θ bins only.
        got, want = got // NPHI * NPHI, want // NPHI * NPHI
    if got != want:
        # Only allowed where the reference angles sit on a bin edge, to within the reader's own accuracy:
        # acos loses precision near 0 (an error ~1e-16/θ in θh, θd, which the rotations carry into φd
        # divided by sin θd), and atan2 gives ±π for φd on the edge depending on the sign of a zero.
        tol = 1e-9 + 1e-14 / min(th, td)
        assert _near_merl_edge(th, td, pd, tol, tol + 1e-14 / (th * td)), (got, want, th, td, pd)
        gh, gd, gp = (int(x) for x in g.merl_unindex(got))
        wh, wd, wp = (int(x) for x in g.merl_unindex(want))
        assert abs(gh - wh) <= 1 and abs(gd - wd) <= 1 and min(abs(gp - wp), NPHI - abs(gp - wp)) <= 1


def test_merl_bin_centres_round_trip_all_bins():
    idx = np.arange(MERL_SIZE, dtype=np.int64)
    ih, id_, ip = g.merl_unindex(idx)
    assert ih.min() == 0 and ih.max() == NH - 1 and id_.max() == ND - 1 and ip.max() == NPHI - 1
    th, td, pd = g.merl_bin_centres(ih, id_, ip)
    assert np.array_equal(g.merl_index(th, td, pd), idx)
    assert th.min() > 0 and th.max() < HALF_PI and td.max() < HALF_PI and pd.max() < PI


def test_merl_bin_centres_strided_against_reference():
    for i in range(0, MERL_SIZE, 97):
        th, td, pd = (float(x) for x in g.merl_bin_centres(*g.merl_unindex(i)))
        assert ref_merl_index(th, td, pd) == i
        assert int(g.merl_index(th, td, pd)) == i


@SETTINGS
@given(st.integers(0, MERL_SIZE - 1))
def test_merl_bin_centres_random_bins(i):
    ih, id_, ip = (int(x) for x in g.merl_unindex(i))
    assert (ih, id_, ip) == (i // (ND * NPHI), (i // NPHI) % ND, i % NPHI)
    th, td, pd = (float(x) for x in g.merl_bin_centres(ih, id_, ip))
    assert int(g.merl_index(th, td, pd)) == i == ref_merl_index(th, td, pd)
    # The θh centre is the middle of the bin in the square-root domain.
    assert math.sqrt(th / HALF_PI) * NH == pytest.approx(ih + 0.5, abs=1e-9)
    # And it survives the trip through a direction pair (φh arbitrary).
    wi, wo = g.from_half_diff(th, 1.234, td, pd)
    th2, _, td2, pd2 = g.to_half_diff(wi, wo)
    assert int(g.merl_index(th2, td2, pd2)) == i


# ---------------------------------------------------------------------------------------------------
# Canonical forms
# ---------------------------------------------------------------------------------------------------


class UnionFind:
    def __init__(self, items):
        self.parent = {x: x for x in items}

    def find(self, x):
        while self.parent[x] != x:
            self.parent[x] = self.parent[self.parent[x]]
            x = self.parent[x]
        return x

    def union(self, a, b):
        self.parent[self.find(a)] = self.find(b)

    def classes(self):
        out = {}
        for x in self.parent:
            out.setdefault(self.find(x), []).append(x)
        return list(out.values())


def _key(*angles_rad):
    """Hashable key of canonical angles: degrees rounded to 1e-6 (values come from degree grids)."""
    return tuple(round(float(np.rad2deg(a)), 6) + 0.0 for a in angles_rad)


def _check_partition(classes, keys):
    """The key is constant on each class, and different classes get different keys."""
    for cls in classes:
        assert len({keys[x] for x in cls}) == 1, [(x, keys[x]) for x in cls]
    assert len({keys[cls[0]] for cls in classes}) == len(classes)
    assert len(set(keys.values())) == len(classes)


def _canon_rec(ti, pi_, to, po):
    return g.canonical_reciprocal(ti, pi_, to, po)


@SETTINGS
@given(direction, direction)
def test_canonical_reciprocal_properties(di, do):
    (ti, pi_), (to, po) = di, do
    a = _canon_rec(ti, pi_, to, po)
    b = _canon_rec(to, po, ti, pi_)
    # Constant on the class {pair, swapped pair}: exactly, unless the two directions are the same to
    # within the angle tolerance (then either order is canonical, and the two agree to that tolerance).
    if bool(a[4]) == bool(b[4]):
        assert not bool(a[4])
        assert abs(ti - to) <= 1e-9 and (min(ti, to) <= 1e-9 or circ(pi_, po) <= 2e-9)
        np.testing.assert_allclose([float(x) for x in a[:4]], [float(x) for x in b[:4]], rtol=0, atol=1e-9)
    else:
        assert [float(x) for x in a[:4]] == [float(x) for x in b[:4]]
    # Idempotent, and the second call never swaps.
    c = _canon_rec(*a[:4])
    assert [float(x) for x in c[:4]] == [float(x) for x in a[:4]] and not bool(c[4])
    # In range, and the same physical pair as the input (or its swap, as flagged).
    t1, p1, t2, p2 = (float(x) for x in a[:4])
    assert 0.0 <= p1 < TWO_PI and 0.0 <= p2 < TWO_PI
    first, second = ((to, po), (ti, pi_)) if bool(a[4]) else ((ti, pi_), (to, po))
    # (θ <= 1e-9 counts as the pole, where φ is set to 0: a vector error up to 2e-9.)
    np.testing.assert_allclose(vec(t1, p1), vec(*first), rtol=0, atol=3e-9)
    np.testing.assert_allclose(vec(t2, p2), vec(*second), rtol=0, atol=3e-9)
    # Aliases of the same input give the same form: φ + 2π, and any φ at the pole.
    # (Where the two directions are within the tolerance of each other, rounding in φ ± 2π may flip
    # which of the two comes first: equal then only to that tolerance.)
    tie = abs(ti - to) <= 2e-9 and (min(ti, to) <= 2e-9 or circ(pi_, po) <= 2e-9)
    tol = 3e-9 if tie else 1e-12
    d = _canon_rec(ti, pi_ + TWO_PI, to, po - TWO_PI)
    assert all(abs(float(x) - float(y)) <= tol or circ(float(x), float(y)) <= tol
               for x, y in zip(d[:4], a[:4], strict=True))
    if ti == 0.0:
        assert [float(x) for x in _canon_rec(0.0, 1.0, to, po)[:4]] == [float(x) for x in a[:4]]


def test_canonical_reciprocal_near_2pi_is_0():
    """φ within the angle tolerance below 2π is φ = 0: same canonical form, not one 2π away."""
    for p in (TWO_PI - 1e-12, math.nextafter(TWO_PI, 0.0), np.deg2rad(360.0)):
        a = g.canonical_reciprocal(0.5, p, 0.5, 1.0)
        b = g.canonical_reciprocal(0.5, 0.0, 0.5, 1.0)
        for x, y in zip(a[:4], b[:4], strict=True):
            assert abs(float(x) - float(y)) <= 1e-9


@pytest.mark.parametrize(("reciprocity", "mirror"), [(r, m) for r in (True, False) for m in (False, True)])
def test_canonical_isotropic_near_2pi_is_0(reciprocity, mirror):
    for d in (TWO_PI - 1e-12, math.nextafter(TWO_PI, 0.0), -1e-12, -5e-324):
        for ti, to in ((0.5, 0.5), (0.3, 0.9), (0.9, 0.3)):
            a = g.canonical_isotropic(ti, to, d, reciprocity=reciprocity, mirror=mirror)
            b = g.canonical_isotropic(ti, to, 0.0, reciprocity=reciprocity, mirror=mirror)
            for x, y in zip(a, b, strict=True):
                assert abs(float(x) - float(y)) <= 1e-9


def test_canonical_reciprocal_grid_classes():
    thetas = [0, 30, 60, 90]
    phis = [0, 90, 180, 270, 360, 720, -90]
    dirs = [(t, p) for t in thetas for p in phis]
    nodes = [d1 + d2 for d1 in dirs for d2 in dirs]
    uf = UnionFind(nodes)
    for ti, pi_, to, po in nodes:
        uf.union((ti, pi_, to, po), (to, po, ti, pi_))  # reciprocity
        uf.union((ti, pi_, to, po), (ti, pi_ % 360, to, po % 360))  # the same direction
        if ti == 0:
            uf.union((ti, pi_, to, po), (0, 0, to, po))  # φ means nothing at the pole
        if to == 0:
            uf.union((ti, pi_, to, po), (ti, pi_, 0, 0))
    classes = uf.classes()
    n_dirs = 1 + 3 * 4  # the pole, and 4 azimuths on each of 3 rings
    assert len(classes) == n_dirs * (n_dirs + 1) // 2  # unordered pairs, repetition allowed
    arr = np.deg2rad(np.array(nodes, dtype=float))
    ti, pi_, to, po, _ = g.canonical_reciprocal(arr[:, 0], arr[:, 1], arr[:, 2], arr[:, 3])
    keys = {n: _key(*k) for n, k in zip(nodes, zip(ti, pi_, to, po, strict=True), strict=True)}
    _check_partition(classes, keys)


@SETTINGS
@given(direction, direction, st.one_of(st.sampled_from([PI, -PI, TWO_PI, 1e-12]), st.floats(-10, 10)))
def test_to_isotropic_rotation_invariant(di, do, alpha):
    (ti, pi_), (to, po) = di, do
    a = [float(x) for x in g.to_isotropic(ti, pi_, to, po)]
    b = [float(x) for x in g.to_isotropic(ti, pi_ + alpha, to, po + alpha)]
    assert a[:2] == [ti, to] and b[:2] == [ti, to]
    assert 0.0 <= a[2] < TWO_PI
    assert circ(a[2], b[2]) <= 1e-13
    if min(ti, to) <= 1e-9:
        assert a[2] == 0.0
    else:
        assert circ(a[2], po - pi_) <= 1e-13


CANON_OPTIONS = [(r, m) for r in (True, False) for m in (False, True)]


@pytest.mark.parametrize(("reciprocity", "mirror"), CANON_OPTIONS)
def test_canonical_isotropic_properties(reciprocity, mirror):
    @SETTINGS
    @given(theta_hemi, theta_hemi, st.one_of(phi_any, st.floats(-20, 20), st.sampled_from([-PI, -1e-12])))
    def check(ti, to, d):
        def canon(a, b, c):
            return [float(x) for x in g.canonical_isotropic(a, b, c, reciprocity=reciprocity, mirror=mirror)]

        def same(x, y):
            # Angles within the module's tolerance (1e-9) are the same; allow for rounding on top.
            return (abs(x[0] - y[0]) <= 2e-9 and abs(x[1] - y[1]) <= 2e-9
                    and circ(x[2], y[2]) <= 2e-9)

        c = canon(ti, to, d)
        # Idempotent.
        assert canon(*c) == c
        # In range.
        assert 0.0 <= c[2] < TWO_PI
        if mirror:
            assert c[2] <= PI
        if reciprocity:
            assert c[0] <= c[1] + 1e-9
            if abs(c[0] - c[1]) <= 1e-9:
                assert c[2] <= PI
        if min(ti, to) <= 1e-9:
            assert c[2] == 0.0
        # A member of the input's class.
        members = [(ti, to, d)]
        if reciprocity:
            members.append((to, ti, -d))
        if mirror:
            members += [(a, b, -e) for a, b, e in members]
        pole = min(ti, to) <= 1e-9
        assert any(same(c, (a, b, 0.0 if pole else e)) for a, b, e in members)
        # Constant on the class (and on Δφ + 2π k).
        for a, b, e in members + [(ti, to, d + TWO_PI), (ti, to, d - 2 * TWO_PI)]:
            assert same(canon(a, b, e), c)
        if pole:
            assert same(canon(ti, to, 1.0), c)

    check()


@pytest.mark.parametrize(("reciprocity", "mirror"), CANON_OPTIONS)
def test_canonical_isotropic_grid_classes(reciprocity, mirror):
    """(θi, θo, Δφ) on a degree grid: canonical keys partition it exactly as the symmetries do."""
    thetas = [0, 15, 45, 90]
    dphis = list(range(-360, 361, 30)) + [-315, -225, -135, -45, 45, 135, 225, 315]
    nodes = [(a, b, d) for a in thetas for b in thetas for d in dphis]
    node_set = set(nodes)
    uf = UnionFind(nodes)

    def link(n, m):
        if m in node_set:
            uf.union(n, m)

    for a, b, d in nodes:
        n = (a, b, d)
        link(n, (a, b, d % 360))  # Δφ is an angle
        if reciprocity:
            link(n, (b, a, -d % 360))
        if mirror:
            link(n, (a, b, -d % 360))
        if a == 0 or b == 0:
            link(n, (a, b, 0))  # Δφ means nothing when either direction is at the pole
    assert all((a, b, d % 360) in node_set for a, b, d in nodes)
    classes = uf.classes()
    arr = np.deg2rad(np.array(nodes, dtype=float))
    out = g.canonical_isotropic(arr[:, 0], arr[:, 1], arr[:, 2], reciprocity=reciprocity, mirror=mirror)
    keys = {n: _key(*k) for n, k in zip(nodes, zip(*out, strict=True), strict=True)}
    _check_partition(classes, keys)


@pytest.mark.parametrize(("reciprocity", "mirror"), CANON_OPTIONS)
def test_isotropic_grid_classes_from_direction_pairs(reciprocity, mirror):
    """Full pairs (θi, φi, θo, φo) on a degree grid, modulo rotations about z (and the chosen symmetries):
    canonical_isotropic∘to_isotropic separates exactly the orbits."""
    thetas = [0, 30, 60, 90]
    phis = list(range(0, 361, 45))
    dirs = [(t, p) for t in thetas for p in phis]
    nodes = [d1 + d2 for d1 in dirs for d2 in dirs]
    uf = UnionFind(nodes)

    def norm(n):
        return (n[0], n[1] % 360, n[2], n[3] % 360)

    for n in nodes:
        ti, pi_, to, po = n
        uf.union(n, norm(n))
        uf.union(n, norm((ti, pi_ + 45, to, po + 45)))  # rotation about z generates all 8
        if reciprocity:
            uf.union(n, (to, po, ti, pi_))
        if mirror:
            uf.union(n, norm((ti, -pi_, to, -po)))  # reflection in the xz plane
        if ti == 0:
            uf.union(n, (0, 0, to, po))
        if to == 0:
            uf.union(n, (ti, pi_, 0, 0))
    classes = uf.classes()
    arr = np.deg2rad(np.array(nodes, dtype=float))
    iso = g.to_isotropic(arr[:, 0], arr[:, 1], arr[:, 2], arr[:, 3])
    out = g.canonical_isotropic(*iso, reciprocity=reciprocity, mirror=mirror)
    keys = {n: _key(*k) for n, k in zip(nodes, zip(*out, strict=True), strict=True)}
    _check_partition(classes, keys)
    # Orbit counts, independently: rings {30, 60, 90} with 8 relative azimuths, plus pole pairs.
    rings, n_dphi = 3, 8
    if not reciprocity:
        expected = rings * rings * (n_dphi // 2 + 1 if mirror else n_dphi) + (2 * rings + 1)
    elif mirror:
        expected = rings * (rings + 1) // 2 * (n_dphi // 2 + 1) + (rings + 1)
    else:
        # Unequal θ: ordered once, any Δφ; equal θ: Δφ ~ −Δφ.
        expected = rings * (rings - 1) // 2 * n_dphi + rings * (n_dphi // 2 + 1) + (rings + 1)
    assert len(classes) == expected
