"""MATERIAL strings: ``name:key=value,key=value`` parsed, validated and normalized.

A value is a number, a word (``d=beckmann``) or, for colour parameters, either one number (the same in
R, G and B) or three numbers separated by ``/`` (``albedo=0.8/0.6/0.4``, in the order R/G/B). Spaces
around names and values are ignored. Every error is a :class:`ValueError` whose message names the model,
the parameter and what is allowed, e.g. ``cook-torrance: parameter 'm' must be > 0, got -0.1``.

The normalized spec lists every parameter the model used, defaults included, in the model's own order,
with numbers in their shortest round-trip form, so that ``load(m.spec).spec == m.spec`` and two specs
that mean the same material compare equal.
"""

from __future__ import annotations

import contextvars
import math

__all__ = ["Params", "split_spec", "format_number", "recording"]

RGB = ("R", "G", "B")

#: While set (:func:`recording`), every key a model reads, and every rule across keys, is appended here:
#: how :mod:`.catalog` lists each model's keys, ranges and defaults from the parsers themselves.
_RECORD: contextvars.ContextVar[list | None] = contextvars.ContextVar("gonio_material_keys", default=None)


class recording:
    """``with recording() as notes: load(spec)``: ``notes`` is then the list of what the model's parser
    read, in order: dicts with ``kind`` ``number``, ``colour``, ``word`` (``key``, ``what``, ``default``,
    ``options`` for words, ``context`` the words chosen before it) or ``rule`` (``text``)."""

    def __enter__(self) -> list:
        self.notes: list = []
        self._token = _RECORD.set(self.notes)
        return self.notes

    def __exit__(self, *exc) -> None:
        _RECORD.reset(self._token)


def format_number(x: float) -> str:
    """Shortest round-trip text of ``x``; integral values without a trailing ``.0``."""
    text = repr(float(x))
    return text[:-2] if text.endswith(".0") else text


def split_spec(spec: str) -> tuple[str, str]:
    """``"name:rest"`` → ``("name", "rest")``; the name is lower-cased, ``rest`` may be empty."""
    if not isinstance(spec, str):
        raise ValueError(f"material spec must be a string 'name:key=value,...', got {type(spec).__name__}")
    name, _, rest = spec.partition(":")
    return name.strip().lower(), rest.strip()


def _bound(x: float) -> str:
    """A range's bound as a person reads it: π/2 is 1.5708 (to 6 digits), 1 is 1."""
    return format_number(float(f"{x:.6g}"))


def _range_text(lo, hi, lo_open, hi_open) -> str:
    if lo is not None and hi is not None:
        left, right = "(" if lo_open else "[", ")" if hi_open else "]"
        return f"in {left}{_bound(lo)}, {_bound(hi)}{right}"
    if lo is not None:
        return f"{'>' if lo_open else '>='} {_bound(lo)}"
    if hi is not None:
        return f"{'<' if hi_open else '<='} {_bound(hi)}"
    return "a finite number"


