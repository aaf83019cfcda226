"""MATERIALS of a batch: a file of MATERIAL strings, or a generator spec that spans a family of them.

A line (or the command-line argument itself) is a MATERIAL string (``gonio materials``) in which any
``key=value`` option may instead span values:

- ``key=A..BxN``: N values evenly spaced from A to B, both included (N from 2 to :data:`MAX_SPAN`);
- ``key=a|b|c``: each of the values given.

The batch is the product of every spanned option, in the order written, the first option varying slowest:
``ggx:alpha=0.1..0.3x3,metal=gold|copper`` is ``ggx:alpha=0.1,metal=gold``, ``ggx:alpha=0.1,metal=copper``,
``ggx:alpha=0.2,metal=gold``, ... (6 materials). A file holds one such line per line; blank lines and
lines starting with ``#`` are skipped. Every material is checked (:func:`gonio.sim.materials.load`) and
kept as written (spans expanded); the same material twice (as :func:`load` normalizes it) is refused.

>>> expand("ggx:alpha=0.1..0.3x3,metal=gold|copper")[:3]
['ggx:alpha=0.1,metal=gold', 'ggx:alpha=0.1,metal=copper', 'ggx:alpha=0.2,metal=gold']
>>> expand("merl:../data/gold.binary")           # a path is never a span
['merl:../data/gold.binary']
"""

from __future__ import annotations

import itertools
import math
import re
from pathlib import Path

from gonio.files import NamedFileError, read_named_file

__all__ = ["MAX_MATERIALS", "MAX_SPAN", "expand", "read_materials"]

#: The most materials one batch holds.
MAX_MATERIALS = 100_000
#: The most values one ``A..BxN`` span gives.
MAX_SPAN = 10_000
#: The largest MATERIALS file read: MAX_MATERIALS lines of a few hundred characters.
MATERIALS_MAX_BYTES = 64 << 20

_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_RANGE = re.compile(rf"^({_NUMBER})\.\.({_NUMBER})x(\d+)$")


def _values(key: str, value: str, where: str) -> list[str]:
    m = _RANGE.match(value)
    if m is not None:
        a, b, n = float(m[1]), float(m[2]), int(m[3])
        if not (math.isfinite(a) and math.isfinite(b)):
            raise ValueError(f"{where}: {key}={value}: the ends of a span must be finite numbers")
        if not 2 <= n <= MAX_SPAN:
            raise ValueError(f"{where}: {key}={value}: a span A..BxN needs N from 2 to {MAX_SPAN}, got {n}")
        return [format(a + (b - a) * k / (n - 1), ".10g") for k in range(n)]
    if "|" in value:
        parts = value.split("|")
        if any(not p.strip() for p in parts):
            raise ValueError(f"{where}: {key}={value}: an empty alternative in a|b|...")
        return [p.strip() for p in parts]
    return [value]


def expand(text: str, where: str = "MATERIALS") -> list[str]:
    """The MATERIAL strings a line spans (not yet checked against the models), in batch order.

    Raises
    ------
    ValueError
        A malformed span, or more than :data:`MAX_MATERIALS` materials; the message starts with ``where``.
    """
    text = text.strip()
    name, sep, rest = text.partition(":")
    if not sep or "=" not in rest:
        return [text]          # a model without options, or a path (merl:PATH): nothing spans
    options = []
    for item in rest.split(","):
        key, eq, value = item.partition("=")
        values = _values(key.strip(), value.strip(), where) if eq else [""]
        options.append([f"{key}{eq}{v}" for v in values])
    count = math.prod(len(o) for o in options)
    if count > MAX_MATERIALS:
        raise ValueError(f"{where}: {text!r} spans {count} materials; a batch holds at most {MAX_MATERIALS}")
    return [f"{name}:{','.join(combo)}" for combo in itertools.product(*options)]


def read_materials(arg: str) -> list[str]:
    """The checked MATERIAL strings of the batch argument ``arg`` (a file of lines, else one line), as
    written with their spans expanded.

    Raises
    ------
    ValueError
        A line that is no material (naming the file and line), a material twice, none at all, too many.
    """
    from gonio.sim.materials import load

    path = Path(arg)
    if path.is_file():
        try:
            text = read_named_file(path, MATERIALS_MAX_BYTES, "MATERIALS file").decode("utf-8")
        except (NamedFileError, UnicodeDecodeError) as e:
            raise ValueError(f"MATERIALS: {path}: cannot be read as UTF-8 text ({e})") from None
        lines = [(f"{path}:{n}", line) for n, line in enumerate(text.splitlines(), 1)
                 if line.strip() and not line.lstrip().startswith("#")]
        if not lines:
            raise ValueError(f"MATERIALS: {path} holds no MATERIAL line (one per line; # starts a comment)")
    elif path.exists():
        raise ValueError(f"MATERIALS: {path} is not a file (give a file of MATERIAL lines or a MATERIAL "
                         "string)")
    else:
        lines = [("MATERIALS", arg)]
    seen: dict[str, tuple[str, str]] = {}
    for where, line in lines:
        for material in expand(line, where):
            try:
                spec = load(material).spec
            except ValueError as e:
                raise ValueError(f"{where}: {e}") from None
            if spec in seen:
                raise ValueError(f"{where}: {material} is already in the batch as {seen[spec][0]} "
                                 f"({seen[spec][1]}); give each material once")
            seen[spec] = (material, where)
            if len(seen) > MAX_MATERIALS:
                raise ValueError(f"MATERIALS: more than {MAX_MATERIALS} materials; split the batch")
    return [material for material, _ in seen.values()]
