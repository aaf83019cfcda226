"""Helpers of the daemon's tests: bounded waits, submitting a campaign (a module of its own: every test
folder has a ``conftest``, so tests import these by this unique name)."""

from __future__ import annotations

import functools
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

#: Upper bound for every wait in these tests (a campaign of a few dozen steps takes well under it).
WAIT_S = 60.0
TOKEN = "s3cret-token-of-the-lab"
GONIO = [sys.executable, "-m", "gonio.cli"]
#: The browser of the tests that drive one (Debian's chromium; those tests are skipped without it).
CHROMIUM = "/usr/bin/chromium"
#: ``gonio serve`` processes started by Serve and not yet reaped (conftest stops them after each test).
STARTED: list = []


def wait_for(predicate, what: str, timeout_s: float = WAIT_S, poll_s: float = 0.01):
    """Poll ``predicate`` until it returns something truthy (returned), or fail after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(poll_s)


def wait_state(client: httpx.Client, cid: str, states, timeout_s: float = WAIT_S) -> dict:
    states = {states} if isinstance(states, str) else set(states)

    def check():
        st = client.get(f"/campaigns/{cid}").json()
        return st if st["state"] in states else None

    return wait_for(check, f"campaign {cid} to be {sorted(states)}", timeout_s)


def unpace(daemon, only: str | None = None) -> None:
    """From now on the in-process ``daemon``'s simulated gantry spends no real time: the running
    campaign's clock and those of the campaigns it runs next (pacing spends wall time only: a campaign
    measures the same unpaced). For a test done with what needed a campaign to last. ``only``: that
    campaign's clock alone, once it runs (those after it keep the daemon's pace)."""
    queue = daemon.queue
    if only is None:
        queue.pace = 0.0
    else:
        wait_for(lambda: queue.gantry is not None and queue.current is not None and queue.current.id == only,
                 f"campaign {only} to run")
    gantry = queue.gantry
    if gantry is not None:
        gantry.clock.pace = 0.0


#: The grids most of these tests submit, on the simulated gantry: planned once per process.
SHARED_GRIDS = ("iso:step=15", "iso:step=30")


@functools.cache
def shared_plans():
    """A :class:`gonio.daemon.planner.PlanCache` holding :data:`SHARED_GRIDS` on the default config (the
    process's plans, tests/planned.py), which the tests' in-process daemons hand their planner's worker
    (a copy each; planning is deterministic): each daemon's worker planned iso:step=15 afresh, 0.4 s of
    CPU for each of some 40 tests, where a kept plan is a copy of 10 ms. Tests of the planning itself
    plan grids and configs not kept here."""
    from planned import planned

    from gonio.config import load_config
    from gonio.daemon.planner import PlanCache

    plans, cfg = PlanCache(), load_config()
    for grid in SHARED_GRIDS:
        plans.keep(grid, cfg, planned(grid, cfg))
    return plans


def http_client(url: str, **kw) -> httpx.Client:
    """An httpx client of ``url`` (``kw``: headers, timeout, ...; timeout WAIT_S unless given). No
    certificate store: these daemons speak plain http, and httpx loads certifi's for every client that
    verifies (~27 ms of CPU each, some 150 clients in these tests)."""
    kw.setdefault("timeout", WAIT_S)
    return httpx.Client(base_url=url, verify=False, **kw)


def submit(client: httpx.Client, grid: str = "iso:step=30", material: str = "lambert:albedo=0.5",
           **extra) -> dict:
    r = client.post("/campaigns", json={"material": material, "grid": grid, **extra})
    assert r.status_code == 201, r.text
    return r.json()


class Serve:
    """A ``gonio serve`` subprocess on a free loopback port; its URL once it listens. Its planner plans at
    normal priority (``--plan-priority normal``): at idle priority each submission waited for a core to
    fall idle, seconds at a time while the suite's other worker computes (idle priority is checked in
    tests/daemon/test_daemon_submit.py)."""

    def __init__(self, data: Path, *extra: str, env: dict | None = None, prefix: tuple = ()):
        self.log = data.parent / f"serve-{time.monotonic_ns()}.log"
        self._f = self.log.open("w")
        self.p = subprocess.Popen([*prefix, *GONIO, "serve", "--data", str(data), "--port", "0",
                                   "--plan-priority", "normal", *extra],
                                  stdout=self._f, stderr=subprocess.STDOUT,
                                  env={**os.environ, "GONIO_TOKEN": "", **(env or {})})
        STARTED.append(self)
        m = wait_for(lambda: re.search(r"listening on (http://\S+)", self.log.read_text())
                     or self.p.poll() is not None, "the daemon to listen")
        if m is True or self.p.poll() is not None:
            pytest.fail(f"gonio serve exited: {self.log.read_text()}")
        self.url = m.group(1)
        self.client = http_client(self.url)

    def stop(self, sig=signal.SIGTERM) -> int:
        self.client.close()
        if self.p.poll() is None:
            self.p.send_signal(sig)
        try:
            return self.p.wait(WAIT_S)
        finally:
            self._f.close()
