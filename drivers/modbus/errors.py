"""The Modbus driver's faults (a :class:`~gonio.protocols.DeviceFault` each): a link that failed, an
exception response, a controller alarm. Apart from the axis so that the start group raises them too
without importing the axis (which makes the group)."""

from __future__ import annotations

from gonio.protocols import DeviceFault

__all__ = ["ModbusCommError", "ModbusExceptionError", "ModbusAlarmError"]


class ModbusCommError(DeviceFault):
    def __init__(self, device: str, message: str):
        super().__init__(device, message, transient=True)


class ModbusExceptionError(DeviceFault):
    """The controller answered with exception ``code`` (1 illegal function, 2 illegal address, 3 illegal
    value, 4 device failure, 5 acknowledge, 6 busy, ...)."""

    def __init__(self, device: str, message: str, code: int):
        super().__init__(device, message, transient=code in (5, 6))
        self.code = code


class ModbusAlarmError(DeviceFault):
    def __init__(self, device: str, message: str, alarm_code: int):
        super().__init__(device, message, transient=False)
        self.alarm_code = alarm_code
