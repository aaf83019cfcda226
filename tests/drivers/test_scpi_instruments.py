"""The SCPI profiles (thorlabs-pm100, scpi-current-source) driving emulators written from the instruments'
manuals (gonio.sim.emulators.scpi), over a pty and over loopback TCP, through pyserial and through PyVISA
(pyvisa-py): the lines on the wire, silent setters that are never waited for, the error queue, *OPC?,
replies that are not numbers, and each fault of the serial-instrument fault matrix (drivers/README.md)."""

from __future__ import annotations

import math
from contextlib import contextmanager

import pytest
from side_by_side import side_by_side

from gonio.clock import VirtualClock
from gonio.drivers.serial import InstrumentCommError, InstrumentError, SerialLightSource, SerialPowerMeter
from gonio.drivers.serial.transport import open_transport
from gonio.sim.emulators.scpi import CurrentSourceEmulator, Pm100Emulator, header_matches
from gonio.sim.emulators.tcp_link import TcpLink

WATTS = 1.25e-6
DARK_W = 2e-9
#: Reply deadline: long enough for a loaded machine (the emulator answers from a thread of this process;
#: at load 8-9 on 2 cores, 0.3 s was seen to run out on a good reply), short enough for the faults that
#: wait it out (about 16 scenarios wait one or two of them; those of one test wait side by side).
TIMEOUT_S = 0.5
#: How a driver reaches an emulator: (link for the emulator, the port string the driver is given).
TRANSPORTS = {
    "pty": (lambda: None, lambda emu: emu.port),
    "visa-asrl": (lambda: None, lambda emu: f"ASRL{emu.port}::INSTR"),
    "socket": (TcpLink, lambda emu: f"socket://{emu.port}"),
    "visa-socket": (TcpLink, lambda emu: f"TCPIP0::127.0.0.1::{emu.link.tcp_port}::SOCKET"),
}


class Recorder:
    """A transport factory that counts what the driver reads: a silent setter must cost no read."""

    def __init__(self):
        self.reads = 0
        self.writes: list[bytes] = []

    def __call__(self, port, baudrate, terminator):
        t = open_transport(port, baudrate, terminator)
        rec = self

        class _Counted:
            def write(self, data):
                rec.writes.append(data)
                t.write(data)

            def read_until(self, term, deadline):
                rec.reads += 1
                return t.read_until(term, deadline)

            def flush_input(self):
                t.flush_input()

            def close(self):
                t.close()
        return _Counted()


@contextmanager
def running(emu, dev):
    """``emu`` started and ``dev`` connected to it; both stopped at the end."""
    emu.start()
    try:
        dev.connect()
        yield emu, dev
    finally:
        dev.close()
        emu.stop()
    assert emu.error is None, f"the emulator's thread died of {emu.error!r}"


def _meter(port, clock, **kw):
    return SerialPowerMeter("pm", port, "thorlabs-pm100", wavelength_nm=633.0, timeout_s=TIMEOUT_S,
                            clock=clock, **kw)


@pytest.fixture(params=sorted(TRANSPORTS))
def transport(request):
    return request.param


@contextmanager
def _pm100_on(transport, clock):
    """The PM100 emulator and a driver connected to it through ``transport``."""
    link, port = TRANSPORTS[transport]
    emu = Pm100Emulator(lambda exposure_s: WATTS, dark_w=DARK_W, clock=clock, link=link())
    with running(emu, _meter(port(emu), clock)) as both:
        yield both


@pytest.fixture
def pm100(clock, transport):
    with _pm100_on(transport, clock) as both:
        yield both


@pytest.fixture
def source(clock, transport):
    link, port = TRANSPORTS[transport]
    emu = CurrentSourceEmulator(clock=clock, link=link())
    dev = SerialLightSource("lamp", port(emu), "scpi-current-source", level=1.5, timeout_s=TIMEOUT_S,
                            clock=clock)
    with running(emu, dev) as both:
        yield both


def test_scpi_headers_match_in_short_and_long_form_with_optional_nodes():
    spec = "[SENSe]:CORRection:WAVelength"
    for header in ("SENS:CORR:WAV", "sense:correction:wavelength", ":CORR:WAV", "Sens1:Corr:Wavelength"):
        assert header_matches(spec, header), header
    for header in ("SEN:CORR:WAV", "SENS:CORR", "SENS:CORR:WAVE", "SENS::CORR:WAV"):
        assert not header_matches(spec, header), header


