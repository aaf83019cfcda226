"""Campaigns through the two SCPI profiles (scpi-current-source lamp over loopback TCP, thorlabs-pm100 power
meter on a pty, both opened through PyVISA) on the emulated two-arm gantry: the result matches the
simulation, the dark readings are the power meter's lamp-off level, the instruments' identities are
journaled, and each row of the serial-instrument fault matrix (drivers/README.md) does what the table says:
retried or faulted with its reason, and run again, one reading per step, none lost, none twice."""

from __future__ import annotations

import subprocess
import time

import numpy as np
import pytest
from side_by_side import each_side_by_side
from test_run_emulated import (
    CHANGER_SWING_DEG,
    GONIO,
    MATERIAL,
    _emulated_run,
    _fast,
    _faulted_then_cleared,
    _rows,
    _simulated,
)

from gonio.config import load_config, parse_config
from gonio.dataset import read_brdf
from gonio.plan.schedule import STEP_DARK, STEP_REFERENCE
from gonio.runner import State
from gonio.sim.emulators.gantry import WATTS_PER_UNIT, EmulatedGantry
from gonio.sim.emulators.link import SyncedVirtualClock
from gonio.store import JOURNAL_NAME, Journal

TWIN = "emulated-two-arm-scpi"
DARK_W = load_config(TWIN).detector.sim.noise.dark_offset * WATTS_PER_UNIT


def _journal(folder):
    j = Journal.open(folder / JOURNAL_NAME, readonly=True)
    try:
        return j.measurements(), j.events(), j.meta(), j.step_count()
    finally:
        j.close()


def _whole(folder):
    """One reading per step, every dark at the lamp-off level, the white standard lit far above it."""
    ms, events, meta, n = _journal(folder)
    assert sorted(m.step for m in ms) == list(range(n))
    dark = np.array([m.signal[0] for m in ms if m.kind == STEP_DARK])
    white = np.array([m.signal[0] for m in ms if m.kind == STEP_REFERENCE])
    lit = np.array([m.signal[0] for m in ms if m.kind != STEP_DARK])
    assert dark.size >= 2 and np.allclose(dark, DARK_W, rtol=1e-5)
    assert white.size >= 2 and white.min() > 10 * DARK_W and lit.min() >= DARK_W * (1 - 1e-5)
    return events, meta


def _matches(measured, simulated):
    """The calibrated BRDF equals the simulation's channel mean within 4 of their standard errors plus 1 %,
    plus what a 7-digit NR3 reply resolves (10^-6 of the largest value: a pose whose light is a millionth
    of the meter's dark level reads as the dark level)."""
    (m_order, m_keys), (s_order, s_keys) = _rows(measured), _rows(simulated)
    np.testing.assert_allclose(m_keys[m_order], s_keys[s_order], atol=0.11)
    sim = simulated.value.mean(axis=1)[s_order]
    sd, value = simulated.stddev.max(axis=1)[s_order], measured.value[m_order, 0]
    tol = 4.0 * np.sqrt(2.0) * sd + 0.01 * sim + 1e-6 * sim.max()
    bad = np.flatnonzero(np.abs(value - sim) > tol)
    assert bad.size == 0, [(m_keys[m_order][i], value[i], sim[i], tol[i]) for i in bad[:3]]


#: The instruments' reply deadline here (the twin's is the default 1 s): the emulators answer from threads
#: of this process at once, and the faults that wait a deadline out wait this one.
REPLY_TIMEOUT_S = 0.5


def _emulated():
    """The SCPI twin's emulators, its instruments' reply deadline REPLY_TIMEOUT_S: (gantry, clock)."""
    data = load_config(TWIN).model_dump(mode="json")
    for bus in ("lamp", "powermeter"):
        data["buses"][bus]["timeout_s"] = REPLY_TIMEOUT_S
    clock = SyncedVirtualClock()
    return EmulatedGantry(parse_config(data), MATERIAL, clock=clock, any_port=True, referenced=True), clock


@pytest.fixture
def emulated():
    emu, clock = _emulated()
    with emu:
        yield emu, clock


