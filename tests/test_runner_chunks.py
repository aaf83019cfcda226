"""Stop-and-go campaigns on a detector that reads in batches (the simulated one): a chunk of steps is
taken, then developed in one launch and committed in one transaction. Every reading, retry and fault is
the one a campaign measured one step a unit gets, bit for bit; requests act before the next step."""

import numpy as np
import pytest

from gonio.campaign import create_campaign
from gonio.config import load_config
from gonio.runner import Runner, State
from gonio.wiring import build_gantry

GRID = "iso:step=30,order=serpentine"  # 30 steps, every kind


@pytest.fixture
def cfg():
    return load_config()


def _campaign(tmp_path, cfg, name, chunk, material="ggx:alpha=0.2,metal=gold"):
    c = create_campaign(tmp_path / name, cfg, grid=GRID, material=material, seed=7)
    g = build_gantry(cfg, material, seed=7)
    g.detector.chunk = chunk
    g.connect()
    return c, g, Runner(g, c.journal, cfg)


def _arm(r, g, faults):
    """Arm ``faults[k]`` = (axis, kind) on the k-th move to a step (counted alike in every mode)."""
    goto, calls = r.executor.goto, []

    def counting(target):
        calls.append(1)
        if len(calls) in faults:
            axis, kind = faults[len(calls)]
            g.axes[axis].fail_next(kind)
        return goto(target)
    r.executor.goto = counting


def _journal(c):
    rows = [(m.step, m.attempts, m.signal.tobytes(), m.stderr.tobytes(), m.actual_deg.tobytes(), m.clock_s,
             m.campaign_s, m.extra["reading"]) for m in c.journal.measurements()]
    events = [(e["kind"], e.get("step"), e.get("message")) for e in c.journal.events()
              if e["kind"] in ("retry", "fault", "state")]
    return rows, events


def test_chunks_equal_one_step_a_unit_bit_for_bit_retries_included(tmp_path, cfg):
    faults = {3: ("light_tilt", "timeout"), 9: ("detector_tilt", "timeout"), 10: ("detector_tilt", "timeout")}
    out = {}
    for chunk in (1, 4, 64):
        c, g, r = _campaign(tmp_path, cfg, f"c{chunk}", chunk)
        assert (r.executor.abilities.batches is not None) == (chunk > 1)
        _arm(r, g, faults)
        assert r.run() == State.DONE
        out[chunk] = _journal(c)
        steps = c.journal.step_count()
        c.close()
    rows, events = out[1]
    assert [row[0] for row in rows] == list(range(steps))
    assert sum(1 for e in events if e[0] == "retry") == 3     # the faults happened, mid-chunk too
    assert any(row[1] == 2 for row in rows) and any(row[1] == 3 for row in rows)
    assert out[4] == out[1]
    assert out[64] == out[1]


def test_a_pause_during_a_chunk_acts_before_the_next_step_and_resumes_bit_for_bit(tmp_path, cfg):
    c0, _, r0 = _campaign(tmp_path, cfg, "whole", 64)
    assert r0.run() == State.DONE
    c, g, r = _campaign(tmp_path, cfg, "paused", 64)
    take = r.reader.take

    def pausing(step, attempt, detector):
        taken = take(step, attempt, detector)
        if step == 5:
            r.request_pause()
        return taken
    r.reader.take = pausing
    assert r.run() == State.PAUSED
    assert c.journal.done_steps().tolist() == list(range(6))   # the chunk's steps up to the request
    r.reader.take = take
    g2 = build_gantry(cfg, "ggx:alpha=0.2,metal=gold", seed=7)
    g2.connect()
    assert Runner(g2, c.journal, cfg).run() == State.DONE
    a, b = c0.journal.measurements(), c.journal.measurements()
    assert [m.step for m in a] == [m.step for m in b]
    for x, y in zip(a, b, strict=True):
        assert np.array_equal(x.signal, y.signal) and np.array_equal(x.stderr, y.stderr)
        assert np.array_equal(x.actual_deg, y.actual_deg)


def test_a_hardware_fault_mid_chunk_commits_the_steps_before_it_and_latches(tmp_path, cfg):
    c, g, r = _campaign(tmp_path, cfg, "c", 64)
    _arm(r, g, {6: ("light_tilt", "hardware")})
    assert r.run() == State.FAULTED
    assert "light_tilt" in r.fault
    done = c.journal.done_steps().tolist()
    assert done == list(range(len(done))) and 0 < len(done) < c.journal.step_count()
    assert c.journal.latched_fault() is not None
