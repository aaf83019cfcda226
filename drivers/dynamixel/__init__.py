"""Dynamixel Protocol 2.0 servos (X-series) through dynamixel-sdk.

- :class:`DynamixelBus`: one port, one lock, typed errors, retries and reconnection.
- :class:`DynamixelAxis`: one servo as a :class:`gonio.protocols.Axis`.
- :class:`DynamixelGroup`: several axes of one bus, one Sync Write / Sync Read per step.
- :mod:`.reference`: the reference marker an axis keeps in its servo's RAM.
- :mod:`.config`: the driver's config models (``driver = "dynamixel"`` axes and buses).
"""

from gonio.registry import lazy_attributes

#: Each public name -> the submodule it lives in (imported when the name is first used: the driver's
#: config model, gonio.config reads at every config load, must not import the driver's library).
_EXPORTS = {
    "AxisState": "state", "DynamixelAxis": "axis", "NotReferencedError": "axis", "DynamixelBus": "bus",
    "TABLES": "control_table", "XL430": "control_table", "XM430": "control_table",
    "ControlTable": "control_table", "Field": "control_table", "DynamixelCommError": "errors",
    "DynamixelError": "errors", "DynamixelHardwareError": "errors", "DynamixelStatusError": "errors",
    "HardwareError": "errors", "PacketError": "errors", "DynamixelGroup": "group",
}
__all__ = list(_EXPORTS)
__getattr__ = lazy_attributes(__name__, _EXPORTS)
