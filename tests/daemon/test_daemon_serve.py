"""``gonio serve`` as a process: the loopback rule and the token's strength, SIGTERM (pause, park, resume
at the next start or hold with --hold), and SIGKILL at random moments of a simulated campaign: after
each restart the daemon resumes it, the journal says that each killed run stopped uncleanly, and the
end result equals an uninterrupted run bit for bit."""

from __future__ import annotations

import os
import random
import signal
import sqlite3
import subprocess
from pathlib import Path

import h5py
import numpy as np
import pytest
from daemon_helpers import GONIO, WAIT_S, Serve, wait_for
from planned import create

from gonio.config import load_config
from gonio.lifecycle import run_campaign
from gonio.sim.materials import load
from gonio.store import JOURNAL_NAME, Journal
from gonio.wiring import build_gantry


def _done(folder: Path) -> int:
    if not (folder / JOURNAL_NAME).exists():
        return 0
    j = Journal.open(folder / JOURNAL_NAME, readonly=True)
    try:
        return j.done_count()
    finally:
        j.close()


def test_serve_refuses_a_non_loopback_address_without_a_token(tmp_path):
    r = subprocess.run([*GONIO, "serve", "--host", "0.0.0.0", "--data", str(tmp_path / "d")],
                       capture_output=True, text=True, timeout=WAIT_S, env={**os.environ, "GONIO_TOKEN": ""})
    assert r.returncode == 2
    assert r.stderr.strip().startswith("gonio serve: --host: 0.0.0.0 is not a loopback address")
    assert len(r.stderr.strip().splitlines()) == 1 and not (tmp_path / "d").exists()


@pytest.mark.parametrize(("args", "token", "message"), [
    (("--host", "0.0.0.0"), "     ", "GONIO_TOKEN / --token: a token needs at least 16 characters"),
    (("--host", "0.0.0.0"), "x", "GONIO_TOKEN / --token: a token needs at least 16 characters"),
    ((), "sixteen chars ok", "GONIO_TOKEN / --token: a token needs at least 16 characters"),
    (("--token", "\t"), "", "GONIO_TOKEN / --token: a token needs at least 16 characters"),
    (("--materials", "/nonexistent/m"), "", "--materials: /nonexistent/m is not a folder"),
    (("--allow-host", "http://x"), "", "--allow-host: expected NAME or NAME:PORT"),
])
def test_serve_refuses_weak_tokens_and_bad_options_before_writing_anything(tmp_path, monkeypatch, capsys,
                                                                         args, token, message):
    # In this process (the refusal above is the one made by a process of its own): a serve that did not
    # refuse would fail at once rather than serve.
    code, err = _serve_here(monkeypatch, capsys, ["--data", str(tmp_path / "d"), *args], token)
    assert code == 2, err
    assert err.strip().startswith(f"gonio serve: {message}"), err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "d").exists()


def test_serve_refuses_a_data_folder_that_is_a_file(tmp_path, monkeypatch, capsys):
    """It said `gonio serve: FILE: File exists`, naming neither --data nor what it wants."""
    (tmp_path / "d").write_text("notes")
    code, err = _serve_here(monkeypatch, capsys, ["--data", str(tmp_path / "d")], "")
    assert code == 2 and err.strip() == (f"gonio serve: --data: {tmp_path / 'd'} is a file, not a folder; "
                                         "give the folder that holds (or will hold) the daemon's campaigns")
    assert (tmp_path / "d").read_text() == "notes"


def _serve_here(monkeypatch, capsys, args: list[str], token: str) -> tuple[int, str]:
    """``gonio serve ARGS`` in this process with GONIO_TOKEN=``token``, for what it refuses before it
    listens: (exit status, stderr). One that gets as far as serving fails the test instead (its logging
    set-up, which would replace the test's, is kept to this call)."""
    import logging

    import uvicorn

    from gonio.cli import main

    def refused_too_late(*a, **kw):
        raise AssertionError("gonio serve went on to serve")

    root = logging.getLogger()
    monkeypatch.setattr(root, "handlers", list(root.handlers))
    monkeypatch.setattr(root, "level", root.level)
    monkeypatch.setattr(uvicorn.Server, "run", refused_too_late)
    monkeypatch.setenv("GONIO_TOKEN", token)
    capsys.readouterr()
    code = main(["serve", *args])
    return code, capsys.readouterr().err


@pytest.mark.parametrize(("args", "idle", "hold"), [
    ((), True, False), (("--plan-priority", "normal"), False, False),
    (("--plan-priority", "idle", "--hold"), True, True)])
