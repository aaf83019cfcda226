"""The daemon's client (httpx), behind ``gonio submit|queue|watch|pause|resume|abort|halt|fetch``.

The daemon is found at ``--url`` or ``GONIO_URL`` (default ``http://127.0.0.1:8765``); writes carry
``GONIO_TOKEN`` as a bearer token. Every failure is one line (:class:`ClientError`): the daemon is not
running, it refused (with its own reason), or it answered something unexpected.

A submission the daemon did not answer in time (it plans the campaign before it answers, and a busy
daemon plans slowly) may still be accepted: :meth:`Client.submit` then looks for it in the queue for a
while, and says so (exit code 4, :data:`ACCEPTED_UNKNOWN`) rather than "no daemon", which would invite a
duplicate.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Iterator
from pathlib import Path

import httpx

__all__ = ["Client", "ClientError", "DEFAULT_URL", "iter_sse", "BAD_REQUEST", "NO_DAEMON", "ACCEPTED_UNKNOWN"]

DEFAULT_URL = "http://127.0.0.1:8765"
#: Exit status: the daemon found a field of the request invalid (422, naming it): a mistake in the command
#: line, as every other command's exit status 2.
BAD_REQUEST = 2
#: Exit status: no daemon answered (nothing was sent, or a read that changes nothing went unanswered).
NO_DAEMON = 3
#: Exit status: the daemon accepted the campaign, or may have: do not submit it again, look at the queue.
ACCEPTED_UNKNOWN = 4
#: Seconds a submission waits for its answer: longer than the daemon may plan it (its planner stops after
#: gonio.daemon.planner.PLAN_TIMEOUT_S of CPU time, at most WALL_FACTOR times that of wall time, 600 s),
#: since the daemon drops a submission whose client has gone away.
SUBMIT_TIMEOUT_S = 660.0
#: After a submission went unanswered: how long to look for it in the queue, and how often.
FIND_S = 60.0
FIND_POLL_S = 1.0


class ClientError(RuntimeError):
    """One line for the user; ``code`` is the exit status (1: refused or failed, 2: a field of the request
    is invalid, 3: no daemon, 4: the campaign was or may have been accepted). ``sent``: the request may
    have reached the daemon."""

    def __init__(self, message: str, code: int = 1, sent: bool = True):
        super().__init__(message)
        self.code = code
        self.sent = sent


def _reason(r: httpx.Response) -> str:
    try:
        detail = r.json().get("detail")
    except (ValueError, AttributeError):
        detail = r.text[:200]
    if isinstance(detail, list) and detail and isinstance(detail[0], dict):
        d = detail[0]
        loc = ".".join(str(x) for x in d.get("loc", [])[1:])
        msg = d.get("msg", "")
        detail = msg if msg.startswith(f"{loc}:") or not loc else f"{loc}: {msg}"
    return str(detail)


def _same_campaign(st: dict, request: dict) -> bool:
    """Whether the queue's campaign ``st`` is what ``request`` asked for: the same material (normalized)
    or sample, the same seed, and a grid that spells out to the same one."""
    from gonio.plan import parse_grid

    if int(st.get("seed", -1)) != int(request.get("seed", 0)) or st.get("sample") != request.get("sample"):
        return False
    if request.get("material") is not None:
        from gonio.sim.materials import load

        try:
            if load(request["material"]).spec != st.get("material"):
                return False
        except ValueError:
            return False
    try:
        want, got = parse_grid(request["grid"]), parse_grid(st["grid"])
    except ValueError:
        return False
    fields = ("kind", "step_deg", "stride", "reciprocity", "mirror")
    return (all(getattr(want, f) == getattr(got, f) for f in fields)
            and want.theta_max_deg in (None, got.theta_max_deg) and want.order in ("auto", got.order))


def iter_sse(lines: Iterator[str]) -> Iterator[tuple[str, str | None, str]]:
    """(event, id, data) of each message in a server-sent event stream's lines."""
    event, eid, data = "message", None, []
    for line in lines:
        if line == "":
            if data:
                yield event, eid, "\n".join(data)
            event, data = "message", []
            continue
        if line.startswith(":"):
            continue
        name, _, value = line.partition(":")
        value = value[1:] if value.startswith(" ") else value
        if name == "event":
            event = value
        elif name == "data":
            data.append(value)
        elif name == "id":
            eid = value


