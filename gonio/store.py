"""The campaign journal: one SQLite file per campaign, append-only, one transaction per step.

Crash safety (DESIGN.md, rule 5): the file is in WAL mode and every measurement is committed in its own
transaction before the runner moves on, so a crash at any instant loses at most the step in flight;
``Journal.open`` on the same file resumes from what was committed. The schema version lives in
``PRAGMA user_version`` and is upgraded by numbered functions (none yet: version 1 is the first).

Angles are stored in degrees (a user boundary: anyone may open the file with ``sqlite3``), signals as
little-endian float64 blobs of one value per channel.
"""

from __future__ import annotations

import json
import sqlite3
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["Journal", "JournalError", "Measurement", "SCHEMA_VERSION", "JOURNAL_NAME"]

SCHEMA_VERSION = 1
JOURNAL_NAME = "campaign.sqlite"

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
    virtual_s REAL NOT NULL,        -- gantry clock (virtual in simulation) at the reading
    wall_s REAL NOT NULL,           -- Unix time of the commit
    exposure_s REAL NOT NULL,
    frames INTEGER NOT NULL,
    signal BLOB NOT NULL,           -- float64 per channel, dark not subtracted
    stderr BLOB NOT NULL,
    attempts INTEGER NOT NULL       -- 1 + retries it took
);
CREATE TABLE events (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    virtual_s REAL, wall_s REAL NOT NULL,
    kind TEXT NOT NULL,             -- state, fault, retry, pause, resume, ...
    state TEXT, step INTEGER, message TEXT
);
"""


class JournalError(RuntimeError):
    pass


@dataclass(frozen=True)
class Measurement:
    step: int
    kind: int
    pose: int
    commanded_deg: np.ndarray
    actual_deg: np.ndarray
    angles_deg: np.ndarray  # (θi, φi, θo, φo) actual
    virtual_s: float
    exposure_s: float
    frames: int
    signal: np.ndarray
    stderr: np.ndarray
    attempts: int = 1


def _blob(x) -> bytes:
    return np.ascontiguousarray(x, dtype="<f8").tobytes()


def _unblob(b: bytes) -> np.ndarray:
    return np.frombuffer(b, dtype="<f8").copy()


class Journal:
    """An open campaign journal. Create with :meth:`create`, reopen (resume) with :meth:`open`.

    ``write_hook`` is called with a running count before every write statement; tests raise from it
    to simulate a crash between any two writes.
    """

    def __init__(self, conn: sqlite3.Connection, path: Path,
                 write_hook: Callable[[int], None] | None = None):
        self._conn = conn
        self.path = path
        self._write_hook = write_hook
        self._writes = 0
        # The runner writes from its thread; pause/abort requests and readers may come from others
        # (the daemon). One lock serializes every use of the connection.
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
    def create(cls, path: str | Path, meta: dict, steps: dict, *,
               write_hook: Callable[[int], None] | None = None) -> Journal:
        """A new journal holding the campaign ``meta`` (JSON-able values) and the ordered plan.

        ``steps`` holds equal-length arrays: kind, pose, theta_i_deg, phi_i_deg, theta_o_deg, phi_o_deg
        and axes_deg (S, n_axes). The whole set-up is one transaction: a crash leaves no journal.
        """
        path = Path(path)
        if path.exists():
            raise JournalError(f"{path}: a campaign journal already exists (resume it instead)")
        conn = cls._connect(path)
        j = cls(conn, path, write_hook)
        with j._transaction():
            for stmt in _SCHEMA.split(";"):
                if stmt.strip():
                    j._write(stmt)
            j._write(f"PRAGMA user_version={SCHEMA_VERSION}")
            for k, v in meta.items():
                j._write("INSERT INTO meta VALUES (?, ?)", (k, json.dumps(v)))
            rows = zip(
                range(len(steps["kind"])), (int(k) for k in steps["kind"]), (int(p) for p in steps["pose"]),
                *(np.asarray(steps[c], float).tolist()
                  for c in ("theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg")),
                (json.dumps(a) for a in np.asarray(steps["axes_deg"], float).tolist()),
                strict=True,
            )
            j._write_many("INSERT INTO steps VALUES (?, ?, ?, ?, ?, ?, ?, ?)", rows)
        return j

    @classmethod
    def open(cls, path: str | Path, *, write_hook: Callable[[int], None] | None = None) -> Journal:
        path = Path(path)
        if not path.exists():
            raise JournalError(f"{path}: no campaign journal here")
        conn = cls._connect(path)
        version = conn.execute("PRAGMA user_version").fetchone()[0]
        if version != SCHEMA_VERSION:
            conn.close()
            raise JournalError(f"{path}: journal schema version {version}; this gonio reads "
                               f"version {SCHEMA_VERSION}")
        return cls(conn, path, write_hook)

    def close(self) -> None:
        with self._lock:
            self._conn.close()

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
        return Journal._Txn(self._conn, self._lock)

    def _query(self, sql: str, params=()) -> list:
        with self._lock:
            return self._conn.execute(sql, params).fetchall()

    def commit_measurement(self, m: Measurement, events: list[tuple[str, str | None, str]] = ()) -> None:
        """Commit one step's measurement (and the events that go with it) in one transaction."""
        wall = time.time()
        with self._transaction():
            self._write(
                "INSERT INTO measurements VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (m.step, m.kind, m.pose, json.dumps(np.asarray(m.commanded_deg, float).tolist()),
                 json.dumps(np.asarray(m.actual_deg, float).tolist()),
                 *(float(a) for a in m.angles_deg), m.virtual_s, wall, m.exposure_s, m.frames,
                 _blob(m.signal), _blob(m.stderr), m.attempts),
            )
            for kind, state, message in events:
                self._write("INSERT INTO events (virtual_s, wall_s, kind, state, step, message) "
                            "VALUES (?, ?, ?, ?, ?, ?)", (m.virtual_s, wall, kind, state, m.step, message))

    def log_event(self, kind: str, *, state: str | None = None, step: int | None = None,
                  message: str = "", virtual_s: float | None = None) -> None:
        with self._transaction():
            self._write("INSERT INTO events (virtual_s, wall_s, kind, state, step, message) "
                        "VALUES (?, ?, ?, ?, ?, ?)", (virtual_s, time.time(), kind, state, step, message))

    def set_meta(self, key: str, value) -> None:
        with self._transaction():
            self._write("INSERT OR REPLACE INTO meta VALUES (?, ?)", (key, json.dumps(value)))

    # -- reading ---------------------------------------------------------------------------------
    def meta(self) -> dict:
        return {k: json.loads(v) for k, v in self._query("SELECT key, value FROM meta")}

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

    def next_step(self) -> int:
        """The first step with no measurement (== step_count() when the campaign is complete)."""
        done = self.done_steps()
        missing = np.setdiff1d(np.arange(self.step_count()), done)
        return int(missing[0]) if missing.size else self.step_count()

    def measurements(self) -> list[Measurement]:
        out = []
        for r in self._query(
            "SELECT step, kind, pose, commanded_deg, actual_deg, theta_i_deg, phi_i_deg, theta_o_deg, "
            "phi_o_deg, virtual_s, exposure_s, frames, signal, stderr, attempts "
            "FROM measurements ORDER BY step"
        ):
            out.append(Measurement(
                step=r[0], kind=r[1], pose=r[2], commanded_deg=np.array(json.loads(r[3])),
                actual_deg=np.array(json.loads(r[4])), angles_deg=np.array(r[5:9], float),
                virtual_s=r[9], exposure_s=r[10], frames=r[11], signal=_unblob(r[12]),
                stderr=_unblob(r[13]), attempts=r[14]))
        return out

    def events(self) -> list[dict]:
        names = ("id", "virtual_s", "wall_s", "kind", "state", "step", "message")
        rows = self._query(f"SELECT {', '.join(names)} FROM events ORDER BY id")
        return [dict(zip(names, r, strict=True)) for r in rows]
