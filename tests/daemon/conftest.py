"""Daemons served in-process on 127.0.0.1 (any free port), each stopped at the end of its test."""

from __future__ import annotations

import pytest
from daemon_helpers import STARTED, WAIT_S, http_client, shared_plans

from gonio.config import load_config
from gonio.daemon.server import build_daemon, start_in_thread


@pytest.fixture
def serve(tmp_path):
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
        kw.setdefault("plans", shared_plans())   # iso:step=15 and 30, planned once
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
