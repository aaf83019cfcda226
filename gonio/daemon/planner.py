"""Planning submitted campaigns in a worker process, within a time limit, cancelled when the client leaves.

Planning a fine grid takes seconds to minutes of CPU. In the daemon's own process it competed with the
runner for the interpreter (a burst of 20 small submits slowed a running campaign by 86 %) and nothing
could stop it once started. Here one worker process (forked from a server that has imported the planner
once, so a fresh worker is ready at once; at idle priority, so the runner comes first) takes one request
at a time: it loads the material, checks the request against the gantry, plans it and creates its
journal in a staging folder (:func:`gonio.daemon.records.prepare_campaign`). The daemon then gives that
folder its id (:meth:`gonio.daemon.queue.CampaignQueue.admit`).

A request whose planning uses more than ``timeout_s`` of CPU time (so that a machine busy with other work
does not turn a sound request into a refusal; at most :data:`WALL_FACTOR` times that of wall time), or
whose client went away, has its worker killed (a fresh one takes its place) and its staging folder
removed: 422 naming ``grid`` for the time limit. At most ``max_waiting``
requests wait for the worker; more are refused (503, :class:`PlannerBusy`).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import copy
import errno
import logging
import multiprocessing
import os
import queue
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from gonio.daemon.records import DiskFull, FieldError, prepare_campaign
from gonio.store import is_disk_full

if TYPE_CHECKING:   # the worker imports it (and Dr.Jit with it) after its fork
    from gonio.sim.materials.library import MaterialsFolder

__all__ = ["Planner", "PlannerBusy", "ClientGone", "PlanCache", "PLAN_TIMEOUT_S", "MAX_WAITING",
           "start_fork_server"]

log = logging.getLogger(__name__)

#: CPU seconds one request may plan (the finest grids the daemon accepts plan in under 20 s); where the
#: worker's CPU time cannot be read, wall seconds.
PLAN_TIMEOUT_S = 120.0
#: Requests that may wait for the worker at once.
MAX_WAITING = 32
#: Seconds a fresh worker may take to start.
START_TIMEOUT_S = 60.0
_POLL_S = 0.05
#: Seconds :meth:`Planner.stop` lets a worker's start go on when the daemon's process exits next.
EXIT_GRACE_S = 0.5
#: Plans the worker keeps for the next request of the same grid (:class:`PlanCache`), and their steps in
#: all (~80 bytes a step: at most ~80 MB however fine the grids).
PLANS_KEPT = 8
PLAN_STEPS_KEPT = 1_000_000
#: Seconds between checks that a waiting request's client is still there (a look at the connection's
#: receive queue: a client gone is noticed, and its planning stopped, within this).
_CLIENT_POLL_S = 0.1
_TICKS = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
#: A request's planning is stopped after this many times its time limit of wall time, however little CPU
#: time the machine's other work left it (it runs at idle priority).
WALL_FACTOR = 5
#: What the fork server imports for its workers: the planner's modules (gonio.plan and gonio.campaign import
#: them only when they plan, gonio.config when a config is read) and the k-d trees they plan with.
_PRELOAD = ("gonio.daemon.records", "gonio.config", "gonio.plan.build", "scipy.spatial", "gonio.campaign",
            "gonio.lifecycle", "gonio.fly.plans")


class PlannerBusy(RuntimeError):
    """Too many requests wait for the planner (503)."""


class ClientGone(RuntimeError):
    """The request's client went away; its planning was cancelled."""


class PlannerFailed(RuntimeError):
    """The planner could not create the campaign for a reason that is not the request's (500, one line)."""


@dataclass
class _Job:
    req: dict
    folder: Path
    done: concurrent.futures.Future = field(default_factory=concurrent.futures.Future)
    cancelled: threading.Event = field(default_factory=threading.Event)


