"""An emulator's serving thread outlives whatever a driver sends (it answers as the device's manual says),
and a thread that still dies (a bug) is told at once to whoever watches it, not kept where nobody looks.

Every emulator here is stopped by its test; every wait is bounded (an event, a condition), none a sleep.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time

import pytest
import serial
from pymodbus.framer.rtu import FramerRTU

from gonio.clock import VirtualClock
from gonio.config import load_config
from gonio.drivers.serial.transport import open_transport
from gonio.sim.emulators.dxl_packet import Inst, PacketReader, instruction_packet
from gonio.sim.emulators.dynamixel import DynamixelBusEmulator, EmulatedServo
from gonio.sim.emulators.gantry import EmulatedGantry
from gonio.sim.emulators.link import PtyLink
from gonio.sim.emulators.modbus import ModbusBusEmulator, ModbusMotorEmulator
from gonio.sim.emulators.scpi import Pm100Emulator

#: A bound on every wait for an emulator's thread (it answers within ms; a loaded machine may take more).
WAIT_S = 5.0


def _dxl(emu, packet: bytes):
    """Send ``packet`` on the bus; the status packets that came back once the emulator handled it."""
    n = emu.handled
    with serial.Serial(emu.port, 1_000_000, timeout=0) as port:
        port.write(packet)
        assert emu.wait_received(n + 1, WAIT_S), f"the bus emulator died: {emu.error!r}"
        return PacketReader().feed(port.read(1024))


def _write(dxl_id: int, address: int, data: bytes) -> bytes:
    return instruction_packet(dxl_id, Inst.WRITE, address.to_bytes(2, "little") + data)


def test_indirect_addresses_that_point_at_each_other_are_one_level_deep_and_the_bus_serves_on():
    """Indirect Address 1 at Indirect Data 2 and Indirect Address 2 at Indirect Data 1: a write to Indirect
    Data 1 lands one level down, as a read of it does; it used to chase the pointers until the serving
    thread died of a RecursionError, and the bus never answered again."""
    emu = DynamixelBusEmulator([EmulatedServo(1, clock=VirtualClock())])
    emu.start()
    try:
        assert [p.params for p in _dxl(emu, _write(1, 168, (225).to_bytes(2, "little")))] == [b"\x00"]
        assert [p.params for p in _dxl(emu, _write(1, 170, (224).to_bytes(2, "little")))] == [b"\x00"]
        # error 0: written at Indirect Data 2's own byte, which a read of Indirect Data 1 then returns
        assert [p.params for p in _dxl(emu, _write(1, 224, b"\x2a"))] == [b"\x00"]
        read = _dxl(emu, instruction_packet(1, Inst.READ, (224).to_bytes(2, "little") + b"\x01\x00"))
        assert [p.params for p in read] == [b"\x00\x2a"]
        assert [p.dxl_id for p in _dxl(emu, instruction_packet(1, Inst.PING))] == [1]
        assert emu.error is None
    finally:
        emu.stop()


def test_a_corrupt_packet_gets_a_crc_error_from_its_servo_and_noise_is_skipped():
    """Protocol 2.0: a servo answers an instruction packet whose CRC does not match with a status packet of
    error 3 (CRC error); nobody answers a corrupt broadcast; bytes before a header are noise. The bus
    answers the next packet either way (coverage of what the emulator already did)."""
    clock = VirtualClock()
    emu = DynamixelBusEmulator([EmulatedServo(1, clock=clock), EmulatedServo(2, clock=clock)])
    emu.start()
    try:
        corrupt = bytearray(instruction_packet(1, Inst.PING))
        corrupt[-1] ^= 0x5A
        assert [(p.dxl_id, p.params) for p in _dxl(emu, bytes(corrupt))] == [(1, b"\x03")]
        broadcast = bytearray(instruction_packet(0xFE, Inst.PING))
        broadcast[-2] ^= 0x01
        assert _dxl(emu, bytes(broadcast)) == []
        noisy = b"\x00\xff\xfd\x13\xff\xff" + instruction_packet(2, Inst.PING)
        assert [p.dxl_id for p in _dxl(emu, noisy)] == [2]
    finally:
        emu.stop()
    assert emu.error is None


@pytest.mark.parametrize("count", ["1E999", "-1E999"])
def test_a_number_past_any_double_is_out_of_range_in_the_error_queue_and_the_meter_serves_on(count):
    """``SENS:AVER:COUN 1E999`` is decimal numeric data (IEEE 488.2) too large for the meter: -222 in the
    error queue, as for any count past its range. It used to kill the meter's thread (OverflowError
    converting infinity to an integer): every later query timed out."""
    emu = Pm100Emulator(lambda exposure_s: 1e-6, clock=VirtualClock())
    emu.start()
    port = open_transport(emu.port, 115200, b"\n")
    try:
        port.write(f"SENS:AVER:COUN {count};SYST:ERR?\n".encode())
        assert port.read_until(b"\n", time.monotonic() + WAIT_S) == b'-222,"Data out of range"\n'
        port.write(b"SENS:AVER:COUN?;*IDN?\n")
        assert port.read_until(b"\n", time.monotonic() + WAIT_S) == f"1;{emu.idn}\n".encode()
        assert emu.error is None
    finally:
        port.close()
        emu.stop()


class Deaths:
    """A watcher's callback: what it was told, and an event set by the first telling."""

    def __init__(self):
        self.told: list[tuple] = []
        self.event = threading.Event()

    def __call__(self, *what) -> None:
        self.told.append(what)
        self.event.set()


