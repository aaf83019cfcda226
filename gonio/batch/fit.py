"""Fitting many measured BRDFs at once: every done material of a batch store, or every finished
campaign of a folder, fitted with one model on the Dask cluster, into one table.

A row of the table: the source (the material of a store row, or the campaign folder), its status (``ok``,
``misfit``: the model leaves a structured residual, ``failed`` with the reason, ``missing``: a store row
not done), the fitted MATERIAL string, χ²/dof, the relative residual, and each parameter's value and
standard deviation (``NAME`` and ``NAME_stddev``; ``NAME_at_bound`` where the fit ended on a bound). A
store row is fitted from its samples alone; a campaign folder's fit includes its calibration's shared
errors, as ``gonio fit CAMPAIGN`` does.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["FitJob", "FitRow", "sources", "fit_one", "fit_many", "table_csv"]


@dataclass(frozen=True)
class FitJob:
    """What each fit does: the model and :func:`gonio.fit.fit`'s options."""

    model: str
    channels: str | None = None
    loss: str = "auto"
    starts: int = 4


@dataclass(frozen=True)
class FitRow:
    """One row of the table (see the module docstring); ``fit`` is :meth:`FitResult.to_json` or None."""

    source: str
    status: str
    fit: dict | None = None
    error: str = ""


def sources(path: Path) -> tuple[str, list]:
    """What ``path`` holds to fit: ``("store", [(material, SampledBRDF or None), ...])`` for a batch
    store (None: a row not done), ``("folder", [campaign folder, ...])`` for a folder of finished
    campaigns (sorted by name).

    Raises
    ------
    ValueError
        Neither, or a folder without any finished campaign.
    """
    from gonio.dataset import BRDF_NAME

    path = Path(path)
    if (path / ".zgroup").is_file():
        from gonio.batch.store import DONE, BatchStore

        store = BatchStore.open(path)
        status = store.status()
        return "store", [(m, store.row(k) if status[k] == DONE else None)
                         for k, m in enumerate(store.materials)]
    campaigns = sorted(p for p in path.iterdir() if (p / BRDF_NAME).is_file()) if path.is_dir() else []
    if not campaigns:
        raise ValueError(f"{path}: neither a batch store nor a folder of finished campaigns (folders with "
                         f"{BRDF_NAME})")
    return "folder", campaigns


def fit_one(source, label: str, job: FitJob, threads: int | None = None) -> FitRow:
    """Fit ``job.model`` to one source (a Dask task); a failure is a row, never raised."""
    try:
        if threads is not None:
            import drjit as dr

            if dr.thread_count() != threads:
                dr.set_thread_count(threads)
        from gonio.fit import fit

        result = fit(source, job.model, channels=job.channels, loss=job.loss, starts=job.starts)
        status = "misfit" if result.residual["misfit"] else "ok"
        return FitRow(label, status, result.to_json())
    except Exception as e:
        return FitRow(label, "failed", error=f"{type(e).__name__}: {e}")


def fit_many(kind: str, items: list, job: FitJob, client, threads: int | None = None,
             on_row=None) -> list[FitRow]:
    """Every item of :func:`sources` fitted on ``client``; the rows in the sources' order."""
    from gonio.batch.cluster import bounded_map

    rows: list[FitRow | None] = [None] * len(items)
    tasks = []
    for k, item in enumerate(items):
        label, data = (item[0], item[1]) if kind == "store" else (str(item), item)
        if data is None:
            rows[k] = FitRow(label, "missing", error="the batch has not simulated it yet (rerun gonio batch)")
        else:
            tasks.append((k, (data, label, job, threads)))

    def take(k: int, row: FitRow) -> None:
        rows[k] = row
        if on_row is not None:
            on_row(k, row)

    bounded_map(client, fit_one, tasks, take, key=f"fit-{id(rows):x}")
    return rows


def table_csv(rows: list[FitRow]) -> str:
    """The table as CSV text: one line per source, a column per parameter (their union, in order)."""
    names: list[str] = []
    for r in rows:
        for name in (r.fit or {}).get("parameters", {}):
            if name not in names:
                names.append(name)
    header = ["source", "status", "material", "chi2_reduced", "rms_relative", "samples"]
    for n in names:
        header += [n, f"{n}_stddev", f"{n}_at_bound"]
    header.append("error")
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for r in rows:
        f = r.fit or {}
        res, params = f.get("residual", {}), f.get("parameters", {})
        line = [r.source, r.status, f.get("material", ""), _num(res.get("chi2_reduced")),
                _num(res.get("rms_relative")), f.get("samples", "")]
        for n in names:
            p = params.get(n)
            line += ["", "", ""] if p is None else [_num(p["value"]), _num(p["stddev"]),
                                                    str(p["at_bound"]).lower()]
        line.append(r.error)
        w.writerow(line)
    return buf.getvalue()


def _num(x) -> str:
    return "" if x is None or not np.isfinite(x) else repr(float(x))
