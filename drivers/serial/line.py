"""A line instrument: command lines out, reply lines back, in the dialect its profile describes.

Every query flushes the input first (a late reply must not be taken for this one's answer), then reads
until the terminator under one deadline for the whole reply; a reply without its terminator, a garbled
one, or one that is not of the expected format (not a number where a number is expected, SCPI's NaN,
an empty line) is a transient :class:`InstrumentCommError`, never a value. A lost port is reopened with
exponential back-off and the operation retried once; after a time-out the port is reopened at the next
operation (a dead port can swallow writes without an error).

A reply that comes after its time-out would arrive during a later query, after that query's flush: an
instrument answers in order, so the next query would read the late line as its own. After a time-out
the next exchange therefore first re-synchronises: it asks the identity (``*IDN?``) and reads lines
until the one the instrument gave at connect, discarding (and counting, :attr:`late_replies`) every
line before it. An instrument that answers with another identity (swapped) is a fault that says so.

Setters, per the profile (:mod:`gonio.drivers.serial.profile`):

- ``setters = "ok"``: each setter is a query whose reply must be ``OK``; a refusal comes back in its
  place (``ERR <code>,"<text>"``).
- ``setters = "silent"`` (SCPI): a setter is written and nothing is read for it. After a group of setters
  the driver asks ``complete`` (``*OPC?``, where the profile has it; it answers ``1`` once they are done)
  and drains the error queue (``errors``, ``SYST:ERR?``) until it answers ``0,...``. A non-empty queue is
  an :class:`InstrumentError` naming the command and the instrument's message; where a group of
  idempotent setters erred, each is sent again with its own check to name the one refused. A query
  that gets no reply is followed by the same drain: an instrument that refused it queued why.

Instrument errors are transient (retried by the runner) for SCPI's command errors (-100..-199: a
command garbled on the wire reads as an undefined header), query errors (-400..-499) and -230 (data
stale); the others (execution errors such as -222 data out of range, device-specific errors) are not.
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable, Sequence

from gonio.clock import WallClock
from gonio.drivers.serial.profile import (
    DEFAULT_PROFILE,
    InstrumentProfile,
    is_query,
    load_profile,
    parse_bool,
    parse_number,
    parse_numbers,
)
from gonio.drivers.serial.transport import PortLost, open_transport
from gonio.protocols import DeviceFault

__all__ = ["LineInstrument", "InstrumentCommError", "InstrumentError", "transient_code", "refusal_code"]

#: Most entries drained from an error queue at once (SCPI queues hold 10 to 30; -350 marks overflow).
MAX_ERRORS = 32
_ERROR_ENTRY = re.compile(r'\s*([+-]?\d+)\s*,\s*"?(.*?)"?\s*')


class InstrumentCommError(DeviceFault):
    """No reply, a reply without its terminator, a garbled or malformed reply, or a lost port
    (transient)."""

    def __init__(self, device: str, message: str):
        super().__init__(device, message, transient=True)


def transient_code(code: int | None) -> bool:
    """Whether an instrument error may pass on a retry: SCPI command errors (-1xx: a line garbled on the
    wire), query errors (-4xx) and -230 (data corrupt or stale: no measurement to fetch, as after a
    lost INIT)."""
    return code is not None and (-199 <= code <= -100 or -499 <= code <= -400 or code == -230)


class InstrumentError(DeviceFault):
    """The instrument refused a command: its code and message (transient per :func:`transient_code`)."""

    def __init__(self, device: str, message: str, code: int | None = None):
        super().__init__(device, message, transient=transient_code(code))
        self.code = code


def refusal_code(reply: str, prefix: str) -> int | None:
    """The code of a refusal ``<prefix> <code>,"<text>"`` (None where it has none)."""
    try:
        return int(reply[len(prefix):].split(",")[0])
    except ValueError:
        return None


class LineInstrument:
    """Base of the serial instrument drivers.

    Parameters
    ----------
    name : str
        Device name in error messages.
    port : str
        A pyserial port or URL (``/dev/ttyUSB0``, ``socket://127.0.0.1:5025``, a pty), or a VISA resource
        string (``ASRL/dev/ttyUSB0::INSTR``, ``TCPIP0::host::5025::SOCKET``; see
        :mod:`gonio.drivers.serial.transport`).
    profile : InstrumentProfile or str, optional
        The dialect and commands (a shipped profile's name, a path, or a loaded profile); default
        :data:`~gonio.drivers.serial.profile.DEFAULT_PROFILE`.
    baudrate : int
    terminator : str, optional
        Line terminator both ways; default the profile's.
    timeout_s : float
        Deadline for one whole reply (s), plus the exposure where a reply waits for a measurement.
    reconnect_attempts : int
        Reopen attempts after a lost port (back-off 0.05, 0.1, 0.2 ... s).
    transport_factory : callable, optional
        ``transport_factory(port, baudrate, terminator_bytes) -> Transport``; default
        :func:`~gonio.drivers.serial.transport.open_transport`.
    clock : Clock, optional
        For the back-off and settling waits.
    """

    def __init__(self, name: str, port: str, profile: InstrumentProfile | str | None = None, *,
                 baudrate: int = 115200, terminator: str | None = None, timeout_s: float = 1.0,
                 reconnect_attempts: int = 3, transport_factory: Callable | None = None, clock=None):
        if not 0 < timeout_s <= 60:
            raise ValueError(f"instrument '{name}': timeout_s {timeout_s} is outside (0, 60] s")
        if terminator is not None and not terminator:
            raise ValueError(f"instrument '{name}': terminator must not be empty")
        if not isinstance(profile, InstrumentProfile):
            profile = load_profile(DEFAULT_PROFILE if profile is None else profile)
        self.name = name
        self.port = port
        self.profile = profile
        self.baudrate = baudrate
        self.terminator = (terminator or profile.terminator).encode("ascii")
        self.timeout_s = float(timeout_s)
        self.reconnect_attempts = reconnect_attempts
        self._factory = transport_factory or open_transport
        self.clock = clock or WallClock()
        self._t = None
        self._connected = False
        self.reconnects = 0
        #: Lines discarded while re-synchronising after a time-out (replies that came late).
        self.late_replies = 0
        self._stale: float | None = None  # after a time-out: how long its reply could still take
        self._owed = 0  # identities asked while re-synchronising and not yet read
        self._held = b""  # silent setters to write with the next query
        #: The instrument's answer to the profile's identify query, read at connect.
        self.identity: str | None = None

    # -- the port ------------------------------------------------------------------------------------
    def connect(self) -> None:
        """Open the port, read the identity, send the profile's reset commands."""
        self._open()
        self._connected = True
        self._stale = None
        self._owed = 0
        self._held = b""
        self.identity = None
        self.identity = self.query(self.profile.identify)
        if self.profile.reset:
            self.setters(self.profile.reset)

    def close(self) -> None:
        self._connected = False
        self._drop()

    def describe(self) -> dict:
        """What this instrument is, for the campaign's journal: profile, its hash, identity, port."""
        return {"name": self.name, "driver": "serial", "profile": self.profile.name,
                "profile_source": self.profile.source, "profile_sha256": self.profile.sha256,
                "identity": self.identity, "port": self.port}

    def _drop(self) -> None:
        if self._t is not None:
            self._t.close()
        self._t = None

    def _open(self) -> None:
        self._drop()
        try:
            self._t = self._factory(self.port, self.baudrate, self.terminator)
        except PortLost as exc:
            raise InstrumentCommError(self.name, f"cannot open {self.port} ({exc})") from exc

    def _reopen_with_backoff(self) -> None:
        delay = 0.05
        for attempt in range(self.reconnect_attempts):
            try:
                self._open()
                self.reconnects += 1
                return
            except InstrumentCommError:
                if attempt + 1 == self.reconnect_attempts:
                    raise
                self.clock.sleep(delay)
                delay *= 2

    def _io(self, line: str, fn: Callable[[], str]) -> str:
        """``fn()`` on the open port; a port lost earlier or now is reopened (back-off) and ``fn`` retried
        once."""
        if self._t is None:
            if not self._connected:
                raise InstrumentCommError(self.name, "not connected; call connect() first")
            self._reopen_with_backoff()  # a port lost earlier (connect() was called before)
        try:
            return fn()
        except PortLost as exc:
            self._reopen_with_backoff()
            try:
                return fn()
            except PortLost:
                self._drop()
                raise InstrumentCommError(self.name, f"{line!r}: port {self.port} lost ({exc})") from exc

    # -- one line each way ---------------------------------------------------------------------------
    def _resync(self) -> None:
        """After a time-out: ask the identity, discard every line before the one given at connect.

        Every identity asked and not yet read is owed (a resync that timed out leaves one coming): the
        link is in step once all are read, or once one is read and the line stays quiet ``timeout_s``
        after it (an instrument switched off meanwhile never answers the others)."""
        t, ident = self._t, self.identity
        t.flush_input()
        t.write(self.profile.identify.encode("ascii") + self.terminator)
        self._owed += 1
        end = time.monotonic() + 2 * self.timeout_s + self._stale
        seen = False
        for _ in range(64):  # bounded: a late line per query that timed out
            deadline = min(end, time.monotonic() + self.timeout_s) if seen else end
            buf = t.read_until(self.terminator, deadline)
            if seen and not buf:
                break  # quiet after an identity: the rest are not coming
            if not buf.endswith(self.terminator):
                self._drop()
                raise InstrumentCommError(self.name, f"{self.profile.identify!r} (re-synchronising after a "
                                          f"time-out): {'no reply' if not buf else 'a reply cut short'}")
            got = buf[:-len(self.terminator)].decode("ascii", "replace").strip()
            if got != ident:
                self.late_replies += 1
                continue
            seen = True
            self._owed -= 1
            if self._owed == 0:
                break
        else:
            raise InstrumentCommError(self.name, f"{self.profile.identify!r} (re-synchronising after a "
                                      f"time-out): no {ident!r} among the replies (another instrument on "
                                      f"{self.port}?)")
        self._owed = 0
        self._stale = None

    def _exchange(self, line: str, wait_s: float = 0.0) -> str:
        t = self._t
        if self._stale is not None and self.identity is not None:
            self._resync()
        t.flush_input()
        held, self._held = self._held, b""
        t.write(held + line.encode("ascii") + self.terminator)
        budget = self.timeout_s + wait_s
        buf = t.read_until(self.terminator, time.monotonic() + budget)
        if not buf.endswith(self.terminator):
            # A silent port may be a dead one (a pty or USB adapter gone without an error on write):
            # the next operation reopens it. The reply may still come: re-synchronise first.
            self._drop()
            self._stale = max(self._stale or 0.0, wait_s)
            what = "no reply" if not buf else f"reply {buf!r} without its terminator"
            raise InstrumentCommError(self.name, f"{line!r}: {what} within {budget:g} s")
        try:
            return buf[:-len(self.terminator)].decode("ascii").strip()
        except UnicodeDecodeError:
            raise InstrumentCommError(self.name, f"{line!r}: garbled reply {buf!r}") from None

    def _send(self, lines: Sequence[str]) -> None:
        """Silent setters: held and written with the query that follows them (``*OPC?`` or the error
        queue), in one write. Over TCP a small segment written right after another waits for the
        instrument's delayed acknowledgement of the first (Nagle): ~40 ms a reading, measured."""
        self._held += b"".join(line.encode("ascii") + self.terminator for line in lines)

    # -- the dialect -----------------------------------------------------------------------------------
    def query(self, line: str, *, wait_s: float = 0.0, drain: bool = True) -> str:
        """Send ``line`` and return its reply line. ``wait_s`` extends the deadline (a query that waits
        for a measurement). A refusal (``ERR`` reply; or, silent dialect, an error queued for a query
        that got no good reply) raises :class:`InstrumentError`."""
        try:
            reply = self._io(line, lambda: self._exchange(line, wait_s))
        except InstrumentCommError as err:
            if drain and self.profile.errors is not None:
                self._check_errors([line], cause=err)
            raise
        p = self.profile
        if p.setters == "ok" and reply.startswith(p.error_prefix):
            raise InstrumentError(self.name, f"{line!r} refused: {reply}",
                                  refusal_code(reply, p.error_prefix))
        return reply

    def setters(self, commands: Sequence[str], *, wait_s: float = 0.0, idempotent: bool = True) -> None:
        """Send setters. ``"ok"`` dialect: each must answer OK. ``"silent"``: written, then ``complete``
        (waiting up to ``wait_s`` more) and the error queue checked once for the group; where it erred
        and the group is ``idempotent``, each setter is sent again alone to name the one refused."""
        commands = list(commands)
        p = self.profile
        if p.setters == "ok":
            for c in commands:
                reply = self.query(c, wait_s=wait_s)
                if reply != p.ok_reply:
                    raise InstrumentCommError(self.name, f"{c!r}: expected {p.ok_reply!r}, got {reply!r}")
            return
        self._send(commands)
        try:
            self._settle(commands, wait_s)
        except InstrumentError:
            if not idempotent or len(commands) < 2:
                raise
            for c in commands:  # find the culprit: one at a time, each checked
                self._send([c])
                self._settle([c], wait_s)
            raise

    def _settle(self, commands: list[str], wait_s: float) -> None:
        p = self.profile
        if p.complete is not None:
            reply = self.query(p.complete, wait_s=wait_s, drain=False)
            if parse_number(reply) != 1:
                raise InstrumentCommError(self.name, f"{p.complete!r} after {'; '.join(commands)!r}: "
                                          f"expected '1', got {reply!r}")
        self._check_errors(commands)

    def _check_errors(self, commands: list[str], cause: Exception | None = None) -> None:
        """Drain the error queue; InstrumentError naming ``commands`` and every message if it held any."""
        errors: list[tuple[int, str]] = []
        q = self.profile.errors
        for _ in range(MAX_ERRORS):
            try:
                reply = self.query(q, drain=False)
            except InstrumentCommError:
                if cause is not None:
                    return  # the instrument is not answering at all: the original fault stands
                raise
            m = _ERROR_ENTRY.fullmatch(reply)
            if m is None:
                raise InstrumentCommError(self.name, f"{q!r}: reply {reply!r} is not <code>,\"<message>\"")
            code = int(m.group(1))
            if code == 0:
                break
            errors.append((code, m.group(2)))
        if errors:
            what = "; ".join(f'{c},"{msg}"' for c, msg in errors)
            raise InstrumentError(self.name, f"{'; '.join(commands)!r} refused: {what}",
                                  errors[0][0]) from cause

    # -- typed queries -------------------------------------------------------------------------------
    def _malformed(self, line: str, reply: str, what: str) -> InstrumentCommError:
        return InstrumentCommError(self.name, f"{line!r}: reply {reply[:40]!r} is not {what}")

    def query_number(self, line: str, *, wait_s: float = 0.0) -> float:
        reply = self.query(line, wait_s=wait_s)
        value = parse_number(reply)
        if value is None:
            raise self._malformed(line, reply, "a number")
        return value

    def query_numbers(self, line: str, *, wait_s: float = 0.0) -> list[float]:
        reply = self.query(line, wait_s=wait_s)
        values = parse_numbers(reply)
        if values is None:
            raise self._malformed(line, reply, "a list of numbers")
        return values

    def query_bool(self, line: str) -> bool:
        reply = self.query(line)
        value = parse_bool(reply)
        if value is None:
            raise self._malformed(line, reply, "1, 0, ON or OFF")
        return value

    def command(self, line: str) -> None:
        """One setter (or, for a line that is a query, the query with its reply discarded)."""
        if is_query(line):
            self.query(line)
        else:
            self.setters([line])

    def identify(self) -> str:
        return self.query(self.profile.identify)
