"""A simulated light source: a lamp of finite angular size whose radiance drifts in time.

The drift has three parts, each off by default: a linear trend, a warm-up (the output rises to its
settled value exponentially after power-on) and a slow periodic wander; the last two curve, so a
drift correction that only interpolates straight lines between white references is put to the test.

The lamp was switched on when the campaign began (clock time 0, the campaign clock's origin) and drifts
from then on, across resumes of the campaign; ``set_on`` opens and closes its shutter, so dark readings
taken between white references do not reset the drift the references are there to track.
"""

from __future__ import annotations

import math

from gonio.config import LightConfig
from gonio.protocols import Clock, DeviceFault

__all__ = ["SimLight"]

_SECONDS_PER_HOUR = 3600.0


class SimLight:
    """A simulated lamp satisfying :class:`gonio.protocols.LightSource`.

    Parameters
    ----------
    cfg : gonio.config.LightConfig
        ``radiance`` (arbitrary but consistent units) at power-on, ``half_angle_deg`` of the cone the
        source subtends seen from the sample (°), ``drift_per_hour`` (relative change of radiance per
        hour of clock time).
    clock : gonio.protocols.Clock
        Time source of the drift.
    name : str
        Device name used in messages.

    Notes
    -----
    Radiance at clock time t is ``radiance · (1 + drift_per_hour · t / 3600 s)
    · (1 − warmup_fraction · exp(−t / warmup_s)) · (1 + wander_fraction · sin(2π t / wander_period_s))``:
    the clock is the campaign clock (a resumed simulation starts its virtual clock where the journal
    left off). The shutter starts closed.
    """

    def __init__(self, cfg: LightConfig, clock: Clock, name: str = "light"):
        self.name = name
        self.cfg = cfg
        self.half_angle_deg = float(cfg.sim.half_angle_deg)
        self._clock = clock
        self._connected = False
        self._on = False

    def describe(self) -> dict:
        """What this lamp is, for the journal (:class:`gonio.protocols.Describes`)."""
        return {"name": self.name, "driver": "sim", "identity": "simulated lamp", "firmware": None,
                "units": "radiance", "settings": {"radiance": float(self.cfg.sim.radiance),
                                                  "half_angle_deg": self.half_angle_deg}}

    def connect(self) -> None:
        """Open the (simulated) link with the shutter closed; a no-op when connected."""
        if self._connected:
            return
        self._connected = True
        self._on = False

    def close(self) -> None:
        self._on = False
        self._connected = False

    def set_on(self, on: bool) -> None:
        """Open (True) or close (False) the shutter."""
        self._require_connected()
        self._on = bool(on)

    def is_on(self) -> bool:
        self._require_connected()
        return self._on

    def lamp_radiance(self, t_s: float | None = None) -> float:
        """Radiance the lamp emits at clock time ``t_s`` (default: now), shutter regardless.

        Raises
        ------
        DeviceFault
            The linear drift has brought the output to zero or below (a lamp that has burnt down);
            the linear model no longer describes it.
        """
        t = self._clock.now() if t_s is None else float(t_s)
        hours = t / _SECONDS_PER_HOUR
        sim = self.cfg.sim
        factor = 1.0 + sim.drift_per_hour * hours
        if factor <= 0.0:
            raise DeviceFault(
                self.name, f"lamp output drifted to zero after {hours:.2f} h "
                f"(drift_per_hour = {self.cfg.sim.drift_per_hour})", transient=False,
            )
        curve = (1.0 - sim.warmup_fraction * math.exp(-t / sim.warmup_s)) \
            * (1.0 + sim.wander_fraction * math.sin(2.0 * math.pi * t / sim.wander_period_s))
        return sim.radiance * factor * curve

    def radiance(self) -> float:
        """Radiance reaching the sample now: the lamp's when the shutter is open, else 0."""
        self._require_connected()
        return self.lamp_radiance() if self._on else 0.0

    def _require_connected(self) -> None:
        if not self._connected:
            raise DeviceFault(self.name, "not connected: call connect() first", transient=False)
