"""Dynamixel Protocol 2.0 bytes: CRC vectors from the e-Manual, stuffing, and the exact packets that the
real dynamixel-sdk puts on the wire for each instruction the driver uses (seen by the emulator)."""

from __future__ import annotations

import pytest

from gonio.drivers.dynamixel import XM430, DynamixelAxis, DynamixelBus
from gonio.sim.emulators.dxl_packet import (
    Inst,
    PacketReader,
    crc16,
    instruction_packet,
    status_packet,
    stuff,
    unstuff,
)

# Packets printed in the ROBOTIS e-Manual (Protocol 2.0 instruction examples).
EMANUAL = {
    "ping id 1": "FF FF FD 00 01 03 00 01 19 4E",
    "read id 1 present position": "FF FF FD 00 01 07 00 02 84 00 04 00 1D 15",
    "write id 1 goal position 512": "FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89",
    "status ping id 1": "FF FF FD 00 01 07 00 55 00 06 04 26 65 5D",
    "sync read ids 1 2": "FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA",
    "sync write ids 1 2": "FF FF FD 00 FE 11 00 83 74 00 04 00 01 96 00 00 00 02 AA 00 00 00 82 87",
    "reboot id 1": "FF FF FD 00 01 03 00 08 2F 4E",
    "action id 1": "FF FF FD 00 01 03 00 05 02 CE",
    "reg write id 1 goal velocity 200": "FF FF FD 00 01 09 00 04 68 00 C8 00 00 00 AE 8E",
}


def h(text: str) -> bytes:
    return bytes.fromhex(text)


@pytest.mark.parametrize("name", sorted(EMANUAL))
def test_crc_matches_emanual_vectors(name):
    packet = h(EMANUAL[name])
    assert crc16(packet[:-2]).to_bytes(2, "little") == packet[-2:]


def test_packets_built_byte_for_byte():
    assert instruction_packet(1, Inst.PING) == h(EMANUAL["ping id 1"])
    assert instruction_packet(1, Inst.READ, h("84 00 04 00")) == h(EMANUAL["read id 1 present position"])
    assert instruction_packet(1, Inst.WRITE, h("74 00 00 02 00 00")) == \
        h(EMANUAL["write id 1 goal position 512"])
    assert status_packet(1, 0, h("06 04 26")) == h(EMANUAL["status ping id 1"])
    assert instruction_packet(1, Inst.REBOOT) == h(EMANUAL["reboot id 1"])
    assert instruction_packet(1, Inst.ACTION) == h(EMANUAL["action id 1"])


def test_stuffing_inserts_fd_and_len_counts_it():
    body = h("55 00 FF FF FD 01")
    assert stuff(body) == h("55 00 FF FF FD FD 01")
    assert unstuff(stuff(body)) == body
    # A stuffed FD never starts a new pattern; two patterns in a row are each stuffed once.
    assert stuff(h("FF FF FD FF FF FD")) == h("FF FF FD FD FF FF FD FD")
    packet = status_packet(7, 0, h("FF FF FD 01"))
    assert packet[5:7] == (2 + 4 + 1 + 2).to_bytes(2, "little")  # INST ERR + 4 params + 1 stuffed + CRC
    (parsed,) = PacketReader().feed(b"\x00\x13" + packet)  # leading noise is skipped
    assert parsed.crc_ok and parsed.dxl_id == 7 and parsed.params == h("00 FF FF FD 01")


def test_reader_waits_for_whole_packets_and_flags_bad_crc():
    reader = PacketReader()
    packet = h(EMANUAL["ping id 1"])
    assert reader.feed(packet[:5]) == []
    (p,) = reader.feed(packet[5:])
    assert (p.dxl_id, p.inst, p.crc_ok) == (1, Inst.PING, True)
    (bad,) = reader.feed(packet[:-1] + b"\x00")
    assert not bad.crc_ok


def _bus(emu):
    bus = DynamixelBus(emu.port, name="dxl0")
    bus.connect()
    return bus


def test_sdk_sends_the_emanual_bytes(dxl_emu):
    bus = _bus(dxl_emu)
    try:
        def last(fn):
            n = len(dxl_emu.received)
            fn()
            assert dxl_emu.wait_received(n + 1)
            return dxl_emu.received[n]

        assert last(lambda: bus.ping(1)) == h(EMANUAL["ping id 1"])
        assert last(lambda: bus.read(1, XM430["present_position"])) == \
            h(EMANUAL["read id 1 present position"])
        bus.write(1, XM430["torque_enable"], 1)
        assert last(lambda: bus.write(1, XM430["goal_position"], 512)) == \
            h(EMANUAL["write id 1 goal position 512"])
        assert last(lambda: bus.sync_read(132, 4, [1, 2])) == h(EMANUAL["sync read ids 1 2"])
        assert last(lambda: bus.sync_write(XM430["goal_position"], {1: 150, 2: 170})) == \
            h(EMANUAL["sync write ids 1 2"])
        assert last(lambda: bus.reg_write(1, XM430["goal_velocity"], 200)) == \
            h(EMANUAL["reg write id 1 goal velocity 200"])
        assert last(lambda: bus.action(1)) == h(EMANUAL["action id 1"])
        assert last(lambda: bus.reboot(1)) == h(EMANUAL["reboot id 1"])
        items = [(1, XM430["present_position"]), (3, XM430["present_temperature"])]
        bulk = last(lambda: bus.bulk_read(items))
        assert bulk == instruction_packet(0xFE, Inst.BULK_READ, h("01 84 00 04 00 03 92 00 01 00"))
    finally:
        bus.close()


def test_transmit_side_is_stuffed(dxl_emu):
    """Goal -131073 ticks is FF FF FD FF on the wire: the driver's handler stuffs it (the SDK's own
    txPacket drops its stuffing), so the servo reads the value back intact."""
    bus = DynamixelBus(dxl_emu.port)
    axis = DynamixelAxis("spin", bus, 1, limits_deg=(-20000.0, 20000.0), operating_mode="extended",
                         homing_offset_ticks=0, clock=dxl_emu.servos[1].clock)
    axis.connect()
    try:
        n = len(dxl_emu.received)
        bus.write(1, XM430["goal_position"], -131073)
        assert dxl_emu.received[n] == instruction_packet(1, Inst.WRITE, h("74 00 FF FF FD FF"))
        assert h("FF FF FD FD FF") in dxl_emu.received[n]
        assert dxl_emu.servos[1].value(116) == -131073
    finally:
        axis.close()
