"""Wiring: a validated config in, a Gantry out (DESIGN.md, rule 3).

Which implementation drives each device is decided here from the config's ``driver`` fields, never by
``if sim:`` elsewhere. Today every device of a config is ``sim``; real drivers register beside it.
"""

from __future__ import annotations

from gonio.clock import VirtualClock
from gonio.config import GonioConfig
from gonio.protocols import Clock, Gantry

__all__ = ["build_gantry"]


def _sim_gantry(cfg: GonioConfig, material, seed: int, clock: Clock | None, state) -> Gantry:
    from gonio.sim.gantry import SimGantry

    start_deg, campaign_s = (None, 0.0) if state is None else state
    return SimGantry.from_config(cfg, material, seed=seed, clock=clock or VirtualClock(campaign_s),
                                 start_deg=start_deg)


_GANTRIES = {"sim": _sim_gantry}


def build_gantry(cfg: GonioConfig, material=None, *, seed: int = 0, clock: Clock | None = None,
                 state=None) -> Gantry:
    """The gantry a config describes. ``material`` (a spec string or a material) and ``seed`` are what
    the simulated devices render; real devices ignore them.

    ``state`` = (axis positions in degrees, campaign_s) is where the journal last saw the gantry
    (:meth:`gonio.store.Journal.last_known_axes`): simulated axes power up there and the simulated clock
    starts at that campaign time, as a real gantry that no process drove since would stand there. Real
    devices report their own positions and ignore it."""
    drivers = {a.driver for a in cfg.axes.values()} | {cfg.light.driver, cfg.detector.driver}
    if len(drivers) != 1:
        raise ValueError(f"config '{cfg.name}': mixing device drivers {sorted(drivers)} in one gantry is not "
                         f"supported; allowed: one of {sorted(_GANTRIES)} for every device")
    (driver,) = drivers
    if driver == "sim" and material is None:
        raise ValueError("the simulated gantry needs a material to render, e.g. 'lambert:albedo=0.5'")
    return _GANTRIES[driver](cfg, material, seed, clock, state)