def _cpu_s(pid: int) -> float | None:
    """CPU seconds process ``pid`` has used (Linux: /proc), or None where that cannot be read."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return (int(fields[11]) + int(fields[12])) / _TICKS


def _consume(future) -> None:
    """Read the outcome of a job nobody waits for any more (else asyncio logs it as never retrieved)."""
    if not future.cancelled():
        future.exception()


def _context():
    ctx = multiprocessing.get_context("forkserver")
    # The server imports the planning modules once; every worker forks from it with them loaded. (A fork
    # of the daemon itself would copy its threads' locks mid-use; Dr.Jit, which starts a thread pool, is
    # imported by each worker after its fork.)
    ctx.set_forkserver_preload(list(_PRELOAD))
    return ctx


def start_fork_server() -> None:
    """Start the fork server the planner's workers fork from, now, without waiting for it: a fresh
    interpreter importing the planner (~0.7 s of CPU) then overlaps the rest of the daemon's start (its
    web stack's imports), where the first worker, started once the daemon listens, waited for it. Where
    it runs already (one per process), nothing."""
    from multiprocessing import forkserver

    _context()
    forkserver.ensure_running()


class PlanCache:
    """:func:`gonio.campaign.plan_campaign` that keeps the ``size`` plans it made last, by grid and
    config: planning is deterministic (the same grid on the same config plans the same poses, order and
    estimates), and a lab submits one grid for sample after sample (each took a fresh plan: 0.4 s of CPU
    for iso:step=15, minutes for the finest grids). Each call gets a copy of its own: nothing a campaign
    does to its plan reaches another's. A grid the planner refuses is not kept; the least recently asked
    plans make room, past ``size`` plans or ``max_steps`` steps in all (the newest is always kept)."""

    def __init__(self, size: int = PLANS_KEPT, max_steps: int = PLAN_STEPS_KEPT):
        self.size = size
        self.max_steps = max_steps
        self.planned = 0            # plans made (the others were copies of kept ones)
        self._plans: OrderedDict = OrderedDict()

    def __call__(self, grid: str, cfg):
        from gonio.campaign import config_hash, plan_campaign

        key = (grid, config_hash(cfg))
        if key in self._plans:
            self._plans.move_to_end(key)
        else:
            self.keep(grid, cfg, plan_campaign(grid, cfg))
            self.planned += 1
        return copy.deepcopy(self._plans[key])

    def keep(self, grid: str, cfg, planned) -> None:
        """Keep ``planned`` (:func:`gonio.campaign.plan_campaign` of ``grid`` on ``cfg``, made elsewhere) as
        the newest plan."""
        from gonio.campaign import config_hash

        key = (grid, config_hash(cfg))
        self._plans[key] = planned
        self._plans.move_to_end(key)
        while len(self._plans) > 1 and (len(self._plans) > self.size or self._steps() > self.max_steps):
            self._plans.popitem(last=False)

    def _steps(self) -> int:
        return sum(len(p.plan.step_kind) for p in self._plans.values())


def _worker_main(conn, cfg, materials_root, idle: bool = True, plans: PlanCache | None = None) -> None:
    """The worker: one request at a time from ``conn``, each answered with one tuple; at idle priority
    unless ``idle`` is False; planning with ``plans`` (its copy of them) when given.

    The start, up to its "ready", runs at the daemon's priority: a daemon stopped while this worker
    started (it does not wait for a start) leaves it to find that out, and at idle priority on a busy
    machine it waited for an idle core to do so, holding the daemon's stdout and stderr open meanwhile (a
    caller reading them to their end waited as long). The materials (and Dr.Jit with them, ~0.1 s of CPU)
    are imported with the first request: the worker of a daemon stopped before anything was submitted
    never pays for them (in a test suite's daemons, 36 of 86), and every start is that much shorter."""
    materials = None
    plans = PlanCache() if plans is None else plans
    try:
        conn.send(("ready",))
    except (BrokenPipeError, OSError):   # the daemon stopped while this worker started
        return
    try:   # the runner and the event loop first: planning takes only the CPU time they leave idle
        if idle:
            os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    except (AttributeError, OSError):
        os.nice(19)
    while True:
        try:
            req, folder = conn.recv()
        except (EOFError, OSError):   # the daemon is gone
            return
        try:
            if materials is None:
                from gonio.sim.materials.library import MaterialsFolder

                materials = MaterialsFolder(materials_root)
            reply = ("ok", prepare_campaign(cfg, req, materials, Path(folder), plan=plans))
        except FieldError as err:
            reply = ("field", err.field, str(err))
        except Exception as err:
            reply = ("disk-full" if is_disk_full(err) else "error", f"{type(err).__name__}: {err}")
        try:
            conn.send(reply)
        except (BrokenPipeError, OSError):
            return


class Planner:
    """The planning worker (see the module docstring).

    Parameters
    ----------
    cfg : GonioConfig
        The daemon's gantry.
    materials : MaterialsFolder
        Where measured materials are named from.
    timeout_s : float
        Seconds one request may plan.
    max_waiting : int
        Requests that may wait at once.
    idle : bool
        Plan at idle priority (the default: the runner and the event loop first). False plans at the
        daemon's own priority, for a machine whose other work is no more urgent than the planning (a
        test suite's other workers: at idle priority a submission waited for a core to fall idle).
    plans : PlanCache, optional
        Plans each worker starts with (a copy of them each; default none): plans made beforehand, e.g.
        by the other daemons of one process (a test suite's: each planned iso:step=15 afresh, 0.4 s of
        CPU, where a kept plan is a copy of 10 ms). A worker keeps the plans it makes to itself.
    """

    def __init__(self, cfg, materials: MaterialsFolder, *, timeout_s: float = PLAN_TIMEOUT_S,
                 max_waiting: int = MAX_WAITING, idle: bool = True, plans: PlanCache | None = None):
        self.cfg = cfg
        self.idle = idle
        self.plans = plans
        self.materials = materials
        self.timeout_s = timeout_s
        self.max_waiting = max_waiting
        self._jobs: queue.Queue = queue.Queue()
        self._waiting = 0
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._stopping = threading.Event()
        self._starting = threading.Event()   # a worker is being started
        self._first_start = threading.Event()   # the first worker has started, or failed to
        self._proc = None
        self._conn = None
        self.busy = False          # a request is being planned now
        self.planned = 0           # requests the worker was given
        self.killed = 0            # workers killed (time limit, a client gone)

    # -- life --------------------------------------------------------------------------------------
    def start(self) -> None:
        self._thread = threading.Thread(target=self._serve, name="gonio-planner", daemon=True)
        self._thread.start()

    def stop(self, start_grace_s: float = 0.0) -> None:
        """Stop the worker: the request being planned and every waiting one fail (PlannerFailed). A
        worker still starting is waited for at most ``start_grace_s`` (a fresh fork server imports the
        planner for a second or more; a daemon stopped as it starts waited for that): it is killed as soon
        as it has started. A process about to exit gives :data:`EXIT_GRACE_S`: the start writes the fork
        server's new child its data right after asking for it, and a daemon that exited in between (its
        start's thread held up there) left that child an EOFError's traceback on the daemon's stderr."""
        self._stopping.set()
        self._jobs.put(None)
        if self._thread is not None:
            self._thread.join(start_grace_s if self._starting.is_set() else START_TIMEOUT_S)
        self._kill()

    def wait_started(self, timeout_s: float = START_TIMEOUT_S) -> bool:
        """Wait (at most ``timeout_s``) until the first worker has started, or failed to (logged); whether it
        did either. ``gonio serve`` waits for it before it says it listens: a stop that came during the
        start (its fork server still importing the planner) waited :data:`EXIT_GRACE_S` for it, and that
        fork server held the daemon's stdout and stderr open until its imports were done."""
        return self._first_start.wait(timeout_s)

    def _worker(self):
        """The worker's connection, started (and waited for) when there is none."""
        if self._proc is not None and self._proc.is_alive():
            return self._conn
        self._kill()
        ctx = _context()
        parent, child = ctx.Pipe()
        proc = ctx.Process(target=_worker_main, daemon=True, name="gonio-planner-worker",
                           args=(child, self.cfg, self.materials.root, self.idle, self.plans))
        self._starting.set()
        try:
            proc.start()     # blocks while a fresh fork server imports the planner
            child.close()
            self._proc, self._conn = proc, parent
            deadline = time.monotonic() + START_TIMEOUT_S
            while True:
                if self._stopping.is_set():
                    self._kill()
                    raise PlannerFailed("the daemon is stopping")
                if parent.poll(_POLL_S):
                    break
                if time.monotonic() > deadline:
                    self._kill()
                    raise PlannerFailed(f"the planner did not start within {START_TIMEOUT_S:g} s")
            try:
                ready = parent.recv()
            except (EOFError, OSError):     # it died starting
                ready = None
            if ready != ("ready",):
                self._kill()
                raise PlannerFailed("the planner's worker stopped as it started")
        finally:
            self._starting.clear()
        return parent

    def _kill(self) -> None:
        proc, conn = self._proc, self._conn
        self._proc = self._conn = None
        if proc is not None:
            if proc.is_alive():
                proc.kill()
            proc.join(10)
        if conn is not None:
            conn.close()

    # -- requests ----------------------------------------------------------------------------------
    async def prepare(self, req: dict, folder: Path, is_disconnected=None) -> str | None:
        """Plan ``req`` into ``folder`` in the worker; the material's spec. Raises FieldError (the
        request's fault, or its planning outlasted the limit), DiskFull, PlannerBusy, ClientGone (when
        ``is_disconnected()`` says the client left) or PlannerFailed."""
        with self._lock:
            if self._waiting >= self.max_waiting:
                raise PlannerBusy(f"{self._waiting} campaigns are being planned; retry in a few seconds")
            self._waiting += 1
        job = _Job(req, folder)
        self._jobs.put(job)
        done = asyncio.wrap_future(job.done)
        try:
            while True:
                finished, _ = await asyncio.wait({done}, timeout=_CLIENT_POLL_S)
                if finished:
                    return done.result()
                if is_disconnected is not None and await is_disconnected():
                    job.cancelled.set()
                    done.add_done_callback(_consume)
                    raise ClientGone("the client went away")
        except asyncio.CancelledError:
            job.cancelled.set()
            done.add_done_callback(_consume)
            raise
        finally:
            with self._lock:
                self._waiting -= 1

    def _serve(self) -> None:
        try:
            self._worker()          # ready before the first request comes
        except PlannerFailed as err:
            log.error("%s", err)
        finally:
            self._first_start.set()
        while True:
            job = self._jobs.get()
            if job is None:
                self._kill()      # one that started after stop() looked
                return
            if job.cancelled.is_set():
                job.done.set_exception(ClientGone("the client went away"))
                continue
            if self._stopping.is_set():
                job.done.set_exception(PlannerFailed("the daemon is stopping"))
                continue
            self.busy = True
            try:
                job.done.set_result(self._plan(job))
            except BaseException as err:
                job.done.set_exception(err)
            finally:
                self.busy = False

    def _plan(self, job: _Job):
        conn = self._worker()
        conn.send((job.req, str(job.folder)))
        self.planned += 1
        cpu0, wall_end = _cpu_s(self._proc.pid), time.monotonic() + WALL_FACTOR * self.timeout_s
        while not conn.poll(_POLL_S):
            if self._stopping.is_set():
                self._kill()
                raise PlannerFailed("the daemon is stopping")
            cpu = _cpu_s(self._proc.pid)
            late = time.monotonic() > wall_end or (cpu is not None and cpu - cpu0 > self.timeout_s)
            if job.cancelled.is_set() or late or not self._proc.is_alive():
                alive = self._proc.is_alive()
                self._kill()
                self.killed += 1
                if job.cancelled.is_set():
                    log.info("planning of %s cancelled: the client went away", job.req.get("grid"))
                    raise ClientGone("the client went away")
                if not alive:
                    raise PlannerFailed("the planner stopped while planning; try again")
                log.warning("planning of %s stopped after %.0f s", job.req.get("grid"), self.timeout_s)
                raise FieldError("grid", f"planning took longer than {self.timeout_s:g} s, the daemon's "
                                 "limit; choose a coarser grid (gonio plan --grid GRID times it)")
        kind, *rest = conn.recv()
        if kind == "ok":
            return rest[0]
        if kind == "field":
            raise FieldError(rest[0], rest[1])
        if kind == "disk-full":
            raise DiskFull(errno.ENOSPC, rest[0])
        raise PlannerFailed(rest[0])
