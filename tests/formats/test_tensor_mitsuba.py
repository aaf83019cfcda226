"""Tensor files: our container and measured-BSDF layout, loaded by Mitsuba 3 itself."""

import numpy as np
import pytest
from brdf_samples import sampled

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


#: (Mitsuba variant, export format, simulated material, the matching roughconductor's eta and k or None
#: for material="none"): the RGB file of a conductor, the spectral file of a Fresnel-free GGX.
CASES = {"scalar_rgb": ("bsdf", GGX, {"eta": [0.2, 0.9, 1.1], "k": [3.9, 2.4, 2.2]}),
         "scalar_spectral": ("bsdf-spectral", WHITE, None)}


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """Variant -> (path of our export of a simulated merl:stride=2 campaign, ExportReport), made once."""
    made = {}

    def get(variant):
        if variant not in made:
            fmt, spec, _ = CASES[variant]
            path = tmp_path_factory.mktemp("export") / "m.bsdf"
            report = export(sampled(spec, "merl:stride=2", theta_max_deg=90.0), fmt, path)
            made[variant] = path, report
        return made[variant]

    return get


def _roughconductor(variant) -> dict:
    ref = CASES[variant][2]
    props = {"type": "roughconductor", "distribution": "ggx", "alpha": 0.35, "sample_visible": True}
    if ref is None:
        props["material"] = "none"
    else:
        props.update(eta={"type": "rgb", "value": ref["eta"]}, k={"type": "rgb", "value": ref["k"]})
    return props


@pytest.mark.parametrize("variant", list(CASES))
def test_mitsuba_measured_matches_roughconductor(exported, variant):
    mi.set_variant(variant)
    path, report = exported(variant)
    assert report.interpolated > 0.8 * report.cells
    measured = mi.load_dict({"type": "measured", "filename": str(path)})
    rough = mi.load_dict(_roughconductor(variant))
    wi, wo = _pairs(600)
    a = _mitsuba_eval(measured, wi, wo, variant.endswith("spectral"))
    b = _mitsuba_eval(rough, wi, wo, variant.endswith("spectral"))
    assert np.abs(a - b).sum() / b.sum() < 0.02  # weighted (by cos θo) L1
    # our reader of the layout evaluates the file as Mitsuba does (spectral: at _mitsuba_eval's wavelengths)
    nm = [450.0, 550.0, 650.0, 500.0] if variant.endswith("spectral") else None
    ours = eval_measured(read_tensor(path), wi, wo, nm).mean(axis=1)
    np.testing.assert_allclose(ours, a, rtol=1e-4, atol=1e-6)


@pytest.mark.slow
def test_mitsuba_loads_the_export_of_a_gantry_campaign_within_2_percent(tmp_path):
    """The same check on what a lab has: a whole campaign on the simulated two-arm gantry (iso:step=5,
    θ up to 80°, the occlusion gap around retro-reflection unmeasured), exported and loaded by Mitsuba.
    Its 9196 poses in raster order (the grid's loops as they come): the tour (the default) takes 3 s
    longer to plan the same poses and serpentine sweeps 0.7 s, and the order is not what this checks."""
    from gonio.campaign import create_campaign
    from gonio.config import load_config
    from gonio.dataset import read_brdf
    from gonio.lifecycle import run_campaign
    from gonio.wiring import build_gantry

    c = create_campaign(tmp_path / "c", load_config(), grid="iso:step=5,order=raster", material=GGX,
                         seed=3)
    try:
        run_campaign(c, build_gantry(c.cfg, GGX, seed=3))
    finally:
        c.close()
    report = export(read_brdf(tmp_path / "c" / "brdf.h5"), "bsdf", tmp_path / "m.bsdf")
    assert report.interpolated > 0.8 * report.cells
    mi.set_variant("scalar_rgb")
    measured = mi.load_dict({"type": "measured", "filename": str(tmp_path / "m.bsdf")})
    rough = mi.load_dict(_roughconductor("scalar_rgb"))
    wi, wo = _pairs(600)
    a = _mitsuba_eval(measured, wi, wo, False)
    b = _mitsuba_eval(rough, wi, wo, False)
    # 0.52 % measured (1.3 % when the cells looking past the data's 80° were left 0)
    assert np.abs(a - b).sum() / b.sum() < 0.01


# -- a sphere rendered with each ---------------------------------------------------------------------
SIZE, SPP, SEEDS, BLOCK, FOV_DEG, DISTANCE = 64, 16, 8, 4, 28.0, 5.0


