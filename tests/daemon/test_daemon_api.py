"""The daemon's HTTP API: health, the gantry, campaigns through the queue, and what it refuses."""

from __future__ import annotations

import threading

import pytest
from daemon_helpers import TOKEN, WAIT_S, http_client, submit, unpace, wait_for, wait_state

from gonio.daemon.auth import FAILURES_ALLOWED, check_bind, check_token, is_loopback, token_ok
from gonio.store import JOURNAL_NAME, Journal

WRITES = [("POST", "/campaigns", {"material": "lambert:albedo=0.5", "grid": "iso:step=30"}),
          ("POST", "/campaigns/c00001/pause", None), ("POST", "/campaigns/c00001/resume", None),
          ("POST", "/campaigns/c00001/abort", None), ("POST", "/gantry/home", None),
          ("POST", "/gantry/move", {"theta_i_deg": 30, "phi_i_deg": 0, "theta_o_deg": 30, "phi_o_deg": 180}),
          ("POST", "/gantry/halt", None)]


def _one_step_measured(r):
    def check():
        st = r.client.get("/campaigns/c00001").json()
        return st if st["steps_done"] >= 1 else None
    return check


def test_a_campaign_runs_to_the_end_and_its_brdf_can_be_fetched(serve):
    r = serve()
    health = r.client.get("/health").json()
    assert health["status"] == "ok" and health["gantry"] == "sim-two-arm" and health["auth"] is False
    st = submit(r.client)
    assert st["id"] == "c00001" and st["state"] in ("queued", "starting", "running", "finishing", "done")
    st = wait_state(r.client, "c00001", "done")
    assert st["steps_done"] == st["steps"] and st["brdf"] and st["progress"] == 1.0
    data = r.client.get("/campaigns/c00001/brdf")
    assert data.status_code == 200 and data.content[:8] == b"\x89HDF\r\n\x1a\n"
    log = r.client.get("/campaigns/c00001/log").json()
    assert [e["state"] for e in log if e["kind"] == "state"] == ["running", "done"]
    assert r.client.get("/campaigns").json()["campaigns"][0]["state"] == "done"
    assert (r.daemon.queue.root / "c00001" / JOURNAL_NAME).is_file()   # DATA/campaigns/<id>/


@pytest.mark.parametrize(("body", "field", "text"), [
    ({"material": "lambert:albedo=5", "grid": "iso:step=30"}, "material", "albedo"),
    ({"material": "merl:/etc/passwd", "grid": "iso:step=30"}, "material", "serves none"),
    ({"material": "bsdf:/dev/zero", "grid": "iso:step=30"}, "material", "serves none"),
    ({"grid": "iso:step=30"}, "material", "required"),
    ({"material": "lambert:albedo=0.5", "grid": "iso:step=-1"}, "grid", "step"),
    ({"material": "lambert:albedo=0.5", "grid": "nope"}, "grid", ""),
    ({"material": "lambert:albedo=0.5", "grid": "iso:step=30", "seed": -1}, "seed", ""),
    ({"material": "lambert:albedo=0.5", "grid": "iso:step=30", "detector": {"exposure_s": 0}},
     "detector", ""),
    ({"material": "lambert:albedo=0.5", "grid": "iso:step=30", "path": "/tmp/x"}, "path", ""),
])
def test_bad_requests_are_refused_with_422_naming_the_field(serve, body, field, text):
    r = serve()
    resp = r.client.post("/campaigns", json=body)
    assert resp.status_code == 422, resp.text
    detail = resp.json()["detail"][0]
    assert field in [str(x) for x in detail["loc"]], detail
    assert text in detail["msg"]
    assert r.client.get("/campaigns").json()["campaigns"] == []   # nothing journaled


