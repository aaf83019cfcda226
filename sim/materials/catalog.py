"""The catalogue of material models (``gonio materials``): each model's keys with their ranges and
defaults, and the rules across keys, read from the models' own parsers.

Nothing here is written by hand: every model class names ``EXAMPLES`` (specs that together read all its
keys) and each is parsed while :class:`.spec.recording` notes what the parser asks for: each key's kind
(a number, an RGB colour: one value or ``R/G/B``, or a word), its range or words, its default, and the
rules it states (``rho_d + rho_s <= 1``, either ``alpha`` or both anisotropic widths, ...). A key read
with different ranges in different examples (``m`` of cook-torrance by its distribution ``d``) lists
each with the words that chose it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from . import MODELS, load
from .spec import format_number, recording

__all__ = ["ModelEntry", "KeyEntry", "catalog", "format_catalog"]

_KINDS = {"number": "number", "colour": "RGB", "word": "word"}


@dataclass
class KeyEntry:
    key: str
    kind: str                 # number, RGB or word
    ranges: list[str]         # each with the words that chose it where they differ
    default: str              # "x", "none" (no default) or "depends on the other keys"


@dataclass
class ModelEntry:
    model: str
    summary: str
    reciprocal: bool
    energy_conserving: bool
    examples: tuple[str, ...]
    usage: str = ""
    keys: list[KeyEntry] = field(default_factory=list)
    rules: list[str] = field(default_factory=list)


def _summary(cls) -> str:
    text = " ".join((cls.__doc__ or "").split())
    for drop in (" (see the module docstring)", " (C: module docstring)"):
        text = text.replace(drop, "")
    end = text.find(". ")
    return text if end < 0 else text[:end + 1]


def _default(value) -> str:
    if value is None:
        return "none"
    return value if isinstance(value, str) else format_number(value)


def _entry(name: str, cls) -> ModelEntry:
    entry = ModelEntry(name, _summary(cls), cls.reciprocal, cls.energy_conserving, tuple(cls.EXAMPLES),
                       cls.USAGE)
    notes: list[dict] = []
    for example in cls.EXAMPLES:
        with recording() as got:
            load(example)
        notes += got
    by_key: dict[str, list[dict]] = {}
    for n in notes:
        if n["kind"] == "rule":
            if n["text"] not in entry.rules:
                entry.rules.append(n["text"])
        else:
            by_key.setdefault(n["key"], []).append(n)
    order = list(getattr(cls, "KEYS", ())) or list(by_key)
    for key in sorted(by_key, key=order.index):
        seen = by_key[key]
        if seen[0]["kind"] == "word":
            options = list(dict.fromkeys(o for n in seen for o in n["options"]))
            ranges = [f"one of {', '.join(options)}"]
        else:
            texts = list(dict.fromkeys(n["what"] for n in seen))
            ranges = texts
            if len(texts) > 1:   # name the words that chose each range
                varying = {k for n in seen for k in n["context"]
                           if len({m["context"].get(k) for m in seen}) > 1}
                ranges = []
                for t in texts:
                    ctx = next(n["context"] for n in seen if n["what"] == t)
                    words = ", ".join(f"{k}={v}" for k, v in ctx.items() if k in varying)
                    ranges.append(f"{t} (with {words})" if words else t)
        defaults = {_default(n["default"]) for n in seen}
        default = defaults.pop() if len(defaults) == 1 else "depends on the other keys"
        entry.keys.append(KeyEntry(key, _KINDS[seen[0]["kind"]], ranges, default))
    return entry


def catalog() -> list[ModelEntry]:
    """Every model of :data:`MODELS`, in its order (module docstring)."""
    return [_entry(name, cls) for name, cls in MODELS.items()]


def format_catalog(entries: list[ModelEntry] | None = None, width: int = 100) -> str:
    """The catalogue as text: per model its summary, examples, keys and rules."""
    import textwrap

    entries = catalog() if entries is None else entries
    lines = textwrap.wrap("MATERIAL is NAME:KEY=VALUE,... (RGB keys take one value or three as R/G/B); keys "
                          "without a default must be given where the rules ask for them.", width) + [""]
    for e in entries:
        flags = ", ".join(x for x, on in (("reciprocal", e.reciprocal), ("energy conserving",
                                                                         e.energy_conserving)) if on)
        lines.append(f"{e.model}: {e.summary}" + (f" [{flags}]" if flags else ""))
        if e.usage:
            lines.append(f"  {e.usage}")
        if e.examples:
            lines.append("  e.g. " + e.examples[0])
        for k in e.keys:
            head = f"  {k.key:<8} {k.kind:<6} "
            body = "; ".join(k.ranges) + f"; default {k.default}"
            lines += textwrap.wrap(body, width, initial_indent=head, subsequent_indent=" " * len(head))
        for rule in e.rules:
            lines += textwrap.wrap(rule, width, initial_indent="  rule: ", subsequent_indent=" " * 8)
        lines.append("")
    return "\n".join(lines).rstrip() + "\n"
