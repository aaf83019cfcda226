"""``gonio batch``: many simulated campaigns on Dask into one xarray/Zarr store (:mod:`gonio.batch`)."""

from __future__ import annotations

import os
import re
import sys
from pathlib import Path

from gonio.cli.common import Interrupted, UsageError, _Out, _seed, creatable_folder

_SCHEDULER = re.compile(r"^(tcp|tls|inproc|ws|wss)://[^\s/]+$")
#: The most local workers (a local cluster runs one process each).
MAX_WORKERS = 256


def _workers(text: str) -> int:
    import argparse

    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer from 1 to {MAX_WORKERS}, got {text!r}") \
            from None
    if not 1 <= n <= MAX_WORKERS:
        raise argparse.ArgumentTypeError(f"must be an integer from 1 to {MAX_WORKERS}, got {n}")
    return n


def _check_out(text: str) -> Path:
    out = Path(text)
    if not text.strip():
        raise UsageError("--out: empty; give the store's folder name, e.g. batch.zarr")
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out: {out} is a file; a batch store is a folder (e.g. batch.zarr)")
    if out.is_dir() and not (out / ".zgroup").is_file():
        raise UsageError(f"--out: {out} is a folder but no batch store; choose a new name (e.g. batch.zarr)")
    return creatable_folder(out)


def _client(args, out: _Out):
    """The Dask client: a local cluster of one-thread worker processes on loopback, or the scheduler
    given. Returns (client, cluster or None, Dr.Jit threads per task)."""
    import dask
    from distributed import Client, LocalCluster

    if args.scheduler is not None:
        if not _SCHEDULER.match(args.scheduler):
            raise UsageError(f"--scheduler: {args.scheduler!r} is no scheduler address; give e.g. "
                             "tcp://127.0.0.1:8786")
        try:
            client = Client(args.scheduler, timeout="10s")
        except (OSError, TimeoutError) as e:
            raise UsageError(f"--scheduler: no Dask scheduler answers at {args.scheduler} ({e})") from None
        return client, None, None
    workers = args.workers or len(os.sched_getaffinity(0))
    with dask.config.set({"distributed.worker.daemon": True}):
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=_dashboard(), silence_logs=40)
    return Client(cluster), cluster, 1


def _dashboard():
    """Loopback dashboard on a free port where bokeh is installed (Dask's dashboard needs it)."""
    import importlib.util

    return "127.0.0.1:0" if importlib.util.find_spec("bokeh") is not None else None


#: How long ``--scheduler`` waits for a first worker to join.
WORKER_WAIT_S = 30.0


def _check_versions(client) -> None:
    from gonio.campaign import software_version

    try:
        client.wait_for_workers(1, timeout=WORKER_WAIT_S)
    except TimeoutError:
        raise UsageError(f"--scheduler: no worker joined the scheduler at {client.scheduler.address} in "
                         f"{WORKER_WAIT_S:.0f} s; start one (python -m dask worker ADDRESS)") from None
    mine = software_version()

    def theirs():
        from gonio.campaign import software_version

        return software_version()

    try:
        versions = client.run(theirs)
    except Exception as e:      # a worker without gonio at all
        raise UsageError(f"--scheduler: a worker cannot run gonio ({type(e).__name__}: {e}); install gonio "
                         f"{mine} on every worker") from None
    for worker, v in versions.items():
        if v != mine:
            raise UsageError(f"--scheduler: worker {worker} runs gonio {v}, this is gonio {mine}; give every "
                             "worker the same version")


def cmd_batch(args) -> int:
    from gonio.batch import read_materials
    from gonio.config import load_config
    from gonio.plan import parse_grid

    out = _Out(args.quiet)
    store = _check_out(args.out)
    materials = read_materials(args.materials)
    try:
        grid = parse_grid(args.grid)
    except ValueError as e:
        raise UsageError(f"--grid: {e}") from None
    if grid.order == "fly":
        raise UsageError("--grid: order=fly is not for a batch (a fly campaign sweeps one gantry); give "
                         "another order, e.g. order=auto")
    cfg = load_config(args.config)
    if cfg.detector.driver != "sim":
        raise UsageError(f"--config: the detector of config '{cfg.name}' is '{cfg.detector.driver}'; a batch "
                         "simulates, so it needs a simulated detector (driver 'sim')")
    client, cluster, threads = _client(args, out)
    try:
        if cluster is None:
            _check_versions(client)
        workers = len(client.scheduler_info(n_workers=-1)["workers"])
        where = f"{workers} local workers" if cluster is not None else f"the scheduler at {args.scheduler}"
        link = client.dashboard_link if _dashboard() is not None or cluster is None else None
        out(f"batch of {len(materials)} materials on {where}" + (f"; dashboard {link}" if link else ""))
        summary = _run(args, out, materials, args.grid, cfg, client, threads, store)
    except Interrupted as err:
        print(f"gonio batch: interrupted ({err}); {store} keeps every row written: run the same command to "
              "do the rest", file=sys.stderr)
        return 130
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    for material, error in summary.failed:
        out(f"failed: {material}: {error}")
    done = summary.done_before + summary.written - len(summary.failed)
    out(f"{done}/{len(materials)} materials done in {summary.path} ({summary.written} written now, "
        f"{summary.done_before} before, {len(summary.failed)} failed)")
    return 1 if summary.failed else 0


def _run(args, out: _Out, materials, grid, cfg, client, threads, store):
    from gonio.batch import run_batch

    if args.quiet or not out.console.is_terminal:
        return run_batch(materials, grid=grid, seed=args.seed, cfg=cfg, out=store, client=client,
                         threads=threads)
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                  console=out.console) as progress:
        task = progress.add_task("materials", total=len(materials))
        return run_batch(materials, grid=grid, seed=args.seed, cfg=cfg, out=store, client=client,
                         threads=threads, on_row=lambda i, row: progress.advance(task))


def add_parsers(sub, fmt) -> None:
    """``gonio batch``."""
    sb = sub.add_parser("batch", formatter_class=fmt,
                        help="simulate many materials on Dask into one xarray/Zarr store")
    sb.add_argument("materials", metavar="MATERIALS",
                    help="a file of MATERIAL lines, or one MATERIAL whose options may span values: "
                         "key=A..BxN (N values from A to B) or key=a|b (each), e.g. "
                         "'ggx:alpha=0.02..0.5x20,metal=gold|copper' (40 materials)")
    sb.add_argument("--grid", required=True,
                    help="GRID of every campaign, e.g. iso:step=15 (gonio plan --help)")
    sb.add_argument("--out", required=True, help="the store, a folder, e.g. batch.zarr (a store of the same "
                    "batch is continued: only the missing materials run)")
    sb.add_argument("--seed", type=_seed, default=0, help="seed of every campaign's simulated detector")
    sb.add_argument("--config", default=None,
                    help="gantry config with a simulated detector (default: sim)")
    where = sb.add_mutually_exclusive_group()
    where.add_argument("--workers", type=_workers, default=None,
                       help="local worker processes (default: the CPU count)")
    where.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="an existing Dask scheduler, e.g. tcp://10.0.0.5:8786 (its workers need this "
                            "gonio version)")
    sb.add_argument("--quiet", action="store_true", help="no progress output")
    sb.set_defaults(func=cmd_batch)