def test_writes_need_the_token_reads_do_not(serve):
    r = serve(token=TOKEN)
    anon = http_client(r.url)
    wrong = http_client(r.url, headers={"Authorization": "Bearer nope"})
    try:
        for method, path, body in WRITES[:-1]:
            for c in (anon, wrong):
                resp = c.request(method, path, json=body)
                assert resp.status_code == 401, (path, resp.text)
                assert "token" in resp.json()["detail"]
        assert r.daemon.queue.records() == []            # nothing was submitted
        assert anon.get("/health").json()["auth"] is True
        assert anon.get("/campaigns").status_code == 200 and anon.get("/gantry").status_code == 200
        # The emergency stop from the rig (a loopback client) needs no token.
        assert anon.post("/gantry/halt").json()["message"] == "halt: every axis stopped"
        lower = http_client(r.url, headers={"Authorization": f"bearer  {TOKEN}"})
        with lower:                                      # RFC 7235: the scheme in any case
            assert submit(lower)["id"] == "c00001"       # the token opens writes
    finally:
        anon.close()
        wrong.close()


def test_the_halt_needs_the_token_when_configured_so(serve):
    r = serve(token=TOKEN, halt_needs_token=True)
    with http_client(r.url) as anon:
        assert anon.post("/gantry/halt").status_code == 401
    assert r.client.post("/gantry/halt").status_code == 200


def test_wrong_tokens_are_rate_limited_per_client(serve):
    r = serve(token=TOKEN)
    with http_client(r.url, headers={"Authorization": "Bearer x" * 4}) as wrong:
        codes = [wrong.post("/campaigns/c00001/pause").status_code for _ in range(FAILURES_ALLOWED + 2)]
    assert codes == [401] * FAILURES_ALLOWED + [429, 429]
    blocked = r.client.post("/campaigns/c00001/pause")          # the right token too, from that client
    assert blocked.status_code == 429 and 0 < int(blocked.headers["retry-after"]) <= 60
    assert "too many wrong tokens" in blocked.json()["detail"]


def test_token_comparison_and_the_loopback_rule():
    assert token_ok(None, None) and token_ok("", "whatever")
    assert token_ok("abc", "Bearer abc") and not token_ok("abc", "Bearer abd") and not token_ok("abc", "abc")
    assert token_ok("abc", "BEARER abc") and token_ok("abc", "bearer abc")
    assert not token_ok("abc", "Basic abc")
    assert is_loopback("::ffff:127.0.0.1") and is_loopback("127.3.2.1") and not is_loopback("::ffff:10.0.0.1")
    for weak in (" " * 20, "x", "short-token", "fifteen-chars-x", "has a space in it!!",
                 "tab\tseparated-token1", "nön-ascii-token-abc"):
        with pytest.raises(ValueError, match="at least 16 characters and no whitespace"):
            check_token(weak)
    assert check_token("") is None and check_token(TOKEN) == TOKEN
    check_bind("127.0.0.1", None)
    check_bind("::1", None)
    check_bind("localhost", None)
    check_bind("0.0.0.0", TOKEN)
    for host in ("0.0.0.0", "203.0.113.5", "::", "gantry.lab"):
        with pytest.raises(ValueError, match="--host: .* token"):
            check_bind(host, None)


def test_request_bodies_are_bounded(serve):
    r = serve()
    resp = r.client.post("/campaigns", content=b"{" + b" " * 20000 + b"}",
                         headers={"Content-Type": "application/json"})
    assert resp.status_code == 413
    resp = r.client.post("/campaigns", content=iter([b"x" * 10000] * 3),
                         headers={"Content-Type": "application/json"})
    assert resp.status_code == 413


def test_ids_cannot_name_paths(serve):
    r = serve()
    for cid in ("%2e%2e", "c00001%2f..%2f..", "C00001", "c1", "c000011"):
        assert r.client.get(f"/campaigns/{cid}").status_code in (404, 422)
    assert r.client.get("/campaigns/c99999").status_code == 404
    assert r.client.get("/static/../app.py").status_code == 404


