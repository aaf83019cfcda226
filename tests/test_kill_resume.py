"""`gonio simulate` killed with SIGKILL at random moments, creation included, then run again until done:
the final brdf.h5 equals an uninterrupted run's bit for bit (the simulated gantry resumes where the
journal last saw it, every reading's random numbers are keyed by (seed, step, attempt), the campaign clock
continues), and with a drifting lamp and a dark offset it matches the true material within the stated
uncertainty."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import h5py
import numpy as np
import pytest

from gonio.config import DEFAULT_CONFIG, load_config
from gonio.store import JOURNAL_NAME, Journal

pytestmark = pytest.mark.slow

GONIO = [sys.executable, "-m", "gonio.cli"]
#: Upper bound on one whole run of these small campaigns (start-up included), for every wait below.
RUN_LIMIT_S = 120.0


def _toml(data: dict, prefix: str = "") -> str:
    """A config dict as TOML (tables of scalars and lists of scalars: all a gonio config holds)."""
    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, list | tuple):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(v)

    scalars = [f"{k} = {value(v)}" for k, v in data.items() if not isinstance(v, dict) and v is not None]
    tables = [_toml(v, f"{prefix}{k}.") for k, v in data.items() if isinstance(v, dict)]
    head = f"[{prefix[:-1]}]\n" if prefix and scalars else ""
    return head + "\n".join(scalars) + ("\n\n" if scalars else "") + "".join(tables)


def _set(data: dict, key: str, value) -> bool:
    """Set ``key`` wherever the config schema keeps it (simulator-only settings may sit in a sub-table)."""
    found = False
    for k, v in data.items():
        if k == key and not isinstance(v, dict):
            data[k] = value
            found = True
        elif isinstance(v, dict):
            found |= _set(v, key, value)
    return found


def _config(tmp_path: Path, **settings) -> Path:
    data = tomllib.loads(DEFAULT_CONFIG.read_text())
    for key, value in settings.items():
        assert _set(data, key, value), key
    path = tmp_path / "gantry.toml"
    path.write_text(_toml(data))
    load_config(path)  # the written file is a valid config
    return path


def _argv(material, grid, out, config, seed=3):
    return [*GONIO, "simulate", material, "--grid", grid, "--out", str(out), "--seed", str(seed),
            "--config", str(config), "--quiet"]


def _run_to_end(argv) -> float:
    """Run the command to the end; the seconds it took."""
    t0 = time.monotonic()
    r = subprocess.run(argv, capture_output=True, text=True, timeout=RUN_LIMIT_S)
    assert r.returncode == 0, r.stderr
    return time.monotonic() - t0


def _kill_during_creation(argv, out: Path) -> bool:
    """Start the command and SIGKILL it while the journal is being built (its temporary file exists).
    True when it was caught in that window (the window is short: the caller counts the catches)."""
    p = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    caught = False
    deadline = time.monotonic() + RUN_LIMIT_S
    try:
        while p.poll() is None and time.monotonic() < deadline:
            if out.is_dir() and Journal.partial_paths(out / JOURNAL_NAME):
                caught = True
                break
            if (out / JOURNAL_NAME).exists():
                break
            time.sleep(0.0002)
    finally:
        p.kill()
        p.wait(timeout=RUN_LIMIT_S)
    return caught


def _done(out: Path) -> int:
    if not (out / JOURNAL_NAME).exists():
        return 0
    j = Journal.open(out / JOURNAL_NAME, readonly=True)
    try:
        return j.done_count()
    finally:
        j.close()


def _kill_after(argv, out: Path, *, seconds: float | None = None, steps: int | None = None) -> bool:
    """Start the command and SIGKILL it after ``seconds`` of start-up, or once ``steps`` more steps are
    committed (watched through a read-only journal connection). False when it finished first."""
    start = _done(out)
    p = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + RUN_LIMIT_S
    t0 = time.monotonic()
    try:
        while p.poll() is None and time.monotonic() < deadline:
            if seconds is not None and time.monotonic() - t0 >= seconds:
                break
            if steps is not None and _done(out) >= start + steps:
                break
            time.sleep(0.001)
        if p.poll() is not None:
            return False
        os.kill(p.pid, signal.SIGKILL)
        return True
    finally:
        p.wait(timeout=RUN_LIMIT_S)


def _kill_and_resume(argv, out: Path, kills: int, seed: int) -> dict:
    """Kill ``kills`` times at random moments: a few while the journal is being created, some during
    start-up, the rest after a random number of further committed steps (each run gets part of the way).
    Then run to the end."""
    rng = random.Random(seed)
    stats = {"creation": 0, "startup": 0, "running": 0, "progress": []}
    for _ in range(3):
        if not (out / JOURNAL_NAME).exists():
            stats["creation"] += _kill_during_creation(argv, out)
    total = None
    while stats["startup"] + stats["running"] < kills:
        if (out / JOURNAL_NAME).exists() and total is None:
            j = Journal.open(out / JOURNAL_NAME, readonly=True)
            total = j.step_count()
            j.close()
        if total is not None and rng.random() < 0.3:
            killed = _kill_after(argv, out, seconds=rng.uniform(0.02, 0.6))
            stats["startup"] += killed
        else:
            most = 60 if total is None else max(1, total // (2 * kills))
            killed = _kill_after(argv, out, steps=rng.randint(1, most))
            stats["running"] += killed
        if not killed:
            pytest.fail(f"a run finished before its kill; kills so far: {stats}")
        stats["progress"].append(_done(out))
    _run_to_end(argv)
    return stats


def _h5(path: Path) -> dict:
    with h5py.File(path, "r") as f:
        return {k: f["samples"][k][()] for k in f["samples"]}


def _killed_equals_uninterrupted(tmp_path, material, grid, config, kills, seed, running) -> dict:
    """Run the campaign once to the end and once killed ``kills`` times (``running`` of them at least
    mid-campaign) and resumed; the two brdf.h5 are equal bit for bit and the journal holds exactly one
    measurement per step. Returns the killed run's samples."""
    ref, out = tmp_path / "ref", tmp_path / "killed"
    _run_to_end(_argv(material, grid, ref, config))
    stats = _kill_and_resume(_argv(material, grid, out, config), out, kills=kills, seed=seed)
    assert stats["startup"] + stats["running"] >= kills and stats["running"] >= running, stats
    a, b = _h5(ref / "brdf.h5"), _h5(out / "brdf.h5")
    assert a.keys() == b.keys()
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    j = Journal.open(out / JOURNAL_NAME, readonly=True)
    assert j.done_steps().tolist() == list(range(j.step_count()))  # exactly one measurement per step
    j.close()
    return b


