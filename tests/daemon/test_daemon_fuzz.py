"""Fuzz the daemon's API with schemathesis against its own OpenAPI document: no 5xx, no hang.

Every operation gets bounded examples (valid and invalid bodies, paths, queries, headers) against a
fresh in-process daemon on the simulated gantry (pace 0). The event stream is left out (a stream lasts
as long as its campaign; it has its own tests)."""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.checks import not_a_server_error

from gonio.config import load_config
from gonio.daemon.app import asgi
from gonio.daemon.server import build_daemon

# The application exists when the module is collected (schemathesis reads its OpenAPI document then);
# its queue's worker runs only while this module's tests do.
_DATA = Path(tempfile.mkdtemp(prefix="gonio-fuzz-"))
_DAEMON = build_daemon(load_config(), _DATA / "data", pace=0.0)
schema = schemathesis.openapi.from_asgi("/openapi.json", asgi(_DAEMON)).exclude(path_regex=r".*/events$")


@pytest.fixture(scope="module", autouse=True)
def _running_queue():
    _DAEMON.queue.start()
    try:
        yield
    finally:
        _DAEMON.queue.stop(timeout_s=60)
        _DAEMON.gantry.release()
        shutil.rmtree(_DATA, ignore_errors=True)


@schema.parametrize()
@settings(max_examples=8, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much,
                                 HealthCheck.function_scoped_fixture])
def test_no_request_makes_the_daemon_fail(case):
    case.call_and_validate(checks=[not_a_server_error])
