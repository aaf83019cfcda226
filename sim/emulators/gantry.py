"""The emulated devices of a whole gantry config: every bus's emulator, and a detector that renders a
material at the positions the emulated axes stand.

:class:`EmulatedGantry` reads a config's buses and devices and starts, for each bus:

- ``dynamixel``: a :class:`DynamixelBusEmulator` with one :class:`EmulatedServo` per axis on it (model
  from the axis's ``family``), each powered up at the axis's home position, an extended-mode axis with
  mechanical stops at its limits (the ends of its travel: a hard-stop reference finds them) and, as a
  real one, reporting its position within one turn: it must be referenced before it moves;
- ``modbus``: a :class:`ModbusMotorEmulator` following the axis's profile (one controller per TCP bus,
  on the url's loopback port; on an RTU line, over a pty, one or several units: a
  :class:`ModbusBusEmulator` where several share it);
- ``serial``: the lamp's or the detector's emulator, chosen by the device's instrument profile
  (:data:`LAMP_EMULATORS`, :data:`METER_EMULATORS`: ``acknowledging``, ``scpi-current-source``,
  ``thorlabs-pm100``), over a pty, or over loopback TCP where the bus's port is a socket
  (``socket://127.0.0.1:5025``, ``TCPIP0::127.0.0.1::5025::SOCKET``; a port written as a VISA resource
  string stays one, so the driver opens it through PyVISA). The emulated detector (a power meter, or a
  spectrometer reporting one band per channel) renders the material through the Dr.Jit simulation
  (:class:`gonio.sim.detector.SimDetector`) at the poses the emulated axes' shafts are at, lit while the
  emulated lamp is lit (output on; for a current source, a current above zero; off, a power meter reads
  the rendered dark level), and sees the white standard when the target axis stands at ``reference_deg``.
  While axes move (a fly sweep) a reading integrates over their motion: stratified times through the
  exposure, each axis where its trajectory (the servo's profile as commanded when the reading starts)
  has it then, rendered and averaged (``SimDetector.measure(motion=...)``); a still gantry's reading is
  the still one, unchanged.

Everything runs on one clock (the wall clock by default; a test shares a virtual clock with the gantry
it builds: a :class:`~gonio.sim.emulators.link.SyncedVirtualClock`, so that a Sync Write, which gets no
reply, acts at the virtual instant it was sent). :meth:`EmulatedGantry.config` is the config with each
bus's port or url replaced by where its emulator listens; :meth:`EmulatedGantry.config_toml` writes it
out for another process. :meth:`EmulatedGantry.watch` tells at once of an emulator whose serving thread
died (:attr:`EmulatedGantry.devices` says what it emulated).
"""

from __future__ import annotations

import json
import math
import re
import threading
from urllib.parse import urlparse

import numpy as np

from gonio.clock import WallClock
from gonio.config import GonioConfig
from gonio.sim.emulators.dynamixel import DynamixelBusEmulator, EmulatedServo
from gonio.sim.emulators.instruments import (
    LightSourceEmulator,
    PowerMeterEmulator,
    SpectrometerEmulator,
    StreamingPhotodiodeEmulator,
)
from gonio.sim.emulators.modbus import ModbusBusEmulator, ModbusMotorEmulator
from gonio.sim.emulators.scpi import CurrentSourceEmulator, Pm100Emulator
from gonio.sim.emulators.tcp_link import TcpLink

__all__ = ["EmulatedGantry", "EMULATOR_LATENCY_MS", "SPECTROMETER_BANDS_NM", "to_toml", "LAMP_EMULATORS",
           "METER_EMULATORS", "WATTS_PER_UNIT"]

#: Band centres (nm) the emulated spectrometer reports for the R, G, B of the rendered material.
SPECTROMETER_BANDS_NM = (610.0, 550.0, 465.0)
#: The emulated power meter's watts per unit of rendered signal per second of exposure (a PM100 reads W).
WATTS_PER_UNIT = 1e-6
#: Instrument profile name -> the emulator of a lamp that speaks it.
LAMP_EMULATORS = {"acknowledging": LightSourceEmulator, "scpi-current-source": CurrentSourceEmulator}
#: Instrument profile name -> the emulator of a power meter that speaks it.
METER_EMULATORS = {"acknowledging": PowerMeterEmulator, "thorlabs-pm100": Pm100Emulator,
                   "streaming-photodiode": StreamingPhotodiodeEmulator}