def test_a_second_campaign_waits_in_the_queue_while_the_first_runs(serve):
    r = serve(pace=0.01)   # the first still runs when the second, planned meanwhile, comes
    submit(r.client, grid="iso:step=15")
    wait_state(r.client, "c00001", "running")
    second = submit(r.client, grid="iso:step=30")
    assert second["state"] == "queued"
    q = r.client.get("/campaigns").json()
    assert q["running"] == "c00001" and [c["state"] for c in q["campaigns"]] == ["running", "queued"]
    unpace(r.daemon)
    wait_state(r.client, "c00002", "done")
    first = Journal.open(r.daemon.queue.root / "c00001" / JOURNAL_NAME, readonly=True)
    later = Journal.open(r.daemon.queue.root / "c00002" / JOURNAL_NAME, readonly=True)
    try:
        assert later.events()[0]["wall_s"] >= first.last_event("state")["wall_s"]  # one at a time
        assert first.done_steps().tolist() == list(range(first.step_count()))
    finally:
        first.close()
        later.close()


def test_pause_resume_abort_through_the_api(serve):
    r = serve(pace=0.01)   # the first still runs when the second, planned meanwhile, comes
    submit(r.client, grid="iso:step=15")
    submit(r.client, grid="iso:step=30")
    wait_for(_one_step_measured(r), "a committed step")
    resp = r.client.post("/campaigns/c00001/pause")
    assert resp.status_code == 200
    paused = wait_state(r.client, "c00001", "paused")
    assert 0 < paused["steps_done"] < paused["steps"]
    # A paused head holds the queue: the second campaign does not start behind the operator's back.
    assert r.client.get("/campaigns/c00002").json()["state"] == "queued"
    assert r.client.get("/campaigns/c00002").json()["steps_done"] == 0
    log = r.client.get("/campaigns/c00001/log").json()
    assert any(e["kind"] == "park" for e in log)
    assert r.client.post("/campaigns/c00001/resume").status_code == 200
    unpace(r.daemon, only="c00001")   # its rest at once; the second keeps the pace, to be aborted running
    wait_state(r.client, "c00001", "done")
    wait_state(r.client, "c00002", ("running", "done", "finishing"))
    assert r.client.post("/campaigns/c00002/abort").status_code == 200
    st = wait_state(r.client, "c00002", ("aborted", "done"))
    if st["state"] == "aborted":
        assert not st["brdf"]
    assert r.client.post("/campaigns/c00001/abort").status_code == 409   # done is final


def test_halt_stops_the_running_campaign_and_resume_finishes_it(serve):
    r = serve(pace=0.002)
    submit(r.client, grid="iso:step=15")
    wait_for(_one_step_measured(r), "a committed step")
    resp = r.client.post("/gantry/halt")
    assert resp.status_code == 200 and resp.json()["id"] == "c00001"
    halted = wait_state(r.client, "c00001", "halted")
    assert halted["steps_done"] < halted["steps"]
    log = r.client.get("/campaigns/c00001/log").json()
    assert any(e["kind"] == "halt" for e in log) and not any(e["kind"] == "park" for e in log)
    r.client.post("/campaigns/c00001/resume").raise_for_status()
    unpace(r.daemon, only="c00001")   # the rest at once
    wait_state(r.client, "c00001", "done")
    j = Journal.open(r.daemon.queue.root / "c00001" / JOURNAL_NAME, readonly=True)
    try:
        assert j.done_steps().tolist() == list(range(j.step_count()))
    finally:
        j.close()


@pytest.mark.slow
def test_an_aborted_queued_campaign_never_runs_and_a_paused_one_can_be_aborted(serve):
    r = serve(pace=0.01)   # the first still runs when the second, planned meanwhile, comes
    submit(r.client, grid="iso:step=15")
    submit(r.client, grid="iso:step=30")
    assert r.client.post("/campaigns/c00002/abort").json()["state"] == "aborted"
    r.client.post("/campaigns/c00001/pause").raise_for_status()
    wait_state(r.client, "c00001", "paused")
    r.client.post("/campaigns/c00001/abort").raise_for_status()
    assert r.client.get("/campaigns/c00001").json()["state"] == "aborted"
    assert r.client.get("/campaigns/c00002").json()["steps_done"] == 0
    assert r.client.post("/campaigns/c00001/resume").status_code == 409
    assert r.client.get("/campaigns/c00001/brdf").status_code == 409


