"""Instrument profiles: the dialect and commands of a line instrument, read from TOML (``profiles/*.toml``).

A profile says how an instrument talks (its terminator; whether a setter answers ``OK`` or is silent;
how it reports errors: an ``ERR ...`` reply, or a queue read with ``SYST:ERR?``; how to wait for
completion, ``*OPC?``) and, per kind of device it can be, the commands gonio sends. The drivers in
:mod:`gonio.drivers.serial.instruments` take everything from here; the emulators do not (they are
written from the instruments' manuals, so a wrong command in a profile shows up as the instrument's
error).

Schema::

    name, description
    terminator = "\\n"            ends every command sent and every reply read
    setters = "silent" | "ok"    a setter gets no reply (SCPI), or answers ``ok_reply``
    ok_reply = "OK"              ("ok" dialect) the acknowledgement of a setter
    error_prefix = "ERR"         ("ok" dialect) a reply starting with it is the instrument's refusal
    errors = "SYST:ERR?"         ("silent" dialect) the error queue: ``<code>,"<message>"``, 0 when empty
    complete = "*OPC?"           optional: asked after setters, answers 1 once they are done
    identify = "*IDN?"           read at connect, journaled with the campaign
    reset = ["*RST", "*CLS"]     optional setters sent once at connect
    secondary = [fields]         fields taken from a secondary source, to verify on a real unit

    [light]                      on, off, state (a query: 1/0 or ON/OFF); optional: level (a setter with
                                 {percent} or {current_a}), level_query, ready (warm-up flag query, 1/0)
    [power_meter]                measure = [setters..., query] (the query's reply: one number);
                                 optional: configure = [setters] sent before each reading, with
                                 {exposure_s}, {count} (= exposure_s / sample_s, needs sample_s) or
                                 {wavelength_nm}; unit (of the reading, e.g. "W")
    [spectrometer]               as power_meter, the query's reply a comma-separated list; and
                                 wavelengths (a query: the bins' centres in nm)
    [power_meter.stream]         optional: a continuous mode (the instrument sends a line per sample at a
                                 set rate, unasked): rate (a setter with {rate_hz}), start, stop (setters),
                                 rate_hz (the default rate), format = "index,value" (each line: the
                                 instrument's sample counter from 0 at start, then the value),
                                 delay_s (from the end of a sample's integration to its line's first
                                 byte: the instrument's processing), combine = "sum" (a sample is the
                                 signal integrated over its period) or "mean" (a rate, e.g. W),
                                 rate_tolerance (relative: a stream whose period measured on the gantry
                                 clock differs more is journaled)

A number in a reply is SCPI decimal data (NR1, NR2 or NR3: ``42``, ``0.5``, ``1.234567E-03``); SCPI's
9.91E37 (not a number) and ±9.9E37 (overload) are not readings.
"""

from __future__ import annotations

import hashlib
import math
import re
import string
import tomllib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

__all__ = ["InstrumentProfile", "LightCommands", "MeterCommands", "StreamCommands", "STREAM_FORMATS",
           "load_profile", "parse_profile", "PROFILES",
           "DEFAULT_PROFILE", "DEVICE_KINDS", "parse_number", "parse_numbers", "parse_bool", "is_query",
           "command_fields"]

#: Shipped profiles, by name.
PROFILES = ("acknowledging", "thorlabs-pm100", "scpi-current-source", "streaming-photodiode")
#: The profile of a config that names none: gonio's own acknowledging line dialect.
DEFAULT_PROFILE = "acknowledging"
#: The kinds of device a profile may describe (its sections).
DEVICE_KINDS = ("light", "power_meter", "spectrometer")
#: Placeholders each command may hold.
_LEVEL_FIELDS = ("percent", "current_a")
_CONFIGURE_FIELDS = ("exposure_s", "count", "wavelength_nm")
_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")
#: SCPI-99: 9.91E37 is not-a-number, ±9.9E37 an overload (infinity).
_SCPI_NAN = 9.9e37
_TOP_KEYS = {"name", "description", "terminator", "setters", "ok_reply", "error_prefix", "errors", "complete",
             "identify", "reset", "secondary", *DEVICE_KINDS}
