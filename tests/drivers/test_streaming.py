"""A photodiode's continuous mode through pyserial over a pty (profile ``streaming-photodiode``, its
emulator ``StreamingPhotodiodeEmulator``), on a SyncedVirtualClock that stops at each line's instant:
the commands on the wire, every line's stamp on the gantry clock, a rate off the configured one, and
each stream fault (a dropped, garbled, truncated or late line, an overflow, a lost port)."""

from __future__ import annotations

import time
from importlib.resources import files

import numpy as np
import pytest
import serial

from gonio.drivers.serial import InstrumentCommError, InstrumentError, StreamingPowerMeter
from gonio.drivers.serial.profile import load_profile, parse_profile
from gonio.drivers.serial.stream import fit_sample_clock
from gonio.protocols import Detector, Streams
from gonio.sim.emulators.instruments import StreamingPhotodiodeEmulator
from gonio.sim.emulators.link import SyncedVirtualClock

RATE = 200.0
P = 1.0 / RATE
DELAY = load_profile("streaming-photodiode").power_meter.stream.delay_s


def _signal(exposure_s: float) -> float:
    return 3.0e4 * exposure_s


def _read(dev, last: int):
    """The stream once the reader thread has taken line ``last`` (read off the pty before the clock
    moved on, but handed over in the reader's own time; bounded)."""
    deadline = time.monotonic() + 5.0
    s = dev.read_stream()
    while (not len(s.index) or s.index[-1] < last) and time.monotonic() < deadline:
        time.sleep(0.001)
        s = dev.read_stream()
    return s


@pytest.fixture
def streaming():
    clock = SyncedVirtualClock(10.0)
    made = []

    def make(**kw):
        emu = StreamingPhotodiodeEmulator(_signal, clock=clock, **kw)
        emu.start()
        clock.attach(emu.drain, emu.next_due)
        dev = StreamingPowerMeter("pd", emu.port, "streaming-photodiode", timeout_s=0.5, clock=clock)
        made.append((emu, dev))
        dev.connect()
        return emu, dev

    yield clock, make
    for emu, dev in made:
        dev.close()
        clock.detach(emu.drain)
        emu.stop()
        assert emu.error is None, f"the emulator's thread died of {emu.error!r}"


def test_declares_the_stream_ability_and_does_no_io_in_its_constructor():
    dev = StreamingPowerMeter("d", "/nonexistent", "streaming-photodiode")
    assert isinstance(dev, Streams) and isinstance(dev, Detector)
    with pytest.raises(ValueError, match="has no \\[power_meter.stream\\]"):
        StreamingPowerMeter("d", "/nonexistent", "acknowledging")


def test_stream_commands_on_the_wire_and_every_line_stamped_where_its_sample_ended(streaming):
    clock, make = streaming
    emu, dev = make()
    assert dev.start_stream() == P
    t0 = clock.now()   # the emulator starts integrating when STRM ON reaches it
    clock.sleep(0.5)
    s = _read(dev, 98)
    # 100 samples have ended by 0.5 s; the 100th line is still on its way (delay + its transfer)
    assert s.index.tolist() == list(range(99)) and s.missing == () and not s.warnings
    np.testing.assert_allclose(s.t_end_s, t0 + (s.index + 1) * P, rtol=0, atol=1e-9)
    np.testing.assert_allclose(s.values[:, 0], _signal(P), rtol=1e-8)
    assert s.period_s == pytest.approx(P, abs=1e-12)
    dev.stop_stream()
    # a stream a killed process left running is stopped first, at connect
    assert emu.commands == ["STRM OFF", "*IDN?", "STRM:RATE 200", "STRM ON", "STRM OFF"]
    assert emu.streaming is False
    # the link is in step: a reading on request answers its own request
    reading = dev.measure(0.05)
    assert reading.signal[0] == pytest.approx(_signal(0.05))
    assert emu.commands[-2:] == ["CONF:EXP 0.05", "MEAS?"]


def test_a_stream_running_fast_is_journaled_and_stamped_at_its_own_period(streaming):
    clock, make = streaming
    emu, dev = make(clock_error=0.02)   # the instrument's crystal runs 2 % fast
    dev.start_stream()
    t0 = clock.now()
    clock.sleep(1.0)
    s = _read(dev, 202)
    true_p = P / 1.02
    assert len(s.warnings) == 1 and "+/-" not in s.warnings[0] and "-1.96 %" in s.warnings[0], s.warnings
    assert s.period_s == pytest.approx(true_p, rel=1e-6)
    np.testing.assert_allclose(s.t_end_s, t0 + (s.index + 1) * true_p, rtol=0, atol=1e-8)
    dev.stop_stream()


