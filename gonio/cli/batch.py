"""``gonio batch``: many simulated campaigns on Dask into one xarray/Zarr store (:mod:`gonio.batch`)."""

from __future__ import annotations

import sys
from pathlib import Path

from gonio.cli.common import Interrupted, Out, UsageError, creatable_folder, grid_arg


def connected(args, out: Out, what: str):
    """The Dask client of ``--workers``/``--scheduler`` (see :func:`gonio.batch.cluster.connect`), with
    the line that says where the work runs."""
    from gonio.batch.cluster import connect, dashboard_link

    try:
        client, cluster, threads = connect(args.workers, args.scheduler)
    except ValueError as e:
        raise UsageError(str(e)) from None
    workers = len(client.scheduler_info(n_workers=-1)["workers"])
    where = f"{workers} local worker{'s' * (workers != 1)}" if cluster is not None else \
        f"the scheduler at {args.scheduler}"
    link = dashboard_link(client)
    out(f"{what} on {where}" + (f"; dashboard {link}" if link else ""))
    return client, cluster, threads


def _check_out(text: str) -> Path:
    out = Path(text)
    if not text.strip():
        raise UsageError("--out: empty; give the store's folder name, e.g. batch.zarr")
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out: {out} is a file; a batch store is a folder (e.g. batch.zarr)")
    if out.is_dir() and not (out / ".zgroup").is_file():
        raise UsageError(f"--out: {out} is a folder but no batch store; choose a new name (e.g. batch.zarr)")
    if out.is_dir():
        from gonio.batch.store import BatchStore

        try:
            BatchStore.open(out)
        except ValueError as e:
            raise UsageError(f"--out: {e}; choose a new name (e.g. batch.zarr)") from None
    return creatable_folder(out)


def cmd_batch(args) -> int:
    from gonio.batch import read_materials
    from gonio.config import load_config

    out = Out(args.quiet)
    store = _check_out(args.out)
    materials = read_materials(args.materials)
    grid = grid_arg(args.grid)
    if grid.budget_s is not None:
        raise UsageError("--grid: a batch stores one sample count for every material; an adaptive grid "
                         "with budget_s measures as many as the time holds: give poses=N instead")
    if grid.order == "fly":
        raise UsageError("--grid: order=fly is not for a batch (a fly campaign sweeps one gantry); give "
                         "another order, e.g. order=auto")
    cfg = load_config(args.config)
    if cfg.detector.driver != "sim":
        raise UsageError(f"--config: the detector of config '{cfg.name}' is '{cfg.detector.driver}'; a batch "
                         "simulates, so it needs a simulated detector (driver 'sim')")
    n = len(materials)
    from gonio.batch.run import refuse_another_batch

    refuse_another_batch(store, materials, args.grid, args.seed, cfg)   # before any worker starts
    if args.scheduler is None:
        from gonio.batch.cluster import start_fork_server

        start_fork_server()         # the local workers' imports, while this process plans
    from gonio.batch.run import plan_batch
    from gonio.lifecycle import RequestError

    try:
        planned = plan_batch(materials, args.grid, args.seed, cfg)
    except RequestError as err:
        flag = {"grid": "--grid", "gantry": "--config", "material": "MATERIALS"}.get(err.field, err.field)
        raise UsageError(f"{flag}: {err}") from None
    client, cluster, threads = connected(args, out, f"batch of {n} material{'s' * (n != 1)}")
    from gonio.batch.cluster import disconnect

    try:
        summary = _run(args, out, materials, args.grid, cfg, client, threads, store, planned)
    except Interrupted as err:
        print(f"gonio batch: interrupted ({err}); {store} keeps every row written: run the same command to "
              "do the rest", file=sys.stderr)
        return 130
    finally:
        disconnect(client, cluster)
    for material, error in summary.failed:
        out(f"failed: {material}: {error}")
    done = summary.done_before + summary.written - len(summary.failed)
    out(f"{done}/{len(materials)} materials done in {summary.path} ({summary.written} written now, "
        f"{summary.done_before} before, {len(summary.failed)} failed)")
    return 1 if summary.failed else 0


def _run(args, out: Out, materials, grid, cfg, client, threads, store, planned):
    from gonio.batch import run_batch

    if args.quiet or not out.is_terminal:
        return run_batch(materials, grid=grid, seed=args.seed, cfg=cfg, out=store, client=client,
                         threads=threads, planned=planned)
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                  console=out.console) as progress:
        task = progress.add_task("materials", total=len(materials))
        return run_batch(materials, grid=grid, seed=args.seed, cfg=cfg, out=store, client=client,
                         threads=threads, on_row=lambda i, row: progress.advance(task), planned=planned)