class Params:
    """The ``key=value`` list of one model, read key by key.

    A model calls :meth:`colour`, :meth:`number` and :meth:`choice` for the keys it uses (which both
    validates them and records them for the normalized spec), then :meth:`finish`.

    Parameters
    ----------
    model : str
        Model name, used in every error message.
    text : str
        The part of the spec after ``name:``.
    allowed : sequence of str
        Every key the model knows; any other key is rejected at once, with this list.
    """

    def __init__(self, model: str, text: str, allowed):
        self.model = model
        self.allowed = tuple(allowed)
        self._raw: dict[str, str] = {}
        self._used: list[tuple[str, str]] = []
        self._words: dict[str, str] = {}
        for position, item in enumerate(text.split(",") if text else [], start=1):
            key, eq, value = item.partition("=")
            key, value = key.strip().lower(), value.strip()
            if not eq or not key or not value:
                raise self.error(f"item {position} {item.strip()!r} is not of the form key=value")
            if key not in self.allowed:
                raise self.error(f"unknown parameter {key!r}; allowed: {', '.join(self.allowed)}")
            if key in self._raw:
                raise self.error(f"parameter {key!r} is given twice")
            self._raw[key] = value

    def _note(self, kind: str, **entry) -> None:
        notes = _RECORD.get()
        if notes is not None:
            notes.append({"kind": kind, "context": dict(self._words), **entry})

    def rule(self, text: str) -> None:
        """A rule across keys (what a combination must be), for the catalogue of models."""
        self._note("rule", text=text)

    def error(self, message: str) -> ValueError:
        """A ValueError prefixed with the model name."""
        return ValueError(f"{self.model}: {message}")

    def has(self, key: str) -> bool:
        """Whether ``key`` was given in the spec."""
        return key in self._raw

    def _take(self, key: str, default, what: str) -> str | None:
        if key in self._raw:
            return self._raw.pop(key)
        if default is None:
            raise self.error(f"parameter {key!r} is required ({what})")
        return None

    def _parse(self, key: str, text: str, what: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise self.error(f"parameter {key!r} must be {what}, got {text!r}") from None
        if not math.isfinite(value):
            raise self.error(f"parameter {key!r} must be {what}, got {text!r}")
        return value

    def number(self, key: str, default: float | None = None, *, lo=None, hi=None, lo_open=False,
               hi_open=False, unit: str = "") -> float:
        """One real number in the stated range (``lo``/``hi`` inclusive unless ``*_open``)."""
        what = _range_text(lo, hi, lo_open, hi_open) + (f" {unit}" if unit else "")
        self._note("number", key=key, what=what, default=default)
        text = self._take(key, default, f"a number {what}")
        if "/" in (text or ""):
            raise self.error(f"parameter {key!r} takes one number, not R/G/B values, got {text!r}")
        value = float(default) if text is None else self._parse(key, text, f"a number {what}")
        self._check(key, value, lo, hi, lo_open, hi_open, what, channel=None)
        self._used.append((key, format_number(value)))
        return value

    def colour(self, key: str, default: float | None = None, *, lo=0.0, hi=1.0, lo_open=False,
               hi_open=False) -> tuple[float, float, float]:
        """One number for R, G and B, or three separated by ``/``; each in the stated range."""
        what = _range_text(lo, hi, lo_open, hi_open)
        self._note("colour", key=key, what=what, default=default)
        text = self._take(key, default, f"one number {what} or three as R/G/B")
        if text is None:
            values = (float(default),) * 3
        else:
            parts = text.split("/")
            if len(parts) not in (1, 3):
                raise self.error(f"parameter {key!r} takes one number or three R/G/B numbers separated "
                                 f"by '/', got {text!r}")
            values = tuple(self._parse(key, p.strip(), f"a number {what}") for p in parts)
            values = values * 3 if len(values) == 1 else values
        for channel, value in zip(RGB, values, strict=True):
            self._check(key, value, lo, hi, lo_open, hi_open, what,
                        channel=None if len(set(values)) == 1 else channel)
        shown = format_number(values[0]) if len(set(values)) == 1 else "/".join(map(format_number, values))
        self._used.append((key, shown))
        return values

    def choice(self, key: str, options, default: str | None = None, *, context: str = "") -> str:
        """One word out of ``options``; ``context`` (e.g. "with metal=...") is added to errors."""
        options = tuple(options)
        self._note("word", key=key, what=f"one of {', '.join(options)}", options=options, default=default)
        text = self._take(key, default, f"one of {', '.join(options)}")
        value = default if text is None else text.lower()
        if value not in options:
            where = f" {context}" if context else ""
            raise self.error(f"parameter {key!r} must be one of {', '.join(options)}{where}, got {text!r}")
        self._used.append((key, value))
        self._words[key] = value
        return value

    def roughness(self, iso: str, aniso: tuple[str, str]) -> tuple[float, float]:
        """Either ``iso`` (the same along x and y) or both keys of ``aniso``; each > 0."""
        self.rule(f"give {iso}, or both {aniso[0]} and {aniso[1]} (anisotropic)")
        if self.has(iso):
            self.reject(aniso, f"together with {iso!r} (give either {iso} or both {aniso[0]} and {aniso[1]})")
            a = self.number(iso, lo=0.0, lo_open=True)
            return a, a
        if self.has(aniso[0]) or self.has(aniso[1]):
            return (self.number(aniso[0], lo=0.0, lo_open=True), self.number(aniso[1], lo=0.0, lo_open=True))
        raise self.error(f"parameter {iso!r} (> 0) or both {aniso[0]!r} and {aniso[1]!r} (> 0) "
                         "are required")

    def _check(self, key, value, lo, hi, lo_open, hi_open, what, channel):
        bad = (lo is not None and (value < lo or (lo_open and value == lo))) or \
              (hi is not None and (value > hi or (hi_open and value == hi)))
        if bad:
            where = f" in channel {channel}" if channel else ""
            raise self.error(f"parameter {key!r} must be {what}, got {format_number(value)}{where}")

    def reject(self, keys, reason: str) -> None:
        """Raise if any of ``keys`` was given: they do not apply because of ``reason``."""
        for key in keys:
            if key in self._raw:
                raise self.error(f"parameter {key!r} does not apply {reason}")

    def at_most_one(self, weights: dict[str, tuple[float, float, float]], why: str) -> None:
        """Raise unless the per-channel sum of ``weights`` is <= 1 (e.g. rho_d + ks for energy)."""
        self.rule(f"{' + '.join(weights)} <= 1 in each channel ({why})")
        for i, channel in enumerate(RGB):
            total = sum(w[i] for w in weights.values())
            if total > 1.0 + 1e-12:
                names = " + ".join(weights)
                raise self.error(f"{names} must be <= 1 ({why}), got {format_number(total)} in "
                                 f"channel {channel}")

    def finish(self) -> str:
        """The normalized spec. Raises if a given key was never read (it does not apply here)."""
        for key in self._raw:
            raise self.error(f"parameter {key!r} does not apply to this configuration")
        return self.model + (":" + ",".join(f"{k}={v}" for k, v in self._used) if self._used else "")
