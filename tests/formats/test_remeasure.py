"""A measured material measured again: our bsdf / MERL export of a material becomes the simulated sample
(``bsdf:PATH``, ``merl:PATH``) of a campaign run by ``gonio simulate``, whose export is compared with the
export of the same grid measured on the original material."""

import numpy as np
import pytest
from brdf_samples import sampled

from gonio.cli import main
from gonio.export import export
from gonio.formats.merl import read_merl
from gonio.formats.rgl import eval_measured
from gonio.formats.tensor import read_tensor
from gonio.geometry import from_half_diff, merl_bin_centres, merl_unindex
from gonio.registries import EXPORT_FORMATS

GGX = "ggx:alpha=0.35,fresnel=conductor,eta=0.2/0.9/1.1,k=3.9/2.4/2.2"
GRID = "iso:step=15,order=raster"  # the order is not what this checks: the tour plans 0.3 s longer
THETA_MAX = 80.0  # the sim config's kinematics.theta_max_deg: the campaign's grid stops there


def _pairs(n, theta_max_deg, seed):
    rng = np.random.default_rng(seed)
    th = np.radians(rng.uniform(0, theta_max_deg, (2, n)))
    ph = rng.uniform(0, 2 * np.pi, (2, n))
    v = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)
    return v[0], v[1]


def _compare_bsdf(a, b):
    wi, wo = _pairs(5000, 75.0, seed=3)
    fa, fb = eval_measured(read_tensor(a), wi, wo), eval_measured(read_tensor(b), wi, wo)
    return np.abs(fa - fb).sum() / fb.sum()  # the files hold f_r cos θo: weighted L1


def _compare_merl(a, b):
    ta, tb = read_merl(a), read_merl(b)  # (3, bins), -1 where no data
    wi, wo = from_half_diff(*(lambda h, d, p: (h, 0.0, d, p))(*merl_bin_centres(*merl_unindex(
        np.arange(ta.shape[1])))))
    inside = (wi[:, 2] > np.cos(np.radians(75.0))) & (wo[:, 2] > np.cos(np.radians(75.0)))
    both = inside & (ta >= 0).all(axis=0) & (tb >= 0).all(axis=0)
    assert both.sum() > 0.4 * inside.sum()
    w = wo[both, 2]
    return (np.abs(ta[:, both] - tb[:, both]) @ w) / (tb[:, both] @ w)  # per channel


@pytest.mark.parametrize("fmt,source_grid,tolerance", [
    # the bsdf export is within 2 % of the material (test_tensor_mitsuba); detector noise adds ~0.3 %
    ("bsdf", "merl:stride=2", 0.03),
    # a MERL file resampled from every third bin: its own interpolation error against the material
    ("merl", "merl:stride=3", 0.03),
])
def test_a_measured_material_measured_again_exports_the_same(tmp_path, fmt, source_grid, tolerance):
    first = export(sampled(GGX, source_grid, theta_max_deg=90.0), fmt, tmp_path / f"first.{fmt}")
    spec = f"{'bsdf' if fmt == 'bsdf' else 'merl'}:{first.paths[0]}"
    folder = tmp_path / "again"
    assert main(["simulate", spec, "--grid", GRID, "--out", str(folder), "--quiet", "--seed", "5",
                 "--export", fmt]) == 0
    # the same grid measured (noise-free) on the original material, exported the same way
    reference = export(sampled(GGX, GRID, theta_max_deg=THETA_MAX), fmt, tmp_path / f"reference.{fmt}")
    compare = _compare_bsdf if fmt == "bsdf" else _compare_merl
    err = compare(folder / EXPORT_FORMATS[fmt].extra["file_name"], reference.paths[0])
    print(f"{fmt}: weighted L1 of the re-measured export against the reference export: {np.max(err):.4f}")
    assert np.max(err) < tolerance
