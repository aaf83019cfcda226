"""Wiring: a validated config in, a Gantry out (DESIGN.md, rule 3).

Which implementation drives each device is decided here from the config's ``driver`` fields, never by
``if sim:`` elsewhere. A config whose every device is ``sim`` gives the simulated gantry
(:class:`gonio.sim.gantry.SimGantry`, on a virtual clock); any other mix gives an
:class:`gonio.gantry.AssembledGantry`: buses first (devices on one bus share one bus object), then
axes, light and detector. A real device puts the gantry on the wall clock.

A ``sim`` detector beside real (or emulated) axes is a dry run: it renders the material at the
positions the axes report, lit by the real lamp's shutter state and the ``[light.sim]`` radiance. It
reads the axes when a reading starts and again when it ends and integrates along the line between
(``track_motion``): a reading taken while a servo sweeps (``order=fly``) is blurred as a real one is.

The white standard: a config with a ``target.axis`` (a sample changer) moves it for
``set_target("reference")`` and back; without one only a simulated detector can render the standard
(the config refuses a real detector without a changer: a campaign never waits for a person).
"""

from __future__ import annotations

from gonio.clock import VirtualClock, WallClock
from gonio.config import GonioConfig
from gonio.gantry import AssembledGantry, TargetChanger
from gonio.protocols import Clock, DeviceFault, Gantry

__all__ = ["build_gantry", "build_buses", "build_axis"]


def _sim_gantry(cfg: GonioConfig, material, seed: int, clock: Clock | None, state) -> Gantry:
    from gonio.sim.gantry import SimGantry

    start_deg, campaign_s = (None, 0.0) if state is None else state
    return SimGantry.from_config(cfg, material, seed=seed, clock=clock or VirtualClock(campaign_s),
                                 start_deg=start_deg)


def build_buses(cfg: GonioConfig) -> dict:
    """One bus object per ``[buses.NAME]`` that a device uses: a :class:`DynamixelBus`, a pymodbus client,
    or (serial) the bus config itself (each serial instrument opens its own port). No I/O."""
    out = {}
    for name, bus in cfg.buses.items():
        if bus.driver == "dynamixel":
            from gonio.drivers.dynamixel import DynamixelBus

            out[name] = DynamixelBus(bus.port, bus.baudrate, name=name, retries=bus.retries)
        elif bus.driver == "modbus":
            from gonio.drivers.modbus import make_client

            out[name] = make_client(bus.url, timeout_s=bus.timeout_s, retries=bus.retries)
        else:
            out[name] = bus
    return out


def build_axis(name: str, cfg: GonioConfig, buses: dict, clock: Clock, start_deg: float | None = None):
    """The axis ``[axes.NAME]`` describes, on its bus (``buses`` from :func:`build_buses`)."""
    a = cfg.axes[name]
    limits = (a.min_deg, a.max_deg)
    if a.driver == "dynamixel":
        from gonio.drivers.dynamixel import DynamixelAxis

        return DynamixelAxis(name, buses[a.bus], a.id, limits_deg=limits, family=a.family,
                             operating_mode=a.operating_mode, gear_ratio=a.gear_ratio, direction=a.direction,
                             homing_offset_ticks=a.homing_offset_ticks, velocity_deg_s=a.max_velocity_deg_s,
                             accel_deg_s2=a.max_accel_deg_s2, watchdog_s=a.watchdog_s, clock=clock,
                             reference_method=a.reference)
    if a.driver == "modbus":
        from gonio.drivers.modbus import ModbusAxis

        return ModbusAxis(name, buses[a.bus], a.profile, device_id=a.device_id, limits_deg=limits,
                          gear_ratio=a.gear_ratio, direction=a.direction, zero_steps=a.zero_steps,
                          velocity_deg_s=a.max_velocity_deg_s, accel_deg_s2=a.max_accel_deg_s2, clock=clock,
                          reference_method=a.reference)
    from gonio.sim.axis import SimAxis

    return SimAxis(name, a, clock, start_deg)


class _ReadBack:
    """A real axis seen by a simulated detector: the position it reports is the pose rendered."""

    def __init__(self, axis):
        self._axis = axis

    def true_position_deg(self) -> float:
        return self._axis.position_deg()


class _LampView:
    """A real lamp seen by a simulated detector: ``[light.sim]`` radiance while its output is on."""

    def __init__(self, lamp, sim_cfg):
        self._lamp = lamp
        self.half_angle_deg = float(sim_cfg.half_angle_deg)
        self._radiance = float(sim_cfg.radiance)

    def radiance(self) -> float:
        return self._radiance if self._lamp.is_on() else 0.0