SPECTROMETER_EMULATORS = {"acknowledging": SpectrometerEmulator}
_LOOPBACK = ("127.0.0.1", "localhost")
_VISA_SOCKET = re.compile(r"^TCPIP(\d*)::([^:]+)::(\d+)::SOCKET$", re.IGNORECASE)
_VISA_ASRL = re.compile(r"^ASRL(.+)::INSTR$", re.IGNORECASE)


#: The latency (ms) a Dynamixel bus's config allows an emulator's replies, twice per reply as for a
#: USB adapter's latency timer: the servos' emulator is a thread on this host, and a host loaded by
#: other work (a test suite on every core) can hold its reply for tens of ms past the SDK's 34 ms. At 50 ms
#: (a reply time-out of ~100 ms, two tries) `gonio gantry reference` on the README's emulated gantry missed
#: a status packet twice in a row while both cores ran the test suite and other pages beside it.
EMULATOR_LATENCY_MS = 100.0


def _socket_address(port: str) -> tuple[str, int, str] | None:
    """(host, port, form) of a bus port that is a TCP socket (form: "url" or "visa"), else None."""
    if port.startswith("socket://"):
        u = urlparse(port)
        return u.hostname or "", u.port or 0, "url"
    m = _VISA_SOCKET.match(port)
    return (m.group(2), int(m.group(3)), "visa") if m else None
_MODELS = {"XM430": "XM430-W350", "XL430": "XL430-W250"}
_TICKS_PER_REV = 4096


class _ShaftView:
    """An emulated axis seen by the optics: its shaft angle (°) from a device position function."""

    def __init__(self, position):
        self._position = position

    def true_position_deg(self) -> float:
        return self._position(None)


