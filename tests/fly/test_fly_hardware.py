"""Fly campaigns through the real drivers (dynamixel-sdk and pyserial over ptys to the emulators, on a
SyncedVirtualClock): the result matches the stop-and-go simulation of the same material and grid within
its stated uncertainty, the stored directions come from the timestamped axis reads, a campaign halted
mid-sweep resumes (through ``gonio run``) with that sweep done again, a servo's hardware error mid-sweep
faults naming the axis, and a gantry whose sweeping axis is not a Dynamixel servo is refused."""

from __future__ import annotations

import time

import numpy as np
import pytest
from built_once import built_once
from emulated_clock import WallThenVirtual, gonio_on
from fly_compare import matches_stop_and_go as _matches_stop_and_go
from fly_compare import measurements as _measurements
from fly_compare import pose_order as _rows
from fly_compare import simulate_stop_and_go
from fly_compare import z_scores as _z
from side_by_side import side_by_side

from gonio.campaign import create_campaign
from gonio.cli import main
from gonio.config import load_config
from gonio.dataset import read_brdf
from gonio.fly import fly_plan_of
from gonio.lifecycle import run_campaign
from gonio.plan.fly import fly_steps
from gonio.runner import State
from gonio.sim.emulators.gantry import EmulatedGantry
from gonio.sim.emulators.link import SyncedVirtualClock
from gonio.store import JOURNAL_NAME, Journal
from gonio.wiring import build_gantry

MATERIAL = "cook-torrance:d=beckmann,m=0.3,metal=gold"
GRID = "iso:step=30"
TWIN = "emulated-two-arm-dynamixel"
TICK_DEG = 360.0 / 4096 / 1.5   # the coarsest encoder step of the twin's axes (tilts, 1.5:1)


def _fly(folder, emu, clock, *, on_runner=None, detector_hook=None, clear_fault=False, create=True):
    """Create (or reopen) and run the fly campaign in ``folder`` on the emulators; ``detector_hook(g)``
    may wrap the gantry's detector. Returns (state, runner, campaign meta, journal measurements)."""
    from gonio.campaign import open_campaign

    cfg = emu.config()
    c = (create_campaign(folder, cfg, grid=GRID + ",order=fly", material=None, sample="gold") if create
         else open_campaign(folder))
    try:
        g = build_gantry(cfg, clock=clock)
        if detector_hook is not None:
            detector_hook(g)
        state, runner = run_campaign(c, g, on_runner=on_runner, clear_fault=clear_fault)
        return state, runner, c.meta
    finally:
        c.close()


@pytest.fixture(scope="module")
def stop_and_go(tmp_path_factory):
    """The stop-and-go simulation of the same material and grid (the twin's simulated gantry), once per
    run (tests/built_once.py): the tests only read it."""
    return built_once(tmp_path_factory, "fly-stop-and-go",
                      lambda folder: simulate_stop_and_go(folder, "sim", GRID, MATERIAL))


@pytest.fixture(scope="module")
def flown(tmp_path_factory):
    """An uninterrupted fly campaign on the emulated Dynamixel gantry: (folder, the servos' watchdog and
    profile registers after it, the axes' profiles, the campaign's meta, what the executor sent). Its
    moves are watched, not changed (on the synced virtual clock the watching takes no gantry time):
    every ``send_move`` as (servos moving then, the axes its target changes), every ``goto`` target.
    Built once per run (tests/built_once.py): the tests only read it."""
    return built_once(tmp_path_factory, "fly-flown", _flown)


def _flown(folder):
    from gonio.executor import MotionExecutor

    clock = SyncedVirtualClock()
    sent, gotos = [], []
    with EmulatedGantry(load_config(TWIN), MATERIAL, clock=clock, any_port=True, referenced=True) as emu, \
            pytest.MonkeyPatch.context() as mp:
        send, goto = MotionExecutor.send_move, MotionExecutor.goto

        def spy_send(self, start, target):
            moving = [n for n, s in emu.servos.items() if s._moving() and n != "changer"]
            changed = [self.kinematics.axis_names[i] for i in np.flatnonzero(np.asarray(target) != start)]
            sent.append((moving, changed))
            return send(self, start, target)

        def spy_goto(self, target):
            gotos.append(np.asarray(target, dtype=float).copy())
            return goto(self, target)

        mp.setattr(MotionExecutor, "send_move", spy_send)
        mp.setattr(MotionExecutor, "goto", spy_goto)
        state, runner, meta = _fly(folder, emu, clock)
        assert state == State.DONE, runner.fault
        servos = {n: (s.watchdog_fired_at, s.value(98), s.value(112), s.value(108))
                  for n, s in emu.servos.items()}
        profiles = {n: (a.profile_velocity, a.profile_acceleration)
                    for n, a in runner.gantry.axes.items()}
    return folder, servos, profiles, meta, (sent, gotos, runner.gantry.kinematics.axis_names)




