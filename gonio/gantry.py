"""An assembled gantry: kinematics, axes, light, detector and clock of any mix of drivers, behind the
:class:`gonio.protocols.Gantry` protocol.

:mod:`gonio.wiring` builds one from a config: Dynamixel servos, Modbus controllers, serial instruments
and simulated devices side by side. The gantry itself knows nothing of bytes: it connects and
closes its devices in order, stops every axis (a halt reaches every bus), and puts the white standard
under the beam with the config's target axis (a sample changer), or, without one, tells a simulated
detector to render the standard.

Batched motion: :meth:`AssembledGantry.move_axes`, :meth:`AssembledGantry.poll_axes` and
:meth:`AssembledGantry.positions` move and read the kinematics' axes with one Sync Write and one Sync
Read per Dynamixel bus (:class:`gonio.drivers.dynamixel.DynamixelGroup`) and one read per Modbus
controller (two where its profile keeps status and position apart and may not span them), the Modbus
connections asked at once where their round trips make that pay (:attr:`AssembledGantry.concurrent`;
the axes of one connection, e.g. an RTU bus, always in turn), and
:meth:`AssembledGantry.keep_alive` reads them during a move often enough that an armed Dynamixel bus
watchdog never fires while gonio lives (and stops the servos when it does not).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from gonio.protocols import (
    Axis,
    BatchedAxes,
    ChecksTarget,
    Clock,
    CountsLink,
    Describes,
    Detector,
    DeviceFault,
    FliesAxes,
    Flyable,
    Gantry,
    HoldsAtGoal,
    JoinsGroup,
    KeepsAlive,
    LightSource,
    ReadsInBatches,
    ReadsOnTheFly,
    ReadsState,
    Referencing,
    RendersFly,
    ReportsLink,
    ReportsWarnings,
    SharesConnection,
    StartsTogether,
    Streams,
    SwitchesTarget,
    TimesRoundTrip,
    Warns,
)

__all__ = ["AssembledGantry", "TargetChanger", "TARGETS", "Abilities", "abilities", "describe_devices",
           "start_groups"]


@dataclass(frozen=True)
class Abilities:
    """What a gantry declares it can do beyond :class:`gonio.protocols.Gantry` (each field the gantry
    itself where it satisfies that ability protocol, else None), asked once: :func:`abilities`."""

    batched: BatchedAxes | None
    keep_alive: KeepsAlive | None
    flies: FliesAxes | None
    renders_fly: RendersFly | None
    warnings: ReportsWarnings | None
    link: ReportsLink | None
    reads_on_the_fly: bool
    #: The detector, where it takes readings to develop them later in batches of more than one.
    batches: ReadsInBatches | None = None
    #: The detector where it streams (:class:`gonio.protocols.Streams`): fly sub-reads come from its
    #: stream, not from requests.
    streams: Streams | None = None


def abilities(gantry: Gantry) -> Abilities:
    """The declared abilities of ``gantry`` (see :mod:`gonio.protocols`): the one place core code asks
    a gantry what it can do. The engine asks once per run, the fly checks once per campaign."""
    def ask(protocol):
        return gantry if isinstance(gantry, protocol) else None

    return Abilities(batched=ask(BatchedAxes), keep_alive=ask(KeepsAlive), flies=ask(FliesAxes),
                     renders_fly=ask(RendersFly), warnings=ask(ReportsWarnings), link=ask(ReportsLink),
                     reads_on_the_fly=isinstance(gantry.detector, ReadsOnTheFly),
                     batches=_batches(gantry.detector),
                     streams=gantry.detector if isinstance(gantry.detector, Streams) else None)


def _batches(detector) -> ReadsInBatches | None:
    """``detector`` where it develops readings in batches of more than one, else None."""
    if isinstance(detector, ReadsInBatches) and detector.batch_readings() > 1:
        return detector
    return None


def describe_devices(gantry: Gantry) -> dict[str, dict]:
    """What every device of ``gantry`` says it is (:class:`gonio.protocols.Describes`), by name: the
    axes (the changer's too), the light and the detector."""
    devices = [*gantry.all_axes.values(), gantry.light, gantry.detector]
    return {d.name: d.describe() for d in devices if isinstance(d, Describes)}

#: What can be under the beam.
TARGETS = ("sample", "reference")
#: Automatic :attr:`AssembledGantry.concurrent`: the Modbus connections of a look are asked at once when
#: asking them in turn would take longer than this (s; the sum of the axes' shortest round trips). Below
#: it, handing the requests to threads costs more than it saves: against the in-process emulators
#: (~0.2 ms of Python per round trip, one thread at a time) a look at 4 controllers took 0.85 ms in
#: turn and 0.9-2.1 ms at once; behind real gateways, each round trip is milliseconds of waiting.
CONCURRENT_ABOVE_S = 0.002


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


def start_groups(axes) -> list:
    """The start groups of the connected ``axes`` that declare :class:`~gonio.protocols.StartsTogether`:
    one per key (an axis alone under its key, whose driver makes no group of it, moves by itself)."""
    by_key: dict[object, list] = {}
    for axis in axes:
        key = axis.start_key() if isinstance(axis, StartsTogether) else None
        if key is not None:
            by_key.setdefault(key, []).append(axis)
    groups = [group[0].make_start_group(group) for group in by_key.values()]
    return [g for g in groups if g is not None]


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
        if changer is None and not isinstance(detector, SwitchesTarget):
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
        # Batches, made at connect: (DynamixelGroup, its axes' indices in kinematics order); the
        # indices read one by one (Modbus controllers, simulated axes).
        self._groups: list = []
        self._singles: list[int] = []
        # The singles by connection (a Modbus client; otherwise each axis alone), in kinematics order.
        self._links: list[list[int]] = []
        # Singles whose moves start together (StartsTogether: Modbus held moves and one trigger), two
        # or more a group; read and stopped as singles still.
        self._starters: list = []
        self._pool: ThreadPoolExecutor | None = None
        #: Ask the Modbus connections of a look (and of a move) at once: True, False, or None for
        #: automatic (see :data:`CONCURRENT_ABOVE_S`).
        self.concurrent: bool | None = None
        #: Longest quiet spell (s, gantry clock) while a Dynamixel watchdog is armed: half the shortest
        #: watchdog; None without one.
        self.feed_s: float | None = None
        self._last_read = 0.0
        # What each device declared it can do (gonio.protocols), asked once here.
        every = self.all_axes
        self._renders_target = isinstance(detector, SwitchesTarget)
        self._checks = {n for n, a in self.axes.items() if isinstance(a, ChecksTarget)}
        self._flyable = {n for n, a in self.axes.items() if isinstance(a, Flyable)}
        warners = [*every.items(), (detector.name, detector)]
        self._warners = [(n, a) for n, a in warners if isinstance(a, Warns)]
        self._counters = [(n, a) for n, a in every.items() if isinstance(a, CountsLink)]
        self._holders = {n for n, a in every.items() if isinstance(a, HoldsAtGoal)}
        axes = list(self.axes.values())
        self._state_readers = {i for i, a in enumerate(axes) if isinstance(a, ReadsState)}
        self._timed = {i for i, a in enumerate(axes) if isinstance(a, TimesRoundTrip)}

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
        try:
            self._batch()  # a start mode the links do not allow: one line, every device closed
        except BaseException:
            self.close()
            raise

    def _batch(self) -> None:
        """Group the axes that declare :class:`~gonio.protocols.JoinsGroup` by bus, and the others by
        the connection they share (:class:`~gonio.protocols.SharesConnection`); those of the others
        that declare :class:`~gonio.protocols.StartsTogether` into start groups by their key."""
        names = list(self.axes)
        by_bus: dict[object, list[str]] = {}
        self._singles = []
        for i, (name, axis) in enumerate(self.axes.items()):
            if isinstance(axis, JoinsGroup):
                by_bus.setdefault(axis.group_key(), []).append(name)
            else:
                self._singles.append(i)
        self._groups = [(self.axes[group[0]].make_group([self.axes[n] for n in group]),
                         [names.index(n) for n in group]) for group in by_bus.values()]
        axes = list(self.axes.values())
        links: dict[int, list[int]] = {}
        for i in self._singles:
            link = axes[i].client if isinstance(axes[i], SharesConnection) else axes[i]
            links.setdefault(id(link), []).append(i)
        self._links = list(links.values())
        self._starters = start_groups([axes[i] for i in self._singles])
        dogs = [g.watchdog_s for g, _ in self._groups if g.watchdog_s]
        self.feed_s = min(dogs) / 2 if dogs else None

    def close(self) -> None:
        """Close every connected device (axes stop first); each is closed even if another fails."""
        first: Exception | None = None
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
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
        if self._renders_target:
            self.detector.set_target(target)
        self.target = target

    # -- what the devices saw (the runner journals it) ---------------------------------------------------
    def drain_warnings(self) -> list[tuple[str, str]]:
        """(axis, message) of the hardware warnings the axes saw since the last call: conditions their
        controllers report but do not act on (the axis went on)."""
        out = []
        for name, axis in self._warners:
            out += [(name, w) for w in axis.warnings()]
        return out

    def link_report(self) -> str | None:
        """One line on what the drivers could not trust (replies thrown away: late, duplicated, of another
        request; positions read again because implausible) and the transactions that failed, or None
        when there was nothing."""
        parts, links = [], {}
        for name, axis in self._counters:
            stats = axis.link_stats()
            if stats.get("implausible"):
                parts.append(f"{name}: {stats['implausible']} implausible position(s) read again")
            links[stats["link"]] = stats
        for link, stats in links.items():
            failed = ", ".join(f"{k} {v}" for k, v in sorted(stats.get("failed", {}).items()) if v)
            if stats.get("discarded") or failed:
                parts.append(f"{link}: {stats.get('discarded', 0)} reply(ies) discarded"
                             + (f"; failed: {failed}" if failed else ""))
        return "; ".join(parts) or None

    # -- batched motion (the runner uses these when a gantry has them) ---------------------------------
    def move_axes(self, targets: Mapping[str, float]) -> None:
        """Start moving the named kinematics axes to ``targets`` (°): every target is checked first
        (nothing moves if one is refused), then one Sync Write of goals per Dynamixel bus (after one
        arming the watchdogs of servos that are not armed yet), one start per start group (Modbus
        controllers: every move held, then one trigger; a failed start named, the others stopped) and
        one move per other axis."""
        unknown = [n for n in targets if n not in self.axes]
        if unknown:
            raise ValueError(f"axes: unknown {', '.join(unknown)}; known: {', '.join(self.axes)}")
        for name, t in targets.items():
            if name in self._checks:
                self.axes[name].check_target(t)
        for group, _ in self._groups:
            mine = {n: float(t) for n, t in targets.items() if n in group.axes}
            if mine:
                group.move_to(mine)
        started: set[str] = set()
        for group in self._starters:
            mine = {n: float(t) for n, t in targets.items() if n in group.axes}
            if mine:
                group.move_to(mine)
                started |= set(mine)
        axes, names = list(self.axes.values()), self.kinematics.axis_names
        self._each_link(lambda i: axes[i].move_to(float(targets[names[i]])),
                        [i for i in self._singles if names[i] in targets and names[i] not in started])
        self._last_read = self.clock.now()

    def _read_groups(self, pos: np.ndarray, moving: np.ndarray) -> None:
        for group, idx in self._groups:
            states = group.read()
            for i, axis in zip(idx, group.axes.values(), strict=True):
                pos[i], moving[i] = states[axis.name].position_deg, states[axis.name].moving
        self._last_read = self.clock.now()

    def stamped_positions(self) -> tuple[np.ndarray, np.ndarray]:
        """(times, positions) of the kinematics' axes, in their order: one stamped Sync Read per
        Dynamixel bus (:meth:`DynamixelGroup.read_stamped`: each axis carries its own bus's stamp, on
        the gantry clock), and each other axis read one by one, stamped halfway through its read."""
        n = len(self.axes)
        pos, stamp = np.empty(n), np.empty(n)
        for group, idx in self._groups:
            t, states = group.read_stamped(self.clock)
            for i, axis in zip(idx, group.axes.values(), strict=True):
                pos[i], stamp[i] = states[axis.name].position_deg, t
        self._last_read = self.clock.now()
        axes = list(self.axes.values())
        for i in self._singles:
            t0 = self.clock.now()
            pos[i] = axes[i].position_deg()
            stamp[i] = 0.5 * (t0 + self.clock.now())
        return stamp, pos

    def sweep(self, name: str, target_deg: float, velocity_deg_s: float,
              accel_deg_s2: float) -> tuple[float, float]:
        """Start axis ``name`` toward ``target_deg`` at a set velocity and acceleration (a fly sweep);
        returns the (velocity, acceleration) it runs at, quantised by its driver. Only an axis whose
        driver can be given a profile per move (a Dynamixel servo) sweeps; :meth:`end_sweep` restores
        its campaign profile.

        Raises
        ------
        ValueError
            ``name`` is unknown, or its driver cannot sweep (the message names it and why).
        """
        return self.sweep_axes({name: (target_deg, velocity_deg_s, accel_deg_s2)})[name]

    def sweep_axes(self, sweeps: Mapping[str, tuple[float, float, float]]) -> dict[str, tuple[float, float]]:
        """Start several axes at once, each toward its target at its own velocity and acceleration:
        ``sweeps`` maps a name to (target °, velocity °/s, acceleration °/s²). Every profile is prepared
        (checked, quantised) first, so nothing moves if one is refused; then the axes of one bus start
        with one packet (:meth:`DynamixelGroup.start_sweeps`: goal and profile of every servo in one Sync
        Write) and any other sweeping axis by its own kickoff. Returns each axis's (velocity, acceleration)
        as its driver quantised them.

        Raises
        ------
        ValueError
            A name is unknown, or its driver cannot sweep (the message names it and why), or a profile or
            target is refused.
        """
        for name in sweeps:
            if name not in self.axes:
                raise ValueError(f"axes: unknown {name}; known: {', '.join(self.axes)}")
            if not self.can_sweep(name):
                raise ValueError(f"axes.{name}: its driver cannot sweep at a set velocity (on-the-fly "
                                 "scanning needs a Dynamixel servo)")
        out = {n: self.axes[n].prepare(float(v), float(a)) for n, (_t, v, a) in sweeps.items()}
        for n, (t, _v, _a) in sweeps.items():
            self.axes[n].check_target(float(t))
        grouped = set()
        for group, _ in self._groups:
            mine = {n: float(sweeps[n][0]) for n in sweeps if n in group.axes}
            if mine:
                group.start_sweeps(mine)
                grouped |= set(mine)
        for n, (t, _v, _a) in sweeps.items():
            if n not in grouped:
                self.axes[n].kickoff(float(t))
        self._last_read = self.clock.now()
        return out

    def can_sweep(self, name: str) -> bool:
        """Whether axis ``name`` declares it sweeps at a set velocity (:class:`gonio.protocols.Flyable`)."""
        return name in self._flyable

    def end_sweep(self, name: str) -> None:
        """Restore axis ``name``'s campaign profile after :meth:`sweep`."""
        if name in self._flyable:
            self.axes[name].complete()

    def positions(self) -> np.ndarray:
        """Positions (°) of the kinematics' axes, in their order: one Sync Read per Dynamixel bus (a
        servo that does not answer raises, never a silent 0), and one read per other axis."""
        n = len(self.axes)
        pos = np.empty(n)
        self._read_groups(pos, np.zeros(n, dtype=bool))
        axes = list(self.axes.values())
        for i, p in self._each_link(lambda i: axes[i].position_deg()).items():
            pos[i] = p
        return pos

    def _threads(self, singles: list[int]) -> bool:
        """Whether to ask the connections of ``singles`` at once (see :attr:`concurrent`)."""
        links = sum(any(i in link for i in singles) for link in self._links)
        if links < 2 or self.concurrent is False:
            return False
        if self.concurrent:
            return True
        axes = list(self.axes.values())
        return sum(axes[i].round_trip_s or 0.0 for i in singles if i in self._timed) > CONCURRENT_ABOVE_S

    def _each_link(self, fn: Callable[[int], object], singles: list[int] | None = None) -> dict[int, object]:
        """``fn(i)`` for each axis index of ``singles`` (default: every single axis), by index. The axes
        of one connection are asked in turn in one task (an RTU bus is one shared line, and a pymodbus
        client one transaction at a time); different connections at once where :meth:`_threads` says
        so. Every task is let finish; then the first failure, in kinematics order, is raised."""
        singles = self._singles if singles is None else singles
        if not self._threads(singles):
            return {i: fn(i) for i in singles}

        def link_task(link):
            out = {}
            for i in link:
                try:
                    out[i] = fn(i)
                except BaseException as err:  # the rest of this connection is not asked
                    return out, (i, err)
            return out, None

        if self._pool is None:
            self._pool = ThreadPoolExecutor(len(self._links), thread_name_prefix="gantry-link")
        tasks = [self._pool.submit(link_task, [i for i in link if i in singles]) for link in self._links
                 if any(i in singles for i in link)]
        results, failures = {}, []
        for task in tasks:
            out, failed = task.result()
            results.update(out)
            if failed is not None:
                failures.append(failed)
        if failures:
            raise min(failures, key=lambda f: f[0])[1]
        return results

    def poll_axes(self) -> tuple[np.ndarray | None, bool]:
        """One look while waiting for a move: (positions, False) once every axis is still, else
        (None, True). The Dynamixel buses are read first (one Sync Read each); while one of their axes
        moves, no other axis is asked, and an axis read one by one (Modbus) is asked for its position
        only when it is still."""
        n = len(self.axes)
        pos, moving = np.empty(n), np.zeros(n, dtype=bool)
        self._read_groups(pos, moving)
        if moving.any():
            return None, True
        axes = list(self.axes.values())
        if self._threads(self._singles):  # every connection at once: one round trip, two where apart
            states = self._each_link(lambda i: axes[i].read_state() if i in self._state_readers
                                     else (axes[i].position_deg(), axes[i].is_moving()))
            for i, (p, m) in states.items():
                pos[i], moving[i] = p, m
            return (None, True) if moving.any() else (pos, False)
        apart = []
        for i in self._singles:
            a = axes[i]
            if i in self._state_readers and a.state_in_one_read:
                pos[i], m = a.read_state()
            else:
                m = a.is_moving()
                apart.append(i)
            if m:
                return None, True
        for i in apart:
            pos[i] = axes[i].position_deg()
        return pos, False

    def keep_alive(self) -> None:
        """Called between slices of a wait: while a Dynamixel watchdog is armed (a move under way), read
        the Dynamixel axes (one Sync Read per bus) once every half ``feed_s`` (a quarter of the
        watchdog), so that the watchdog hears from gonio with three quarters of its period to spare for
        a host the OS holds up (a loaded machine: 0.1-0.2 s seen); otherwise nothing. A fault seen on
        the way (a hardware error, a servo that does not answer, a watchdog that fired) raises as from
        :meth:`positions`."""
        if self.feed_s is None or not any(g.armed for g, _ in self._groups):
            return
        if self.clock.now() - self._last_read >= 0.5 * self.feed_s:
            n = len(self.axes)
            self._read_groups(np.empty(n), np.zeros(n, dtype=bool))

    def stop(self) -> None:
        """Stop every axis on every bus (the changer's too), each even if another fails; safe from any
        thread. Re-raises the first failure once all were asked.

        Axes stopped by a command (Modbus controllers, simulated axes) get it first. Servos are stopped by
        a goal at their present position, read fresh (one Sync Read per bus) and plausible, never from a
        reply that cannot be trusted (:meth:`DynamixelAxis.stop_goal`); before the goals are written, the
        configuration they hold and each servo's braking overshoot beyond it (v²/2a at the kinematics'
        acceleration) are checked with the swept-path check: goals it rejects are not written (those
        servos go on to the goals they had, which were checked before they were given) and the stop
        raises saying so."""
        first: Exception | None = None
        planned: dict[str, tuple] = {}  # name -> (goal ticks, state, group or None)
        grouped: set[str] = set()
        for group, _ in self._groups:
            grouped |= set(group.axes)
            try:
                for n, (ticks, state) in group.stop_goals().items():
                    planned[n] = (ticks, state, group)
            except Exception as err:
                first = first or err
        for name, axis in self.all_axes.items():
            if name in grouped:
                continue
            try:
                if name in self._holders:
                    found = axis.stop_goal()
                    if found is not None:
                        planned[name] = (found[0], found[1], None)
                else:
                    axis.stop()
            except Exception as err:
                first = first or err
        refused = self._stop_refused(planned)
        if refused is not None:
            first = first or refused
            planned = {n: p for n, p in planned.items() if n not in self.axes}
        for group, _ in self._groups:
            mine = {n: p[0] for n, p in planned.items() if p[2] is group}
            try:
                group.write_goals(mine)
            except Exception as err:
                first = first or err
        for name, (ticks, _state, group) in planned.items():
            if group is None:
                try:
                    self.all_axes[name].hold(ticks)
                except Exception as err:
                    first = first or err
        if first is not None:
            raise first

    def _stop_refused(self, planned: Mapping[str, tuple]) -> DeviceFault | None:
        """The swept-path check of a stop's goals (see :meth:`stop`): None when clear, or cannot be
        made (no kinematics axis gets a goal; an axis not referenced reads in a frame of its own)."""
        kin = self.kinematics
        names = kin.axis_names
        if not any(n in planned for n in names):
            return None
        if any(isinstance(a, Referencing) and not a.referenced() for a in self.axes.values()):
            return None
        here, brake = np.empty(len(names)), np.empty(len(names))
        for i, n in enumerate(names):
            if n in planned:
                state = planned[n][1]
                v, a = state.velocity_deg_s, float(kin.accel_deg_s2[i])
                here[i], brake[i] = state.position_deg, state.position_deg + v * abs(v) / (2.0 * a)
            else:
                try:
                    here[i] = brake[i] = self.axes[n].position_deg()
                except Exception:
                    return None  # no position to check with: the goals hold the servos where they are
        lo, hi = kin.limits_deg[:, 0], kin.limits_deg[:, 1]
        brake = np.clip(brake, lo, hi)
        _clear, margin = kin.sweep_clearance(np.vstack([here, brake]), np.vstack([brake, here]))
        if float(margin.min()) >= -1e-9:
            return None
        fmt = ", ".join(f"{n}={x:.2f}°" for n, x in zip(names, here, strict=True))
        return DeviceFault("gantry", f"stop: goals at the present positions ({fmt}) are not clear "
                           f"({kin.collision_rule}): not written; the servos go on to the goals they had, "
                           "which were checked before they were given")
