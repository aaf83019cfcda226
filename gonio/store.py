"""The campaign journal: one SQLite file per campaign, append-only, one transaction per step.

Crash safety (DESIGN.md, rule 5): the file is in WAL mode and every measurement is committed in its own
transaction before the runner moves on, so a crash at any instant loses at most the step in flight;
``Journal.open`` on the same file resumes from what was committed. A journal is created whole or not at
all: it is written under a temporary name in the same folder and renamed into place, so a kill during
creation (which for a fine grid writes for a while) leaves either no journal or a complete one.

Time. Every measurement and event carries ``campaign_s``, the campaign clock: seconds since the campaign
started, continuing across resumes (the runner starts each run where the journal left off, plus the
downtime when the gantry runs on the wall clock). The drift correction interpolates on it, so it must
never go backwards. ``clock_s`` is the gantry's own clock at the reading (virtual in simulation).

The schema version lives in ``PRAGMA user_version`` and older journals are upgraded in place by the
numbered functions in ``_UPGRADES`` (N -> N + 1) when opened for writing.

Angles are stored in degrees (a user boundary: anyone may open the file with ``sqlite3``), signals as
little-endian float64 blobs with their shape beside them (JSON: ``[C]`` for a point detector, ``[L]``
for a spectrometer's bands, any N-D shape a detector reports). The meta key ``detector`` describes what a
reading is (:func:`detector_descriptor`): kind, channel names, wavelengths (nm, or null), shape, dtype and
units; a journal without it (schema < 3) reads as an RGB photodiode with its ``channels``.

``Reading.extra`` is kept per measurement as JSON (numpy values as lists). A camera's frame (a
:class:`gonio.frames.Frame` under ``extra["frame"]``) is written as an EXR file in ``frames/`` next to the
journal, whole (written aside and renamed) and before the transaction that commits the measurement row
naming it, with the SHA-256 of its pixels in the row: a crash between the two leaves a file no row names,
which the replayed step (same key, same frame) overwrites. :meth:`Journal.frame` reads it back and checks
the hash: a missing or altered file is a :class:`gonio.frames.FrameError` naming the file and the step.
Schema 2 journals are upgraded to 3 when opened for writing and read as they are when opened read-only.

Reading. A writer holds an exclusive ``flock`` on ``campaign.lock`` beside the journal
(:class:`gonio.campaign.CampaignLock`) for as long as it has the journal open. A reader
(``Journal.open(readonly=True)``) of a journal nobody writes (that lock free, no commits waiting in the
WAL) opens it ``immutable``: SQLite then creates no ``-shm``/``-wal`` beside it, which a read-only
connection could not remove, and needs no write access to the folder (a finished campaign archived on a
read-only share, a DVD, a folder the analysis account cannot write). Otherwise it is a live WAL reader,
which sees every step committed so far. Before it trusts a query's answer, an immutable reader checks
that nobody has written since it opened (lock free, WAL empty, file unchanged); when a writer has come, it
becomes a live reader and asks again, so a reader held open across a resume (the daemon's event stream)
misses nothing.
"""

from __future__ import annotations

import errno
import fcntl
import json
import math
import os
import sqlite3
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from gonio.protocols import detector_descriptor

__all__ = ["Journal", "JournalError", "Measurement", "SCHEMA_VERSION", "JOURNAL_NAME", "FRAMES_DIR",
           "LOCK_NAME", "detector_descriptor", "is_disk_full", "disk_full_error", "lock_holder"]

SCHEMA_VERSION = 3
JOURNAL_NAME = "campaign.sqlite"
#: The lock file beside the journal whose exclusive ``flock`` its writer holds
#: (:class:`gonio.campaign.CampaignLock`).
LOCK_NAME = "campaign.lock"
#: Folder (beside the journal) of the frames that measurements name.
FRAMES_DIR = "frames"

