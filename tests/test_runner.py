"""The runner on the simulated gantry: state machine, faults, retries, pause/resume/abort/halt, parking."""

import threading

import numpy as np
import pytest

from gonio.campaign import create_campaign
from gonio.clock import VirtualClock
from gonio.config import load_config, parse_config
from gonio.plan import STEP_POSE
from gonio.protocols import DeviceFault
from gonio.runner import TRANSITIONS, Runner, State, TransitionError
from gonio.store import Journal
from gonio.wiring import build_gantry

GRID = "iso:step=45,order=serpentine"  # 3 θ values x 8 Δφ: a handful of poses, every step kind


@pytest.fixture
def cfg():
    return load_config()


def _setup(tmp_path, cfg, material="lambert:albedo=0.5", on_step=None):
    c = create_campaign(tmp_path / "c", cfg, grid=GRID, material=material, seed=1)
    g = build_gantry(cfg, material, seed=1)
    g.connect()
    if on_step is not None:
        # Requests timed by the step committed: one step a unit (the simulated detector would take a
        # chunk of steps a unit; tests/test_runner_chunks.py times its requests within a chunk).
        g.detector.chunk = 1
    return c, g, Runner(g, c.journal, cfg, on_step=on_step)


def _events(c, kind):
    return [e for e in c.journal.events() if e["kind"] == kind]


def test_transition_table_is_closed_and_terminal_states_are_final():
    for dsts in TRANSITIONS.values():
        assert set(dsts) <= set(State)
    assert TRANSITIONS[State.DONE] == frozenset() and TRANSITIONS[State.ABORTED] == frozenset()
    # a pause or a halt is only ever left by resuming or aborting, never straight to done; a pause is
    # halted while it parks (a second Ctrl-C)
    assert TRANSITIONS[State.PAUSED] == frozenset({State.RUNNING, State.ABORTED, State.HALTED})
    assert TRANSITIONS[State.HALTED] == frozenset({State.RUNNING, State.ABORTED})
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


def test_a_halt_while_the_pause_parks_ends_halted_with_the_axes_where_they_stopped(tmp_path, cfg):
    """A second Ctrl-C: the first pauses, the second arrives while the gantry parks. It used to log a
    fault 'park failed: ' with an empty reason and end 'paused'."""
    c, g, r = _setup(tmp_path, cfg, on_step=lambda run, s: s == 3 and run.request_pause())
    for axis in g.axes.values():
        def move_to(t, real=axis.move_to):
            real(t)
            if r.state == State.PAUSED:      # the park's first command has gone out: halt now
                r.request_halt("second SIGINT")

        axis.move_to = move_to
    assert r.run() == State.HALTED
    assert c.journal.done_steps().tolist() == [0, 1, 2, 3]
    faults = _events(c, "fault")
    assert faults == [], faults
    stopped = _events(c, "stopped")
    assert len(stopped) == 1 and "halted while parking" in stopped[0]["message"]
    assert _events(c, "park") == []
    assert c.journal.last_event("state")["state"] == "halted"
    home = np.asarray(g.kinematics.home_deg, float)
    assert not np.allclose(stopped[0]["axes_deg"], home)     # stopped on the way, not parked
    assert not any(a.is_moving() for a in g.axes.values())
    # and it resumes from where it stopped
    r.on_step = None
    assert r.run() == State.DONE


def test_timeout_is_retried_after_the_axes_are_still(tmp_path, cfg):
    c, g, r = _setup(tmp_path, cfg)
    g.axes["detector_tilt"].fail_next("timeout")
    seen = {"timed_out": False, "moving_at_retry": None}
    for axis in g.axes.values():
        real = axis.move_to

        def move_to(t, real=real):
            if seen["timed_out"] and seen["moving_at_retry"] is None:
                seen["moving_at_retry"] = [a.name for a in g.axes.values() if a.is_moving()]
            try:
                real(t)
            except DeviceFault:
                seen["timed_out"] = True
                raise

        axis.move_to = move_to
    assert r.run() == State.DONE
    assert len(_events(c, "retry")) == 1
    assert sorted(m.attempts for m in c.journal.measurements())[-1] == 2
    assert c.journal.done_steps().size == c.journal.step_count()
    # The axes commanded before the time-out were braking; the retry waited until all were still.
    assert seen["moving_at_retry"] == []