def _serial_kwargs(bus, clock: Clock) -> dict:
    return dict(baudrate=bus.baudrate, terminator=bus.terminator, timeout_s=bus.timeout_s, clock=clock)


def _light(cfg: GonioConfig, buses: dict, clock: Clock):
    lc = cfg.light
    if lc.driver == "sim":
        from gonio.sim.light import SimLight

        return SimLight(lc, clock)
    from gonio.drivers.serial import SerialLightSource

    bus = buses[lc.bus]
    return SerialLightSource("light", bus.port, lc.profile, level=lc.level,
                             warmup_timeout_s=lc.warmup_timeout_s, settle_s=lc.settle_s,
                             **_serial_kwargs(bus, clock))


def _serial_detector(cfg: GonioConfig, buses: dict, clock: Clock):
    from gonio.drivers.serial import SerialPowerMeter, SerialSpectrometer

    dc = cfg.detector
    bus = buses[dc.bus]
    kwargs = dict(wavelength_nm=dc.wavelength_nm, **_serial_kwargs(bus, clock))
    if dc.kind == "power_meter":
        det = SerialPowerMeter("detector", bus.port, dc.profile, **kwargs)
        det.channels = tuple(dc.channels)
        return det

    class _Spectrometer(SerialSpectrometer):
        """A spectrometer whose bands are the campaign's channels: as many bins as channels, by name."""

        def connect(self) -> None:
            super().connect()
            if len(self.wavelengths_nm) != len(dc.channels):
                bins = ", ".join(f"{w:g}" for w in self.wavelengths_nm)
                self.close()
                raise DeviceFault(self.name, f"reports {len(self.wavelengths_nm)} bands ({bins} nm) but "
                                  f"detector.channels names {len(dc.channels)} ({', '.join(dc.channels)}): "
                                  "configure the instrument to report one band per channel")
            self.channels = tuple(dc.channels)

    det = _Spectrometer("detector", bus.port, dc.profile, **kwargs)
    det.channels = tuple(dc.channels)
    return det


def _sim_detector(cfg: GonioConfig, material, seed: int, light, axes: dict, kinematics, clock: Clock):
    from gonio.sim.gantry import sim_detector
    from gonio.sim.light import SimLight

    if material is None:
        raise ValueError("the simulated detector needs a material to render, e.g. 'lambert:albedo=0.5'")
    views = {n: a if hasattr(a, "true_position_deg") else _ReadBack(a) for n, a in axes.items()}
    lamp = light if isinstance(light, SimLight) else _LampView(light, cfg.light.sim)
    real = any(isinstance(v, _ReadBack) for v in views.values())
    return sim_detector(cfg, material, light=lamp, axes=views, kinematics=kinematics, clock=clock, seed=seed,
                        track_motion=real)


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

    drivers = cfg.drivers()
    if drivers == {"sim"} and cfg.target.axis is None:
        if material is None:
            raise ValueError("the simulated gantry needs a material to render, e.g. 'lambert:albedo=0.5'")
        return _sim_gantry(cfg, material, seed, clock, state)
    start_deg, campaign_s = (None, 0.0) if state is None else state
    if clock is None:
        clock = VirtualClock(campaign_s) if drivers == {"sim"} else WallClock()
    kinematics = make_kinematics(cfg)
    buses = build_buses(cfg)
    starts = dict.fromkeys(kinematics.axis_names) if start_deg is None else dict(
        zip(kinematics.axis_names, (float(x) for x in start_deg), strict=True))
    axes = {n: build_axis(n, cfg, buses, clock, starts[n]) for n in kinematics.axis_names}
    light = _light(cfg, buses, clock)
    if cfg.detector.driver == "sim":
        detector = _sim_detector(cfg, material, seed, light, axes, kinematics, clock)
    else:
        detector = _serial_detector(cfg, buses, clock)
    changer = None
    if cfg.target.axis is not None:
        t = cfg.target
        changer = TargetChanger(build_axis(t.axis, cfg, buses, clock), sample_deg=t.sample_deg,
                                reference_deg=t.reference_deg,
                                tolerance_deg=cfg.runner.position_tolerance_deg, timeout_s=t.timeout_s,
                                poll_s=cfg.runner.poll_s)
    return AssembledGantry(cfg.name, kinematics, axes, light, detector, clock, changer)
