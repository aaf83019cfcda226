"""The runner on the simulated gantry: state machine, faults, retries, pause/resume/abort, parking."""

import numpy as np
import pytest

from gonio.campaign import create_campaign
from gonio.config import load_config
from gonio.runner import TRANSITIONS, Runner, State, TransitionError
from gonio.wiring import build_gantry

GRID = "iso:step=45"  # 3 θ values x 8 Δφ: a handful of poses, every step kind


@pytest.fixture
def cfg():
    return load_config()


def _setup(tmp_path, cfg, material="lambert:albedo=0.5", on_step=None):
    c = create_campaign(tmp_path / "c", cfg, grid=GRID, material=material, seed=1)
    g = build_gantry(cfg, material, seed=1)
    g.connect()
    return c, g, Runner(g, c.journal, cfg, on_step=on_step)


def _events(c, kind):
    return [e for e in c.journal.events() if e["kind"] == kind]


def test_transition_table_is_closed_and_terminal_states_are_final():
    for dsts in TRANSITIONS.values():
        assert set(dsts) <= set(State)
    assert TRANSITIONS[State.DONE] == frozenset() and TRANSITIONS[State.ABORTED] == frozenset()
    # a pause is only ever left by resuming or aborting, never straight to done
    assert TRANSITIONS[State.PAUSED] == frozenset({State.RUNNING, State.ABORTED})
    assert set(TRANSITIONS) == set(State)


def test_runs_to_done_one_measurement_per_step_and_parks(tmp_path, cfg):
    c, g, r = _setup(tmp_path, cfg)
    assert r.run() == State.DONE
    n = c.journal.step_count()
    assert c.journal.done_steps().tolist() == list(range(n))
    home = np.array([cfg.axes[a].home_deg for a in cfg.axis_names])
    np.testing.assert_allclose([g.axes[a].position_deg() for a in cfg.axis_names], home, atol=1e-9)
    assert not g.light.is_on()
    states = [e["state"] for e in _events(c, "state")]
    assert states == ["running", "done"]
    with pytest.raises(TransitionError, match="campaign is done"):
        r.run()


def test_commanded_and_actual_positions_are_both_recorded(tmp_path, cfg):
    c, g, r = _setup(tmp_path, cfg)
    r.run()
    for m in c.journal.measurements():
        assert m.actual_deg.shape == m.commanded_deg.shape == (4,)
        assert np.all(np.abs(m.actual_deg - m.commanded_deg) <= cfg.runner.position_tolerance_deg)


def test_pause_at_a_step_boundary_then_resume(tmp_path, cfg):
    def on_step(runner, step):
        if step == 4:
            runner.request_pause()

    c, g, r = _setup(tmp_path, cfg, on_step=on_step)
    assert r.run() == State.PAUSED
    assert c.journal.done_steps().tolist() == [0, 1, 2, 3, 4]
    r.on_step = None
    assert r.run() == State.DONE
    assert c.journal.done_steps().size == c.journal.step_count()
    assert [e["state"] for e in _events(c, "state")] == ["running", "paused", "running", "done"]
    assert len(_events(c, "pause")) == 1


def test_abort_at_a_step_boundary(tmp_path, cfg):
    def on_step(runner, step):
        if step == 2:
            runner.request_abort()

    c, g, r = _setup(tmp_path, cfg, on_step=on_step)
    assert r.run() == State.ABORTED
    assert c.journal.done_steps().tolist() == [0, 1, 2]
    with pytest.raises(TransitionError):
        r.run()


def test_abort_while_paused_is_immediate(tmp_path, cfg):
    c, g, r = _setup(tmp_path, cfg, on_step=lambda run, s: run.request_pause())
    assert r.run() == State.PAUSED
    r.request_abort()
    assert r.state == State.ABORTED


@pytest.mark.parametrize("kind", ["timeout", "stall"])
def test_transient_faults_are_retried(tmp_path, cfg, kind):
    c, g, r = _setup(tmp_path, cfg)
    g.axes["detector_tilt"].fail_next(kind)
    assert r.run() == State.DONE
    retries = _events(c, "retry")
    assert len(retries) == 1
    if kind == "stall":
        assert "position_tolerance_deg" in retries[0]["message"]
    assert sorted(m.attempts for m in c.journal.measurements())[-1] == 2
    assert c.journal.done_steps().size == c.journal.step_count()


def test_retries_exhausted_is_a_fault(tmp_path, cfg):
    c, g, r = _setup(tmp_path, cfg)
    g.axes["light_tilt"].fail_next("timeout", times=cfg.runner.retries + 1)
    assert r.run() == State.FAULTED
    assert "light_tilt" in r.fault
    assert len(_events(c, "retry")) == cfg.runner.retries


def test_hardware_fault_stops_faults_and_resumes_after_clearing(tmp_path, cfg):
    c, g, r = _setup(tmp_path, cfg)
    axis = g.axes["detector_azimuth"]
    # Fault on the 3rd move command of the campaign.
    real_move = axis.move_to
    calls = {"n": 0}

    def move_to(t):
        calls["n"] += 1
        if calls["n"] == 3:
            axis.fail_next("hardware")
        real_move(t)

    axis.move_to = move_to
    assert r.run() == State.FAULTED
    assert "detector_azimuth" in r.fault
    assert not any(a.is_moving() for a in g.axes.values())
    done = c.journal.done_steps().size
    assert 0 < done < c.journal.step_count()
    assert any("park failed" in e["message"] for e in _events(c, "fault"))  # the axis refuses to move
    axis.clear_fault()
    assert r.run() == State.DONE
    assert c.journal.done_steps().tolist() == list(range(c.journal.step_count()))
    assert [e["state"] for e in _events(c, "state")] == ["running", "faulted", "running", "done"]


def test_limit_violation_in_a_journal_is_a_fault_with_the_axis_name(tmp_path, cfg):
    c, g, r = _setup(tmp_path, cfg)
    r._steps["axes_deg"][3, 1] = 97.0  # a corrupted plan: light_tilt beyond its limit
    with pytest.raises(ValueError, match="light_tilt"):
        r.run()
    assert r.state == State.FAULTED
    assert "97" in r.fault


def test_pause_and_abort_requests_from_another_thread(tmp_path, cfg):
    """The daemon asks from its own thread; the request must reach the runner and the journal."""
    import threading

    def on_step(runner, step):
        if step == 1:
            t = threading.Thread(target=runner.request_pause)
            t.start()
            t.join(timeout=10)
            assert not t.is_alive()

    c, g, r = _setup(tmp_path, cfg, on_step=on_step)
    assert r.run() == State.PAUSED
    assert len(_events(c, "pause")) == 1
    t = threading.Thread(target=r.request_abort)
    t.start()
    t.join(timeout=10)
    assert r.state == State.ABORTED
    assert [e["state"] for e in _events(c, "state")][-1] == "aborted"
