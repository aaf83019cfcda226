import sqlite3

import numpy as np
import pytest

from gonio.store import SCHEMA_VERSION, Journal, JournalError, Measurement


def _steps(n=5, n_axes=4):
    kind = np.array([1, 2] + [0] * (n - 2), dtype=np.int8)
    pose = np.array([-1, -1] + list(range(n - 2)))
    ang = np.arange(n, dtype=float)
    return {"kind": kind, "pose": pose, "theta_i_deg": ang, "phi_i_deg": ang, "theta_o_deg": ang,
            "phi_o_deg": ang, "axes_deg": np.arange(n * n_axes, dtype=float).reshape(n, n_axes)}


def _m(step, kind=0, pose=0):
    return Measurement(step=step, kind=kind, pose=pose, commanded_deg=np.zeros(4),
                       actual_deg=np.ones(4) * 0.01,
                       angles_deg=np.array([10.0, 0.0, 20.0, 180.0]), virtual_s=1.5 * step, exposure_s=0.1,
                       frames=1, signal=np.array([1.0, 2.0, 3.0]) * step, stderr=np.zeros(3))


class Crash(BaseException):
    pass


def test_create_reopen_and_read_back_with_plain_sqlite(tmp_path):
    p = tmp_path / "c.sqlite"
    j = Journal.create(p, {"grid": "iso:step=5", "seed": 3}, _steps())
    j.commit_measurement(_m(0, kind=1, pose=-1))
    j.commit_measurement(_m(1, kind=2, pose=-1))
    j.close()
    # an independent reader: the sqlite3 module alone
    con = sqlite3.connect(p)
    assert con.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION
    assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert con.execute("SELECT COUNT(*) FROM steps").fetchone()[0] == 5
    blob = con.execute("SELECT signal FROM measurements WHERE step=1").fetchone()[0]
    assert np.frombuffer(blob, "<f8").tolist() == [1.0, 2.0, 3.0]
    con.close()
    j = Journal.open(p)
    assert j.meta() == {"grid": "iso:step=5", "seed": 3}
    assert j.next_step() == 2
    assert j.steps()["axes_deg"].shape == (5, 4)
    assert [m.step for m in j.measurements()] == [0, 1]
    j.close()


def test_refuses_to_overwrite_and_to_open_missing(tmp_path):
    p = tmp_path / "c.sqlite"
    Journal.create(p, {}, _steps()).close()
    with pytest.raises(JournalError, match="already exists"):
        Journal.create(p, {}, _steps())
    with pytest.raises(JournalError, match="no campaign journal"):
        Journal.open(tmp_path / "nope.sqlite")


def test_rejects_unknown_schema_version(tmp_path):
    p = tmp_path / "c.sqlite"
    Journal.create(p, {}, _steps()).close()
    con = sqlite3.connect(p)
    con.execute("PRAGMA user_version=99")
    con.close()
    with pytest.raises(JournalError, match="schema version 99"):
        Journal.open(p)


def test_a_step_is_one_transaction(tmp_path):
    """A crash between the measurement row and its events leaves neither behind."""
    p = tmp_path / "c.sqlite"
    Journal.create(p, {}, _steps()).close()

    def hook(n):
        if n == 2:  # 1: measurement insert, 2: first event insert
            raise Crash

    j = Journal.open(p, write_hook=hook)
    with pytest.raises(Crash):
        j.commit_measurement(_m(0, kind=1, pose=-1), events=[("retry", None, "x")])
    j.close()
    j = Journal.open(p)
    assert j.done_steps().size == 0 and j.events() == [] and j.next_step() == 0


@pytest.mark.parametrize("crash_at", range(1, 8))
def test_crash_during_creation_leaves_no_half_plan(tmp_path, crash_at):
    """Creation writes 4 tables, the schema version, 1 meta row and the steps: 7 writes, one
    transaction. A crash before any of them leaves an empty file, never half a plan."""
    p = tmp_path / "c.sqlite"
    writes = []

    def hook(n):
        writes.append(n)
        if n == crash_at:
            raise Crash

    with pytest.raises(Crash):
        Journal.create(p, {"a": 1}, _steps(), write_hook=hook)
    con = sqlite3.connect(p)
    assert con.execute("SELECT name FROM sqlite_master").fetchall() == []
    assert con.execute("PRAGMA user_version").fetchone()[0] == 0
    con.close()


def test_next_step_fills_gaps(tmp_path):
    j = Journal.create(tmp_path / "c.sqlite", {}, _steps())
    for s in (0, 1, 3):
        j.commit_measurement(_m(s))
    assert j.next_step() == 2
    with pytest.raises(sqlite3.IntegrityError):
        j.commit_measurement(_m(3))  # one measurement per step, ever
    j.close()