_LIGHT_KEYS = {"on", "off", "state", "level", "level_query", "ready"}
_METER_KEYS = {"configure", "sample_s", "measure", "unit", "wavelengths", "stream"}
_STREAM_KEYS = {"rate", "start", "stop", "rate_hz", "format", "delay_s", "combine", "rate_tolerance"}
#: The line formats a stream may have (the sample counter makes every dropped line visible).
STREAM_FORMATS = ("index,value",)


def is_query(command: str) -> bool:
    """Whether ``command`` is a query (its header ends in ``?``): it gets a reply in every dialect."""
    head = command.split(None, 1)[0] if command.strip() else ""
    return head.endswith("?")


def parse_number(text: str) -> float | None:
    """A SCPI decimal number (NR1/NR2/NR3), or None: not a number, NaN, infinite or SCPI's NaN/overload."""
    text = text.strip()
    if not _NUMBER.fullmatch(text):
        return None
    value = float(text)
    if not math.isfinite(value) or abs(value) >= _SCPI_NAN:
        return None
    return value


def parse_numbers(text: str) -> list[float] | None:
    """A comma-separated list of SCPI numbers, or None if any element is not one."""
    out = [parse_number(x) for x in text.split(",")]
    return None if not text.strip() or any(v is None for v in out) else out


def parse_bool(text: str) -> bool | None:
    """``1``/``ON`` true, ``0``/``OFF`` false (SCPI boolean response data); None for anything else."""
    return {"1": True, "ON": True, "0": False, "OFF": False}.get(text.strip().upper())


@dataclass(frozen=True)
class LightCommands:
    on: str
    off: str
    state: str
    level: str | None = None
    level_query: str | None = None
    ready: str | None = None

    @property
    def level_field(self) -> str | None:
        """``percent`` or ``current_a``: what the level command takes (None: no level command)."""
        return None if self.level is None else command_fields(self.level)[0]


@dataclass(frozen=True)
class StreamCommands:
    """A power meter's continuous mode: it sends ``<index>,<value>`` lines at ``rate_hz`` from ``start``
    to ``stop``, unasked."""

    rate: str
    start: str
    stop: str
    rate_hz: float
    format: str = "index,value"
    delay_s: float = 0.0
    combine: str = "sum"
    rate_tolerance: float = 0.005


@dataclass(frozen=True)
class MeterCommands:
    """A power meter's or a spectrometer's commands."""

    measure: tuple[str, ...]
    configure: tuple[str, ...] = ()
    sample_s: float | None = None
    unit: str = ""
    wavelengths: str | None = None
    stream: StreamCommands | None = None

    @property
    def fields(self) -> set[str]:
        """The placeholders ``configure`` uses (the settings a reading needs)."""
        return {f for c in self.configure for f in command_fields(c)}


@dataclass(frozen=True)
class InstrumentProfile:
    name: str
    description: str
    terminator: str
    setters: str
    identify: str
    ok_reply: str = "OK"
    error_prefix: str = "ERR"
    errors: str | None = None
    complete: str | None = None
    reset: tuple[str, ...] = ()
    light: LightCommands | None = None
    power_meter: MeterCommands | None = None
    spectrometer: MeterCommands | None = None
    secondary: tuple[str, ...] = ()
    #: Where it was read from (a shipped name or a path), and the SHA-256 of its text (journaled).
    source: str = ""
    sha256: str = ""
    kinds: tuple[str, ...] = ()

    def section(self, kind: str):
        """The commands for ``kind`` (one of :data:`DEVICE_KINDS`); ValueError naming what it has."""
        got = getattr(self, kind, None) if kind in DEVICE_KINDS else None
        if got is None:
            raise ValueError(f"instrument profile {self.source}: has no [{kind}] section (it describes "
                             f"{', '.join(self.kinds) or 'nothing'})")
        return got