def test_a_fly_campaign_through_the_drivers_matches_the_stop_and_go_simulation(flown, stop_and_go):
    folder, servos, profiles, meta, _ = flown
    assert meta["fly"]["lines"] >= 4
    rows, events, swept = _matches_stop_and_go(folder, meta, stop_and_go)
    assert any(np.max(m.extra["stderr_blur"]) > 0 for m in swept)
    # The watchdog was fed through every sweep (never fired), nothing was retried, and every sweeping
    # servo runs with the campaign's profile again.
    assert not [e for e in events if e["kind"] in ("retry", "fault")]
    for name, (fired, armed, velocity, accel) in servos.items():
        assert fired is None and armed == 0
        if name in profiles:
            assert (velocity, accel) == profiles[name]


def test_a_dry_run_fly_campaign_renders_along_the_servos_read_backs(tmp_path, stop_and_go):
    """A dry run: the emulated servos with a simulated photodiode in place of the serial power meter.
    The detector reads the servos at each sub-read's start and end and integrates along the line
    between; the campaign matches the stop-and-go simulation as the real-detector one does, and the
    readings taken mid-sweep rendered a moving pose (the start and end read-backs differ)."""
    from gonio.config import parse_config
    from gonio.sim.detector import SimDetector

    clock = SyncedVirtualClock()
    with EmulatedGantry(load_config(TWIN), MATERIAL, clock=clock, any_port=True, referenced=True) as emu:
        data = emu.config().model_dump(mode="python", exclude_unset=True)
        data["detector"] = {"driver": "sim", "channels": ["R", "G", "B"], "exposure_s": 0.1, "frames": 1,
                            "sim": {"half_angle_deg": 1.0, "aperture_samples": 256,
                                    "noise": {"shot_counts_per_unit": 0.0, "read_sigma": 0.0}}}
        cfg = parse_config(data)
        c = create_campaign(tmp_path, cfg, grid=GRID + ",order=fly", material=MATERIAL, sample="gold")
        moving = []
        try:
            g = build_gantry(cfg, MATERIAL, clock=clock)
            assert isinstance(g.detector, SimDetector)
            measure = g.detector.measure

            def spy(*args, **kw):
                reading = measure(*args, **kw)
                moving.append(reading.extra["moving"])
                return reading

            g.detector.measure = spy
            state, runner = run_campaign(c, g)
            assert state == State.DONE, runner.fault
            poses = c.meta["poses"]
        finally:
            c.close()
    rows, events = _measurements(tmp_path)
    assert not [e for e in events if e["kind"] in ("retry", "fault")]
    swept = [m for m in rows if m.frames > 1]
    assert len(swept) == poses and sum(moving) >= len(swept) * swept[0].frames // 2
    measured = read_brdf(tmp_path / "brdf.h5")
    (m_order, m_keys), (s_order, s_keys) = _rows(measured), _rows(stop_and_go)
    np.testing.assert_array_equal(m_keys[m_order], s_keys[s_order])
    value, sd = measured.value[m_order], measured.stddev[m_order]
    sim, sd_sim = stop_and_go.value[s_order], stop_and_go.stddev[s_order]
    z = (value - sim) / np.sqrt(sd**2 + sd_sim**2)
    assert np.all(np.abs(value - sim) <= 4 * np.sqrt(sd**2 + sd_sim**2) + 0.01 * sim), z
    assert np.sqrt(np.mean(z**2)) < 1.5, z


