"""Wiring: a validated config in, a Gantry out (DESIGN.md, rule 3).

Which implementation drives each device is decided by the config's ``driver`` fields: each device
section is validated by its driver's config model (the driver registries of :mod:`gonio.registries`),
and that model builds the device, so nothing here asks which driver it has (nor ``if sim:`` anywhere).
A config whose every device is ``sim`` gives the simulated gantry (:class:`gonio.sim.gantry.SimGantry`,
on a virtual clock); any other mix gives an
:class:`gonio.gantry.AssembledGantry`: buses first (devices on one bus share one bus object), then
axes, light and detector. A real device puts the gantry on the wall clock.

A ``sim`` detector beside real (or emulated) axes is a dry run: it renders the material at the
positions the axes report, lit by the real lamp's shutter state and the ``[light.sim]`` radiance
(:func:`gonio.sim.gantry.detector_beside`): a reading taken while a servo sweeps (``order=fly``) is
blurred as a real one is.

The white standard: a config with a ``target.axis`` (a sample changer) moves it for
``set_target("reference")`` and back; without one only a simulated detector can render the standard
(the config refuses a real detector without a changer: a campaign never waits for a person).
"""

from __future__ import annotations

from gonio.clock import VirtualClock, WallClock
from gonio.config import GonioConfig
from gonio.device_config import BuildContext
from gonio.gantry import AssembledGantry, TargetChanger
from gonio.protocols import Clock, Gantry

__all__ = ["build_gantry", "build_buses", "build_axis"]


def _sim_gantry(cfg: GonioConfig, material, seed: int, clock: Clock | None, state) -> Gantry:
    from gonio.sim.gantry import SimGantry

    start_deg, campaign_s = (None, 0.0) if state is None else state
    return SimGantry.from_config(cfg, material, seed=seed, clock=clock or VirtualClock(campaign_s),
                                 start_deg=start_deg)


def build_buses(cfg: GonioConfig) -> dict:
    """One bus object per ``[buses.NAME]``, made by the bus's driver (:meth:`BusConfig.open
    <gonio.device_config.BusConfig.open>`: a :class:`DynamixelBus`, a pymodbus client, or for a serial port
    the bus config itself, each serial instrument opening its own port). No I/O."""
    return {name: bus.open(name) for name, bus in cfg.buses.items()}


def build_axis(name: str, cfg: GonioConfig, buses: dict, clock: Clock, start_deg: float | None = None):
    """The axis ``[axes.NAME]`` describes, on its bus (``buses`` from :func:`build_buses`), made by its
    driver's config model (:meth:`AxisConfig.build <gonio.device_config.AxisConfig.build>`)."""
    return cfg.axes[name].build(name, BuildContext(cfg=cfg, clock=clock, buses=buses), start_deg)


def build_gantry(cfg: GonioConfig, material=None, *, seed: int = 0, clock: Clock | None = None,
                 state=None) -> Gantry:
    """The gantry a config describes. ``material`` (a spec string or a material) and ``seed`` are what
    the simulated devices render; real devices ignore them.

    ``state`` = (axis positions in degrees, campaign_s) is where the journal last saw the gantry
    (:meth:`gonio.store.Journal.last_known_axes`): simulated axes power up there and the simulated clock
    starts at that campaign time, as a real gantry that no process drove since would stand there. Real
    devices report their own positions and ignore it.

    ``clock`` defaults to a :class:`~gonio.clock.VirtualClock` for an all-simulated gantry and to the
    wall clock when a real device takes part (tests of emulated devices pass the emulators' clock).
    """
    from gonio.kinematics import make_kinematics

    if cfg.simulated and cfg.target.axis is None:
        if material is None:
            raise ValueError("the simulated gantry needs a material to render, e.g. 'lambert:albedo=0.5'")
        return _sim_gantry(cfg, material, seed, clock, state)
    start_deg, campaign_s = (None, 0.0) if state is None else state
    if clock is None:
        clock = VirtualClock(campaign_s) if cfg.simulated else WallClock()
    kinematics = make_kinematics(cfg)
    ctx = BuildContext(cfg=cfg, clock=clock, buses=build_buses(cfg), material=material, seed=seed,
                       kinematics=kinematics)
    starts = dict.fromkeys(kinematics.axis_names) if start_deg is None else dict(
        zip(kinematics.axis_names, (float(x) for x in start_deg), strict=True))
    ctx.axes = {n: cfg.axes[n].build(n, ctx, starts[n]) for n in kinematics.axis_names}
    ctx.light = cfg.light.build(ctx)
    detector = cfg.detector.build(ctx)
    changer = None
    if cfg.target.axis is not None:
        t = cfg.target
        changer = TargetChanger(cfg.axes[t.axis].build(t.axis, ctx), sample_deg=t.sample_deg,
                                reference_deg=t.reference_deg,
                                tolerance_deg=cfg.runner.position_tolerance_deg, timeout_s=t.timeout_s,
                                poll_s=cfg.runner.poll_s)
    return AssembledGantry(cfg.name, kinematics, ctx.axes, ctx.light, detector, clock, changer)
