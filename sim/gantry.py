"""The simulated gantry: simulated axes, lamp and detector wired behind the Gantry protocol.

Everything runs on one injected clock (a :class:`gonio.clock.VirtualClock` by default), so a campaign
that takes hours on hardware runs in seconds and replays exactly from its seed.
"""

from __future__ import annotations

from collections.abc import Mapping

from gonio.clock import VirtualClock
from gonio.config import GonioConfig
from gonio.kinematics import make_kinematics
from gonio.protocols import Clock
from gonio.sim import materials as _materials
from gonio.sim.axis import SimAxis
from gonio.sim.detector import TARGETS, SimDetector
from gonio.sim.light import SimLight

__all__ = ["SimGantry", "sim_detector", "detector_beside", "ReadBack", "LampView"]


def sim_detector(cfg: GonioConfig, material, *, light, axes, kinematics, clock: Clock, seed: int = 0,
                 track_motion: bool = False):
    """The simulated detector ``[detector.sim] kind`` names (:data:`gonio.registries.SIM_DETECTORS`: the
    RGB photodiode :class:`~gonio.sim.detector.SimDetector`, the spectrometer
    :class:`~gonio.sim.detector_spectral.SpectrometerDetector` of spectral materials, the camera
    :class:`~gonio.sim.detector_camera.CameraDetector`, or a plugin's), with the white standard a
    Lambertian of ``reference.albedo``.

    ``light`` has ``radiance()`` and ``half_angle_deg``; ``axes`` have ``true_position_deg()``.
    ``track_motion``: the detector integrates along the axes' read-backs at the start and the end of each
    reading (real axes: :class:`~gonio.sim.detector.SimDetector`).
    """
    from gonio.registries import SIM_DETECTORS

    sample = _materials.load(material) if isinstance(material, str) else material
    return SIM_DETECTORS.load(cfg.detector.sim.kind).build(cfg, sample, light=light, axes=axes,
                                                           kinematics=kinematics, clock=clock, seed=seed,
                                                           track_motion=track_motion)


class ReadBack:
    """A real axis seen by a simulated detector: the position it reports is the pose rendered."""

    def __init__(self, axis):
        self.axis = axis

    def true_position_deg(self) -> float:
        return self.axis.position_deg()


class LampView:
    """A real lamp seen by a simulated detector: ``[light.sim]`` radiance while its output is on."""

    def __init__(self, lamp, sim_cfg):
        self.lamp = lamp
        self.half_angle_deg = float(sim_cfg.half_angle_deg)
        self.radiance_on = float(sim_cfg.radiance)

    def radiance(self) -> float:
        return self.radiance_on if self.lamp.is_on() else 0.0


def detector_beside(cfg: GonioConfig, material, *, light, axes, kinematics, clock: Clock, seed: int = 0):
    """The simulated detector of ``cfg`` in a gantry whose axes and lamp may be real (a dry run): a real
    axis is seen at the position it reports, a real lamp lit with the ``[light.sim]`` radiance while it is
    on, and with real axes each reading integrates along the line between the positions read at its start
    and at its end (a reading taken while a servo sweeps is blurred as a real one is)."""
    if material is None:
        raise ValueError("the simulated detector needs a material to render, e.g. 'lambert:albedo=0.5'")
    views = {n: a if isinstance(a, SimAxis) else ReadBack(a) for n, a in axes.items()}
    lamp = light if isinstance(light, SimLight) else LampView(light, cfg.light.sim)
    real = any(isinstance(v, ReadBack) for v in views.values())
    return sim_detector(cfg, material, light=lamp, axes=views, kinematics=kinematics, clock=clock, seed=seed,
                        track_motion=real)