_SCHEMA = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE steps (
    step INTEGER PRIMARY KEY,       -- position in the ordered plan
    kind INTEGER NOT NULL,          -- 0 pose, 1 dark, 2 reference (gonio.plan STEP_*)
    pose INTEGER NOT NULL,          -- index of the pose for kind 0, else -1
    theta_i_deg REAL, phi_i_deg REAL, theta_o_deg REAL, phi_o_deg REAL,   -- planned directions
    axes_deg TEXT NOT NULL          -- JSON list: commanded axis targets (the previous ones for a dark)
);
CREATE TABLE measurements (
    step INTEGER PRIMARY KEY REFERENCES steps(step),
    kind INTEGER NOT NULL,
    pose INTEGER NOT NULL,
    commanded_deg TEXT NOT NULL,    -- JSON list, axis order of meta 'axis_names'
    actual_deg TEXT NOT NULL,       -- JSON list, read back from the axes after settling
    theta_i_deg REAL NOT NULL, phi_i_deg REAL NOT NULL,   -- actual directions (forward kinematics)
    theta_o_deg REAL NOT NULL, phi_o_deg REAL NOT NULL,
    clock_s REAL NOT NULL,          -- gantry clock (virtual in simulation) at the end of the reading
    wall_s REAL NOT NULL,           -- Unix time of the commit
    exposure_s REAL NOT NULL,
    frames INTEGER NOT NULL,
    signal BLOB NOT NULL,           -- float64 per channel, dark not subtracted
    stderr BLOB NOT NULL,
    attempts INTEGER NOT NULL,      -- 1 + retries it took
    campaign_s REAL NOT NULL,       -- campaign clock at the end of the reading (continues across resumes)
    shape TEXT,                     -- JSON list: the shape of signal and stderr (NULL: flat, schema < 3)
    extra TEXT,                     -- JSON: the reading's extra (NULL: none kept)
    frame_file TEXT,                -- the frame's EXR, relative to the journal's folder (NULL: none)
    frame_sha256 TEXT               -- SHA-256 of its pixels (gonio.frames.content_hash)
);
CREATE TABLE events (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    campaign_s REAL, wall_s REAL NOT NULL,
    kind TEXT NOT NULL,             -- state, fault, retry, pause, halt, park, signal, ...
    state TEXT, step INTEGER, message TEXT,
    axes_deg TEXT                   -- JSON list: where the axes stood, when the event says (park, halt)
);
"""

_MEASUREMENT_COLUMNS = ("step", "kind", "pose", "commanded_deg", "actual_deg", "theta_i_deg", "phi_i_deg",
                        "theta_o_deg", "phi_o_deg", "clock_s", "campaign_s", "wall_s", "exposure_s",
                        "frames", "signal", "stderr", "attempts")
#: Columns of schema 3 (read as NULL from a schema 2 journal opened read-only).
_V3_COLUMNS = ("shape", "extra", "frame_file", "frame_sha256")
_EVENT_COLUMNS = ("id", "campaign_s", "wall_s", "kind", "state", "step", "message", "axes_deg")


def _upgrade_1_to_2(conn: sqlite3.Connection) -> None:
    # Version 1 named the gantry clock virtual_s and had no campaign clock. Its clock restarted at 0 on
    # every resume, so the copied campaign_s can go backwards: calibration then refuses it, as it should.
    conn.execute("ALTER TABLE measurements RENAME COLUMN virtual_s TO clock_s")
    conn.execute("ALTER TABLE measurements ADD COLUMN campaign_s REAL NOT NULL DEFAULT 0")
    conn.execute("UPDATE measurements SET campaign_s = clock_s")
    conn.execute("ALTER TABLE events RENAME COLUMN virtual_s TO campaign_s")
    conn.execute("ALTER TABLE events ADD COLUMN axes_deg TEXT")


def _upgrade_2_to_3(conn: sqlite3.Connection) -> None:
    # Readings with a shape, their extra and the frame they name; version 2 rows stay flat (NULL shape).
    for column in _V3_COLUMNS:
        conn.execute(f"ALTER TABLE measurements ADD COLUMN {column} TEXT")


_UPGRADES: dict[int, Callable[[sqlite3.Connection], None]] = {1: _upgrade_1_to_2, 2: _upgrade_2_to_3}


class JournalError(RuntimeError):
    pass


def is_disk_full(err: BaseException | None) -> bool:
    """True when ``err`` (or what caused it) is a full disk or a spent quota, from the OS (ENOSPC,
    EDQUOT) or SQLite (SQLITE_FULL: "database or disk is full")."""
    return disk_full_error(err) is not None


def disk_full_error(err: BaseException | None) -> BaseException | None:
    """The error in ``err``'s chain (itself, its cause or context, ...) that says the disk is full, or
    None (see :func:`is_disk_full`)."""
    seen = set()
    while err is not None and id(err) not in seen:
        seen.add(id(err))
        if isinstance(err, OSError) and err.errno in (errno.ENOSPC, errno.EDQUOT):
            return err
        if isinstance(err, sqlite3.Error) and getattr(err, "sqlite_errorcode", None) == sqlite3.SQLITE_FULL:
            return err
        err = err.__cause__ or err.__context__
    return None


@dataclass(frozen=True)
class Measurement:
    step: int
    kind: int
    pose: int
    commanded_deg: np.ndarray
    actual_deg: np.ndarray
    angles_deg: np.ndarray  # (θi, φi, θo, φo) actual
    clock_s: float          # gantry clock at the end of the reading
    campaign_s: float       # campaign clock at the end of the reading (continues across resumes)
    exposure_s: float
    frames: int
    signal: np.ndarray      # any shape (the detector's); stderr alike
    stderr: np.ndarray
    attempts: int = 1
    #: The reading's extra (JSON-able once numpy values become lists). On commit, a Frame under "frame"
    #: is written to ``frames/`` and replaced by the file's name; read back, it holds that name.
    extra: dict = field(default_factory=dict)
    frame_file: str | None = None     # read back: the frame's EXR, relative to the journal's folder
    frame_sha256: str | None = None


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    # Anything else a driver put there (a Path, an enum, ...) is kept as its text, never lost silently
    # and never a reason to lose the reading.
    return str(value)


#: ``json.dumps(extra, default=_json_default, sort_keys=True)``, its encoder made once (one per reading
#: would cost more than a small extra's encoding).
_EXTRA_JSON = json.JSONEncoder(default=_json_default, sort_keys=True)


def _float_list_json(values) -> str:
    """``json.dumps`` of ``values`` as a list of floats (axis positions): finite floats joined by their
    repr, as json writes them, without its encoder's per-call cost; NaN and inf through json itself."""
    array = np.asarray(values, float)
    floats = array.tolist()
    if array.ndim == 1 and all(-math.inf < x < math.inf for x in floats):
        return "[" + ", ".join(map(float.__repr__, floats)) + "]"
    return json.dumps(floats)


