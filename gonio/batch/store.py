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
           "row_data"]

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

    def __init__(self, path: Path, mode: str = "r+"):
        import zarr

        self.path = Path(path)
        self._group = zarr.open_group(str(self.path), mode=mode, zarr_format=2)
        self.attrs = dict(self._group.attrs)
        self.materials = [str(m) for m in self._group["material"][:]]

    @classmethod
    def open(cls, path) -> BatchStore:
        """The batch store at ``path``, read-only; ValueError where ``path`` is not a gonio batch store."""
        import zarr

        path = Path(path)
        _check_group(path)
        _check_format(path, zarr.open_group(str(path), mode="r", zarr_format=2).attrs)
        return cls(path, mode="r")

    @classmethod
    def create(cls, path: Path, materials: list[str], seed: int, first: Row, batch_attrs: dict) -> BatchStore:
        """Create the store for ``materials`` shaped like ``first`` (every row of a batch has its shape:
        one grid, one config), under a temporary name renamed into place.

        Written with zarr alone, as xarray writes a dataset whose variables are not computed yet
        (``to_zarr(compute=False)``): each variable's dimensions in ``_ARRAY_DIMENSIONS``, the
        non-dimension coordinates named in ``coordinates``, the coordinates' values, no chunk of a
        variable, consolidated metadata. The process that writes a batch so imports neither xarray nor
        dask.array (about 1 s of CPU at every ``gonio batch``)."""
        import zarr

        from gonio.sim.materials import load

        path = Path(path)
        m, (n, c), k = len(materials), first.arrays["value"].shape, first.arrays["grid_index"].shape[1]
        dims = {"material": m, "sample": n, "channel": c, "grid_axis": k}
        coords = {"material": ("material", np.array(materials, dtype=object)),
                  "spec": ("material", np.array([load(x).spec for x in materials], dtype=object)),
                  "seed": ("material", np.full(m, seed, np.int64)),
                  "sample": ("sample", np.arange(n, dtype=np.int64)),
                  "channel": ("channel", np.array([str(x) for x in first.attrs["channels"]], dtype=object)),
                  "grid_axis": ("grid_axis", np.array(first.attrs["grid_axes"], dtype=object))}
        variables = {}
        for name, arr in first.arrays.items():
            d = ("material", "sample") + (("channel",) if name in _PER_CHANNEL else
                                          ("grid_axis",) if name == "grid_index" else ())
            variables[name] = (d, arr.dtype, np.nan if arr.dtype.kind == "f" else None)
        variables["status"] = (("material",), np.dtype(np.int8), None)
        variables["error"] = (("material",), np.dtype(f"<U{ERROR_CHARS}"), None)
        attrs = _shared_attrs(first.attrs) | batch_attrs
        attrs |= {"format": FORMAT, "format_version": FORMAT_VERSION}
        attrs.pop("grid_axes", None)
        path.parent.mkdir(parents=True, exist_ok=True)
        for stale in path.parent.glob(f".{path.name}.partial-*"):    # of a run killed while it created
            shutil.rmtree(stale, ignore_errors=True)                   # (the caller holds the batch's lock)
        tmp = path.with_name(f".{path.name}.partial-{os.getpid()}")
        try:
            group = zarr.open_group(str(tmp), mode="w-", zarr_format=2, attributes=attrs)
            for name, (d, values) in coords.items():
                # strings as variable-length UTF-8; an empty list (an adaptive grid's grid_axis) as
                # float64, as xarray stores it; a chunk holds at least one element (Zarr's spec)
                dtype = values.dtype if values.dtype != object else str if values.size else np.float64
                group.create_array(name, shape=values.shape, chunks=(max(values.size, 1),), fill_value=None,
                                   dtype=dtype, attributes={"_ARRAY_DIMENSIONS": [d]})[...] = values
            others = " ".join(sorted(x for x in coords if x not in dims))
            for name, (d, dtype, fill) in variables.items():
                shape = tuple(dims[x] for x in d)
                group.create_array(name, shape=shape, chunks=(1,) + tuple(max(x, 1) for x in shape[1:]),
                                   dtype=dtype, fill_value=fill,
                                   attributes={"coordinates": others, "_ARRAY_DIMENSIONS": list(d)})
            # consolidated: the metadata never changes after this (rows write chunks only)
            zarr.consolidate_metadata(str(tmp), zarr_format=2)
            tmp.rename(path)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return cls(path)

    def status(self) -> np.ndarray:
        """Per material: :data:`MISSING`, :data:`DONE` or :data:`FAILED`."""
        return np.asarray(self._group["status"][:])

    def row(self, k: int):
        """Material ``k`` as the :class:`gonio.dataset.SampledBRDF` its ``brdf.h5`` held (its attributes:
        the store's, with its material and seed): the values :func:`open_store` gives, read with zarr
        alone (no xarray, no dask in the process that reads)."""
        from gonio.dataset import SampledBRDF

        g = self._group
        attrs = self.attrs | {"material": str(g["spec"][k]), "seed": int(g["seed"][k])}
        for key in ("symmetries", "config"):
            if isinstance(attrs.get(key), str):
                attrs[key] = json.loads(attrs[key])
        get = {name: np.asarray(g[name][k]) for name in (*_PER_SAMPLE, *_PER_CHANNEL, "grid_index")}
        planned = np.stack([get[f"{a}_planned"] for a in _ANGLES], axis=1)
        return SampledBRDF(*(get[a] for a in _ANGLES), get["value"], get["stddev"], attrs, planned=planned,
                           step=get["step"], pose=get["pose"], exposure_s=get["exposure_s"],
                           campaign_s=get["campaign_s"], grid_index=get["grid_index"],
                           grid_axes=tuple(str(a) for a in g["grid_axis"][:]))

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


def _check_group(path: Path) -> None:
    if not (path / ".zgroup").is_file():
        raise ValueError(f"{path}: not a batch store (no Zarr group there)")


def _check_format(path: Path, attrs) -> None:
    if attrs.get("format") != FORMAT:
        raise ValueError(f"{path}: a Zarr store, but not a gonio batch store (format "
                         f"{attrs.get('format')!r})")


def open_store(path):
    """The batch store at ``path`` as an ``xarray.Dataset`` (lazy, dask-backed).

    Raises
    ------
    ValueError
        ``path`` is not a gonio batch store.
    """
    import xarray as xr

    path = Path(path)
    _check_group(path)
    ds = xr.open_zarr(str(path), consolidated=True)
    _check_format(path, ds.attrs)
    return ds
