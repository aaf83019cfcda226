"""The batch store: the sampled BRDFs of many simulated campaigns in one xarray dataset in Zarr.

Dimensions ``material`` × ``sample`` × ``channel`` (and ``grid_axis`` for the grid indices). Every
variable of a campaign's ``brdf.h5`` (:mod:`gonio.dataset`: measured and planned angles, ``value`` and
``stddev`` in sr⁻¹, step, pose, exposure, campaign clock, grid indices) gains a leading ``material``
dimension; ``material`` (the MATERIAL strings as given, spans expanded), ``spec`` (each as
:func:`gonio.sim.materials.load` normalizes it, as ``brdf.h5`` records it) and ``seed`` are
coordinates; ``status`` says per material whether its row is missing (0), done (1) or failed (2), and
``error`` holds a failure's message. The attributes hold what every material shares: the grid, the
config snapshot and its hash, the software version, units and conventions, ``format = "gonio-batch"``
and its ``format_version``.

Writes are crash-safe: the store is created under a temporary name and renamed into place; each material
is one chunk of every variable (Zarr's local store writes each chunk file under a temporary name and
renames it), written before the material's ``status`` chunk, so a row marked done is complete and a
killed batch leaves rows that are either done or still missing. Zarr format 2, which every Zarr reader
understands; open it with ``xarray.open_zarr(STORE)`` or :func:`open_store`.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["FORMAT", "FORMAT_VERSION", "MISSING", "DONE", "FAILED", "Row", "BatchStore", "open_store",
           "row_data", "row_brdf"]

FORMAT = "gonio-batch"
FORMAT_VERSION = 1
MISSING, DONE, FAILED = 0, 1, 2
#: A failure's message is kept to this many characters.
ERROR_CHARS = 300

_PER_SAMPLE = ("theta_i", "phi_i", "theta_o", "phi_o", "theta_i_planned", "phi_i_planned", "theta_o_planned",
               "phi_o_planned", "step", "pose", "exposure_s", "campaign_s")
_PER_CHANNEL = ("value", "stddev")
_ANGLES = ("theta_i", "phi_i", "theta_o", "phi_o")
# brdf.h5 attributes that belong to one campaign, not to the batch (its material and seed are
# coordinates; its clock readings would make two runs of one batch differ).
_OWN_ATTRS = ("material", "seed", "sample", "created_unix", "created_utc", "written_unix")


@dataclass(frozen=True)
class Row:
    """One material's result as a worker returns it: the arrays of its ``brdf.h5`` by store variable
    name, and the file's attributes (or a failure's ``error`` and no arrays)."""

    arrays: dict
    attrs: dict
    error: str = ""


def row_data(data) -> Row:
    """The :class:`Row` of a :class:`gonio.dataset.SampledBRDF`."""
    n = int(np.asarray(data.theta_i).size)
    arrays = {a: np.asarray(getattr(data, a), np.float64).reshape(n) for a in _ANGLES}
    planned = np.asarray(data.planned, np.float64).reshape(n, 4)
    for k, a in enumerate(_ANGLES):
        arrays[f"{a}_planned"] = planned[:, k].copy()
    for name in ("step", "pose"):
        arrays[name] = np.asarray(getattr(data, name), np.int64).reshape(n)
    for name in ("exposure_s", "campaign_s"):
        arrays[name] = np.asarray(getattr(data, name), np.float64).reshape(n)
    arrays["value"] = np.asarray(data.value, np.float64).reshape(n, -1)
    arrays["stddev"] = np.asarray(data.stddev, np.float64).reshape(n, -1)
    # Scattered poses (an adaptive grid) have no grid indices: no grid_axis.
    index = np.zeros((n, 0)) if data.grid_index is None else data.grid_index
    arrays["grid_index"] = np.asarray(index, np.int64).reshape(n, -1)
    attrs = dict(data.attrs)
    attrs["grid_axes"] = list(data.grid_axes)
    return Row(arrays, attrs)


def _shared_attrs(attrs: dict) -> dict:
    out = {}
    for k, v in attrs.items():
        if k in _OWN_ATTRS:
            continue
        if isinstance(v, np.generic):
            v = v.item()
        elif isinstance(v, np.ndarray):
            v = v.tolist()
        out[k] = json.dumps(v, sort_keys=True) if isinstance(v, dict) else v
    return out


class BatchStore:
    """An open batch store (the Zarr group at ``path``), for :meth:`write` of rows and :meth:`status`."""

    def __init__(self, path: Path):
        import zarr

        self.path = Path(path)
        self._group = zarr.open_group(str(self.path), mode="r+", zarr_format=2)
        self.attrs = dict(self._group.attrs)
        self.materials = [str(m) for m in self._group["material"][:]]

    @classmethod
    def create(cls, path: Path, materials: list[str], seed: int, first: Row, batch_attrs: dict) -> BatchStore:
        """Create the store for ``materials`` shaped like ``first`` (every row of a batch has its shape:
        one grid, one config), under a temporary name renamed into place."""
        import dask.array as da
        import xarray as xr

        path = Path(path)
        m, (n, c), k = len(materials), first.arrays["value"].shape, first.arrays["grid_index"].shape[1]
        dims = {"material": m, "sample": n, "channel": c, "grid_axis": k}
        data_vars, encoding = {}, {}
        for name, arr in first.arrays.items():
            d = ("material", "sample") + (("channel",) if name in _PER_CHANNEL else
                                          ("grid_axis",) if name == "grid_index" else ())
            shape = tuple(dims[x] for x in d)
            fill = np.nan if arr.dtype.kind == "f" else 0
            data_vars[name] = (d, da.full(shape, fill, dtype=arr.dtype, chunks=(1,) + shape[1:]))
            encoding[name] = {"_FillValue": np.nan} if arr.dtype.kind == "f" else {"_FillValue": None}
        data_vars["status"] = (("material",), da.zeros(m, dtype=np.int8, chunks=1))
        data_vars["error"] = (("material",), da.full(m, "", dtype=f"<U{ERROR_CHARS}", chunks=1))
        encoding["status"] = {"_FillValue": None}
        encoding["error"] = {"_FillValue": None}
        from gonio.sim.materials import load

        specs = [load(m).spec for m in materials]
        coords = {"material": ("material", np.array(materials, dtype=object)),
                  "spec": ("material", np.array(specs, dtype=object)),
                  "seed": ("material", np.full(m, seed, np.int64)),
                  "sample": ("sample", np.arange(n, dtype=np.int64)),
                  "channel": ("channel", np.array([str(x) for x in first.attrs["channels"]], dtype=object)),
                  "grid_axis": ("grid_axis", np.array(first.attrs["grid_axes"], dtype=object))}
        attrs = _shared_attrs(first.attrs) | batch_attrs
        attrs |= {"format": FORMAT, "format_version": FORMAT_VERSION}
        attrs.pop("grid_axes", None)
        ds = xr.Dataset(data_vars, coords=coords, attrs=attrs)
        path.parent.mkdir(parents=True, exist_ok=True)
        for stale in path.parent.glob(f".{path.name}.partial-*"):    # of a run killed while it created
            shutil.rmtree(stale, ignore_errors=True)                   # (the caller holds the batch's lock)
        tmp = path.with_name(f".{path.name}.partial-{os.getpid()}")
        try:
            # consolidated: the metadata never changes after this (rows write chunks only)
            ds.to_zarr(str(tmp), mode="w-", compute=False, encoding=encoding, zarr_format=2,
                       consolidated=True)
            tmp.rename(path)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return cls(path)

    def status(self) -> np.ndarray:
        """Per material: :data:`MISSING`, :data:`DONE` or :data:`FAILED`."""
        return np.asarray(self._group["status"][:])

    def write(self, i: int, row: Row) -> None:
        """Material ``i``'s row: its arrays, then its status (done, or failed with ``row.error``)."""
        if row.error:
            self._group["error"][i] = row.error[:ERROR_CHARS]
            self._group["status"][i] = FAILED
            return
        for name, arr in row.arrays.items():
            target = self._group[name]
            if target.shape[1:] != arr.shape:
                raise ValueError(f"material {self.materials[i]}: {name} has shape {arr.shape}; the batch's "
                                 f"rows have {target.shape[1:]}")
            target[i] = arr
        self._group["error"][i] = ""
        self._group["status"][i] = DONE