def command_fields(command: str) -> list[str]:
    """The ``{placeholders}`` of a command template."""
    return [f for _, f, _, _ in string.Formatter().parse(command) if f is not None]


def _fail(where: str, key: str, msg: str) -> ValueError:
    return ValueError(f"instrument profile {where}: {key}: {msg}")


def _command(where: str, key: str, value, allowed: tuple[str, ...] = (), query: bool | None = None) -> str:
    if not isinstance(value, str) or not value.strip():
        raise _fail(where, key, f"must be a non-empty command string, got {value!r}")
    if any(c in value for c in "\r\n"):
        raise _fail(where, key, "must be one line (the terminator is added)")
    try:
        names = command_fields(value)
        value.format(**dict.fromkeys(names, 1))
    except (ValueError, IndexError, KeyError) as err:
        raise _fail(where, key, f"{value!r} is not a valid command template ({err})") from None
    bad = [n for n in names if n not in allowed]
    if bad:
        raise _fail(where, key, f"placeholder {{{bad[0]}}} is not one of "
                    f"{', '.join('{' + a + '}' for a in allowed) or 'none (no placeholders here)'}")
    if query is not None and is_query(value) != query:
        raise _fail(where, key, f"{value!r} must be a {'query (ending in ?)' if query else 'setter (no ?)'}")
    return value


def _commands(where: str, key: str, value, **kw) -> tuple[str, ...]:
    if not isinstance(value, list):
        raise _fail(where, key, f"must be a list of commands, got {value!r}")
    return tuple(_command(where, f"{key}[{i}]", v, **kw) for i, v in enumerate(value))


def _table(where: str, key: str, data: dict, keys: set[str], required: tuple[str, ...]) -> dict:
    table = data.get(key)
    if not isinstance(table, dict):
        raise _fail(where, key, f"must be a table, got {table!r}")
    unknown = sorted(set(table) - keys)
    if unknown:
        raise _fail(where, f"{key}.{unknown[0]}", f"unknown key (allowed: {', '.join(sorted(keys))})")
    missing = [k for k in required if k not in table]
    if missing:
        raise _fail(where, f"{key}.{missing[0]}", "missing (a required command)")
    return table


def _light(where: str, data: dict) -> LightCommands:
    t = _table(where, "light", data, _LIGHT_KEYS, ("on", "off", "state"))
    level = None
    if "level" in t:
        level = _command(where, "light.level", t["level"], allowed=_LEVEL_FIELDS, query=False)
        if len(command_fields(level)) != 1:
            raise _fail(where, "light.level",
                        f"{level!r} must take exactly one of {{percent}}, {{current_a}}")
    return LightCommands(
        on=_command(where, "light.on", t["on"], query=False),
        off=_command(where, "light.off", t["off"], query=False),
        state=_command(where, "light.state", t["state"], query=True),
        level=level,
        level_query=(_command(where, "light.level_query", t["level_query"], query=True)
                     if "level_query" in t else None),
        ready=_command(where, "light.ready", t["ready"], query=True) if "ready" in t else None,
    )


