"""A campaign's event stream (server-sent events), read from its journal.

Every client reads the journal through its own read-only connection (WAL: a reader never blocks the
runner's commits, and a slow client only delays itself). The stream merges two append-only sequences
in commit order:

``measurement``
    each committed measurement, once and in step order, with the progress it makes (``done``/``steps``);
``state``, ``fault``, ``log``
    the journal's events (``log`` carries the others: pause, halt, park, retry, signal, ...).

The SSE ``id`` of each message is the cursor ``E-M``: the last journal event id and the number of
measurements sent. A client that reconnects with ``Last-Event-ID`` continues exactly after it. When the
campaign is done (brdf.h5 written) or aborted and everything is sent, an ``end`` message closes the
stream. A comment line every ``HEARTBEAT_S`` keeps proxies from closing an idle stream.
"""

from __future__ import annotations

import asyncio
import json
import re
import time
from collections.abc import AsyncIterator

from gonio.plan.schedule import STEP_DARK, STEP_POSE, STEP_REFERENCE

__all__ = ["stream", "parse_cursor", "StreamLimit"]

POLL_S = 0.05
HEARTBEAT_S = 15.0
BATCH = 500
KIND_NAMES = {STEP_POSE: "pose", STEP_DARK: "dark", STEP_REFERENCE: "reference"}
_CURSOR = re.compile(r"^([0-9]{1,12})-([0-9]{1,9})$")


class StreamLimit:
    """At most ``limit`` streams open at once (each holds a journal connection and a task)."""

    def __init__(self, limit: int):
        self.limit = limit
        self.open = 0

    def acquire(self) -> bool:
        if self.open >= self.limit:
            return False
        self.open += 1
        return True

    def release(self) -> None:
        self.open -= 1


def parse_cursor(text: str | None) -> tuple[int, int]:
    """``Last-Event-ID`` as (event id, measurements sent); (0, 0) when absent. ValueError when malformed."""
    if not text:
        return 0, 0
    m = _CURSOR.match(text.strip())
    if m is None:
        raise ValueError(f"Last-Event-ID: expected 'E-M' (two integers, as sent in the stream's ids), "
                         f"got {text[:40]!r}")
    return int(m.group(1)), int(m.group(2))


def _sse(kind: str, cursor: tuple[int, int], data: dict) -> str:
    return f"id: {cursor[0]}-{cursor[1]}\nevent: {kind}\ndata: {json.dumps(data, separators=(',', ':'))}\n\n"


def _measurement(m: dict, steps: int) -> dict:
    names = ("theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg")
    return {"step": m["step"], "kind": KIND_NAMES.get(m["kind"], str(m["kind"])), "pose": m["pose"],
            **{k: m[k] for k in names}, "actual_deg": m["actual_deg"], "signal": m["signal"],
            "stderr": m["stderr"], "exposure_s": m["exposure_s"], "frames": m["frames"],
            "campaign_s": m["campaign_s"], "wall_s": m["wall_s"], "attempts": m["attempts"],
            "done": m["step"] + 1, "steps": steps}


def _event(e: dict) -> tuple[str, dict]:
    kind = e["kind"] if e["kind"] in ("state", "fault") else "log"
    return kind, {"id": e["id"], "kind": e["kind"], "state": e["state"], "step": e["step"],
                  "message": e["message"], "campaign_s": e["campaign_s"], "wall_s": e["wall_s"],
                  "axes_deg": e["axes_deg"]}


def _read(journal, cursor: tuple[int, int]) -> list[tuple[str, dict, tuple[int, int]]]:
    """The next messages after ``cursor``, merged by commit time (runs in a worker thread)."""
    e_id, m_next = cursor
    ms = journal.measurement_rows(m_next, BATCH)
    es = journal.events(e_id, BATCH)
    # A full batch may have more behind it: send only what is certainly before the next batch.
    horizon = min([x[-1]["wall_s"] for x in (ms, es) if len(x) == BATCH], default=float("inf"))
    merged = sorted([(m["wall_s"], 1, m["step"], "m", m) for m in ms]
                    + [(e["wall_s"], 0, e["id"], "e", e) for e in es], key=lambda t: t[:3])
    steps = journal.step_count() if ms else 0
    out = []
    for wall, _, _, what, item in merged:
        if wall > horizon:
            break
        if what == "m":
            if item["step"] != m_next:  # measurements form a prefix of the plan; never skip one
                break
            m_next += 1
            out.append(("measurement", _measurement(item, steps), (e_id, m_next)))
        else:
            e_id = item["id"]
            kind, data = _event(item)
            out.append((kind, data, (e_id, m_next)))
    return out


async def stream(queue, rec, cursor: tuple[int, int], limit: StreamLimit,
                 is_disconnected) -> AsyncIterator[str]:
    """The SSE text of campaign ``rec`` from ``cursor`` on, until it ends, the client leaves or the daemon
    stops. ``limit`` was acquired by the caller and is released here."""
    journal = None
    try:
        journal = await asyncio.to_thread(queue.journal, rec)
        yield "retry: 1000\n\n"
        last_sent = time.monotonic()
        failed = None   # the error last said: a failure is the daemon's, not in the journal
        while not queue.stopping:
            batch = await asyncio.to_thread(_read, journal, cursor)
            for kind, data, cursor in batch:
                yield _sse(kind, cursor, data)
            if batch:
                last_sent = time.monotonic()
                continue
            state = await asyncio.to_thread(queue.state, rec)
            if state == "failed" and rec.error != failed:
                # The daemon could not run it (its journal says nothing of that): said once per failure,
                # and the stream stays open, since a resume tries again.
                failed = rec.error
                yield _sse("state", cursor, {"id": None, "kind": "state", "state": "failed", "step": None,
                                             "message": f"the daemon could not run it: {rec.error}; a "
                                                        "resume tries again", "campaign_s": None,
                                             "wall_s": time.time(), "axes_deg": None})
                last_sent = time.monotonic()
                continue
            if state != "failed":
                failed = None
            if state in ("done", "aborted"):
                # Everything committed before the final state is sent: one more read settles it.
                tail = await asyncio.to_thread(_read, journal, cursor)
                for kind, data, cursor in tail:
                    yield _sse(kind, cursor, data)
                if not tail:
                    yield _sse("end", cursor, {"state": state, "id": rec.id})
                    return
                continue
            if await is_disconnected():
                return
            if time.monotonic() - last_sent > HEARTBEAT_S:
                yield ": keep-alive\n\n"
                last_sent = time.monotonic()
            await asyncio.sleep(POLL_S)
    finally:
        limit.release()
        if journal is not None:
            journal.close()
