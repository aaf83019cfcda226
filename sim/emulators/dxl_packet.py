"""Dynamixel Protocol 2.0 packets, byte for byte: CRC-16, byte stuffing, instruction and status packets.

Packet: ``FF FF FD 00``, ID, LEN (u16 LE = bytes after LEN, i.e. INST + params + CRC, after stuffing),
INST, params, CRC (u16 LE). The CRC is CRC-16/BUYPASS (polynomial 0x8005, init 0, no reflection, no
final XOR) over every byte before it, stuffed bytes included. Stuffing: inside INST..params, every
``FF FF FD`` is followed by an extra ``FD``.

References
----------
ROBOTIS e-Manual, "DYNAMIXEL Protocol 2.0" (packet, CRC, byte stuffing, instruction and status packets).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "HEADER", "BROADCAST_ID", "STATUS", "Inst", "crc16", "stuff", "unstuff", "instruction_packet",
    "status_packet", "Packet", "PacketReader",
]

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
STATUS = 0x55


class Inst:
    """Instruction codes used by gonio (Protocol 2.0)."""

    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    REBOOT = 0x08
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83
    BULK_READ = 0x92


def _crc_table() -> list[int]:
    table = []
    for i in range(256):
        c = i << 8
        for _ in range(8):
            c = ((c << 1) ^ 0x8005) if c & 0x8000 else (c << 1)
        table.append(c & 0xFFFF)
    return table


_TABLE = _crc_table()


def crc16(data: bytes) -> int:
    """CRC-16 of ``data`` as Protocol 2.0 defines it (poly 0x8005, init 0, MSB first, no final XOR)."""
    crc = 0
    for b in data:
        crc = ((crc << 8) ^ _TABLE[((crc >> 8) ^ b) & 0xFF]) & 0xFFFF
    return crc


def stuff(body: bytes) -> bytes:
    """Insert an ``FD`` after every ``FF FF FD`` in ``body`` (INST + params)."""
    out = bytearray()
    for b in body:
        out.append(b)
        if b == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF:
            # Count only original bytes: a stuffed FD itself never starts a new pattern.
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes) -> bytes:
    """Remove the ``FD`` that follows every ``FF FF FD`` (the inverse of :func:`stuff`)."""
    out = bytearray()
    i = 0
    while i < len(body):
        out.append(body[i])
        if body[i] == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF \
                and i + 1 < len(body) and body[i + 1] == 0xFD:
            i += 1
        i += 1
    return bytes(out)


def _frame(dxl_id: int, body: bytes) -> bytes:
    body = stuff(body)
    head = HEADER + bytes([dxl_id]) + (len(body) + 2).to_bytes(2, "little") + body
    return head + crc16(head).to_bytes(2, "little")


def instruction_packet(dxl_id: int, inst: int, params: bytes = b"") -> bytes:
    """The instruction packet for ``inst`` to ``dxl_id`` with ``params`` (stuffed, with its CRC)."""
    if not 0 <= dxl_id <= 0xFE:
        raise ValueError(f"dynamixel packet: id {dxl_id} is outside [0, 254]")
    return _frame(dxl_id, bytes([inst]) + bytes(params))


def status_packet(dxl_id: int, error: int, params: bytes = b"") -> bytes:
    """The status packet (INST 0x55) a servo sends: ERROR byte then ``params``."""
    return _frame(dxl_id, bytes([STATUS, error & 0xFF]) + bytes(params))


@dataclass(frozen=True)
class Packet:
    """A received packet, unstuffed. ``crc_ok`` is False when its CRC did not match."""

    dxl_id: int
    inst: int
    params: bytes
    crc_ok: bool = True
    raw: bytes = b""


class PacketReader:
    """Splits a byte stream into packets: skips noise before a header, waits for whole packets."""

    MAX_LEN = 1024

    def __init__(self) -> None:
        self._buf = bytearray()

    def feed(self, data: bytes) -> list[Packet]:
        self._buf += data
        out = []
        while True:
            start = self._buf.find(HEADER)
            if start < 0:
                # Keep a possible partial header at the end.
                del self._buf[: max(0, len(self._buf) - 3)]
                return out
            del self._buf[:start]
            if len(self._buf) < 7:
                return out
            length = int.from_bytes(self._buf[5:7], "little")
            if length < 3 or length > self.MAX_LEN:
                del self._buf[:4]
                continue
            total = 7 + length
            if len(self._buf) < total:
                return out
            raw = bytes(self._buf[:total])
            del self._buf[:total]
            crc_ok = crc16(raw[:-2]) == int.from_bytes(raw[-2:], "little")
            body = unstuff(raw[7:-2])
            out.append(Packet(raw[4], body[0], body[1:], crc_ok, raw))
