"""Several Modbus axes started together: each one's move preloaded, then one start that they all execute.

Each moving axis's move block is written with the profile's hold trigger (``[sync_start]``: Oriental
Motor's direct data operation keeps target, speed and acceleration written with trigger 0, and a later
write of trigger 1 alone starts the move with them), each write answered by its own unit. Then the
start, one of three ways (``mode``):

- ``"group"`` (Oriental Motor's group send, units on one line): after the preloads, each child's group
  register is set to the parent's address (the first axis; its own stays -1) and read back (one
  function 23 request each where the profile has ``write_read``); ONE Write Multiple Registers of the
  trigger to the parent's address is executed by every child and answered by the parent alone; then the
  parent's group register is written -1, which every child executes too, and each child's is read back
  (-1 again; one that missed it is written itself). The group is held only for the start:
  while it stands, every Write Multiple Registers to the parent (a move, a stop) is executed by every
  child too, which a gantry's stop-and-go moves of the parent must never be. (The unit also drops it at
  power-off. Should gonio die between the join and the leave, the children stay grouped until the next
  start or a power cycle: the parent is preloaded first, so such a stale group's copy of its block is
  overwritten by each child's own preload.)
- ``"broadcast"`` (units on one RTU line): ONE Write Multiple Registers of the trigger to address 0;
  every unit on the line executes it, none answers (so every unit of the line must be in the group).
- ``"back_to_back"`` (each unit behind its own Modbus TCP gateway: no query reaches two): the trigger
  query is sent on every connection before any reply is awaited; then each reply is read.

In the group and broadcast modes every unit that executes the query starts whatever it holds: the axes
of the group that are not given a move are preloaded to stay where they are. Nobody answers for the
children (or anyone, on a broadcast): every axis's start is then checked by reading its status (the
moving bit, or the position at its target) until its ``start_timeout_s``; an axis that did not start (an
alarm, a unit out of the group) is named in a :class:`SyncStartError`, after the axes that did start
are stopped (a coordinated move with an axis missing would leave its path). A start query that fails
on the way (a trigger's reply lost behind one gateway) stops every axis of the start before it raises.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence

from pymodbus.client import ModbusSerialClient, ModbusTcpClient

from gonio.drivers.modbus.errors import ModbusAlarmError, ModbusCommError, ModbusExceptionError
from gonio.protocols import DeviceFault

__all__ = ["ModbusStartGroup", "SyncStartError", "START_MODES"]

START_MODES = ("group", "broadcast", "back_to_back")


class SyncStartError(DeviceFault):
    """Some axes of a synchronized start did not start; ``failed`` maps each one's name to why."""

    def __init__(self, device: str, failed: Mapping[str, str]):
        self.failed = dict(failed)
        if list(self.failed) == [device]:  # one axis, the device named: not twice
            why = self.failed[device]
        else:
            why = "; ".join(f"{n}: {why}" for n, why in self.failed.items())
        super().__init__(device, f"did not start: {why}",
                         transient=False)


