"""Daemons served in-process on 127.0.0.1 (any free port), each stopped at the end of its test."""

from __future__ import annotations

import pytest
from daemon_helpers import STARTED, WAIT_S, http_client

from gonio.config import load_config
from gonio.daemon.server import build_daemon, start_in_thread

#: The grids most of these tests submit, on the simulated gantry: planned once per process.
SHARED_GRIDS = ("iso:step=15", "iso:step=30")


@pytest.fixture(scope="session")
def shared_plans():
    """A :class:`gonio.daemon.planner.PlanCache` holding :data:`SHARED_GRIDS` on the default config, which
    every daemon of :func:`serve` hands its planner's worker (a copy each; planning is deterministic):
    each daemon's worker planned iso:step=15 afresh, 0.4 s of CPU for each of some 40 tests, where a
    kept plan is a copy of 10 ms. Tests of the planning itself plan grids and configs not kept here."""
    from gonio.daemon.planner import PlanCache

    plans, cfg = PlanCache(), load_config()
    for grid in SHARED_GRIDS:
        plans(grid, cfg)
    return plans


@pytest.fixture
def serve(tmp_path, shared_plans):
    """``serve(token=None, pace=0.0, hold=False, data=None, cfg=None, clock=None, **kw)``: a running
    daemon (``.url``, ``.client`` an httpx client that carries the token when one is set); ``kw`` go to
    :func:`build_daemon` (``materials``, ``allow_hosts``, ``plan_timeout_s``, ...), ``head_timeout_s``
    to the server."""
    running = []

    def start(token=None, pace=0.0, hold=False, data=None, cfg=None, max_streams=16, clock=None,
              head_timeout_s=10.0, **kw):
        # The planner at the test's own priority (`gonio serve` keeps it idle; tests/daemon/test_daemon_serve
        # and test_daemon_disk run that): at idle priority a submission waited for a core to fall idle.
        kw.setdefault("plan_idle", False)
        kw.setdefault("plans", shared_plans)
        d = build_daemon(cfg or load_config(), data or tmp_path / "data", token=token, pace=pace, hold=hold,
                         max_streams=max_streams, clock=clock, **kw)
        r = start_in_thread(d, head_timeout_s=head_timeout_s)
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        r.client = http_client(r.url, headers=headers)
        running.append(r)
        return r

    yield start
    for r in running:
        r.client.close()
        r.stop()


@pytest.fixture(autouse=True)
def _no_daemon_left_behind():
    """Every ``gonio serve`` process a test starts (daemon_helpers.Serve) is stopped, also when the test
    fails half-way."""
    yield
    while STARTED:
        s = STARTED.pop()
        if s.p.poll() is None:
            s.p.kill()
            s.p.wait(WAIT_S)
        s._f.close()
