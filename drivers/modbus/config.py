"""The ``modbus`` driver's config models: a bus (``[buses.NAME] driver = "modbus"``, one TCP gateway or RTU
line) and a motor controller on it (``[axes.NAME] driver = "modbus"``). Registered in
:data:`gonio.registries.BUS_DRIVERS` and :data:`gonio.registries.AXIS_DRIVERS`; building the devices
imports pymodbus, validating does not.
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field, model_validator

from gonio.device_config import AxisConfig, BuildContext, BusConfig

__all__ = ["ModbusBusConfig", "ModbusAxisConfig"]


class ModbusBusConfig(BusConfig):
    driver: Literal["modbus"]
    #: ``tcp://host:port`` or ``rtu:///dev/ttyX?baudrate=N``.
    url: str = Field(pattern=r"^(tcp://[^/]+|rtu:///.+)$")
    timeout_s: float = Field(0.5, gt=0.0, le=10.0)
    retries: int = Field(1, ge=0, le=5)

    def open(self, name: str):
        from gonio.drivers.modbus.axis import make_client

        return make_client(self.url, timeout_s=self.timeout_s, retries=self.retries)


class ModbusAxisConfig(AxisConfig):
    """A Modbus motor controller whose registers a profile describes, driven by the axis class of the
    profile's family (:data:`gonio.drivers.modbus.profile.FAMILIES`; :class:`~gonio.drivers.modbus.ModbusAxis`
    for the shipped ones)."""

    driver: Literal["modbus"]
    bus_driver: ClassVar[str | None] = "modbus"

    #: Name of the ``[buses.NAME]`` section the controller is reached through.
    bus: str | None = None
    #: Modbus unit id.
    device_id: int | None = Field(None, ge=1, le=247)
    #: Register profile: a family's name (a shipped profile, or a plugin's) or a path to a TOML profile.
    profile: str = "generic"
    #: Motor revolutions per axis revolution.
    gear_ratio: float = Field(1.0, gt=0.0, le=10000.0)
    direction: Literal[1, -1] = 1
    #: Controller position (steps) at axis 0°.
    zero_steps: int = 0
    #: How the axis finds its absolute position after power-up: "none" (it never loses it) or "origin"
    #: (the controller's return-to-origin operation). Unset: "none" here; the axis itself takes
    #: "origin" where the profile's drive loses its position at power-off.
    reference: Literal["none", "hard_stop", "index", "origin"] | None = None
    #: How a pose's moves start where the profile has ``[sync_start]`` (held moves, one trigger):
    #: "auto" (together with the other such axes, in the mode their links allow: one RTU line ->
    #: "group", each unit behind its own TCP gateway -> "back_to_back"), a mode by name ("group",
    #: "broadcast": every unit of the line executes it, "back_to_back"), or "off" (axis by axis).
    sync_start: Literal["auto", "off", "group", "broadcast", "back_to_back"] = "auto"

    @model_validator(mode="after")
    def _names_its_unit(self):
        if self.device_id is None:
            raise ValueError("device_id: a modbus axis names its unit id (1..247)")
        return self

    @model_validator(mode="after")
    def _mode_its_profile_has(self):
        """A start mode by name needs the profile's ``[sync_start]`` (and its group send or broadcast)."""
        if self.sync_start in ("auto", "off"):
            return self
        from gonio.drivers.modbus.profile import load_profile

        try:
            sync = load_profile(self.profile).sync_start
        except (OSError, ValueError, KeyError):
            return self  # the profile's own error comes where the axis is built, naming it
        lacks = ("no [sync_start] (its manual gives no held move and trigger)" if sync is None
                 else "no group send (sync_start.group_register)" if self.sync_start == "group"
                 and sync.group_register is None
                 else "no broadcast (sync_start.broadcast)" if self.sync_start == "broadcast"
                 and not sync.broadcast else None)
        if lacks:
            raise ValueError(f"sync_start: {self.sync_start!r}, but profile '{self.profile}' has {lacks}; "
                             "one of auto, off")
        return self

    def bus_address(self) -> int | None:
        return self.device_id

    def reference_methods(self) -> tuple[tuple[str, ...], str]:
        return ("none", "origin"), "a 'modbus' axis"

    def build(self, name: str, ctx: BuildContext, start_deg: float | None = None):
        from gonio.drivers.modbus.axis import axis_class

        return axis_class(self.profile)(
            name, ctx.buses[self.bus], self.profile, device_id=self.device_id,
            limits_deg=(self.min_deg, self.max_deg), gear_ratio=self.gear_ratio, direction=self.direction,
            zero_steps=self.zero_steps, velocity_deg_s=self.max_velocity_deg_s,
            accel_deg_s2=self.max_accel_deg_s2, clock=ctx.clock, reference_method=self.reference,
            sync_start=self.sync_start)
