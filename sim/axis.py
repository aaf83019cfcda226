"""A simulated servo axis on an injected clock: trapezoidal moves, limits, encoder counts, faults.

The axis never waits: its state is a motion segment that started at a known instant, and every query
evaluates that segment at ``clock.now()``. Moves use :func:`gonio.motion.trapezoid.position_at`, the
same profile the planner times its moves with, so plan estimates and simulated campaigns agree.

Fault injection (for the runner's tests) is explicit, via :meth:`SimAxis.fail_next`:

``"timeout"``
    The controller does not answer the next ``move_to``: it raises ``DeviceFault(transient=True)`` and
    the command is *not* executed (the axis stays where it was), so a retry is safe.
``"hardware"``
    The next ``move_to`` trips an error bit (overload): the command is refused with
    ``DeviceFault(transient=False)``, the axis stays where it is, and the fault latches (every later
    ``move_to`` raises; positions can still be read) until :meth:`SimAxis.clear_fault` or ``close()``
    + ``connect()``.
``"stall"``
    The next move is blocked halfway: the axis follows the profile until half of the move time has
    passed, then stops dead at the midpoint of the path and reports that it is no longer moving. No
    error is raised; the runner's position check is what must catch it.

Faults are consumed one per accepted ``move_to`` call, in the order they were queued. ``move_to`` is
accepted only at rest (a moving axis refuses a new target: the profile is rest-to-rest), so a fault
never interrupts a move in progress.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from gonio.config import AxisConfig
from gonio.motion.trapezoid import move_time, position_at
from gonio.protocols import Clock, DeviceFault

__all__ = ["SimAxis", "FAULT_KINDS"]

_INF = float("inf")
#: The fault kinds :meth:`SimAxis.fail_next` accepts.
FAULT_KINDS = ("timeout", "hardware", "stall")


@dataclass(frozen=True)
class _Move:
    """A rest-to-rest trapezoidal move that began at ``t0_s``; it may be cut short at ``stall_s``."""

    t0_s: float
    start_deg: float
    target_deg: float
    v_max: float
    a_max: float
    #: Seconds after ``t0_s`` at which the shaft is blocked (inf: never).
    stall_s: float = float("inf")

    @cached_property
    def duration_s(self) -> float:
        # Cached: a campaign looks at a moving axis ~10 times a step (the same value every time).
        return min(float(move_time(self.target_deg - self.start_deg, self.v_max, self.a_max)), self.stall_s)

    def position(self, t_s: float) -> float:
        tau = min(max(t_s - self.t0_s, 0.0), self.duration_s)
        if tau == self.duration_s and self.stall_s == _INF:
            # Arrived: the target itself, not start + (target − start), which can miss it by an ulp.
            return self.target_deg
        return float(position_at(tau, self.start_deg, self.target_deg, self.v_max, self.a_max))

    def velocity(self, t_s: float) -> float:
        """Signed velocity (°/s) at ``t_s``: the trapezoid's slope, min(a·τ, v_peak, a·(T − τ))."""
        tau = t_s - self.t0_s
        if tau <= 0.0 or tau >= self.duration_s:
            return 0.0
        delta = self.target_deg - self.start_deg
        total = float(move_time(delta, self.v_max, self.a_max))
        v_peak = min(self.v_max, np.sqrt(abs(delta) * self.a_max))
        speed = min(self.a_max * tau, v_peak, self.a_max * (total - tau))
        return float(np.sign(delta)) * max(speed, 0.0)


@dataclass(frozen=True)
class _Brake:
    """A stop at the maximum deceleration from velocity ``v0`` (°/s, signed) at ``x0_deg``, after
    which the servo holds ``settle_deg`` (the encoder count nearest where the brake ended)."""

    t0_s: float
    x0_deg: float
    v0: float
    a_max: float
    settle_deg: float

    @property
    def duration_s(self) -> float:
        return abs(self.v0) / self.a_max

    def position(self, t_s: float) -> float:
        tau = t_s - self.t0_s
        if tau >= self.duration_s:
            return self.settle_deg
        tau = max(tau, 0.0)
        return self.x0_deg + self.v0 * tau - 0.5 * np.sign(self.v0) * self.a_max * tau * tau

    def velocity(self, t_s: float) -> float:
        tau = t_s - self.t0_s
        if tau <= 0.0 or tau >= self.duration_s:
            return 0.0
        return self.v0 - np.sign(self.v0) * self.a_max * tau


