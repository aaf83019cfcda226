"""`gonio simulate` killed at random moments, creation included, then run again until done: the final
brdf.h5 equals an uninterrupted run's bit for bit (the simulated gantry resumes where the journal last saw
it, every reading's random numbers are keyed by (seed, step, attempt), the campaign clock continues), and
with a drifting lamp and a dark offset it matches the true material within the stated uncertainty.

Most kills are simulated in the test's process (tests/journal_crash.py): the command dies before a chosen
journal write (one of the creation's, the first ones of a resumed run, or one after a random number of
further writes), then the same command runs again. One real SIGKILL per path (stop-and-go steps, fly
sweeps, adaptive rounds) runs the command as a process and kills it mid-campaign (the stop-and-go one also
while the journal is being created); the run that resumes it is this process's."""

from __future__ import annotations

import os
import random
import re
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import h5py
import numpy as np
import planned
import pytest
from built_once import built_once
from journal_crash import Crash, crash_at_write

from gonio.cli import main
from gonio.config import DEFAULT_CONFIG, load_config
from gonio.sim import detector as sim_detector
from gonio.store import JOURNAL_NAME, Journal

GONIO = [sys.executable, "-m", "gonio.cli"]
#: Upper bound on one whole run of these small campaigns (start-up included), for every wait below.
RUN_LIMIT_S = 120.0


@pytest.fixture(autouse=True)
def _each_plan_made_once(monkeypatch):
    """The campaigns here plan each grid on the same gantry again and again (the uninterrupted run, the
    crashed one's creation, in this process; a fly campaign's every run rebuilds its fly plan from the
    journal): the planner (deterministic: a function of the grid and the gantry) runs once per (grid,
    config) and each campaign gets a copy of its plan (:func:`planned.planned`, :func:`planned.fly_plans`).
    What these tests check comes after the plan: the crashes, the resumes, the results bit for bit (and a
    resumed fly campaign still checks the plan it gets against its journal's steps; the SIGKILLed one's
    journal was planned by another process)."""
    import gonio.fly.plans as fly_planning
    import gonio.lifecycle as lifecycle

    monkeypatch.setattr(lifecycle, "plan_campaign", planned.planned)
    monkeypatch.setattr(fly_planning, "fly_plans", planned.fly_plans)


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
    return ["simulate", material, "--grid", grid, "--out", str(out), "--seed", str(seed), "--config",
            str(config), "--quiet"]


def _done(out: Path) -> int:
    if not (out / JOURNAL_NAME).exists():
        return 0
    j = Journal.open(out / JOURNAL_NAME, readonly=True)
    try:
        return j.done_count()
    finally:
        j.close()


def _h5(path: Path) -> dict:
    with h5py.File(path, "r") as f:
        return {k: f["samples"][k][()] for k in f["samples"]}


def _uninterrupted(monkeypatch, argv):
    """Run the command in this process to the end; the journal writes it made (:class:`Writes`)."""
    with crash_at_write(monkeypatch, None) as writes:
        assert main(argv) == 0
    return writes


def _equal_to(ref: Path, out: Path) -> dict:
    """The two campaigns' brdf.h5 are equal bit for bit and ``out``'s journal holds exactly one measurement
    per step. Returns ``out``'s samples."""
    a, b = _h5(ref / "brdf.h5"), _h5(out / "brdf.h5")
    assert a.keys() == b.keys()
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    j = Journal.open(out / JOURNAL_NAME, readonly=True)
    assert j.done_steps().tolist() == list(range(j.step_count()))  # exactly one measurement per step
    j.close()
    return b


def _crash(monkeypatch, argv, at: int) -> None:
    with crash_at_write(monkeypatch, at), pytest.raises(Crash):   # DID NOT RAISE: it finished first
        main(argv)


#: The journal writes a run makes before its first unit (its state event, the devices' descriptions in
#: the meta and an event, the resume's event): a crash among them is a start-up crash.
STARTUP_WRITES = 4


