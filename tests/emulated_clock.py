"""A clock for tests whose emulators another process drives on the wall clock until it is killed, after which
the same emulators serve a command run again in the test's own process on a synced virtual clock
(:func:`gonio_on`): the kill is real, and the resumed run does not wait for the emulated motion."""

from __future__ import annotations

import contextlib
import io
import threading
import time
from unittest import mock

from gonio.clock import VirtualClock
from gonio.sim.emulators.link import SyncedVirtualClock


class WallThenVirtual(SyncedVirtualClock):
    """The wall clock while another process drives the emulators (the ``gonio run`` killed mid-sweep);
    from :meth:`go_virtual` on, a synced virtual clock that carries on from that instant, for the run that
    resumes in this process (the CLI's clock is this one): it does not wait for the servos' motion."""

    def __init__(self):
        super().__init__(time.monotonic())
        self.real_time = True

    def now(self) -> float:
        return time.monotonic() if self.real_time else super().now()

    def sleep(self, seconds: float) -> None:
        if self.real_time:
            time.sleep(seconds)
        else:
            super().sleep(seconds)

    def sleep_until(self, t: float) -> None:
        if self.real_time:
            time.sleep(max(0.0, t - time.monotonic()))
        else:
            super().sleep_until(t)

    def go_virtual(self, gap_s: float) -> None:
        """Stop on the wall-clock instant now, then let ``gap_s`` of gantry time pass unheard (no emulator
        drained: what the killed process's servos and stream did meanwhile is due, as on a wire nobody
        reads)."""
        self._t = time.monotonic()
        self.real_time = False
        VirtualClock.sleep(self, gap_s)


#: Held while a command runs in this process on a test's clock: the CLI's clock is patched process-wide.
_CLI = threading.Lock()


def gonio_on(clock, args: list[str]) -> tuple[int, str]:
    """``gonio <args>`` run in this process (``gonio.cli.main``) with ``clock`` as the gantry's wall clock,
    one such run at a time; returns (exit code, what it wrote to stderr)."""
    from gonio.cli import main

    err = io.StringIO()
    with _CLI, mock.patch("gonio.wiring.WallClock", lambda: clock), contextlib.redirect_stderr(err):
        code = main(args)
    return code, err.getvalue()