@lru_cache(maxsize=64)
def _shape_json(shape: tuple) -> str:
    """``json.dumps`` of a reading's shape (a detector reports one shape: written once per journal)."""
    return json.dumps(list(shape))


def _blob(x) -> bytes:
    return np.ascontiguousarray(x, dtype="<f8").tobytes()


def _unblob(b: bytes, shape=None) -> np.ndarray:
    x = np.frombuffer(b, dtype="<f8").copy()
    return x if shape is None else x.reshape(shape)


def _frame_hash(frame) -> str:
    from gonio.frames import content_hash

    return content_hash(frame.pixels)


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # a platform without directory handles: the rename is still atomic
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _step_rows(steps: dict, first: int):
    """Rows of the steps table for ``steps`` (equal-length arrays, :meth:`Journal.create`), numbered from
    ``first``."""
    return zip(
        range(first, first + len(steps["kind"])), (int(k) for k in steps["kind"]),
        (int(p) for p in steps["pose"]),
        *(np.asarray(steps[c], float).tolist()
          for c in ("theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg")),
        (json.dumps(a) for a in np.asarray(steps["axes_deg"], float).tolist()),
        strict=True,
    )


def lock_holder(path: str | Path) -> int | None:
    """The pid of the process holding the ``flock`` on the lock file ``path`` (-1 when it wrote none), or
    None: no such file, nobody holds it, or a filesystem without locks (where no writer can take one)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except FileNotFoundError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        text = os.read(fd, 64).decode(errors="replace").strip()
        return int(text) if text.isdigit() else -1
    except OSError:   # ENOLCK (an NFS export without lockd): a writer's flock fails there too
        return None
    else:
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


def _still(path: Path) -> bool:
    """Whether nobody writes the journal at ``path`` now, so that it may be read ``immutable``: no commits
    wait in its WAL (a writer killed before its checkpoint leaves them there, where only a WAL reader sees
    them), and its lock file is free, or absent from a folder this process cannot write (a writer creates
    it); a journal with no lock file in a writable folder may have a writer that takes none."""
    try:
        if os.stat(path.with_name(path.name + "-wal")).st_size:
            return False
    except FileNotFoundError:
        pass
    lock = path.with_name(LOCK_NAME)
    if lock.exists():
        return lock_holder(lock) is None
    return not os.access(path.parent, os.W_OK)


def _signature(path: Path) -> tuple:
    """What changes when the journal's file is written: an immutable reader's answers hold while it
    does not."""
    st = os.stat(path)
    return st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns


def _reader(path: Path, immutable: bool) -> sqlite3.Connection:
    """A read-only connection (the path as a URI: a folder named with ``?`` or ``#`` is a folder)."""
    uri = path.absolute().as_uri() + ("?mode=ro&immutable=1" if immutable else "?mode=ro")
    return sqlite3.connect(uri, uri=True, isolation_level=None, check_same_thread=False)


def _is_stub(path: Path) -> bool:
    """True for a journal that an old gonio left empty when killed during creation (no schema)."""
    try:
        conn = _reader(path, _still(path))
        try:
            version = conn.execute("PRAGMA user_version").fetchone()[0]
            tables = conn.execute("SELECT COUNT(*) FROM sqlite_master").fetchone()[0]
        finally:
            conn.close()
    except sqlite3.DatabaseError:
        return False
    return version == 0 and tables == 0


def _remove_db(path: Path) -> None:
    for p in (path, path.with_name(path.name + "-wal"), path.with_name(path.name + "-shm"),
              path.with_name(path.name + "-journal")):
        p.unlink(missing_ok=True)


class Journal:
    """An open campaign journal. Create with :meth:`create`, reopen (resume) with :meth:`open`.

    ``write_hook`` is called with a running count before every write statement; tests raise from it
    to simulate a crash between any two writes.
    """

    def __init__(self, conn: sqlite3.Connection, path: Path,
                 write_hook: Callable[[int], None] | None = None, readonly: bool = False,
                 version: int = SCHEMA_VERSION):
        self._conn = conn
        self.path = path
        self.version = version
        self.readonly = readonly
        # An immutable reader's (:func:`_still`): the journal file's signature when it was opened; else None.
        self._still_as: tuple | None = None
        self._write_hook = write_hook
        self._writes = 0
        # The runner writes from its thread; pause/abort/halt requests and readers may come from others
        # (signal handlers, the daemon). One lock serializes every use of the connection.
        self._lock = threading.RLock()

    # -- opening ---------------------------------------------------------------------------------
    @staticmethod
    def _connect(path: Path) -> sqlite3.Connection:
        # Transactions are explicit; the connection is shared between threads under Journal._lock.
        conn = sqlite3.connect(str(path), isolation_level=None, check_same_thread=False)
        conn.execute("PRAGMA journal_mode=WAL")
        # NORMAL in WAL mode: a committed transaction survives a crash of the process (what a
        # campaign must survive); only a power cut may lose the last few. See README.
        conn.execute("PRAGMA synchronous=NORMAL")
        conn.execute("PRAGMA foreign_keys=ON")
        return conn

    @classmethod
    def partial_paths(cls, path: str | Path) -> list[Path]:
        """Temporary files a creation killed before its rename may have left beside ``path``."""
        path = Path(path)
        return sorted(path.parent.glob(f".{path.name}.*.partial*"))

    @classmethod
    def create(cls, path: str | Path, meta: dict, steps: dict, *,
               write_hook: Callable[[int], None] | None = None) -> Journal:
        """A new journal holding the campaign ``meta`` (JSON-able values) and the ordered plan.

        ``steps`` holds equal-length arrays: kind, pose, theta_i_deg, phi_i_deg, theta_o_deg, phi_o_deg
        and axes_deg (S, n_axes). The journal is built under a temporary name in the same folder and
        renamed into place: a crash at any instant leaves no journal or a complete one. Temporary files
        of an earlier creation that was killed are removed (the caller holds the campaign's lock), and
        so is an empty journal that gonio before schema 2 left behind when killed during creation.
        """
        path = Path(path)
        if path.exists():
            if not _is_stub(path):
                raise JournalError(f"{path}: a campaign journal already exists (resume it instead)")
            _remove_db(path)
        for stale in cls.partial_paths(path):
            stale.unlink(missing_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.partial")
        # Built as one file to rename, nothing beside it. Nothing of the temporary file has to survive a
        # crash (a later creation removes it): SQLite syncs nothing while building and keeps its rollback
        # journal in memory; the file is synced once, complete, before the rename. It is switched to WAL
        # (what every open sets) before it is closed, so that the first open converts nothing.
        conn = sqlite3.connect(str(tmp), isolation_level=None)
        conn.execute("PRAGMA synchronous=OFF")
        conn.execute("PRAGMA journal_mode=MEMORY")
        j = cls(conn, tmp, write_hook)
        try:
            with j._transaction():
                for stmt in _SCHEMA.split(";"):
                    if stmt.strip():
                        j._write(stmt)
                j._write(f"PRAGMA user_version={SCHEMA_VERSION}")
                for k, v in meta.items():
                    j._write("INSERT INTO meta VALUES (?, ?)", (k, json.dumps(v)))
                j._write_many("INSERT INTO steps VALUES (?, ?, ?, ?, ?, ?, ?, ?)", _step_rows(steps, 0))
            conn.execute("PRAGMA journal_mode=WAL")
        finally:
            conn.close()
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
        _fsync_dir(path.parent)
        return cls.open(path, write_hook=write_hook)

    @classmethod
    def open(cls, path: str | Path, *, write_hook: Callable[[int], None] | None = None,
             readonly: bool = False) -> Journal:
        """Open a journal to resume it, or ``readonly`` to look at it while another process runs it."""
        path = Path(path)
        if not path.is_file():
            raise JournalError(f"{path}: no campaign journal here")
        still_as = None
        if readonly:
            still = _still(path)
            still_as = _signature(path) if still else None
            conn = _reader(path, still)
        else:
            conn = cls._connect(path)
        try:
            version = conn.execute("PRAGMA user_version").fetchone()[0]
        except sqlite3.DatabaseError as err:
            conn.close()
            if (readonly and still_as is None and isinstance(err, sqlite3.OperationalError)
                    and not os.access(path.parent, os.W_OK)):
                raise JournalError(f"{path}: cannot be read from a folder this process cannot write ({err}): "
                                   "its WAL holds commits, which SQLite reads only with a -shm file beside "
                                   "it; copy the folder somewhere writable") from None
            raise JournalError(f"{path}: not a campaign journal ({err})") from None
        if version == 0 and _is_stub(path):
            conn.close()
            raise JournalError(f"{path}: an empty journal left by a creation that was interrupted; "
                               "run the same command again to create the campaign afresh")
        if version < SCHEMA_VERSION and version in _UPGRADES and not readonly:
            with conn:
                conn.execute("BEGIN IMMEDIATE")
                for v in range(version, SCHEMA_VERSION):
                    _UPGRADES[v](conn)
                conn.execute(f"PRAGMA user_version={SCHEMA_VERSION}")
            version = SCHEMA_VERSION
        if version != SCHEMA_VERSION and not (readonly and version == 2):
            conn.close()
            raise JournalError(f"{path}: journal schema version {version}; this gonio reads "
                               f"version {SCHEMA_VERSION}" + (" (open it for writing to upgrade it)"
                                                              if version in _UPGRADES else ""))
        j = cls(conn, path, write_hook, readonly=readonly, version=version)
        j._still_as = still_as
        return j

    def close(self) -> None:
        with self._lock:
            if not self.readonly:
                self._checkpoint()
            self._conn.close()

    def _checkpoint(self) -> None:
        """Copy every commit into the journal's file and empty the WAL, so that the file alone is the whole
        journal even when a reader held it open at this close (SQLite checkpoints by itself only at the
        last connection's): later readers open it immutable, and a copy of the file alone misses nothing.
        Best effort, waiting on no reader: what stays in the WAL is read from there."""
        try:
            self._conn.execute("PRAGMA busy_timeout=0")
            self._conn.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchall()
        except sqlite3.Error:
            pass

    # -- writing ---------------------------------------------------------------------------------
    def _write(self, sql: str, params=()) -> None:
        self._writes += 1
        if self._write_hook is not None:
            self._write_hook(self._writes)
        self._conn.execute(sql, params)

    def _write_many(self, sql: str, rows) -> None:
        self._writes += 1
        if self._write_hook is not None:
            self._write_hook(self._writes)
        self._conn.executemany(sql, rows)

    class _Txn:
        def __init__(self, conn, lock):
            self.conn, self.lock = conn, lock

        def __enter__(self):
            self.lock.acquire()
            try:
                self.conn.execute("BEGIN IMMEDIATE")
            except BaseException:
                self.lock.release()
                raise

        def __exit__(self, exc_type, exc, tb):
            try:
                self.conn.execute("COMMIT" if exc_type is None else "ROLLBACK")
            finally:
                self.lock.release()
            return False

    def _transaction(self):
        if self.readonly:
            raise JournalError(f"{self.path}: opened read-only")
        return Journal._Txn(self._conn, self._lock)

    def _query(self, sql: str, params=()) -> list:
        with self._lock:
            if self._still_as is None:
                return self._conn.execute(sql, params).fetchall()
            try:
                rows = self._conn.execute(sql, params).fetchall()
            except sqlite3.DatabaseError:
                if self._stays_still():
                    raise
                rows = None
            if rows is not None and self._stays_still():
                return rows
            # A writer has come since this immutable reader opened the journal (and may have written the
            # file under it): read it live from now on, and ask again.
            self._conn.close()
            self._conn, self._still_as = _reader(self.path, False), None
            return self._conn.execute(sql, params).fetchall()

    def _stays_still(self) -> bool:
        return _still(self.path) and _signature(self.path) == self._still_as

    def commit_measurement(self, m: Measurement) -> None:
        """Commit one step's measurement in its own transaction; its frame (if any) first, as a file."""
        values = self._measurement_row(m)
        columns = _MEASUREMENT_COLUMNS + _V3_COLUMNS
        with self._transaction():
            self._write(f"INSERT INTO measurements ({', '.join(columns)}) "
                        f"VALUES ({', '.join('?' * len(columns))})", values)

    def _measurement_row(self, m: Measurement) -> tuple:
        signal = np.asarray(m.signal, dtype=np.float64)
        stderr = np.asarray(m.stderr, dtype=np.float64)
        if stderr.shape != signal.shape:
            raise JournalError(f"step {m.step}: stderr has shape {stderr.shape}, signal {signal.shape}")
        extra = dict(m.extra or {})
        frame_file, digest = m.frame_file, m.frame_sha256
        frame = extra.pop("frame", None)
        if frame is not None and not isinstance(frame, str):
            frame_file, digest = self._write_frame(m.step, m.attempts, frame)
        extra_json = _EXTRA_JSON.encode(extra) if extra else None
        values = (m.step, m.kind, m.pose, _float_list_json(m.commanded_deg), _float_list_json(m.actual_deg),
                  *np.asarray(m.angles_deg, float).tolist(),
                  float(m.clock_s), float(m.campaign_s), time.time(), float(m.exposure_s), int(m.frames),
                  _blob(signal), _blob(stderr), int(m.attempts),
                  _shape_json(signal.shape), extra_json, frame_file, digest)
        return values

    def commit_measurements(self, ms: list[Measurement]) -> None:
        """Commit several steps' measurements in one transaction, all or none (a fly campaign's sweep:
        a crash loses at most that sweep); frames (if any) first, as files."""
        rows = [self._measurement_row(m) for m in ms]
        columns = _MEASUREMENT_COLUMNS + _V3_COLUMNS
        with self._transaction():
            self._write_many(f"INSERT INTO measurements ({', '.join(columns)}) "
                             f"VALUES ({', '.join('?' * len(columns))})", rows)

    def _write_frame(self, step: int, attempt: int, frame) -> tuple[str, str]:
        """Write ``frame`` (a gonio.frames.Frame) to frames/ whole, and make its name durable."""
        from gonio.frames import write_exr

        if self.readonly:
            raise JournalError(f"{self.path}: opened read-only")
        folder = self.path.parent / FRAMES_DIR
        folder.mkdir(exist_ok=True)
        name = f"{FRAMES_DIR}/step{step:06d}-a{attempt}.exr"
        digest = write_exr(self.path.parent / name, frame)
        fd = os.open(self.path.parent / name, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        _fsync_dir(folder)
        return name, digest

    def frame(self, step: int):
        """The frame the measurement of ``step`` names (a gonio.frames.Frame), its hash checked.

        Raises
        ------
        gonio.frames.FrameError
            The step has no frame, or its file is missing, unreadable or not the one committed.
        """
        from gonio.frames import FrameError, read_exr

        rows = self._query(f"SELECT {self._v3('frame_file')}, {self._v3('frame_sha256')} FROM measurements "
                           "WHERE step = ?", (int(step),))
        if not rows or rows[0][0] is None:
            raise FrameError(f"{self.path}: step {step} has no frame")
        path = self.path.parent / rows[0][0]
        if not path.is_file():
            raise FrameError(f"{path}: the frame of step {step} is missing")
        frame = read_exr(path)  # checks the pixels against the hash in the file's own header
        if _frame_hash(frame) != rows[0][1]:
            raise FrameError(f"{path}: the frame of step {step} is not the one committed (hash differs)")
        return frame

    def log_event(self, kind: str, *, state: str | None = None, step: int | None = None,
                  message: str = "", campaign_s: float | None = None, axes_deg=None) -> None:
        axes = None if axes_deg is None else json.dumps(np.asarray(axes_deg, float).tolist())
        with self._transaction():
            self._write("INSERT INTO events (campaign_s, wall_s, kind, state, step, message, axes_deg) "
                        "VALUES (?, ?, ?, ?, ?, ?, ?)",
                        (campaign_s, time.time(), kind, state, step, message, axes))

    def note_unclean_stop(self, reason: str | None = None) -> bool:
        """Journal an ``unclean-stop`` event when the last run ended without a stop of its own: its last
        state is still ``running`` (the process was killed, crashed or lost power, or met a fault it
        could not journal, such as a full disk) and no unclean-stop was journaled since. ``reason``: why,
        when the caller knows. True when one was written; a campaign resumed after a crash says so."""
        with self._lock:
            last = self._query("SELECT id, state FROM events WHERE kind = 'state' ORDER BY id DESC LIMIT 1")
            if not last or last[0][1] != "running":
                return False
            if self._query("SELECT 1 FROM events WHERE kind = 'unclean-stop' AND id > ?", (last[0][0],)):
                return False
            why = reason or ("the last run ended without a stop of its own (the process was killed or "
                             "crashed, or the power failed)")
            self.log_event("unclean-stop", step=self.next_step(), campaign_s=self.campaign_clock()[0],
                           message=f"{why}; {self.done_count()} steps were committed")
            return True

    def append_steps(self, steps: dict, meta: dict, *, event: str = "",
                     campaign_s: float | None = None) -> int:
        """Append ``steps`` (as :meth:`create` takes them; pose indices as given) to the plan, set the
        ``meta`` keys and log an ``append`` event (``event``: its message), all in one transaction: a
        crash leaves the journal as it was or holds all of it (an adaptive campaign's round). Returns
        the first new step's number."""
        with self._transaction():
            first = self._query("SELECT COUNT(*) FROM steps")[0][0]
            self._write_many("INSERT INTO steps VALUES (?, ?, ?, ?, ?, ?, ?, ?)", _step_rows(steps, first))
            self._write_many("INSERT OR REPLACE INTO meta VALUES (?, ?)",
                             [(k, json.dumps(v)) for k, v in meta.items()])
            self._write("INSERT INTO events (campaign_s, wall_s, kind, state, step, message, axes_deg) "
                        "VALUES (?, ?, ?, ?, ?, ?, ?)",
                        (campaign_s, time.time(), "append", None, first, event, None))
        return int(first)

    def set_meta(self, key: str, value) -> None:
        with self._transaction():
            self._write("INSERT OR REPLACE INTO meta VALUES (?, ?)", (key, json.dumps(value)))

    def delete_meta(self, key: str) -> None:
        with self._transaction():
            self._write("DELETE FROM meta WHERE key = ?", (key,))

    def check_frames(self) -> list[tuple[int, str]]:
        """(step, message) for every frame the journal names that is missing, unreadable or altered."""
        from gonio.frames import FrameError

        rows = self._query(f"SELECT step FROM measurements WHERE {self._v3('frame_file')} IS NOT NULL "
                           "ORDER BY step") if self.version >= 3 else []
        problems = []
        for (step,) in rows:
            try:
                self.frame(step)
            except FrameError as err:
                problems.append((int(step), str(err)))
        return problems

    # -- latched faults --------------------------------------------------------------------------
    def latch_fault(self, reason: str, devices: list[str]) -> None:
        """Record a fault that only an operator may clear (it survives restarts of gonio)."""
        self.set_meta("latched_fault", {"reason": reason, "devices": list(devices)})

    def latched_fault(self) -> dict | None:
        """``{"reason": str, "devices": [names]}`` of the latched fault, or None."""
        rows = self._query("SELECT value FROM meta WHERE key = 'latched_fault'")
        return json.loads(rows[0][0]) if rows else None

    # -- reading ---------------------------------------------------------------------------------
    def meta(self) -> dict:
        return {k: json.loads(v) for k, v in self._query("SELECT key, value FROM meta")}

    def detector(self) -> dict:
        """The detector descriptor (:func:`detector_descriptor`); for a journal without one (schema < 3),
        an RGB photodiode with the journal's ``channels``."""
        meta = self.meta()
        if "detector" in meta:
            return meta["detector"]
        return detector_descriptor("photodiode", meta.get("channels", ["R", "G", "B"]))

    def _v3(self, column: str) -> str:
        return column if self.version >= 3 else f"NULL AS {column}"

    def step_count(self) -> int:
        return self._query("SELECT COUNT(*) FROM steps")[0][0]

    def steps(self) -> dict[str, np.ndarray]:
        rows = self._query("SELECT kind, pose, theta_i_deg, phi_i_deg, theta_o_deg, phi_o_deg, "
                           "axes_deg FROM steps ORDER BY step")
        cols = list(zip(*rows, strict=True)) if rows else [()] * 7
        return {
            "kind": np.array(cols[0], dtype=np.int8), "pose": np.array(cols[1], dtype=np.int64),
            "theta_i_deg": np.array(cols[2], float), "phi_i_deg": np.array(cols[3], float),
            "theta_o_deg": np.array(cols[4], float), "phi_o_deg": np.array(cols[5], float),
            "axes_deg": np.array([json.loads(a) for a in cols[6]], float),
        }

    def done_steps(self) -> np.ndarray:
        """Sorted step numbers that have a committed measurement."""
        return np.array([r[0] for r in self._query("SELECT step FROM measurements ORDER BY step")],
                        dtype=np.int64)

    def done_count(self) -> int:
        return self._query("SELECT COUNT(*) FROM measurements")[0][0]

    def next_step(self) -> int:
        """The first step with no measurement (== step_count() when the campaign is complete)."""
        done = self.done_steps()
        missing = np.setdiff1d(np.arange(self.step_count()), done)
        return int(missing[0]) if missing.size else self.step_count()

    def measurements(self, *, extra: bool = True) -> list[Measurement]:
        """Every committed measurement in step order; ``extra=False`` leaves each reading's extra out
        (an empty dict: a caller that reads only the readings, as calibration does, spares parsing it)."""
        keep_extra = extra
        out = []
        names = [c for c in _MEASUREMENT_COLUMNS if c != "wall_s"]
        select = names + [self._v3(c) for c in _V3_COLUMNS]
        shapes: dict[str, tuple] = {}   # the few shape texts a journal holds, each parsed once
        loads = json.loads
        for (step, kind, pose, commanded, actual, ti, pi_, to, po, clock_s, campaign_s, exposure_s, frames,
             signal, stderr, attempts, shape, extra, frame_file, frame_sha256) in self._query(
                f"SELECT {', '.join(select)} FROM measurements ORDER BY step"):
            if shape is not None:
                if shape not in shapes:
                    shapes[shape] = tuple(loads(shape))
                shape = shapes[shape]
            out.append(Measurement(
                step=step, kind=kind, pose=pose, commanded_deg=np.array(loads(commanded)),
                actual_deg=np.array(loads(actual)), angles_deg=np.array([ti, pi_, to, po], float),
                clock_s=clock_s, campaign_s=campaign_s, exposure_s=exposure_s, frames=frames,
                signal=_unblob(signal, shape), stderr=_unblob(stderr, shape), attempts=attempts,
                extra=loads(extra) if keep_extra and extra is not None else {}, frame_file=frame_file,
                frame_sha256=frame_sha256))
        return out

    def measurement_rows(self, start_step: int = 0, limit: int = 1000) -> list[dict]:
        """Committed measurements from ``start_step`` on, at most ``limit``, in step order, as plain dicts
        (angles in degrees, signals as lists, ``wall_s`` the Unix time of the commit): what an event
        stream sends."""
        rows = self._query(f"SELECT {', '.join(_MEASUREMENT_COLUMNS)} FROM measurements WHERE step >= ? "
                           "ORDER BY step LIMIT ?", (int(start_step), int(limit)))
        out = []
        for r in rows:
            d = dict(zip(_MEASUREMENT_COLUMNS, r, strict=True))
            for k in ("commanded_deg", "actual_deg"):
                d[k] = json.loads(d[k])
            d["signal"] = _unblob(d["signal"]).tolist()
            d["stderr"] = _unblob(d["stderr"]).tolist()
            out.append(d)
        return out

    def events(self, after_id: int = 0, limit: int = -1) -> list[dict]:
        """Events after ``after_id`` in order, at most ``limit`` (-1: all)."""
        rows = self._query(f"SELECT {', '.join(_EVENT_COLUMNS)} FROM events WHERE id > ? ORDER BY id LIMIT ?",
                           (after_id, int(limit)))
        out = [dict(zip(_EVENT_COLUMNS, r, strict=True)) for r in rows]
        for e in out:
            if e["axes_deg"] is not None:
                e["axes_deg"] = json.loads(e["axes_deg"])
        return out

    def last_event(self, kind: str) -> dict | None:
        rows = self._query(f"SELECT {', '.join(_EVENT_COLUMNS)} FROM events WHERE kind = ? "
                           "ORDER BY id DESC LIMIT 1", (kind,))
        return self._event_dict(rows[0]) if rows else None

    @staticmethod
    def _event_dict(row) -> dict:
        e = dict(zip(_EVENT_COLUMNS, row, strict=True))
        if e["axes_deg"] is not None:
            e["axes_deg"] = json.loads(e["axes_deg"])
        return e

    def campaign_clock(self) -> tuple[float, float | None]:
        """(campaign_s, wall_s) of the latest record (measurement or event): where the campaign clock
        stands, and the Unix time it stood there; (0, None) for a campaign that never ran."""
        rows = self._query(
            "SELECT campaign_s, wall_s FROM (SELECT campaign_s, wall_s FROM measurements UNION ALL "
            "SELECT campaign_s, wall_s FROM events WHERE campaign_s IS NOT NULL) "
            "ORDER BY campaign_s DESC, wall_s DESC LIMIT 1")
        return (float(rows[0][0]), float(rows[0][1])) if rows else (0.0, None)

    def last_known_axes(self) -> tuple[np.ndarray, float] | None:
        """(axis positions in degrees, campaign_s) the journal last recorded, or None: the latest of
        the last measurement's read-back positions and the last event that recorded positions (a
        park, a halt). It is where a gantry that no process drove since stands."""
        m = self._query("SELECT actual_deg, campaign_s FROM measurements ORDER BY campaign_s DESC, step DESC "
                        "LIMIT 1")
        e = self._query("SELECT axes_deg, campaign_s FROM events WHERE axes_deg IS NOT NULL "
                        "ORDER BY id DESC LIMIT 1")
        best = None
        for rows in (m, e):
            if rows and (best is None or rows[0][1] >= best[1]):
                best = (np.array(json.loads(rows[0][0]), float), float(rows[0][1]))
        return best
