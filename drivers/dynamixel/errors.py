"""Dynamixel errors: the hardware error status as an IntFlag, the status packet's error number, and the
typed exceptions (all :class:`gonio.protocols.DeviceFault`)."""

from __future__ import annotations

import enum

from gonio.protocols import DeviceFault

__all__ = ["HardwareError", "PacketError", "DynamixelError", "DynamixelCommError",
           "DynamixelStatusError", "DynamixelHardwareError", "ALERT_BIT"]

#: Bit 7 of a status packet's ERROR byte: the servo has a hardware error (read Hardware Error Status).
ALERT_BIT = 0x80


class HardwareError(enum.IntFlag):
    """Hardware Error Status (address 70) of an X-series servo."""

    INPUT_VOLTAGE = 0x01
    OVERHEATING = 0x04
    MOTOR_ENCODER = 0x08
    ELECTRICAL_SHOCK = 0x10
    OVERLOAD = 0x20

    def describe(self) -> str:
        """A readable list, e.g. ``"overheating + overload"`` (unknown bits shown in hex)."""
        names = [m.name.lower().replace("_", " ") for m in HardwareError if m in self]
        unknown = int(self) & ~sum(int(m) for m in HardwareError)
        if unknown:
            names.append(f"unknown bits 0x{unknown:02X}")
        return " + ".join(names) or "none"


class PacketError(enum.IntEnum):
    """The error number in the low 7 bits of a status packet's ERROR byte."""

    RESULT_FAIL = 1
    INSTRUCTION = 2
    CRC = 3
    DATA_RANGE = 4
    DATA_LENGTH = 5
    DATA_LIMIT = 6
    ACCESS = 7

    def describe(self) -> str:
        return {
            1: "result fail (the instruction could not be processed)",
            2: "instruction error (undefined instruction, or action without reg write)",
            3: "CRC error (the servo received a corrupt packet)",
            4: "data range error (value out of range, or goal locked by a bus watchdog error)",
            5: "data length error",
            6: "data limit error (value outside the servo's limit)",
            7: "access error (read-only address, or EEPROM written with torque on)",
        }[int(self)]


class DynamixelError(DeviceFault):
    """A Dynamixel failure on ``device`` (the bus or axis name); ``dxl_id`` is the servo concerned."""

    def __init__(self, device: str, message: str, transient: bool = False, dxl_id: int | None = None):
        super().__init__(device, message, transient)
        self.dxl_id = dxl_id


class DynamixelCommError(DynamixelError):
    """No reply, a corrupt reply, or a lost port: may be retried (``transient=True``)."""

    def __init__(self, device: str, message: str, dxl_id: int | None = None, result: int | None = None):
        super().__init__(device, message, transient=True, dxl_id=dxl_id)
        self.result = result


class DynamixelStatusError(DynamixelError):
    """The servo refused an instruction (the status packet's error number)."""

    def __init__(self, device: str, message: str, dxl_id: int, error: PacketError):
        super().__init__(device, message, transient=False, dxl_id=dxl_id)
        self.error = error


class DynamixelHardwareError(DynamixelError):
    """A latched hardware error (overload, overheating, ...): cleared only by a reboot."""

    def __init__(self, device: str, message: str, dxl_id: int, flags: HardwareError):
        super().__init__(device, message, transient=False, dxl_id=dxl_id)
        self.flags = flags