def _sphere_scene(bsdf: dict):
    """A unit sphere seen from DISTANCE on +z (SIZE x SIZE, box filter), lit by a directional light from
    the upper right front and a dim constant environment; direct lighting only (a convex object has no
    inter-reflection)."""
    look = mi.ScalarTransform4f().look_at(origin=[0, 0, DISTANCE], target=[0, 0, 0], up=[0, 1, 0])
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "direct"},
        "sensor": {"type": "perspective", "fov": FOV_DEG, "to_world": look,
                   "film": {"type": "hdrfilm", "width": SIZE, "height": SIZE, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": SPP}},
        "sphere": {"type": "sphere", "bsdf": bsdf},
        "sun": {"type": "directional", "direction": [-1.0, -0.6, -1.0], "irradiance": 3.0},
        "env": {"type": "constant", "radiance": 0.3},
    })


def _renders(bsdf: dict, first_seed: int) -> np.ndarray:
    """SEEDS independent renders averaged over the colour channels, shape (SEEDS, SIZE, SIZE)."""
    scene = _sphere_scene(bsdf)
    return np.stack([np.array(mi.render(scene, seed=first_seed + k)).mean(axis=-1) for k in range(SEEDS)])


def _blocks_on_the_sphere() -> np.ndarray:
    """(SIZE/BLOCK)^2 mask of the BLOCK x BLOCK pixel blocks whose four corners see the sphere: its disc
    has radius tan(asin(1/DISTANCE)) / tan(FOV/2) * SIZE/2 pixels about the image centre."""
    radius = np.tan(np.arcsin(1 / DISTANCE)) / np.tan(np.radians(FOV_DEG / 2)) * SIZE / 2
    edges = np.arange(0, SIZE + 1, BLOCK) - SIZE / 2
    r = np.hypot(*np.meshgrid(edges, edges, indexing="ij")) < radius
    return r[:-1, :-1] & r[1:, :-1] & r[:-1, 1:] & r[1:, 1:]


def _block_z(a: np.ndarray, b: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """z of the difference of the block means of two sets of renders, for the blocks ``inside``, with each
    mean's standard error estimated from the spread over its own seeds."""
    n = SIZE // BLOCK

    def blocks(x):
        return x.reshape(len(x), n, BLOCK, n, BLOCK).mean(axis=(2, 4))

    ba, bb = blocks(a), blocks(b)
    se2 = ba.var(axis=0, ddof=1) / len(ba) + bb.var(axis=0, ddof=1) / len(bb)
    return ((ba.mean(axis=0) - bb.mean(axis=0)) / np.sqrt(se2))[inside]


@pytest.mark.parametrize("variant", list(CASES))
def test_a_rendered_sphere_agrees_within_noise(exported, variant):
    mi.set_variant(variant)
    path, _ = exported(variant)
    ours = _renders({"type": "measured", "filename": str(path)}, first_seed=0)
    ref = _renders(_roughconductor(variant), first_seed=10_000)  # seeds independent of ours
    inside = _blocks_on_the_sphere()
    assert inside.sum() >= 100
    z = _block_z(ours, ref, inside)
    # Under agreement each z is a difference of two 8-seed means over its estimated standard error:
    # Student-like with ~14 degrees of freedom, E[z^2] = 14/12 = 1.17 (1.43 RGB, 1.48 spectral measured
    # over the 112 blocks); 2 leaves room for the heavy tails of 16-spp pixel noise ...
    assert np.mean(z**2) < 2.0, (np.mean(z**2), np.abs(z).max())
    # ... and the same rule rejects a 2 % error in brightness (5.4 RGB, 4.6 spectral measured)
    assert np.mean(_block_z(ours, 1.02 * ref, inside) ** 2) > 2.0
    # a sphere where it should be: lit (above the environment's 0.3) towards the light, upper right
    mean = ref.mean(axis=0)
    top_right, bottom_left = mean[: SIZE // 2, SIZE // 2:].max(), mean[SIZE // 2:, : SIZE // 2].max()
    assert top_right > 2 * bottom_left > 0.3


def test_bsdf_material_measures_a_measured_material_again(exported):
    # the module's RGB export: the bsdf file of GGX sampled on merl:stride=2 (made once, read only here)
    path, _ = exported("scalar_rgb")
    assert CASES["scalar_rgb"][:2] == ("bsdf", GGX)
    m = load(f"bsdf:{path}")
    wi, wo = _pairs(4000, seed=11)
    fr = m.eval(wi, wo, precision="float64")
    np.testing.assert_allclose(fr * wo[:, 2:3], eval_measured(read_tensor(path), wi, wo),
                               rtol=1e-9, atol=1e-12)
    truth = load(GGX).eval(wi, wo, precision="float64")
    w = wo[:, 2:3]
    assert np.abs(fr - truth).__mul__(w).sum() / (truth * w).sum() < 0.02


def test_bsdf_material_rejects_a_file_without_the_fields(tmp_path):
    write_tensor(tmp_path / "x.bsdf", {"a": np.zeros(3, np.float32)})
    with pytest.raises(ValueError, match="lacks the measured-BSDF fields"):
        load(f"bsdf:{tmp_path / 'x.bsdf'}")
