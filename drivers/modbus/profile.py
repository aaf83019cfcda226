"""Register maps of Modbus motor controllers, read from TOML profiles (``profiles/*.toml``).

A profile says where each quantity lives (address, 16/32-bit, signed), the word order of 32-bit values,
the units of velocity and acceleration, the block of registers a move writes (with its constant values,
e.g. the operation type and the trigger), the status bits (moving, alarm, ready) and how to stop and
reset an alarm. :class:`ModbusAxis` and the emulator both take everything from here.

Schema (all addresses are 0-based protocol addresses)::

    name, description, word_order = "big" | "little", steps_per_rev
    velocity_unit = "steps_per_s" | "rpm";  accel_unit = "steps_per_s2" | "ms_per_1000rpm"
    [registers.NAME] address, type = "u16" | "s16" | "u32" | "s32"
      (required: target_position, velocity, acceleration, deceleration, actual_position, status, alarm_code)
    [move] block = [NAMES written in one Write Multiple Registers], constants = {NAME = value}
    [status] moving_bit, alarm_bit, ready_bit (optional)
    [stop] register, value, release (value written after, optional)
    [alarm_reset] register, value, release (optional)
    [origin] register, value, release (optional): the controller's return-to-origin operation; with it
      [status] referenced_bit: set while the controller knows its origin (e.g. Oriental's HOME-END)
    absolute = true | false (default true): whether the drive keeps its position and origin across a
      power cycle; false (an incremental stepper): an axis on it is referenced by its origin operation
      before it moves, and again after every power cycle
    span_read = true | false (default false): the controller answers one Read Holding Registers from
      the lower of status/actual_position to the end of the higher across the registers between
      them (at most 125 words); adjacent registers are always read together
    write_read = true | false (default false): the controller supports function 23 (Read/Write
      Multiple Registers), so a move's block write also reads the status back in the same request
    [sync_start] (optional): how several units start together (:mod:`gonio.drivers.modbus.group`):
      hold = the value of the block's last register (the trigger) that stores the block's data without
      starting; a later write of that register alone, with its [move] constant, starts the move with
      the data held; group_register = NAME (optional): the unit's group address (the parent's
      address; -1 individual): a Write Multiple Registers to the parent is executed by every child;
      broadcast = true | false: the unit executes a write to address 0 (and answers none)
    secondary = [NAMES of fields taken from a secondary source, to verify on a real unit]
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

from gonio.registry import Registry

__all__ = ["Register", "Command", "SyncStart", "MotorProfile", "load_profile", "FAMILIES", "PROFILES"]

_TYPES = {"u16": (1, False), "s16": (1, True), "u32": (2, False), "s32": (2, True)}
_REQUIRED = ("target_position", "velocity", "acceleration", "deceleration", "actual_position", "status",
             "alarm_code")
#: What ``secondary`` may name besides registers: the scalar settings and the command/status tables.
_SECONDARY_KEYS = ("word_order", "steps_per_rev", "velocity_unit", "accel_unit", "move", "status bits",
                   "stop", "alarm_reset", "span_read", "write_read", "origin", "absolute")
#: The most registers one Read Holding Registers may ask for (Modbus application protocol, 6.3).
MAX_READ_WORDS = 125
#: Families of controllers, by the name an axis's ``profile`` gives: each entry's target is the axis class
#: that drives it (:class:`~gonio.drivers.modbus.axis.ModbusAxis`, or a subclass with the family's own
#: behaviour) and its ``profile`` extra the register map (a TOML file). A plugin adds a family with its
#: module and its profile (docs/EXTENDING.md).
FAMILIES = Registry("modbus family")
#: The shipped families (their profiles are ``profiles/NAME.toml``), driven by ModbusAxis as it is.
PROFILES = ("generic", "oriental_az_direct", "leadshine_pr")
for _name, _summary in zip(PROFILES, ("a plain register map for controllers configured by hand",
                                      "Oriental Motor AZ series, direct data operation",
                                      "Leadshine servo drives, PR (path) mode"), strict=True):
    FAMILIES.add(_name, "gonio.drivers.modbus.axis:ModbusAxis", _summary,
                 profile=resources.files("gonio.drivers.modbus").joinpath(f"profiles/{_name}.toml"))
del _name, _summary


@dataclass(frozen=True)
class Register:
    name: str
    address: int
    type: str

    @property
    def count(self) -> int:
        return _TYPES[self.type][0]

    @property
    def signed(self) -> bool:
        return _TYPES[self.type][1]

    def encode(self, value: int, word_order: str) -> list[int]:
        """The register words for ``value``; raises ValueError outside the type's range."""
        bits = 16 * self.count
        lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if self.signed else (0, (1 << bits) - 1)
        value = int(value)
        if not lo <= value <= hi:
            raise ValueError(f"modbus register '{self.name}': value {value} is outside [{lo}, {hi}]")
        raw = value & ((1 << bits) - 1)
        words = [(raw >> (16 * i)) & 0xFFFF for i in reversed(range(self.count))]  # high word first
        return words if word_order == "big" else words[::-1]

    def decode(self, words: list[int], word_order: str) -> int:
        words = list(words) if word_order == "big" else list(words)[::-1]
        raw = 0
        for w in words:
            raw = (raw << 16) | (w & 0xFFFF)
        bits = 16 * self.count
        if self.signed and raw >= 1 << (bits - 1):
            raw -= 1 << bits
        return raw