def test_an_axis_that_stops_short_is_a_latched_fault_never_a_silent_retry(tmp_path, cfg):
    c, g, r = _setup(tmp_path, cfg)
    g.axes["detector_tilt"].fail_next("stall")
    assert r.run() == State.FAULTED
    assert "detector_tilt" in r.fault and "short of its target" in r.fault
    assert _events(c, "retry") == []
    assert c.journal.latched_fault()["devices"] == ["detector_tilt"]
    assert r.run() == State.FAULTED  # latched: nothing runs until an operator clears it
    r.clear_fault()
    assert r.run() == State.DONE


def test_retries_exhausted_is_a_fault(tmp_path, cfg):
    c, g, r = _setup(tmp_path, cfg)
    g.axes["light_tilt"].fail_next("timeout", times=cfg.runner.retries + 1)
    assert r.run() == State.FAULTED
    assert "light_tilt" in r.fault and f"gave up after {cfg.runner.retries} retries" in r.fault
    assert len(_events(c, "retry")) == cfg.runner.retries


def test_hardware_fault_stops_leaves_axes_and_stays_latched_across_a_restart(tmp_path, cfg):
    c, g, r = _setup(tmp_path, cfg)
    axis = g.axes["detector_azimuth"]
    real_move = axis.move_to
    calls = {"n": 0}

    def move_to(t):
        calls["n"] += 1
        if calls["n"] == 3:
            axis.fail_next("hardware")
        real_move(t)

    axis.move_to = move_to
    assert r.run() == State.FAULTED
    assert "detector_azimuth" in r.fault and "overload" in r.fault
    assert not any(a.is_moving() for a in g.axes.values())
    done = c.journal.done_steps().size
    assert 0 < done < c.journal.step_count()
    # Left where they are: no park after a fault.
    assert _events(c, "park") == [] and _events(c, "stopped")
    # A new process (new runner, new simulated gantry whose power cycle cleared the servo's error bit)
    # still finds the fault latched in the journal and refuses to move.
    g2 = build_gantry(cfg, "lambert:albedo=0.5", seed=1)
    g2.connect()
    r2 = Runner(g2, c.journal, cfg)
    assert r2.state == State.FAULTED and "overload" in r2.fault
    commands = []
    for a in g2.axes.values():
        a.move_to = lambda t, a=a: commands.append(a.name)
    assert r2.run() == State.FAULTED and commands == []
    assert c.journal.done_steps().size == done
    r.clear_fault()  # the operator
    assert [e["kind"] for e in c.journal.events()].count("fault-cleared") == 1
    assert r.run() == State.DONE
    assert c.journal.done_steps().tolist() == list(range(c.journal.step_count()))
    assert [e["state"] for e in _events(c, "state")] == ["running", "faulted", "running", "done"]


def test_limit_violation_in_a_journal_faults_before_any_axis_moves(tmp_path, cfg):
    c, g, r = _setup(tmp_path, cfg)
    r.reader.steps["axes_deg"][3, 1] = 97.0  # a corrupted plan: light_tilt beyond its limit
    assert r.run() == State.FAULTED
    assert "light_tilt" in r.fault and "97" in r.fault
    # Step 3 was refused before anything moved: the steps before it are committed (the chunk they were
    # taken in too), and the axes stand where step 2 left them.
    assert c.journal.done_steps().tolist() == [0, 1, 2]
    step2 = c.journal.measurements()[2].actual_deg
    assert [g.axes[n].position_deg() for n in cfg.axis_names] == step2.tolist()


