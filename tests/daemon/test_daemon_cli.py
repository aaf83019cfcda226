"""The CLI clients against an in-process daemon: submit, queue, watch, pause, resume, abort, halt, fetch;
one clear line when the daemon is not running or refuses."""

from __future__ import annotations

import h5py
import pytest
from daemon_helpers import TOKEN, WAIT_S, submit, wait_for, wait_state

from gonio.cli import main


@pytest.fixture
def env(monkeypatch):
    def set_(url, token=None):
        monkeypatch.setenv("GONIO_URL", url)
        if token:
            monkeypatch.setenv("GONIO_TOKEN", token)
        else:
            monkeypatch.delenv("GONIO_TOKEN", raising=False)
    return set_


def test_submit_watch_queue_fetch(serve, env, tmp_path, capsys):
    r = serve(token=TOKEN)
    env(r.url, TOKEN)
    assert main(["submit", "lambert:albedo=0.5", "--grid", "iso:step=30", "--seed", "2",
                 "--frames", "2"]) == 0
    out = capsys.readouterr()
    assert out.out.strip() == "c00001" and "campaign c00001: " in out.err and "(30 steps)" in out.err
    assert main(["watch", "c00001"]) == 0
    err = capsys.readouterr().err
    assert "c00001: 30/30 steps (100 %)" in err and "campaign c00001: done" in err
    assert main(["queue"]) == 0
    assert "c00001  done" in capsys.readouterr().out
    assert main(["queue", "c00001"]) == 0
    assert "progress: 30/30 steps (100.0 %)" in capsys.readouterr().out
    assert main(["status", "c00001"]) == 0            # an id: the daemon's status of that campaign
    out = capsys.readouterr().out
    assert out.startswith("c00001: done") and "progress: 30/30 steps (100.0 %)" in out
    assert main(["fetch", "c00001", "--out", str(tmp_path / "b.h5")]) == 0
    with h5py.File(tmp_path / "b.h5") as f:
        assert "samples" in f
    capsys.readouterr()
    (tmp_path / "b.h5").write_bytes(b"mine")   # an existing file is replaced only with --force, as by export
    assert main(["fetch", "c00001", "--out", str(tmp_path / "b.h5")]) == 2
    assert "--out: " in capsys.readouterr().err and (tmp_path / "b.h5").read_bytes() == b"mine"
    assert main(["fetch", "c00001", "--out", str(tmp_path / "b.h5"), "--force"]) == 0
    assert h5py.is_hdf5(tmp_path / "b.h5")
    assert main(["submit", "lambert:albedo=0.5", "--grid", "iso:step=30", "--exposure-s", "0.05",
                 "--watch"]) == 0


def test_pause_resume_abort_halt_from_the_command_line(serve, env, capsys):
    r = serve(pace=0.002)
    env(r.url)
    submit(r.client, grid="iso:step=15")
    wait_for(lambda: r.client.get("/campaigns/c00001").json()["steps_done"] >= 1, "a committed step")
    capsys.readouterr()
    assert main(["pause", "c00001"]) == 0
    said = capsys.readouterr().out   # the state once: it read "c00001: pausing: pausing: the step ..."
    assert said.startswith("c00001: ") and said.count("pausing") == 1 and "the step in flight" in said
    wait_state(r.client, "c00001", "paused")
    assert main(["resume", "c00001"]) == 0
    wait_state(r.client, "c00001", ("running", "done", "finishing"))
    assert main(["halt"]) == 0
    st = wait_state(r.client, "c00001", ("halted", "done"))
    capsys.readouterr()
    if st["state"] == "halted":
        assert main(["abort", "c00001"]) == 0
        assert "c00001: aborted" in capsys.readouterr().out
        assert main(["abort", "c00001"]) == 1
        assert "refused (409)" in capsys.readouterr().err


