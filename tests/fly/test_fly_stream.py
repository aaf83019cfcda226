"""Fly campaigns whose photodiode streams (profile ``streaming-photodiode``: dynamixel-sdk and pyserial
over ptys to the emulators, on a SyncedVirtualClock that stops at each of the stream's lines): sub-reads
come from the stream, back to back, and the result matches the stop-and-go simulation within its
stated uncertainty; lines lost mid-reading make the sweep be read again (never interpolated across);
a stream off its configured rate is journaled; a campaign halted mid-sweep resumes with that sweep
read again."""

from __future__ import annotations

import numpy as np
import pytest
from built_once import built_once
from test_fly_hardware import (  # the fly hardware tests' helpers and their stop-and-go reference
    MATERIAL,
    TWIN,
    _fly,
    _matches_stop_and_go,
    _measurements,
    _resume_through_gonio_run,
    _z,
    fly_plan_of_folder,
    stop_and_go,  # noqa: F401 - a fixture
)

from gonio.config import load_config, parse_config
from gonio.dataset import read_brdf
from gonio.plan.fly import fly_steps
from gonio.protocols import Streams
from gonio.runner import State
from gonio.sim.emulators.gantry import EmulatedGantry
from gonio.sim.emulators.link import SyncedVirtualClock

#: 20 ms a sample: four or more per sub-read of the twin's fly exposures (0.25-0.33 s read in four).
RATE_HZ = 50.0


def _streaming_config():
    data = load_config(TWIN).model_dump(mode="json")
    data["detector"].update(profile="streaming-photodiode", stream_rate_hz=RATE_HZ)
    return parse_config(data)


def _on_stream_start(hook):
    """A detector hook: ``hook(g, n)`` before the gantry's detector starts its n-th stream (from 1)."""
    def wrap(g):
        assert isinstance(g.detector, Streams)
        start, count = g.detector.start_stream, [0]

        def counted():
            count[0] += 1
            hook(g, count[0])
            return start()

        g.detector.start_stream = counted
    return wrap


@pytest.fixture(scope="module")
def streamed(tmp_path_factory):
    """The streamed fly campaign: (folder, meta, the meter's commands), once per run (tests/built_once.py):
    the tests only read it."""
    return built_once(tmp_path_factory, "fly-stream", _streamed)


def _streamed(folder):
    clock = SyncedVirtualClock()
    with EmulatedGantry(_streaming_config(), MATERIAL, clock=clock, any_port=True, referenced=True) as emu:
        state, runner, meta = _fly(folder, emu, clock)
        assert state == State.DONE, runner.fault
        commands = list(emu.meter.commands)
    return folder, meta, commands


def test_a_streamed_fly_campaign_matches_the_stop_and_go_simulation(streamed, stop_and_go):  # noqa: F811
    folder, meta, commands = streamed
    rows, events, swept = _matches_stop_and_go(folder, meta, stop_and_go)
    # every reading from the stream: whole samples covering its exposure, none requested mid-sweep
    for m in swept:
        assert m.extra["stream_samples"] == pytest.approx(m.exposure_s * RATE_HZ, abs=m.frames)
    fp = fly_plan_of_folder(folder)
    moving = sum(1 for kind, k, _ in fly_steps(fp) if kind == "line" and fp.lines[k].moving)
    # one stream per sweep (a sweep retried after a fault on a loaded host: one more)
    retried = len([e for e in events if e["kind"] == "retry"])
    assert commands[0] == "STRM OFF"   # at connect: a stream a killed run left going is stopped
    starts = commands.count("STRM ON")
    assert starts == commands.count("STRM OFF") - 1 == commands.count(f"STRM:RATE {RATE_HZ:g}")
    assert moving <= starts <= moving + retried
    # on request only at rest: the checkpoints' dark and white and any pose read stop-and-go
    assert len(rows) - len(swept) <= commands.count("MEAS?") <= len(rows) - len(swept) + 2 * retried
    assert not [e for e in events if e["kind"] == "warning"]


