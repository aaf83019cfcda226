"""Daemons served in-process on 127.0.0.1 (any free port), each stopped at the end of its test; one
headless Chromium for the tests that drive a browser."""

from __future__ import annotations

import pytest
from daemon_helpers import CHROMIUM, STARTED, WAIT_S, http_client, shared_plans

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


@pytest.fixture(scope="session")
def browser():
    """One Chromium (Debian's, driven by Playwright) for every test here that drives one (the web view's
    and the cross-origin attacks'): a launch costs ~1.5 s of CPU, and each module launched its own. Each
    test's pages have browser contexts of their own (cookies, storage, cache).

    Every *.test name resolves to 127.0.0.1 (as a rebinding attacker's DNS makes it), and Chromium's Local
    Network Access checks are off: Firefox and Safari have none, and they do not stop a page served from
    the LAN, so the daemon must refuse on its own (test_daemon_origin). The web view's pages are the
    daemon's own, on 127.0.0.1: neither setting touches them."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=[
            "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
            "--disable-component-update", "--no-first-run", "--host-resolver-rules=MAP *.test 127.0.0.1",
            "--disable-features=LocalNetworkAccessChecks,BlockInsecurePrivateNetworkRequests,"
            "PrivateNetworkAccessRespectPreflightResults"])
        try:
            yield b
        finally:
            b.close()