class Client:
    """A connection to one daemon.

    Parameters
    ----------
    url : str, optional
        The daemon's base URL (default: ``GONIO_URL``, else ``DEFAULT_URL``).
    token : str, optional
        Bearer token for writes (default: ``GONIO_TOKEN``).
    timeout_s : float
        Seconds to wait for a reply (event streams wait for data indefinitely between messages).
    """

    def __init__(self, url: str | None = None, token: str | None = None, timeout_s: float = 30.0):
        self.url = (url or os.environ.get("GONIO_URL") or DEFAULT_URL).rstrip("/")
        if not self.url.startswith(("http://", "https://")):
            raise ClientError(f"--url: {self.url!r} is not an http:// or https:// URL", code=2)
        try:
            host = httpx.URL(self.url).host
        except httpx.InvalidURL as err:   # "http://[::1", "http://host:port"
            raise ClientError(f"--url: {self.url!r} is not a valid URL ({err})", code=2) from None
        if not host:
            raise ClientError(f"--url: {self.url!r} names no host (e.g. http://127.0.0.1:8765)", code=2)
        token = token if token is not None else os.environ.get("GONIO_TOKEN")
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        # An http:// daemon never speaks TLS (redirects are not followed): no certificate store to load
        # (httpx loads certifi's for every client, ~27 ms of CPU a command).
        self.http = httpx.Client(base_url=self.url, headers=headers, timeout=timeout_s,
                                 verify=self.url.startswith("https://"))

    def close(self) -> None:
        self.http.close()

    def request(self, method: str, path: str, **kw) -> httpx.Response:
        try:
            r = self.http.request(method, path, **kw)
        except (httpx.ConnectError, httpx.ConnectTimeout):
            raise ClientError(f"no gonio daemon at {self.url} (start one with `gonio serve`, or set --url / "
                              "GONIO_URL)", code=NO_DAEMON, sent=False) from None
        except httpx.TimeoutException:
            raise ClientError(f"the daemon at {self.url} did not answer in time", code=NO_DAEMON) from None
        except httpx.HTTPError as err:
            raise ClientError(f"{self.url}: {err}", code=NO_DAEMON) from None
        if r.status_code == 401:
            raise ClientError(f"the daemon at {self.url} refused: it needs its token (set GONIO_TOKEN)")
        if r.status_code >= 400:
            raise ClientError(f"the daemon refused ({r.status_code}): {_reason(r)}",
                              code=BAD_REQUEST if r.status_code == 422 else 1)
        return r

    def get(self, path: str, **kw):
        return self.request("GET", path, **kw).json()

    def post(self, path: str, body: dict | None = None, **kw):
        return self.request("POST", path, json=body, **kw).json()

    def submit(self, request: dict) -> dict:
        """Submit a campaign; its status. When the daemon does not answer in time, the queue is searched
        for the campaign (new since the submission, same material or sample, grid and seed): found, its
        status with ``"found_in_queue": True``; not found, a ClientError with code ACCEPTED_UNKNOWN."""
        before = {st["id"] for st in self.campaigns()["campaigns"]}
        try:
            return self.post("/campaigns", request, timeout=SUBMIT_TIMEOUT_S)
        except ClientError as err:
            if err.code != NO_DAEMON or not err.sent:
                raise
        deadline = time.monotonic() + FIND_S
        while True:
            try:
                found = [st for st in self.campaigns()["campaigns"]
                         if st["id"] not in before and _same_campaign(st, request)]
            except ClientError:
                found = []
            if found:
                return {**found[0], "found_in_queue": True}
            if time.monotonic() >= deadline:
                raise ClientError(f"the daemon at {self.url} did not answer the submission within "
                                  f"{SUBMIT_TIMEOUT_S:g} s, nor show it in its queue within {FIND_S:g} s "
                                  "more; it may still accept it: look with `gonio queue` before submitting "
                                  "again", code=ACCEPTED_UNKNOWN)
            time.sleep(FIND_POLL_S)

    def campaigns(self) -> dict:
        return self.get("/campaigns")

    def campaign(self, cid: str) -> dict:
        return self.get(f"/campaigns/{cid}")

    def action(self, cid: str, what: str, **params) -> dict:
        return self.post(f"/campaigns/{cid}/{what}", params=params or None)

    def halt(self) -> dict:
        return self.post("/gantry/halt")

    def fetch(self, cid: str, out: Path) -> int:
        """Download ``cid``'s brdf.h5 to ``out`` (atomically); bytes written."""
        r = self.request("GET", f"/campaigns/{cid}/brdf")
        tmp = out.with_name(out.name + ".partial")
        tmp.write_bytes(r.content)
        tmp.replace(out)
        return len(r.content)

    def events(self, cid: str, last_event_id: str | None = None) -> Iterator[tuple[str, str | None, dict]]:
        """(event, id, data) of ``cid``'s event stream until its ``end``, reconnecting after a dropped
        connection with ``Last-Event-ID`` (nothing is lost or repeated)."""
        eid = last_event_id
        failures = 0
        while True:
            headers = {"Last-Event-ID": eid} if eid else {}
            try:
                with self.http.stream("GET", f"/campaigns/{cid}/events", headers=headers,
                                      timeout=httpx.Timeout(30.0, read=None)) as r:
                    if r.status_code >= 400:
                        r.read()
                        raise ClientError(f"the daemon refused ({r.status_code}): {_reason(r)}")
                    failures = 0
                    for event, new_id, data in iter_sse(r.iter_lines()):
                        eid = new_id or eid
                        payload = json.loads(data)
                        yield event, eid, payload
                        if event == "end":
                            return
            except (httpx.ConnectError, httpx.RemoteProtocolError, httpx.ReadError) as err:
                failures += 1
                if failures > 3:
                    raise ClientError(f"lost the daemon at {self.url} ({type(err).__name__}); run the same "
                                      "command to watch again", code=3) from None