def test_the_stored_directions_follow_the_axis_reads_not_the_plan(tmp_path):
    """Every servo runs 6 % faster than its profile says. The stored axis positions are the shafts' true
    positions at each reading's mid-time (within an encoder step), where a reader timed by the plan
    would be degrees off; the readings still land on their poses (the reads time them)."""
    clock = SyncedVirtualClock()
    truth: list[tuple[float, np.ndarray]] = []
    starts: list[float] = []
    with EmulatedGantry(load_config(TWIN), MATERIAL, clock=clock, any_port=True, referenced=True) as emu:
        for s in emu.servos.values():
            s._velocity_ticks_s = (lambda f: lambda: 1.06 * f())(s._velocity_ticks_s)

        def hook(g):
            measure, sweep = g.detector.measure, g.sweep

            def logged(*args, **kw):
                truth.append((clock.now(), emu.axes_at([clock.now()])[0]))
                out = measure(*args, **kw)
                truth.append((clock.now(), emu.axes_at([clock.now()])[0]))
                return out

            def swept(*args):
                out = sweep(*args)
                starts.append(clock.now())
                return out

            g.detector.measure, g.sweep = logged, swept

        state, runner, c = _fly(tmp_path / "fly", emu, clock, detector_hook=hook)
        assert state == State.DONE, runner.fault
    fp = fly_plan_of_folder(tmp_path / "fly")
    rows, _ = _measurements(tmp_path / "fly")
    by_step = {m.step: m for m in rows}
    t_truth = np.array([t for t, _ in truth])
    x_truth = np.array([x for _, x in truth])
    lines = [(fp.lines[k], step) for kind, k, step in fly_steps(fp) if kind == "line" and fp.lines[k].moving]
    assert len(lines) == len(starts)
    off_plan = []
    for (line, step), t_go in zip(lines, starts, strict=True):
        for j in range(line.n):
            m = by_step[step + j]
            mid = m.extra["mid_s"]
            true = np.array([np.interp(mid, t_truth, x_truth[:, i]) for i in range(x_truth.shape[1])])
            np.testing.assert_allclose(m.actual_deg, true, atol=TICK_DEG)
            off_plan.append(abs(line.position_at(mid - t_go)[line.axis] - true[line.axis]))
            # Centred on its pose: within a fraction of the blur (speed × exposure).
            assert abs(m.actual_deg[line.axis] - m.commanded_deg[line.axis]) < \
                0.05 * line.speed_deg_s * line.exposure_s
    assert max(off_plan) > 1.0  # what the plan's clock would have put there


def fly_plan_of_folder(folder):
    from gonio.campaign import open_campaign

    c = open_campaign(folder, readonly=True)
    try:
        return fly_plan_of(c)
    finally:
        c.close()


def _after_subreads(count, action):
    """A detector hook: ``action()`` once the gantry's detector has answered ``count`` sub-reads of
    sweeps (single readings of checkpoints are not counted)."""
    seen = [0]

    def hook(g):
        measure = g.detector.measure

        def counted(exposure_s, frames=1, **kw):
            out = measure(exposure_s, frames, **kw)
            if exposure_s < g.detector_exposure_s:
                seen[0] += 1
                if seen[0] == count:
                    action(g)
            return out

        g.detector_exposure_s = load_config(TWIN).detector.exposure_s
        g.detector.measure = counted

    return hook


