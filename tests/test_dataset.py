"""brdf.h5 format version 2: read back by h5py, xarray (h5netcdf) and sqlite3 (the journal), v1 still read."""

import json
import sqlite3

import h5py
import numpy as np
import pytest
from brdf_samples import sampled

from gonio.brdf import Reason, open_brdf
from gonio.dataset import FORMAT_VERSION, SampledBRDF, grid_indices, read_brdf, write_brdf
from gonio.plan.grids import enumerate_grid, parse_grid

SPEC = "ggx:alpha=0.3,metal=gold"


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    from gonio.campaign import create_campaign
    from gonio.config import load_config
    from gonio.lifecycle import run_campaign
    from gonio.runner import State
    from gonio.wiring import build_gantry

    folder = tmp_path_factory.mktemp("ds") / "c"
    c = create_campaign(folder, load_config(), grid="iso:step=20", material=SPEC, seed=3)
    try:
        state, _ = run_campaign(c, build_gantry(c.cfg, SPEC, seed=3))
    finally:
        c.close()
    assert state == State.DONE
    return folder


def _journal(folder):
    con = sqlite3.connect(f"file:{folder / 'campaign.sqlite'}?mode=ro", uri=True)
    try:
        steps = {r[0]: r[1:] for r in con.execute(
            "SELECT step, theta_i_deg, phi_i_deg, theta_o_deg, phi_o_deg FROM steps")}
        meas = {r[0]: r[1:] for r in con.execute(
            "SELECT step, exposure_s, campaign_s, theta_i_deg, phi_o_deg FROM measurements WHERE kind = 0")}
        meta = {k: json.loads(v) for k, v in con.execute("SELECT key, value FROM meta")}
    finally:
        con.close()
    return steps, meas, meta


def test_h5py_sees_dimension_scales_planned_angles_and_the_journal(campaign):
    steps, meas, meta = _journal(campaign)
    with h5py.File(campaign / "brdf.h5", "r") as f:
        g = f["samples"]
        assert f.attrs["format_version"] == FORMAT_VERSION == 2
        assert g["value"].dims[0][0].name == "/samples/sample"
        assert g["value"].dims[1][0].name == "/samples/channel"
        assert [c.decode() for c in g["channel"][()]] == ["R", "G", "B"]
        step = g["step"][()]
        assert sorted(step) == sorted(meas) and len(step) == meta["poses"]
        planned = np.stack([g[f"{a}_planned"][()] for a in ("theta_i", "phi_i", "theta_o", "phi_o")], 1)
        np.testing.assert_array_equal(planned, np.array([steps[s] for s in step]))
        np.testing.assert_array_equal(g["exposure_s"][()], [meas[s][0] for s in step])
        np.testing.assert_array_equal(g["campaign_s"][()], [meas[s][1] for s in step])
        np.testing.assert_array_equal(g["theta_i"][()], [meas[s][2] for s in step])
        # iso grid indices: θi/20, θo/20, Δφ/20 of the planned directions
        idx = g["grid_index"][()]
        np.testing.assert_allclose(idx[:, 0] * 20.0, planned[:, 0], atol=1e-9)  # the plan's own radians
        np.testing.assert_allclose(idx[:, 1] * 20.0, planned[:, 2], atol=1e-9)
        assert [a.decode() for a in g["grid_axis"][()]] == ["theta_i", "theta_o", "dphi"]
        a = dict(f.attrs)
        assert a["cosine"] == "none" and a["units"] == "sr^-1" and g["value"].attrs["units"] == "sr^-1"
        assert g["theta_i"].attrs["units"] == "degree" and g["exposure_s"].attrs["units"] == "s"
        assert json.loads(a["symmetries"]) == meta["symmetries"]
        assert a["seed"] == 3 and a["material"] == SPEC and a["source"] == "simulated"
        assert a["config_sha256"] == meta["config_sha256"] and json.loads(a["config"]) == meta["config"]
        assert a["created_unix"] == meta["created_unix"] and a["reference_albedo"] == 0.99
        assert "Rec. 709" in a["color_space"] and "+z the sample normal" in a["frame"]
        assert a["software_version"] and a["created_utc"].endswith("+00:00")
        assert dict(g.attrs)["grid"] == a["grid"] == meta["grid"]


def test_xarray_reads_named_dimensions_coordinates_and_units(campaign):
    xr = pytest.importorskip("xarray")
    pytest.importorskip("h5netcdf")
    with xr.open_dataset(campaign / "brdf.h5", engine="h5netcdf", group="samples") as ds:
        assert ds["value"].dims == ("sample", "channel")
        assert list(ds["channel"].values) == ["R", "G", "B"]
        assert {"theta_i", "theta_o_planned", "step", "campaign_s"} <= set(ds.coords)
        assert ds["value"].attrs["units"] == "sr^-1" and ds["phi_o"].attrs["units"] == "degree"
        assert ds.attrs["cosine"] == "none" and ds.attrs["format_version"] == 2
        with h5py.File(campaign / "brdf.h5", "r") as f:
            np.testing.assert_array_equal(ds["value"].values, f["samples/value"][()])
            np.testing.assert_array_equal(ds["theta_i_planned"].values, f["samples/theta_i_planned"][()])
        g = ds["value"].sel(channel="G")
        assert g.dims == ("sample",) and np.all(g.values > 0)