def test_a_campaign_through_the_two_scpi_profiles_reads_darks_at_the_lamp_off_level(tmp_path,
                                                                                   tmp_path_factory,
                                                                                   emulated):
    emu, clock = emulated
    cfg = emu.config()
    assert cfg.buses["lamp"].port.startswith("TCPIP0::127.0.0.1::")
    assert cfg.buses["powermeter"].port.startswith("ASRL/")
    (state, runner), _ = _emulated_run(tmp_path / "emu", emu, clock)
    assert state == State.DONE, runner.fault
    events, meta = _whole(tmp_path / "emu")
    assert not [e for e in events if e["kind"] in ("retry", "fault")]
    # identity read at connect, journaled with the profile and its hash
    ids = meta["instruments"]
    assert ids["light"]["identity"] == emu.lamp.idn and ids["light"]["profile"] == "scpi-current-source"
    assert ids["detector"]["identity"] == emu.meter.idn and ids["detector"]["profile"] == "thorlabs-pm100"
    assert len(ids["detector"]["profile_sha256"]) == 64
    assert [e["message"] for e in events if e["kind"] == "instruments"] == [
        f"light: scpi-current-source {emu.lamp.idn!r}; detector: thorlabs-pm100 {emu.meter.idn!r}"]
    # every reading at 633 nm, 33 x 3 ms averaged; the lamp off at the end
    assert {(w, c) for w, c, _ in emu.meter.measurements} == {(633.0, 33)}
    assert not emu.lamp.output and emu.lamp.current_a == 1.5
    _matches(read_brdf(tmp_path / "emu" / "brdf.h5"), _simulated(tmp_path_factory, "sim"))


def _power_cycle(instrument, unplug: bool) -> None:
    instrument.power_off(unplug=unplug)
    instrument.power_on()


def _inject(emu, at_step, action):
    fired = []

    def on_step(runner, step):
        if step == at_step and not fired:
            fired.append(step)
            action(emu)
    return on_step


def _bad_reply(folder, kind):
    """A campaign whose power meter answers one FETC? badly (``kind``): retried once, then it finishes."""
    emu, clock = _emulated()
    with emu:
        # delay: 0.5 s after the reading's 0.6 s deadline (the time-out and the exposure), 0.5 s before its
        # re-synchronisation gives up (two time-outs more)
        on_step = _inject(emu, 4, lambda e: e.meter.faults.add(kind, match="FETC?", delay_s=1.1))
        (state, runner), _ = _emulated_run(folder, emu, clock, on_step=on_step)
        assert state == State.DONE, runner.fault
        assert emu.meter.faults.applied == [(kind, "FETC?")]
    events, _ = _whole(folder)
    retries = [e for e in events if e["kind"] == "retry"]
    assert len(retries) == 1 and retries[0]["step"] == 5 and "detector: 'FETC?'" in retries[0]["message"]


def test_a_bad_power_meter_reply_is_retried_and_the_campaign_finishes(tmp_path):
    """A reply late, dropped, corrupt or cut short: the step is retried once and the campaign finishes.
    The four are independent (each its own emulators, ports and folder) and run side by side: the
    deadlines three of them wait out are waited out together."""
    each_side_by_side(lambda kind: _bad_reply(tmp_path / kind, kind),
                      ("delay", "drop", "corrupt", "truncate"))


def test_a_lamp_switch_lost_on_the_wire_is_retried_and_the_dark_is_still_dark(tmp_path, emulated):
    """OUTP OFF before a dark reading never arrives (a silent setter: no error anywhere): the read-back
    shows the output still on, the step is retried, and the dark reading is taken with the lamp off."""
    emu, clock = emulated
    on_step = _inject(emu, 1, lambda e: e.lamp.faults.add("drop", match="OUTP"))
    (state, runner), _ = _emulated_run(tmp_path / "s", emu, clock, on_step=on_step)
    assert state == State.DONE, runner.fault
    events, _ = _whole(tmp_path / "s")
    retries = [e for e in events if e["kind"] == "retry"]
    assert len(retries) == 1 and "light: 'OUTP" in retries[0]["message"]
    assert "the output reads" in retries[0]["message"]


def test_an_instrument_error_faults_naming_the_command_and_message_and_resumes_once_cleared(tmp_path,
                                                                                          emulated):
    """The source refuses the lamp's current (its range now below it): -222, not transient: the campaign
    faults with the instrument's own words; fixed and cleared, it finishes, no step lost or twice."""
    emu, clock = emulated

    def limit(e):
        e.lamp.max_current_a = 1.0

    def fix(e):
        e.lamp.max_current_a = 3.0
    reason, events = _faulted_then_cleared(tmp_path, emu, clock, limit, at_step=1, between=fix)
    assert reason == "light: 'SOUR:CURR 1.5000' refused: -222,\"Data out of range\""
    assert not [e for e in events if e["kind"] == "retry"]
    _whole(tmp_path / "f")


def test_a_power_meter_unplugged_mid_reading_faults_and_resumes_once_replugged(tmp_path, emulated):
    emu, clock = emulated
    reason, events = _faulted_then_cleared(
        tmp_path, emu, clock, lambda e: e.meter.faults.add("disconnect", match="FETC?"), at_step=3,
        between=lambda e: e.meter.replug())
    assert reason.startswith("detector: step 4: ") and "gave up after 2 retries" in reason
    assert [e["kind"] for e in events].count("retry") == 2
    _whole(tmp_path / "f")


