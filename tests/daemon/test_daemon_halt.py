"""The emergency stop always works: with every request thread held up by slow reads (the queue's own
worker among them, holding the queue's lock) and the planner busy with slow submits, ``POST /gantry/halt``
from the rig (loopback, no token) is still answered and the running campaign halts mid-move."""

from __future__ import annotations

import json
import select
import socket
import threading

import httpx
import pytest
from daemon_helpers import TOKEN, WAIT_S, http_client, submit, wait_for, wait_state

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
    admits, lock = {"in": 0, "done": 0}, threading.Lock()      # admissions under way, and done
    real_admit = r.daemon.queue.admit

    def counted_admit(*args, **kw):
        with lock:
            admits["in"] += 1
        try:
            rec = real_admit(*args, **kw)
            with lock:
                admits["done"] += 1
            return rec
        finally:
            with lock:
                admits["in"] -= 1

    monkeypatch.setattr(r.daemon.queue, "admit", counted_admit)
    reads: list[int] = []
    submits: list[int] = []
    give_up = threading.Event()

    def read():
        headers = {"Authorization": f"Bearer {TOKEN}"}
        with http_client(r.url, headers=headers) as c:
            reads.append(c.get("/campaigns").status_code)

    def slow_submit():
        """A submit whose client waits for its answer until ``give_up`` (then leaves: its planning is
        cancelled): the answer's status, or 0 for none."""
        body = json.dumps({"material": "lambert:albedo=0.5", "grid": "iso:step=2"}).encode()
        url = httpx.URL(r.url)
        head = (f"POST /campaigns HTTP/1.1\r\nHost: {url.host}:{url.port}\r\nAuthorization: Bearer {TOKEN}"
                f"\r\nContent-Type: application/json\r\nContent-Length: {len(body)}\r\n\r\n")
        with socket.create_connection((url.host, url.port), timeout=WAIT_S) as sock:
            sock.sendall(head.encode() + body)
            while not give_up.wait(0.01):   # an answer, or the client leaves
                if select.select([sock], [], [], 0)[0]:
                    answer = b""
                    while b"\r\n" not in answer:   # the status line, whole
                        chunk = sock.recv(4096)
                        if not chunk:
                            break
                        answer += chunk
                    submits.append(int(answer.split()[1]) if b"\r\n" in answer else 0)
                    return
            submits.append(0)

    # Seconds of planning each on a slow machine; their clients leave once the halts are answered and
    # every admission that the slow reads held up has answered, which cancels the rest.
    threads = [threading.Thread(target=read) for _ in range(60)]
    threads += [threading.Thread(target=slow_submit) for _ in range(10)]
    try:
        for t in threads:
            t.start()
        wait_for(lambda: len(blocked) >= 40, "every request thread to be held up")
        wait_for(lambda: r.daemon.planner.busy, "the planner to be busy")
        # The rig's client (no token) gives up long before the held-up requests are released (WAIT_S).
        with http_client(r.url, timeout=HALT_WAIT_S) as rig:
            halt = rig.post("/gantry/halt")
        assert halt.status_code == 200 and halt.json()["id"] == "c00001", halt.text
        wait_for(lambda: _journal_state(r) == "halted", "the runner to journal its halt")
        # The queue's worker, looking for the next campaign, now waits in a slow read holding the queue's
        # lock: a second halt is answered all the same (nothing is moving: every axis is stopped again).
        wait_for(lambda: len(blocked) > 40, "the queue's worker to be held up too")
        with http_client(r.url, timeout=HALT_WAIT_S) as rig:
            again = rig.post("/gantry/halt")
        assert again.status_code == 200 and again.json()["message"] == "halt: every axis stopped", again.text
        assert not reads and not submits                      # every other request is still held up
        release.set()
        # The reads answer; a submit whose planning ended while the queue's lock was held up is admitted
        # now, and answered (201) before its client leaves.
        wait_for(lambda: len(reads) == 60 and not admits["in"] and submits.count(201) == admits["done"],
                 "the held-up requests to be answered")
    finally:
        release.set()
        give_up.set()
        for t in threads:
            t.join(WAIT_S)
    st = wait_state(r.client, "c00001", "halted")
    assert st["steps_done"] < st["steps"]
    # The reads answered in the end and none failed; a submit whose planning ended before its client gave
    # up (a fast machine) is admitted once its admission is released (201).
    assert set(reads) == {200} and set(submits) <= {0, 201} and len(submits) == 10
    wait_for(lambda: not r.daemon.planner.busy, "the abandoned submits to be cancelled")
    admitted = [f"c{k:05d}" for k in range(2, 2 + submits.count(201))]   # queued behind the halted one
    assert [c["id"] for c in r.client.get("/campaigns").json()["campaigns"]] == ["c00001", *admitted]


