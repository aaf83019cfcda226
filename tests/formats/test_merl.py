"""MERL files: our writer read back by an independent reader written here from the format description."""

import struct

import numpy as np
import pytest

from gonio.export import export
from gonio.formats.merl import read_merl, write_merl
from gonio.geometry import from_half_diff, merl_bin_centres, merl_unindex, sph_to_vec
from gonio.sim.materials import load


def independent_merl_lookup(path, wi, wo):
    """From FORMATS.md alone: header, planes, the bin rules, the 1/1500 scales."""
    raw = open(path, "rb").read()
    n = struct.unpack("<3i", raw[:12])
    assert n == (90, 90, 180)
    planes = np.frombuffer(raw[12:], dtype="<f8").reshape(3, -1)
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=1, keepdims=True)
    th, ph = np.arccos(np.clip(h[:, 2], -1, 1)), np.arctan2(h[:, 1], h[:, 0])
    # ωi rotated by −φh about z, then by −θh about y
    c, s = np.cos(-ph), np.sin(-ph)
    x, y, z = c * wi[:, 0] - s * wi[:, 1], s * wi[:, 0] + c * wi[:, 1], wi[:, 2]
    c, s = np.cos(-th), np.sin(-th)
    dx, dz = c * x + s * z, -s * x + c * z
    td, pd = np.arccos(np.clip(dz, -1, 1)), np.arctan2(y, dx)
    pd = np.where(pd < 0, pd + np.pi, pd)
    ih = np.clip(np.floor(np.sqrt(th / (np.pi / 2)) * 90), 0, 89).astype(int)
    id_ = np.clip(np.floor(td / (np.pi / 2) * 90), 0, 89).astype(int)
    ip = np.clip(np.floor(pd / np.pi * 180), 0, 179).astype(int)
    idx = ip + 180 * (id_ + 90 * ih)
    return planes[:, idx].T * np.array([1 / 1500, 1.15 / 1500, 1.66 / 1500])


def test_stride_one_campaign_fills_every_cell_exactly(make_sampled, tmp_path):
    spec = "ggx:alpha=0.3,metal=gold"
    data = make_sampled(spec, "merl:stride=1", theta_max_deg=90.0)
    rep = export(data, "merl", tmp_path / "m.binary")
    assert rep.from_data == len(data.theta_i) and rep.interpolated == 0
    assert rep.from_data + rep.empty == 1_458_000
    table = read_merl(tmp_path / "m.binary")
    # cell centres of the measured bins: the independent reader returns the material's value there
    r = np.radians
    wi = sph_to_vec(r(data.theta_i), r(data.phi_i))
    wo = sph_to_vec(r(data.theta_o), r(data.phi_o))
    got = independent_merl_lookup(tmp_path / "m.binary", wi, wo)
    np.testing.assert_allclose(got, data.value, rtol=1e-14, atol=0)
    # below-horizon bins are MERL's "no data"
    assert (table < 0).any(axis=0).sum() == rep.empty


def test_resampled_campaign_reads_back_close_to_the_material(make_sampled, tmp_path):
    spec = "ggx:alpha=0.4,metal=copper"
    export(make_sampled(spec, "iso:step=5"), "merl", tmp_path / "r.binary")
    rng = np.random.default_rng(3)
    idx = rng.choice(1_458_000, 20000, replace=False)
    th, td, pd = merl_bin_centres(*merl_unindex(idx))
    wi, wo = from_half_diff(th, 0.0, td, pd)
    got = independent_merl_lookup(tmp_path / "r.binary", wi, wo)
    ok = (got >= 0).all(axis=1) & (wi[:, 2] > 0.2) & (wo[:, 2] > 0.2)
    truth = load(spec).eval(wi[ok], wo[ok], precision="float64")
    assert ok.sum() > 5000
    assert np.abs(got[ok] - truth).sum() / truth.sum() < 0.03


def test_merl_material_reads_our_file(tmp_path, make_sampled):
    data = make_sampled("lambert:albedo=0.5/0.4/0.3", "merl:stride=6", theta_max_deg=90.0)
    export(data, "merl", tmp_path / "l.binary")
    m = load(f"merl:{tmp_path / 'l.binary'}")
    v = m.eval(np.array([[0.0, 0.0, 1.0]]), np.array([[0.6, 0.0, 0.8]]), precision="float64")
    np.testing.assert_allclose(v[0], np.array([0.5, 0.4, 0.3]) / np.pi, rtol=1e-12)


def test_write_rejects_wrong_shape_and_leaves_nothing(tmp_path):
    with pytest.raises(ValueError, match=r"shape \(3, 1458000\)"):
        write_merl(tmp_path / "x.binary", np.zeros((3, 10)))
    assert list(tmp_path.iterdir()) == []