def test_a_lamp_power_cycled_mid_campaign_is_switched_on_again_and_the_step_measured_again(tmp_path,
                                                                                         tmp_path_factory,
                                                                                         emulated):
    """The source comes back from a power cycle with its output off and 0 A: the lit reading after it
    would be a dark one. The runner finds the output off after the reading, switches the lamp on again
    (its current restored) and measures the step again."""
    emu, clock = emulated
    (state, runner), _ = _emulated_run(tmp_path / "c", emu, clock,
                                       on_step=_inject(emu, 2, lambda e: _power_cycle(e.lamp, unplug=False)))
    assert state == State.DONE, runner.fault
    events, _ = _whole(tmp_path / "c")
    retries = [e for e in events if e["kind"] == "retry"]
    assert len(retries) == 1
    assert "light: output found off after the reading of step 3" in retries[0]["message"]
    assert emu.lamp.current_a == 1.5
    _matches(read_brdf(tmp_path / "c" / "brdf.h5"), _simulated(tmp_path_factory, "sim"))


def test_a_power_meter_power_cycled_mid_campaign_is_configured_again(tmp_path, emulated):
    """The meter's USB port goes and comes back in its reset state (635 nm, no averaging): the next
    reading reopens the port and configures it again; no reading is taken at the reset settings."""
    emu, clock = emulated
    (state, runner), _ = _emulated_run(tmp_path / "m", emu, clock,
                                       on_step=_inject(emu, 3, lambda e: _power_cycle(e.meter, unplug=True)))
    assert state == State.DONE, runner.fault
    _whole(tmp_path / "m")
    assert {(w, c) for w, c, _ in emu.meter.measurements} == {(633.0, 33)}


# -- as a user runs it: gonio emulate in one process, gonio gantry reference and gonio run in another --
@pytest.mark.slow
def test_gonio_emulate_and_gonio_run_through_the_scpi_profiles(tmp_path, capsys):
    from gonio.cli import main

    data = _fast(TWIN)
    for axis in data["axes"].values():  # within each servo's velocity limit, its gear included; quick
        # ramps (Profile Acceleration): the moves are not what is tested here
        axis["max_velocity_deg_s"], axis["max_accel_deg_s2"] = 180.0, 6000.0
        if axis.get("reference") == "hard_stop":  # the ring carriages: 1:1 pinions, so 240 °/s on the
            # ring, and the approach to the stop at that speed
            axis.update(gear_ratio=1.0, max_velocity_deg_s=240.0, reference_velocity_deg_s=240.0)
    # the changer at the XL430's quickest (364 °/s), the white standard 20° from the sample: its swings
    # of 90° were a third of the campaign
    data["axes"]["changer"].update(max_velocity_deg_s=350.0, max_accel_deg_s2=20000.0)
    data["target"]["reference_deg"] = CHANGER_SWING_DEG
    # The light carriage on a ring of ±60° (this campaign's light azimuths lie within ±15°): its reference
    # seeks a stop 60° from where the servo powers up, not 200° (1.2 s less on the wall clock).
    data["axes"]["light_azimuth"].update(min_deg=-60.0, max_deg=60.0, reference_deg=-60.0)
    data["light"]["settle_s"] = 0.0
    src = tmp_path / "scpi.toml"
    from gonio.sim.emulators.gantry import to_toml

    src.write_text(to_toml(parse_config(data).model_dump(mode="json", exclude_defaults=True)))
    written = tmp_path / "emulated.toml"
    emulate = subprocess.Popen([*GONIO, "emulate", "--config", str(src), "--write-config", str(written),
                                "--any-port", "--material", MATERIAL], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60.0
        while not written.exists() and time.monotonic() < deadline and emulate.poll() is None:
            time.sleep(0.05)  # waiting for another process to write its file; bounded by the deadline
        assert written.exists(), emulate.communicate(timeout=10)
        # The emulated servos power up as real ones do: the carriages are referenced first. Both
        # commands run in this process (another than the emulators', as a user's would).
        assert main(["gantry", "reference", "--config", str(written)]) == 0, capsys.readouterr().err
        out = tmp_path / "run"
        argv = ["run", "--config", str(written), "--grid", "iso:step=45", "--out", str(out), "--sample",
                "gold", "--quiet"]
        assert main(argv) == 0, capsys.readouterr().err
    finally:
        emulate.terminate()
        emulate.communicate(timeout=30)
    events, meta = _whole(out)
    assert meta["instruments"]["detector"]["identity"].startswith("Thorlabs,PM100D,")
    assert not [e for e in events if e["kind"] in ("retry", "fault")]