def _crash_and_resume(monkeypatch, argv, out: Path, kills: int, seed: int, writes, creation: int) -> dict:
    """Crash the command ``creation`` times (0 to 2) during the journal's creation, then ``kills`` times
    more, each run before a random journal write of its own; then run it to the end. ``writes``: an
    uninterrupted run's (:class:`Writes`). About a third of the kills come among a resumed run's first
    :data:`STARTUP_WRITES` writes (its start-up), the rest after a random number of further writes (each
    run gets part of the way)."""
    rng = random.Random(seed)
    stats = {"creation": 0, "startup": 0, "running": 0, "progress": []}
    for at in (1, rng.randint(2, writes.creation))[:creation]:
        _crash(monkeypatch, argv, at)
        assert not (out / JOURNAL_NAME).exists() and Journal.partial_paths(out / JOURNAL_NAME)
        stats["creation"] += 1
    most = max(4, (writes.count - writes.creation) // (2 * kills))
    while stats["startup"] + stats["running"] < kills:
        if (out / JOURNAL_NAME).exists() and rng.random() < 0.3:
            _crash(monkeypatch, argv, rng.randint(1, STARTUP_WRITES))
            stats["startup"] += 1
        else:
            created = 0 if (out / JOURNAL_NAME).exists() else writes.creation
            _crash(monkeypatch, argv, created + STARTUP_WRITES + rng.randint(1, most))
            stats["running"] += 1
        stats["progress"].append(_done(out))
    assert main(argv) == 0
    assert not Journal.partial_paths(out / JOURNAL_NAME)   # the killed creation's files are gone
    return stats


def _crashed_equals_uninterrupted(tmp_path, monkeypatch, material, grid, config, kills, seed,
                                  creation=2, reference=None) -> dict:
    """Run the campaign once to the end and once crashed ``creation`` + ``kills`` times (at least a third
    of the kills mid-campaign) and resumed, in this process; see :func:`_equal_to`. ``reference``: the
    (folder, :class:`Writes`) of the uninterrupted run of these arguments when one is at hand."""
    out = tmp_path / "crashed"
    ref, writes = reference or (tmp_path / "ref", None)
    if writes is None:
        writes = _uninterrupted(monkeypatch, _argv(material, grid, ref, config))
    stats = _crash_and_resume(monkeypatch, _argv(material, grid, out, config), out, kills=kills, seed=seed,
                              writes=writes, creation=creation)
    assert stats["running"] >= kills // 3 and len(set(stats["progress"])) >= kills // 3, stats
    return _equal_to(ref, out)


@pytest.mark.slow
def test_crashes_at_random_journal_writes_then_resume_equal_an_uninterrupted_run(tmp_path, monkeypatch):
    # Chunks of 8 steps (one transaction each): ~40 commits a run, so the random crashes fall mid-campaign,
    # and a crash inside a chunk loses it and the resumed run measures it again, bit for bit.
    monkeypatch.setattr(sim_detector, "CAMPAIGN_CHUNK", 8)
    _crashed_equals_uninterrupted(tmp_path, monkeypatch, "ggx:alpha=0.15,metal=gold", "iso:step=15",
                                  _config(tmp_path), kills=10, seed=1)


@pytest.mark.slow
def test_crashes_with_a_drifting_lamp_and_dark_offset_match_the_truth_within_its_uncertainty(tmp_path,
                                                                                             monkeypatch):
    config = _config(tmp_path, drift_per_hour=-0.3, dark_offset=2.0, shot_counts_per_unit=50.0,
                     read_sigma=0.05, radiance=1e6)
    # Long enough for the lamp to drift (iso:step=10: 17 minutes); the creation's crashes: the test above.
    b = _crashed_equals_uninterrupted(tmp_path, monkeypatch, "lambert:albedo=0.5", "iso:step=10", config,
                                      kills=10, seed=2, creation=0)
    # The lamp lost several percent over the campaign; the references track it.
    assert b["campaign_s"].max() > 600.0
    z = (b["value"] - 0.5 / np.pi) / b["stddev"]
    assert 0.8 < np.std(z) < 1.25 and abs(np.mean(z)) < 1.0
    assert np.mean(np.abs(z) < 3.0) > 0.99


def test_a_fly_campaign_crashed_at_random_journal_writes_resumes_to_the_uninterrupted_result(tmp_path,
                                                                                              monkeypatch,
                                                                                              shared_reference):
    """The same for on-the-fly scanning (one journal transaction per sweep): a crash loses at most the
    sweep in flight, and the resumed campaign is the uninterrupted one bit for bit. Most of its lines
    are in serpentine passes (entered through a swept turnaround from the line before), so the crashes
    cut passes: a resumed pass starts at its first line with no reading, moved to at rest."""
    from gonio.fly.plans import fly_plans

    material, grid = "ward:rho_d=0.1,rho_s=0.05,alpha=0.15", "iso:step=15,order=fly"
    config, reference = shared_reference(material, grid)   # the SIGKILLed fly campaign's as well
    _, fp = fly_plans(grid, load_config(config))
    turned = sum(fp.swept_turn(k) for k in range(len(fp.lines)))
    assert turned >= 0.3 * len(fp.lines)
    b = _crashed_equals_uninterrupted(tmp_path, monkeypatch, material, grid, config, kills=6, seed=4,
                                      creation=1, reference=reference)
    assert len(b["value"]) == 304   # every pose of iso:step=15


# -- one real SIGKILL per path ---------------------------------------------------------------------------

GONIO = [sys.executable, "-m", "gonio.cli"]
#: Upper bound on one whole run of these small campaigns (start-up included), for every wait below.
RUN_LIMIT_S = 120.0


def _kill_during_creation(argv, out: Path) -> bool:
    """Start the command and SIGKILL it while the journal is being built (its temporary file exists), or
    as soon as the journal exists. True when it was caught in the creation's window (a short one)."""
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
            time.sleep(0.0002)  # polling what another process writes; bounded by the deadline
        assert p.poll() is None, "the run finished before its kill"
    finally:
        p.kill()
        p.wait(timeout=RUN_LIMIT_S)
    return caught


def _kill_after_steps(argv, out: Path, steps: int) -> None:
    """Start the command and SIGKILL it once ``steps`` more steps are committed (watched through a
    read-only journal connection)."""
    start = _done(out)
    p = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + RUN_LIMIT_S
    try:
        while p.poll() is None and time.monotonic() < deadline and _done(out) < start + steps:
            time.sleep(0.001)  # polling what another process writes; bounded by the deadline
        assert p.poll() is None, "the run finished before its kill"
        os.kill(p.pid, signal.SIGKILL)
    finally:
        p.wait(timeout=RUN_LIMIT_S)
    assert start + steps <= _done(out) < Journal.open(out / JOURNAL_NAME, readonly=True).step_count()


def _sigkilled_equals_uninterrupted(tmp_path, monkeypatch, material, grid, steps, shared=None,
                                   creation=False) -> None:
    """``gonio simulate`` as a process, SIGKILLed during the journal's creation (or just after it) when
    ``creation``, then after ``steps`` committed steps; then the same command run to the end in this
    process (what resumes is the journal the killed process left): bit for bit the uninterrupted run
    (made in this process). ``shared``: a :func:`shared_reference` to take the config and that run from."""
    out = tmp_path / "killed"
    if shared is not None:
        config, (ref, _) = shared(material, grid)
    else:
        config, ref = _config(tmp_path), tmp_path / "ref"
        _uninterrupted(monkeypatch, _argv(material, grid, ref, config))
    argv = _argv(material, grid, out, config)
    if creation:
        _kill_during_creation([*GONIO, *argv], out)
    _kill_after_steps([*GONIO, *argv], out, steps)
    assert main(argv) == 0
    assert not Journal.partial_paths(out / JOURNAL_NAME)
    _equal_to(ref, out)


@pytest.mark.slow
def test_sigkill_during_creation_and_mid_campaign_then_resume_equals_an_uninterrupted_run(tmp_path,
                                                                                          monkeypatch):
    _sigkilled_equals_uninterrupted(tmp_path, monkeypatch, "ggx:alpha=0.15,metal=gold", "iso:step=15", 10,
                                    creation=True)


@pytest.mark.slow
def test_a_sigkilled_fly_campaign_resumes_to_the_uninterrupted_result(tmp_path, monkeypatch,
                                                                    shared_reference):
    _sigkilled_equals_uninterrupted(tmp_path, monkeypatch, "ward:rho_d=0.1,rho_s=0.05,alpha=0.15",
                                    "iso:step=15,order=fly", 3, shared=shared_reference)


# -- adaptive campaigns: rounds planned from the journal ------------------------------------------------

ADAPTIVE_GRID = "adaptive:poses=45"
#: (material, grid, poses) of the adaptive cases, each with four rounds or more: isotropic, and
#: anisotropic (4D: a 21-pose full:step=60 pilot, then rounds).
ADAPTIVE_CASES = [("ggx:alpha=0.15,metal=gold", ADAPTIVE_GRID, 45),
                  ("ward:rho_d=0.1,rho_s=0.05,alpha_x=0.1,alpha_y=0.3", "adaptive:poses=75,anisotropic=true",
                   75)]


@pytest.fixture(scope="module")
def shared_reference(tmp_path_factory):
    """``shared_reference(material, grid)``: the default config and the uninterrupted run of
    ``gonio simulate material --grid grid`` (seed 3) on it, made once for this module, and once per run
    under pytest-xdist (tests/built_once.py): (config, (folder, :class:`Writes`)). Only read by the tests
    that compare with it (an adaptive campaign's costs seconds)."""
    made = {}

    def build(material, grid, folder):
        config, ref = _config(folder), folder / "ref"
        with pytest.MonkeyPatch.context() as m:
            return config, (ref, _uninterrupted(m, _argv(material, grid, ref, config)))

    def reference(material, grid):
        if (material, grid) not in made:
            name = "kill-reference-" + re.sub(r"[^A-Za-z0-9]+", "-", f"{material}-{grid}")
            made[material, grid] = built_once(tmp_path_factory, name,
                                              lambda folder: build(material, grid, folder))
        return made[material, grid]
    return reference


@pytest.mark.parametrize("material, grid, poses", ADAPTIVE_CASES, ids=["iso", "anisotropic"])
def test_an_adaptive_campaign_crashed_at_random_journal_writes_resumes_to_the_uninterrupted_result(
        tmp_path, monkeypatch, shared_reference, material, grid, poses):
    """Kills at random journal writes, the round appends among them (a kill inside one leaves no part of
    the round): the resumed campaign plans the same rounds and ends bit for bit the uninterrupted one."""
    config, reference = shared_reference(material, grid)
    b = _crashed_equals_uninterrupted(tmp_path, monkeypatch, material, grid, config, kills=8, seed=5,
                                      creation=1, reference=reference)
    assert len(b["value"]) == poses


@pytest.mark.parametrize("material, grid, poses", ADAPTIVE_CASES, ids=["iso", "anisotropic"])
def test_an_adaptive_campaign_killed_while_it_plans_a_round_resumes_to_the_uninterrupted_result(
        tmp_path, monkeypatch, shared_reference, material, grid, poses):
    """A death in the middle of planning each round (nothing of it journaled), then the same command
    again: the round is planned again from the journal, and the result is the uninterrupted run's."""
    import gonio.adaptive.plan as adaptive_plan

    config, (ref, _) = shared_reference(material, grid)
    out = tmp_path / "crashed"
    argv = _argv(material, grid, out, config)
    plan_round = adaptive_plan.plan_round
    rounds, dying, appends = [], [], []
    append = Journal.append_steps

    def counted_append(journal, *args, **kwargs):
        appends.append(1)
        return append(journal, *args, **kwargs)

    def dies_after_planning(*args, **kwargs):
        plan_round(*args, **kwargs)   # the whole round planned, then the process dies before the append
        rounds.append(_done(out))
        dying[0].die()

    for _ in range(4):   # a death in each of the four rounds
        with monkeypatch.context() as m, crash_at_write(monkeypatch, None) as writes:
            dying[:] = [writes]
            m.setattr(adaptive_plan, "plan_round", dies_after_planning)
            with pytest.raises(Crash):
                main(argv)
        assert _rounds(out) == len(rounds) - 1      # the round in planning was not journaled
        # The next run plans it again and dies inside the transaction that appends it (its second write):
        # none of it is journaled; the one after gets it whole and dies among its steps.
        appends.clear()
        with monkeypatch.context() as m:
            m.setattr(Journal, "append_steps", counted_append)
            _crash(monkeypatch, argv, STARTUP_WRITES + 2)
        assert appends == [1] and _rounds(out) == len(rounds) - 1
        _crash(monkeypatch, argv, STARTUP_WRITES + 6)
        assert _rounds(out) == len(rounds)
    assert main(argv) == 0
    assert len(set(rounds)) == 4   # each death came at another round
    assert _rounds(out) >= 4 and len(_equal_to(ref, out)["value"]) == poses


def _rounds(out: Path) -> int:
    j = Journal.open(out / JOURNAL_NAME, readonly=True)
    try:
        return len(j.meta()["adaptive"]["rounds"])
    finally:
        j.close()


@pytest.mark.slow
def test_a_sigkilled_adaptive_campaign_resumes_to_the_uninterrupted_result(tmp_path, monkeypatch,
                                                                         shared_reference):
    """The adaptive path's real SIGKILL (the isotropic case; the anisotropic one's crashes are the
    in-process ones above, at random writes and while planning each round)."""
    material, grid, _ = ADAPTIVE_CASES[0]
    _sigkilled_equals_uninterrupted(tmp_path, monkeypatch, material, grid, 10, shared=shared_reference)
