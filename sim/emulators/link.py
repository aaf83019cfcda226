"""The wire under an emulator: a pty pair with a stable name, faults to inject, and the serving thread.

A driver opens :attr:`PtyLink.port` (a symlink in a private folder, like ``/dev/serial/by-id/...``) as if
it were a USB serial adapter; the emulator reads and writes the pty master. :meth:`PtyLink.unplug` closes
both ends, as pulling the cable does (the driver's next read or flush fails), and :meth:`PtyLink.replug`
makes a fresh pty behind the same name, so a driver can reconnect by reopening the port.
"""

from __future__ import annotations

import fcntl
import os
import select
import struct
import tempfile
import termios
import threading
import time
import tty
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from gonio.clock import VirtualClock

__all__ = ["PtyLink", "Fault", "FaultPlan", "FAULT_KINDS", "Watched", "EmulatorThread", "mangle",
           "SyncedVirtualClock", "Deferred"]

#: Kinds of fault an emulator applies to its next matching reply: ``drop`` it, ``corrupt`` its last
#: byte, ``truncate`` it to half, ``delay`` it (the emulator waits ``delay_s`` before it goes on),
#: ``disconnect`` the link, ``duplicate`` it (sent twice), ``late`` (held back and sent just before the
#: next reply: after its requester timed out, while the next request waits), ``reorder`` (sent right
#: after the next reply; see :class:`Deferred`), ``stale`` (instead of the reply, the one sent to the
#: last identical request: what a late reply of the same length carries, which no pairing by ID,
#: instruction and length can tell apart).
FAULT_KINDS = ("drop", "corrupt", "truncate", "delay", "disconnect", "duplicate", "late", "reorder", "stale")


class PtyLink:
    """A pseudo-terminal whose slave side is reachable under a stable path.

    Parameters
    ----------
    name : str
        Base name of the symlink (e.g. ``"ttyDXL"``).
    """

    def __init__(self, name: str = "ttyEMU"):
        self._dir = tempfile.mkdtemp(prefix="gonio-emu-")
        self.port = os.path.join(self._dir, name)
        self.master: int | None = None
        self._slave: int | None = None
        # Bumped at every plug and unplug: a read or write that waited on a descriptor number checks,
        # under the lock, that the number is still this link's before it reads or writes (once closed,
        # the number can be given to another pty of the process, whose bytes are not this link's).
        self._generation = 0
        # The emulator thread unplugs (an injected disconnect) while a test may replug: one at a time.
        self._lock = threading.RLock()
        self.replug()

    def replug(self) -> None:
        """Make a fresh pty pair behind :attr:`port` (closing any previous one)."""
        with self._lock:
            self._replug()

    def _replug(self) -> None:
        self.unplug()
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        tmp = self.port + ".new"
        os.symlink(os.ttyname(slave), tmp)
        os.replace(tmp, self.port)
        # The emulator keeps the slave open too: the master never sees EIO while a driver reopens.
        self.master, self._slave = master, slave
        self._generation += 1

    def unplug(self) -> None:
        """Close both ends: the driver's open port stops working, as when a cable is pulled; the port's
        name goes too, as a pulled adapter's /dev/serial/by-id link does (else a driver reopening it could
        open the pty number another process was given since: another emulator's servo 1)."""
        with self._lock:
            try:
                os.unlink(self.port)
            except FileNotFoundError:
                pass
            for fd in (self.master, self._slave):
                if fd is not None:
                    try:
                        os.close(fd)
                    except OSError:
                        pass
            self.master = self._slave = None
            self._generation += 1

    @property
    def plugged(self) -> bool:
        return self.master is not None

    def readable(self, timeout_s: float = 0.0, wake: int | None = None) -> bool:
        """Whether bytes the driver wrote wait to be read (waiting at most ``timeout_s`` s, or until the
        file descriptor ``wake`` is readable: :attr:`EmulatorThread.wake_fd`)."""
        fd = self.master
        if fd is None:
            return False
        try:
            return fd in select.select([fd] if wake is None else [fd, wake], [], [], timeout_s)[0]
        except (OSError, ValueError):
            return False

    def pending(self) -> int:
        """Bytes written to the driver that it has not read yet (0 when unplugged)."""
        fd = self._slave
        if fd is None:
            return 0
        try:
            return struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"))[0]
        except OSError:
            return 0

    def read(self, timeout_s: float, wake: int | None = None) -> bytes:
        """Bytes the driver wrote, waiting at most ``timeout_s`` s or until ``wake`` is readable (b"" when
        none, or unplugged)."""
        with self._lock:
            fd, generation = self.master, self._generation
        if fd is None:
            return b""
        try:
            ready, _, _ = select.select([fd] if wake is None else [fd, wake], [], [], timeout_s)
            if fd not in ready:
                return b""
            with self._lock:                # unplugged (and the number perhaps reused) while waiting?
                if self._generation != generation:
                    return b""
                return os.read(fd, 4096)    # non-blocking: never holds the lock for long
        except (OSError, ValueError):
            return b""

    def write(self, data: bytes) -> None:
        with self._lock:
            fd, generation = self.master, self._generation
        if fd is None or not data:
            return
        view = memoryview(data)
        deadline = time.monotonic() + 1.0
        while view and time.monotonic() < deadline:
            try:
                with self._lock:
                    if self._generation != generation:
                        return              # unplugged: the rest of the reply is lost, as on a cable
                    n = os.write(fd, view)
            except BlockingIOError:
                try:
                    select.select([], [fd], [], 0.01)
                except (OSError, ValueError):
                    return
                continue
            except OSError:
                return
            view = view[n:]

    def close(self) -> None:
        self.unplug()
        try:
            os.unlink(self.port)
        except OSError:
            pass
        try:
            os.rmdir(self._dir)
        except OSError:
            pass


