"""Dynamixel Protocol 2.0 servos (X-series) through dynamixel-sdk.

- :class:`DynamixelBus`: one port, one lock, typed errors, retries and reconnection.
- :class:`DynamixelAxis`: one servo as a :class:`gonio.protocols.Axis`.
- :class:`DynamixelGroup`: several axes of one bus, one Sync Write / Sync Read per step.
- :mod:`.reference`: the reference marker an axis keeps in its servo's RAM.
"""

from gonio.drivers.dynamixel.axis import AxisState, DynamixelAxis, NotReferencedError
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
from gonio.drivers.dynamixel.group import DynamixelGroup

__all__ = [
    "AxisState", "DynamixelAxis", "DynamixelGroup", "DynamixelBus", "TABLES", "XL430", "XM430",
    "ControlTable", "Field", "DynamixelCommError", "DynamixelError", "DynamixelHardwareError",
    "DynamixelStatusError", "HardwareError", "PacketError", "NotReferencedError",
]