class ModbusStartGroup:
    """Modbus axes whose moves start together (see the module docstring).

    Parameters
    ----------
    axes : sequence of ModbusAxis
        Connected axes whose profiles have ``[sync_start]``, distinct units; the first is the group's
        parent in the ``"group"`` mode.
    mode : str
        One of :data:`START_MODES`.
    turnaround_s : float
        After a broadcast, how long (s, on the axes' clock) the line is left silent before the status
        reads, so every unit has handled it (the Modbus serial line specification's turnaround delay,
        typically 100 to 200 ms).
    """

    def __init__(self, axes: Sequence, mode: str, *, turnaround_s: float = 0.1):
        axes = list(axes)
        if mode not in START_MODES:
            raise ValueError(f"modbus start group: mode {mode!r} is not one of {', '.join(START_MODES)}")
        if not axes:
            raise ValueError("modbus start group: needs at least one axis")
        for a in axes:
            if a.profile.sync_start is None:
                raise ValueError(f"modbus start group: axis '{a.name}': profile '{a.profile.name}' has no "
                                 "[sync_start] (its manual gives no held move and trigger)")
        if not 0.0 <= turnaround_s <= 1.0:
            raise ValueError(f"modbus start group: turnaround_s {turnaround_s} is outside [0, 1]")
        self.mode = mode
        self.turnaround_s = float(turnaround_s)
        #: Wall time (s) between the first and the last trigger sent, at the last back_to_back start.
        self.send_spread_s = 0.0
        self.axes = {a.name: a for a in axes}
        if len(self.axes) != len(axes):
            raise ValueError("modbus start group: axis names must be distinct")
        clients = {id(a.client) for a in axes}
        if mode == "back_to_back":
            if len(clients) != len(axes) or not all(isinstance(a.client, ModbusTcpClient) for a in axes):
                raise ValueError("modbus start group: back_to_back starts axes each behind its own "
                                 "Modbus TCP connection")
            return
        if len(clients) != 1:
            raise ValueError(f"modbus start group: mode {mode!r} sends one query on one line: every axis "
                             "must be on the same bus")
        if len({a.device_id for a in axes}) != len(axes):
            raise ValueError("modbus start group: unit ids must be distinct")
        if mode == "group":
            refusing = [a.name for a in axes if a.profile.sync_start.group_register is None]
            if refusing:
                raise ValueError(f"modbus start group: profile of {', '.join(refusing)} has no group send "
                                 "(sync_start.group_register)")
        if mode == "broadcast":
            refusing = [a.name for a in axes if not a.profile.sync_start.broadcast]
            if refusing:
                raise ValueError(f"modbus start group: profile of {', '.join(refusing)} does not execute "
                                 "broadcasts (sync_start.broadcast)")
            if not isinstance(axes[0].client, ModbusSerialClient):
                raise ValueError("modbus start group: broadcast needs an RTU line (a TCP gateway may take "
                                 "unit 0 for itself)")

    @classmethod
    def for_axes(cls, axes: Sequence) -> ModbusStartGroup:
        """The group in the mode the axes' links and profiles allow: one line -> ``"group"`` where every
        profile has group send, else ``"broadcast"`` on RTU where every profile executes broadcasts;
        each axis on its own TCP connection -> ``"back_to_back"``. Joined (group mode)."""
        axes = list(axes)
        if len({id(a.client) for a in axes}) > 1:
            group = cls(axes, "back_to_back")
        elif all(a.profile.sync_start is not None and a.profile.sync_start.group_register for a in axes):
            group = cls(axes, "group")
        else:
            group = cls(axes, "broadcast")
        return group

    @property
    def parent(self):
        return next(iter(self.axes.values()))

    def join(self) -> None:
        """Group mode: each child's group register set to the parent's address, the parent's to -1
        (individual); each write answered and read back (in one request where the profile has
        ``write_read``). :meth:`start` joins and leaves by itself."""
        if self.mode != "group":
            return
        parent = self.parent
        for a in self.axes.values():
            want = -1 if a is parent else parent.device_id
            self._checked(a, want, a.write_value_read_back(a.profile.sync_start.group_register, want))

    def leave(self) -> None:
        """Group mode: every unit individual again (-1). The parent's write (answered) is a Write Multiple
        Registers to the parent, which every child executes too: the whole group leaves at once. Each
        child's register is then read; one that does not read -1 (it missed the query) is written itself
        and read back."""
        if self.mode != "group":
            return
        parent = self.parent
        parent.write_value(parent.profile.sync_start.group_register, -1)
        for a in self.axes.values():
            reg = a.profile.sync_start.group_register
            if a is not parent and a.read_value(reg) != -1:
                self._checked(a, -1, a.write_value_read_back(reg, -1))

    @staticmethod
    def _checked(axis, want: int, got: int) -> None:
        if got != want:
            raise ModbusCommError(axis.name, f"group register reads {got} after writing {want}")

    def start(self, moves: Mapping[str, tuple[float, float | None, float | None]]) -> dict[str, int]:
        """Start ``moves`` (axis name -> (target °, speed °/s or None, acceleration °/s² or None))
        together. Every target is checked before anything is written. Returns each moving axis's
        target (steps).

        Raises
        ------
        ValueError
            An unknown axis or a refused target, speed or acceleration (nothing written).
        SyncStartError
            Axes that did not start, each named with why (the others stopped).
        """
        unknown = set(moves) - set(self.axes)
        if unknown:
            raise ValueError(f"modbus start group: unknown axes {sorted(unknown)}; "
                             f"known: {sorted(self.axes)}")
        for n, (target, _v, _a) in moves.items():
            self.axes[n].check_target(target)
        goals = {}
        for a in self.axes.values():
            if a.name in moves:
                goals[a.name] = a.preload(*moves[a.name])
            elif self.mode != "back_to_back":  # it executes the query too: it is told to stay
                goals[a.name] = a.preload(a.deg_of_steps(a.present_steps()))
        self.join()  # after the preloads: a write to the parent while grouped is every child's too
        try:
            self._trigger([self.axes[n] for n in goals])
        except BaseException:  # no trusted word on who started (a reply lost): every axis stopped
            self._stop_all(goals)
            raise
        finally:
            self.leave()
        self._check(goals)
        return {n: goals[n] for n in moves}

    def move_to(self, targets: Mapping[str, float]) -> None:
        """A gantry's move (:class:`~gonio.protocols.StartsTogether`): ``targets`` (axis name -> °) at
        each axis's own speed and acceleration, started together (:meth:`start`)."""
        self.start({n: (float(t), None, None) for n, t in targets.items()})

    def _trigger_words(self, axis) -> tuple[int, list[int]]:
        sync = axis.profile.sync_start
        reg = axis.profile[sync.trigger]
        return reg.address, reg.encode(sync.start, axis.profile.word_order)

    def _trigger(self, axes) -> None:
        first = axes[0]
        address, words = self._trigger_words(first)
        if self.mode == "group":
            first.write_words(address, words, what="group start (trigger to the group's parent)")
        elif self.mode == "broadcast":
            first.write_words(address, words, what="broadcast start (trigger to unit 0)", device_id=0)
            first.clock.sleep(self.turnaround_s)
        else:
            self._back_to_back(axes)

    def _back_to_back(self, axes) -> None:
        """The trigger on every connection, then every reply read (MBAP frames, function 16)."""
        frames = []
        for i, a in enumerate(axes):
            address, words = self._trigger_words(a)
            pdu = bytes([16]) + address.to_bytes(2, "big") + len(words).to_bytes(2, "big") \
                + bytes([2 * len(words)]) + b"".join(w.to_bytes(2, "big") for w in words)
            tid = 0xFF00 + i  # pymodbus counts its own ids up from 1: no reply of its is taken for ours
            frames.append((a, tid, tid.to_bytes(2, "big") + b"\0\0" + (len(pdu) + 1).to_bytes(2, "big")
                           + bytes([a.device_id]) + pdu))
        t0 = time.perf_counter()
        for a, _tid, frame in frames:
            if a.client.send(frame) != len(frame):
                raise ModbusCommError(a.name, "start trigger: the connection took only part of the query")
        self.send_spread_s = time.perf_counter() - t0
        for a, tid, _frame in frames:
            head = a.client.recv(9)
            if len(head) < 9 or int.from_bytes(head[:2], "big") != tid:
                raise ModbusCommError(a.name, f"start trigger: no reply, or not this query's ({head.hex()})")
            if head[7] == 16 | 0x80:
                raise ModbusExceptionError(a.name, f"start trigger: exception response, code {head[8]}",
                                           head[8])
            rest = a.client.recv(3)
            if head[7] != 16 or len(rest) < 3:
                raise ModbusCommError(a.name, f"start trigger: the reply is not this query's "
                                      f"({(head + rest).hex()})")

    def _stop_all(self, names) -> None:
        """Stop each of ``names``, each even if another fails (the caller raises its own error)."""
        for n in names:
            try:
                self.axes[n].stop()
            except Exception:  # noqa: S112 - the start's own failure is what is raised
                continue

    def _check(self, goals: Mapping[str, int]) -> None:
        """Every axis's start read back until its start time-out; the failures named, the others stopped."""
        pending, failed = dict(goals), {}
        clock = self.parent.clock
        deadline = clock.now() + max(a.start_timeout_s for a in self.axes.values())
        while pending:
            for n, steps in list(pending.items()):
                try:
                    if self.axes[n].start_state(steps):
                        del pending[n]
                except (ModbusAlarmError, ModbusCommError, ModbusExceptionError) as err:
                    failed[n] = str(err).removeprefix(f"{n}: ")
                    del pending[n]
            if not pending or clock.now() >= deadline:
                break
            clock.sleep(0.01)
        for n in pending:
            failed[n] = ("did not start: neither moving nor at its target"
                         + (" (not in the group: power cycled?)" if self.mode == "group" else ""))
        if failed:
            for n in goals:
                if n not in failed:
                    self.axes[n].stop()
            raise SyncStartError(", ".join(failed), failed)
