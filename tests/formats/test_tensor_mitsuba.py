"""Tensor files: our container and measured-BSDF layout, loaded by Mitsuba 3 itself."""

import numpy as np
import pytest

from gonio.export import export
from gonio.formats.rgl import eval_measured
from gonio.formats.tensor import read_tensor, write_tensor
from gonio.sim.materials import load

mi = pytest.importorskip("mitsuba")

GGX = "ggx:alpha=0.35,fresnel=conductor,eta=0.2/0.9/1.1,k=3.9/2.4/2.2"
WHITE = "ggx:alpha=0.35,fresnel=none"


def _pairs(n, theta_max_deg=80.0, seed=7):
    rng = np.random.default_rng(seed)

    def dirs():
        th = np.arccos(1 - rng.random(n) * (1 - np.cos(np.radians(theta_max_deg))))
        ph = rng.random(n) * 2 * np.pi
        return np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=1)

    return dirs(), dirs()


def _mitsuba_eval(bsdf, wi, wo, spectral):
    ctx = mi.BSDFContext()
    out = np.zeros(len(wi))
    for k in range(len(wi)):
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*wi[k])
        if spectral:
            si.wavelengths = mi.Spectrum([450.0, 550.0, 650.0, 500.0])
        out[k] = float(np.mean(np.array(bsdf.eval(ctx, si, mi.Vector3f(*wo[k])))))
    return out


def test_container_round_trip_every_dtype(tmp_path):
    fields = {f"a{i}": (np.arange(6) % 5).astype(t).reshape(2, 3) for i, t in
              enumerate(["u1", "i1", "<u2", "<i2", "<u4", "<i4", "<u8", "<i8", "<f2", "<f4", "<f8"])}
    fields["text"] = np.frombuffer(b"hello", dtype=np.uint8)
    write_tensor(tmp_path / "t.bsdf", fields)
    back = read_tensor(tmp_path / "t.bsdf")
    assert list(back) == list(fields)
    for k, v in fields.items():
        assert back[k].dtype == v.dtype.newbyteorder("=") and np.array_equal(back[k], v)
    tf = mi.TensorFile(str(tmp_path / "t.bsdf"))  # Mitsuba's own reader accepts the container
    assert "a9" in str(tf) and "float32" in str(tf)


@pytest.mark.parametrize("variant,fmt,spec,ref", [
    ("scalar_rgb", "bsdf", GGX, {"eta": [0.2, 0.9, 1.1], "k": [3.9, 2.4, 2.2]}),
    ("scalar_spectral", "bsdf-spectral", WHITE, None),
])
def test_mitsuba_measured_matches_roughconductor(tmp_path, make_sampled, variant, fmt, spec, ref):
    mi.set_variant(variant)
    data = make_sampled(spec, "merl:stride=2", theta_max_deg=90.0)
    report = export(data, fmt, tmp_path / "m.bsdf")
    assert report.interpolated > 0.8 * report.cells
    props = {"type": "roughconductor", "distribution": "ggx", "alpha": 0.35, "sample_visible": True}
    if ref is None:
        props["material"] = "none"
    else:
        props.update(eta={"type": "rgb", "value": ref["eta"]}, k={"type": "rgb", "value": ref["k"]})
    measured = mi.load_dict({"type": "measured", "filename": str(tmp_path / "m.bsdf")})
    rough = mi.load_dict(props)
    wi, wo = _pairs(600)
    a = _mitsuba_eval(measured, wi, wo, variant.endswith("spectral"))
    b = _mitsuba_eval(rough, wi, wo, variant.endswith("spectral"))
    assert np.abs(a - b).sum() / b.sum() < 0.02  # weighted (by cos θo) L1
    # our reader of the layout evaluates the file as Mitsuba does
    if variant == "scalar_rgb":
        ours = eval_measured(read_tensor(tmp_path / "m.bsdf"), wi, wo).mean(axis=1)
        np.testing.assert_allclose(ours, a, rtol=1e-4, atol=1e-6)


def test_bsdf_material_measures_a_measured_material_again(tmp_path, make_sampled):
    data = make_sampled(GGX, "merl:stride=2", theta_max_deg=90.0)
    export(data, "bsdf", tmp_path / "g.bsdf")
    m = load(f"bsdf:{tmp_path / 'g.bsdf'}")
    wi, wo = _pairs(4000, seed=11)
    fr = m.eval(wi, wo, precision="float64")
    np.testing.assert_allclose(fr * wo[:, 2:3], eval_measured(read_tensor(tmp_path / "g.bsdf"), wi, wo),
                               rtol=1e-9, atol=1e-12)
    truth = load(GGX).eval(wi, wo, precision="float64")
    w = wo[:, 2:3]
    assert np.abs(fr - truth).__mul__(w).sum() / (truth * w).sum() < 0.02


def test_bsdf_material_rejects_a_file_without_the_fields(tmp_path):
    write_tensor(tmp_path / "x.bsdf", {"a": np.zeros(3, np.float32)})
    with pytest.raises(ValueError, match="lacks the measured-BSDF fields"):
        load(f"bsdf:{tmp_path / 'x.bsdf'}")
