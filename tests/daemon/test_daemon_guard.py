"""What a request must be before a route sees it, on the wire (raw sockets where a client library would
tidy the request up): the daemon's own Host names and --allow-host, JSON-only writes, and connections
that stall in their head or body are closed instead of held forever."""

from __future__ import annotations

import socket
import time

import pytest
from daemon_helpers import WAIT_S, http_client
from side_by_side import side_by_side

from gonio.daemon.guard import HostNames, parse_allow_host


def _raw(url: str, data: bytes, *, read_s: float = WAIT_S) -> tuple[bytes, float]:
    """Send ``data`` on a fresh connection; (everything the daemon sent until it closed, seconds taken)."""
    host, port = url.removeprefix("http://").rsplit(":", 1)
    t0 = time.monotonic()
    with socket.create_connection((host, int(port)), timeout=read_s) as s:
        s.sendall(data)
        out = b""
        while chunk := s.recv(65536):
            out += chunk
    return out, time.monotonic() - t0


def test_only_the_daemons_own_names_are_answered(serve):
    r = serve(allow_hosts=("gantry.lab", "proxy.lab:8443"))
    port = r.url.rsplit(":", 1)[1]
    ok = [f"127.0.0.1:{port}", f"localhost:{port}", f"LOCALHOST:{port}", f"[::1]:{port}",
          f"gantry.lab:{port}", "proxy.lab:8443"]
    bad = ["evil.test", f"evil.test:{port}", "127.0.0.1", f"127.0.0.1:{int(port) + 1}", "gantry.lab",
           f"gantry.lab.evil.test:{port}", f"127.0.0.1:{port}@evil", ""]
    with http_client(r.url) as c:
        for host in ok:
            assert c.get("/health", headers={"Host": host}).status_code == 200, host
        for host in bad:
            resp = c.get("/health", headers={"Host": host})
            assert resp.status_code == 403, host
            assert "is not one of this daemon's names; add it with gonio serve --allow-host" in \
                resp.json()["detail"]
    out, _ = _raw(r.url, b"GET /health HTTP/1.0\r\n\r\n")            # HTTP/1.0 sends no Host at all
    assert out.startswith(b"HTTP/1.1 403")


def test_host_names_and_allow_host_values():
    h = HostNames(("Gantry.Lab",))
    assert not h.accepts("localhost:8765")          # no port known yet: nothing is accepted
    h.listen("0.0.0.0", 8765)
    assert h.accepts("gantry.lab:8765") and h.accepts("localhost:8765") and not h.accepts("0.0.0.0:8765")
    h.listen("192.0.2.7", 80)
    assert h.accepts("192.0.2.7") and h.accepts("192.0.2.7:80") and h.accepts("localhost")
    assert h.accepts("localhost", default_port=80) and not h.accepts("localhost", default_port=443)
    for bad in ("http://x", "a/b", "x:0", "x:99999", "", "-x", "a b"):
        with pytest.raises(ValueError, match="--allow-host: expected NAME or NAME:PORT"):
            parse_allow_host(bad)


@pytest.mark.parametrize(("headers", "status"), [
    ({"Origin": "http://evil.test"}, 403),
    ({"Origin": "null"}, 403),
    ({"Sec-Fetch-Site": "cross-site"}, 403),
    ({"Sec-Fetch-Site": "same-site"}, 403),
    ({"Content-Type": "text/plain"}, 415),
    ({"Content-Type": "application/x-www-form-urlencoded"}, 415),
    ({"Content-Type": "multipart/form-data; boundary=x"}, 415),
    ({"Content-Type": "application/json", "Sec-Fetch-Site": "same-origin"}, 201),
    ({"Content-Type": "application/json; charset=utf-8", "Sec-Fetch-Site": "none"}, 201),
])
def test_writes_from_other_origins_and_bodies_that_are_not_json_are_refused(serve, headers, status):
    r = serve()
    port = r.url.rsplit(":", 1)[1]
    body = b'{"material": "lambert:albedo=0.5", "grid": "iso:step=30"}'
    if "Origin" not in headers and status == 201:
        headers = {**headers, "Origin": f"http://127.0.0.1:{port}"}      # the daemon's own page
    resp = r.client.post("/campaigns", content=body, headers=headers)
    assert resp.status_code == status, resp.text
    assert len(r.daemon.queue.records()) == (status == 201)


def test_a_body_that_never_arrives_is_answered_408_and_its_connection_closed(serve):
    r = serve(body_timeout_s=0.5)
    host = r.url.removeprefix("http://")
    head = (f"POST /campaigns HTTP/1.1\r\nHost: {host}\r\nContent-Type: application/json\r\n"
            "Content-Length: 200\r\n\r\n").encode()
    out, took = _raw(r.url, head + b'{"grid": ')                       # 9 of the 200 bytes promised
    assert out.startswith(b"HTTP/1.1 408") and b"did not arrive within 0.5 s" in out
    assert b"connection: close" in out.lower() and took < 5.0          # closed by the daemon
    assert r.daemon.queue.records() == []


def test_a_head_that_trickles_in_is_cut_off(serve):
    r = serve(head_timeout_s=0.5)
    host, port = r.url.removeprefix("http://").rsplit(":", 1)

    def trickle():
        t0 = time.monotonic()
        with socket.create_connection((host, int(port)), timeout=WAIT_S) as s:
            s.sendall(b"GET /health HTTP/1.1\r\n")
            for _ in range(50):                 # a header line every 0.1 s, never the blank line
                try:
                    s.sendall(b"X-Slow: 1\r\n")
                    if s.recv(1, socket.MSG_DONTWAIT) == b"":
                        return time.monotonic() - t0
                except BlockingIOError:
                    pass
                except OSError:
                    return time.monotonic() - t0
                time.sleep(0.1)
        return None

    # A connection that says nothing is closed too (its wait beside the trickle's: each its own connection).
    got = side_by_side({"trickle": trickle, "silent": lambda: _raw(r.url, b"")})
    closed = got["trickle"]
    assert closed is not None and 0.4 < closed < 3.0, closed
    out, took = got["silent"]
    assert out == b"" and took < 3.0
    # One that asks in time is answered.
    out, _ = _raw(r.url, f"GET /health HTTP/1.1\r\nHost: {host}:{port}\r\nConnection: close\r\n\r\n".encode())
    assert out.startswith(b"HTTP/1.1 200")


def test_a_head_that_grows_past_16_kib_is_refused(serve):
    r = serve()
    host = r.url.removeprefix("http://")
    out, took = _raw(r.url, f"GET /health HTTP/1.1\r\nHost: {host}\r\nX-Big: {'a' * 20000}".encode())
    assert out.startswith(b"HTTP/1.1 400") and took < 5.0      # not buffered on and on
