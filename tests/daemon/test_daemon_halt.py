"""The emergency stop always works: with every request thread held up by slow reads (the queue's own
worker among them, holding the queue's lock) and the planner busy with slow submits, ``POST /gantry/halt``
from the rig (loopback, no token) is still answered and the running campaign halts mid-move."""

from __future__ import annotations

import threading

import httpx
import pytest
from daemon_helpers import TOKEN, WAIT_S, submit, wait_for, wait_state

from gonio.store import JOURNAL_NAME, Journal

HALT_WAIT_S = 10.0


def _journal_state(r) -> str:
    j = Journal.open(r.daemon.queue.root / "c00001" / JOURNAL_NAME, readonly=True)
    try:
        return j.last_event("state")["state"]
    finally:
        j.close()


@pytest.mark.slow
def test_the_halt_is_answered_with_every_pool_saturated(serve, monkeypatch):
    r = serve(token=TOKEN, pace=0.5)
    submit(r.client, grid="iso:step=15")    # half a real second per gantry second: it outlasts the test
    wait_state(r.client, "c00001", "running")
    # Slow reads: GET /campaigns (a plain function: FastAPI runs it on its request threads, 40 of them)
    # blocks until released, as a read stuck on a slow disk would; so does the queue's worker when it
    # looks for the next campaign after the halt, holding the queue's lock.
    release = threading.Event()
    blocked = []
    real_records = r.daemon.queue.records

    def slow_records():
        blocked.append(1)
        release.wait(WAIT_S)
        return real_records()

    monkeypatch.setattr(r.daemon.queue, "records", slow_records)
    results: list[int] = []

    def call(method, path, read_s=WAIT_S, **kw):
        headers = {"Authorization": f"Bearer {TOKEN}"}
        try:
            timeout = httpx.Timeout(WAIT_S, read=read_s)
            with httpx.Client(base_url=r.url, timeout=timeout, headers=headers) as c:
                results.append(c.request(method, path, **kw).status_code)
        except httpx.ReadTimeout:
            results.append(0)    # a submit that gave up waiting (its planning is cancelled)

    # Seconds of planning each on a slow machine; their clients give up after 10 s, which cancels them.
    slow_grid = {"material": "lambert:albedo=0.5", "grid": "iso:step=2"}
    threads = [threading.Thread(target=call, args=("GET", "/campaigns")) for _ in range(60)]
    threads += [threading.Thread(target=call, args=("POST", "/campaigns", 10.0), kwargs={"json": slow_grid})
                for _ in range(10)]
    try:
        for t in threads:
            t.start()
        wait_for(lambda: len(blocked) >= 40, "every request thread to be held up")
        wait_for(lambda: r.daemon.planner.busy, "the planner to be busy")
        # The rig's client (no token) gives up long before the held-up requests are released (WAIT_S).
        with httpx.Client(base_url=r.url, timeout=HALT_WAIT_S) as rig:
            halt = rig.post("/gantry/halt")
        assert halt.status_code == 200 and halt.json()["id"] == "c00001", halt.text
        wait_for(lambda: _journal_state(r) == "halted", "the runner to journal its halt")
        # The queue's worker, looking for the next campaign, now waits in a slow read holding the queue's
        # lock: a second halt is answered all the same (nothing is moving: every axis is stopped again).
        wait_for(lambda: len(blocked) > 40, "the queue's worker to be held up too")
        with httpx.Client(base_url=r.url, timeout=HALT_WAIT_S) as rig:
            again = rig.post("/gantry/halt")
        assert again.status_code == 200 and again.json()["message"] == "halt: every axis stopped", again.text
        assert not results                                    # every other request is still held up
    finally:
        release.set()
        for t in threads:
            t.join(WAIT_S)
    st = wait_state(r.client, "c00001", "halted")
    assert st["steps_done"] < st["steps"]
    # The reads answered in the end and none failed; a submit whose planning ended before its client gave
    # up (a fast machine) is admitted once its admission is released (201).
    assert set(results) <= {0, 200, 201}
    wait_for(lambda: not r.daemon.planner.busy, "the abandoned submits to be cancelled")
    admitted = [f"c{k:05d}" for k in range(2, 2 + results.count(201))]   # queued behind the halted one
    assert [c["id"] for c in r.client.get("/campaigns").json()["campaigns"]] == ["c00001", *admitted]
