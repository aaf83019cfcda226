"""Gantry configurations shipped with gonio (installed as ``gonio.configs``): ``sim.toml``, the default
simulated two-arm gantry, and the other designs. ``gonio config list`` names them; ``--config NAME``
loads one by name, ``--config PATH`` any file."""