@dataclass
class Fault:
    """One injected fault: what happens to the next reply that matches.

    ``kind`` is one of :data:`FAULT_KINDS`; ``match`` narrows which replies it applies to (an emulator
    compares it with its own key, e.g. a servo ID or a command word; None matches any); ``delay_s`` is
    the hold-back for ``"delay"``.
    """

    kind: str
    match: object = None
    delay_s: float = 0.0


class FaultPlan:
    """A thread-safe queue of faults, consumed one per matching reply, in order."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._queue: deque[Fault] = deque()
        #: Faults applied so far, as (kind, key) pairs: tests check what actually happened.
        self.applied: list[tuple[str, object]] = []

    def add(self, kind: str, *, match: object = None, times: int = 1, delay_s: float = 0.0) -> None:
        """Queue ``times`` faults of ``kind`` for replies matching ``match`` (None: any reply)."""
        if kind not in FAULT_KINDS:
            raise ValueError(f"fault kind {kind!r} is not one of {', '.join(FAULT_KINDS)}")
        if not isinstance(times, int) or times < 1:
            raise ValueError(f"fault times must be an integer >= 1, got {times!r}")
        if kind == "delay" and not 0.0 < delay_s <= 10.0:
            raise ValueError(f"fault delay_s must be in (0, 10] s, got {delay_s!r}")
        with self._lock:
            self._queue.extend(Fault(kind, match, delay_s) for _ in range(times))

    def take(self, *keys: object) -> Fault | None:
        """The first queued fault whose ``match`` is None or equals one of ``keys`` (removed from the
        queue), or None. An emulator passes its keys from coarse to fine, e.g. ``(id, (id, inst))``."""
        with self._lock:
            for i, fault in enumerate(self._queue):
                if fault.match is None or fault.match in keys:
                    del self._queue[i]
                    self.applied.append((fault.kind, keys[0] if keys else None))
                    return fault
        return None

    def clear(self) -> None:
        with self._lock:
            self._queue.clear()

    def pending(self) -> int:
        with self._lock:
            return len(self._queue)


def mangle(reply: bytes, fault: Fault | None) -> bytes | None:
    """Apply a byte-level fault to a reply: None to drop it, else the bytes to send (after any delay).
    ``late`` and ``reorder`` are scheduled by the emulator (:class:`Deferred`), not here."""
    if fault is None:
        return reply
    if fault.kind in ("late", "reorder", "stale"):
        raise ValueError(f"fault '{fault.kind}' is applied by the emulator (Deferred, its own replies), "
                         "not mangled")
    if fault.kind == "duplicate":
        return reply + reply
    if fault.kind == "drop":
        return None
    if fault.kind == "corrupt":
        # Flip the last byte: the checksum (or the line terminator's neighbour) no longer matches.
        return reply[:-1] + bytes([reply[-1] ^ 0x5A]) if reply else reply
    if fault.kind == "truncate":
        return reply[: max(1, len(reply) // 2)]
    if fault.kind == "delay":
        time.sleep(fault.delay_s)  # the emulator's own thread: holding the reply back is the point
    return reply


class Deferred:
    """Replies an emulator holds back, released by the replies that follow (never by a timer, so
    tests stay deterministic): a ``late`` reply goes out just before the next reply, i.e. after its
    requester gave up waiting and while the next request waits for its own answer; a ``reorder`` reply
    goes out right after the next reply. The emulator calls :meth:`hold` for each reply with its fault,
    :meth:`before` before it writes a reply and :meth:`after` once it wrote one."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._late: list[bytes] = []
        self._held: list[bytes] = []

    def hold(self, reply: bytes, fault: Fault | None) -> bool:
        """Take ``reply`` if ``fault`` defers it (True), else leave it to the caller (False)."""
        if fault is None or fault.kind not in ("late", "reorder"):
            return False
        with self._lock:
            (self._late if fault.kind == "late" else self._held).append(reply)
        return True

    def before(self, write) -> None:
        """Before a reply goes out: the late replies go first."""
        with self._lock:
            late, self._late = self._late, []
        for reply in late:
            write(reply)

    def after(self, write) -> None:
        """After a reply went out: the replies held for reordering follow it."""
        with self._lock:
            held, self._held = self._held, []
        for reply in held:
            write(reply)

    def pending(self) -> int:
        with self._lock:
            return len(self._late) + len(self._held)


