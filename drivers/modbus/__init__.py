"""Modbus motor controllers (pymodbus), table-driven: every address, word order, unit, command and status
bit comes from a TOML profile (``profiles/*.toml``: generic, Oriental Motor AZ direct data operation,
Leadshine PR mode)."""

from gonio.drivers.modbus.axis import (
    ModbusAlarmError,
    ModbusAxis,
    ModbusCommError,
    ModbusExceptionError,
    make_client,
)
from gonio.drivers.modbus.profile import PROFILES, MotorProfile, Register, load_profile, parse_profile

__all__ = ["ModbusAlarmError", "ModbusAxis", "ModbusCommError", "ModbusExceptionError", "make_client",
           "PROFILES", "MotorProfile", "Register", "load_profile", "parse_profile"]
