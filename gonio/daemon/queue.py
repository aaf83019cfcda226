"""The persistent campaign queue, and the worker thread that runs its head on the gantry.

Each campaign is a folder ``DATA/campaigns/<id>/`` holding its journal (:mod:`gonio.store`), its lock,
``brdf.h5`` once finished, and ``daemon.json``: the request it was submitted with, its place in the
queue (``seq``) and the operator's intent (``run`` or ``hold``). Everything else (running, paused,
halted, faulted, done, aborted, progress) is read from the journal, so the queue survives any crash of
the daemon: on start it is rebuilt from the folders.

One campaign owns the gantry at a time: the head of the queue (the first campaign by ``seq`` that is
neither done nor aborted). The worker runs it when its intent is ``run``; a paused, halted or faulted
head holds the whole queue until an operator resumes or aborts it, so nothing moves behind the back of
someone who stopped the gantry. A campaign the daemon was running when it died (or was stopped by
SIGTERM, which pauses it) keeps intent ``run`` and resumes when the daemon starts again; ``hold=True``
holds such campaigns paused instead.

A campaign appears whole or not at all: it is planned and journaled in a staging folder
(``campaigns/.incoming/``, by :mod:`gonio.daemon.planner`), then :meth:`CampaignQueue.admit` reserves the
next id (a folder of that name made exclusively: an id is never reused, nor one whose folder someone
left behind), writes ``daemon.json`` into the staging folder and renames it into place. At start, staging
leftovers are removed and a folder that is not a whole campaign is moved aside (``cNNNNN.orphan-T``).

A fault the runner cannot journal (a full disk) is kept in ``daemon.json`` (the daemon frees a 1 MiB
reserve file, ``DATA/.reserve``, to write it) and journaled as ``unclean-stop`` at the next start, as is
every run a crash cut short (:meth:`gonio.store.Journal.note_unclean_stop`).

Pause, resume, abort and halt are requests to the engine from request handlers' threads, through its
command queue (:meth:`gonio.runner.Runner.request`); the engine acts at its next unit boundary (halt:
within one ``poll_s`` slice, mid-move too). Requests that come while the worker is starting a campaign
reach its engine before it runs (they act before anything moves). A campaign's state is the explicit
table of :mod:`gonio.daemon.states`, derived from its engine's state while the worker runs it, from its
journal and the operator's intent otherwise. Campaigns are run through the campaign lifecycle
(:mod:`gonio.lifecycle`), whatever their kind (stop-and-go or fly, on a configured gantry or the
simulated one).
"""

from __future__ import annotations

import logging
import os
import re
import shutil
import threading
import time
import uuid
from pathlib import Path

from gonio.campaign import LockHeld, gantry_state, open_campaign
from gonio.config import GonioConfig
from gonio.daemon.pacing import PacedClock
from gonio.daemon.records import (
    ID_PATTERN,
    RECORD_NAME,
    Conflict,
    DiskFull,
    FieldError,
    NotFound,
    Record,
)
from gonio.daemon.states import CampaignView, campaign_state
from gonio.dataset import BRDF_NAME
from gonio.runner import Runner, State
from gonio.sim.materials.library import MaterialsFolder
from gonio.store import JOURNAL_NAME, Journal, JournalError, is_disk_full

__all__ = ["CampaignQueue", "FieldError", "Conflict", "NotFound", "DiskFull", "INCOMING"]

log = logging.getLogger(__name__)

#: Seconds a running campaign's status read from its journal is reused (progress comes from the runner).
STATUS_TTL_S = 0.25
#: Seconds an abort waits for a starting or stopping campaign to settle, so its reply tells the outcome.
ABORT_WAIT_S = 10.0
#: Folder (under campaigns/) where requests are planned and journaled before they get an id.
INCOMING = ".incoming"
#: Bytes kept in DATA/.reserve, freed to record a fault when the disk is full.
RESERVE_BYTES = 1 << 20
_ANY_ID = re.compile(r"^c([0-9]{5})")


