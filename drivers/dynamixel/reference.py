"""Where a Dynamixel axis keeps its reference: a marker in the servo's own RAM.

An X-series servo in extended position mode counts turns while it is powered, but after power-up, a
reboot or a change of operating mode its Present Position restarts within one turn (e-Manual, Present
Position notes): behind a gear of ratio g the axis angle is then known only modulo 360°/g. Referencing
finds the whole turns (``correction``, ticks added to Present Position) once; it stays valid exactly as
long as the servo keeps counting, i.e. until its RAM is reset.

So the correction is kept where a power cycle erases it: Indirect Data 17..28 (addresses 240..251), RAM
bytes that read 0 after power-up and after a reboot, and that nothing else in gonio writes. The choice,
item by item (XM430-W350 / XL430-W250 control tables):

- Indirect Data: with Indirect Address 17..28 (200..222, also RAM) at their power-up defaults
  (240..251), the Indirect Data bytes are plain storage; gonio checks those defaults before it writes
  (a lab's program that maps Indirect Data 17..28 elsewhere would otherwise have gonio write into the
  items they point at) and uses the last twelve bytes, leaving 1..16 to such programs.
- Bus Watchdog(98): gonio arms and disarms it on every move and the servo sets it to -1 when it fires.
- LED(65), the gains, Goal PWM/Current/Velocity: writing them changes what the servo does or shows.
- EEPROM items (Homing Offset(20) and the rest) survive a power cycle: the opposite of what is needed,
  and they are written only with torque off.

The marker is 12 bytes, little endian: the correction (int32, ticks), when it was found (uint32, Unix
seconds), and a CRC-32 of the servo ID and those 8 bytes. Zeroed RAM fails the check, so does any
other content: only a marker gonio wrote for this servo passes.
"""

from __future__ import annotations

import zlib

__all__ = ["MARKER_ADDRESS", "MARKER_LEN", "INDIRECT_ADDRESS", "encode_marker", "decode_marker",
           "indirect_defaults"]

#: Indirect Data 17 (240): the marker's first byte; it spans Indirect Data 17..28.
MARKER_ADDRESS = 240
MARKER_LEN = 12
#: Indirect Address 17 (200): 12 two-byte pointers whose power-up defaults are 240..251.
INDIRECT_ADDRESS = 200
_SALT = b"gonio-reference"


def _check(dxl_id: int, body: bytes) -> bytes:
    return zlib.crc32(_SALT + bytes([dxl_id]) + body).to_bytes(4, "little")


def encode_marker(dxl_id: int, correction_ticks: int, stamp_s: int) -> bytes:
    """The 12 marker bytes for servo ``dxl_id``: ``correction_ticks`` found at Unix time ``stamp_s``."""
    body = int(correction_ticks).to_bytes(4, "little", signed=True) + (int(stamp_s) & 0xFFFFFFFF).to_bytes(
        4, "little")
    return body + _check(dxl_id, body)


def decode_marker(dxl_id: int, data: bytes) -> tuple[int, int] | None:
    """(correction ticks, stamp s) from marker bytes read from servo ``dxl_id``, or None when they are
    not a marker gonio wrote for it (zeroed by a power cycle or a reboot, or anything else)."""
    data = bytes(data)
    if len(data) != MARKER_LEN or data[8:] != _check(dxl_id, data[:8]):
        return None
    return int.from_bytes(data[:4], "little", signed=True), int.from_bytes(data[4:8], "little")


def indirect_defaults() -> bytes:
    """Indirect Address 17..28 at their power-up defaults (240..251, u16 each): 24 bytes."""
    return b"".join((MARKER_ADDRESS + i).to_bytes(2, "little") for i in range(MARKER_LEN))
