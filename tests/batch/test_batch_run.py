"""Batch runs in-process (a one-thread Dask worker in this process): every row bit for bit the campaign
``gonio simulate`` makes, failures recorded, a rerun doing only what is missing, another batch refused."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import planned
import pytest
import xarray as xr
import zarr

from gonio.batch import DONE, FAILED, MISSING, BatchStore, open_store, read_materials, run_batch
from gonio.config import load_config
from gonio.dataset import read_brdf
from gonio.lifecycle import run_campaign
from gonio.sim.materials import load
from gonio.wiring import build_gantry

GRID, SEED = "iso:step=45", 4
VARIABLES = ("theta_i", "phi_i", "theta_o", "phi_o", "value", "stddev", "step", "pose", "exposure_s",
             "campaign_s", "grid_index")


@pytest.fixture(scope="module")
def materials():
    return read_materials("ggx:alpha=0.1|0.4,metal=gold")[:1] + read_materials("lambert:albedo=0.3|0.7") \
        + read_materials("ward:rho_d=0.1,rho_s=0.05,alpha_x=0.1,alpha_y=0.3")


def _simulated(tmp_path: Path, material: str, grid: str = GRID):
    """What gonio simulate writes for the material (its steps, in this process)."""
    cfg = load_config()
    folder = tmp_path / f"ref-{abs(hash(material))}"
    c = planned.create(folder, cfg, grid=grid, material=load(material).spec, seed=SEED)
    try:
        state, _ = run_campaign(c, build_gantry(cfg, material, seed=SEED))
    finally:
        c.close()
    assert state == "done"
    return read_brdf(folder / "brdf.h5")


def _rows(path: Path) -> dict:
    """The store's variables as stored (zarr alone: 0.02 s where an xarray open costs 0.1-0.15 s), for
    comparing stores and reading rows; the tests below read a store through xarray where that is the point."""
    group = zarr.open_group(str(path), mode="r", zarr_format=2)
    rows = {k: group[k][...] for k in (*VARIABLES, "status", "error", "seed")}
    return rows | {"material": [str(m) for m in group["material"][...]]}


@pytest.fixture(scope="module")
def whole(tmp_path_factory, client, materials):
    """The batch of ``materials`` run whole: its summary and store (read, never written, by the tests)."""
    out = tmp_path_factory.mktemp("whole") / "b.zarr"
    return run_batch(materials, grid=GRID, seed=SEED, cfg=load_config(), out=out, client=client, threads=1)


def test_every_row_is_bit_for_bit_the_simulated_campaign(tmp_path, whole, materials):
    summary = whole
    assert summary.written == len(materials) and summary.failed == [] and summary.done_before == 0
    ds = xr.open_zarr(summary.path)          # an ordinary xarray reader
    assert [str(m) for m in ds.material.values] == materials
    assert [str(m) for m in ds.spec.values] == [load(m).spec for m in materials]
    assert (ds.status.values == DONE).all() and (ds.seed.values == SEED).all()
    assert ds.attrs["batch_grid"].startswith("iso:step=45") and ds.attrs["units"] == "sr^-1"
    store = BatchStore.open(summary.path)       # what gonio fit reads, with zarr alone
    for k, material in enumerate(materials):
        ref = _simulated(tmp_path, material)
        row = ds.isel(material=k)
        for name in VARIABLES:
            want = np.asarray(getattr(ref, name))
            np.testing.assert_array_equal(row[name].values, want.reshape(row[name].shape), err_msg=name)
        _same_samples(store.row(k), ref, material)


def _same_samples(got, ref, material: str) -> None:
    """A store row read back (:meth:`BatchStore.row`) holds the campaign's samples bit for bit."""
    for name in (*VARIABLES, "planned"):
        want = getattr(ref, name)
        if want is None:        # scattered poses (an adaptive grid): no grid indices
            want = np.zeros((len(ref.theta_i), 0), np.int64)
        np.testing.assert_array_equal(np.asarray(getattr(got, name)), np.asarray(want), err_msg=name)
    assert got.grid_axes == ref.grid_axes and list(got.attrs["channels"]) == list(ref.attrs["channels"])
    assert got.attrs["material"] == load(material).spec and got.attrs["seed"] == SEED
    assert got.attrs["symmetries"] == ref.attrs["symmetries"] and got.attrs["config"] == ref.attrs["config"]


