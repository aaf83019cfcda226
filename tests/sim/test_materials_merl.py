"""MERL tables: the Dr.Jit bin index matches gonio.geometry, lookups return the table's values scaled to
sr⁻¹, no-data bins give 0, and malformed files are rejected. The test table is written here from a
known function of the bin centres (the format as FORMATS.md states it, not through the reader)."""

from __future__ import annotations

import drjit as dr
import materials_ref as ref
import numpy as np
import pytest

from gonio.geometry import MERL_SHAPE, merl_bin_centres, merl_index, merl_unindex, to_half_diff
from gonio.sim.materials import load
from gonio.sim.materials.merl import merl_index_dr

SCALE = np.array([1.0 / 1500, 1.15 / 1500, 1.66 / 1500])
BINS = int(np.prod(MERL_SHAPE))


def known_brdf(index):
    """f_r (3, n) in sr⁻¹ of MERL bins: smooth in the bin centres, different in every channel."""
    theta_h, theta_d, phi_d = merl_bin_centres(*merl_unindex(index))
    base = 1 + np.cos(theta_h) + theta_d * phi_d
    return np.stack([base, 2 * base + 0.5, 3 * base + np.sin(theta_d)])


def no_data(index):
    """Bins left without data: θd bins >= 85 in R only, and θh bin 0 with θd bin 0 in all channels."""
    i_th, i_td, _ = merl_unindex(index)
    all_missing = (i_th == 0) & (i_td == 0)
    return np.stack([(i_td >= 85) | all_missing, all_missing, all_missing])


@pytest.fixture(scope="module")
def table_file(tmp_path_factory):
    index = np.arange(BINS)
    stored = known_brdf(index) / SCALE[:, None]
    stored[no_data(index)] = -1.0
    path = tmp_path_factory.mktemp("merl") / "synthetic.binary"
    with open(path, "wb") as fh:
        np.asarray(MERL_SHAPE, dtype="<i4").tofile(fh)
        stored.astype("<f8").tofile(fh)
    return path


def bin_coordinates(wi, wo):
    """Continuous bin coordinates (u_θh, u_θd, u_φd); a bin edge is at an integer."""
    theta_h, _, theta_d, phi_d = to_half_diff(wi, wo)
    return np.stack([np.sqrt(theta_h / (np.pi / 2)) * 90, theta_d / (np.pi / 2) * 90,
                     np.mod(phi_d, np.pi) / np.pi * 180])


def near_edge(wi, wo, tol):
    u = bin_coordinates(wi, wo)
    return (np.abs(u - np.round(u)) < tol).any(axis=0)


@pytest.mark.parametrize("precision,edge_tol", [("float64", 1e-9), ("float32", 2e-3)])
def test_drjit_index_matches_geometry_merl_index(precision, edge_tol, to_dr, jit):
    rng = np.random.default_rng(3)
    wi, wo = ref.random_pairs(rng, 100_000, specular_fraction=0.3)
    theta_h, _, theta_d, phi_d = to_half_diff(wi, wo)
    expected = merl_index(theta_h, theta_d, phi_d)
    vector_type = jit.Array3f64 if precision == "float64" else jit.Array3f
    got = merl_index_dr(to_dr(vector_type, wi), to_dr(vector_type, wo)).numpy().astype(np.int64)
    mismatch = got != expected
    # A different bin is allowed only for pairs this close to a bin edge, where rounding decides.
    assert not (mismatch & ~near_edge(wi, wo, edge_tol)).any()
    assert mismatch.mean() < 2e-3
    assert len(np.unique(expected)) > 50_000  # the pairs cover many bins


