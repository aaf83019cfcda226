"""An adaptive campaign whose round finds no reachable new pose: a gantry whose light arm cannot tilt
(±0.001°, the light at the zenith) reaches only poses with θi = 0 or, through the Helmholtz twin, θo = 0,
a set of measure zero that no trial point and no random pair of the rounds lands on. The campaign ends
cleanly after its pilot: the reason journaled with the round's append (one transaction), shown by
``gonio simulate``, ``gonio status`` and the report; a kill at any write around the end resumes to the
same end; never a latched fault, a hang or a traceback."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest
from journal_crash import Crash, crash_at_write
from zenith_gantry import zenith_light_config

from gonio.adaptive import acquire, material_measure, plan_round
from gonio.cli import main
from gonio.config import load_config
from gonio.kinematics import make_kinematics
from gonio.sim.materials import load
from gonio.store import JOURNAL_NAME, Journal

MATERIAL = "ggx:alpha=0.2,metal=gold"
GRID = "adaptive:poses=100"
REASON = ("round 1 found no reachable new pose (the gantry's reach, its occlusion cone and theta_max leave "
          "none): ended with 10 poses of a budget of 100 poses")


@pytest.fixture(scope="module")
def config(tmp_path_factory):
    return zenith_light_config(tmp_path_factory.mktemp("gantry"))


def _argv(out, config):
    return ["simulate", MATERIAL, "--grid", GRID, "--out", str(out), "--config", str(config), "--seed", "3"]


def _journal(out):
    j = Journal.open(out / JOURNAL_NAME, readonly=True)
    try:
        return j.meta(), j.step_count(), j.done_count(), j.last_event("append")
    finally:
        j.close()


def test_the_round_finds_nothing_and_the_library_run_ends_after_its_pilot(config):
    kin = make_kinematics(load_config(config))
    tmax = np.radians(80.0)
    acq = acquire(material_measure(load(MATERIAL)), kin, tmax, 100)
    assert acq.ended == 1 and acq.phases == (len(acq.samples),) and len(acq.samples) == 10
    assert np.all(acq.samples.theta_i == 0.0)          # the pilot: the light at the zenith only
    ti, to, d = plan_round(acq.samples, 10, kin, tmax)
    assert ti.size == to.size == d.size == 0


def test_a_round_with_no_reachable_pose_ends_the_campaign_cleanly(config, tmp_path, capsys):
    out = tmp_path / "c"
    assert main(_argv(out, config)) == 0
    said = capsys.readouterr()
    assert f"ended short of its budget: {REASON}" in said.err   # the run's progress lines
    assert "Traceback" not in said.out + said.err and "fault" not in said.err
    meta, steps, done, append = _journal(out)
    assert meta["adaptive"]["ended"] == {"round": 1, "reason": REASON} and meta["adaptive"]["rounds"] == []
    assert steps == done == 14 and append["message"] == REASON and append["step"] == 14
    assert meta.get("latched_fault") is None
    with h5py.File(out / "brdf.h5", "r") as f:
        assert f["samples"]["value"].shape[0] == 10
    # gonio status: done, 100 %, and why it ended short
    assert main(["status", str(out)]) == 0
    said = capsys.readouterr().out
    assert ": done" in said and "14/14 steps (100.0 %)" in said
    assert f"ended short of its budget: {REASON}" in said
    assert main(["status", str(out), "--json"]) == 0
    st = json.loads(capsys.readouterr().out)
    assert st["ended_short"] == REASON and st["steps"] == st["steps_done"] == 14
    # the report says it too
    from html import escape

    from gonio.report import build_report

    rep = build_report(out, "lambert", starts=1)
    assert "ended short of the budget" in rep.html and escape(REASON) in rep.html
    # and the same command again: complete, nothing more planned
    assert main(_argv(out, config)) == 0
    assert "is complete" in capsys.readouterr().err
    assert _journal(out)[1] == 14


def test_a_kill_at_any_write_around_the_end_resumes_to_the_same_end(config, tmp_path, monkeypatch):
    """The end is appended as a round is (steps, meta and event in one transaction): a kill before it,
    inside it or after it, then the same command, gives the uninterrupted run's journal end and brdf.h5."""
    ref = tmp_path / "ref"
    append = Journal.append_steps
    at = []
    with crash_at_write(monkeypatch, None) as writes:
        def counted(journal, *args, **kwargs):
            at.append(writes.count)
            return append(journal, *args, **kwargs)

        monkeypatch.setattr(Journal, "append_steps", counted)
        assert main(_argv(ref, config)) == 0
        total = writes.count
    monkeypatch.setattr(Journal, "append_steps", append)
    assert len(at) == 1
    with h5py.File(ref / "brdf.h5", "r") as f:
        truth = {k: f["samples"][k][()] for k in f["samples"]}
    ends = []
    # the last write before the append, its 3 writes, the first after it
    for k, crash in enumerate(range(at[0], min(at[0] + 5, total + 1))):
        out = tmp_path / f"k{k}"
        with crash_at_write(monkeypatch, crash), pytest.raises(Crash):
            main(_argv(out, config) + ["--quiet"])
        ends.append(_journal(out)[0]["adaptive"].get("ended"))
        assert main(_argv(out, config) + ["--quiet"]) == 0
        meta, steps, done, _ = _journal(out)
        assert meta["adaptive"] == _journal(ref)[0]["adaptive"] and steps == done == 14
        with h5py.File(out / "brdf.h5", "r") as f:
            for key, value in truth.items():
                np.testing.assert_array_equal(f["samples"][key][()], value, err_msg=key)
    # the kills came before the end was journaled and after it: both resumed to it
    assert ends[0] is None and ends[-1] is not None


def test_an_end_after_rounds_without_a_closing_checkpoint_appends_one(config, tmp_path):
    """Checkpoints as needed leave a round's readings without a reference after them until a later round
    closes: an end found then appends the checkpoint (a dark where the gantry stands, the white
    reference as the journal's first checkpoint read it) with the reason."""
    from gonio.adaptive.plan import next_round
    from gonio.campaign import open_campaign
    from gonio.plan.schedule import STEP_DARK, STEP_REFERENCE

    out = tmp_path / "c"
    assert main(_argv(out, config) + ["--quiet"]) == 0
    c = open_campaign(out)
    try:
        a = c.meta["adaptive"]
        c.journal.set_meta("adaptive", {**{k: v for k, v in a.items() if k != "ended"},
                                        "since_reference_s": 12.5})
        journaled = c.journal.steps()
        steps, meta, line = next_round(c.journal, c.cfg)
    finally:
        c.close()
    assert steps["kind"].tolist() == [STEP_DARK, STEP_REFERENCE] and steps["pose"].tolist() == [-1, -1]
    np.testing.assert_array_equal(steps["axes_deg"][0], journaled["axes_deg"][-1])
    np.testing.assert_array_equal(steps["axes_deg"][1], journaled["axes_deg"][1])
    assert meta["adaptive"]["since_reference_s"] == 0.0 and meta["adaptive"]["ended"]["reason"] == REASON
    assert line == REASON