@pytest.mark.slow
def test_an_abort_that_comes_as_the_paused_runner_leaves_is_not_lost(serve, monkeypatch):
    """The window between the runner stopping (paused) and the campaign leaving the worker: the
    runner is gone, so nobody but the worker can record the abort. The abort request comes while the
    worker closes the campaign's journal, and the worker goes on once the queue holds it (the request
    then waits for the campaign to leave the worker, so its reply tells the outcome)."""
    import gonio.daemon.queue as queue_module

    real_open, fired, requests = queue_module.open_campaign, [], []
    r = None

    def abort():
        fired.append(r.client.post("/campaigns/c00001/abort").json()["state"])

    def open_with_late_abort(folder, **kw):
        c = real_open(folder, **kw)
        real_close = c.close

        def close():
            if not requests:   # the worker's own journal, closed after the runner has stopped
                requests.append(threading.Thread(target=abort))
                requests[0].start()
                wait_for(lambda: r.daemon.queue.get("c00001").abort_pending, "the abort to reach the queue")
            real_close()
        c.close = close
        return c

    monkeypatch.setattr(queue_module, "open_campaign", open_with_late_abort)
    r = serve(pace=0.002)
    submit(r.client, grid="iso:step=30")
    wait_state(r.client, "c00001", "running")
    r.client.post("/campaigns/c00001/pause").raise_for_status()
    wait_state(r.client, "c00001", "aborted")
    requests[0].join(WAIT_S)
    assert fired == ["aborted"] and r.client.get("/campaigns/c00001").json()["state"] == "aborted"
    assert r.client.post("/campaigns/c00001/resume").status_code == 409


def test_manual_moves_are_checked_and_a_halt_stops_one_mid_move(serve):
    r = serve(pace=0.5)   # the move takes about a second of wall time: the halt comes well within it
    g = r.client.get("/gantry").json()
    names = ["light_azimuth", "light_tilt", "detector_azimuth", "detector_tilt"]
    assert [a["name"] for a in g["axes"]] == names
    assert g["owner"] is None and g["light"]["on"] is False and g["detector"]["channels"] == ["R", "G", "B"]
    bad = r.client.post("/gantry/move", json={"theta_i_deg": 85, "phi_i_deg": 0, "theta_o_deg": 30,
                                              "phi_o_deg": 180})
    assert bad.status_code == 422 and "beyond_theta_max" in bad.json()["detail"][0]["msg"]
    bad = r.client.post("/gantry/move", json={"theta_i_deg": 30, "phi_i_deg": 0, "theta_o_deg": 30})
    assert bad.status_code == 422 and "phi_o_deg" in str(bad.json()["detail"][0]["loc"])
    result = {}
    mover = threading.Thread(target=lambda: result.update(r=r.client.post("/gantry/move", json={
        "theta_i_deg": 60, "phi_i_deg": 0, "theta_o_deg": 60, "phi_o_deg": 180})))
    mover.start()
    def under_way():
        g = r.client.get("/gantry").json()
        return g["moving"] and g["angles"]["theta_i_deg"] > 1.0
    wait_for(under_way, "the move to be under way")
    assert r.client.post("/gantry/move", json={"theta_i_deg": 10, "phi_i_deg": 0, "theta_o_deg": 10,
                                               "phi_o_deg": 180}).status_code == 409   # one at a time
    r.client.post("/gantry/halt").raise_for_status()
    mover.join(WAIT_S)
    assert result["r"].status_code == 409 and "halted" in result["r"].json()["detail"]
    g = r.client.get("/gantry").json()
    assert not g["moving"] and 0 < g["angles"]["theta_i_deg"] < 60       # stopped mid-move
    home = r.client.post("/gantry/home")
    assert home.status_code == 200 and home.json()["angles"]["theta_i_deg"] == pytest.approx(0, abs=1e-6)


def test_manual_moves_are_refused_while_a_campaign_owns_the_gantry(serve):
    r = serve(pace=0.002)
    submit(r.client, grid="iso:step=15")
    wait_state(r.client, "c00001", "running")
    assert r.client.get("/gantry").json()["owner"] == "c00001"
    resp = r.client.post("/gantry/home")
    assert resp.status_code == 409 and "c00001" in resp.json()["detail"]
    r.client.post("/campaigns/c00001/abort").raise_for_status()
    wait_state(r.client, "c00001", "aborted")
