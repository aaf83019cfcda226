"""Registries: one per kind of thing chosen by name, so that a name is written once.

A :class:`Registry` maps a name (``merl``, ``two-arm``, ``dynamixel``) to an :class:`Entry`: where the
implementation is (an object, or a ``"module:attr"`` path imported only when it is used), a one-line
summary, and a few facts about it (``extra``) that help text and validation read without importing the
implementation. So ``gonio plot --help`` lists every plot kind, and a config names every driver, without
importing matplotlib or a driver's library.

Plugins add entries from outside gonio, without editing gonio's files (docs/EXTENDING.md): a plugin is a
module that, when imported, calls :meth:`Registry.add` (or the :meth:`Registry.register` decorator) on the
registries of :mod:`gonio.registries`. :func:`load_plugins` imports them, once, the first time any
registry is read:

- the modules named by the entry points of the group ``gonio.plugins`` (an installed package declares
  ``[project.entry-points."gonio.plugins"] name = "its_module"``), then
- the modules named in the environment variable ``GONIO_PLUGINS`` (comma-separated; found on
  ``sys.path``/``PYTHONPATH``): a lab script or a test registers a plugin without packaging it.

Importing a plugin module yourself before gonio reads the registry works too.

This module imports nothing beyond the standard library: reading a registry costs microseconds.
"""

from __future__ import annotations

import importlib
import os
import threading
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

__all__ = ["Entry", "Registry", "PluginError", "load_plugins", "lazy_attributes", "PLUGIN_GROUP",
           "PLUGIN_ENV"]

#: The entry-point group an installed plugin package declares its module in.
PLUGIN_GROUP = "gonio.plugins"
#: The environment variable naming plugin modules to import (comma-separated).
PLUGIN_ENV = "GONIO_PLUGINS"


class PluginError(ValueError):
    """A plugin that cannot be imported, or that registers a name twice: one line naming it."""


@dataclass(frozen=True)
class Entry:
    """One registered thing.

    Attributes
    ----------
    name : str
        What users write (a config value, a CLI choice, the head of a GRID string).
    target : object or str
        The implementation, or ``"module:attr"`` (``attr`` may be dotted) imported by :meth:`load`.
    summary : str
        One line for help text.
    extra : Mapping
        Facts about the entry that its registry documents (read without importing ``target``).
    """

    name: str
    target: object
    summary: str = ""
    extra: Mapping = field(default_factory=lambda: MappingProxyType({}))

    def load(self):
        """The implementation (imported on first use when ``target`` is a ``"module:attr"`` path)."""
        if not isinstance(self.target, str):
            return self.target
        module, _, attr = self.target.partition(":")
        obj = importlib.import_module(module)
        for part in filter(None, attr.split(".")):
            obj = getattr(obj, part)
        return obj