class CampaignQueue:
    """The campaigns under ``data/campaigns`` and the worker that runs them one at a time.

    Parameters
    ----------
    data : Path
        The daemon's data folder.
    cfg : GonioConfig
        The gantry new campaigns are planned for (a resumed campaign runs with its own snapshot).
    pace : float
        Real seconds per gantry second of a simulated gantry (:class:`PacedClock`); 0 in tests.
    hold : bool
        Campaigns that were running when the daemon stopped are held paused instead of resumed.
    before_run : callable, optional
        Called by the worker before it connects a campaign's gantry (the daemon releases its idle one).
    clock : Clock, optional
        Time source of a gantry with real devices (default: the wall clock; tests pass the emulators').
    materials : MaterialsFolder, optional
        Where ``bsdf:NAME`` and ``merl:NAME`` materials are read (default: none, refused).
    """

    def __init__(self, data: Path, cfg: GonioConfig, *, pace: float = 0.0, hold: bool = False,
                 before_run=None, clock=None, materials: MaterialsFolder | None = None):
        self.data = Path(data)
        self.materials = materials or MaterialsFolder(None)
        self.clock = clock
        self.root = self.data / "campaigns"
        self.cfg = cfg
        self.pace = pace
        self.hold = hold
        self.before_run = before_run
        self._records: dict[str, Record] = {}
        self._cond = threading.Condition(threading.RLock())
        self._stopping = threading.Event()
        self._thread: threading.Thread | None = None
        self.current: Record | None = None
        self.runner: Runner | None = None
        self.gantry = None           # the running campaign's gantry
        self.run_started: tuple[float, int] | None = None   # (Unix time, steps done) of this run's start
        self.finishing = False       # the current campaign's runner has stopped; it is leaving the worker

    # -- start and stop --------------------------------------------------------------------------
    def start(self) -> None:
        """Rebuild the queue from the folders (setting aside what is not a whole campaign, journaling
        runs a crash cut short), then start the worker."""
        self.root.mkdir(parents=True, exist_ok=True)
        shutil.rmtree(self.root / INCOMING, ignore_errors=True)
        (self.root / INCOMING).mkdir()
        for folder in sorted(self.root.iterdir()):
            if not (re.match(ID_PATTERN, folder.name) and folder.is_dir()):
                continue
            rec = self._load(folder)
            if rec is None:
                continue
            self._records[rec.id] = rec
            if self._journal_state(rec) == "running":
                self._note_unclean(rec)
            if self.hold and rec.intent == "run" and self._journal_state(rec) in ("running", "pausing",
                                                                                   "paused"):
                rec.intent = "hold"
                self._save(rec)
                log.info("campaign %s: held paused at start (--hold)", rec.id)
        self._make_reserve()
        self._thread = threading.Thread(target=self._work, name="gonio-runner", daemon=True)
        self._thread.start()

    def _load(self, folder: Path) -> Record | None:
        """The campaign in ``folder``, or None after moving aside a folder that is not a whole one (a
        creation an older daemon left half-done, something put there by hand)."""
        try:
            rec = Record.load(folder)
            whole = rec.id == folder.name and (folder / JOURNAL_NAME).is_file()
        except (OSError, ValueError, KeyError, TypeError):
            rec, whole = None, False
        if whole:
            return rec
        aside = folder.with_name(f"{folder.name}.orphan-{time.time_ns()}")
        try:
            folder.rename(aside)
            log.warning("%s is not a whole campaign (no %s or no journal): moved aside to %s; its id is not "
                        "reused", folder, RECORD_NAME, aside.name)
        except OSError as err:
            log.error("%s is not a whole campaign and could not be moved aside (%s); its id is not reused",
                      folder, err)
        return None

    def _note_unclean(self, rec: Record) -> None:
        """Journal that the campaign's last run was cut short (with the reason the daemon kept, if any)."""
        try:
            c = open_campaign(rec.folder)
        except (JournalError, LockHeld, OSError) as err:
            log.error("campaign %s: could not journal its unclean stop (%s)", rec.id, err)
            return
        try:
            if c.journal.note_unclean_stop(rec.unclean):
                log.warning("campaign %s: its last run stopped uncleanly%s", rec.id,
                            f" ({rec.unclean})" if rec.unclean else "")
            if rec.unclean is not None:
                rec.unclean = None
                self._save(rec)
        except Exception as err:
            log.error("campaign %s: could not journal its unclean stop (%s)", rec.id, err)
        finally:
            c.close()

    def _save(self, rec: Record) -> bool:
        """Write ``daemon.json``; on a full disk free the reserve and try once more. False (logged) when
        it could not be written: what it holds stays in effect in memory."""
        for attempt in (0, 1):
            try:
                rec.save()
                return True
            except OSError as err:
                if attempt == 0 and is_disk_full(err) and self._release_reserve():
                    continue
                log.error("campaign %s: could not write %s (%s)", rec.id, RECORD_NAME, err)
                return False
        return False

    def _make_reserve(self) -> None:
        path = self.data / ".reserve"
        if path.is_file() and path.stat().st_size == RESERVE_BYTES:
            return
        try:
            with open(path, "wb") as fh:
                fh.write(b"\0" * RESERVE_BYTES)
                fh.flush()
                os.fsync(fh.fileno())
        except OSError as err:
            path.unlink(missing_ok=True)
            log.warning("no room for the disk-full reserve %s (%s)", path, err)

    def _release_reserve(self) -> bool:
        try:
            (self.data / ".reserve").unlink()
        except OSError:
            return False
        log.warning("the data folder's disk is full: freed the reserve %s", self.data / ".reserve")
        return True

    def stop(self, reason: str = "daemon stopping", timeout_s: float = 300.0) -> None:
        """Pause the running campaign (it finishes the step in flight and parks) and end the worker.

        The campaign keeps intent ``run``: it resumes when the daemon starts again."""
        self._stopping.set()
        with self._cond:
            if self.runner is not None:
                self.runner.request_pause(reason)
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout_s)

    @property
    def stopping(self) -> bool:
        return self._stopping.is_set()

    def running_gantry(self):
        """(gantry, record) of the campaign running now, read together under the queue's lock; (None,
        None) or a record without a gantry between campaigns."""
        with self._cond:
            return self.gantry, self.current

    # -- submitting ------------------------------------------------------------------------------
    def staging(self) -> Path:
        """A fresh staging folder's path (not created) for the planner to journal a request in."""
        return self.root / INCOMING / uuid.uuid4().hex

    def _next_seq(self) -> int:
        taken = [r.seq for r in self._records.values()]
        taken += [int(m.group(1)) for m in map(_ANY_ID.match, os.listdir(self.root)) if m]
        return max(taken, default=0) + 1

    def admit(self, staging: Path, req: dict) -> Record:
        """Give the campaign journaled in ``staging`` the next free id and put it at the end of the queue:
        ``daemon.json`` is written into ``staging``, which is then renamed into place. Raises DiskFull
        (nothing left behind) when the disk is full."""
        with self._cond:
            seq = self._next_seq()
            while True:
                folder = self.root / f"c{seq:05d}"
                try:
                    folder.mkdir()       # the id, reserved: exclusive creation
                    break
                except FileExistsError:
                    seq += 1
            rec = Record(id=folder.name, seq=seq, folder=folder, request=dict(req),
                         submitted_unix=time.time())
            try:
                rec.save(staging)
                os.rename(staging, folder)   # replaces the empty reservation: whole, or not at all
            except OSError as err:
                try:
                    folder.rmdir()
                except OSError:
                    pass
                if is_disk_full(err):
                    raise DiskFull(err.errno, f"the data folder's disk is full ({err.strerror or err})") \
                        from None
                raise
            self._records[rec.id] = rec
            self._cond.notify_all()
        log.info("campaign %s submitted: %s, grid %s", rec.id, req.get("material") or req.get("sample"),
                 req["grid"])
        return rec

    # -- reading ---------------------------------------------------------------------------------
    def get(self, cid: str) -> Record:
        rec = self._records.get(cid)
        if rec is None:
            raise NotFound(f"campaign '{cid}': no such campaign")
        return rec

    def queued(self) -> int:
        """Campaigns waiting for the gantry (cheap: no journal is read)."""
        with self._cond:
            return sum(r.final is None and r is not self.current and r.intent == "run"
                       for r in self._records.values())

    def records(self) -> list[Record]:
        with self._cond:
            return sorted(self._records.values(), key=lambda r: r.seq)

    def journal(self, rec: Record) -> Journal:
        """A read-only journal connection (the caller closes it): never blocks the runner."""
        return Journal.open(rec.folder / JOURNAL_NAME, readonly=True)

    def _journal_state(self, rec: Record) -> str | None:
        try:
            j = self.journal(rec)
        except JournalError:
            return None
        try:
            e = j.last_event("state")
            return e["state"] if e else None
        finally:
            j.close()

    def state(self, rec: Record, journal: Journal | None = None) -> str:
        """The campaign's state (:func:`gonio.daemon.states.campaign_state`): from its engine's while
        the worker runs it (and has not begun to let it go), else from its journal and the operator's
        intent."""
        if rec.final is not None:
            return rec.final
        with self._cond:
            # A finishing campaign's state comes from its journal, like a waiting one's.
            if self.current is rec and not self.finishing:
                runner = self.runner
                return campaign_state(CampaignView(in_worker=True,
                                                   engine=runner.state if runner is not None else None))
        if not (rec.folder / JOURNAL_NAME).is_file():
            return campaign_state(CampaignView(journal=False, error=rec.error is not None))
        j = journal or self.journal(rec)
        try:
            e = j.last_event("state")
            latched = j.latched_fault()
        finally:
            if journal is None:
                j.close()
        state = campaign_state(CampaignView(last=e["state"] if e else None, latched=latched is not None,
                                            brdf=(rec.folder / BRDF_NAME).is_file(), intent=rec.intent,
                                            clear_fault=rec.clear_fault, error=rec.error is not None))
        if state in ("done", "aborted"):
            rec.final = state
        return state

    def status(self, rec: Record) -> dict:
        """State, progress, ETA and last fault of one campaign.

        The running campaign's journal is read at most every ``STATUS_TTL_S`` (its state and progress
        come from the runner in between), a finished one's once: a status request stays cheap while
        the runner works."""
        with self._cond:
            live = self.current is rec and not self.finishing
            started = self.run_started if live else None
        cached = rec.cache
        fresh = cached is not None and live and time.monotonic() - cached[0] < STATUS_TTL_S
        if cached is not None and (fresh or (rec.final is not None and cached[1]["state"] == rec.final)):
            st = dict(cached[1])
            if live:
                st["state"] = self.state(rec)
                if rec.live is not None and rec.live[0] > st["steps_done"]:
                    st.update(steps_done=rec.live[0], campaign_s=rec.live[1], last_update_unix=rec.live[2])
                self._progress(st, rec, started)
            return st
        st = self._read_status(rec)
        self._progress(st, rec, started)
        if live or rec.final is not None:
            rec.cache = (time.monotonic(), st)
        return st

    @staticmethod
    def _progress(st: dict, rec: Record, started) -> None:
        # A round appended since the cached read: the runner has measured at least this many steps.
        total = st["steps"] = max(st["steps"], st["steps_done"])
        done = st["steps_done"]
        st["progress"] = done / total if total else 1.0
        st["eta_gantry_s"] = rec.static["estimated_s"] * (total - done) / total if total else 0.0
        st["eta_wall_s"] = None
        if started is not None and done > started[1]:
            rate = (done - started[1]) / max(time.time() - started[0], 1e-9)
            st["eta_wall_s"] = (total - done) / rate

    def _read_status(self, rec: Record) -> dict:
        j = self.journal(rec)
        try:
            if not rec.static:
                meta = j.meta()
                rec.static = {"grid": meta["grid"], "material": meta.get("material"),
                              "sample": meta.get("sample"), "seed": meta["seed"], "poses": meta["poses"],
                              "gantry": meta["gantry"], "estimated_s": meta["estimated_s"],
                              "steps": j.step_count(), "channels": meta["channels"]}
            s = rec.static
            state = self.state(rec, j)
            done = j.done_count()
            campaign_s, last_wall = j.campaign_clock()
            latched = j.latched_fault()
            fault = j.last_event("fault")
            adaptive = None
            if s["grid"].startswith("adaptive"):
                # Each round appends steps and poses to the journal: its counts, not the first read's.
                meta = j.meta()
                adaptive = meta.get("adaptive")
                s.update(steps=j.step_count(), poses=meta["poses"])
        finally:
            j.close()
        return {"id": rec.id, "state": state, "seq": rec.seq, "submitted_unix": rec.submitted_unix,
                **{k: s[k] for k in ("grid", "material", "sample", "seed", "poses", "gantry", "channels")},
                "steps": s["steps"], "steps_done": done, "campaign_s": campaign_s,
                "last_update_unix": last_wall,
                "latched_fault": latched["reason"] if latched else None,
                "last_fault": fault["message"] if fault else None, "error": rec.error,
                "brdf": (rec.folder / BRDF_NAME).is_file(),
                "ended_short": adaptive["ended"]["reason"] if adaptive and adaptive.get("ended") else None}

    # -- operator requests -----------------------------------------------------------------------
    def pause(self, cid: str) -> None:
        rec = self.get(cid)
        with self._cond:
            if self.state(rec) in ("done", "aborted"):
                raise Conflict(f"campaign '{cid}' is {self.state(rec)}; there is nothing to pause")
            rec.intent = "hold"
            self._save(rec)
            if self.current is rec and self.runner is not None:
                self.runner.request_pause("pause requested through the API")
        log.info("campaign %s: pause requested", cid)

    def resume(self, cid: str, clear_fault: bool = False) -> None:
        rec = self.get(cid)
        with self._cond:
            state = self.state(rec)
            if state in ("done", "aborted"):
                raise Conflict(f"campaign '{cid}' is {state}; there is nothing to resume")
            if state == "faulted" and not clear_fault:
                j = self.journal(rec)
                try:
                    latched = j.latched_fault()
                finally:
                    j.close()
                reason = latched["reason"] if latched else "a fault"
                raise Conflict(f"campaign '{cid}' is faulted ({reason}); fix the cause, then resume with "
                               "clear_fault=true")
            if self.current is rec and state in ("running", "starting"):
                return
            withdrawn = (self.current is rec and state == "pausing" and self.runner is not None
                         and self.runner.request_resume("resume requested through the API"))
            rec.intent, rec.clear_fault, rec.halt_pending, rec.error = "run", clear_fault, False, None
            if self.current is not rec or state in ("halted", "faulted", "paused"):
                rec.resumes += 1    # not a pause withdrawn: the run it stopped is over (see _run)
            self._save(rec)
            self._cond.notify_all()
        log.info("campaign %s: resume requested%s%s", cid, " (clearing the fault)" if clear_fault else "",
                 " (the pause withdrawn)" if withdrawn else "")

    def abort(self, cid: str) -> None:
        rec = self.get(cid)
        with self._cond:
            state = self.state(rec)
            if state in ("done", "aborted"):
                raise Conflict(f"campaign '{cid}' is {state}; there is nothing to abort")
            if self.current is rec:
                rec.intent, rec.abort_pending = "hold", True
                self._save(rec)
                if self.runner is None:
                    # Starting (the first step boundary acts on it) or finishing (the worker records
                    # it as the campaign leaves): wait for either, so the reply tells the outcome.
                    self._cond.wait_for(lambda: self.current is not rec or self.runner is not None,
                                        timeout=ABORT_WAIT_S)
                # An engine not started yet aborts when it starts, before anything moves; a running one
                # at its next unit boundary; a stopped one at once (it still parks).
                if self.current is rec and self.runner is not None:
                    self.runner.request_abort("abort requested through the API")
                    if self.runner.state not in (State.RUNNING, State.PAUSING):
                        self._cond.wait_for(lambda: self.current is not rec, timeout=ABORT_WAIT_S)
            else:
                self._mark_aborted(rec, state)
                self._cond.notify_all()
        log.info("campaign %s: abort requested", cid)

    @staticmethod
    def _mark_aborted(rec: Record, state: str) -> None:
        """Record the abort of a campaign that is not running (its journal is closed)."""
        c = open_campaign(rec.folder)
        try:
            e = c.journal.last_event("state")
            if e is None or e["state"] != str(State.ABORTED):
                c.journal.log_event("state", state=str(State.ABORTED),
                                    message=f"aborted through the API while {state}",
                                    campaign_s=c.journal.campaign_clock()[0])
        finally:
            c.close()

    def halt(self, reason: str = "halt requested through the API") -> str | None:
        """Emergency stop of the running campaign (if any): its id, or None.

        Nothing here waits for the queue's lock (whoever holds it, for however long): the runner is told
        at once and its axes stop; the campaign is held (in memory at once, in ``daemon.json`` as soon as
        the lock is free). A runner that has just finished only fails to journal the halt."""
        runner, rec = self.runner, self.current
        if runner is not None:
            self._stop_runner(runner, reason)
        if rec is not None:
            rec.intent, rec.halt_pending = "hold", True
        if self._cond.acquire(timeout=0.2):
            try:
                self._record_halt(runner, rec, reason)
            finally:
                self._cond.release()
        else:
            threading.Thread(target=self._record_halt, args=(runner, rec, reason), name="gonio-halt-record",
                             daemon=True).start()
        if rec is not None:
            log.warning("campaign %s: halt", rec.id)
        return rec.id if rec is not None else None

    def _record_halt(self, runner: Runner | None, rec: Record | None, reason: str) -> None:
        """The rest of :meth:`halt`, under the queue's lock (at once, or from a thread of its own when the
        lock is held up): a runner that started meanwhile is stopped too, unless the campaign was resumed
        since (a resume takes the lock and withdraws the halt: a late record halted the resumed campaign
        again), and the campaign's record is saved."""
        with self._cond:
            stands = rec is None or rec.halt_pending
            if stands and self.runner is not None and self.runner is not runner:
                self._stop_runner(self.runner, reason)
            if rec is not None:
                self._save(rec)

    @staticmethod
    def _stop_runner(runner: Runner, reason: str) -> None:
        try:   # the axes stop first; only the journal's line of it can fail (a full disk, a closed journal)
            runner.request_halt(reason)
        except Exception as err:
            log.error("halt: the axes were told to stop; the journal could not record it (%s)", err)

    # -- the worker ------------------------------------------------------------------------------
    def _head(self) -> Record | None:
        """The campaign to run now, or None (empty queue, or a head that holds it)."""
        for rec in self.records():
            state = self.state(rec)
            if state in ("done", "aborted"):
                continue
            return rec if state == "queued" else None
        return None

    def _work(self) -> None:
        while not self._stopping.is_set():
            with self._cond:
                rec = self._head()
                if rec is None:
                    self._cond.wait(0.5)
                    continue
                self.current, self.runner, self.finishing = rec, None, False
            try:
                self._run(rec)
            except Exception as err:  # the worker stays up; the campaign waits for the operator
                log.exception("campaign %s: %s", rec.id, err)
                reason = f"{type(err).__name__}: {err}"
                if is_disk_full(err):   # the journal could not say so: daemon.json keeps it until it can
                    reason = f"the data folder's disk is full ({reason})"
                    rec.unclean = reason
                rec.intent, rec.error = "hold", reason
                self._save(rec)
            finally:
                with self._cond:
                    # An abort that came after the runner had stopped (paused, halted, faulted) and
                    # before the campaign left the worker: the runner never saw it, so record it here.
                    if rec.abort_pending:
                        try:
                            self._mark_aborted(rec, "stopped")
                        except Exception as err:
                            log.exception("campaign %s: recording the abort: %s", rec.id, err)
                        rec.abort_pending = False
                        self._save(rec)
                    self.current, self.runner, self.gantry, self.run_started = None, None, None, None
                    self.finishing = False
                    rec.cache = rec.live = None
                    self._cond.notify_all()

    def _run(self, rec: Record) -> None:
        from gonio.lifecycle import campaign_gantry, run_campaign

        if self.before_run is not None:
            self.before_run()
        # A resume asked once this run has stopped (the API says halted or faulted as soon as the engine
        # does, before the worker has let the campaign go) stands: the hold below is not put over it.
        resumes = rec.resumes
        c = open_campaign(rec.folder)
        try:
            meta = c.meta
            state = gantry_state(c)
            clock = (PacedClock(state[1] if state else 0.0, self.pace) if c.cfg.drivers() == {"sim"}
                     else self.clock)
            material = self.materials.load(meta["material"]) if meta.get("material") else None
            gantry = campaign_gantry(c, material, clock=clock)
            if c.journal.note_unclean_stop(rec.unclean) or rec.unclean:
                rec.unclean = None
                self._save(rec)
            with self._cond:
                self.gantry = gantry
                self.run_started = (time.time(), c.journal.done_count())

            def on_runner(runner: Runner) -> None:
                with self._cond:
                    self.runner = runner
                    self._cond.notify_all()
                # Requests that came while the worker was starting reach the engine before it runs.
                reason = "through the API"
                if rec.halt_pending:
                    runner.request_halt(f"halt requested {reason}")
                if rec.abort_pending:
                    runner.request_abort(f"abort requested {reason}")
                if rec.intent == "hold" or self._stopping.is_set():
                    runner.request_pause(f"pause requested {reason}" if rec.intent == "hold"
                                         else "daemon stopping")

            def on_step(runner: Runner, step: int) -> None:
                rec.live = (step + 1, runner.campaign_s(), time.time())

            log.info("campaign %s: %s at step %d", rec.id,
                     "resuming" if c.journal.done_count() else "starting", c.journal.next_step())
            result, runner = run_campaign(c, gantry, on_step=on_step, on_runner=on_runner,
                                          clear_fault=rec.clear_fault)
        finally:
            with self._cond:  # requests reach the runner under this lock: none after its journal closes
                self.runner, self.gantry, self.finishing = None, None, True
            c.close()
        with self._cond:
            if rec.resumes == resumes:
                rec.clear_fault = False
            if result == State.ABORTED:
                rec.abort_pending = False
            if result in (State.HALTED, State.FAULTED) and rec.resumes == resumes:
                rec.intent = "hold"
                self._save(rec)
        log.info("campaign %s: %s%s", rec.id, result, f" ({runner.fault})" if runner.fault else "")