def test_sigkill_at_random_moments_then_resume_equals_an_uninterrupted_run(tmp_path):
    _killed_equals_uninterrupted(tmp_path, "ggx:alpha=0.15,metal=gold", "iso:step=10", _config(tmp_path),
                                 kills=10, seed=1, running=3)


def test_sigkill_with_a_drifting_lamp_and_dark_offset_matches_the_truth_within_its_uncertainty(tmp_path):
    config = _config(tmp_path, drift_per_hour=-0.3, dark_offset=2.0, shot_counts_per_unit=50.0,
                     read_sigma=0.05, radiance=1e6)
    b = _killed_equals_uninterrupted(tmp_path, "lambert:albedo=0.5", "iso:step=10", config, kills=10, seed=2,
                                     running=3)
    # The lamp lost several percent over the campaign; the references track it.
    assert b["campaign_s"].max() > 600.0
    z = (b["value"] - 0.5 / np.pi) / b["stddev"]
    assert 0.8 < np.std(z) < 1.25 and abs(np.mean(z)) < 1.0
    assert np.mean(np.abs(z) < 3.0) > 0.99


def test_a_fly_campaign_killed_at_random_moments_resumes_to_the_uninterrupted_result(tmp_path):
    """The same for on-the-fly scanning (one journal transaction per sweep): a kill loses at most the
    sweep in flight, and the resumed campaign is the uninterrupted one bit for bit."""
    b = _killed_equals_uninterrupted(tmp_path, "ward:rho_d=0.1,rho_s=0.05,alpha=0.15",
                                     "iso:step=10,order=fly", _config(tmp_path), kills=6, seed=4, running=2)
    assert len(b["value"]) > 1000
