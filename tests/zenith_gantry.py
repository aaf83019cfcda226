"""A gantry whose light arm cannot tilt (±0.001°): the light stays at the zenith, so only poses with
θi = 0 (or, through the Helmholtz twin, θo = 0) can be measured, a set of measure zero that no round of
an adaptive campaign lands a pose on after its pilot. A module of its own (imported by this unique name
from any test folder)."""

from __future__ import annotations

from pathlib import Path

from gonio.config import resolve_config


def zenith_light_config(folder: Path) -> Path:
    """The shipped simulated gantry with the light's tilt limited to ±0.001°, written into ``folder``."""
    head, sep, tail = resolve_config(None).read_text().partition("[axes.light_tilt]")
    tail = tail.replace("min_deg = -90.0", "min_deg = -0.001", 1)
    tail = tail.replace("max_deg = 90.0", "max_deg = 0.001", 1)
    path = Path(folder) / "zenith-light.toml"
    path.write_text(head + sep + tail)
    return path