@dataclass(frozen=True)
class Command:
    """Write ``value`` to ``register``, then ``release`` if given (a pulse, e.g. an alarm reset)."""

    register: str
    value: int
    release: int | None = None


@dataclass(frozen=True)
class SyncStart:
    """How units of the profile start together: data held by the ``hold`` value of the ``trigger``
    register (the move block's last), started by a write of ``start`` to it alone; by group send (the
    unit's ``group_register``, or None) or broadcast."""

    trigger: str
    hold: int
    start: int
    group_register: str | None
    broadcast: bool


@dataclass(frozen=True)
class MotorProfile:
    name: str
    description: str
    word_order: str
    steps_per_rev: int
    velocity_unit: str
    accel_unit: str
    registers: dict[str, Register]
    move_block: tuple[str, ...]
    move_constants: dict[str, int]
    moving_bit: int
    alarm_bit: int
    ready_bit: int | None
    stop: Command
    alarm_reset: Command
    secondary: tuple[str, ...] = field(default=())
    span_read: bool = False
    write_read: bool = False
    origin: Command | None = None
    referenced_bit: int | None = None
    absolute: bool = True
    sync_start: SyncStart | None = None

    def __getitem__(self, name: str) -> Register:
        try:
            return self.registers[name]
        except KeyError:
            raise KeyError(f"modbus profile '{self.name}': no register {name!r}") from None

    @property
    def block_start(self) -> int:
        return self.registers[self.move_block[0]].address

    @property
    def state_span(self) -> tuple[int, int]:
        """(first address, word count) of the one read that holds both status and actual_position."""
        pos, st = self.registers["actual_position"], self.registers["status"]
        lo = min(pos.address, st.address)
        return lo, max(pos.address + pos.count, st.address + st.count) - lo

    @property
    def state_adjacent(self) -> bool:
        """Whether status and actual_position are side by side (their span holds nothing else)."""
        return self.state_span[1] == self.registers["actual_position"].count + self.registers["status"].count

    @property
    def state_block(self) -> tuple[int, int] | None:
        """The one read that gives status and actual position, where the profile allows it: always when
        they are adjacent, across the registers between them when ``span_read`` says so; else None."""
        return self.state_span if self.state_adjacent or self.span_read else None

    def velocity_value(self, motor_rev_s: float) -> int:
        """The velocity register value for ``motor_rev_s`` motor revolutions per second."""
        if self.velocity_unit == "rpm":
            return round(motor_rev_s * 60.0)
        return round(motor_rev_s * self.steps_per_rev)

    def velocity_rev_s(self, value: int) -> float:
        return value / 60.0 if self.velocity_unit == "rpm" else value / self.steps_per_rev

    def accel_value(self, motor_rev_s2: float) -> int:
        """The acceleration register value for ``motor_rev_s2`` motor rev/s²."""
        if self.accel_unit == "ms_per_1000rpm":
            # Milliseconds to go from 0 to 1000 rev/min.
            return round(1000.0 / 60.0 / motor_rev_s2 * 1000.0)
        return round(motor_rev_s2 * self.steps_per_rev)

    def accel_rev_s2(self, value: int) -> float:
        if self.accel_unit == "ms_per_1000rpm":
            return 1000.0 / 60.0 / (max(value, 1) / 1000.0)
        return value / self.steps_per_rev