# -- the power meter ---------------------------------------------------------------------------------
def test_pm100_lines_on_the_wire_and_a_reading(pm100):
    emu, dev = pm100
    r = dev.measure(0.1, frames=2, key=(3, 1))
    assert dev.identity == Pm100Emulator.idn
    # connect: identity, reset, clear, then *OPC? and the error queue; each reading configures the
    # meter (33 x 3 ms averaged), then per frame INIT, *OPC? (waits for it), the queue, FETC?
    assert emu.commands == [
        "*IDN?", "*RST", "*CLS", "*OPC?", "SYST:ERR?",
        "SENS:CORR:WAV 633", "SENS:AVER:COUN 33", "CONF:POW", "INIT", "*OPC?", "SYST:ERR?", "FETC?",
        "INIT", "*OPC?", "SYST:ERR?", "FETC?"]
    assert r.signal[0] == pytest.approx(WATTS + DARK_W, rel=1e-6) and r.frames == 2
    assert emu.measurements == [(633.0, 33, WATTS + DARK_W)] * 2
    assert dev.describe()["identity"] == Pm100Emulator.idn and dev.describe()["profile"] == "thorlabs-pm100"


def test_without_a_wavelength_the_meter_keeps_its_own(clock):
    emu = Pm100Emulator(lambda exposure_s: WATTS, clock=clock)
    dev = SerialPowerMeter("pm", emu.port, "thorlabs-pm100", timeout_s=TIMEOUT_S, clock=clock)
    with running(emu, dev):
        dev.measure(0.03)
    assert emu.commands[5:] == ["SENS:AVER:COUN 10", "CONF:POW", "INIT", "*OPC?", "SYST:ERR?", "FETC?"]
    assert emu.measurements == [(635.0, 10, WATTS)]  # the meter's own (reset) wavelength


def test_silent_setters_are_never_waited_for(clock):
    """Only queries are read: 16 lines sent, 9 of them queries, 9 reads (a setter waited for would also
    have timed out: the instrument never answers one)."""
    emu = Pm100Emulator(lambda exposure_s: WATTS, clock=clock)
    rec = Recorder()
    with running(emu, _meter(emu.port, clock, transport_factory=rec)) as (_, dev):
        dev.measure(0.1, frames=2)
    assert b"".join(rec.writes).decode().splitlines() == emu.commands and len(emu.commands) == 16
    assert len(rec.writes) == 9  # setters go out with the query after them, in one write
    assert rec.reads == sum(c.endswith("?") for c in emu.commands) == 9


def test_a_refused_setting_is_a_fault_naming_the_command_and_the_instruments_message(pm100):
    emu, dev = pm100
    dev.wavelength_nm = 2000.0  # beyond the sensor's 400-1100 nm
    with pytest.raises(InstrumentError) as err:
        dev.measure(0.1)
    # the configure group erred: each setter sent again alone names the one refused
    assert str(err.value) == "pm: 'SENS:CORR:WAV 2000' refused: -222,\"Data out of range\""
    assert err.value.code == -222 and not err.value.transient
    assert not emu.errors  # drained


def test_a_query_the_instrument_does_not_know_is_its_error_not_a_time_out(clock):
    emu = Pm100Emulator(lambda exposure_s: WATTS, clock=clock)
    with running(emu, _meter(emu.port, clock)) as (_, dev):
        with pytest.raises(InstrumentError, match=r"'POW:BOGUS\?' refused: -113,\"Undefined header\""):
            dev.query_number("POW:BOGUS?")
        assert dev.measure(0.1).signal[0] == pytest.approx(WATTS)


@pytest.mark.parametrize("value", [math.nan, math.inf, 9.91e37, -9.9e37])
def test_a_reading_that_is_not_a_number_is_transient_never_a_value(clock, value):
    """NaN, infinity, SCPI's not-a-number (9.91E37) and overload (-9.9E37) are not readings."""
    emu = Pm100Emulator(lambda exposure_s: value, clock=clock)
    with running(emu, _meter(emu.port, clock)) as (_, dev):
        with pytest.raises(InstrumentCommError, match=r"'FETC\?': reply .* is not a number") as err:
            dev.measure(0.1)
        assert err.value.transient


