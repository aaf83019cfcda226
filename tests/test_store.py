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
                       angles_deg=np.array([10.0, 0.0, 20.0, 180.0]), clock_s=1.5 * step,
                       campaign_s=1.5 * step, exposure_s=0.1,
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


def test_a_crash_inside_a_commit_leaves_nothing_of_that_step(tmp_path):
    p = tmp_path / "c.sqlite"
    Journal.create(p, {}, _steps()).close()

    def hook(n):
        raise Crash

    j = Journal.open(p, write_hook=hook)
    with pytest.raises(Crash):
        j.commit_measurement(_m(0, kind=1, pose=-1))
    j.close()
    j = Journal.open(p)
    assert j.done_steps().size == 0 and j.next_step() == 0
    j.close()


@pytest.mark.parametrize("crash_at", range(1, 8))
def test_crash_during_creation_leaves_no_journal(tmp_path, crash_at):
    """Creation writes 4 tables, the schema version, 1 meta row and the steps (7 writes) into a
    temporary file that is renamed into place only when whole: a crash leaves no journal at all, and
    the next creation clears the temporary file away."""
    p = tmp_path / "c.sqlite"

    def hook(n):
        if n == crash_at:
            raise Crash

    with pytest.raises(Crash):
        Journal.create(p, {"a": 1}, _steps(), write_hook=hook)
    assert not p.exists()
    with pytest.raises(JournalError, match="no campaign journal"):
        Journal.open(p)
    j = Journal.create(p, {"a": 1}, _steps())
    assert j.meta() == {"a": 1} and j.step_count() == 5
    j.close()
    assert Journal.partial_paths(p) == []


def test_an_empty_journal_from_an_old_interrupted_creation_is_replaced(tmp_path):
    p = tmp_path / "c.sqlite"
    sqlite3.connect(p).close()  # what gonio < 0.2 left when killed while creating: no schema
    with pytest.raises(JournalError, match="interrupted; run the same command again"):
        Journal.open(p)
    j = Journal.create(p, {"b": 2}, _steps())
    assert j.meta() == {"b": 2}
    j.close()


def test_version_1_journals_are_upgraded_in_place(tmp_path):
    p = tmp_path / "c.sqlite"
    con = sqlite3.connect(p)
    con.executescript("""
        CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
        CREATE TABLE steps (step INTEGER PRIMARY KEY, kind INTEGER NOT NULL, pose INTEGER NOT NULL,
            theta_i_deg REAL, phi_i_deg REAL, theta_o_deg REAL, phi_o_deg REAL, axes_deg TEXT NOT NULL);
        CREATE TABLE measurements (step INTEGER PRIMARY KEY REFERENCES steps(step), kind INTEGER NOT NULL,
            pose INTEGER NOT NULL, commanded_deg TEXT NOT NULL, actual_deg TEXT NOT NULL,
            theta_i_deg REAL NOT NULL, phi_i_deg REAL NOT NULL, theta_o_deg REAL NOT NULL,
            phi_o_deg REAL NOT NULL, virtual_s REAL NOT NULL, wall_s REAL NOT NULL, exposure_s REAL NOT NULL,
            frames INTEGER NOT NULL, signal BLOB NOT NULL, stderr BLOB NOT NULL, attempts INTEGER NOT NULL);
        CREATE TABLE events (id INTEGER PRIMARY KEY AUTOINCREMENT, virtual_s REAL, wall_s REAL NOT NULL,
            kind TEXT NOT NULL, state TEXT, step INTEGER, message TEXT);
        INSERT INTO steps VALUES (0, 1, -1, 0, 0, 0, 0, '[0, 0, 0, 0]');
        INSERT INTO measurements VALUES (0, 1, -1, '[0,0,0,0]', '[0,0,0,0]', 0, 0, 0, 0, 7.5, 0, 0.1, 1,
            x'000000000000f03f', x'0000000000000000', 1);
        INSERT INTO events (virtual_s, wall_s, kind) VALUES (7.5, 0, 'state');
        PRAGMA user_version=1;
    """)
    con.close()
    with pytest.raises(JournalError, match="schema version 1.*open it for writing"):
        Journal.open(p, readonly=True)
    j = Journal.open(p)
    (m,) = j.measurements()
    assert m.clock_s == m.campaign_s == 7.5 and m.signal.tolist() == [1.0]
    assert j.events()[0]["campaign_s"] == 7.5
    j.close()
    assert sqlite3.connect(p).execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION


def test_readonly_reader_sees_commits_and_cannot_write(tmp_path):
    p = tmp_path / "c.sqlite"
    j = Journal.create(p, {}, _steps())
    r = Journal.open(p, readonly=True)
    j.commit_measurement(_m(0, kind=1, pose=-1))
    assert r.done_count() == 1
    with pytest.raises(JournalError, match="read-only"):
        r.log_event("x")
    r.close()
    j.close()