def _fail(where: str, msg: str) -> ValueError:
    return ValueError(f"modbus profile {where}: {msg}")


def _command(where: str, d: dict, registers: dict) -> Command:
    if d.get("register") not in registers:
        raise _fail(where, f"register {d.get('register')!r} is not defined in [registers]")
    return Command(d["register"], int(d["value"]), None if d.get("release") is None else int(d["release"]))


def parse_profile(data: dict, where: str = "<dict>") -> MotorProfile:
    """Validate a profile's TOML table; errors name the field and what is allowed."""
    registers = {}
    for name, r in data.get("registers", {}).items():
        if r.get("type") not in _TYPES:
            raise _fail(where, f"registers.{name}.type {r.get('type')!r} is not one of {sorted(_TYPES)}")
        if not 0 <= int(r.get("address", -1)) <= 0xFFFF:
            raise _fail(where, f"registers.{name}.address {r.get('address')!r} is outside [0, 0xFFFF]")
        registers[name] = Register(name, int(r["address"]), r["type"])
    missing = [n for n in _REQUIRED if n not in registers]
    if missing:
        raise _fail(where, f"[registers] lacks {', '.join(missing)}")
    word_order = data.get("word_order", "big")
    if word_order not in ("big", "little"):
        raise _fail(where, f"word_order {word_order!r} is not one of 'big', 'little'")
    if data.get("velocity_unit") not in ("steps_per_s", "rpm"):
        raise _fail(where, f"velocity_unit {data.get('velocity_unit')!r} is not one of steps_per_s, rpm")
    if data.get("accel_unit") not in ("steps_per_s2", "ms_per_1000rpm"):
        raise _fail(where, f"accel_unit {data.get('accel_unit')!r} is not one of "
                    "steps_per_s2, ms_per_1000rpm")
    steps = int(data.get("steps_per_rev", 0))
    if steps < 1:
        raise _fail(where, f"steps_per_rev {steps} must be >= 1")
    move = data.get("move", {})
    block = tuple(move.get("block", ()))
    constants = {k: int(v) for k, v in move.get("constants", {}).items()}
    address = None
    for name in block:
        if name not in registers:
            raise _fail(where, f"move.block names {name!r}, not defined in [registers]")
        reg = registers[name]
        if address is not None and reg.address != address:
            raise _fail(where, f"move.block is not contiguous at {name!r} (address {reg.address:#06x}, "
                        f"expected {address:#06x})")
        address = reg.address + reg.count
    for name in ("target_position", "velocity", "acceleration", "deceleration"):
        if name not in block:
            raise _fail(where, f"move.block lacks {name!r}")
    for name in set(block) - {"target_position", "velocity", "acceleration", "deceleration"}:
        if name not in constants:
            raise _fail(where, f"move.block register {name!r} needs a value in move.constants")
    status = data.get("status", {})
    for key in ("moving_bit", "alarm_bit"):
        if not 0 <= int(status.get(key, -1)) <= 15:
            raise _fail(where, f"status.{key} {status.get(key)!r} is outside [0, 15]")
    flags = {}
    for key in ("span_read", "write_read", "absolute"):
        flags[key] = data.get(key, key == "absolute")
        if not isinstance(flags[key], bool):
            raise _fail(where, f"{key} {flags[key]!r} is not one of true, false")
    pos, st = registers["actual_position"], registers["status"]
    span = max(pos.address + pos.count, st.address + st.count) - min(pos.address, st.address)
    if flags["span_read"] and span > MAX_READ_WORDS:
        raise _fail(where, f"span_read: status ({st.address:#06x}) and actual_position ({pos.address:#06x}) "
                    f"span {span} registers, more than one read may ask for ({MAX_READ_WORDS})")
    origin = None if "origin" not in data else _command(f"{where} [origin]", data["origin"], registers)
    referenced_bit = status.get("referenced_bit")
    if (origin is None) != (referenced_bit is None):
        raise _fail(where, "[origin] and status.referenced_bit go together: the operation, and the bit that "
                    "says it is done")
    if referenced_bit is not None and not 0 <= int(referenced_bit) <= 15:
        raise _fail(where, f"status.referenced_bit {referenced_bit!r} is outside [0, 15]")
    if not flags["absolute"] and origin is None:
        raise _fail(where, "absolute = false needs an [origin] operation to reference the axis with")
    secondary = tuple(data.get("secondary", ()))
    known = set(registers) | set(_SECONDARY_KEYS)
    unknown = [n for n in secondary if n not in known]
    if unknown:  # a misspelt name would leave a field unmarked without a word
        raise _fail(where, f"secondary names {', '.join(map(repr, unknown))}: not a register nor one of "
                    f"{', '.join(_SECONDARY_KEYS)}")
    sync = _sync_start(where, data.get("sync_start"), registers, block, constants)
    return MotorProfile(
        name=data.get("name", where), description=data.get("description", ""), word_order=word_order,
        steps_per_rev=steps, velocity_unit=data["velocity_unit"], accel_unit=data["accel_unit"],
        registers=registers, move_block=block, move_constants=constants,
        moving_bit=int(status["moving_bit"]), alarm_bit=int(status["alarm_bit"]),
        ready_bit=None if status.get("ready_bit") is None else int(status["ready_bit"]),
        stop=_command(f"{where} [stop]", data.get("stop", {}), registers),
        alarm_reset=_command(f"{where} [alarm_reset]", data.get("alarm_reset", {}), registers),
        secondary=secondary, origin=origin,
        referenced_bit=None if referenced_bit is None else int(referenced_bit), sync_start=sync, **flags,
    )