def test_a_target_one_axis_rejects_stops_the_axes_commanded_before_it(tmp_path, cfg):
    c, g, r = _setup(tmp_path, cfg)
    commanded = {}
    for name in cfg.axis_names[:3]:
        axis = g.axes[name]
        real = axis.move_to

        def move_to(t, real=real, axis=axis):
            if not any(a.is_moving() for a in g.axes.values()):
                commanded.clear()  # a new batch of commands
            commanded[axis.name] = (axis.position_deg(), t)
            real(t)

        axis.move_to = move_to

    tilt = g.axes["detector_tilt"]
    real_tilt = tilt.move_to

    def refuse(t):  # detector_tilt is commanded last: refuse once the others are on their way
        if any(a.is_moving() for a in g.axes.values()):
            raise DeviceFault("detector_tilt", "refused: hardware error: input voltage")
        commanded.clear()
        real_tilt(t)

    tilt.move_to = refuse
    assert r.run() == State.FAULTED and "input voltage" in r.fault
    assert not any(a.is_moving() for a in g.axes.values())
    long_moves = {n: v for n, v in commanded.items() if abs(v[1] - v[0]) > 1.0}
    assert long_moves, "the refused batch should have sent some other axis on its way"
    for name, (start, _target) in long_moves.items():
        # Braked at once (at the very instant of the refusal): none went on toward its target.
        assert g.axes[name].position_deg() == pytest.approx(start, abs=1e-9)


class _HaltingClock(VirtualClock):
    """A virtual clock that calls ``hook(now)`` from inside the runner's sleeps."""

    def __init__(self):
        super().__init__()
        self.hook = None

    def sleep(self, seconds):
        super().sleep(seconds)
        if self.hook is not None:
            self.hook(self.now())


def _halt_setup(tmp_path, cfg):
    c = create_campaign(tmp_path / "c", cfg, grid=GRID, material="lambert:albedo=0.5", seed=1)
    clock = _HaltingClock()
    g = build_gantry(cfg, "lambert:albedo=0.5", seed=1, clock=clock)
    g.connect()
    return c, g, clock, Runner(g, c.journal, cfg)


def test_a_halt_is_journaled_once_even_if_the_run_ends_and_closes_its_journal_before_the_requester_can(
        tmp_path, cfg):
    """The requester tells the axes to stop, then journals the halt; meanwhile the engine can see the halt,
    end the run halted and its owner close the journal (the daemon's halt under load: "Cannot operate on
    a closed database", no halt event). Whichever thread comes first journals it, once, before the
    halted state."""
    c, g, clock, r = _halt_setup(tmp_path, cfg)
    closed, halting, errors = threading.Event(), threading.Event(), []
    stop_axes = r.executor.halt

    def halt_then_fall_behind():
        err = stop_axes()
        halting.set()
        assert closed.wait(timeout=10)      # the run ends and the journal closes before we go on
        return err

    def request():
        try:
            r.request_halt("emergency stop button")
        except Exception as err:            # noqa: BLE001 - reported by the assertion below
            errors.append(err)

    requester = threading.Thread(target=request)
    r.executor.halt = halt_then_fall_behind

    def hook(now):
        if now > 5.0 and requester.ident is None:
            requester.start()
            # the engine goes on once the axes are told to stop: without this wait a quick engine could
            # finish the campaign before the requester's thread ran at all (seen once on a loaded host)
            assert halting.wait(timeout=10)

    clock.hook = hook
    assert r.run() == State.HALTED
    clock.hook = None
    path = c.journal.path
    c.close()
    closed.set()
    requester.join(timeout=10)
    assert not requester.is_alive() and errors == []
    j = Journal.open(path, readonly=True)
    try:
        events = j.events()
    finally:
        j.close()
    halts = [e for e in events if e["kind"] == "halt"]
    assert [e["message"] for e in halts] == ["emergency stop button"]
    last_state = [e for e in events if e["kind"] == "state"][-1]
    assert last_state["state"] == "halted" and halts[0]["id"] < last_state["id"]