def test_an_empty_reply_line_is_not_a_number(clock):
    class Blank(Pm100Emulator):
        def _fetch(self, arg):
            return ""
    emu = Blank(lambda exposure_s: WATTS, clock=clock)
    with running(emu, _meter(emu.port, clock)) as (_, dev):
        with pytest.raises(InstrumentCommError, match=r"'FETC\?': reply '' is not a number"):
            dev.measure(0.1)


#: The fault tests run on the two ends of the matrix.
FAULT_TRANSPORTS = ("pty", "visa-socket")


def test_a_bad_reply_is_transient_and_the_next_reading_is_its_own():
    """Dropped, corrupt, truncated or late (after the time-out) FETC? replies: a transient fault; the
    next reading is the meter's new one, never the late one (the driver re-synchronises on *IDN?). Each
    fault on each transport is a meter of its own, all side by side (three of the four wait the
    deadline out)."""
    def scenario(kind, transport):
        def run():
            with _pm100_on(transport, VirtualClock()) as (emu, dev):
                # Late by 0.4 s after the FETC? deadline (time-out + 0.1 s exposure), and 0.6 s before the
                # end of the re-synchronisation that follows (its two time-outs after the first), so
                # neither edge is close.
                emu.faults.add(kind, match="FETC?", delay_s=2 * TIMEOUT_S)
                with pytest.raises(InstrumentCommError) as err:
                    dev.measure(0.1)
                assert err.value.transient and emu.faults.applied == [(kind, "FETC?")]
                emu.signal = lambda exposure_s: 3 * WATTS
                assert dev.measure(0.1).signal[0] == pytest.approx(3 * WATTS + DARK_W, rel=1e-6)
                # the late line was flushed, or discarded while re-synchronising (a TCP driver reconnected
                # after the time-out: it went to the closed connection)
                assert dev.late_replies <= 1
        return run

    side_by_side({f"{kind}-{transport}": scenario(kind, transport)
                   for kind in ("drop", "corrupt", "truncate", "delay") for transport in FAULT_TRANSPORTS})


def test_lines_that_come_after_the_flush_are_discarded_until_the_identity(clock):
    """After a time-out the next exchange asks *IDN? and reads until the identity: here two late lines
    come in front of it, after the driver's flush (an instrument still answering what timed out)."""
    class Late(Pm100Emulator):
        def _execute(self, header, arg):
            if header == "*IDN?" and self.late:
                self.link.write(b"".join(f"{v}\n".encode() for v in self.late))
                self.late = []
            return super()._execute(header, arg)

    emu = Late(lambda exposure_s: WATTS, clock=clock)
    emu.late = []
    with running(emu, _meter(emu.port, clock)) as (_, dev):
        emu.faults.add("drop", match="FETC?")
        emu.late = ["9.999999E-01", '0,"No error"']
        with pytest.raises(InstrumentCommError, match="no reply"):
            dev.measure(0.1)
        assert emu.commands[-3:] == ["FETC?", "*IDN?", "SYST:ERR?"]  # re-synchronised, then the queue
        assert dev.measure(0.1).signal[0] == pytest.approx(WATTS)
        assert dev.late_replies == 2


@pytest.mark.parametrize("kind, says", [("drop", "-230"), ("corrupt", "-102")])
def test_a_setter_lost_or_garbled_on_the_wire_is_caught_by_the_error_queue(kind, says):
    """A lost INIT leaves nothing to fetch (-230, data stale); a garbled one is a syntax error (-102).
    Both transient: the next reading is right. The two transports side by side (a lost INIT waits the
    FETC? deadline out)."""
    def scenario(transport):
        def run():
            with _pm100_on(transport, VirtualClock()) as (emu, dev):
                emu.faults.add(kind, match="INIT")
                with pytest.raises(InstrumentError, match=says) as err:
                    dev.measure(0.1)
                assert err.value.transient
                assert dev.measure(0.1).signal[0] == pytest.approx(WATTS + DARK_W, rel=1e-6)
        return run

    side_by_side({transport: scenario(transport) for transport in FAULT_TRANSPORTS})