def test_a_halt_recorded_late_leaves_the_campaign_resumed_since_running(serve):
    """When the queue's lock is held up, the halt's record (daemon.json, and a runner that started
    meanwhile) waits for it in a thread of its own. A resume can take the lock first and start the
    campaign again: the late record then halted it once more, and it never finished (a whole-suite run
    at load 5, test_daemon_api's halt-and-resume test). Here the late record comes, as that thread
    would run it, while the resumed campaign runs."""
    from daemon_helpers import unpace

    r = serve(pace=0.01)
    submit(r.client, grid="iso:step=15")
    queue = r.daemon.queue
    wait_for(lambda: queue.runner is not None and r.client.get("/campaigns/c00001").json()["steps_done"],
             "a committed step")
    halted_runner, rec = queue.runner, queue.current
    assert r.client.post("/gantry/halt").status_code == 200
    wait_state(r.client, "c00001", "halted")
    r.client.post("/campaigns/c00001/resume").raise_for_status()
    wait_for(lambda: queue.runner not in (None, halted_runner), "the resumed campaign's runner")
    queue._record_halt(halted_runner, rec, "halt requested through the API")   # the late record
    # not halted again (its runner may still be starting on a loaded machine: the end below says it ran)
    assert r.client.get("/campaigns/c00001").json()["state"] in ("starting", "running", "finishing", "done")
    unpace(r.daemon)
    wait_state(r.client, "c00001", "done", timeout_s=15.0)


def test_a_resume_as_soon_as_the_halt_shows_is_not_lost(serve, monkeypatch):
    """The operator resumes the moment the API says ``halted``, while the worker is still letting the
    halted campaign go (closing its journal): the worker then put it back on hold, the resume was lost
    and the campaign stayed halted (test_daemon_fly's halt-and-resume, 3 runs in ~30 at load 3-4). Here
    the worker is held at that moment until the resume has been answered."""
    from gonio.daemon import queue as queue_module

    real_open = queue_module.open_campaign
    closing, resumed = threading.Event(), threading.Event()

    def open_held(folder, *args, **kw):
        c = real_open(folder, *args, **kw)
        real_close = c.close

        def close():
            if not resumed.is_set() and _journal_state(r) == "halted":
                closing.set()
                resumed.wait(HALT_WAIT_S)
            real_close()
        c.close = close
        return c

    r = serve(pace=0.01)
    monkeypatch.setattr(queue_module, "open_campaign", open_held)
    submit(r.client, grid="iso:step=15")
    wait_for(lambda: r.client.get("/campaigns/c00001").json()["steps_done"], "a committed step")
    assert r.client.post("/gantry/halt").status_code == 200
    assert closing.wait(HALT_WAIT_S), "the worker never let the halted campaign go"
    assert r.client.get("/campaigns/c00001").json()["state"] == "halted"
    r.client.post("/campaigns/c00001/resume").raise_for_status()
    resumed.set()
    from daemon_helpers import unpace

    unpace(r.daemon)
    wait_state(r.client, "c00001", "done", timeout_s=30.0)    # it stayed halted, the resume lost