@pytest.mark.parametrize("kind, missing, garbage", [("drop", [(4, 5)], 0), ("corrupt", [(4, 5)], 1),
                                                    ("truncate", [(4, 6)], 1), ("late", [], 0)])
def test_a_lost_or_garbled_line_is_a_gap_and_a_late_burst_keeps_its_stamps(streaming, kind, missing, garbage):
    clock, make = streaming
    emu, dev = make()
    dev.start_stream()
    t0 = clock.now()
    clock.sleep(0.025)                       # lines 0..3 sent (line 4 is on its way)
    emu.faults.add(kind, match="SAMPLE", times=3 if kind == "late" else 1)
    clock.sleep(0.1)
    s = _read(dev, 23)                       # lines 0..23 have ended by 0.125 s and arrived
    assert s.index[-1] == 23 and list(s.missing) == missing and dev._reader.garbage == garbage
    got = set(s.index.tolist())
    assert got == set(range(s.index[-1] + 1)) - {k for a, b in missing for k in range(a, b)}
    # a late burst (lines 4, 5, 6 held back and sent with line 7) arrives late, stamped where it ended
    np.testing.assert_allclose(s.t_end_s, t0 + (s.index + 1) * P, rtol=0, atol=1e-9)
    dev.stop_stream()
    lost = sum(b - a for a, b in missing)
    assert dev.warnings() == ([f"stream: {lost} of {len(s.index) + lost} lines lost (samples "
                               f"{missing[0][0]}..{missing[0][1] - 1}; {garbage} garbled); a reading they "
                               "fell in was read again"] if missing else [])


def test_an_unread_stream_overflows_the_instruments_buffer_and_the_counter_shows_the_gap():
    clock = SyncedVirtualClock()
    emu = StreamingPhotodiodeEmulator(_signal, clock=clock, buffer_bytes=60)
    emu.start()
    try:
        with serial.Serial(emu.port, 115200, timeout=0.5) as port:
            port.write(b"STRM:RATE 200\nSTRM ON\n")
            assert port.readline() == b"OK\n" and port.readline() == b"OK\n"
            clock.attach(emu.drain, emu.next_due)
            clock.sleep(0.1)                      # nobody reads: the buffer fills after three lines
            assert emu.overflowed > 0
            lines = [port.readline() for _ in range(3)]
            assert [ln.split(b",")[0] for ln in lines] == [b"0", b"1", b"2"]
            clock.sleep(0.01)                     # read again: the lines go out again
            clock.detach(emu.drain)
            port.write(b"STRM OFF\n")
            rest = []
            for _ in range(50):                  # bounded: the lines due at STRM OFF, then its OK
                rest.append(port.readline())
                if rest[-1] == b"OK\n":
                    break
            assert rest[-1] == b"OK\n" and int(rest[0].split(b",")[0]) > 3  # the counter skipped
    finally:
        emu.stop()


def test_a_rate_the_instrument_refuses_is_its_error_and_a_lost_port_a_transient_fault(streaming):
    clock, make = streaming
    emu, dev = make()
    dev.rate_hz = 5000.0                         # its lines would not fit 115200 baud
    with pytest.raises(InstrumentError, match="-222") as err:
        dev.start_stream()
    assert not err.value.transient
    dev.rate_hz = RATE
    dev.start_stream()
    with pytest.raises(ValueError, match="while the stream runs"):
        dev.measure(0.1)
    emu.link.unplug()
    deadline = time.monotonic() + 2.0
    while dev._reader.error is None and time.monotonic() < deadline:
        time.sleep(0.005)                        # the reader thread sees the port go
    with pytest.raises(InstrumentCommError, match="lost") as err:
        dev.read_stream()
    assert err.value.transient
    with pytest.raises(InstrumentCommError):
        dev.stop_stream()                        # its STRM OFF cannot go out: the port is dropped
    emu.replug()                                 # plugged in again: the next start reopens the port,
    assert emu.streaming                         # stops the stream that ran on meanwhile, starts anew
    dev.start_stream()
    clock.sleep(0.1)
    assert _read(dev, 18).index.tolist() == list(range(19))
    dev.stop_stream()