def _sync_start(where: str, d, registers: dict, block: tuple, constants: dict) -> SyncStart | None:
    if d is None:
        return None
    trigger = block[-1]
    if trigger not in constants:
        raise _fail(where, f"[sync_start] needs a trigger: move.block's last register {trigger!r} with a "
                    "value in move.constants")
    hold = d.get("hold")
    if not isinstance(hold, int) or hold == constants[trigger]:
        raise _fail(where, f"sync_start.hold {hold!r} must be an integer other than the trigger's start "
                    f"value {constants[trigger]}")
    group = d.get("group_register")
    if group is not None and group not in registers:
        raise _fail(where, f"sync_start.group_register {group!r} is not defined in [registers]")
    broadcast = d.get("broadcast", False)
    if not isinstance(broadcast, bool):
        raise _fail(where, f"sync_start.broadcast {broadcast!r} is not one of true, false")
    return SyncStart(trigger, hold, constants[trigger], group, broadcast)


def load_profile(name_or_path: str | Path) -> MotorProfile:
    """The profile of a family by name (:data:`FAMILIES`) or a TOML file by path."""
    if str(name_or_path) in FAMILIES:
        text = FAMILIES[str(name_or_path)].extra["profile"].read_text()
        return parse_profile(tomllib.loads(text), str(name_or_path))
    path = Path(name_or_path)
    if not path.is_file():
        raise ValueError(f"modbus profile {str(name_or_path)!r} is neither one of "
                         f"{', '.join(FAMILIES.names())} nor a file")
    return parse_profile(tomllib.loads(path.read_text()), str(path))
