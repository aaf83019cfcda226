"""Batch simulation past one machine: many simulated campaigns on Dask into one xarray/Zarr store.

- :mod:`gonio.batch.materials`: the MATERIALS of a batch (a file, or a spec that spans a family);
- :mod:`gonio.batch.store`: the store's layout and its crash-safe writes;
- :mod:`gonio.batch.run`: one Dask task per material, each exactly ``gonio simulate``, written as it comes.
"""

from gonio.batch.materials import expand, read_materials
from gonio.batch.run import BatchSummary, run_batch, simulate_row
from gonio.batch.store import DONE, FAILED, MISSING, BatchStore, open_store

__all__ = ["expand", "read_materials", "run_batch", "simulate_row", "BatchSummary", "BatchStore",
           "open_store", "MISSING", "DONE", "FAILED"]
