"""Running a batch: every material's simulated campaign as a Dask task, each result written into the
store (:mod:`gonio.batch.store`) as it arrives.

A task runs exactly what ``gonio simulate MATERIAL --grid GRID --seed S`` runs (a campaign created in a
temporary folder, the simulated gantry, the runner, the calibration, ``brdf.h5``), so each row is bit for
bit that command's samples. The client keeps at most one task per worker in flight and writes each
result as it comes, so memory holds at most one material's result per worker whatever the batch's size.
A failing material is recorded in the store (``status`` failed, its message in ``error``) and the others
go on. A rerun of the same command does only the rows that are not done.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gonio.batch.store import DONE, BatchStore, Row, row_data

__all__ = ["BatchSummary", "simulate_row", "run_batch", "plan_batch", "batch_attrs", "check_store"]


@dataclass(frozen=True)
class BatchSummary:
    """What a run did: rows written now, done before, failed (material, message), and the store."""

    path: Path
    written: int
    done_before: int
    failed: list


def simulate_row(material: str, grid: str, seed: int, cfg, threads: int | None = None, planned=None) -> Row:
    """The :class:`~gonio.batch.store.Row` of ``gonio simulate MATERIAL --grid GRID --seed SEED`` on
    ``cfg``'s simulated gantry, through the campaign lifecycle (:mod:`gonio.lifecycle`) in a temporary
    folder (a Dask task; ``threads`` caps Dr.Jit's thread pool in this worker; ``planned``: the grid's
    plan on ``cfg``, made once for the whole batch, else planned here). A failure is returned as a row
    with its ``error``, never raised."""
    try:
        if threads is not None:
            import drjit as dr

            if dr.thread_count() != threads:
                dr.set_thread_count(threads)
        from gonio.dataset import BRDF_NAME, read_brdf
        from gonio.lifecycle import Request, campaign_gantry, check_request, open_or_create, run_campaign

        request = Request(grid, material=material, seed=seed)
        mat = check_request(cfg, request)
        with tempfile.TemporaryDirectory(prefix="gonio-batch-") as d:
            folder = Path(d) / "c"
            c, _ = open_or_create(folder, cfg, request, spec=mat.spec,
                                  plan=(lambda: planned) if planned is not None else None)
            try:
                state, _ = run_campaign(c, campaign_gantry(c, mat))
            finally:
                c.close()
            if state != "done":
                return Row({}, {}, error=f"the campaign ended {state}, not done")
            return row_data(read_brdf(folder / BRDF_NAME))
    except Exception as e:      # recorded in the store; the batch goes on
        return Row({}, {}, error=f"{type(e).__name__}: {e}")


def batch_attrs(grid: str, seed: int, cfg) -> dict:
    """The store attributes that name a batch: a rerun must match them to continue it."""
    from gonio.campaign import config_hash, software_version
    from gonio.plan import parse_grid

    return {"batch_grid": parse_grid(grid).normalized, "batch_seed": int(seed), "batch_config_sha256":
            config_hash(cfg), "batch_software_version": software_version()}


def check_store(store: BatchStore, attrs: dict, materials: list[str]) -> str | None:
    """How the store at hand differs from the batch asked for (None: the same batch)."""
    names = {"batch_grid": "grid", "batch_seed": "seed", "batch_config_sha256": "config",
             "batch_software_version": "gonio version"}
    for key, what in names.items():
        if store.attrs.get(key) != attrs[key]:
            return f"its {what} is {store.attrs.get(key)!r}, this batch's {attrs[key]!r}"
    if store.materials != materials:
        pairs = zip([*store.materials, ""], [*materials, ""], strict=False)
        first = next(k for k, (a, b) in enumerate(pairs) if a != b)
        return (f"its materials differ: it holds {len(store.materials)}, this batch {len(materials)}; the "
                f"first difference at #{first + 1}")
    return None


def refuse_another_batch(out: Path, materials: list[str], grid: str, seed: int, cfg) -> None:
    """ValueError (naming --out) where the store at ``out`` holds another batch than this one: what
    :func:`run_batch` finds, said before any worker starts."""
    if Path(out).exists():
        _same_batch(Path(out), batch_attrs(grid, seed, cfg), materials)


def _same_batch(out: Path, attrs: dict, materials: list[str]) -> BatchStore:
    store = BatchStore(out)
    diff = check_store(store, attrs, materials)
    if diff is not None:
        raise ValueError(f"--out: {out} holds another batch ({diff}); repeat the original command to "
                         "continue it, or choose another --out")
    return store


def run_batch(materials: list[str], *, grid: str, seed: int, cfg, out: Path, client,
              threads: int | None = None, on_row: Callable[[int, Row], None] | None = None,
              planned=None) -> BatchSummary:
    """Run every material of the batch not yet done in the store at ``out`` on the Dask ``client``.

    Parameters
    ----------
    materials : list of str
        MATERIAL strings, checked (:func:`gonio.batch.materials.read_materials`).
    out : Path
        The store; created at the first result, continued where it holds this batch (a store of
        another batch is refused with ValueError).
    client : distributed.Client
    threads : int, optional
        Dr.Jit threads per task (1 on a local cluster of one-thread workers).
    on_row : callable, optional
        Called with the material's index and its row after each row is written.
    planned : gonio.campaign.Planned, optional
        The grid planned on ``cfg`` (:func:`plan_batch`), when the caller planned it already.
    """
    from gonio.campaign import LockHeld, pid_lock

    attrs = batch_attrs(grid, seed, cfg)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        lock = pid_lock(out.parent / f".{out.name}.lock")
    except LockHeld as held:
        raise ValueError(f"--out: another gonio batch (pid {held.holder}) is writing {out}; wait for it, or "
                         "stop it first") from None
    try:
        return _run(materials, grid, seed, cfg, out, client, threads, on_row, attrs, planned)
    finally:
        os.close(lock)


def plan_batch(materials: list[str], grid: str, seed: int, cfg):
    """The plan every campaign of the batch shares (one grid, one config): planning a tour costs more
    than simulating a material on a coarse grid, so it is made once. RequestError (``grid``) where the
    planner refuses the grid."""
    from gonio.lifecycle import Request, plan_request

    return plan_request(cfg, Request(grid, material=materials[0], seed=seed))


def _run(materials, grid, seed, cfg, out, client, threads, on_row, attrs, planned) -> BatchSummary:
    from gonio.batch.cluster import bounded_map

    store = None
    todo = list(range(len(materials)))
    done_before = 0
    if out.exists():
        store = _same_batch(out, attrs, materials)
        todo = [int(i) for i in np.flatnonzero(store.status() != DONE)]
        done_before = len(materials) - len(todo)
    written, failed, held = 0, [], []

    def take(i: int, row: Row) -> None:
        nonlocal store, written
        if row.error:
            failed.append((materials[i], row.error))
        elif store is None:
            store = BatchStore.create(out, materials, seed, row, attrs)
        if store is None:
            held.append((i, row))      # a failure before any row gave the store its shape
        else:
            for j, r in [*held, (i, row)]:
                store.write(j, r)
                written += 1
            held.clear()
        if on_row is not None:
            on_row(i, row)

    if not todo:
        return BatchSummary(out, 0, done_before, [])
    if planned is None:
        planned = plan_batch(materials, grid, seed, cfg)
    plan = client.scatter(planned, broadcast=True)      # sent to each worker once
    key = hashlib.sha256(json.dumps(attrs, sort_keys=True).encode()).hexdigest()[:12]
    tasks = ((i, (materials[i], grid, seed, cfg, threads, plan)) for i in todo)
    bounded_map(client, simulate_row, tasks, take, key)
    return BatchSummary(out, written, done_before, failed)