class EmulatedGantry:
    """Emulators for every real device of ``cfg``.

    Parameters
    ----------
    cfg : GonioConfig
        A config whose buses name ports or urls (they are replaced by the emulators' own, see
        :meth:`config`).
    material : str or material
        What the emulated detector sees (a MATERIAL spec).
    clock : Clock, optional
        Time source of every emulator (default: the wall clock).
    seed : int
        Seed of the rendered readings.
    any_port : bool
        Serve Modbus TCP on free loopback ports instead of the ports the urls name.
    referenced : bool
        Power up as if a previous session had referenced every axis and nothing was power-cycled since
        (the servos count from where the config puts them and hold gonio's reference marker; the
        controllers report their origin set). False (the default, and ``gonio emulate``): as real
        hardware fresh from power-up, so ``gonio gantry reference`` comes first.
    """

    def __init__(self, cfg: GonioConfig, material="lambert:albedo=0.5", *, clock=None, seed: int = 0,
                 any_port: bool = False, referenced: bool = False):
        self.cfg = cfg
        self.clock = clock or WallClock()
        self.any_port = any_port
        self.referenced = referenced
        self.emulators: dict[str, object] = {}
        #: Bus name -> what its emulator is, in words ("the Dynamixel servos of light_azimuth, ...").
        self.devices: dict[str, str] = {}
        self.servos: dict[str, EmulatedServo] = {}
        self.motors: dict[str, ModbusMotorEmulator] = {}
        self.lamp: LightSourceEmulator | None = None
        self.meter: PowerMeterEmulator | None = None
        self._locations: dict[str, str] = {}
        self._render_lock = threading.Lock()
        self._positions = {}
        for name, axis in cfg.axes.items():
            if axis.driver == "sim":
                continue
            self._positions[name] = self._position_fn(name)
        self._detector = None
        if cfg.detector.driver != "sim":
            missing = [a for a in cfg.axis_names if cfg.axes[a].driver == "sim"]
            if missing:
                raise ValueError(f"the emulated detector renders at the emulated axes' poses, but "
                                 f"{', '.join(missing)} {'is' if len(missing) == 1 else 'are'} 'sim'")
            self._detector, self._light = self._renderer(material, seed, self.clock)
        self._material, self._seed = material, seed
        self._stream_render = None   # (clock, detector, light) of a streaming photodiode's samples
        self._build()

    # -- building -------------------------------------------------------------------------------------
    def _build(self) -> None:
        cfg = self.cfg
        for bus_name, bus in cfg.buses.items():
            axes = [n for n, a in cfg.axes.items() if a.driver != "sim" and a.bus == bus_name]
            if bus.driver == "dynamixel":
                servos = []
                for n in axes:
                    a = cfg.axes[n]

                    def ticks(deg, a=a):
                        per_deg = _TICKS_PER_REV * a.gear_ratio / 360.0
                        return a.homing_offset_ticks + a.direction * deg * per_deg

                    # Mechanical stops at the travel limits, on the encoder tick just inside each: a
                    # carriage referenced against one then reads a position within its limits.
                    lo, hi = sorted((ticks(a.min_deg), ticks(a.max_deg)))
                    stops = ((None, None) if a.operating_mode != "extended"
                             else (float(math.ceil(lo - 1e-9)), float(math.floor(hi + 1e-9))))
                    servo = EmulatedServo(a.id, _MODELS[a.family], self.clock,
                                          position_ticks=round(ticks(a.home_deg)), stops_ticks=stops,
                                          operating_mode=4 if a.operating_mode == "extended" else 3)
                    if self.referenced:
                        servo.assume_referenced()
                    self.servos[n] = servo
                    servos.append(servo)
                self.emulators[bus_name] = DynamixelBusEmulator(servos)
                self.devices[bus_name] = f"the Dynamixel servo{'s' * (len(axes) != 1)} of {', '.join(axes)}"
            elif bus.driver == "modbus":
                if not axes or (len(axes) > 1 and not bus.url.startswith("rtu:")):
                    raise ValueError(f"buses.{bus_name}: the Modbus emulator serves one controller "
                                     f"per TCP bus, several on an RTU line; {len(axes)} axes are on it "
                                     f"({', '.join(axes) or 'none'})")
                units = []
                for n in axes:
                    a = cfg.axes[n]
                    emu = ModbusMotorEmulator(a.profile, clock=self.clock, device_id=a.device_id)
                    steps_per_deg = emu.profile.steps_per_rev * a.gear_ratio / 360.0
                    emu.set_position(a.zero_steps + round(a.direction * a.home_deg * steps_per_deg))
                    if self.referenced:
                        emu.assume_referenced()
                    self.motors[n] = emu
                    units.append(emu)
                self.emulators[bus_name] = units[0] if len(units) == 1 else ModbusBusEmulator(units)
                self.devices[bus_name] = (f"the Modbus controller{'s' * (len(axes) != 1)} of "
                                          f"{', '.join(axes)}")
            elif cfg.light.driver == "serial" and cfg.light.bus == bus_name:
                make = self._emulator_for("light", cfg.light.profile, LAMP_EMULATORS)
                self.lamp = make(clock=self.clock, link=self._link(bus_name))
                self.emulators[bus_name] = self.lamp
                self.devices[bus_name] = f"the lamp ({cfg.light.profile})"
            elif cfg.detector.driver == "serial" and cfg.detector.bus == bus_name:
                if cfg.detector.kind == "power_meter":
                    make = self._emulator_for("detector", cfg.detector.profile, METER_EMULATORS)
                    signal = self._watts if make is Pm100Emulator else self._power
                    extra = {}
                    if make is StreamingPhotodiodeEmulator:
                        extra = dict(window=self._window, baudrate=cfg.buses[bus_name].baudrate)
                    self.meter = make(signal, clock=self.clock, link=self._link(bus_name), **extra)
                else:
                    self._emulator_for("detector", cfg.detector.profile, SPECTROMETER_EMULATORS)
                    if len(cfg.detector.channels) != len(SPECTROMETER_BANDS_NM):
                        raise ValueError(f"the emulated spectrometer reports the rendered R, G, B "
                                         f"as {len(SPECTROMETER_BANDS_NM)} bands; detector.channels names "
                                         f"{len(cfg.detector.channels)}")
                    self.meter = SpectrometerEmulator(SPECTROMETER_BANDS_NM, self._spectrum, clock=self.clock,
                                                      link=self._link(bus_name))
                self.emulators[bus_name] = self.meter
                self.devices[bus_name] = f"the detector ({cfg.detector.profile})"

    @staticmethod
    def _emulator_for(device: str, profile: str, table: dict):
        from gonio.drivers.serial.profile import load_profile

        name = load_profile(profile).name
        if name not in table:
            raise ValueError(f"{device}.profile {profile!r} (profile '{name}') has no emulator; "
                             f"emulated profiles: {', '.join(table)}")
        return table[name]

    def _link(self, bus_name: str):
        """A loopback TCP server where the bus's port is a socket, else None (the emulator's own pty)."""
        where = _socket_address(self.cfg.buses[bus_name].port)
        if where is None:
            return None
        host, port, _ = where
        return TcpLink(port=0 if self.any_port or host not in _LOOPBACK else port)

    def _position_fn(self, name: str):
        a = self.cfg.axes[name]
        if a.driver == "dynamixel":
            per_deg = _TICKS_PER_REV * a.gear_ratio / 360.0

            def dxl(t=None) -> float:
                s = self.servos[name]
                ticks = s.shaft_ticks(t)
                return a.direction * (ticks - a.homing_offset_ticks) / per_deg
            return dxl

        def modbus(t=None) -> float:
            m = self.motors[name]
            per_deg = m.profile.steps_per_rev * a.gear_ratio / 360.0
            return a.direction * (m.position_steps_f(t) - a.zero_steps) / per_deg
        return modbus

    def _renderer(self, material, seed: int, clock):
        from gonio.kinematics import make_kinematics
        from gonio.sim import materials as _materials
        from gonio.sim.detector import SimDetector
        from gonio.sim.light import SimLight
        from gonio.sim.standard import reference_material

        cfg = self.cfg
        kinematics = make_kinematics(cfg)
        light = SimLight(cfg.light, clock)
        light.connect()
        sample = _materials.load(material) if isinstance(material, str) else material
        views = {n: _ShaftView(self._positions[n]) for n in kinematics.axis_names}
        self._detector_axes = list(kinematics.axis_names)
        rgb = cfg.detector.model_copy(update={"channels": ("R", "G", "B")})
        # the standard as the config describes it (albedo, per channel or spectral; its response)
        reference = reference_material(cfg.model_copy(update={"detector": rgb}))
        det = SimDetector(rgb, light=light, axes=views,
                          kinematics=kinematics, materials={"sample": sample, "reference": reference},
                          clock=clock, seed=seed, name="emulated detector")
        det.connect()
        return det, light

    # -- what the emulated detector sees ---------------------------------------------------------------
    def target_now(self) -> str:
        """``"reference"`` when the target axis is nearer its reference position than its sample one."""
        t = self.cfg.target
        if t.axis is None:
            return "sample"
        at = self._positions[t.axis](None)
        return "reference" if abs(at - t.reference_deg) < abs(at - t.sample_deg) else "sample"

    def axes_deg(self) -> dict[str, float]:
        """Every emulated axis's shaft angle (°) now."""
        return {n: f(None) for n, f in self._positions.items()}

    def axes_at(self, times) -> np.ndarray:
        """The kinematics' axes (°, columns in ``axis_names`` order) at clock ``times`` (K,), on the
        trajectories the emulated devices follow now."""
        names = self._detector_axes
        return np.array([[self._positions[n](float(t)) for n in names] for t in np.ravel(times)])

    def _render(self, exposure_s: float):
        with self._render_lock:
            self._light.set_on(bool(self.lamp.on) if self.lamp is not None else True)
            self._detector.set_target(self.target_now())
            return self._detector.measure(exposure_s, motion=self.axes_at).signal

    def _window(self, t0: float, t1: float) -> float:
        """A streaming photodiode's sample: the signal integrated over ``[t0, t1]`` of the gantry's
        timeline, the axes moving along their trajectories meanwhile; rendered on a clock of its own set
        to ``t0`` (the shared clock does not move: the stream's instants are the emulator's own)."""
        from gonio.clock import VirtualClock

        with self._render_lock:
            if self._stream_render is None or self._stream_render[0].now() > t0:
                clock = VirtualClock(t0)
                self._stream_render = (clock, *self._renderer(self._material, self._seed, clock))
            clock, det, light = self._stream_render
            clock.sleep_until(t0)
            light.set_on(bool(self.lamp.on) if self.lamp is not None else True)
            det.set_target(self.target_now())
            return float(det.measure(t1 - t0, motion=self.axes_at).signal.mean())

    def _power(self, exposure_s: float) -> float:
        return float(self._render(exposure_s).mean())

    def _watts(self, exposure_s: float) -> float:
        """A power meter's reading: power (W), not a count, whatever the averaging time."""
        return self._power(exposure_s) / exposure_s * WATTS_PER_UNIT

    def _spectrum(self, exposure_s: float):
        return list(self._render(exposure_s))

    # -- running -----------------------------------------------------------------------------------------
    def start(self) -> EmulatedGantry:
        """Start every emulator (stopping those started if one fails)."""
        try:
            for name, emu in self.emulators.items():
                if isinstance(emu, ModbusBusEmulator):
                    baud = self.cfg.buses[name].url.partition("baudrate=")[2] or "115200"
                    self._locations[name] = f"rtu://{emu.start_rtu(int(baud))}?baudrate={baud}"
                elif isinstance(emu, ModbusMotorEmulator):
                    url = self.cfg.buses[name].url
                    u = urlparse(url)
                    if u.scheme == "tcp":
                        port = 0 if self.any_port or u.hostname not in ("127.0.0.1", "localhost") else u.port
                        try:
                            host, port = emu.start_tcp(port or 0)
                        except OSError as err:  # another server holds the port: one line, nothing runs
                            raise ValueError(f"buses.{name}: {err}; stop what holds it, or serve on a free "
                                             "port (--any-port)") from None
                        self._locations[name] = f"tcp://{host}:{port}"
                    else:
                        baud = self.cfg.buses[name].url.partition("baudrate=")[2] or "115200"
                        self._locations[name] = f"rtu://{emu.start_rtu(int(baud))}?baudrate={baud}"
                else:
                    emu.start()
                    self._locations[name] = self._location(name, emu)
                    if hasattr(emu, "drain") and hasattr(self.clock, "attach"):
                        # a SyncedVirtualClock: no time passes mid-packet; a stream's lines at their instants
                        self.clock.attach(emu.drain, getattr(emu, "next_due", None))
        except BaseException:
            self.stop()
            raise
        return self

    def _location(self, bus_name: str, emu) -> str:
        """Where the driver reaches ``emu``, written as the config wrote the bus's port: a pty path (or
        ``ASRL<pty>::INSTR``), or the socket in its url or VISA form."""
        port = self.cfg.buses[bus_name].port
        where = _socket_address(port)
        if where is not None:
            host, _, form = where
            tcp = emu.link.tcp_port
            if form == "url":
                return f"socket://127.0.0.1:{tcp}"
            return f"TCPIP{_VISA_SOCKET.match(port).group(1)}::127.0.0.1::{tcp}::SOCKET"
        if _VISA_ASRL.match(port):
            return f"ASRL{emu.port}::INSTR"
        return emu.port

    def watch(self, callback) -> None:
        """Call ``callback(bus_name, exc)`` when the serving thread of a bus's emulator dies of ``exc`` (a
        bug: nothing a driver sends kills one), at once, from that thread (keep it short: record, set an
        event); for a thread that died already, at once from this one. Call it before :meth:`start`."""
        for name, emu in self.emulators.items():
            emu.watch(lambda exc, name=name: callback(name, exc))

    def stop(self) -> None:
        """Stop every emulator that was started (each, even if another fails to stop)."""
        first = None
        for name in list(self._locations):
            emu = self.emulators[name]
            if hasattr(emu, "drain") and hasattr(self.clock, "detach"):
                self.clock.detach(emu.drain)
            try:
                emu.stop()
            except Exception as err:
                first = first or err
            del self._locations[name]
        if first is not None:
            raise first

    def __enter__(self) -> EmulatedGantry:
        return self.start()

    def __exit__(self, exc_type, exc, tb) -> None:
        """Stop every emulator; leaving the block without an exception, one whose serving thread died is
        one (a test whose emulator died would otherwise show only its driver's time-outs)."""
        self.stop()
        if exc_type is None:
            for name, emu in self.emulators.items():
                if emu.error is not None:
                    raise RuntimeError(f"buses.{name}: the emulator of {self.devices[name]} died of "
                                       f"{emu.error!r}") from emu.error

    def locations(self) -> dict[str, str]:
        """Where each bus's emulator listens: a pty path, or a Modbus url."""
        return dict(self._locations)

    def config(self) -> GonioConfig:
        """The config with each bus's port or url pointing at its running emulator. A Dynamixel bus
        also allows :data:`EMULATOR_LATENCY_MS` for each reply where its config allowed less."""
        data = self.cfg.model_dump(mode="json")
        for name, where in self._locations.items():
            bus = data["buses"][name]
            key = "url" if bus["driver"] == "modbus" else "port"
            bus[key] = where
            if bus["driver"] == "dynamixel":
                bus["latency_timer_ms"] = max(bus["latency_timer_ms"], EMULATOR_LATENCY_MS)
        return GonioConfig.model_validate(data)

    def config_toml(self, header: str = "") -> str:
        """:meth:`config` as TOML (only settings that differ from the defaults)."""
        return header + to_toml(self.config().model_dump(mode="json", exclude_defaults=True))


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)  # a TOML basic string
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    return repr(v)


def to_toml(data: dict, prefix: str = "") -> str:
    """A dict of tables, scalars and lists of scalars (all a gonio config holds) as TOML."""
    scalars = [f"{k} = {_value(v)}" for k, v in data.items() if not isinstance(v, dict) and v is not None]
    head = f"[{prefix[:-1]}]\n" if prefix and scalars else ""
    out = head + "".join(s + "\n" for s in scalars) + ("\n" if scalars else "")
    for k, v in data.items():
        if isinstance(v, dict):
            out += to_toml(v, f"{prefix}{k}.")
    return out
