"""What a request must be before the daemon's routes see it (an ASGI middleware, :class:`Guard`).

A web page in the operator's browser must not be able to drive the gantry, and a client that stalls or
sends nonsense must cost the daemon nothing. In order, for every request:

1. **Host** is one of the daemon's own names (:class:`HostNames`: ``localhost``, ``127.0.0.1`` and
   ``[::1]`` with its port, the address it listens on, and the names given with ``--allow-host``),
   else 403. A page on a name that an attacker re-binds to 127.0.0.1 (DNS rebinding) is same-origin
   with itself, not with the daemon: this is what keeps it from reading or writing anything.
2. A **write** (any method but GET, HEAD, OPTIONS) that a browser sends from another origin is refused
   (403): ``Sec-Fetch-Site`` must be ``same-origin`` or ``none`` when present, and ``Origin`` one of
   the daemon's names when present. Tools (the CLI, curl, httpx) send neither and pass.
3. A write's **body** is JSON (``Content-Type: application/json``), else 415: a cross-site form can send
   only form encodings and text/plain. Every body is bounded (:data:`MAX_BODY_BYTES`, 413) and must
   arrive within ``body_timeout_s`` (408 and the connection closed). A write's body that is not UTF-8
   JSON, holds NaN or ±Infinity (which Python reads but JSON does not have) or nests past any sense is
   422 before a route parses it.

Every refusal is one JSON line ``{"detail": ...}``. The time a request's head may take is bounded by
the server (:mod:`gonio.daemon.server`).
"""

from __future__ import annotations

import asyncio
import json
import re
import time
from dataclasses import dataclass, field

__all__ = ["Guard", "HostNames", "MAX_BODY_BYTES", "BODY_TIMEOUT_S", "parse_allow_host"]

MAX_BODY_BYTES = 16 * 1024
#: Seconds a request's whole body may take to arrive.
BODY_TIMEOUT_S = 10.0
SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})
_LOOPBACK_NAMES = ("localhost", "127.0.0.1", "[::1]")
_WILDCARDS = ("0.0.0.0", "::", "[::]", "")
_HOST = re.compile(r"^(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9](?:[A-Za-z0-9.-]{0,252}))(?::([0-9]{1,5}))?$")


def parse_allow_host(text: str) -> str:
    """One ``--allow-host`` value (``NAME`` or ``NAME:PORT``, NAME a host name or an IP literal, IPv6 in
    brackets), lower-cased; ValueError naming the option otherwise."""
    m = _HOST.match(text.strip())
    if m is None or (m.group(2) is not None and not 0 < int(m.group(2)) < 65536):
        raise ValueError(f"--allow-host: expected NAME or NAME:PORT (a host name, an IPv4 address or an IPv6 "
                         f"address in brackets), got {text!r}")
    return text.strip().lower()


@dataclass
class HostNames:
    """The names this daemon answers to: loopback names and ``bind`` with ``port``, and ``extra``
    (``--allow-host``; one without a port takes the daemon's)."""

    extra: tuple[str, ...] = ()
    bind: str | None = None
    port: int | None = None
    _allowed: frozenset = field(default=frozenset(), init=False, repr=False)

    def __post_init__(self):
        self.extra = tuple(parse_allow_host(h) for h in self.extra)
        self._update()

    def listen(self, bind: str, port: int) -> None:
        """Where the daemon listens, once its socket is bound (port 0 becomes the real port)."""
        self.bind, self.port = bind, port
        self._update()

    def _update(self) -> None:
        names = set(_LOOPBACK_NAMES)
        if self.bind is not None and self.bind not in _WILDCARDS:
            names.add(f"[{self.bind}]" if ":" in self.bind else self.bind.lower())
        allowed = set()
        for name in (*names, *self.extra):
            if _HOST.match(name).group(2) is not None:
                allowed.add(name)
            elif self.port is not None:
                allowed.add(f"{name}:{self.port}")
        self._allowed = frozenset(allowed)

    def accepts(self, host: str | None, default_port: int = 80) -> bool:
        """True when ``host`` (a Host header, or an origin's host; without a port, its scheme's default)
        names this daemon."""
        m = _HOST.match((host or "").strip().lower())
        if m is None:
            return False
        return f"{m.group(1)}:{m.group(2) or default_port}" in self._allowed


def _origin_host(origin: str) -> tuple[str, int] | None:
    scheme, sep, rest = origin.partition("://")
    if not sep or scheme not in ("http", "https") or "/" in rest:
        return None
    return rest, 80 if scheme == "http" else 443


