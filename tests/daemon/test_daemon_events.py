"""The event stream: every committed measurement once and in order, across reconnects; bounds."""

from __future__ import annotations

import json

import httpx
from daemon_helpers import WAIT_S, submit, unpace, wait_for, wait_state

from gonio.daemon.client import iter_sse
from gonio.store import JOURNAL_NAME, Journal


def _read(url: str, cid: str, last_id: str | None = None, stop_after: int | None = None):
    """(messages, last id) of one connection: until ``end``, or until ``stop_after`` measurements."""
    headers = {"Last-Event-ID": last_id} if last_id else {}
    out, eid = [], last_id
    with httpx.stream("GET", f"{url}/campaigns/{cid}/events", headers=headers,
                      timeout=httpx.Timeout(WAIT_S)) as r:
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/event-stream")
        for event, new_id, data in iter_sse(r.iter_lines()):
            eid = new_id
            out.append((event, json.loads(data)))
            if event == "end":
                break
            if stop_after is not None and sum(e == "measurement" for e, _ in out) >= stop_after:
                break
    return out, eid


def test_every_measurement_once_and_in_order_across_reconnects(serve):
    r = serve(pace=0.001)
    submit(r.client, grid="iso:step=15")
    messages, eid = [], None
    for _ in range(3):  # drop the connection twice, mid-campaign, and reconnect with Last-Event-ID
        part, eid = _read(r.url, "c00001", eid, stop_after=7)
        messages += part
    part, eid = _read(r.url, "c00001", eid)
    messages += part
    steps = [d["step"] for e, d in messages if e == "measurement"]
    j = Journal.open(r.daemon.queue.root / "c00001" / JOURNAL_NAME, readonly=True)
    try:
        total = j.step_count()
        signals = {m.step: m.signal.tolist() for m in j.measurements()}
    finally:
        j.close()
    assert steps == list(range(total))
    for e, d in messages:
        if e == "measurement":
            assert d["signal"] == signals[d["step"]] and d["done"] == d["step"] + 1 and d["steps"] == total
    states = [d["state"] for e, d in messages if e == "state"]
    assert states[0] == "running" and states[-1] == "done"
    assert messages[-1] == ("end", {"state": "done", "id": "c00001"})
    # A client that connects after the end gets the whole history, then the end.
    again, _ = _read(r.url, "c00001")
    assert [d["step"] for e, d in again if e == "measurement"] == list(range(total))
    # Reconnecting with the last id gets only the end.
    tail, _ = _read(r.url, "c00001", eid)
    assert [e for e, _ in tail] == ["end"]


def test_a_paused_campaign_streams_its_pause_and_later_its_resume(serve):
    r = serve(pace=0.002)
    submit(r.client, grid="iso:step=15")
    first, eid = _read(r.url, "c00001", stop_after=2)
    r.client.post("/campaigns/c00001/pause").raise_for_status()
    wait_state(r.client, "c00001", "paused")
    r.client.post("/campaigns/c00001/resume").raise_for_status()
    unpace(r.daemon, only="c00001")   # the rest at once
    rest, _ = _read(r.url, "c00001", eid)
    allm = first + rest
    steps = [d["step"] for e, d in allm if e == "measurement"]
    assert steps == list(range(len(steps))) and rest[-1][0] == "end"
    states = [d["state"] for e, d in allm if e == "state"]
    assert "paused" in states and states[-1] == "done"
    assert any(d["kind"] == "park" for e, d in allm if e == "log")


def test_stream_errors_and_the_client_bound(serve):
    r = serve(max_streams=1)
    assert r.client.get("/campaigns/c00009/events").status_code == 404
    submit(r.client, grid="iso:step=30")
    wait_state(r.client, "c00001", "done")
    bad = r.client.get("/campaigns/c00001/events", headers={"Last-Event-ID": "../x"})
    assert bad.status_code == 422 and "Last-Event-ID" in bad.json()["detail"][0]["msg"]
    # One stream held open (it ends only after the whole history): a second one is refused.
    r.daemon.streams.open = 1
    try:
        busy = r.client.get("/campaigns/c00001/events")
        assert busy.status_code == 503 and "too many" in busy.json()["detail"]
    finally:
        r.daemon.streams.open = 0
    ok, _ = _read(r.url, "c00001")
    assert ok[-1][0] == "end"
    # The server releases its slot when its generator ends, just after the last bytes went out.
    wait_for(lambda: r.daemon.streams.open == 0, "the stream's slot to be released")