def test_serve_hands_its_plan_priority_and_hold_to_the_daemon(tmp_path, monkeypatch, args, idle, hold):
    """What ``--plan-priority`` (and ``--hold``) hand the daemon (the worker's scheduling policy for each
    value is checked in test_daemon_submit.py, what a held start does below); a value not allowed is
    refused (exit status 2, argparse's)."""
    import logging

    import gonio.daemon.server as server
    from gonio.cli import main

    seen = []
    root = logging.getLogger()
    monkeypatch.setattr(root, "handlers", list(root.handlers))
    monkeypatch.setattr(root, "level", root.level)
    monkeypatch.setattr(server, "serve", lambda cfg, **kw: seen.append((kw["plan_idle"], kw["hold"])) or 0)
    assert main(["serve", "--data", str(tmp_path / "d"), *args]) == 0 and seen == [(idle, hold)]
    with pytest.raises(SystemExit) as exc:
        main(["serve", "--data", str(tmp_path / "d"), "--plan-priority", "low"])
    assert exc.value.code == 2 and seen == [(idle, hold)]


@pytest.mark.slow
def test_sigterm_pauses_and_parks_then_the_next_start_resumes_or_holds(tmp_path, monkeypatch, capsys, serve):
    data = tmp_path / "data"
    # 310 steps paced at 10 ms of wall time per gantry second (~20 ms a step): seconds of runway for the
    # waits below, and a plan of 0.3 s of CPU where iso:step=10 (1168 steps) took 1.2 s, then ran on.
    s = Serve(data, "--pace", "0.01")
    body = {"material": "lambert:albedo=0.5", "grid": "iso:step=15"}
    s.client.post("/campaigns", json=body).raise_for_status()
    folder = data / "campaigns" / "c00001"
    wait_for(lambda: _done(folder) >= 2, "two committed steps")
    # A second daemon on the same data folder is refused (this process's: the lock is the other's).
    with monkeypatch.context() as m:
        code, err = _serve_here(m, capsys, ["--data", str(data), "--port", "0"], "")
    assert code == 2 and "served by another gonio daemon" in err, err
    assert s.stop(signal.SIGTERM) == 0
    j = Journal.open(folder / JOURNAL_NAME, readonly=True)
    try:
        assert j.last_event("state")["state"] == "paused"
        assert j.last_event("park") is not None
        n, total = j.done_count(), j.step_count()
    finally:
        j.close()
    assert 0 < n < total
    # The next starts in this process (what holds or resumes is the queue's start-up, not the process; the
    # --hold option's way to it is checked below, in-process too; a `gonio serve` costs ~2 s of CPU).
    held = serve(data=data, pace=0.01, hold=True)
    assert held.client.get("/campaigns/c00001").json()["state"] == "paused"
    assert _done(folder) == n
    held.client.post("/campaigns/c00001/resume").raise_for_status()   # held until an operator resumes
    wait_for(lambda: _done(folder) >= n + 2, "two more steps")
    held.stop()    # the daemon's stop, as its SIGTERM handler asks it
    # Stopped while running: the next start resumes it by itself.
    s = serve(data=data)
    wait_for(lambda: s.client.get("/campaigns/c00001").json()["state"] == "done", "the campaign to finish")
    runs, unclean = _runs(folder)
    assert runs == 3 and unclean == 0    # SIGTERM stops are clean: paused, then resumed


def _runs(folder: Path) -> tuple[int, int]:
    """(runs, unclean stops) of a journal, checking that every run ends in a state of its own or, when a
    crash cut it short, in exactly one ``unclean-stop`` journaled before the next run starts."""
    j = Journal.open(folder / JOURNAL_NAME, readonly=True)
    try:
        events = [(e["kind"], e["state"]) for e in j.events() if e["kind"] in ("state", "unclean-stop")]
    finally:
        j.close()
    running, runs, unclean = False, 0, 0
    for kind, state in events:
        if kind == "unclean-stop":
            assert running, events            # only after a run the journal left open
            running, unclean = False, unclean + 1
        elif state == "running":
            assert not running, events        # the previous run was closed, cleanly or not
            running, runs = True, runs + 1
        else:
            running = False
    assert not running, events
    return runs, unclean


def _running_states(folder: Path) -> int:
    j = Journal.open(folder / JOURNAL_NAME, readonly=True)
    try:
        return sum(e["kind"] == "state" and e["state"] == "running" for e in j.events())
    finally:
        j.close()


