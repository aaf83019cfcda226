"""Stand-ins for hardware: Dr.Jit materials and optics, and a simulated gantry behind the same protocols.

- :mod:`gonio.sim.materials`: reflectance models (MATERIAL strings).
- :mod:`gonio.sim.axis`, :mod:`gonio.sim.light`, :mod:`gonio.sim.detector`: simulated servo axes, lamp
  and detector on an injected clock.
- :mod:`gonio.sim.gantry`: :class:`~gonio.sim.gantry.SimGantry`, all of them wired from a config.
"""