def _meter(where: str, data: dict, kind: str) -> MeterCommands:
    required = ("measure", "wavelengths") if kind == "spectrometer" else ("measure",)
    keys = _METER_KEYS if kind == "spectrometer" else _METER_KEYS - {"wavelengths"}
    t = _table(where, kind, data, keys, required)
    measure = _commands(where, f"{kind}.measure", t["measure"])
    if not measure or not is_query(measure[-1]) or any(is_query(c) for c in measure[:-1]):
        raise _fail(where, f"{kind}.measure", f"{list(measure)} must be setters (if any) then one query "
                    "(ending in ?) whose reply is the reading")
    configure = _commands(where, f"{kind}.configure", t.get("configure", []), allowed=_CONFIGURE_FIELDS,
                          query=False)
    sample_s = t.get("sample_s")
    if sample_s is not None and (isinstance(sample_s, bool) or not isinstance(sample_s, int | float)
                                 or not 0 < sample_s <= 60):
        raise _fail(where, f"{kind}.sample_s", f"{sample_s!r} is outside (0, 60] s")
    uses = {f for c in configure for f in command_fields(c)}
    if "count" in uses and sample_s is None:
        raise _fail(where, f"{kind}.sample_s",
                    "missing: {count} (readings averaged) is exposure_s / sample_s")
    unit = t.get("unit", "")
    if not isinstance(unit, str):
        raise _fail(where, f"{kind}.unit", f"must be a string, got {unit!r}")
    wavelengths = (_command(where, f"{kind}.wavelengths", t["wavelengths"], query=True)
                   if kind == "spectrometer" else None)
    stream = _stream(where, t, kind) if "stream" in t else None
    return MeterCommands(measure=measure, configure=configure, sample_s=None if sample_s is None else
                         float(sample_s), unit=unit, wavelengths=wavelengths, stream=stream)


def _number(where: str, key: str, value, lo: float, hi: float, *, open_lo: bool = True) -> float:
    inside = isinstance(value, int | float) and not isinstance(value, bool) and (
        (lo < value if open_lo else lo <= value) and value <= hi)
    if not inside:
        raise _fail(where, key, f"{value!r} is outside {'(' if open_lo else '['}{lo:g}, {hi:g}]")
    return float(value)


def _stream(where: str, data: dict, kind: str) -> StreamCommands:
    key = f"{kind}.stream"
    if kind != "power_meter":
        raise _fail(where, key, "only a power meter streams (one value per line)")
    t = _table(where, key, {key: data["stream"]}, _STREAM_KEYS, ("rate", "start", "stop", "rate_hz"))
    rate = _command(where, f"{key}.rate", t["rate"], allowed=("rate_hz",), query=False)
    if command_fields(rate) != ["rate_hz"]:
        raise _fail(where, f"{key}.rate", f"{rate!r} must take {{rate_hz}} once")
    fmt = t.get("format", "index,value")
    if fmt not in STREAM_FORMATS:
        raise _fail(where, f"{key}.format", f"{fmt!r} is not one of {', '.join(STREAM_FORMATS)}")
    combine = t.get("combine", "sum")
    if combine not in ("sum", "mean"):
        raise _fail(where, f"{key}.combine", f"{combine!r} is not one of 'sum' (a sample is integrated over "
                    "its period), 'mean' (a sample is a rate)")
    return StreamCommands(
        rate=rate, start=_command(where, f"{key}.start", t["start"], query=False),
        stop=_command(where, f"{key}.stop", t["stop"], query=False),
        rate_hz=_number(where, f"{key}.rate_hz", t["rate_hz"], 0.0, 100_000.0), format=fmt,
        delay_s=_number(where, f"{key}.delay_s", t.get("delay_s", 0.0), 0.0, 1.0, open_lo=False),
        combine=combine,
        rate_tolerance=_number(where, f"{key}.rate_tolerance", t.get("rate_tolerance", 0.005), 0.0, 0.5))


