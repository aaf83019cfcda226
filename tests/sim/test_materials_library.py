"""Measured materials by name from one folder (``gonio serve --materials DIR``): regular files of DIR
only, size-capped, links, FIFOs and devices refused unopened, and one message whatever the reason."""

from __future__ import annotations

import os
import stat

import numpy as np
import pytest
from brdf_samples import tiny_tensor_file

from gonio.formats.merl import MERL_FILE_BYTES
from gonio.geometry import MERL_SHAPE
from gonio.sim.materials import library as library_module
from gonio.sim.materials import load
from gonio.sim.materials.library import MAX_TENSOR_BYTES, MaterialsFolder

WI = np.array([[0.0, 0.0, 1.0], [0.3, 0.1, 0.9]])
WO = np.array([[0.6, 0.0, 0.8], [-0.5, 0.2, 0.84]])
WI, WO = WI / np.linalg.norm(WI, axis=1)[:, None], WO / np.linalg.norm(WO, axis=1)[:, None]


@pytest.fixture
def folder(tmp_path):
    d = tmp_path / "materials"
    d.mkdir()
    tiny_tensor_file(d / "paint.bsdf")
    with open(d / "gold.binary", "wb") as fh:
        np.asarray(MERL_SHAPE, "<i4").tofile(fh)
        np.full(3 * int(np.prod(MERL_SHAPE)), 750.0, "<f8").tofile(fh)
    return d


def test_named_materials_load_from_the_folder_as_their_paths_do(folder):
    lib = MaterialsFolder(folder)
    m = lib.load("bsdf:paint.bsdf")
    assert m.spec == "bsdf:paint.bsdf"
    np.testing.assert_array_equal(m.eval(WI, WO), load(f"bsdf:{folder / 'paint.bsdf'}").eval(WI, WO))
    g = lib.load("merl: gold.binary")
    assert g.spec == "merl:gold.binary" and os.path.getsize(folder / "gold.binary") == MERL_FILE_BYTES
    np.testing.assert_allclose(g.eval(WI, WO)[0], [0.5, 0.575, 0.83])     # 750 × (1, 1.15, 1.66) / 1500
    assert lib.load("lambert:albedo=0.5").spec == "lambert:albedo=0.5"   # analytic ones pass through


def test_without_a_folder_file_materials_are_refused():
    for spec in ("bsdf:paint.bsdf", "merl:gold.binary", "bsdf:/dev/zero"):
        with pytest.raises(ValueError, match="serves none .*--materials DIR"):
            MaterialsFolder(None).load(spec)


@pytest.mark.parametrize("name", ["../materials/paint.bsdf", "/etc/passwd", "sub/paint.bsdf", ".hidden", "",
                                  "..", "a" * 129, "paint.bsdf\x00", "~/x"])
def test_paths_are_refused_by_their_spelling(folder, name):
    with pytest.raises(ValueError, match="never a path"):
        MaterialsFolder(folder).load(f"bsdf:{name}")


def test_links_fifos_devices_and_oversized_files_are_refused_unopened_with_one_message(folder, monkeypatch):
    (folder / "inside").symlink_to(folder / "paint.bsdf")
    (folder / "outside").symlink_to("/etc/passwd")
    (folder / "zero").symlink_to("/dev/zero")
    os.mkfifo(folder / "fifo")
    (folder / "sub").mkdir()
    with open(folder / "huge", "wb") as fh:              # sparse: no disk used
        fh.truncate(MAX_TENSOR_BYTES + 1)
    (folder / "short.binary").write_bytes(b"\0" * 100)
    names = ["missing", "inside", "outside", "zero", "fifo", "sub", "huge"]
    try:
        os.mknod(folder / "null", stat.S_IFCHR | 0o666, os.makedev(1, 3))
        names.append("null")
    except PermissionError:
        pass
    opened = []
    real_open = os.open
    monkeypatch.setattr(library_module.os, "open",
                        lambda path, *a, **kw: (opened.append(os.fspath(path)), real_open(path, *a, **kw))[1])
    lib = MaterialsFolder(folder)
    messages = set()
    for name in names:
        with pytest.raises(ValueError) as err:
            lib.load(f"bsdf:{name}")
        messages.add(str(err.value).replace(name, "NAME"))
    assert messages == {"bsdf:NAME: no such material in the daemon's materials folder (a regular file of at "
                        f"most {MAX_TENSOR_BYTES:,} bytes)"}
    assert set(opened) == {str(folder)}                # the folder itself, never one of those names
    with pytest.raises(ValueError, match="merl:short.binary: no such material .* exactly 34,992,012 bytes"):
        lib.load("merl:short.binary")


def test_a_regular_file_that_is_not_a_material_is_named(folder):
    (folder / "notes.bsdf").write_bytes(b"hello")
    with pytest.raises(ValueError, match="tensor file 'notes.bsdf': does not start with"):
        MaterialsFolder(folder).load("bsdf:notes.bsdf")
    (folder / "cut.bsdf").write_bytes((folder / "paint.bsdf").read_bytes()[:40])
    with pytest.raises(ValueError, match="tensor file 'cut.bsdf': its header is cut short"):
        MaterialsFolder(folder).load("bsdf:cut.bsdf")