def row_brdf(ds, k: int):
    """Material ``k`` of an open store (:func:`open_store`) as the :class:`gonio.dataset.SampledBRDF`
    its ``brdf.h5`` held (its attributes: the store's, with its material and seed)."""
    from gonio.dataset import SampledBRDF

    row = ds.isel(material=k).load()
    attrs = dict(ds.attrs) | {"material": str(row["spec"].values), "seed": int(row["seed"].values)}
    for key in ("symmetries", "config"):
        if isinstance(attrs.get(key), str):
            attrs[key] = json.loads(attrs[key])
    get = {name: row[name].values for name in row.data_vars}
    planned = np.stack([get[f"{a}_planned"] for a in _ANGLES], axis=1)
    return SampledBRDF(*(get[a] for a in _ANGLES), get["value"], get["stddev"], attrs, planned=planned,
                       step=get["step"], pose=get["pose"], exposure_s=get["exposure_s"],
                       campaign_s=get["campaign_s"], grid_index=get["grid_index"],
                       grid_axes=tuple(str(a) for a in ds["grid_axis"].values))


def open_store(path):
    """The batch store at ``path`` as an ``xarray.Dataset`` (lazy, dask-backed).

    Raises
    ------
    ValueError
        ``path`` is not a gonio batch store.
    """
    import xarray as xr

    path = Path(path)
    if not (path / ".zgroup").is_file():
        raise ValueError(f"{path}: not a batch store (no Zarr group there)")
    ds = xr.open_zarr(str(path), consolidated=True)
    if ds.attrs.get("format") != FORMAT:
        raise ValueError(f"{path}: a Zarr store, but not a gonio batch store (format "
                         f"{ds.attrs.get('format')!r})")
    return ds