def parse_profile(data: dict, where: str = "<dict>", text: str = "") -> InstrumentProfile:
    """Validate a profile's TOML table; errors name the profile, the field and what is allowed."""
    unknown = sorted(set(data) - _TOP_KEYS)
    if unknown:
        raise _fail(where, unknown[0], f"unknown key (allowed: {', '.join(sorted(_TOP_KEYS))})")
    terminator = data.get("terminator", "\n")
    if terminator not in ("\n", "\r\n", "\r"):
        raise _fail(where, "terminator", f"{terminator!r} is not one of '\\n', '\\r\\n', '\\r'")
    setters = data.get("setters")
    if setters not in ("silent", "ok"):
        raise _fail(where, "setters",
                    f"{setters!r} is not one of 'silent' (no reply), 'ok' (answers ok_reply)")
    for key in ("name", "description", "ok_reply", "error_prefix"):
        if key in data and (not isinstance(data[key], str) or (key != "description" and not data[key])):
            raise _fail(where, key, f"must be a non-empty string, got {data[key]!r}")
    if "identify" not in data:
        raise _fail(where, "identify", "missing (the identity query, e.g. '*IDN?')")
    errors = data.get("errors")
    if setters == "silent" and errors is None:
        raise _fail(where, "errors", "missing: silent setters report errors only through a queue "
                    "(e.g. 'SYST:ERR?')")
    if setters == "ok" and errors is not None:
        raise _fail(where, "errors", "an 'ok' dialect refuses a command in its reply (error_prefix); "
                    "leave errors out")
    meter = data.get("power_meter")
    if isinstance(meter, dict) and "stream" in meter and setters != "ok":
        raise _fail(where, "power_meter.stream", "a stream needs setters = 'ok' (its start and stop are told "
                    "apart from the samples by their acknowledgement)")
    kinds = tuple(k for k in DEVICE_KINDS if k in data)
    if not kinds:
        raise _fail(where, "light",
                    f"a profile describes at least one device: [{'], ['.join(DEVICE_KINDS)}]")
    known = set(_TOP_KEYS) | {f"light.{k}" for k in _LIGHT_KEYS} | {
        f"{kind}.{k}" for kind in ("power_meter", "spectrometer") for k in _METER_KEYS}
    secondary = data.get("secondary", [])
    if not isinstance(secondary, list) or any(s not in known for s in secondary):
        bad = secondary if not isinstance(secondary, list) else [s for s in secondary if s not in known][0]
        raise _fail(where, "secondary",
                    f"{bad!r} is not a field of the profile (e.g. 'power_meter.sample_s')")
    return InstrumentProfile(
        name=data.get("name", where), description=data.get("description", ""), terminator=terminator,
        setters=setters, identify=_command(where, "identify", data["identify"], query=True),
        ok_reply=data.get("ok_reply", "OK"), error_prefix=data.get("error_prefix", "ERR"),
        errors=None if errors is None else _command(where, "errors", errors, query=True),
        complete=(_command(where, "complete", data["complete"], query=True)
                  if data.get("complete") is not None else None),
        reset=_commands(where, "reset", data.get("reset", []), query=False),
        light=_light(where, data) if "light" in data else None,
        power_meter=_meter(where, data, "power_meter") if "power_meter" in data else None,
        spectrometer=_meter(where, data, "spectrometer") if "spectrometer" in data else None,
        secondary=tuple(secondary), source=where,
        sha256=hashlib.sha256(text.encode()).hexdigest() if text else "", kinds=kinds,
    )


def load_profile(name_or_path: str | Path) -> InstrumentProfile:
    """A shipped profile by name (see :data:`PROFILES`) or a TOML file by path; ValueError naming the file
    and the field for an unknown name, an unreadable or malformed file."""
    if str(name_or_path) in PROFILES:
        text = resources.files("gonio.drivers.serial").joinpath(f"profiles/{name_or_path}.toml").read_text()
        return parse_profile(tomllib.loads(text), str(name_or_path), text)
    path = Path(name_or_path)
    if not path.is_file():
        raise ValueError(f"instrument profile {str(name_or_path)!r} is neither one of {', '.join(PROFILES)} "
                         "nor a file")
    try:
        text = path.read_text()
        data = tomllib.loads(text)
    except (OSError, UnicodeDecodeError) as err:
        raise ValueError(f"instrument profile {path}: cannot be read ({type(err).__name__})") from None
    except tomllib.TOMLDecodeError as err:
        raise ValueError(f"instrument profile {path}: not valid TOML: {err}") from None
    return parse_profile(data, str(path), text)