def test_lookup_returns_the_scaled_table(table_file):
    m = load(f"merl:{table_file}")
    assert m.spec == f"merl:{table_file}" and m.reciprocal and not m.energy_conserving
    wi, wo = ref.random_pairs(np.random.default_rng(5), 50_000)
    keep = ~near_edge(wi, wo, 2e-3)
    wi, wo = wi[keep], wo[keep]
    theta_h, _, theta_d, phi_d = to_half_diff(wi, wo)
    index = merl_index(theta_h, theta_d, phi_d)
    expected = np.where(no_data(index), 0.0, known_brdf(index)).T
    np.testing.assert_allclose(m.eval(wi, wo, precision="float64"), expected, rtol=1e-12)
    np.testing.assert_allclose(m.eval(wi, wo), expected, rtol=1e-6)
    # The independent numpy lookup agrees too (it reads the same file through the same format).
    table = np.fromfile(table_file, dtype="<f8", offset=12).reshape(3, -1) * SCALE[:, None]
    np.testing.assert_allclose(ref.merl(wi, wo, table), expected, rtol=1e-12)


def test_no_data_bins_evaluate_to_zero_per_channel(table_file):
    m = load(f"merl:{table_file}")
    assert m.missing_bins == np.count_nonzero(no_data(np.arange(BINS)).any(axis=0))
    # θd = 86° lies in θd bin 86 (R has no data there), θh = 5° far from bin 0; φd = 90° keeps both
    # directions above the horizon.
    wi, wo = _pair_from_half_diff(np.radians(5.0), np.radians(86.0), np.radians(90.0))
    assert wi[0, 2] > 0 and wo[0, 2] > 0
    value = m.eval(wi, wo, precision="float64")[0]
    assert value[0] == 0 and value[1] > 0 and value[2] > 0
    wi, wo = _pair_from_half_diff(np.radians(0.001), np.radians(0.3), np.radians(40.0))
    assert np.array_equal(m.eval(wi, wo, precision="float64")[0], [0, 0, 0])


def _pair_from_half_diff(theta_h, theta_d, phi_d):
    from gonio.geometry import from_half_diff

    wi, wo = from_half_diff(theta_h, 0.3, theta_d, phi_d)
    return wi[None], wo[None]


def test_reciprocal_and_isotropic_by_construction(table_file):
    m = load(f"merl:{table_file}")
    wi, wo = ref.random_pairs(np.random.default_rng(9), 20_000)
    keep = ~near_edge(wi, wo, 1e-6)
    wi, wo = wi[keep], wo[keep]
    base = m.eval(wi, wo, precision="float64")
    assert np.array_equal(base, m.eval(wo, wi, precision="float64"))
    c, s = np.cos(1.1), np.sin(1.1)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    turned = m.eval(wi @ rot.T, wo @ rot.T, precision="float64")
    assert np.mean(turned == base) > 0.999  # rotation moves only pairs within rounding of an edge


def test_drjit_types_follow_the_input(table_file, vector_type, to_dr):
    m = load(f"merl:{table_file}")
    wi, wo = ref.random_pairs(np.random.default_rng(2), 100)
    out = m.eval_dr(to_dr(vector_type, wi), to_dr(vector_type, wo))
    assert type(out) is vector_type and dr.width(out) == 100


@pytest.mark.parametrize("content,message", [
    (b"", "has 0 bytes"),
    (np.asarray([90, 90, 180], "<i4").tobytes() + b"\0" * 8, "has 20 bytes"),
])
def test_malformed_files_are_rejected(tmp_path, content, message):
    path = tmp_path / "bad.binary"
    path.write_bytes(content)
    with pytest.raises(ValueError, match=message):
        load(f"merl:{path}")


def test_wrong_header_and_missing_file_are_rejected(tmp_path):
    path = tmp_path / "swapped.binary"
    with open(path, "wb") as fh:
        np.asarray([180, 90, 90], "<i4").tofile(fh)
        fh.write(b"\0" * (3 * BINS * 8))
    with pytest.raises(ValueError, match=r"header \(180, 90, 90\), expected \(90, 90, 180\)"):
        load(f"merl:{path}")
    with pytest.raises(ValueError, match="cannot read file .*nowhere.binary"):
        load(f"merl:{tmp_path / 'nowhere.binary'}")
    with pytest.raises(ValueError, match="merl: a file path is required"):
        load("merl:")
