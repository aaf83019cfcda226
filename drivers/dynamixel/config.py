"""The ``dynamixel`` driver's config models: a bus (``[buses.NAME] driver = "dynamixel"``) and a servo axis
on it (``[axes.NAME] driver = "dynamixel"``). Registered in :data:`gonio.registries.BUS_DRIVERS` and
:data:`gonio.registries.AXIS_DRIVERS`; building the devices imports dynamixel-sdk, validating does not.
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field, model_validator

from gonio.device_config import AxisConfig, BuildContext, BusConfig

__all__ = ["DynamixelBusConfig", "DynamixelAxisConfig"]


class DynamixelBusConfig(BusConfig):
    driver: Literal["dynamixel"]
    #: Serial port of the bus (``/dev/serial/by-id/...``, ``/dev/ttyUSB0``).
    port: str = Field(min_length=1)
    baudrate: Literal[9600, 57600, 115200, 1_000_000, 2_000_000, 3_000_000, 4_000_000] = 1_000_000
    retries: int = Field(1, ge=0, le=5)
    #: The USB-serial adapter's latency timer (ms) each reply's time-out allows for twice: 16 ms is
    #: FTDI's default and the SDK's assumption; an adapter set to 1 ms may say 1.
    latency_timer_ms: float = Field(16.0, gt=0, le=500, allow_inf_nan=False)

    def open(self, name: str):
        from gonio.drivers.dynamixel.bus import DynamixelBus

        return DynamixelBus(self.port, self.baudrate, name=name, retries=self.retries,
                            latency_timer_ms=self.latency_timer_ms)


class DynamixelAxisConfig(AxisConfig):
    """A Dynamixel X-series servo (:class:`gonio.drivers.dynamixel.DynamixelAxis`)."""

    driver: Literal["dynamixel"]
    bus_driver: ClassVar[str | None] = "dynamixel"

    #: Name of the ``[buses.NAME]`` section the servo is on.
    bus: str | None = None
    #: Dynamixel servo ID.
    id: int | None = Field(None, ge=0, le=252)
    family: Literal["XM430", "XL430"] = "XM430"
    operating_mode: Literal["position", "extended"] = "position"
    #: Motor (servo) revolutions per axis revolution.
    gear_ratio: float = Field(1.0, gt=0.0, le=10000.0)
    direction: Literal[1, -1] = 1
    #: Dynamixel Present Position (ticks) at axis 0°.
    homing_offset_ticks: int = Field(0, ge=-1_048_575, le=1_048_575)
    #: Dynamixel bus watchdog while moving (s, up to 2.54; 0 disables it): a servo that hears nothing
    #: for this long mid-move stops by itself (gonio died). The runner reads moving servos every
    #: watchdog_s / 2, so it must be at least 4 x runner.poll_s. Off unless a config sets it.
    watchdog_s: float = Field(0.0, ge=0.0, le=2.54)
    #: How the axis finds its absolute position after power-up (``gonio gantry reference``): "none" (it
    #: never loses it: position mode), "hard_stop" (an XM430 approaches a mechanical stop at reference_deg
    #: in current-based position mode), "index" (it stands at reference_deg, within half a servo turn,
    #: when referenced: a mark, a pin). Unset: "none" in position mode, "index" in extended mode.
    reference: Literal["none", "hard_stop", "index", "origin"] | None = None
    #: Where the stop or index is (°, within the limits); unset: home_deg.
    reference_deg: float | None = None
    #: Hard stop: the direction (+1 / -1, axis degrees) of the approach; unset: toward the limit
    #: nearer reference_deg.
    reference_direction: Literal[1, -1] | None = None
    #: Hard stop: the approach speed (°/s); unset: a tenth of max_velocity_deg_s.
    reference_velocity_deg_s: float | None = Field(None, gt=0.0)
    #: Hard stop: Goal Current while approaching (A): the servo pushes against the stop no harder.
    reference_current_a: float = Field(0.3, gt=0.0, le=5.0)

    @model_validator(mode="after")
    def _names_its_servo(self):
        if self.id is None:
            raise ValueError("id: a dynamixel axis names its servo ID (0..252)")
        return self

    def bus_address(self) -> int | None:
        return self.id

    def check_in(self, cfg, where: str) -> None:
        # The runner reads the moving servos every watchdog_s / 2, checked between poll_s slices.
        poll = cfg.runner.poll_s
        if 0 < self.watchdog_s < 4 * poll:
            raise ValueError(f"{where}.watchdog_s: {self.watchdog_s} is below 4 x runner.poll_s "
                             f"({4 * poll:g} s); allowed: 0 (off) or [{4 * poll:g}, 2.54] s")

    # -- referencing ------------------------------------------------------------------------------------
    def reference_methods(self) -> tuple[tuple[str, ...], str]:
        allowed = ("hard_stop", "index") if self.operating_mode == "extended" else ("none",)
        return allowed, f"a dynamixel axis in {self.operating_mode} mode"

    def default_reference(self) -> str:
        return "index" if self.operating_mode == "extended" else "none"

    def check_reference(self) -> None:
        if self.reference_deg is not None and not self.min_deg <= self.reference_deg <= self.max_deg:
            raise ValueError(f"reference_deg: {self.reference_deg:g} is outside the axis limit "
                             f"[{self.min_deg:g}, {self.max_deg:g}]")
        super().check_reference()
        if self.reference_method == "hard_stop" and self.family != "XM430":
            raise ValueError(f"reference: 'hard_stop' needs current-based position mode, which the "
                             f"{self.family} lacks (allowed: index)")
        v = self.reference_velocity_deg_s
        if v is not None and v > self.max_velocity_deg_s:
            raise ValueError(f"reference_velocity_deg_s: {v:g} is above max_velocity_deg_s "
                             f"({self.max_velocity_deg_s:g})")

    @property
    def reference_at_deg(self) -> float:
        """Where the stop or index is (°): ``reference_deg``, else ``home_deg``."""
        return self.home_deg if self.reference_deg is None else self.reference_deg

    @property
    def reference_toward(self) -> int:
        """The hard stop's approach direction: ``reference_direction``, else toward the nearer limit."""
        if self.reference_direction is not None:
            return self.reference_direction
        at = self.reference_at_deg
        return -1 if at - self.min_deg <= self.max_deg - at else 1

    @property
    def reference_speed_deg_s(self) -> float:
        return self.reference_velocity_deg_s or self.max_velocity_deg_s / 10.0

    def build(self, name: str, ctx: BuildContext, start_deg: float | None = None):
        from gonio.drivers.dynamixel.axis import DynamixelAxis

        return DynamixelAxis(name, ctx.buses[self.bus], self.id, limits_deg=(self.min_deg, self.max_deg),
                             family=self.family, operating_mode=self.operating_mode,
                             gear_ratio=self.gear_ratio, direction=self.direction,
                             homing_offset_ticks=self.homing_offset_ticks,
                             velocity_deg_s=self.max_velocity_deg_s, accel_deg_s2=self.max_accel_deg_s2,
                             watchdog_s=self.watchdog_s, clock=ctx.clock, reference_method=self.reference)