def _resume_through_gonio_run(tmp_path, emu, clock, folder, monkeypatch, capsys) -> None:
    """``gonio run`` on the same folder resumes and finishes (the config written for another process;
    the CLI's wall clock is the emulators' virtual one here, so the test does not wait for the gantry)."""
    path = tmp_path / "gantry.toml"
    path.write_text(emu.config_toml())
    monkeypatch.setattr("gonio.wiring.WallClock", lambda: clock)
    code = main(["run", "--config", str(path), "--grid", GRID + ",order=fly", "--out", str(folder),
                 "--sample", "gold"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "resuming the campaign" in err


def test_halted_mid_sweep_resumes_through_gonio_run_with_that_sweep_done_again(tmp_path, flown, monkeypatch,
                                                                            capsys):
    clock = SyncedVirtualClock()
    runners = []
    folder = tmp_path / "fly"
    with EmulatedGantry(load_config(TWIN), MATERIAL, clock=clock, any_port=True, referenced=True) as emu:
        hook = _after_subreads(30, lambda g: runners[0].request_halt("operator: emergency stop"))
        state, runner, _ = _fly(folder, emu, clock, on_runner=runners.append, detector_hook=hook)
        assert state == State.HALTED
        rows, events = _measurements(folder)
        fp = fly_plan_of_folder(folder)
        sweeps = [(step, fp.lines[k].n) for kind, k, step in fly_steps(fp) if kind == "line"]
        done = {m.step for m in rows}
        in_flight = [(s, n) for s, n in sweeps if s not in done][0]
        assert in_flight[0] < len(rows) + 2 * len(fp.checkpoints)  # halted inside a sweep, nothing of it kept
        assert not done & set(range(in_flight[0], in_flight[0] + in_flight[1]))
        halted_at = max(m.campaign_s for m in rows)
        _resume_through_gonio_run(tmp_path, emu, clock, folder, monkeypatch, capsys)
    rows, _ = _measurements(folder)
    redone = [m for m in rows if in_flight[0] <= m.step < in_flight[0] + in_flight[1]]
    assert len(redone) == in_flight[1] and all(m.campaign_s > halted_at for m in redone)
    resumed, whole = read_brdf(folder / "brdf.h5"), read_brdf(flown[0] / "brdf.h5")
    assert resumed.value.shape == whole.value.shape
    value, other, z = _z(resumed, whole)
    assert np.all(np.abs(z) < 4), z  # the same campaign, read twice: equal within both uncertainties


def test_a_servo_hardware_error_mid_sweep_faults_naming_the_axis(tmp_path):
    clock = SyncedVirtualClock()
    folder = tmp_path / "fly"
    with EmulatedGantry(load_config(TWIN), MATERIAL, clock=clock, any_port=True, referenced=True) as emu:
        def overload(g):
            moving = [n for n, s in emu.servos.items() if s._moving() and n != "changer"]
            assert len(moving) == 1  # one axis sweeps
            emu.servos[moving[0]].inject_hardware_error(0x20)   # overload
            fired.append(moving[0])

        fired: list[str] = []
        # The 11th sub-read: the third of a reading (a line's axis is set going halfway through its first).
        state, runner, c = _fly(folder, emu, clock, detector_hook=_after_subreads(11, overload))
        assert state == State.FAULTED
        assert fired and fired[0] in runner.fault and "hardware error" in runner.fault, runner.fault
        assert "overload" in runner.fault
        assert all(not s._moving() for s in emu.servos.values())  # every axis stopped
        rows, _ = _measurements(folder)
        fp = fly_plan_of_folder(folder)
        done = {m.step for m in rows}
        sizes = [(step, 2 if kind == "checkpoint" else fp.lines[k].n) for kind, k, step in fly_steps(fp)]
        kept = [all(s + i in done for i in range(n)) for s, n in sizes]
        assert done == {s + i for (s, n), whole in zip(sizes, kept, strict=True) if whole for i in range(n)}
        assert kept.index(False) > 1 and not any(kept[kept.index(False):])  # whole sweeps before it, only
        state, runner, _ = _fly(folder, emu, clock, create=False)   # latched: nothing runs
        assert state == State.FAULTED
        state, runner, _ = _fly(folder, emu, clock, create=False, clear_fault=True)  # rebooted, resumed
        assert state == State.DONE, runner.fault
    assert read_brdf(folder / "brdf.h5").value.shape[0] == sum(ln.n for ln in fp.lines)


def test_gonio_run_refuses_order_fly_where_a_sweeping_axis_is_not_a_dynamixel_servo(tmp_path, capsys):
    # the real config (its emulated twin names placeholder ports, refused first): refused before any
    # controller is connected
    out = tmp_path / "run"
    code = main(["run", "--config", "sample-stage-modbus", "--grid", GRID + ",order=fly",
                 "--out", str(out), "--sample", "x"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and "axes." in err[0] and "'modbus' cannot sweep" in err[0], err
    assert not out.exists()


def test_a_run_up_ending_within_the_planners_rounding_of_a_limit_is_taken_to_the_limit():
    """The planner lets a line's rest position lie within 1e-6° beyond a limit (float rounding of
    v²/2a + v·e/2), which the driver would refuse; further beyond is left for the driver to refuse."""
    from gonio.fly.hardware import on_limits
    from gonio.kinematics import make_kinematics

    kin = make_kinematics(load_config(TWIN))
    lo, hi = np.asarray(kin.limits_deg).T
    near = np.array([lo[0] - 1e-9, hi[1] + 5e-7, 10.0, lo[3]])
    np.testing.assert_array_equal(on_limits(kin, near), [lo[0], hi[1], 10.0, lo[3]])
    far = np.array([lo[0] - 1e-3, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(on_limits(kin, far), far)


def _progress(meter) -> int:
    """Sub-reads answered (a photodiode on request), or stream lines sent (a streaming one: it streams
    only during sweeps)."""
    return meter.sent // 4 if hasattr(meter, "sent") else meter.answered


#: The kill-mid-sweep scenarios (gantry, photodiode profile): the two-arm gantry with a photodiode read on
#: request and one that streams, and the sample stage (its sweeps are coordinated lines).
KILLED_MID_SWEEP = [(TWIN, "acknowledging"), (TWIN, "streaming-photodiode"),
                    ("emulated-sample-stage-dynamixel", "acknowledging")]
#: Upper bound on one scenario (its kill within 90 s, its resumed run after it), for the join below.
SCENARIO_LIMIT_S = 300.0
#: Gantry time between the kill and the resumed run's first packet (a process starting): past the servos'
#: bus watchdog (0.5 s), which stops a sweep the killed process left going, as it does on the wall clock.
RESTART_S = 1.5


@pytest.mark.slow
def test_gonio_run_order_fly_killed_mid_sweep_keeps_whole_sweeps_and_resumes(tmp_path):
    """kill -9 of ``gonio run ... order=fly`` on the wall clock while a sweep is under way: the journal
    holds every sweep whole or not at all (one transaction per sweep), and the same command run again
    resumes and completes the campaign with exactly one reading per step. On the sample stage the sweep
    killed is a coordinated line (several servos along a path, segment by segment).

    The emulated servos run in real time while the killed process drives them, so the scenarios
    (:data:`KILLED_MID_SWEEP`), independent of one another (each its own emulators, ports and folder),
    run at once, each in a thread of its own: their waits overlap. The command run again runs in this
    process (``gonio.cli.main``, one scenario at a time) with the emulators' clock gone virtual
    (:class:`WallThenVirtual`): what is tested there is the resume, not the servos' speed."""
    side_by_side({f"{twin}/{profile}": (lambda twin=twin, profile=profile:
                                        _killed_mid_sweep(tmp_path / f"{twin}-{profile}", twin, profile))
                  for twin, profile in KILLED_MID_SWEEP}, limit_s=SCENARIO_LIMIT_S)


def _killed_mid_sweep(tmp_path, twin, profile):
    """One scenario of the test above, in the folder ``tmp_path``."""
    import signal
    import subprocess
    import sys

    from gonio.config import parse_config
    from gonio.plan.flypath import COORDINATED

    tmp_path.mkdir()
    data = load_config(twin).model_dump(mode="json")
    stage = twin != TWIN
    for name, axis in data["axes"].items():   # near each servo's velocity limit, quick ramps
        # The XM430s (275 °/s at the shaft) on 2:1 reducers where the shipped twins have 4:1 or 10:1
        # (the stage's 10:1 cap its axes at 27 °/s), the tilts' 1.5:1 kept; the changer's XL430 (364 °/s)
        # direct: the run up to the first sweep is short. The kill does not depend on the pace: the
        # photodiode is frozen mid-sweep before it (below).
        axis["max_accel_deg_s2"] = 3000.0
        if name == "changer":   # its two swings before the first sweep: 0.08 s each (20°), not 0.4 s
            axis.update(max_velocity_deg_s=350.0, max_accel_deg_s2=20000.0)
        elif stage or "azimuth" in name:
            axis["gear_ratio"] = 2.0
            axis["max_velocity_deg_s"] = 130.0
        else:
            axis["max_velocity_deg_s"] = 150.0
    data["target"]["reference_deg"] = 20.0   # the white standard 20° from the sample, not 90°
    data["runner"].update(settle_s=0.0, poll_s=0.02)
    data["detector"]["exposure_s"] = 0.02
    data["detector"]["profile"] = profile   # read on request, or from its stream
    if profile == "streaming-photodiode":
        # 20 ms a sample (the profile's 200 Hz streams four times the lines the resumed run, on the
        # synced clock, hands over one by one): one or two in each 25 ms sub-read of these sweeps'
        # 0.1 s exposures, every window holding a sample's mid-time (tests/fly/test_fly_stream.py
        # tests the stream's readings and rate)
        data["detector"]["stream_rate_hz"] = 50.0
    cfg = parse_config(data)
    out = tmp_path / "run"
    clock = WallThenVirtual()
    with EmulatedGantry(cfg, MATERIAL, clock=clock, any_port=True, referenced=True) as emu:
        path = tmp_path / "gantry.toml"
        path.write_text(emu.config_toml())
        args = ["run", "--config", str(path), "--grid", GRID + ",order=fly", "--out", str(out), "--sample",
                "gold", "--quiet"]
        proc = subprocess.Popen([sys.executable, "-m", "gonio.cli", *args], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE)
        in_flight = None
        try:
            # Wait until a sweep of several readings is under way: the journal holds every unit before
            # it, that unit's line is next, and the photodiode has answered several sub-reads since the
            # journal last grew (a transit reads nothing). The journal is looked at again only once the
            # photodiode has answered again (nothing to decide before).
            fp, units, last, answered, looked = None, [], None, 0, None
            deadline = time.monotonic() + 90.0
            while in_flight is None and time.monotonic() < deadline and proc.poll() is None:
                progress = _progress(emu.meter)
                if progress != looked and (out / JOURNAL_NAME).exists():
                    looked = progress
                    j = Journal.open(out / JOURNAL_NAME, readonly=True)
                    try:
                        done = set(j.done_steps().tolist())
                    finally:
                        j.close()
                    if fp is None and done:
                        fp = fly_plan_of_folder(out)
                        units = [(step, 2 if kind == "checkpoint" else fp.lines[k].n,
                                  kind == "line" and fp.lines[k].moving and fp.lines[k].n >= 3
                                  and (not stage or fp.lines[k].axis == COORDINATED))
                                 for kind, k, step in fly_steps(fp)]
                    if len(done) != last:
                        last, answered = len(done), _progress(emu.meter)
                    nxt = next((u for u in units if u[0] not in done), None)
                    if nxt is not None and nxt[2] and done and _progress(emu.meter) >= answered + 6:
                        in_flight = nxt
                time.sleep(0.002)  # polling what another process writes; bounded by the deadline
            assert in_flight is not None and proc.poll() is None, proc.communicate()
            # The photodiode frozen (its lock held: no reply, no stream line) from here to the kill: the
            # sweep under way cannot end meanwhile, however fast the servos run.
            with emu.meter.lock:
                j = Journal.open(out / JOURNAL_NAME, readonly=True)
                try:
                    assert in_flight[0] not in set(j.done_steps().tolist())
                finally:
                    j.close()
                proc.send_signal(signal.SIGKILL)
                proc.wait(10)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(10)
        clock.go_virtual(RESTART_S)
        rows, _ = _measurements(out)
        done = {m.step for m in rows}
        for step, n, _ in units:
            part = done & set(range(step, step + n))
            assert len(part) in (0, n), (step, n, sorted(part))   # whole or nothing
        assert not done & set(range(in_flight[0], in_flight[0] + in_flight[1]))  # read in part, not kept
        code, err = gonio_on(clock, args)
        assert code == 0, err
        assert "resuming" in err
    j = Journal.open(out / JOURNAL_NAME, readonly=True)
    try:
        assert j.done_steps().tolist() == list(range(j.step_count()))
    finally:
        j.close()
    b = read_brdf(out / "brdf.h5")
    assert np.all(np.isfinite(b.value)) and np.all(b.value > 0)




def test_a_swept_turnaround_sends_the_change_while_the_sweeping_servo_runs_out(flown):
    """At each turnaround the plan sweeps, the sweeper sends the other axes to the next line's start as
    soon as the last reading is over: the sweeping servo (read from its emulator) is still moving then,
    and the next line starts there with no move of its own (the uninterrupted campaign's moves, as
    :func:`flown` watched them)."""
    folder, _, _, _, (sent, gotos, axis_names) = flown
    fp = fly_plan_of_folder(folder)
    turns = [k for k in range(len(fp.lines)) if fp.swept_turn(k)]
    assert len(turns) >= 2
    # send_move is also how every leg of a move is sent: the turnarounds' are those sent mid-sweep.
    mid_sweep = [(moving, changed) for moving, changed in sent if moving]
    assert len(mid_sweep) == len(turns)
    for (moving, changed), k in zip(mid_sweep, turns, strict=True):
        axis = fp.lines[k].axis
        assert moving == [axis_names[axis]]
        assert changed and axis not in [axis_names.index(n) for n in changed]
    # The lines entered through a turnaround are not gone to: no goto targets their start.
    for k in turns:
        start = fp.lines[k].start_deg
        assert not any(np.allclose(g, start, atol=1e-6) for g in gotos)