def test_open_brdf_reads_v2_on_the_plan(campaign):
    b = open_brdf(campaign)
    assert b.angles == "planned" and b.method == "grid" and b.plan_deviation_deg < 1e-6
    ev = b.eval_deg(20.0, 0.0, 40.0, 180.0)
    assert ev.exact[0] and ev.reason[0] == Reason.OK


def _jittered(sd_deg, seed=0):
    """An iso:step=10 dataset whose measured angles scatter around the plan by ``sd_deg``."""
    d = sampled(SPEC, "iso:step=10")
    rng = np.random.default_rng(seed)
    planned = np.stack([d.theta_i, d.phi_i, d.theta_o, d.phi_o], axis=1)
    measured = planned + rng.normal(0.0, sd_deg, planned.shape) * (planned[:, [0, 0, 2, 2]] > 0)
    measured[:, [0, 2]] = np.abs(measured[:, [0, 2]])
    return SampledBRDF(*measured.T, d.value, d.stddev, d.attrs, planned=planned), planned


def test_exact_lookup_snaps_samples_to_their_plan():
    data, planned = _jittered(0.01)
    b = open_brdf(data)
    assert b.angles == "planned" and b.method == "grid" and 0.001 < b.plan_deviation_deg < 0.25
    ev = b.eval_deg(30.0, 0.0, 40.0, 180.0)
    row = np.flatnonzero(np.all(np.abs(planned - [30.0, 0.0, 40.0, 180.0]) < 1e-9, axis=1))
    assert ev.exact[0] and row.size == 1
    np.testing.assert_array_equal(ev.value[0], data.value[row[0]])
    m = open_brdf(data, angles="measured")
    assert m.method == "scattered" and not m.eval_deg(30.0, 0.0, 40.0, 180.0).exact[0]
    far, _ = _jittered(0.5)
    assert open_brdf(far).angles == "measured"
    with pytest.raises(ValueError, match="angles: must be one of"):
        open_brdf(data, angles="nominal")


def test_grid_indices_are_the_planners_loops():
    for grid in ("iso:step=15", "iso:step=30,mirror=true", "full:step=45", "merl:stride=15",
                 "merl:stride=20,reciprocity=false"):
        g = enumerate_grid(parse_grid(grid), 80.0)
        planned = np.degrees(np.stack([g.theta_i, g.phi_i, g.theta_o, g.phi_o], axis=1))
        idx, axes = grid_indices(grid, planned)
        np.testing.assert_array_equal(idx, g.loops, err_msg=grid)
        assert len(axes) == g.loops.shape[1]
    assert grid_indices("iso:step=15", np.array([[7.0, 0.0, 15.0, 0.0]])) is None


def test_write_read_round_trip_and_v1_files(tmp_path):
    d = sampled(SPEC, "iso:step=30")
    write_brdf(tmp_path / "a.h5", d)
    back = read_brdf(tmp_path / "a.h5")
    np.testing.assert_array_equal(back.value, d.value)
    assert back.attrs["symmetries"] == d.attrs["symmetries"] and back.planned is None
    # a version 1 file, written the way gonio 0.1 wrote it
    with h5py.File(tmp_path / "v1.h5", "w") as f:
        g = f.create_group("samples")
        for name in ("theta_i", "phi_i", "theta_o", "phi_o", "value", "stddev"):
            g.create_dataset(name, data=np.asarray(getattr(d, name)))
        g.create_dataset("step", data=np.arange(len(d.value)))
        f.attrs.update({"format": "gonio-brdf", "format_version": 1, "units": "sr^-1",
                        "channels": ["R", "G", "B"], "symmetries": json.dumps(d.attrs["symmetries"]),
                        "grid": d.attrs["grid"], "material": SPEC})
    v1 = read_brdf(tmp_path / "v1.h5")
    assert v1.planned is None and v1.exposure_s is None and list(v1.step) == list(range(len(d.value)))
    b = open_brdf(tmp_path / "v1.h5")
    assert b.angles == "measured" and b.method == "grid" and b.plan_deviation_deg is None
    np.testing.assert_array_equal(b.eval_deg(30.0, 0.0, 60.0, 180.0).value,
                                  open_brdf(d).eval_deg(30.0, 0.0, 60.0, 180.0).value)


def test_bad_files_name_the_path(tmp_path):
    (tmp_path / "x.h5").write_text("not hdf5")
    with pytest.raises(ValueError, match="x.h5: not an HDF5 file"):
        read_brdf(tmp_path / "x.h5")
    d = sampled(SPEC, "iso:step=45")
    write_brdf(tmp_path / "v9.h5", d)
    with h5py.File(tmp_path / "v9.h5", "a") as f:
        f.attrs["format_version"] = 9
    with pytest.raises(ValueError, match="format version 9; this gonio reads versions 1 to 2"):
        read_brdf(tmp_path / "v9.h5")