class Guard:
    """ASGI middleware that applies the module docstring's rules before ``app`` sees a request."""

    def __init__(self, app, hosts: HostNames, *, limit: int = MAX_BODY_BYTES,
                 body_timeout_s: float = BODY_TIMEOUT_S):
        self.app = app
        self.hosts = hosts
        self.limit = limit
        self.body_timeout_s = body_timeout_s

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        headers: dict[bytes, bytes] = {}
        for k, v in scope.get("headers") or ():
            headers.setdefault(k, v)
        text = {k.decode("latin-1"): v.decode("latin-1") for k, v in headers.items()}
        host = text.get("host")
        if not self.hosts.accepts(host):
            return await _refuse(send, 403, f"Host {str(host)[:100]!r} is not one of this daemon's names; "
                                 "add it with gonio serve --allow-host NAME")
        write = scope["method"] not in SAFE_METHODS
        if write:
            why = self._cross_origin(text)
            if why:
                return await _refuse(send, 403, f"{why}: the daemon takes writes only from its own pages "
                                     "and from tools (gonio, curl)")
        length = text.get("content-length")
        has_body = (length is not None and length != "0") or "transfer-encoding" in text
        if write and has_body:
            ctype = text.get("content-type", "").split(";")[0].strip().lower()
            if ctype != "application/json":
                return await _refuse(send, 415, f"a body of type {ctype or 'none'!r}: the daemon reads "
                                     "JSON only (Content-Type: application/json)")
        if length is not None and (not length.isdigit() or int(length) > self.limit):
            return await _refuse(send, 413, f"request body over {self.limit} bytes")
        body = b""
        if has_body:
            body, status = await self._read(receive)
            if status == 408:
                return await _refuse(send, 408, f"the request body did not arrive within "
                                     f"{self.body_timeout_s:g} s")
            if status == 413:
                return await _refuse(send, 413, f"request body over {self.limit} bytes")
            if status is not None:   # the client went away
                return None
            if write and body:
                why = _json_problem(body)
                if why:
                    return await _refuse(send, 422, why, loc=["body"])
        await self.app(scope, _replay([{"type": "http.request", "body": body, "more_body": False}], receive),
                       send)

    def _cross_origin(self, headers: dict[str, str]) -> str | None:
        site = headers.get("sec-fetch-site")
        if site is not None and site.strip().lower() not in ("same-origin", "none"):
            return f"a write from another site (Sec-Fetch-Site: {site[:40]})"
        origin = headers.get("origin")
        if origin is not None:
            parsed = _origin_host(origin.strip().lower())
            if parsed is None or not self.hosts.accepts(*parsed):
                return f"a write from another origin (Origin: {origin[:100]})"
        return None

    async def _read(self, receive) -> tuple[bytes, int | None]:
        """(body, None), or (b"", status) for a body too slow (408), too large (413) or a client gone (0)."""
        deadline = time.monotonic() + self.body_timeout_s
        chunks, size, more = [], 0, True
        while more:
            try:
                message = await asyncio.wait_for(receive(), max(deadline - time.monotonic(), 0.0))
            except TimeoutError:
                return b"", 408
            if message["type"] != "http.request":
                return b"", 0
            chunk = message.get("body", b"")
            size += len(chunk)
            if size > self.limit:
                return b"", 413
            chunks.append(chunk)
            more = message.get("more_body", False)
        return b"".join(chunks), None


def _no_constant(name: str):
    raise ValueError(name)


class _DuplicateKey(ValueError):
    pass


def _unique_keys(pairs: list) -> dict:
    seen = {}
    for key, value in pairs:
        if key in seen:
            raise _DuplicateKey(key)
        seen[key] = value
    return seen


def _json_problem(body: bytes) -> str | None:
    """Why a JSON body is refused before a route parses it (not UTF-8, not JSON, NaN or ±Infinity, a key
    given twice in one object, nested past sense), or None."""
    try:
        json.loads(body.decode("utf-8"), parse_constant=_no_constant, object_pairs_hook=_unique_keys)
    except UnicodeDecodeError:
        return "body: not UTF-8 text"
    except RecursionError:
        return "body: JSON nested too deeply"
    except json.JSONDecodeError as err:
        return f"body: not JSON ({err})"
    except _DuplicateKey as err:
        # RFC 8259 leaves a repeated name to the reader: one reader (a proxy, a log) may see the first
        # value where the daemon would act on the last.
        return f"body: key {str(err)!r} is given twice in one object; give each once"
    except ValueError as err:
        return (f"body: {err} is not a JSON number (RFC 8259 has no NaN or Infinity); every number must be "
                "finite")
    return None


async def _refuse(send, status: int, detail: str, loc: list | None = None) -> None:
    content = {"detail": [{"loc": loc, "msg": detail, "type": "value_error"}]} if loc else {"detail": detail}
    text = json.dumps(content).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(text)).encode())]
    if status in (408, 413, 415):   # the body was not read: the connection cannot carry another request
        headers.append((b"connection", b"close"))
    await send({"type": "http.response.start", "status": status, "headers": headers})
    await send({"type": "http.response.body", "body": text})


def _replay(messages: list, receive):
    async def inner():
        if messages:
            return messages.pop(0)
        return await receive()
    return inner
