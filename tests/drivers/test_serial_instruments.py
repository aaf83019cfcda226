"""Serial instrument drivers in the acknowledging dialect (the default profile: setters answer OK, a
refusal is an ERR reply) through pyserial against emulated instruments on a pty: commands on the wire,
readings from the injected signal, and each injected fault. The SCPI profiles: test_scpi_instruments.py."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.drivers.serial import (
    InstrumentCommError,
    InstrumentError,
    SerialLightSource,
    SerialPowerMeter,
    SerialSpectrometer,
)
from gonio.protocols import Detector, LightSource
from gonio.sim.emulators.instruments import LightSourceEmulator, PowerMeterEmulator, SpectrometerEmulator


@pytest.fixture
def lamp(clock):
    emu = LightSourceEmulator(warmup_s=2.0, clock=clock)
    emu.start()
    dev = SerialLightSource("lamp", emu.port, timeout_s=0.2, clock=clock)
    try:
        dev.connect()
        yield emu, dev
    finally:
        dev.close()
        emu.stop()
    assert emu.error is None, f"the emulator's thread died of {emu.error!r}"


@pytest.fixture
def meter(clock):
    emu = PowerMeterEmulator(lambda exposure_s: 2.5e-6 * exposure_s, clock=clock)
    emu.start()
    dev = SerialPowerMeter("pd", emu.port, timeout_s=0.2, clock=clock)
    try:
        dev.connect()
        yield emu, dev
    finally:
        dev.close()
        emu.stop()
    assert emu.error is None, f"the emulator's thread died of {emu.error!r}"


def test_protocols_and_no_io_in_constructor():
    assert isinstance(SerialLightSource("l", "/nonexistent"), LightSource)
    assert isinstance(SerialPowerMeter("d", "/nonexistent"), Detector)


def test_lamp_on_level_and_warmup(lamp, clock):
    emu, dev = lamp
    assert dev.identity == LightSourceEmulator.idn  # read at connect
    dev.set_on(True)
    dev.set_level(42.5)
    assert dev.is_on() and dev.level() == 42.5
    # every switch and every level is read back
    assert emu.commands == ["*IDN?", "OUTP ON", "OUTP?", "SOUR:POW:LEV 42.500", "SOUR:POW:LEV?", "OUTP?",
                            "SOUR:POW:LEV?"]
    assert not dev.is_ready()
    dev.wait_ready(timeout_s=5.0, poll_s=0.5)
    assert clock.now() == pytest.approx(2.0)
    with pytest.raises(ValueError, match=r"light 'lamp': level 120% is outside \[0%, 100%\]"):
        dev.set_level(120)


def test_lamp_never_ready_times_out(lamp):
    emu, dev = lamp
    with pytest.raises(InstrumentCommError, match="not ready"):
        dev.wait_ready(timeout_s=1.0)  # lamp is off


def test_power_meter_reading(meter):
    emu, dev = meter
    r = dev.measure(0.1, frames=3, key=(7, 0))
    assert r.signal.shape == (1,) and r.signal[0] == pytest.approx(2.5e-7)
    assert r.stderr[0] == 0.0 and r.frames == 3 and r.extra == {"key": (7, 0)}
    assert emu.commands == ["*IDN?", "CONF:EXP 0.1", "MEAS?", "MEAS?", "MEAS?"]


def test_error_reply_is_a_typed_fault(meter):
    emu, dev = meter
    with pytest.raises(InstrumentError, match=r"'BOGUS\?' refused: ERR -113") as err:
        dev.query("BOGUS?")
    assert err.value.code == -113 and err.value.transient  # a command error: may be line noise
    with pytest.raises(InstrumentError, match=r"'CONF:EXP 99' refused: ERR -222") as err:
        dev.setters(["CONF:EXP 99"])
    assert err.value.code == -222 and not err.value.transient  # refused for good: out of range


@pytest.mark.parametrize("kind, message", [("drop", "no reply"), ("truncate", "without its terminator"),
                                            ("corrupt", "garbled reply")])
def test_bad_reply_is_transient_and_not_taken_for_the_next_answer(meter, kind, message):
    emu, dev = meter
    emu.faults.add(kind, match="MEAS?")
    with pytest.raises(InstrumentCommError, match=message) as err:
        dev.measure(0.1)
    assert err.value.transient
    assert dev.measure(0.2).signal[0] == pytest.approx(5e-7)


def test_late_reply_is_flushed(meter):
    emu, dev = meter
    emu.faults.add("delay", match="MEAS?", delay_s=0.3)
    with pytest.raises(InstrumentCommError):
        dev.query_number("MEAS?")
    assert emu.wait_answered(len(emu.commands))  # the late reply now sits in the input buffer
    assert dev.identify() == PowerMeterEmulator.idn


def test_a_reply_later_than_the_flush_is_discarded_not_taken_for_the_next_answer(meter):
    """The late reply arrives after the next query's flush (the emulator still holds it back when the
    driver asks again): the driver re-synchronises on the identity and discards it, counted."""
    emu, dev = meter
    emu.faults.add("delay", match="MEAS?", delay_s=0.35)
    with pytest.raises(InstrumentCommError, match="no reply"):
        dev.measure(0.1)  # 2.5e-7, late
    assert dev.measure(0.4).signal[0] == pytest.approx(1e-6)  # its own answer, not the late 2.5e-7
    assert dev.late_replies == 1


def test_disconnect_reconnects_with_backoff(meter):
    emu, dev = meter
    emu.faults.add("disconnect", match="MEAS?")
    with pytest.raises(InstrumentCommError):
        dev.measure(0.1)
    emu.replug()
    assert dev.measure(0.1).signal[0] == pytest.approx(2.5e-7)
    assert dev.reconnects >= 1


def test_spectrometer_bins(clock):
    wl = [400.0, 500.0, 600.0, 700.0]
    emu = SpectrometerEmulator(wl, lambda exposure_s: [exposure_s * k for k in range(1, 5)], clock=clock)
    emu.start()
    dev = SerialSpectrometer("spec", emu.port, timeout_s=0.2, clock=clock)
    try:
        dev.connect()
        assert dev.channels == ("400nm", "500nm", "600nm", "700nm")
        r = dev.measure(0.5, frames=2)
        np.testing.assert_allclose(r.signal, [0.5, 1.0, 1.5, 2.0])
    finally:
        dev.close()
        emu.stop()
    assert emu.error is None, f"the emulator's thread died of {emu.error!r}"