def test_latched_fault_survives_reopening_until_deleted(tmp_path):
    p = tmp_path / "c.sqlite"
    j = Journal.create(p, {}, _steps())
    assert j.latched_fault() is None
    j.latch_fault("light_tilt: hardware error: overload", ["light_tilt"])
    j.close()
    j = Journal.open(p)
    assert j.latched_fault() == {"reason": "light_tilt: hardware error: overload", "devices": ["light_tilt"]}
    j.delete_meta("latched_fault")
    assert j.latched_fault() is None
    j.close()


def test_campaign_clock_and_last_known_axes_follow_the_latest_record(tmp_path):
    j = Journal.create(tmp_path / "c.sqlite", {}, _steps())
    assert j.campaign_clock() == (0.0, None) and j.last_known_axes() is None
    j.commit_measurement(_m(2))  # campaign_s 3.0, actual 0.01 each
    assert j.campaign_clock()[0] == 3.0
    axes, t = j.last_known_axes()
    assert axes.tolist() == [0.01] * 4 and t == 3.0
    j.log_event("park", campaign_s=9.0, axes_deg=[1.0, 2.0, 3.0, 4.0])
    j.log_event("state", campaign_s=9.5)
    assert j.campaign_clock()[0] == 9.5
    axes, t = j.last_known_axes()
    assert axes.tolist() == [1.0, 2.0, 3.0, 4.0] and t == 9.0
    j.close()


def test_next_step_fills_gaps(tmp_path):
    j = Journal.create(tmp_path / "c.sqlite", {}, _steps())
    for s in (0, 1, 3):
        j.commit_measurement(_m(s))
    assert j.next_step() == 2
    with pytest.raises(sqlite3.IntegrityError):
        j.commit_measurement(_m(3))  # one measurement per step, ever
    j.close()


# -- schema 3: readings with a shape, their extra, frames beside the journal -----------------------------
def _as_version_2(p):
    """Turn a fresh journal into what gonio with schema 2 wrote (no shape, extra or frame columns)."""
    con = sqlite3.connect(p)
    for column in ("shape", "extra", "frame_file", "frame_sha256"):
        con.execute(f"ALTER TABLE measurements DROP COLUMN {column}")
    con.execute("PRAGMA user_version=2")
    con.commit()
    con.close()


def test_readings_keep_their_shape_and_extra(tmp_path):
    from gonio.store import detector_descriptor

    p = tmp_path / "c.sqlite"
    desc = detector_descriptor("camera", ["R", "G", "B"], shape=[4, 5, 3])
    j = Journal.create(p, {"detector": desc}, _steps())
    signal = np.arange(60, dtype=float).reshape(4, 5, 3)
    extra = {"target": "sample", "key": (2, 1), "stderr_sensor": np.array([0.5, 0.25]), "n": np.int64(7)}
    j.commit_measurement(Measurement(step=2, kind=0, pose=0, commanded_deg=np.zeros(4),
                                     actual_deg=np.zeros(4), angles_deg=np.zeros(4), clock_s=1.0,
                                     campaign_s=1.0, exposure_s=0.1, frames=1, signal=signal,
                                     stderr=signal / 10, extra=extra))
    j.close()
    j = Journal.open(p, readonly=True)
    (m,) = j.measurements()
    assert m.signal.shape == (4, 5, 3) and np.array_equal(m.signal, signal)
    assert np.array_equal(m.stderr, signal / 10)
    assert m.extra == {"target": "sample", "key": [2, 1], "stderr_sensor": [0.5, 0.25], "n": 7}
    assert j.detector() == desc and desc["shape"] == [4, 5, 3] and desc["wavelengths_nm"] is None
    # Without the extra (what calibration reads): the same measurement, its extra alone left out
    (bare,) = j.measurements(extra=False)
    assert bare.extra == {} and np.array_equal(bare.signal, m.signal)
    assert np.array_equal(bare.stderr, m.stderr)
    assert bare.step == m.step and bare.campaign_s == m.campaign_s and bare.signal.shape == (4, 5, 3)
    j.close()


def test_a_signal_and_stderr_of_different_shapes_are_refused(tmp_path):
    j = Journal.create(tmp_path / "c.sqlite", {}, _steps())
    bad = Measurement(step=0, kind=1, pose=-1, commanded_deg=np.zeros(4), actual_deg=np.zeros(4),
                      angles_deg=np.zeros(4), clock_s=0.0, campaign_s=0.0, exposure_s=0.1, frames=1,
                      signal=np.zeros(3), stderr=np.zeros(4))
    with pytest.raises(JournalError, match="step 0: stderr has shape"):
        j.commit_measurement(bad)
    assert j.done_count() == 0
    j.close()