class SimAxis:
    """A simulated servo axis satisfying :class:`gonio.protocols.Axis`.

    Parameters
    ----------
    name : str
        Axis name, used in every error message (e.g. ``"light_tilt"``).
    cfg : gonio.config.AxisConfig
        Limits (°), maximum velocity (°/s) and acceleration (°/s²), home position (°) and encoder
        resolution (°; 0 for an ideal encoder).
    clock : gonio.protocols.Clock
        Time source; a :class:`gonio.clock.VirtualClock` makes every move instantaneous in wall time.

    Notes
    -----
    With ``resolution_deg > 0`` the servo settles on the encoder count nearest the commanded target
    (inside the limits), and :meth:`position_deg` reports the shaft angle rounded to a count, so the
    commanded and reported positions differ by up to half a count, as on a real servo.
    :meth:`true_position_deg` is the unquantized shaft angle: what the simulated optics see.

    The axis powers up at rest at ``start_deg`` (default ``home_deg``; rounded to a count): a gantry
    that no process drives stays where it was, so a resumed simulation starts where the journal last
    saw the axes.
    """

    def __init__(self, name: str, cfg: AxisConfig, clock: Clock, start_deg: float | None = None):
        self.name = name
        self.cfg = cfg
        self.limits_deg = (float(cfg.min_deg), float(cfg.max_deg))
        self._clock = clock
        self._connected = False
        self._fault: str | None = None
        self._pending: deque[str] = deque()
        start = float(cfg.home_deg if start_deg is None else start_deg)
        if not (np.isfinite(start) and self.limits_deg[0] <= start <= self.limits_deg[1]):
            raise ValueError(f"axis '{name}': start_deg {start!r} is outside the limit "
                             f"[{self.limits_deg[0]:g}°, {self.limits_deg[1]:g}°]")
        rest = self._settle_point(start)
        self._motion: _Move | _Brake = _Brake(clock.now(), rest, 0.0, cfg.max_accel_deg_s2, rest)

    def describe(self) -> dict:
        """What this axis is, for the journal (:class:`gonio.protocols.Describes`)."""
        c = self.cfg
        return {"name": self.name, "driver": "sim", "identity": "simulated servo", "firmware": None,
                "units": "deg", "settings": {"limits_deg": list(self.limits_deg),
                                             "velocity_deg_s": float(c.max_velocity_deg_s),
                                             "accel_deg_s2": float(c.max_accel_deg_s2),
                                             "resolution_deg": float(c.sim.resolution_deg)}}

    # -- connection -------------------------------------------------------------------------------
    def connect(self, readonly: bool = False) -> None:
        """Open the (simulated) link; clears a latched hardware fault, as a power cycle would. A simulated
        axis writes nothing to anything: ``readonly`` changes nothing."""
        self._connected = True
        self._fault = None

    def close(self) -> None:
        """Brake to a halt and close the link (a no-op when already closed)."""
        if self._connected:
            self._brake()
        self._connected = False

    # -- the Axis protocol ------------------------------------------------------------------------
    def move_to(self, target_deg: float) -> None:
        """Start a trapezoidal move to ``target_deg`` (°) and return at once.

        Raises
        ------
        ValueError
            ``target_deg`` is not finite or outside ``limits_deg``.
        RuntimeError
            The axis is still moving (wait for it, or ``stop()`` and wait for the brake to finish).
        DeviceFault
            Not connected, a latched hardware fault, or an injected fault (see the module docstring).
        """
        self._require_connected()
        target = float(target_deg)
        lo, hi = self.limits_deg
        if not math.isfinite(target) or not lo <= target <= hi:
            raise ValueError(
                f"axis '{self.name}': target {target:.1f}° is outside the limit [{lo:g}°, {hi:g}°]"
            )
        if self._fault is not None:
            raise DeviceFault(self.name, f"{self._fault} (latched; call clear_fault())", transient=False)
        now = self._clock.now()
        if now < self._end_time():
            raise RuntimeError(
                f"axis '{self.name}': move_to({target:.3f}°) while still moving; "
                "wait for the axis to stop first"
            )
        kind = self._pending.popleft() if self._pending else None
        if kind == "timeout":
            raise DeviceFault(self.name, "no reply to move command (time-out)", transient=True)
        if kind == "hardware":
            self._fault = "hardware error: overload"
            raise DeviceFault(self.name, self._fault, transient=False)
        start = self._motion.position(now)
        goal = self._settle_point(target)
        move = _Move(now, start, goal, self.cfg.max_velocity_deg_s, self.cfg.max_accel_deg_s2)
        if kind == "stall":
            move = _Move(now, start, goal, move.v_max, move.a_max, stall_s=0.5 * move.duration_s)
        self._motion = move

    def position_deg(self) -> float:
        """Encoder reading (°): the shaft angle rounded to the encoder resolution."""
        self._require_connected()
        return self._quantize(self.true_position_deg())

    def is_moving(self) -> bool:
        self._require_connected()
        return self._clock.now() < self._end_time()

    def stop(self) -> None:
        """Brake at the maximum deceleration from the current velocity (not an instant halt).

        The axis keeps reporting ``is_moving()`` until the brake finishes, then settles on the nearest
        encoder count. Stopping an axis at rest does nothing.
        """
        self._require_connected()
        self._brake()

    # -- simulation-only ----------------------------------------------------------------------------
    def true_position_deg(self, t_s: float | None = None) -> float:
        """Unquantized shaft angle (°) at ``t_s`` (default: now); what the simulated optics see."""
        t = self._clock.now() if t_s is None else float(t_s)
        return float(self._motion.position(t))

    def arrival_time_s(self) -> float:
        """Clock time (s) at which the current motion ends (in the past when at rest)."""
        return self._end_time()

    def fail_next(self, kind: str, times: int = 1) -> None:
        """Make the next ``times`` calls of ``move_to`` fail with ``kind`` (see the module docstring)."""
        if kind not in FAULT_KINDS:
            raise ValueError(
                f"axis '{self.name}': fault kind {kind!r} is not one of {', '.join(FAULT_KINDS)}"
            )
        if not isinstance(times, int) or times < 1:
            raise ValueError(f"axis '{self.name}': times must be an integer >= 1, got {times!r}")
        self._pending.extend([kind] * times)

    def clear_fault(self) -> None:
        """Reset a latched hardware fault (the error bit), as a controller's reboot command would."""
        self._require_connected()
        self._fault = None

    def fault(self) -> str | None:
        """The latched fault message, or None."""
        return self._fault

    # -- internals ----------------------------------------------------------------------------------
    def _require_connected(self) -> None:
        if not self._connected:
            raise DeviceFault(self.name, "not connected: call connect() first", transient=False)

    def _end_time(self) -> float:
        return self._motion.t0_s + self._motion.duration_s

    def _brake(self) -> None:
        now = self._clock.now()
        v0 = self._motion.velocity(now)
        x0 = self._motion.position(now)
        # A move's stopping distance never exceeds the distance left to its target, so the brake ends
        # inside the limits; the servo then holds the encoder count nearest that point.
        end = x0 + 0.5 * v0 * abs(v0) / self.cfg.max_accel_deg_s2
        self._motion = _Brake(now, x0, v0, self.cfg.max_accel_deg_s2, self._settle_point(end))

    def _quantize(self, x: float) -> float:
        res = self.cfg.sim.resolution_deg
        return _round_half_even(x / res) * res if res > 0 else float(x)

    def _settle_point(self, x: float) -> float:
        """The encoder count nearest ``x`` that lies inside the limits (``x`` itself when ideal)."""
        res = self.cfg.sim.resolution_deg
        if res <= 0:
            return float(x)
        lo, hi = self.limits_deg
        k = _round_half_even(x / res)
        # Limits need not fall on a count: step one count inward rather than settle past a limit.
        if k * res > hi:
            k -= 1
        if k * res < lo:
            k += 1
        return float(k * res)


def _round_half_even(x: float) -> float:
    """``np.round`` of one float (halves to even, the sign of a zero kept), in plain Python: an axis is
    read several times a step."""
    x = float(x)
    return math.copysign(float(round(x)), x) if math.isfinite(x) else x
