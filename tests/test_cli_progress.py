"""What a person watching a terminal sees while gonio works: a spinner while a plan is made (nothing of it
in a pipe, a log or --json), an ETA only once the pace is known, and no ETA for a finished campaign."""

from __future__ import annotations

import os
import pty
import subprocess
import sys
import time

from gonio.cli import main

GONIO = [sys.executable, "-m", "gonio.cli"]
SIMULATE = ["simulate", "lambert:albedo=0.5", "--grid", "iso:step=45", "--out"]


def _on_a_terminal(argv, cwd, timeout_s=120.0) -> str:
    """Run gonio with stdout and stderr on a pseudo-terminal; everything it wrote there."""
    master, slave = pty.openpty()
    env = dict(os.environ, TERM="xterm-256color", COLUMNS="120", LINES="40")
    env.pop("NO_COLOR", None)
    p = subprocess.Popen([*GONIO, *argv], stdin=subprocess.DEVNULL, stdout=slave, stderr=slave, cwd=cwd,
                         env=env)
    os.close(slave)
    chunks, deadline = [], time.monotonic() + timeout_s
    try:
        while time.monotonic() < deadline:
            try:
                data = os.read(master, 65536)
            except OSError:       # EIO: the child closed the terminal
                break
            if not data:
                break
            chunks.append(data)
        assert p.wait(timeout=max(1.0, deadline - time.monotonic())) == 0, b"".join(chunks)[-2000:]
    finally:
        p.kill()
        os.close(master)
    return b"".join(chunks).decode(errors="replace")


def test_plan_shows_a_spinner_on_a_terminal_and_nothing_of_it_in_a_pipe(tmp_path, capsys):
    # iso:step=45 (5 poses): the spinner is shown however short the plan; a plan of a few poses starts
    # without scipy.spatial's k-d tree (gonio.motion.nearest), a third of a second of each process's CPU.
    seen = _on_a_terminal(["plan", "--grid", "iso:step=45"], tmp_path)
    assert "planning iso:step=45" in seen and "lower bound" in seen
    assert "planning" not in _on_a_terminal(["plan", "--grid", "iso:step=45", "--json"], tmp_path)
    # In a pipe (this process's captured stdout and stderr, no terminal; the terminal runs above are
    # processes of their own).
    capsys.readouterr()
    assert main(["plan", "--grid", "iso:step=45"]) == 0
    r = capsys.readouterr()
    assert "planning" not in r.out + r.err and "lower bound" in r.out


def test_simulate_shows_the_spinner_then_a_bar_whose_eta_waits_for_the_pace(tmp_path):
    seen = _on_a_terminal([*SIMULATE, "run"], tmp_path)
    assert "planning iso:step=45" in seen
    assert "ETA ?" in seen                      # the first steps: no pace yet
    assert (tmp_path / "run" / "brdf.h5").is_file()


def test_plain_progress_lines_give_no_eta_from_the_first_step(tmp_path, capsys):
    # stderr not a terminal: this process's, captured (tests/test_cli.py runs the console script as a
    # process of its own).
    capsys.readouterr()
    # iso:step=20: more steps than the simulated detector's first chunk (iso:step=45's 9 are one chunk)
    assert main(["simulate", "lambert:albedo=0.5", "--grid", "iso:step=20", "--out",
                 str(tmp_path / "run")]) == 0
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("measuring: ")]
    # The first committed unit (the simulated detector's chunk of steps): no pace yet, so no ETA.
    assert len(lines) >= 2 and lines[0].endswith("ETA ?")
    assert "(100 %)" in lines[-1] and lines[-1].endswith("ETA 0:00:00")   # done: nothing left, said so
    assert "planning" not in err


def test_status_of_a_finished_campaign_prints_no_eta(tmp_path, capsys):
    out = tmp_path / "run"
    assert main([*SIMULATE, str(out), "--quiet"]) == 0
    capsys.readouterr()
    assert main(["status", str(out)]) == 0
    text = capsys.readouterr().out
    assert ": done" in text and "ETA" not in text