class Watched:
    """An emulator whose serving threads are watched: the first exception that ends one (a bug: nothing a
    driver sends may) is kept in :attr:`error` and told at once, from the dying thread, to every callback
    given to :meth:`watch`; ``gonio emulate`` stops on it instead of serving on with a dead device."""

    def __init__(self) -> None:
        self._watch_lock = threading.Lock()
        self._watchers: list[Callable[[BaseException], None]] = []
        #: What ended a serving thread first (None while none has died).
        self.error: BaseException | None = None

    def watch(self, callback: Callable[[BaseException], None]) -> None:
        """Call ``callback(exc)`` when a serving thread dies of ``exc`` (at once if one has died)."""
        with self._watch_lock:
            self._watchers.append(callback)
            error = self.error
        if error is not None:
            callback(error)

    def _died(self, exc: BaseException) -> None:
        """A serving thread ends with ``exc``: keep the first, tell the watchers (in this thread)."""
        with self._watch_lock:
            if self.error is not None:
                return
            self.error = exc
            watchers = list(self._watchers)
        for callback in watchers:
            callback(exc)


class EmulatorThread(Watched):
    """A daemon thread running ``step()`` until :meth:`stop`; each step waits at most ``poll_s``, and
    ends its wait at once when :meth:`stop` is called if it waits on :attr:`wake_fd` too (a link's
    ``read``/``readable`` take it as ``wake``). An exception out of ``step()`` ends the thread and is
    told to the watchers (:class:`Watched`)."""

    poll_s = 0.02

    def __init__(self, name: str):
        super().__init__()
        self._name = name
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._wake: tuple[int, int] | None = None

    @property
    def wake_fd(self) -> int | None:
        """A file descriptor that becomes readable when :meth:`stop` is called (None when not running)."""
        return None if self._wake is None else self._wake[0]

    def start(self) -> None:
        if self._thread is not None:
            raise RuntimeError(f"emulator '{self._name}' is already running")
        self._stop.clear()
        self._wake = os.pipe()
        self._thread = threading.Thread(target=self._run, name=f"emu-{self._name}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                self.step()
        except BaseException as exc:  # the thread must not die silently
            self._died(exc)

    def step(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop the thread and wait for it (at most ``timeout_s`` s)."""
        self._stop.set()
        if self._wake is not None:
            os.write(self._wake[1], b"\0")
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                raise RuntimeError(f"emulator '{self._name}' did not stop within {timeout_s} s")
        self._thread = None
        if self._wake is not None:
            for fd in self._wake:
                os.close(fd)
            self._wake = None

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


class SyncedVirtualClock(VirtualClock):
    """A virtual clock shared by emulators and the drivers that talk to them, which lets no time pass
    while an emulator still has bytes to handle.

    On a wire, a packet that gets no reply (a Dynamixel Sync Write) takes effect when it is sent. An
    emulator thread handles it whenever it next runs, and on a plain :class:`VirtualClock` the driver's
    side may meanwhile have slept through a whole move: the emulated servo would start late by that much.
    Before each advance this clock calls every function given to :meth:`attach` (an emulator's
    ``drain``, bounded), so each packet acts at the virtual instant it was sent.
    """

    def __init__(self, start: float = 0.0):
        super().__init__(start)
        self._drains: list = []
        self._dues: dict = {}

    def attach(self, drain, due=None) -> None:
        """Call ``drain()`` before every advance of the clock; ``due()``, where given, says the next
        instant (or None) the emulator acts unasked (a streaming instrument's next line): the clock stops
        there on its way, and drains, so that the act happens at its own instant."""
        self._drains.append(drain)
        if due is not None:
            self._dues[drain] = due

    def detach(self, drain) -> None:
        if drain in self._drains:
            self._drains.remove(drain)
        self._dues.pop(drain, None)

    def sleep(self, seconds: float) -> None:
        end = self.now() + seconds
        stopped = False
        for _ in range(10_000_000):   # bounded: every stop is an emulator's act, each later than the last
            for drain in list(self._drains):
                drain()
            stops = [t for t in (due() for due in list(self._dues.values())) if t is not None]
            nxt = min(stops, default=None)
            if nxt is None or nxt >= end or nxt <= self.now():
                break
            super().sleep(nxt - self.now())
            stopped = True
        # without a stop on the way, exactly as a plain virtual clock sleeps (no rounding of now + s - now)
        super().sleep(max(end - self.now(), 0.0) if stopped else seconds)
