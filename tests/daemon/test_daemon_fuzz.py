"""Fuzz the daemon's API with schemathesis against its own OpenAPI document: no 5xx, no hang, and every
status it answers is one its document lists; hand cases beside it for what a generator does not send
(NaN and ±Infinity, which JSON lacks and Python's parser reads).

Every operation gets bounded, derandomized examples (valid and invalid bodies, paths, queries, headers)
against one in-process daemon on the simulated gantry (pace 0). The event stream is left out (a stream
lasts as long as its campaign; it has its own tests)."""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import pytest
import schemathesis
from daemon_helpers import shared_plans
from hypothesis import HealthCheck, settings
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import content_type_conformance, status_code_conformance

from gonio.config import load_config
from gonio.daemon.app import asgi
from gonio.daemon.server import build_daemon

# The application exists when the module is collected (schemathesis reads its OpenAPI document then);
# its queue's worker and planner run only while this module's tests do. schemathesis calls it as
# http://testserver.
_DATA = Path(tempfile.mkdtemp(prefix="gonio-fuzz-"))
# Its planner at the test's own priority: at idle priority each planned example waited for a core to fall
# idle (the suite's other workers), past schemathesis's 10 s read on a loaded machine.
_DAEMON = build_daemon(load_config(), _DATA / "data", pace=0.0, allow_hosts=("testserver:80",),
                       plan_idle=False)
schema = schemathesis.openapi.from_asgi("/openapi.json", asgi(_DAEMON)).exclude(path_regex=r".*/events$")


def _client():
    import warnings

    with warnings.catch_warnings():   # starlette would rather have httpx2; httpx is what we have
        warnings.simplefilter("ignore")
        from starlette.testclient import TestClient
    return TestClient(asgi(_DAEMON), base_url="http://testserver")


@pytest.fixture(scope="module", autouse=True)
def _running_queue():
    _DAEMON.queue.start()
    _DAEMON.planner.plans = shared_plans()   # the examples' grid, planned once (not at collection)
    _DAEMON.planner.start()
    try:
        yield
    finally:
        _DAEMON.queue.stop(timeout_s=60)
        _DAEMON.planner.stop()
        _DAEMON.gantry.release()
        shutil.rmtree(_DATA, ignore_errors=True)


@schema.parametrize()
@settings(max_examples=8, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much,
                                 HealthCheck.function_scoped_fixture])
def test_no_request_makes_the_daemon_fail_or_answer_an_undocumented_status(case):
    case.call_and_validate(checks=[not_a_server_error, status_code_conformance, content_type_conformance])


@pytest.mark.parametrize(("path", "body"), [
    ("/campaigns", '{"material": "lambert:albedo=0.5", "grid": "iso:step=30", "seed": NaN}'),
    ("/campaigns", '{"material": "lambert:albedo=0.5", "grid": "iso:step=30", "detector": {"exposure_s": '
                   'Infinity}}'),
    ("/campaigns", '{"material": NaN, "grid": "iso:step=30"}'),
    ("/gantry/move", '{"theta_i_deg": NaN, "phi_i_deg": 0, "theta_o_deg": 30, "phi_o_deg": 180}'),
    ("/gantry/move", '{"theta_i_deg": 10, "phi_i_deg": -Infinity, "theta_o_deg": 30, "phi_o_deg": 180}'),
    ("/gantry/halt", '{"x": [1, 2, Infinity]}'),
    ("/campaigns/c00001/pause", '[NaN]'),
])
def test_nan_and_infinity_are_refused_with_422(path, body):
    before = sorted((_DATA / "data" / "campaigns").iterdir())
    with _client() as c:
        r = c.post(path, content=body, headers={"Content-Type": "application/json"})
    assert r.status_code == 422, r.text
    detail = r.json()["detail"][0]
    assert detail["loc"] == ["body"] and "is not a JSON number" in detail["msg"]
    assert sorted((_DATA / "data" / "campaigns").iterdir()) == before


@pytest.mark.parametrize("path, body, key", [
    ("/campaigns", '{"material": "lambert:albedo=0.5", "grid": "iso:step=30", '
                   '"material": "merl:/etc/passwd"}', "material"),
    ("/campaigns", '{"material": "lambert:albedo=0.5", "grid": "iso:step=30", '
                   '"detector": {"exposure_s": 0.1, "exposure_s": 10}}', "exposure_s"),
    ("/gantry/move", '{"theta_i_deg": 10, "phi_i_deg": 0, "theta_o_deg": 30, "phi_o_deg": 180, '
                     '"theta_i_deg": 80}', "theta_i_deg"),
])
def test_a_key_given_twice_is_refused_with_422(path, body, key):
    """Which of two values a reader takes is up to the reader (RFC 8259): a proxy or a log that reads the
    first must not see a request other than the one the daemon acts on."""
    before = sorted((_DATA / "data" / "campaigns").iterdir())
    with _client() as c:
        r = c.post(path, content=body, headers={"Content-Type": "application/json"})
    assert r.status_code == 422, r.text
    detail = r.json()["detail"][0]
    assert detail["loc"] == ["body"]
    assert detail["msg"] == f"body: key {key!r} is given twice in one object; give each once"
    assert sorted((_DATA / "data" / "campaigns").iterdir()) == before


def test_a_validation_error_never_echoes_what_it_cannot_serialize():
    """pydantic's 422 echoes the input; a float it refuses (an exponent past float64) must not make it
    a 500."""
    with _client() as c:
        r = c.post("/gantry/move", content='{"theta_i_deg": 1e999, "phi_i_deg": 0, "theta_o_deg": 30, '
                   '"phi_o_deg": 180}', headers={"Content-Type": "application/json"})
        assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "theta_i_deg"], r.text
        r = c.post("/campaigns", content="[" * 5000 + "]" * 5000,
                   headers={"Content-Type": "application/json"})
        assert r.status_code == 422 and "nested too deeply" in r.text


def test_the_openapi_document_says_which_routes_need_the_token_only_when_one_is_set(tmp_path):
    from gonio.daemon.app import create_app

    def doc(**kw):
        d = build_daemon(load_config(), tmp_path / "d", **kw)
        return create_app(d).openapi()["paths"]

    writes = [("/campaigns", "post"), ("/campaigns/{cid}/pause", "post"), ("/campaigns/{cid}/resume", "post"),
              ("/campaigns/{cid}/abort", "post"), ("/gantry/home", "post"), ("/gantry/move", "post")]
    none, token = doc(), doc(token="0123456789abcdef-token")
    for path, method in writes:
        assert "security" not in none[path][method] and "401" not in none[path][method]["responses"]
        assert token[path][method]["security"] == [{"HTTPBearer": []}]
        assert {"401", "429", "403", "415", "422"} <= set(token[path][method]["responses"])
    halt = token["/gantry/halt"]["post"]
    assert halt["security"] == [{"HTTPBearer": []}, {}]
    assert "loopback client needs no token" in halt["description"]
    assert {"500", "503", "507"} <= set(token["/campaigns"]["post"]["responses"])
    assert {"404", "409"} <= set(token["/campaigns/{cid}/brdf"]["get"]["responses"])
    for path in token.values():
        assert "security" not in path.get("get", {})