def test_a_bus_emulator_whose_thread_dies_tells_its_watcher_at_once_with_the_exception(monkeypatch):
    """A bug in the serving loop (injected: the packet handler raises) ends the thread; the watcher is
    called from it with the exception, once, and :attr:`error` keeps it. The emulator still stops cleanly
    (its pty gone)."""
    bug = RuntimeError("injected: a bug in the packet handler")

    def handle(self, packet):
        raise bug

    monkeypatch.setattr(DynamixelBusEmulator, "_handle", handle)
    emu = DynamixelBusEmulator([EmulatedServo(1, clock=VirtualClock())])
    deaths = Deaths()
    emu.watch(deaths)
    emu.start()
    try:
        with serial.Serial(emu.port, 1_000_000, timeout=0) as port:
            port.write(instruction_packet(1, Inst.PING))
            assert deaths.event.wait(WAIT_S)
        assert deaths.told == [(bug,)] and emu.error is bug
        late = Deaths()
        emu.watch(late)  # watching a thread that died already: told at once
        assert late.told == [(bug,)]
    finally:
        emu.stop()
    assert not (emu.link.plugged or os.path.lexists(emu.port))


@pytest.mark.parametrize("line", ["one unit", "two units"])
def test_a_modbus_rtu_relay_that_dies_tells_its_watcher(monkeypatch, line):
    """On an RTU line (one unit, or several sharing it) the relay thread between the client's pty and
    pymodbus's server is watched as the server's thread is (a bug injected where it reads the bytes)."""
    bug = RuntimeError("injected: a bug on the line")

    def broken(self, timeout_s, wake=None):
        raise bug

    clock = VirtualClock()
    units = [ModbusMotorEmulator("generic", clock=clock, device_id=i) for i in (1, 2)]
    emu = units[0] if line == "one unit" else ModbusBusEmulator(units)
    deaths = Deaths()
    emu.watch(deaths)
    port = emu.start_rtu(115200)
    try:
        monkeypatch.setattr(PtyLink, "read", broken)
        with serial.Serial(port, 115200, timeout=0) as client:
            client.write(b"\x01\x03\x00\x00\x00\x01\x84\x0a")
            assert deaths.event.wait(WAIT_S)
        assert deaths.told == [(bug,)] and emu.error is bug
    finally:
        monkeypatch.undo()
        emu.stop()


def test_a_modbus_tcp_port_in_use_is_refused_at_start_naming_the_address(caplog):
    """A second server on a port another holds could not listen: its thread died while start_tcp
    returned as if it served (a traceback on stderr, then time-outs). Now start_tcp raises, naming the
    address, and nothing runs."""
    clock = VirtualClock()
    first, second = ModbusMotorEmulator(clock=clock), ModbusMotorEmulator(clock=clock)
    host, port = first.start_tcp(0)
    try:
        with caplog.at_level(logging.CRITICAL), pytest.raises(OSError, match=f"{host}:{port}.*in use"):
            second.start_tcp(port)
        assert second.error is None and second.address is None
    finally:
        second.stop()
        first.stop()


