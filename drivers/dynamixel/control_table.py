"""Dynamixel X-series control tables as data: one :class:`ControlTable` per model family.

Addresses, sizes and units are from the ROBOTIS e-Manual control tables of the XM430-W350 and the
XL430-W250 (Protocol 2.0). The two differ where it matters to gonio: the XL430 has no current sensing
(address 126 is Present Load, in 0.1 % of the maximum torque), no Goal Current and no current-based
position mode (5).

Indirect Address 1..28 (168..223, RAM, 2 bytes each) point by default at Indirect Data 1..28 (224..251,
RAM, 1 byte each, 0 at power-up): left at their defaults, the Indirect Data bytes are plain RAM that a
power cycle or a reboot zeroes. gonio keeps its reference marker there (:mod:`.reference`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

__all__ = ["Field", "ControlTable", "XM430", "XL430", "TABLES", "table_for_model"]


@dataclass(frozen=True)
class Field:
    """One control-table item: ``address``, ``size`` in bytes, signedness, and whether it is EEPROM
    (writable only while torque is off)."""

    name: str
    address: int
    size: int
    signed: bool = False
    eeprom: bool = False

    def encode(self, value: int) -> int:
        """The unsigned integer the SDK writes for ``value`` (two's complement for signed fields)."""
        bits = 8 * self.size
        lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if self.signed else (0, (1 << bits) - 1)
        if not lo <= value <= hi:
            raise ValueError(f"dynamixel field '{self.name}': value {value} is outside [{lo}, {hi}]")
        return value & ((1 << bits) - 1)

    def decode(self, raw: int) -> int:
        """The value of the unsigned integer the SDK read (the SDK never sign-extends)."""
        bits = 8 * self.size
        raw &= (1 << bits) - 1
        if self.signed and raw >= 1 << (bits - 1):
            raw -= 1 << bits
        return raw


def _fields(*items: Field) -> dict[str, Field]:
    return {f.name: f for f in items}


_COMMON = (
    Field("model_number", 0, 2, eeprom=True),
    Field("firmware_version", 6, 1, eeprom=True),
    Field("id", 7, 1, eeprom=True),
    Field("baud_rate", 8, 1, eeprom=True),
    Field("return_delay_time", 9, 1, eeprom=True),
    Field("drive_mode", 10, 1, eeprom=True),
    Field("operating_mode", 11, 1, eeprom=True),
    Field("homing_offset", 20, 4, signed=True, eeprom=True),
    Field("moving_threshold", 24, 4, eeprom=True),
    Field("temperature_limit", 31, 1, eeprom=True),
    Field("max_voltage_limit", 32, 2, eeprom=True),
    Field("min_voltage_limit", 34, 2, eeprom=True),
    Field("velocity_limit", 44, 4, eeprom=True),
    Field("max_position_limit", 48, 4, signed=True, eeprom=True),
    Field("min_position_limit", 52, 4, signed=True, eeprom=True),
    Field("shutdown", 63, 1, eeprom=True),
    Field("torque_enable", 64, 1),
    Field("led", 65, 1),
    Field("status_return_level", 68, 1),
    Field("registered_instruction", 69, 1),
    Field("hardware_error_status", 70, 1),
    Field("bus_watchdog", 98, 1, signed=True),
    Field("goal_pwm", 100, 2, signed=True),
    Field("goal_velocity", 104, 4, signed=True),
    Field("profile_acceleration", 108, 4),
    Field("profile_velocity", 112, 4),
    Field("goal_position", 116, 4, signed=True),
    Field("realtime_tick", 120, 2),
    Field("moving", 122, 1),
    Field("moving_status", 123, 1),
    Field("present_pwm", 124, 2, signed=True),
    Field("present_velocity", 128, 4, signed=True),
    Field("present_position", 132, 4, signed=True),
    Field("velocity_trajectory", 136, 4, signed=True),
    Field("position_trajectory", 140, 4, signed=True),
    Field("present_input_voltage", 144, 2),
    Field("present_temperature", 146, 1),
    # Indirect Address 17..28 and Indirect Data 17..28: the reference marker's home (see .reference).
    Field("indirect_address_17", 200, 2),
    Field("indirect_data_17", 240, 1),
)
#: Indirect Data 1..28 (224..251): RAM bytes, readable and writable, 0 at power-up.
_INDIRECT_DATA = range(224, 252)
#: Indirect Address 1..28 (168..223).
_INDIRECT_ADDRESS = range(168, 224)


@dataclass(frozen=True)
class ControlTable:
    """A model family's control table and units.

    Attributes
    ----------
    family : str
        Family name, e.g. ``"XM430"``.
    model_numbers : dict
        Model number (as a ping returns it) -> model name.
    fields : dict
        Field name -> :class:`Field`.
    ticks_per_rev : int
        Encoder ticks per servo revolution.
    velocity_unit_rpm, accel_unit_rpm2 : float
        Profile Velocity unit (rev/min) and Profile Acceleration unit (rev/min²).
    profile_accel_max : int
        Largest Profile Acceleration value.
    current_unit_a : float or None
        Present Current unit (A); None where the family reports load instead of current.
    position_mode_range, extended_mode_range : tuple of int
        Goal Position ranges in position mode (3) and extended position mode (4), ticks.
    """

    family: str
    model_numbers: dict[int, str]
    fields: dict[str, Field]
    ticks_per_rev: int = 4096
    velocity_unit_rpm: float = 0.229
    accel_unit_rpm2: float = 214.577
    profile_accel_max: int = 32767
    current_unit_a: float | None = 0.00269
    voltage_unit_v: float = 0.1
    position_mode_range: tuple[int, int] = (0, 4095)
    extended_mode_range: tuple[int, int] = (-1_048_575, 1_048_575)
    operating_modes: dict[str, int] = field(default_factory=lambda: {"position": 3, "extended": 4})

    @cached_property
    def defined(self) -> frozenset[int]:
        """Every address an item of this table covers (what a read may touch without an access error
        on a servo that refuses undefined addresses)."""
        out = set(_INDIRECT_DATA) | set(_INDIRECT_ADDRESS)
        for f in self.fields.values():
            out.update(range(f.address, f.address + f.size))
        return frozenset(out)

    def room(self, address: int, length: int, most: int = 3) -> tuple[int, int]:
        """(before, after): how many defined addresses (at most ``most``) lie right before ``address``
        and right after ``address + length``: how far a read of that span may be widened."""
        defined = self.defined
        before = 0
        while before < most and address - before - 1 >= 0 and address - before - 1 in defined:
            before += 1
        after = 0
        while after < most and address + length + after in defined:
            after += 1
        return before, after

    def __getitem__(self, name: str) -> Field:
        try:
            return self.fields[name]
        except KeyError:
            raise KeyError(f"dynamixel {self.family}: no control-table field {name!r}") from None


XM430 = ControlTable(
    family="XM430",
    model_numbers={1020: "XM430-W350", 1030: "XM430-W210"},
    fields=_fields(*_COMMON, Field("current_limit", 38, 2, eeprom=True),
                   Field("goal_current", 102, 2, signed=True),
                   Field("present_current", 126, 2, signed=True)),
    operating_modes={"position": 3, "extended": 4, "current_position": 5},
)

XL430 = ControlTable(
    family="XL430",
    model_numbers={1060: "XL430-W250"},
    fields=_fields(*_COMMON, Field("present_load", 126, 2, signed=True)),
    current_unit_a=None,
)

#: Family name -> table.
TABLES = {t.family: t for t in (XM430, XL430)}


def table_for_model(model_number: int) -> ControlTable:
    """The table of the family a pinged ``model_number`` belongs to."""
    for table in TABLES.values():
        if model_number in table.model_numbers:
            return table
    known = ", ".join(f"{n} ({m})" for t in TABLES.values() for n, m in t.model_numbers.items())
    raise ValueError(f"dynamixel: model number {model_number} is not one of {known}")
