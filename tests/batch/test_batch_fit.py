"""Fitting many at once: every row of a batch store, or every campaign of a folder, on the cluster; each
fit the one ``gonio fit`` makes of the same data; missing and failing rows in the table as such."""

from __future__ import annotations

import csv
import io
import shutil

import pytest
import zarr

from gonio.batch import read_materials, run_batch
from gonio.batch.fit import FitJob, fit_many, sources, table_csv
from gonio.config import load_config
from gonio.fit import fit

GRID, SEED = "iso:step=30", 1


@pytest.fixture(scope="module")
def store(tmp_path_factory, client):
    out = tmp_path_factory.mktemp("fit") / "b.zarr"
    run_batch(read_materials("lambert:albedo=0.3|0.6"), grid=GRID, seed=SEED, cfg=load_config(), out=out,
              client=client, threads=1)
    return out


def test_each_row_is_fitted_as_gonio_fit_fits_the_same_samples(store, client):
    kind, items = sources(store)
    assert kind == "store" and [m for m, _ in items] == ["lambert:albedo=0.3", "lambert:albedo=0.6"]
    rows = fit_many(kind, items, FitJob("lambert", starts=1), client, threads=1)
    for (material, data), row in zip(items, rows, strict=True):
        alone = fit(data, "lambert", starts=1)
        assert row.source == material and row.status == "ok" and row.fit["material"] == alone.material
        assert row.fit["parameters"] == alone.parameters
        albedo = float(material.split("=")[1])
        for c in "RGB":   # the simulated albedo comes back within 3 sigma
            p = row.fit["parameters"][f"albedo.{c}"]
            assert abs(p["value"] - albedo) < 3 * p["stddev"] + 1e-3, (material, p)


def test_missing_and_failing_rows_are_rows_of_the_table(store, client, tmp_path):
    cut = tmp_path / "b.zarr"
    shutil.copytree(store, cut)
    zarr.open_group(str(cut), mode="r+")["status"][1] = 0     # as a batch killed before its second row
    kind, items = sources(cut)
    rows = fit_many(kind, items, FitJob("ggx:alpha=7"), client, threads=1)   # alpha out of its range
    assert [r.status for r in rows] == ["failed", "missing"]
    assert "alpha" in rows[0].error and "rerun gonio batch" in rows[1].error
    table = list(csv.DictReader(io.StringIO(table_csv(rows))))
    assert [t["status"] for t in table] == ["failed", "missing"] and table[0]["material"] == ""


def test_gonio_fit_of_a_store_writes_the_csv_table(store, tmp_path, capsys):
    """``gonio fit STORE`` through main() in this process, on a local cluster of one worker process
    (docs/batch.md runs the command as a process, on two)."""
    from gonio.cli import main

    out = tmp_path / "fits.csv"
    capsys.readouterr()
    assert main(["fit", str(store), "--model", "lambert", "--starts", "1", "--workers", "1", "--out",
                 str(out)]) == 0
    assert "2 ok, 0 misfit, 0 failed, 0 missing" in capsys.readouterr().err
    table = list(csv.DictReader(out.open()))
    assert [t["source"] for t in table] == ["lambert:albedo=0.3", "lambert:albedo=0.6"]
    assert {"albedo.R", "albedo.R_stddev", "chi2_reduced"} <= set(table[0])
    assert abs(float(table[1]["albedo.G"]) - 0.6) < 0.01


def test_a_folder_of_campaigns_is_fitted_each_and_workers_for_one_campaign_refused(tmp_path, capsys):
    from gonio.cli import main

    folder = tmp_path / "campaigns"
    for albedo in ("0.2", "0.7"):
        assert main(["simulate", f"lambert:albedo={albedo}", "--grid", GRID, "--out", str(folder / albedo),
                     "--quiet"]) == 0
    kind, items = sources(folder)
    assert kind == "folder" and [p.name for p in items] == ["0.2", "0.7"]
    capsys.readouterr()
    assert main(["fit", str(folder / "0.2"), "--model", "lambert", "--workers", "2"]) == 2
    assert "--workers/--scheduler: for a batch store or a folder of campaigns" in capsys.readouterr().err


def test_a_zarr_store_of_something_else_is_refused_in_one_line_before_any_cluster(tmp_path, capsys):
    from cli_helpers import one_clear_line

    from gonio.cli import main

    other = tmp_path / "other.zarr"
    group = zarr.open_group(str(other), mode="w", zarr_format=2)
    group.attrs["format"] = "someone-else"
    group.create_array("x", shape=(3,), dtype="f8")
    out = tmp_path / "fits.csv"
    assert main(["fit", str(other), "--model", "lambert", "--workers", "1", "--out", str(out)]) == 2
    one_clear_line(capsys, str(other), "not a gonio batch store", "'someone-else'")
    assert not out.exists()
