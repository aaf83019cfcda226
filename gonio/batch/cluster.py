"""Where a batch runs: a local Dask cluster on loopback, or an existing scheduler, and the bounded map
that keeps at most one task per worker in flight (so memory holds one result per worker)."""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Iterable

__all__ = ["WORKER_WAIT_S", "PRELOAD", "PRE_SPAWN_DEFAULTS", "start_fork_server", "connect", "disconnect",
           "bounded_map", "dashboard_link"]

#: How long a client of an existing scheduler waits for a first worker to join.
WORKER_WAIT_S = 30.0
_ADDRESS = re.compile(r"^(tcp|tls|inproc|ws|wss)://[^\s/]+$")


#: The scheduler's HTTP server (the dashboard, where bokeh is installed): loopback, a free port.
DASHBOARD_ADDRESS = "127.0.0.1:0"

#: What a local cluster's fork server imports once, for every worker it forks: Dask's worker and what a
#: batch's or a fit's task imports before it computes. Not Dr.Jit (nor what imports it: the simulated
#: detector and materials, gonio.fit): its import starts a thread pool, which a forked child would lack
#: (tests/batch/test_batch_cluster.py checks that this list imports no thread).
PRELOAD = ("distributed", "gonio.batch.run", "gonio.batch.fit", "gonio.lifecycle", "gonio.dataset",
           "gonio.wiring", "gonio.runner", "h5py")


def dashboard_link(client) -> str | None:
    """Where the Dask dashboard is: its address where the scheduler serves one, a note where its HTTP
    server answers that it needs bokeh, None where nothing answers. One GET with the standard library's
    HTTP client (no redirect followed, no proxy: the scheduler's own address), not httpx, whose import
    costs every ``gonio batch`` and ``gonio fit STORE`` 0.1 s of CPU for this one request."""
    import http.client

    port = client.scheduler_info(n_workers=0).get("services", {}).get("dashboard")
    host = re.sub(r"^\w+://", "", client.scheduler.address).rsplit(":", 1)[0]
    if port is None or not host:
        return None
    link = f"http://{host}:{port}/status"
    conn = http.client.HTTPConnection(host.strip("[]"), int(port), timeout=2.0)
    try:
        conn.request("GET", "/status")
        r = conn.getresponse()
        status, head = r.status, r.read(200).decode("utf-8", "replace")
    except (OSError, http.client.HTTPException):
        return None
    finally:
        conn.close()
    if status != 200:
        return None
    return "none (the scheduler lacks bokeh >= 3.1, which the dashboard needs)" if "bokeh" in head else link


#: Dask's defaults of ``distributed.nanny.pre-spawn-environ``, what Dask sets before it starts a worker
#: process (one BLAS thread, glibc's trim threshold): known before distributed is imported (0.4 s of CPU),
#: which registers them (tests/batch/test_batch_cluster.py checks they are still Dask's).
PRE_SPAWN_DEFAULTS = {"MALLOC_TRIM_THRESHOLD_": 65536, "OMP_NUM_THREADS": 1, "MKL_NUM_THREADS": 1,
                      "OPENBLAS_NUM_THREADS": 1}


def start_fork_server() -> None:
    """Starts the process a local cluster's workers are forked from, importing :data:`PRELOAD` once
    (not each worker a fresh interpreter importing Dask and gonio: 0.5-0.8 s of CPU a worker; a forked
    worker also ends without the interpreter's finalization, which a closing cluster waits for). Called
    before a command imports distributed and plans or reads, it imports meanwhile, and :func:`connect`
    waits for less. Its environment is the one Dask gives a worker process: the variables of
    ``distributed.nanny.pre-spawn-environ`` (Dask's defaults, then the user's Dask config) not set
    already. Once running, it stays as it is."""
    import multiprocessing
    import multiprocessing.forkserver

    import dask  # the user's Dask config (files, DASK_* variables); distributed adds its defaults

    environ = PRE_SPAWN_DEFAULTS | dask.config.get("distributed.nanny.pre-spawn-environ", default={})
    for key, value in environ.items():
        if value is not None:
            os.environ.setdefault(key, str(value))
    multiprocessing.get_context("forkserver").set_forkserver_preload(list(PRELOAD))
    multiprocessing.forkserver.ensure_running()