def _reference(tmp_path: Path, material: str, grid: str, seed: int) -> Path:
    """The uninterrupted run, as ``gonio simulate`` makes it (with the process's plan of ``grid``,
    tests/planned.py, which the daemons of the serve fixture are given too)."""
    cfg = load_config()
    c = create(tmp_path / "ref", cfg, grid=grid, material=load(material).spec, seed=seed)
    try:
        state, _ = run_campaign(c, build_gantry(cfg, material, seed=seed))
    finally:
        c.close()
    assert state == "done"
    return tmp_path / "ref" / "brdf.h5"


def _samples(path: Path) -> dict:
    with h5py.File(path, "r") as f:
        return {k: f["samples"][k][()] for k in f["samples"]}


PACE = "0.01"


@pytest.mark.slow
def test_sigkill_at_random_moments_then_the_daemon_resumes_to_an_identical_result(tmp_path, serve):
    # 310 steps (iso:step=12's 549 planned in 0.8 s of CPU, twice: the reference and the daemon's).
    material, grid, seed = "ggx:alpha=0.2,metal=gold", "iso:step=15", 5
    ref = _reference(tmp_path, material, grid, seed)
    data = tmp_path / "data"
    folder = data / "campaigns" / "c00001"
    rng = random.Random(7)
    # Paced at 10 ms of wall time per gantry second (~10 ms a step): a kill, which waits for at most
    # total // 14 more steps, lands well before the end however fast the machine (unpaced, a fast machine
    # ran the rest of the campaign within a kill's wait). Pacing spends wall time only.
    s = Serve(data, "--pace", PACE)
    s.client.post("/campaigns", json={"material": material, "grid": grid, "seed": seed}).raise_for_status()
    total = Journal.open(folder / JOURNAL_NAME, readonly=True).step_count()
    # Two kills: one mid-campaign, one as soon as the restarted daemon has taken the campaign up again (its
    # resume journaled); a crash between any two journal writes is covered in-process (test_kill_resume.py).
    kills, progress = 0, []
    while kills < 2:
        start = _done(folder)
        if kills == 1:
            wait_for(lambda: _running_states(folder) >= 2, "the resume", poll_s=0.001)
        else:
            wait_for(lambda start=start: _done(folder) >= start + rng.randint(1, total // 14), "more steps",
                     poll_s=0.001)
        assert s.stop(signal.SIGKILL) == -signal.SIGKILL
        kills += 1
        progress.append(_done(folder))
        assert progress[-1] < total, "the campaign finished before its kill"
        if kills < 2:
            s = Serve(data, "--pace", PACE)
    # The last start runs the rest unpaced (pacing spends wall time only: the same result), in this
    # process: what it tests is what the killed processes left, and the start-up that takes it up.
    s = serve(data=data)
    wait_for(lambda: s.client.get("/campaigns/c00001").json()["state"] == "done", "the campaign to finish")
    assert kills == 2 and 0 < progress[0] <= progress[1], progress
    j = Journal.open(folder / JOURNAL_NAME, readonly=True)
    try:
        assert j.done_steps().tolist() == list(range(total))     # exactly one measurement per step
    finally:
        j.close()
    runs, unclean = _runs(folder)
    assert unclean == runs - 1 == kills    # every run but the last was killed, and says so
    conn = sqlite3.connect(folder / JOURNAL_NAME)
    try:
        assert conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    finally:
        conn.close()
    a, b = _samples(ref), _samples(folder / "brdf.h5")
    assert a.keys() == b.keys()
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_the_moment_it_says_listening_stops_the_daemon(tmp_path, sig):
    """A Ctrl-C (or SIGTERM) that comes right after "listening on", before uvicorn has its own handlers,
    stops the daemon as one that comes later does; it was lost, and the daemon ran on."""
    code = ("import os, signal, sys\n"
            "from pathlib import Path\n"
            "from gonio.config import load_config\n"
            "from gonio.daemon.server import serve\n"
            "def announce(line):\n"
            "    print(line, flush=True)\n"
            f"    os.kill(os.getpid(), {int(sig)})\n"
            f"sys.exit(serve(load_config(None), data=Path(sys.argv[1]), port=0, announce=announce))\n")
    r = subprocess.run([GONIO[0], "-c", code, str(tmp_path / "data")], capture_output=True, text=True,
                       timeout=WAIT_S)
    assert r.returncode == 0, r.stderr
    assert "listening on" in r.stdout and "Traceback" not in r.stderr