def _rtu(unit: int, pdu: bytes) -> bytes:
    frame = bytes([unit]) + pdu
    return frame + FramerRTU.compute_CRC(frame).to_bytes(2, "big")


#: Read Holding Registers of the generic profile's status word (address 274), one register.
READ_STATUS = b"\x03\x01\x12\x00\x01"


@pytest.mark.parametrize("line", ["one unit", "two units"])
def test_a_modbus_rtu_unit_answers_a_function_it_lacks_with_exception_1_and_drops_a_bad_crc(line):
    """Modbus over serial line: a request with a good CRC for a function the unit does not implement gets
    exception 1 (illegal function: the code with its high bit set); a request with a bad CRC gets no
    reply; the next request is answered either way. pymodbus's RTU framer answered the first with
    nothing and threw the request after it away (it skipped the unknown frame byte by byte into it)."""
    clock = VirtualClock()
    units = [ModbusMotorEmulator("generic", clock=clock, device_id=i) for i in (1, 2)]
    emu = units[0] if line == "one unit" else ModbusBusEmulator(units)
    status = _rtu(1, b"\x03\x02\x00\x01")  # its reply: one register, the ready bit (0) set
    try:
        with serial.Serial(emu.start_rtu(115200), 115200, timeout=WAIT_S) as client:
            client.write(_rtu(1, b"\x41\x00\x00\x00\x01"))
            assert client.read(5) == _rtu(1, b"\xc1\x01")
            client.write(_rtu(1, READ_STATUS))
            assert client.read(7) == status
            bad = bytearray(_rtu(1, READ_STATUS))
            bad[-1] ^= 0xFF
            client.write(bytes(bad))
            client.write(_rtu(1, READ_STATUS))  # what comes back first is this one's reply
            assert client.read(7) == status
        assert emu.error is None
    finally:
        emu.stop()


def test_a_modbus_tcp_unit_answers_a_function_it_lacks_with_exception_1_under_that_function():
    """Over TCP pymodbus answered exception 1 under function 0x80, whatever the request's; the spec's
    exception response carries the request's code with its high bit set (0x41 -> 0xC1)."""
    emu = ModbusMotorEmulator("generic", clock=VirtualClock())
    host, port = emu.start_tcp(0)
    try:
        with socket.create_connection((host, port), timeout=WAIT_S) as client:
            client.sendall(b"\x00\x07\x00\x00\x00\x06\x01\x41\x00\x00\x00\x01")
            reply = b""
            while len(reply) < 9:
                reply += client.recv(9 - len(reply))
            assert reply == b"\x00\x07\x00\x00\x00\x03\x01\xc1\x01"
    finally:
        emu.stop()


def test_an_emulated_gantry_left_cleanly_with_a_dead_emulator_says_which(monkeypatch):
    """``with EmulatedGantry(...)``, as the campaign tests use it: a serving thread that died is an error
    when the block ends (naming the bus and the device), not a test that passes or fails on time-outs."""
    bug = RuntimeError("injected: a bug in the serving loop")

    def step(self):
        raise bug

    monkeypatch.setattr(DynamixelBusEmulator, "step", step)
    before = set(threading.enumerate())
    emulated = EmulatedGantry(load_config("emulated-two-arm-dynamixel"), clock=VirtualClock(), any_port=True)
    deaths = Deaths()
    emulated.watch(deaths)
    says = r"buses\.arm: the emulator of the Dynamixel servos of light_azimuth, .* died of RuntimeError"
    with pytest.raises(RuntimeError, match=says) as err:
        with emulated:
            assert deaths.event.wait(WAIT_S)
    assert err.value.__cause__ is bug and deaths.told == [("arm", bug)]
    assert emulated.locations() == {}  # every emulator stopped
    assert not [t for t in threading.enumerate() if t not in before and t.name.startswith("emu-")]
