"""The ``sim`` driver's config models: simulated axes, lamp and detector (``driver = "sim"``, the default).

A config whose every device is ``sim`` is the simulated gantry (:class:`gonio.sim.gantry.SimGantry`); a
``sim`` device beside real ones is wired into an assembled gantry (a ``sim`` detector beside real axes
renders the poses they report: a dry run). What a simulated device does is set in the ``sim`` sub-tables
every device has (:mod:`gonio.device_config`); these models add nothing to them but the driver's name.
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import model_validator

from gonio.device_config import AxisConfig, BuildContext, DetectorConfig, LightConfig

__all__ = ["SimAxisConfig", "SimLightConfig", "SimDetectorConfig"]


class SimAxisConfig(AxisConfig):
    """A simulated axis: a trapezoidal move on the gantry's clock (:class:`gonio.sim.axis.SimAxis`)."""

    driver: Literal["sim"] = "sim"
    simulated: ClassVar[bool] = True

    def build(self, name: str, ctx: BuildContext, start_deg: float | None = None):
        from gonio.sim.axis import SimAxis

        return SimAxis(name, self, ctx.clock, start_deg)


class SimLightConfig(LightConfig):
    """A simulated lamp (:class:`gonio.sim.light.SimLight`): ``[light.sim]`` says what it emits."""

    driver: Literal["sim"] = "sim"
    simulated: ClassVar[bool] = True

    def build(self, ctx: BuildContext):
        from gonio.sim.light import SimLight

        return SimLight(self, ctx.clock)


class SimDetectorConfig(DetectorConfig):
    """A simulated detector of the kind ``[detector.sim] kind`` names (:mod:`gonio.sim.detectors`)."""

    driver: Literal["sim"] = "sim"
    simulated: ClassVar[bool] = True

    @model_validator(mode="after")
    def _check_kind(self):
        kind = self._kind()
        if kind.check is not None:
            kind.check(self)
        return self

    def _kind(self):
        from gonio.registries import SIM_DETECTORS

        return SIM_DETECTORS.load(self.sim.kind)

    @property
    def kind_name(self) -> str:
        return self.sim.kind

    @property
    def channel_names(self) -> tuple[str, ...]:
        """The channels a reading has: the kind's own (one per band, ``380nm``, ..., for a simulated
        spectrometer) or the config's."""
        kind = self._kind()
        return tuple(self.channels) if kind.channels is None else tuple(kind.channels(self)[0])

    @property
    def wavelengths_nm(self) -> tuple[float, ...] | None:
        kind = self._kind()
        return None if kind.channels is None else kind.channels(self)[1]

    def build(self, ctx: BuildContext):
        """The simulated detector beside the built light and axes, real or simulated
        (:func:`gonio.sim.gantry.detector_beside`)."""
        from gonio.sim.gantry import detector_beside

        return detector_beside(ctx.cfg, ctx.material, light=ctx.light, axes=ctx.axes,
                               kinematics=ctx.kinematics, clock=ctx.clock, seed=ctx.seed)