def connect(workers: int | None = None, scheduler: str | None = None):
    """A Dask client: a local cluster of ``workers`` one-thread worker processes on loopback (default:
    one per CPU), or the existing ``scheduler``, whose workers must run this gonio version.

    Returns
    -------
    (client, cluster or None, Dr.Jit threads per task: 1 on the local cluster, None elsewhere)

    Raises
    ------
    ValueError
        A malformed address, no scheduler or no worker there, a worker with another gonio version;
        the message names ``--scheduler``.
    """
    if scheduler is None:
        start_fork_server()         # before this process imports distributed: it imports meanwhile
    import dask
    from distributed import Client, LocalCluster

    if scheduler is None:
        n = workers or len(os.sched_getaffinity(0))
        with dask.config.set({"distributed.worker.daemon": True,
                              "distributed.worker.multiprocessing-method": "forkserver"}):
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                                   dashboard_address=DASHBOARD_ADDRESS, silence_logs=40)
        return Client(cluster), cluster, 1
    if not _ADDRESS.match(scheduler):
        raise ValueError(f"--scheduler: {scheduler!r} is no scheduler address; give e.g. tcp://127.0.0.1:8786")
    try:
        client = Client(scheduler, timeout="10s")
    except (OSError, TimeoutError) as e:
        raise ValueError(f"--scheduler: no Dask scheduler answers at {scheduler} ({e})") from None
    try:
        _check_workers(client, scheduler)
    except BaseException:
        client.close()
        raise
    return client, None, None


def disconnect(client, cluster) -> None:
    """Closes what :func:`connect` returned. A local cluster's workers are told first that losing the
    scheduler is expected: they are closed after it stops answering, and a heartbeat sent in between
    (a loaded machine) would otherwise log a traceback to the user's terminal as the batch ends."""
    try:
        if cluster is not None:
            try:
                client.run(_closing)
            except Exception:     # noqa: BLE001 - a worker already gone logs nothing more either
                pass
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _closing() -> None:
    import logging

    for name in ("distributed.worker", "distributed.core", "distributed.comm", "distributed.nanny"):
        logging.getLogger(name).setLevel(logging.CRITICAL)


def _version() -> str:
    from gonio.campaign import software_version

    return software_version()


def _check_workers(client, scheduler: str) -> None:
    try:
        client.wait_for_workers(1, timeout=WORKER_WAIT_S)
    except TimeoutError:
        raise ValueError(f"--scheduler: no worker joined the scheduler at {scheduler} in {WORKER_WAIT_S:.0f} "
                         "s; start one (python -m dask worker ADDRESS)") from None
    mine = _version()
    try:
        versions = client.run(_version)
    except Exception as e:      # a worker without gonio at all
        raise ValueError(f"--scheduler: a worker cannot run gonio ({type(e).__name__}: {e}); install gonio "
                         f"{mine} on every worker") from None
    for worker, v in versions.items():
        if v != mine:
            raise ValueError(f"--scheduler: worker {worker} runs gonio {v}, this is gonio {mine}; give every "
                             "worker the same version")


def bounded_map(client, fn: Callable, items: Iterable[tuple[int, tuple]],
                on_result: Callable[[int, object], None], key: str) -> None:
    """``fn(*args)`` for each ``(index, args)`` of ``items`` on the cluster, at most one task per worker in
    flight; ``on_result(index, result)`` as each ends (in the order they end), before the next is sent."""
    from distributed import as_completed

    workers = max(1, len(client.scheduler_info(n_workers=-1)["workers"]))
    pending = iter(items)
    futures = as_completed()
    index = {}

    def submit() -> None:
        item = next(pending, None)
        if item is not None:
            i, args = item
            f = client.submit(fn, *args, key=f"gonio-{key}-{i}", pure=False)
            index[f.key] = i
            futures.add(f)

    for _ in range(workers):
        submit()
    for f in futures:
        result = f.result()
        f.release()
        on_result(index.pop(f.key), result)
        submit()
