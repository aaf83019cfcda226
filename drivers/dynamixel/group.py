"""Several Dynamixel axes of one bus moved with one Sync Write and read with one Sync Read per step.

The group reads the state block (Bus Watchdog .. Present Position) of every servo in one Sync Read,
checks each position for plausibility as the axis itself does (a servo whose position is implausible
makes the whole Sync Read go again, fresh; still implausible, a fault), and writes the goals of a move,
or of a stop, in one Sync Write.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from gonio.drivers.dynamixel.errors import DynamixelCommError
from gonio.drivers.dynamixel.state import BLOCK_LEN, BLOCK_START, READS, AxisState

__all__ = ["DynamixelGroup", "PROFILE_BLOCK"]

#: The contiguous items a sweep's start writes, in address order (108, 112, 116 on the X-series).
PROFILE_BLOCK = ("profile_acceleration", "profile_velocity", "goal_position")


class DynamixelGroup:
    """Several axes of one bus, moved with one Sync Write and read with one Sync Read per step.

    Parameters
    ----------
    axes : sequence of DynamixelAxis
        Connected axes sharing one :class:`DynamixelBus` (distinct IDs; X-series families, whose
        watchdog, goal and present fields share addresses).
    """

    def __init__(self, axes: Sequence):
        axes = list(axes)
        if not axes:
            raise ValueError("dynamixel group: needs at least one axis")
        bus = axes[0].bus
        if any(a.bus is not bus for a in axes):
            raise ValueError("dynamixel group: every axis must be on the same bus")
        if len({a.dxl_id for a in axes}) != len(axes):
            raise ValueError("dynamixel group: servo IDs must be distinct")
        shared = ("bus_watchdog", "goal_position", "present_velocity", "present_position", "moving",
                  *PROFILE_BLOCK)
        if any(a.table[f] != axes[0].table[f] for a in axes for f in shared):
            raise ValueError("dynamixel group: the axes' control tables must place the watchdog, goal and "
                             "present fields at the same addresses")
        self.bus = bus
        self.axes = {a.name: a for a in axes}
        self._table = axes[0].table
        if [self._table[f].address for f in PROFILE_BLOCK] != [108, 112, 116] \
                or any(self._table[f].size != 4 for f in PROFILE_BLOCK):
            raise ValueError("dynamixel group: Profile Acceleration, Profile Velocity and Goal Position must "
                             "be contiguous 4-byte items at 108, 112, 116 (X-series)")
        rooms = [a.table.room(BLOCK_START, BLOCK_LEN) for a in axes]
        self._room = (min(r[0] for r in rooms), min(r[1] for r in rooms))

    @property
    def watchdog_s(self) -> float | None:
        """The shortest bus watchdog of the group's servos (s), or None when none has one."""
        dogs = [a.watchdog_s for a in self.axes.values() if a.watchdog_s]
        return min(dogs) if dogs else None

    @property
    def armed(self) -> bool:
        """Whether any servo of the group has its bus watchdog armed (a move is under way)."""
        return any(a.armed for a in self.axes.values())

    def move_to(self, targets: Mapping[str, float]) -> None:
        """Check every target first (nothing moves if one is refused), arm the watchdogs that are not
        armed (one Sync Write), then one Sync Write of the goal positions."""
        unknown = set(targets) - set(self.axes)
        if unknown:
            raise ValueError(f"dynamixel group: unknown axes {sorted(unknown)}; known: {sorted(self.axes)}")
        goals = {self.axes[n].dxl_id: self.axes[n].check_target(v) for n, v in targets.items()}
        with self.bus.lock:
            for n in targets:  # a power cycle since the servo last failed; a sweep's profile left behind
                self.axes[n].prepare_goal()
                self.axes[n].restore_profile()
            self._arm(targets)
            self.bus.sync_write(self._table["goal_position"], goals)

    def _arm(self, names) -> None:
        """One Sync Write arming the bus watchdog of the named servos not armed yet (none: nothing sent)."""
        arm = {a.dxl_id: a.watchdog_units for a in self.axes.values()
               if a.name in names and not a.armed and a.watchdog_units}
        if arm:
            self.bus.sync_write(self._table["bus_watchdog"], arm)
            for a in self.axes.values():
                if a.dxl_id in arm:
                    a.mark_armed(True)

    def start_sweeps(self, targets: Mapping[str, float]) -> None:
        """Start the sweeps the named axes prepared (:meth:`DynamixelAxis.prepare`) toward ``targets``
        (°) with ONE Sync Write of Profile Acceleration(108), Profile Velocity(112) and Goal Position(116),
        12 contiguous bytes per servo: every servo starts as the packet ends, each with its own profile
        (the e-Manual: a goal written with its profile is planned on that profile). Every target and
        every prepared profile is checked first (nothing is written if one is refused); the watchdogs
        not armed yet are armed first (one Sync Write). The axes' campaign profiles stay replaced until
        their ``complete()`` (or the next move).

        Raises
        ------
        ValueError
            An unknown axis, a target outside its limits, or an axis with no prepared sweep.
        """
        unknown = set(targets) - set(self.axes)
        if unknown:
            raise ValueError(f"dynamixel group: unknown axes {sorted(unknown)}; known: {sorted(self.axes)}")
        t = self._table
        starts = {n: self.axes[n].sweep_start(v) for n, v in targets.items()}
        blocks = {self.axes[n].dxl_id: b"".join(t[f].encode(int(x)).to_bytes(4, "little")
                                                for f, x in zip(PROFILE_BLOCK, (acc, vel, goal), strict=True))
                  for n, (goal, vel, acc) in starts.items()}
        with self.bus.lock:
            for n in targets:
                self.axes[n].prepare_goal()
            self._arm(targets)
            for n in targets:
                self.axes[n].took_sweep()
            self.bus.sync_write_block(t[PROFILE_BLOCK[0]].address, 12, blocks,
                                      what=f"start sweeps of {', '.join(targets)}")

    def read_stamped(self, clock) -> tuple[float, dict[str, AxisState]]:
        """:meth:`read`, stamped: (time, states), the time on ``clock`` (the gantry's) halfway through
        the Sync Read transaction. Each servo latches its Present Position while it answers, within the
        transaction, so the stamp is off by at most half of it (~0.5 ms for four servos at 1 Mbit/s);
        timestamps of a sweep's reads are what its positions are interpolated on.

        Raises
        ------
        As :meth:`read`.
        """
        states, (t0, t1) = self._read()
        return 0.5 * (t0 + t1), states

    def _sync_read(self) -> tuple[dict[str, bytes], dict[str, AxisState], tuple[float, float]]:
        """One Sync Read whose every position is plausible: (blocks, states, (start, end) on the axes'
        clock), the Sync Read made again (fresh) while one is not; the fault of the first implausible
        one when none comes."""
        by_id = {a.dxl_id: a for a in self.axes.values()}
        first = None
        clock = self.axes[next(iter(self.axes))].clock
        for _ in range(READS):
            t0 = clock.now()
            blocks = self.bus.sync_read(BLOCK_START, BLOCK_LEN, by_id, self._room)
            at = clock.now()
            states, raw = {}, {}
            for dxl_id, block in blocks.items():
                axis = by_id[dxl_id]
                err = axis.alert_fault()
                if err is not None:
                    raise err
                state = axis.checked_state(block, (t0, at))
                if state is None:
                    first = first or (axis, block, at)
                    break
                states[axis.name], raw[axis.name] = state, block
            else:
                return raw, states, (t0, at)
        axis, block, at = first
        raise axis.implausible(axis.state_of(block).position_deg, at)

    def read(self) -> dict[str, AxisState]:
        """Every axis's state from one Sync Read; a servo that does not answer raises (never a silent 0).

        Raises
        ------
        DynamixelCommError
            A servo did not answer, a bus watchdog fired (the servos named stopped short), or a
            position stayed implausible over fresh reads.
        DynamixelHardwareError
            A hardware error latched on one of the servos.
        NotReferencedError
            A servo lost its reference (its RAM was reset).
        """
        return self._read()[0]

    def _read(self) -> tuple[dict[str, AxisState], tuple[float, float]]:
        raw, out, span = self._sync_read()
        fired = [self.axes[n] for n, block in raw.items() if block[0] == 0xFF]
        if fired:
            self.bus.sync_write(self._table["bus_watchdog"], {a.dxl_id: 0 for a in fired})
            for a in fired:
                a.mark_armed(False)
            names = ", ".join(f"'{a.name}' at {out[a.name].position_deg:.2f}°" for a in fired)
            raise DynamixelCommError(self.bus.name, f"bus watchdog fired; stopped short: {names}")
        rest = {a.dxl_id: 0 for a in self.axes.values() if a.armed and not out[a.name].moving}
        if rest:
            self.bus.sync_write(self._table["bus_watchdog"], rest)
            for a in self.axes.values():
                if a.dxl_id in rest:
                    a.mark_armed(False)
        return out, span

    def stop_goals(self) -> dict[str, tuple[int, AxisState]]:
        """Goals (ticks) that hold each axis where it stands, with the state they come from: one Sync
        Read, every position plausible (see :meth:`_sync_read`). Servos their watchdog stopped are left
        out (their goal is locked; the error is cleared). Raises when no plausible read comes: no goal
        may come from a reply that cannot be trusted."""
        raw, states, _span = self._sync_read()
        fired = {n for n, block in raw.items() if block[0] == 0xFF}
        if fired:
            self.bus.sync_write(self._table["bus_watchdog"], {self.axes[n].dxl_id: 0 for n in fired})
            for n in fired:
                self.axes[n].mark_armed(False)
        off = self._table["present_position"].address - BLOCK_START
        field = self._table["present_position"]
        return {n: (field.decode(int.from_bytes(raw[n][off:off + 4], "little")), states[n])
                for n in raw if n not in fired}

    def write_goals(self, goals: Mapping[str, int]) -> None:
        """One Sync Write of goal positions (ticks) by axis name (a stop's: see :meth:`stop_goals`)."""
        if goals:
            self.bus.sync_write(self._table["goal_position"],
                                {self.axes[n].dxl_id: g for n, g in goals.items()})