class Registry:
    """Names of one kind of thing (``kind``, e.g. ``"export format"``), in the order they were added.

    Examples
    --------
    >>> r = Registry("colour")
    >>> _ = r.add("red", "builtins:str", "a warm one", wavelength_nm=700)
    >>> r.names(), r["red"].extra["wavelength_nm"], "blue" in r
    (('red',), 700, False)
    >>> r.check("blue", "--colour")
    Traceback (most recent call last):
    ...
    ValueError: --colour: 'blue' is unknown; allowed: red
    """

    def __init__(self, kind: str):
        self.kind = kind
        self._entries: dict[str, Entry] = {}

    # -- adding ---------------------------------------------------------------------------------------
    def add(self, name: str, target, summary: str = "", **extra) -> Entry:
        """Register ``name``; a name already registered is refused (:class:`PluginError`)."""
        if not isinstance(name, str) or not name or name != name.strip():
            raise PluginError(f"{self.kind}: a name is a non-empty string without surrounding spaces, got "
                              f"{name!r}")
        if name in self._entries:
            raise PluginError(f"{self.kind} '{name}' is registered twice (by {self._entries[name].target!r} "
                              f"and {target!r})")
        entry = Entry(name, target, summary, MappingProxyType(dict(extra)))
        self._entries[name] = entry
        return entry

    def register(self, name: str, summary: str = "", **extra):
        """Decorator form of :meth:`add`: registers the decorated object and returns it unchanged."""
        def decorate(obj):
            self.add(name, obj, summary, **extra)
            return obj
        return decorate

    # -- reading (plugins are imported first) ------------------------------------------------------------
    def _all(self) -> dict[str, Entry]:
        load_plugins()
        return self._entries

    def names(self) -> tuple[str, ...]:
        return tuple(self._all())

    def entries(self) -> tuple[Entry, ...]:
        return tuple(self._all().values())

    def __contains__(self, name) -> bool:
        return name in self._all()

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __len__(self) -> int:
        return len(self._all())

    def __getitem__(self, name: str) -> Entry:
        return self._all()[name]

    def check(self, name: str, where: str) -> Entry:
        """The entry ``name``; a ValueError ``"{where}: '{name}' is unknown; allowed: ..."`` otherwise."""
        entries = self._all()
        if name not in entries:
            raise ValueError(f"{where}: {name!r} is unknown; allowed: {', '.join(entries)}")
        return entries[name]

    def load(self, name: str):
        """The implementation registered as ``name`` (KeyError when there is none: see :meth:`check`)."""
        return self[name].load()

    def help(self, width: int = 100, indent: str = "  ") -> str:
        """Every entry as ``name  summary`` lines, wrapped to ``width``."""
        import textwrap

        entries = self.entries()
        pad = max((len(e.name) for e in entries), default=0) + 2
        lines: list[str] = []
        for e in entries:
            lines += textwrap.wrap(f"{e.name:<{pad}}{e.summary}", width, initial_indent=indent,
                                   subsequent_indent=indent + " " * pad) or [indent + e.name]
        return "\n".join(lines)

    def __repr__(self) -> str:
        return f"Registry({self.kind!r}: {', '.join(self._entries)})"


def lazy_attributes(package: str, exports: Mapping[str, str]):
    """A module ``__getattr__`` (PEP 562) for ``package``: each name of ``exports`` is imported from the
    submodule it maps to when first asked for, so importing the package (or a light submodule of it, such
    as a driver's config model) does not import its heavy ones.

    >>> lazy_attributes("json", {"JSONDecoder": "decoder"})("JSONDecoder").__name__
    'JSONDecoder'
    """
    def __getattr__(name: str):
        if name not in exports:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(f"{package}.{exports[name]}"), name)
    return __getattr__


_lock = threading.RLock()
_loaded = False


def load_plugins() -> None:
    """Import every plugin module once (entry points of :data:`PLUGIN_GROUP`, then :data:`PLUGIN_ENV`).

    A plugin that cannot be imported raises :class:`PluginError` naming it and where it was declared.
    """
    global _loaded
    if _loaded:
        return
    with _lock:
        if _loaded:
            return
        _loaded = True  # set first: a plugin that reads a registry while it is imported must not recurse
        modules: list[tuple[str, str]] = []
        env = os.environ.get(PLUGIN_ENV, "")
        if env.strip() or _has_entry_points():
            from importlib.metadata import entry_points

            modules += [(ep.value, f"entry point {ep.name!r} of group {PLUGIN_GROUP!r}")
                        for ep in entry_points(group=PLUGIN_GROUP)]
        modules += [(m.strip(), PLUGIN_ENV) for m in env.split(",") if m.strip()]
        for spec, where in modules:
            try:
                Entry(spec, spec if ":" in spec else f"{spec}:").load()
            except PluginError:
                raise
            except Exception as err:  # any failure of a foreign module: one line naming it
                raise PluginError(f"plugin {spec!r} ({where}) cannot be imported: "
                                  f"{type(err).__name__}: {err}") from err


def _has_entry_points() -> bool:
    """Whether any installed distribution declares entry points of :data:`PLUGIN_GROUP` (read from the
    ``entry_points.txt`` files on sys.path without importing :mod:`importlib.metadata`'s machinery for
    every distribution when there are none)."""
    import sys
    from pathlib import Path

    needle = f"[{PLUGIN_GROUP}]"
    for folder in sys.path:
        try:
            infos = [p for p in Path(folder or ".").iterdir() if p.name.endswith((".dist-info", ".egg-info"))]
        except OSError:
            continue
        for info in infos:
            try:
                if needle in (info / "entry_points.txt").read_text(errors="replace"):
                    return True
            except OSError:
                continue
    return False
