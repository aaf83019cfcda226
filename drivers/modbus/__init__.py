"""Modbus motor controllers (pymodbus), table-driven: every address, word order, unit, command and status
bit comes from a TOML profile (``profiles/*.toml``: generic, Oriental Motor AZ direct data operation,
Leadshine PR mode); :mod:`.config` holds the driver's config models (``driver = "modbus"``)."""

from gonio.registry import lazy_attributes

#: Each public name -> the submodule it lives in (imported when the name is first used: the driver's
#: config model, gonio.config reads at every config load, must not import the driver's library).
_EXPORTS = {
    "ModbusAlarmError": "errors", "ModbusAxis": "axis", "ModbusCommError": "errors",
    "ModbusExceptionError": "errors", "make_client": "axis", "PROFILES": "profile", "MotorProfile": "profile",
    "Register": "profile", "load_profile": "profile", "parse_profile": "profile",
    "ModbusStartGroup": "group", "SyncStartError": "group",
}
__all__ = list(_EXPORTS)
__getattr__ = lazy_attributes(__name__, _EXPORTS)
