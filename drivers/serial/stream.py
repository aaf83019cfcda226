"""A line instrument's continuous mode: a background reader that takes every line the instrument sends
unasked and stamps it on the gantry clock.

Stamps. The reader thread stamps each line with the gantry clock when its terminator arrives. That
arrival is late by the instrument's processing (the profile's ``delay_s``), the line's own transfer
(bytes x 10 bits / baud rate) and whatever the link adds (a USB adapter's latency timer: up to 16 ms,
in bursts), never early. The instrument's samples are regular (sample k ends at ``t0 + k P``) and every
line carries its sample counter k, so the stamps are a clock model fitted to the arrivals, not the
arrivals themselves (:func:`fit_sample_clock`): ``o_k = arrival_k - delay - transfer_k - k P_nominal``
is the true start ``t0`` plus a delay that is never negative; the lower envelope of ``o_k`` over the
stream (the line through the minima of its blocks, slope by the median of pairwise slopes, then
lowered to touch the lowest point) gives ``t0`` and the period as the gantry clock measures it. A late
burst, a busy host, a slow adapter only ever lift points above the envelope.

Checks. The measured period is compared with the configured one: beyond the profile's
``rate_tolerance`` (more than the fit's own spread can explain), a warning is kept for the journal and
the stamps use the measured period. A counter that skips (a dropped, garbled, truncated or overflowed
line) is a gap, kept in :attr:`StreamSamples.missing`: a reading that spans it is read again, never
interpolated across.
"""

from __future__ import annotations

import itertools
import threading
import time

import numpy as np

from gonio.drivers.serial.profile import StreamCommands, parse_number
from gonio.drivers.serial.transport import Transport
from gonio.protocols import StreamSamples

__all__ = ["StreamReader", "fit_sample_clock"]

#: Longest wait of one read by the reader thread (s): how soon it sees a stop.
READ_SLICE_S = 0.05