def test_an_adaptive_batch_is_row_for_row_the_simulated_campaigns(tmp_path, client):
    """Each material's rounds are placed from its own readings (one pilot plan for all): two glossy
    materials measure different poses, each row bit for bit its gonio simulate campaign; scattered poses
    have no grid indices (grid_axis of length 0)."""
    grid, materials = "adaptive:poses=25", ["ggx:alpha=0.1,metal=gold", "ggx:alpha=0.4,metal=gold"]
    summary = run_batch(materials, grid=grid, seed=SEED, cfg=load_config(), out=tmp_path / "a.zarr",
                        client=client, threads=1)
    assert summary.written == 2 and summary.failed == []
    ds = open_store(tmp_path / "a.zarr")
    assert ds.sizes["sample"] == 25 and ds.sizes["grid_axis"] == 0
    rows = [ds.isel(material=k) for k in range(2)]
    assert not np.array_equal(rows[0]["theta_o"].values, rows[1]["theta_o"].values)
    store = BatchStore.open(tmp_path / "a.zarr")
    for k, (row, material) in enumerate(zip(rows, materials, strict=True)):
        ref = _simulated(tmp_path, material, grid)
        _same_samples(store.row(k), ref, material)
        for name in VARIABLES:
            want = np.asarray(getattr(ref, name) if name != "grid_index" else np.zeros((25, 0), np.int64))
            np.testing.assert_array_equal(row[name].values, want.reshape(row[name].shape), err_msg=name)


def test_a_failing_material_is_recorded_and_the_others_go_on(tmp_path, client, materials, monkeypatch):
    import gonio.wiring

    real = gonio.wiring.build_gantry

    def build(cfg, material, **kw):
        if "albedo=0.3" in getattr(material, "spec", str(material)):
            raise RuntimeError("the lamp's fuse blew")
        return real(cfg, material, **kw)

    monkeypatch.setattr(gonio.wiring, "build_gantry", build)
    out = tmp_path / "b.zarr"
    summary = run_batch(materials, grid=GRID, seed=SEED, cfg=load_config(), out=out, client=client, threads=1)
    assert summary.failed == [("lambert:albedo=0.3", "RuntimeError: the lamp's fuse blew")]
    rows = _rows(out)
    bad = materials.index("lambert:albedo=0.3")
    assert rows["status"].tolist() == [FAILED if k == bad else DONE for k in range(len(materials))]
    assert rows["error"][bad] == "RuntimeError: the lamp's fuse blew"
    assert np.isnan(rows["value"][bad]).all() and not np.isnan(np.delete(rows["value"], bad, 0)).any()
    # the cause fixed, the rerun does the failed material only
    monkeypatch.setattr(gonio.wiring, "build_gantry", real)
    ran = []
    again = run_batch(materials, grid=GRID, seed=SEED, cfg=load_config(), out=out, client=client, threads=1,
                      on_row=lambda i, row: ran.append(i))
    assert ran == [bad] and again.done_before == len(materials) - 1 and again.failed == []
    assert (_rows(out)["status"] == DONE).all() and _rows(out)["error"][bad] == ""


def test_an_interrupted_batch_rerun_does_only_what_is_missing_and_equals_an_uninterrupted_one(
        tmp_path, client, materials, whole):
    cut = tmp_path / "cut.zarr"

    seen = []

    def stop_after_two(i, row):
        seen.append(i)
        if len(seen) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_batch(materials, grid=GRID, seed=SEED, cfg=load_config(), out=cut, client=client, threads=1,
                  on_row=stop_after_two)
    status = BatchStore(cut).status()
    assert (status == DONE).sum() == 2 and (status == MISSING).sum() == len(materials) - 2
    ran = []
    run_batch(materials, grid=GRID, seed=SEED, cfg=load_config(), out=cut, client=client, threads=1,
              on_row=lambda i, row: ran.append(i))
    assert sorted(ran) == [int(i) for i in np.flatnonzero(status == MISSING)]
    a, b = _rows(whole.path), _rows(cut)
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


@pytest.mark.parametrize("change, what", [({"grid": "iso:step=30"}, "grid"), ({"seed": SEED + 1}, "seed")])
def test_a_store_of_another_batch_is_refused_and_left_alone(tmp_path, client, materials, change, what):
    out = tmp_path / "b.zarr"
    run_batch(materials[:1], grid=GRID, seed=SEED, cfg=load_config(), out=out, client=client, threads=1)
    before = _rows(out)
    kw = {"grid": GRID, "seed": SEED} | change
    with pytest.raises(ValueError, match=rf"--out: .* holds another batch \(its {what} is"):
        run_batch(materials[:1], cfg=load_config(), out=out, client=client, threads=1, **kw)
    with pytest.raises(ValueError, match="its materials differ"):
        run_batch(materials[:2], grid=GRID, seed=SEED, cfg=load_config(), out=out, client=client, threads=1)
    after = _rows(out)
    for k in before:
        np.testing.assert_array_equal(before[k], after[k])
