"""An assembled gantry: kinematics, axes, light, detector and clock of any mix of drivers, behind the
:class:`gonio.protocols.Gantry` protocol.

:mod:`gonio.wiring` builds one from a config: Dynamixel servos, Modbus controllers, serial instruments
and simulated devices side by side. The gantry itself knows nothing of buses or bytes: it connects and
closes its devices in order, stops every axis (a halt reaches every bus), and puts the white standard
under the beam with the config's target axis (a sample changer), or, without one, tells a simulated
detector to render the standard.
"""

from __future__ import annotations

from collections.abc import Mapping

from gonio.protocols import Axis, Clock, Detector, DeviceFault, LightSource

__all__ = ["AssembledGantry", "TargetChanger", "TARGETS"]

#: What can be under the beam.
TARGETS = ("sample", "reference")


class TargetChanger:
    """An axis that swaps the sample and the white standard under the beam.

    Parameters
    ----------
    axis : Axis
        The changer's axis (its own device, outside the kinematics).
    sample_deg, reference_deg : float
        Axis positions (°) that put the sample, or the standard, under the beam.
    tolerance_deg : float
        How close (°) the axis must come to count as arrived.
    timeout_s : float
        Longest wait (s, gantry clock) for the axis to arrive.
    poll_s : float
        Interval (s) between looks at the moving axis.
    """

    def __init__(self, axis: Axis, *, sample_deg: float, reference_deg: float, tolerance_deg: float,
                 timeout_s: float, poll_s: float):
        self.axis = axis
        self.positions_deg = {"sample": float(sample_deg), "reference": float(reference_deg)}
        self.tolerance_deg = float(tolerance_deg)
        self.timeout_s = float(timeout_s)
        self.poll_s = float(poll_s)

    def put(self, target: str, clock: Clock) -> None:
        """Move the changer to ``target``'s position and wait until it is there.

        Raises
        ------
        DeviceFault
            The axis did not arrive within ``timeout_s`` (transient: the runner retries the step), or
            stopped away from the position (not transient: something blocks the changer).
        """
        want = self.positions_deg[target]
        if abs(self.axis.position_deg() - want) <= self.tolerance_deg and not self.axis.is_moving():
            return
        self.axis.move_to(want)
        waited = 0.0
        while self.axis.is_moving():
            if waited >= self.timeout_s:
                self.axis.stop()
                raise DeviceFault(self.axis.name, f"did not reach the {target} position {want:g}° within "
                                  f"{self.timeout_s:g} s", transient=True)
            clock.sleep(self.poll_s)
            waited += self.poll_s
        at = self.axis.position_deg()
        if abs(at - want) > self.tolerance_deg:
            raise DeviceFault(self.axis.name, f"stopped at {at:.3f}°, not at the {target} position "
                              f"{want:g}° (tolerance {self.tolerance_deg:g}°): is the changer blocked?")


class AssembledGantry:
    """A gantry of any mix of devices, satisfying :class:`gonio.protocols.Gantry`.

    Parameters
    ----------
    name : str
        Gantry name (from the config).
    kinematics
        Has ``axis_names``; the axes are held in that order.
    axes : Mapping[str, Axis]
        Exactly the kinematics' axes.
    light : LightSource
    detector : Detector
    clock : Clock
        The wall clock (``real_time``) when a real device takes part; a virtual one otherwise.
    changer : TargetChanger, optional
        Puts the sample or the white standard under the beam. Without it the detector must render the
        standard itself (a simulated detector's ``set_target``).
    """

    def __init__(self, name: str, kinematics, axes: Mapping[str, Axis], light: LightSource,
                 detector: Detector, clock: Clock, changer: TargetChanger | None = None):
        missing = [a for a in kinematics.axis_names if a not in axes]
        extra = [a for a in axes if a not in kinematics.axis_names]
        if missing or extra:
            raise ValueError(f"axes: must be exactly {', '.join(kinematics.axis_names)}"
                             + (f"; missing: {', '.join(missing)}" if missing else "")
                             + (f"; unknown: {', '.join(extra)}" if extra else ""))
        if changer is None and not hasattr(detector, "set_target"):
            raise ValueError(f"detector '{detector.name}': a real detector needs a target changer axis to "
                             "put the white standard under the beam")
        self.name = name
        self.kinematics = kinematics
        self.axes = {a: axes[a] for a in kinematics.axis_names}
        self.light = light
        self.detector = detector
        self.clock = clock
        self.changer = changer
        self.target = "sample"
        self._connected: list = []

    @property
    def all_axes(self) -> dict[str, Axis]:
        """The kinematics' axes and the changer's, by name."""
        out = dict(self.axes)
        if self.changer is not None:
            out[self.changer.axis.name] = self.changer.axis
        return out

    def devices(self) -> list:
        """Every device, in the order they connect."""
        return [*self.all_axes.values(), self.light, self.detector]

    # -- the Gantry protocol ------------------------------------------------------------------------
    def connect(self) -> None:
        """Connect every device in turn; if one fails, close those already connected, then raise."""
        for device in self.devices():
            if device in self._connected:
                continue
            try:
                device.connect()
            except BaseException:
                self.close()
                raise
            self._connected.append(device)

    def close(self) -> None:
        """Close every connected device (axes stop first); each is closed even if another fails."""
        first: Exception | None = None
        for device in reversed(self._connected):
            try:
                device.close()
            except Exception as err:  # close the rest, then re-raise the first
                first = first or err
        self._connected = []
        if first is not None:
            raise first

    def set_target(self, target: str) -> None:
        """Put ``"sample"`` or ``"reference"`` (the white standard) under the beam: the changer axis
        moves there and the call returns once it has arrived (a simulated detector is told too)."""
        if target not in TARGETS:
            raise ValueError(f"target: {target!r} is not one of {', '.join(repr(t) for t in TARGETS)}")
        if self.changer is not None:
            self.changer.put(target, self.clock)
        if hasattr(self.detector, "set_target"):
            self.detector.set_target(target)
        self.target = target

    def stop(self) -> None:
        """Stop every axis on every bus (the changer's too), each even if another fails; safe from any
        thread. Re-raises the first failure once all were asked."""
        first: Exception | None = None
        for axis in self.all_axes.values():
            try:
                axis.stop()
            except Exception as err:
                first = first or err
        if first is not None:
            raise first
