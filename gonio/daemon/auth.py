"""Access control and bounds: bearer tokens, the loopback rule, request body size.

Whenever the daemon has a token, every request that changes anything (every method but GET and HEAD)
must carry ``Authorization: Bearer <token>``; tokens are compared in constant time
(:func:`hmac.compare_digest`). Reading (status, events, the web view) needs no token: the daemon only
listens beyond loopback with a token set, and what it shows is what an operator standing at the gantry
sees. Request bodies are bounded (:class:`BodyLimit`) before any handler reads them.
"""

from __future__ import annotations

import hmac
import ipaddress
import json

__all__ = ["token_ok", "is_loopback", "check_bind", "BodyLimit", "MAX_BODY_BYTES"]

MAX_BODY_BYTES = 16 * 1024


def token_ok(expected: str | None, authorization: str | None) -> bool:
    """True when no token is set, or ``authorization`` is ``Bearer <expected>`` (constant time)."""
    if not expected:
        return True
    if not authorization or not authorization.startswith("Bearer "):
        return False
    return hmac.compare_digest(authorization[len("Bearer "):].strip().encode(), expected.encode())


def is_loopback(host: str) -> bool:
    """True for ``localhost`` and loopback addresses (127.0.0.0/8, ::1)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def check_bind(host: str, token: str | None) -> None:
    """Refuse (ValueError) to listen beyond loopback without a token."""
    if not is_loopback(host) and not token:
        raise ValueError(f"--host: {host} is not a loopback address; the daemon listens there only with a "
                         "token (set GONIO_TOKEN or --token), so that nobody on the network can move the "
                         "gantry")


class BodyLimit:
    """ASGI middleware: a request body over ``limit`` bytes is answered 413 before the app sees it."""

    def __init__(self, app, limit: int = MAX_BODY_BYTES):
        self.app = app
        self.limit = limit

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        headers = dict(scope.get("headers") or [])
        length = headers.get(b"content-length")
        if length is not None and (not length.isdigit() or int(length) > self.limit):
            return await self._refuse(send)
        body, more = b"", True
        while more:
            message = await receive()
            if message["type"] != "http.request":
                return await self.app(scope, _replay([message], receive), send)
            body += message.get("body", b"")
            more = message.get("more_body", False)
            if len(body) > self.limit:
                return await self._refuse(send)
        await self.app(scope, _replay([{"type": "http.request", "body": body, "more_body": False}], receive),
                       send)

    async def _refuse(self, send):
        text = json.dumps({"detail": f"request body over {self.limit} bytes"}).encode()
        await send({"type": "http.response.start", "status": 413,
                    "headers": [(b"content-type", b"application/json"),
                                (b"content-length", str(len(text)).encode())]})
        await send({"type": "http.response.body", "body": text})


def _replay(messages: list, receive):
    async def inner():
        if messages:
            return messages.pop(0)
        return await receive()
    return inner