def test_lines_lost_mid_sweep_read_that_sweep_again_and_a_fast_stream_is_journaled(tmp_path):
    clock = SyncedVirtualClock()
    folder = tmp_path / "fly"
    with EmulatedGantry(_streaming_config(), MATERIAL, clock=clock, any_port=True, referenced=True) as emu:
        emu.meter.clock_error = 0.02   # the photodiode's crystal runs 2 % fast

        def hook(g, n):
            emu.meter.faults.clear()
            if n == 3:   # the third sweep loses 1.2 s of lines from its 0.6th second: inside a reading
                for k in range(30, 90):
                    emu.meter.faults.add("drop", match=("SAMPLE", k))

        state, runner, meta = _fly(folder, emu, clock, detector_hook=_on_stream_start(hook))
        assert state == State.DONE, runner.fault
        lost = [f for f in emu.meter.faults.applied if f[0] == "drop"]
    rows, events = _measurements(folder)
    assert len(lost) > 0
    retries = [e for e in events if e["kind"] == "retry"]
    assert any("stream: samples 30.." in e["message"] and "read again" in e["message"]
               for e in retries), retries
    steps = [m.step for m in rows]
    assert sorted(steps) == list(range(len(steps))) and len(steps) == len(set(steps))  # one per step
    warnings = [e["message"] for e in events if e["kind"] == "warning"]
    rate = [w for w in warnings if w.startswith("detector: stream period")]
    assert len(rate) == 1 and "-1.96 %" in rate[0], warnings     # once, not once per sweep
    lost = [w for w in warnings if w.startswith("detector: stream: ")]
    assert len(lost) == 1 and "60 of" in lost[0] and "samples 30..89" in lost[0], warnings


def test_halted_mid_sweep_resumes_through_gonio_run_with_that_sweep_read_again(tmp_path, streamed,
                                                                              monkeypatch, capsys):
    clock = SyncedVirtualClock()
    runners = []
    folder = tmp_path / "fly"
    cfg = _streaming_config()
    with EmulatedGantry(cfg, MATERIAL, clock=clock, any_port=True, referenced=True) as emu:
        def hook(g, n):
            if n == 4:   # the fourth sweep's stream is started: halt on its way
                runners[0].request_halt("operator: emergency stop")

        state, runner, _ = _fly(folder, emu, clock, on_runner=runners.append,
                                detector_hook=_on_stream_start(hook))
        assert state == State.HALTED
        rows, _ = _measurements(folder)
        fp = fly_plan_of_folder(folder)
        sweeps = [(step, fp.lines[k].n) for kind, k, step in fly_steps(fp) if kind == "line"]
        done = {m.step for m in rows}
        for step, n in sweeps:
            assert len(done & set(range(step, step + n))) in (0, n)   # whole sweeps or none
        in_flight = [(s, n) for s, n in sweeps if s not in done][0]
        halted_at = max(m.campaign_s for m in rows)
        _resume_through_gonio_run(tmp_path, emu, clock, folder, monkeypatch, capsys)
    rows, _ = _measurements(folder)
    assert sorted(m.step for m in rows) == list(range(len(rows)))
    redone = [m for m in rows if in_flight[0] <= m.step < in_flight[0] + in_flight[1]]
    assert len(redone) == in_flight[1] and all(m.campaign_s > halted_at for m in redone)
    resumed, whole = read_brdf(folder / "brdf.h5"), read_brdf(streamed[0] / "brdf.h5")
    assert resumed.value.shape == whole.value.shape
    value, other, z = _z(resumed, whole)
    assert np.all(np.abs(z) < 4), z   # the same campaign, read twice: equal within both uncertainties


def test_a_stream_that_stalls_mid_sweep_is_a_transient_fault_and_the_sweep_is_read_again(tmp_path):
    clock = SyncedVirtualClock()
    folder = tmp_path / "fly"
    with EmulatedGantry(_streaming_config(), MATERIAL, clock=clock, any_port=True, referenced=True) as emu:
        def hook(g, n):
            emu.meter.faults.clear()
            if n == 2:   # the second sweep's stream goes silent: no line reaches the host
                emu.meter.faults.add("drop", match="SAMPLE", times=100_000)

        state, runner, _ = _fly(folder, emu, clock, detector_hook=_on_stream_start(hook))
        assert state == State.DONE, runner.fault
    rows, events = _measurements(folder)
    retries = [e["message"] for e in events if e["kind"] == "retry"]
    assert any("stream: no sample past" in m and "the stream stalled" in m for m in retries), retries
    warnings = [e["message"] for e in events if e["kind"] == "warning"]
    assert any(w.startswith("detector: stream: ") and "lines lost (samples 0.." in w
               for w in warnings), warnings
    assert sorted(m.step for m in rows) == list(range(len(rows)))