def test_the_clock_model_is_the_lower_envelope_of_the_arrivals():
    rng = np.random.default_rng(5)
    k = np.arange(400)
    late = rng.exponential(0.002, k.size)        # link delays: never early
    late[::37] = 0.0                             # some lines come straight through
    t0, slope, spread = fit_sample_clock(k, 1.5 + 1e-6 * k + late)
    assert t0 == pytest.approx(1.5, abs=1e-9) and slope == pytest.approx(1e-6, abs=1e-9) and spread < 1e-5


def test_a_stream_needs_an_acknowledging_dialect():
    data = {"name": "x", "setters": "silent", "errors": "SYST:ERR?", "identify": "*IDN?",
            "power_meter": {"measure": ["MEAS?"], "stream": {"rate": "R {rate_hz}", "start": "S", "stop": "T",
                                                             "rate_hz": 10.0}}}
    with pytest.raises(ValueError, match="power_meter.stream: a stream needs setters = 'ok'"):
        parse_profile(data, "x.toml")


def test_a_stream_left_running_by_a_killed_process_is_stopped_at_connect(streaming):
    clock, make = streaming
    emu, first = make()
    first.start_stream()
    clock.sleep(0.05)
    first._reader.halt()
    first._t.close()                  # the process dies: its port closes, the instrument streams on
    clock.sleep(0.05)                 # lines nobody reads
    assert emu.streaming and emu.link.pending() > 0
    dev = StreamingPowerMeter("pd", emu.port, "streaming-photodiode", timeout_s=0.5, clock=clock)
    dev.connect()
    try:
        assert not emu.streaming and dev.identity == StreamingPhotodiodeEmulator.idn
        assert dev.measure(0.05).signal[0] == pytest.approx(_signal(0.05))
    finally:
        dev.close()


STREAMING = (files("gonio.drivers.serial") / "profiles" / "streaming-photodiode.toml").read_text()


@pytest.mark.parametrize("old, new, field", [
    ('rate = "STRM:RATE {rate_hz:g}"', 'rate = "STRM:RATE 200"',
     "power_meter.stream.rate: 'STRM:RATE 200' must take"),
    ('start = "STRM ON"\n', "", "power_meter.stream.start: missing"),
    ('format = "index,value"', 'format = "value"', "power_meter.stream.format: 'value' is not one of"),
    ('combine = "sum"', 'combine = "max"', "power_meter.stream.combine: 'max' is not one of"),
    ("rate_hz = 200.0", "rate_hz = 0", "power_meter.stream.rate_hz: 0 is outside (0, 100000]"),
    ("delay_s = 0.0002", "delay_s = -1", "power_meter.stream.delay_s: -1 is outside [0, 1]"),
    ('stop = "STRM OFF"', 'stop = "STRM OFF"\nburst = 4', "power_meter.stream.burst: unknown key"),
])
def test_a_malformed_stream_section_is_one_line_naming_the_field(tmp_path, old, new, field):
    assert old in STREAMING
    path = tmp_path / "mine.toml"
    path.write_text(STREAMING.replace(old, new))
    with pytest.raises(ValueError) as err:
        load_profile(path)
    assert str(err.value).startswith(f"instrument profile {path}: ") and field in str(err.value)


def test_the_config_builds_the_streaming_driver_where_the_profile_streams_unless_told_not_to():
    from gonio.config import load_config, parse_config
    from gonio.wiring import build_gantry

    data = load_config("emulated-two-arm-dynamixel").model_dump(mode="json")
    data["detector"]["profile"] = "streaming-photodiode"
    assert isinstance(build_gantry(parse_config(data)).detector, StreamingPowerMeter)
    data["detector"]["stream"] = False
    det = build_gantry(parse_config(data)).detector
    assert not isinstance(det, Streams) and isinstance(det, Detector)
    data["detector"]["stream_rate_hz"] = 100.0
    with pytest.raises(ValueError, match="stream_rate_hz: set, but stream = false"):
        parse_config(data)
    data["detector"].update(profile="acknowledging", stream=True)
    with pytest.raises(ValueError, match="stream_rate_hz: profile acknowledging has no stream to run"):
        parse_config(data)