def test_halt_from_another_thread_stops_every_axis_mid_move(tmp_path, cfg):
    c, g, clock, r = _halt_setup(tmp_path, cfg)
    halted_at = {}
    commands_after = []

    def hook(now):
        moving = [a for a in g.axes.values() if a.is_moving()]
        if not halted_at and len(moving) >= 2 and now > 5.0:
            halted_at["t"] = now
            halted_at["targets"] = {a.name: a._motion.target_deg for a in moving}
            t = threading.Thread(target=r.request_halt, args=("emergency stop button",))
            t.start()
            t.join(timeout=10)
            assert not t.is_alive()
            for a in g.axes.values():
                a.move_to = lambda target, a=a: commands_after.append(a.name)

    clock.hook = hook
    assert r.run() == State.HALTED
    assert halted_at, "the campaign never had two axes moving at once"
    clock.hook = None
    # The runner noticed within one poll interval of the halt.
    halt_event = _events(c, "halt")[0]
    assert halt_event["message"] == "emergency stop button"
    state_event = _events(c, "state")[-1]
    assert state_event["state"] == "halted"
    assert state_event["campaign_s"] - halted_at["t"] <= cfg.runner.poll_s + 1e-9
    g.wait_until_still()
    for name, target in halted_at["targets"].items():
        assert abs(g.axes[name].position_deg() - target) > cfg.runner.position_tolerance_deg
    assert commands_after == []  # nothing further reached any axis: no park either
    assert _events(c, "park") == []
    assert not g.light.is_on()
    # A halted campaign resumes where it stopped and finishes.
    for a in g.axes.values():
        del a.move_to
    assert r.run() == State.DONE
    assert c.journal.done_steps().tolist() == list(range(c.journal.step_count()))


def test_a_stop_from_another_thread_is_a_fault_not_a_retry(tmp_path, cfg):
    c, g, clock, r = _halt_setup(tmp_path, cfg)
    fired = []

    def hook(now):
        if not fired and any(a.is_moving() for a in g.axes.values()) and now > 5.0:
            fired.append(now)
            t = threading.Thread(target=g.stop)  # someone else's client, not the runner's halt
            t.start()
            t.join(timeout=10)

    clock.hook = hook
    assert r.run() == State.FAULTED
    assert "short of its target" in r.fault and "stopped by another client" in r.fault
    assert _events(c, "retry") == []


def test_campaign_clock_continues_across_pause_and_resume(tmp_path, cfg):
    c, g, r = _setup(tmp_path, cfg, on_step=lambda run, s: s == 5 and run.request_pause())
    assert r.run() == State.PAUSED
    # A new process: a fresh gantry whose clock starts at 0 again.
    r.on_step = None
    g2 = build_gantry(cfg, "lambert:albedo=0.5", seed=1)
    g2.connect()
    assert g2.clock.now() == 0.0
    assert Runner(g2, c.journal, cfg).run() == State.DONE
    t = [m.campaign_s for m in c.journal.measurements()]
    assert all(b > a for a, b in zip(t, t[1:], strict=False))
    park = _events(c, "park")[0]
    assert t[5] < park["campaign_s"] < t[6]  # the pause parked, then the clock went on from there


def test_pause_parks_along_a_collision_free_path_home(tmp_path, cfg):
    from gonio.motion.safe import safe_path

    c, g, r = _setup(tmp_path, cfg, on_step=lambda run, s: s == 6 and run.request_pause())
    legs = []
    real = safe_path

    import gonio.executor as executor_module

    def spy(kin, start, target, start_tol_deg=0.0):
        path = real(kin, start, target, start_tol_deg)
        legs.append((np.array(start), np.array(target), path))
        return path

    executor_module.safe_path = spy
    try:
        assert r.run() == State.PAUSED
    finally:
        executor_module.safe_path = real
    start, target, path = legs[-1]
    np.testing.assert_array_equal(target, g.kinematics.home_deg)
    clear, _ = g.kinematics.sweep_clearance(np.vstack([start, path[:-1]]), path)
    assert clear.all()
    home = np.array([g.axes[a].position_deg() for a in cfg.axis_names])
    np.testing.assert_allclose(home, g.kinematics.home_deg, atol=1e-9)


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