def test_one_clear_line_when_there_is_no_daemon_or_it_refuses(serve, env, capsys):
    env("http://127.0.0.1:9")        # nothing listens on the discard port
    assert main(["queue"]) == 3
    err = capsys.readouterr().err.strip()
    assert err.startswith("gonio queue: no gonio daemon at http://127.0.0.1:9") and "\n" not in err
    r = serve(token=TOKEN)
    env(r.url)                       # no token
    assert main(["pause", "c00001"]) == 1
    err = capsys.readouterr().err.strip()
    assert "needs its token" in err and "\n" not in err
    env(r.url, TOKEN)
    assert main(["submit", "lambert:albedo=3", "--grid", "iso:step=30"]) == 2   # bad input: 2, as elsewhere
    err = capsys.readouterr().err.strip()
    assert "refused (422)" in err and "material" in err and "\n" not in err
    assert main(["fetch", "c00042", "--out", "x.h5"]) == 1
    assert "no such campaign" in capsys.readouterr().err
    assert main(["queue", "--url", "ftp://x"]) == 2
    capsys.readouterr()
    # Malformed URLs: httpx's InvalidURL came out as a traceback.
    for url, says in [("http://[::1", "is not a valid URL (Invalid port: ':1')"),
                      ("http://host:port", "is not a valid URL"), ("https://:80", "names no host")]:
        assert main(["queue", "--url", url]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith(f"gonio queue: --url: {url!r} {says}") and "\n" not in err, err
    assert main(["status", "c00001", "--url", "http://127.0.0.1:9"]) == 3
    assert capsys.readouterr().err.strip().startswith("gonio status: no gonio daemon at http://127.0.0.1:9")


@pytest.fixture
def slow_admission(monkeypatch):
    """The daemon plans a submission, then admits it only once ``release`` is set (a daemon under load:
    the answer comes after the client gave up waiting; the client then looks in the queue every 10 ms).
    A client that leaves while the campaign is still being planned cancels it; one that leaves while it
    is being admitted does not: that is the case where a campaign was accepted and its client never heard.

    The client's wait for the answer (SUBMIT_TIMEOUT_S) runs out as the admission begins, with no time
    spent waiting for it: the submission goes out on a socket of its own, which is closed (the client
    leaves) once the daemon is admitting the campaign, and the client's HTTP layer then raises the
    time-out it would have raised (httpx's ReadTimeout)."""
    import socket
    import threading

    import httpx

    import gonio.daemon.client as client
    from gonio.daemon.queue import CampaignQueue

    release, admitting = threading.Event(), threading.Event()
    real, real_send = CampaignQueue.admit, httpx.Client.send

    def admit(self, *args, **kw):
        admitting.set()
        assert release.wait(30.0), "the test never released the admission"
        return real(self, *args, **kw)

    def send(self, request, **kw):
        if request.method != "POST" or request.url.path != "/campaigns":
            return real_send(self, request, **kw)
        assert request.extensions["timeout"]["read"] == client.SUBMIT_TIMEOUT_S   # the wait that runs out
        head = f"POST {request.url.raw_path.decode()} HTTP/1.1\r\n"
        head += "".join(f"{k}: {v}\r\n" for k, v in request.headers.items()) + "\r\n"
        with socket.create_connection((request.url.host, request.url.port), timeout=WAIT_S) as sock:
            sock.sendall(head.encode() + request.read())
            assert admitting.wait(WAIT_S), "the daemon never began to admit the campaign"
        raise httpx.ReadTimeout("timed out", request=request)

    monkeypatch.setattr(CampaignQueue, "admit", admit)
    monkeypatch.setattr(httpx.Client, "send", send)
    monkeypatch.setattr(client, "FIND_POLL_S", 0.01)
    yield release
    release.set()


def test_a_submission_waits_longer_than_the_daemon_may_plan():
    from gonio.daemon.client import SUBMIT_TIMEOUT_S
    from gonio.daemon.planner import PLAN_TIMEOUT_S, WALL_FACTOR

    assert SUBMIT_TIMEOUT_S > PLAN_TIMEOUT_S * WALL_FACTOR


def test_submit_watch_under_load_finds_the_campaign_the_daemon_accepted(serve, env, slow_admission,
                                                                         monkeypatch, capsys):
    """It said 'did not answer in time' and exited 3 (no daemon) while the daemon went on to accept the
    campaign: a user resubmitted and got a duplicate."""
    from gonio.daemon.client import Client

    r = serve()
    env(r.url)
    real, calls = Client.campaigns, []

    def campaigns(self):
        calls.append(1)
        if len(calls) == 2:          # the client has given up on the answer and looks in the queue
            slow_admission.set()
        return real(self)

    monkeypatch.setattr(Client, "campaigns", campaigns)
    assert main(["submit", "lambert:albedo=0.5", "--grid", "iso:step=30", "--seed", "3", "--watch"]) == 0
    out = capsys.readouterr()
    assert out.out.strip() == "c00001"
    assert "slow to answer but accepted the campaign: it is c00001" in out.err
    assert "campaign c00001: done" in out.err
    assert [st["id"] for st in r.client.get("/campaigns").json()["campaigns"]] == ["c00001"]


def test_a_submission_still_unanswered_says_not_to_submit_again(serve, env, slow_admission, monkeypatch,
                                                                capsys):
    import gonio.daemon.client as client

    monkeypatch.setattr(client, "FIND_S", 0.2)
    r = serve()
    env(r.url)
    assert main(["submit", "lambert:albedo=0.5", "--grid", "iso:step=30"]) == 4
    err = capsys.readouterr().err.strip()
    assert "may still accept it" in err and "gonio queue" in err and "no gonio daemon" not in err
    assert "\n" not in err
    slow_admission.set()              # and the daemon does accept it, once
    wait_for(lambda: r.client.get("/campaigns").json()["campaigns"], "the campaign in the queue")


def test_watch_after_the_daemon_accepted_says_so_when_it_loses_the_daemon(serve, env, monkeypatch, capsys):
    from gonio.daemon.client import Client, ClientError

    r = serve()
    env(r.url)

    def events(self, cid, last_event_id=None):
        raise ClientError(f"lost the daemon at {self.url} (ReadError); run the same command to watch again",
                          code=3)
        yield   # a generator, as the real one

    monkeypatch.setattr(Client, "events", events)
    assert main(["submit", "lambert:albedo=0.5", "--grid", "iso:step=30", "--watch"]) == 4
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "campaign c00001 was accepted" in err and "gonio watch c00001" in err and "do not submit" in err


def test_watch_ends_when_the_daemon_cannot_run_the_campaign(serve, env, capsys, monkeypatch):
    """A campaign the daemon could not run is `failed` until an operator resumes it, and its journal says
    nothing of it: `gonio submit --watch` waited on its event stream for ever (seen when a reader's lock
    probe met the worker's lock)."""
    import threading

    import gonio.daemon.queue
    from gonio.store import JournalError

    def held(folder, **kw):
        raise JournalError(f"{folder}: another gonio process (pid 1) is running this campaign")
    monkeypatch.setattr(gonio.daemon.queue, "open_campaign", held)
    r = serve()
    env(r.url)
    codes = []
    watcher = threading.Thread(target=lambda: codes.append(
        main(["submit", "lambert:albedo=0.5", "--grid", "iso:step=30", "--watch"])), daemon=True)
    watcher.start()
    watcher.join(WAIT_S)
    assert codes == [1], "gonio submit --watch did not end"
    err = capsys.readouterr().err
    assert "c00001: failed: the daemon could not run it: JournalError: " in err
    assert "another gonio process (pid 1) is running this campaign; a resume tries again" in err
    assert err.rstrip().endswith("campaign c00001: failed (`gonio resume c00001` tries again)")