def test_version_2_journals_read_as_they_are_and_upgrade_when_opened_for_writing(tmp_path):
    p = tmp_path / "c.sqlite"
    j = Journal.create(p, {"channels": ["R", "G", "B"]}, _steps())
    j.close()
    _as_version_2(p)
    con = sqlite3.connect(p)
    con.execute("INSERT INTO measurements (step, kind, pose, commanded_deg, actual_deg, theta_i_deg, "
                "phi_i_deg, theta_o_deg, phi_o_deg, clock_s, wall_s, exposure_s, frames, signal, stderr, "
                "attempts, campaign_s) VALUES (0, 1, -1, '[0,0,0,0]', '[0,0,0,0]', 0, 0, 0, 0, 1.0, 0, 0.1, "
                "1, ?, ?, 1, 1.0)",
                (np.array([1.0, 2.0, 3.0]).tobytes(), np.zeros(3).tobytes()))
    con.commit()
    con.close()
    r = Journal.open(p, readonly=True)  # a reader (gonio status) must not need to upgrade it
    (m,) = r.measurements()
    assert m.signal.tolist() == [1.0, 2.0, 3.0] and m.extra == {} and m.frame_file is None
    assert r.detector()["kind"] == "photodiode" and r.detector()["channels"] == ["R", "G", "B"]
    r.close()
    j = Journal.open(p)
    j.commit_measurement(_m(1, kind=2, pose=-1))
    assert [x.signal.shape for x in j.measurements()] == [(3,), (3,)]
    j.close()
    assert sqlite3.connect(p).execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION


def _frame_measurement(step, frame):
    px = frame.pixels
    return Measurement(step=step, kind=0, pose=0, commanded_deg=np.zeros(4), actual_deg=np.zeros(4),
                       angles_deg=np.zeros(4), clock_s=0.0, campaign_s=0.0, exposure_s=0.1, frames=1,
                       signal=px.mean(axis=(0, 1)), stderr=np.zeros(3), extra={"frame": frame, "n": 3})


def test_a_frame_is_written_before_its_row_and_read_back_by_hash(tmp_path):
    from gonio.frames import Frame, FrameError, content_hash

    p = tmp_path / "c.sqlite"
    px = np.random.default_rng(1).random((6, 7, 3)).astype(np.float32)
    seen = []

    def hook(n):  # at the row's write, the frame is already on disk
        seen.append(sorted(x.name for x in (tmp_path / "frames").glob("*.exr")))

    Journal.create(p, {}, _steps()).close()
    j = Journal.open(p, write_hook=hook)
    j.commit_measurement(_frame_measurement(2, Frame(px, {"exposure_s": 0.1})))
    assert seen[-1] == ["step000002-a1.exr"]
    (m,) = j.measurements()
    assert m.frame_file == "frames/step000002-a1.exr" and m.frame_sha256 == content_hash(px)
    assert m.extra == {"n": 3}
    f = j.frame(2)
    assert np.array_equal(f.pixels, px) and f.metadata == {"exposure_s": 0.1}
    # a frame file that went missing, or that holds other pixels, is an error naming it (never zeros)
    with pytest.raises(FrameError, match="step 3 has no frame"):
        j.frame(3)
    (tmp_path / m.frame_file).rename(tmp_path / "moved.exr")
    with pytest.raises(FrameError, match="step000002-a1.exr: the frame of step 2 is missing"):
        j.frame(2)
    from gonio.frames import write_exr

    write_exr(tmp_path / m.frame_file, Frame(px * 2, {}))
    with pytest.raises(FrameError, match="not the one committed"):
        j.frame(2)
    (tmp_path / m.frame_file).write_bytes(b"not an exr")
    with pytest.raises(FrameError, match="cannot read EXR"):
        j.frame(2)
    j.close()


def test_a_crash_after_the_frame_file_leaves_no_row_and_the_replay_overwrites_it(tmp_path):
    from gonio.frames import Frame

    p = tmp_path / "c.sqlite"
    Journal.create(p, {}, _steps()).close()

    def hook(n):
        raise Crash

    px = np.ones((4, 4, 3), np.float32)
    j = Journal.open(p, write_hook=hook)
    with pytest.raises(Crash):
        j.commit_measurement(_frame_measurement(2, Frame(px, {})))
    j.close()
    assert (tmp_path / "frames" / "step000002-a1.exr").is_file()  # no row names it yet
    j = Journal.open(p)
    assert j.done_count() == 0
    j.commit_measurement(_frame_measurement(2, Frame(px, {})))
    assert np.array_equal(j.frame(2).pixels, px)
    j.close()