class SimGantry:
    """A simulated gantry satisfying :class:`gonio.protocols.Gantry`.

    Parameters
    ----------
    name : str
        Gantry name (from the config).
    kinematics
        ``axis_names`` and ``directions``; the axes are held in its ``axis_names`` order.
    axes : Mapping[str, SimAxis]
    light : SimLight
    detector : SimDetector, SpectrometerDetector or CameraDetector (see :func:`sim_detector`)
        Must read the same ``axes`` and ``light``.
    clock : gonio.protocols.Clock

    Use :meth:`from_config` to build one from a :class:`gonio.config.GonioConfig`.

    Examples
    --------
    >>> from gonio.config import load_config
    >>> gantry = SimGantry.from_config(load_config(), "lambert:albedo=0.5", seed=1)
    >>> gantry.connect()
    >>> gantry.light.set_on(True)
    >>> gantry.axes["light_tilt"].move_to(30.0)
    >>> gantry.wait_until_still()              # advances the virtual clock until the move is over
    >>> gantry.detector.measure(0.1).signal.round(5)    # 1000 · Ω(0.5°) · 0.5/π · cos 30° · 0.1 s
    array([0.0033, 0.0033, 0.0033])
    >>> round(gantry.clock.now(), 3)           # virtual seconds: a 1.167 s move, a 0.1 s exposure
    1.267
    """

    def __init__(self, name: str, kinematics, axes: Mapping[str, SimAxis], light: SimLight,
                 detector: SimDetector, clock: Clock, *, cfg: GonioConfig | None = None, material=None,
                 seed: int = 0):
        missing = [a for a in kinematics.axis_names if a not in axes]
        extra = [a for a in axes if a not in kinematics.axis_names]
        if missing or extra:
            raise ValueError(
                f"axes: must be exactly {', '.join(kinematics.axis_names)}"
                + (f"; missing: {', '.join(missing)}" if missing else "")
                + (f"; unknown: {', '.join(extra)}" if extra else "")
            )
        self.name = name
        self.kinematics = kinematics
        self.axes = {a: axes[a] for a in kinematics.axis_names}
        self.light = light
        self.detector = detector
        self.clock = clock
        # What a fly campaign's readings are rendered from (:meth:`fly_readings`): the config, the sample
        # and the seed the detector was made with.
        self._fly = (cfg, material, int(seed))
        self._fly_sim = None

    @property
    def all_axes(self) -> dict[str, SimAxis]:
        """The kinematics' axes (a simulated gantry has no changer)."""
        return dict(self.axes)

    @classmethod
    def from_config(cls, cfg: GonioConfig, material, *, seed: int = 0, clock: Clock | None = None,
                    start_deg=None) -> SimGantry:
        """Wire a simulated gantry from a config.

        Parameters
        ----------
        cfg : GonioConfig
            Axes, light, detector and reference (the white standard is Lambertian with
            ``reference.albedo``).
        material : str or material
            The sample: a MATERIAL spec string for :func:`gonio.sim.materials.load`, or a loaded
            material (anything with ``eval_dr``).
        seed : int
            Campaign seed of the detector's Monte Carlo and noise (>= 0).
        clock : Clock, optional
            Defaults to a new :class:`gonio.clock.VirtualClock` at t = 0.
        start_deg : array_like, shape (n_axes,), optional
            Where the axes stand at power-up (default: home). A resumed campaign passes the positions the
            journal last recorded: a real gantry stays where it was while no process drives it.
        """
        clock = VirtualClock() if clock is None else clock
        kinematics = make_kinematics(cfg)
        start = [None] * len(kinematics.axis_names) if start_deg is None else [float(x) for x in start_deg]
        if len(start) != len(kinematics.axis_names):
            raise ValueError(f"start_deg: {len(start)} positions for the axes "
                             f"{', '.join(kinematics.axis_names)}")
        axes = {a: SimAxis(a, cfg.axes[a], clock, x)
                for a, x in zip(kinematics.axis_names, start, strict=True)}
        light = SimLight(cfg.light, clock)
        detector = sim_detector(cfg, material, light=light, axes=axes, kinematics=kinematics, clock=clock,
                                seed=seed)
        return cls(cfg.name, kinematics, axes, light, detector, clock, cfg=cfg, material=material, seed=seed)

    # -- the Gantry protocol ------------------------------------------------------------------------
    def connect(self) -> None:
        for axis in self.axes.values():
            axis.connect()
        self.light.connect()
        self.detector.connect()

    def close(self) -> None:
        """Close every device (axes brake to a halt first); each is closed even if another fails."""
        first: Exception | None = None
        for device in [*self.axes.values(), self.light, self.detector]:
            try:
                device.close()
            except Exception as err:  # close the rest, then re-raise the first
                first = first or err
        if first is not None:
            raise first

    @property
    def target(self) -> str:
        """What is under the beam: ``"sample"`` or ``"reference"``."""
        return self.detector.target

    def set_target(self, target: str) -> None:
        """Put ``"sample"`` or ``"reference"`` (the white standard) under the beam."""
        if target not in TARGETS:
            raise ValueError(f"target: {target!r} is not one of {', '.join(repr(t) for t in TARGETS)}")
        self.detector.set_target(target)

    def stop(self) -> None:
        """Brake every axis (see :meth:`SimAxis.stop`); they come to rest within v_max / a_max.

        Safe from any thread: each axis's motion is one attribute replaced at once."""
        for axis in self.axes.values():
            axis.stop()

    # -- fly campaigns: rendered, nothing moves (gonio.protocols.RendersFly) ------------------------------
    def fly_refusal(self) -> str | None:
        """Why this gantry cannot render a fly campaign (:mod:`gonio.sim.fly` simulates the photodiode),
        or None."""
        cfg = self._fly[0]
        if cfg is None:
            return "the simulated gantry was built without its config (SimGantry.from_config renders fly)"
        if cfg.detector.sim.kind != "photodiode":
            return (f"detector.sim.kind: '{cfg.detector.sim.kind}' cannot be simulated on the fly; "
                    "order=fly simulates the photodiode of a simulated gantry only ([detector.sim] kind = "
                    "'photodiode')")
        return None

    def fly_readings(self, fp, item) -> list:
        """The measurements of one entry of :func:`gonio.plan.fly.fly_steps` (a sweep, or a checkpoint's
        dark and reference), rendered by :class:`gonio.sim.fly.FlySimulator`: bit for bit the same
        whenever it is asked (its random numbers are keyed by the item's first step)."""
        if self._fly_sim is None:
            from gonio.sim.fly import FlySimulator

            cfg, material, seed = self._fly
            self._fly_sim = FlySimulator(cfg, material, seed=seed, kin=self.kinematics)
        return self._fly_sim.item(fp, item)

    # -- simulation-only ----------------------------------------------------------------------------
    def wait_until_still(self) -> None:
        """Advance the clock until every axis has finished its move or brake (tests, doctests)."""
        arrival = max(axis.arrival_time_s() for axis in self.axes.values())
        now = self.clock.now()
        if arrival > now:
            self.clock.sleep(arrival - now)