def fit_sample_clock(index: np.ndarray, offsets: np.ndarray, blocks: int = 8) -> tuple[float, float, float]:
    """The lower envelope ``t0 + slope k`` of ``offsets`` (arrival minus known delays minus ``k`` nominal
    periods) over sample counters ``index``; returns ``(t0, slope, spread)``: ``spread`` bounds the
    slope's error (the envelope's block minima scatter about the line, divided by the span)."""
    index = np.asarray(index, dtype=np.float64)
    offsets = np.asarray(offsets, dtype=np.float64)
    n = len(index)
    if n == 0:
        return 0.0, 0.0, np.inf
    size = max(8, n // blocks)
    if n < 2 * size:
        return float(offsets.min()), 0.0, np.inf
    pts = []
    for lo in range(0, n - size + 1, size):
        i = lo + int(np.argmin(offsets[lo:lo + size]))
        pts.append((index[i], offsets[i]))
    slopes = [(o2 - o1) / (k2 - k1) for (k1, o1), (k2, o2) in itertools.combinations(pts, 2) if k2 != k1]
    slope = float(np.median(slopes))
    t0 = float(np.min(offsets - slope * index))
    scatter = max(o - (t0 + slope * k) for k, o in pts)
    return t0, slope, scatter / max(index[-1] - index[0], 1.0)


class StreamReader:
    """The thread that reads a streaming instrument's lines (see the module docstring).

    Parameters
    ----------
    name : str
        The instrument's name, in messages.
    transport : Transport
        The open port (the reader owns its reads while it runs; commands may still be written).
    terminator : bytes
    commands : StreamCommands
        The profile's stream section (delay, combine, tolerance).
    rate_hz : float
        The rate the instrument was set to.
    baudrate : int
        For each line's transfer time (8N1: 10 bits a byte).
    clock : Clock
        The gantry clock the lines are stamped on.
    ok_reply, error_prefix : str
        The dialect's acknowledgement (``STRM ON``'s and ``STRM OFF``'s) and refusal.
    """

    def __init__(self, name: str, transport: Transport, terminator: bytes, commands: StreamCommands,
                 rate_hz: float, baudrate: int, clock, ok_reply: str = "OK", error_prefix: str = "ERR"):
        self.name = name
        self._t = transport
        self.terminator = terminator
        self.commands = commands
        self.period_s = 1.0 / float(rate_hz)
        self.baudrate = int(baudrate)
        self.clock = clock
        self.ok_reply, self.error_prefix = ok_reply, error_prefix
        self._lock = threading.Lock()
        self._halt = threading.Event()
        self._acks = threading.Semaphore(0)
        self._thread: threading.Thread | None = None
        self._index: list[int] = []
        self._offset: list[float] = []
        self._values: list[list[float]] = []
        #: Lines that were neither a sample, an acknowledgement nor a refusal (line noise, two lines run
        #: together); refusals the instrument sent; the reason the reader stopped (a lost port).
        self.garbage = 0
        self.refusals: list[str] = []
        self.error: Exception | None = None

    # -- the thread --------------------------------------------------------------------------------------
    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name=f"stream-{self.name}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        buf = b""
        term = self.terminator
        while not self._halt.is_set():
            try:
                buf += self._t.read_until(term, time.monotonic() + READ_SLICE_S)
            except Exception as exc:   # PortLost, or a port closed under it: kept, never a silent death
                self.error = exc
                self._acks.release()
                return
            if not buf.endswith(term):
                continue
            arrival = self.clock.now()
            line, buf = buf, b""
            self._take(line[:-len(term)], len(line), arrival)

    def _take(self, raw: bytes, nbytes: int, arrival: float) -> None:
        try:
            text = raw.decode("ascii").strip()
        except UnicodeDecodeError:
            text = None
        if text == self.ok_reply:
            self._acks.release()
            return
        if text is not None and text.startswith(self.error_prefix):
            self.refusals.append(text)
            self._acks.release()
            return
        head, _, rest = (text or "").partition(",")
        value = parse_number(rest) if head.isdigit() else None
        with self._lock:
            if value is None or (self._index and int(head) <= self._index[-1]):
                self.garbage += 1
                return
            k = int(head)
            known = self.commands.delay_s + nbytes * 10.0 / self.baudrate
            self._index.append(k)
            self._offset.append(arrival - known - (k + 1) * self.period_s)
            self._values.append([value])

    def wait_ack(self, timeout_s: float) -> bool:
        """Wait for the instrument's next acknowledgement (or refusal, or the loss of the port)."""
        return self._acks.acquire(timeout=timeout_s)

    def halt(self, timeout_s: float = 2.0) -> None:
        self._halt.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
        self._thread = None

    # -- what it read --------------------------------------------------------------------------------------
    def samples(self) -> StreamSamples:
        """The samples so far, stamped by the clock model fitted to all of them."""
        with self._lock:
            index = np.array(self._index, dtype=np.int64)
            offsets = np.array(self._offset, dtype=np.float64)
            values = np.array(self._values, dtype=np.float64).reshape(len(index), 1)
        nominal = self.period_s
        t0, slope, spread = fit_sample_clock(index, offsets)
        period = nominal + slope
        warnings = ()
        tol = self.commands.rate_tolerance
        if np.isfinite(spread) and abs(slope) - spread > tol * nominal:
            warnings = (f"stream period {period * 1e3:.4g} ms on the gantry clock, configured "
                        f"{nominal * 1e3:.4g} ms ({(period / nominal - 1) * 100:+.2f} %, tolerance "
                        f"{tol * 100:g} %)",)
        # offsets are t0 + slope k (the fit) above (k + 1) nominal periods
        t_end = t0 + slope * index + (index + 1) * nominal
        missing = []
        expected = 0
        for k in index.tolist():
            if k > expected:
                missing.append((expected, k))
            expected = k + 1
        return StreamSamples(index=index, t_end_s=t_end, values=values, period_s=float(period),
                             missing=tuple(missing), combine=self.commands.combine, warnings=warnings)
