"""Who may do what: the bearer token, the loopback rule, and the rate of failed tokens.

Whenever the daemon has a token, every request that changes anything (every method but GET and HEAD)
must carry ``Authorization: Bearer <token>`` (the scheme in any case, RFC 7235; compared in constant
time with :func:`hmac.compare_digest`) — except the emergency halt from a loopback client, which an
operator at the rig must be able to send without typing a token (``--halt-needs-token`` turns that off).
A token is at least :data:`MIN_TOKEN_CHARS` visible ASCII characters without whitespace (refused at
start otherwise). Reading (status, events, the web view) needs no token: the daemon only listens beyond
loopback with a token set, and what it shows is what an operator standing at the gantry sees.

A client whose token fails :data:`FAILURES_ALLOWED` times within :data:`FAILURE_WINDOW_S` seconds gets
429 for every write until the window has passed, its right token included, so that guessing gains
nothing. What reaches the routes at all (Host, Origin, body) is :mod:`gonio.daemon.guard`'s job.
"""

from __future__ import annotations

import hmac
import ipaddress
import threading
import time
from collections import OrderedDict, deque

__all__ = ["token_ok", "check_token", "is_loopback", "check_bind", "FailedTokens", "MIN_TOKEN_CHARS",
           "FAILURES_ALLOWED", "FAILURE_WINDOW_S"]

MIN_TOKEN_CHARS = 16
#: Failed tokens a client may send per window before its writes are refused (429).
FAILURES_ALLOWED = 20
FAILURE_WINDOW_S = 60.0
#: Clients whose failures are remembered at once (the oldest is forgotten first).
_CLIENTS_KEPT = 4096


def check_token(token: str | None) -> str | None:
    """The token to require, None for none (unset or empty); ValueError naming ``GONIO_TOKEN`` / ``--token``
    for one shorter than :data:`MIN_TOKEN_CHARS` or holding whitespace or characters beyond visible ASCII
    (a bearer token travels in a header as they are).

    Examples
    --------
    >>> check_token("") is None
    True
    >>> check_token("   ")
    Traceback (most recent call last):
    ...
    ValueError: GONIO_TOKEN / --token: a token needs at least 16 characters and no whitespace (got 0 ...
    """
    if token is None or token == "":
        return None
    visible = sum(0x21 <= ord(c) <= 0x7E for c in token)
    if visible != len(token) or len(token) < MIN_TOKEN_CHARS:
        raise ValueError(f"GONIO_TOKEN / --token: a token needs at least {MIN_TOKEN_CHARS} characters and no "
                         f"whitespace (got {visible} other characters); make one with: python -c \"import "
                         "secrets; print(secrets.token_urlsafe(24))\"")
    return token


def token_ok(expected: str | None, authorization: str | None) -> bool:
    """True when no token is set, or ``authorization`` is ``Bearer <expected>`` (the scheme in any case;
    compared in constant time)."""
    if not expected:
        return True
    scheme, _, credentials = (authorization or "").strip().partition(" ")
    if scheme.lower() != "bearer":
        return False
    return hmac.compare_digest(credentials.strip().encode("latin-1", "replace"), expected.encode())


def is_loopback(host: str) -> bool:
    """True for ``localhost`` and loopback addresses (127.0.0.0/8, ::1, IPv4 loopback mapped into IPv6)."""
    if host.lower() == "localhost":
        return True
    try:
        ip = ipaddress.ip_address(host.strip("[]"))
    except ValueError:
        return False
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        ip = ip.ipv4_mapped
    return ip.is_loopback


def check_bind(host: str, token: str | None) -> None:
    """Refuse (ValueError) to listen beyond loopback without a token."""
    if not is_loopback(host) and not token:
        raise ValueError(f"--host: {host} is not a loopback address; the daemon listens there only with a "
                         "token (set GONIO_TOKEN or --token), so that nobody on the network can move the "
                         "gantry")


class FailedTokens:
    """Failed tokens per client address: :meth:`blocked` once a client has failed
    :data:`FAILURES_ALLOWED` times within :data:`FAILURE_WINDOW_S` (seconds until it may try again)."""

    def __init__(self, allowed: int = FAILURES_ALLOWED, window_s: float = FAILURE_WINDOW_S,
                 clock=time.monotonic):
        self.allowed = allowed
        self.window_s = window_s
        self._clock = clock
        self._lock = threading.Lock()
        self._times: OrderedDict[str, deque] = OrderedDict()

    def _recent(self, client: str, now: float) -> deque:
        times = self._times.get(client)
        if times is None:
            return deque()
        while times and now - times[0] >= self.window_s:
            times.popleft()
        return times

    def blocked(self, client: str) -> float:
        """Seconds until ``client`` may send a token again; 0 when it may now."""
        with self._lock:
            now = self._clock()
            times = self._recent(client, now)
            return self.window_s - (now - times[0]) if len(times) >= self.allowed else 0.0

    def failed(self, client: str) -> None:
        with self._lock:
            times = self._recent(client, self._clock())
            times.append(self._clock())
            self._times[client] = times
            self._times.move_to_end(client)
            while len(self._times) > _CLIENTS_KEPT:
                self._times.popitem(last=False)