def test_unplugged_mid_reading_reconnects(pm100):
    emu, dev = pm100
    emu.faults.add("disconnect", match="FETC?")
    with pytest.raises(InstrumentCommError):
        dev.measure(0.1)
    emu.replug()
    assert dev.measure(0.1).signal[0] == pytest.approx(WATTS + DARK_W, rel=1e-6)
    assert dev.reconnects >= 1


@pytest.mark.parametrize("unplug", [True, False], ids=["usb", "rs232"])
def test_a_power_cycled_meter_is_configured_again_before_its_next_reading(unplug):
    """Off (its USB port gone, or an RS-232 line silent): a transient fault. On again it is in its
    reset state (635 nm, no averaging); the next reading sets wavelength and averaging again. A silent
    line waits the deadline out: its transports side by side. A port that goes closes its pty under the
    emulator's thread, which may be reading the fd number just freed, and that number can be another
    scenario's next pty: those one after the other (they wait nothing)."""
    def scenario(transport):
        def run():
            with _pm100_on(transport, VirtualClock()) as (emu, dev):
                dev.measure(0.1)
                emu.power_off(unplug=unplug)
                with pytest.raises(InstrumentCommError):
                    dev.measure(0.1)
                emu.power_on()
                assert (emu.wavelength_nm, emu.count) == (635.0, 1)
                assert dev.measure(0.1).signal[0] == pytest.approx(WATTS + DARK_W, rel=1e-6)
                assert emu.measurements[-1] == (633.0, 33, WATTS + DARK_W)
        return run

    scenarios = {transport: scenario(transport) for transport in sorted(TRANSPORTS)}
    if unplug:
        for run in scenarios.values():
            run()
    else:
        side_by_side(scenarios)


# -- the current source --------------------------------------------------------------------------------
def test_current_source_lines_on_the_wire(source):
    emu, dev = source
    dev.set_on(True)
    assert emu.on and emu.current_a == 1.5
    dev.set_on(False)
    assert not emu.on and not emu.output
    assert dev.identity == CurrentSourceEmulator.idn
    # the level at connect and again before each switch-on; each setter checked with SYST:ERR? and
    # read back; no *OPC? (not in this profile)
    level = ["SOUR:CURR 1.5000", "SYST:ERR?", "SOUR:CURR?"]
    assert emu.commands == ["*IDN?", *level, *level, "OUTP ON", "SYST:ERR?", "OUTP?",
                            "OUTP OFF", "SYST:ERR?", "OUTP?"]


def test_a_current_beyond_the_source_is_its_error(source):
    emu, dev = source
    with pytest.raises(InstrumentError) as err:
        dev.set_level(5.0)
    assert str(err.value) == "lamp: 'SOUR:CURR 5.0000' refused: -222,\"Data out of range\""
    assert not err.value.transient and emu.current_a == 1.5


@pytest.mark.parametrize("transport", FAULT_TRANSPORTS)
@pytest.mark.parametrize("kind", ["drop", "corrupt"])
def test_a_switch_lost_on_the_wire_is_caught_by_the_read_back(source, kind):
    """A silent setter that never arrives gives no error at all: only reading the output back shows it
    (a garbled one also shows in the queue). Either way a transient fault, never a lamp thought off."""
    emu, dev = source
    dev.set_on(True)
    emu.faults.add(kind, match="OUTP")
    with pytest.raises((InstrumentCommError, InstrumentError)) as err:
        dev.set_on(False)
    assert err.value.transient and emu.output
    dev.set_on(False)
    assert not emu.output


def _retried(fn):
    """``fn()``, once more after a transient fault (as the runner retries a step)."""
    try:
        return fn()
    except InstrumentCommError:
        return fn()


def test_a_power_cycled_source_comes_back_off_and_switching_on_restores_its_current(source, transport):
    emu, dev = source
    dev.set_on(True)
    emu.power_off(unplug=True)
    emu.power_on()
    # pyvisa-py reads a SOCKET whose peer closed as silence: one time-out, then it reconnects
    ask = _retried if transport == "visa-socket" else (lambda fn: fn())
    assert not ask(dev.is_on) and emu.current_a == 0.0
    dev.set_on(True)
    assert emu.on and emu.current_a == 1.5
