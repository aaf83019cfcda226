"""Dynamixel Protocol 2.0 servos (X-series) through dynamixel-sdk.

- :class:`DynamixelBus`: one port, one lock, typed errors, retries and reconnection.
- :class:`DynamixelAxis`: one servo as a :class:`gonio.protocols.Axis`.
- :class:`DynamixelGroup`: several axes of one bus, one Sync Write / Sync Read per step.
"""

from gonio.drivers.dynamixel.axis import AxisState, DynamixelAxis, DynamixelGroup
from gonio.drivers.dynamixel.bus import DynamixelBus
from gonio.drivers.dynamixel.control_table import TABLES, XL430, XM430, ControlTable, Field
from gonio.drivers.dynamixel.errors import (
    DynamixelCommError,
    DynamixelError,
    DynamixelHardwareError,
    DynamixelStatusError,
    HardwareError,
    PacketError,
)

__all__ = [
    "AxisState", "DynamixelAxis", "DynamixelGroup", "DynamixelBus", "TABLES", "XL430", "XM430",
    "ControlTable", "Field", "DynamixelCommError", "DynamixelError", "DynamixelHardwareError",
    "DynamixelStatusError", "HardwareError", "PacketError",
]