@pytest.mark.parametrize("grid", ["iso:step=10,theta_max=20,order=serpentine", "iso:step=45,order=tour"])
def test_encoder_counts_beside_a_clearance_do_not_block_the_next_move(tmp_path, grid):
    """Free azimuths step aside to exactly kinematics.arm_collision_deg from the other carriage, and a
    Δφ = 10° pose puts the carriages that far apart. With encoders of 0.3° counts the read-back of a
    light carriage at −10° is −9.9°, inside that zone; the runner starts the next path from the target
    it arrived at (within position_tolerance_deg), as the planner did, instead of faulting with "no
    collision-free path" from the read-back."""
    data = load_config().model_dump(mode="json")
    for axis in data["axes"].values():
        axis.setdefault("sim", {})["resolution_deg"] = 0.3
    data["runner"]["position_tolerance_deg"] = 0.3
    cfg = parse_config(data)
    c = create_campaign(tmp_path / "c", cfg, grid=grid, material="lambert:albedo=0.5", seed=1)
    g = build_gantry(cfg, "lambert:albedo=0.5", seed=1)
    g.connect()
    steps = c.journal.steps()
    poses = steps["axes_deg"][steps["kind"] == STEP_POSE]
    gap = np.abs((poses[:, 0] - poses[:, 2] + 180.0) % 360.0 - 180.0)
    assert np.any(np.abs(gap - g.kinematics.arm_collision_deg) < 1e-9)  # a pose right at the clearance
    r = Runner(g, c.journal, cfg)
    assert r.run() == State.DONE, r.fault


# -- the command queue: requests before a run starts, a pause withdrawn, each decided under the lock ---------
def test_a_pause_requested_before_the_run_starts_acts_before_its_first_unit(tmp_path, cfg):
    c, g, r = _setup(tmp_path, cfg)
    assert r.request_pause("held by the operator") is True
    assert r.state == State.IDLE            # queued: the engine's thread acts on it when it runs
    assert r.run() == State.PAUSED
    assert c.journal.done_count() == 0
    assert [e["state"] for e in _events(c, "state")] == ["running", "paused"]
    assert len(_events(c, "pause")) == 1
    assert r.run() == State.DONE           # nothing is left in the queue: the next run runs


def test_an_abort_or_a_halt_before_the_run_starts_ends_it_before_anything_moves(tmp_path, cfg):
    c, g, r = _setup(tmp_path, cfg)
    moved = []
    for axis in g.axes.values():
        axis.move_to = lambda t, a=axis: moved.append(a.name)
    r.request_abort()
    assert r.state == State.IDLE
    assert r.run() == State.ABORTED
    assert c.journal.done_count() == 0 and moved == [] and not g.light.is_on()
    assert _events(c, "park") == [] and [e["state"] for e in _events(c, "state")] == ["aborted"]
    c2 = create_campaign(tmp_path / "c2", cfg, grid=GRID, material="lambert:albedo=0.5", seed=1)
    r2 = Runner(g, c2.journal, cfg)
    r2.request_halt("halt before the start")
    assert r2.run() == State.HALTED
    assert c2.journal.done_count() == 0 and moved == []
    assert [e["state"] for e in _events(c2, "state")] == ["running", "halted"]


def test_a_pause_withdrawn_before_it_acts_lets_the_run_go_on(tmp_path, cfg):
    def on_step(runner, step):
        if step == 2:
            assert runner.request_pause() and runner.state == State.PAUSING
            assert runner.request_resume("changed my mind") and runner.state == State.RUNNING

    c, g, r = _setup(tmp_path, cfg, on_step=on_step)
    assert r.run() == State.DONE
    assert [e["state"] for e in _events(c, "state")] == ["running", "done"]
    assert len(_events(c, "pause")) == 1 and len(_events(c, "resume")) == 1
    assert r.request_resume() is False     # nothing to withdraw


def test_an_abort_while_a_paused_run_parks_aborts_it(tmp_path, cfg):
    """The daemon's abort of a campaign whose engine had already paused and is parking: it is decided
    under the engine's lock against the state it finds (paused: at once), not lost."""
    c, g, r = _setup(tmp_path, cfg, on_step=lambda run, s: s == 1 and run.request_pause())
    real = g.light.set_on

    def light(on):
        real(on)
        if not on and r.state == State.PAUSED:   # the park is next: an abort arrives now
            assert r.request_abort() is True

    g.light.set_on = light
    assert r.run() == State.ABORTED
    assert [e["state"] for e in _events(c, "state")] == ["running", "paused", "aborted"]
