"""A toy Modbus family with its own behaviour (docs/EXTENDING.md): a drive that must be servo-enabled
before it moves. Its register map is ``toy_enable.toml`` beside this file; its behaviour, the axis class
below (the enable written at connect, released at close). ``GONIO_PLUGINS=toy_family`` loads it, and an
axis with ``driver = "modbus"``, ``profile = "toy_enable"`` is driven by :class:`ToyEnableAxis`."""

from pathlib import Path

from gonio.drivers.modbus.axis import ModbusAxis, ModbusCommError
from gonio.drivers.modbus.profile import FAMILIES


class ToyEnableAxis(ModbusAxis):
    """A ModbusAxis whose drive is enabled (``servo_on`` = 1) at connect and disabled at close."""

    def set_servo(self, on: bool) -> None:
        reg = self.profile["servo_on"]
        reply = self.client.write_register(reg.address, int(on), device_id=self.device_id)
        if reply.isError():
            raise ModbusCommError(self.name, f"servo {'on' if on else 'off'} refused: {reply}")

    def connect(self, readonly: bool = False) -> None:
        super().connect(readonly)
        if not readonly:
            self.set_servo(True)

    def close(self) -> None:
        try:
            self.set_servo(False)
        finally:
            super().close()


FAMILIES.add("toy_enable", ToyEnableAxis, "a drive enabled at connect and disabled at close",
             profile=Path(__file__).with_name("toy_enable.toml"))
