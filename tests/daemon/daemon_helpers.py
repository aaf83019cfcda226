"""Helpers of the daemon's tests: bounded waits, submitting a campaign (a module of its own: every test
folder has a ``conftest``, so tests import these by this unique name)."""

from __future__ import annotations

import time

import httpx
import pytest

#: Upper bound for every wait in these tests (a campaign of a few dozen steps takes well under it).
WAIT_S = 60.0
TOKEN = "s3cret-token-of-the-lab"


def wait_for(predicate, what: str, timeout_s: float = WAIT_S, poll_s: float = 0.01):
    """Poll ``predicate`` until it returns something truthy (returned), or fail after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(poll_s)


def wait_state(client: httpx.Client, cid: str, states, timeout_s: float = WAIT_S) -> dict:
    states = {states} if isinstance(states, str) else set(states)

    def check():
        st = client.get(f"/campaigns/{cid}").json()
        return st if st["state"] in states else None

    return wait_for(check, f"campaign {cid} to be {sorted(states)}", timeout_s)


def submit(client: httpx.Client, grid: str = "iso:step=30", material: str = "lambert:albedo=0.5",
           **extra) -> dict:
    r = client.post("/campaigns", json={"material": material, "grid": grid, **extra})
    assert r.status_code == 201, r.text
    return r.json()
