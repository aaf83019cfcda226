"""The daemon's HTTP API (FastAPI): the gantry, the campaign queue, event streams, the web view.

Campaigns are named by id only; files are produced inside the data folder and served from there, so no
request can name a path. Handlers that read journals are plain functions (FastAPI runs them in its
thread pool, off the event loop); every read uses its own read-only journal connection. Errors:
422 names the field (``detail[0].loc``), 409 a request the current state refuses, 401 a write without
the token, 404 an unknown campaign, 413 a body over the bound, 503 too many event streams.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from importlib.resources import files
from typing import Annotated

from fastapi import Depends, FastAPI, Header, HTTPException, Path, Query, Request
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse, Response, StreamingResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from gonio.config import GonioConfig
from gonio.daemon import events
from gonio.daemon.auth import BodyLimit, token_ok
from gonio.daemon.gantry import GantryOwner, snapshot
from gonio.daemon.models import (
    Accepted,
    CampaignList,
    CampaignRequest,
    CampaignStatus,
    GantryStatus,
    Health,
    MoveRequest,
)
from gonio.daemon.queue import CampaignQueue
from gonio.daemon.records import ID_PATTERN, Conflict, FieldError, NotFound
from gonio.dataset import BRDF_NAME
from gonio.protocols import DeviceFault
from gonio.store import JournalError

__all__ = ["Daemon", "create_app"]

log = logging.getLogger(__name__)

#: The web view's files (package data), served by fixed names only.
STATIC = {"app.js": "text/javascript", "style.css": "text/css"}


@dataclass
class Daemon:
    """Everything the routes use: the queue, the idle gantry, the token and the stream bound."""

    cfg: GonioConfig
    queue: CampaignQueue
    gantry: GantryOwner
    token: str | None = None
    streams: events.StreamLimit = field(default_factory=lambda: events.StreamLimit(16))
    version: str = "0"


_bearer = HTTPBearer(auto_error=False, description="the daemon's token (GONIO_TOKEN), for every write")
Bearer = Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]
CampaignId = Annotated[str, Path(pattern=ID_PATTERN, description="campaign id, e.g. c00001")]


def _field_error(err: FieldError) -> JSONResponse:
    loc = ["body", *err.field.split(".")]
    return JSONResponse(status_code=422, content={"detail": [
        {"loc": loc, "msg": f"{err.field}: {err}", "type": "value_error"}]})


def create_app(d: Daemon) -> FastAPI:
    """The FastAPI application serving daemon ``d`` (wrapped in the body-size bound)."""
    app = FastAPI(title="gonio daemon", version=d.version,
                  description="Control and acquisition for a gonio-reflectometer: one gantry, a queue of "
                              "campaigns, live event streams. Writes need the bearer token when one is set.")

    def write(request: Request, cred: Bearer) -> None:
        header = request.headers.get("authorization")
        if not token_ok(d.token, header):
            raise HTTPException(401, "this daemon needs its token for every write: send 'Authorization: "
                                "Bearer <token>' (GONIO_TOKEN)", headers={"WWW-Authenticate": "Bearer"})

    @app.exception_handler(FieldError)
    async def _on_field(request, err: FieldError):
        return _field_error(err)

    @app.exception_handler(Conflict)
    async def _on_conflict(request, err: Conflict):
        return JSONResponse(status_code=409, content={"detail": str(err)})

    @app.exception_handler(NotFound)
    async def _on_missing(request, err: NotFound):
        return JSONResponse(status_code=404, content={"detail": str(err)})

    @app.exception_handler(JournalError)
    async def _on_journal(request, err: JournalError):
        return JSONResponse(status_code=409, content={"detail": str(err)})

    @app.exception_handler(DeviceFault)
    async def _on_device(request, err: DeviceFault):
        return JSONResponse(status_code=409, content={"detail": f"gantry: {err}"})

    # -- the web view -----------------------------------------------------------------------------
    web = files("gonio.daemon") / "static"

    @app.get("/", response_class=HTMLResponse, include_in_schema=False)
    def index():
        return HTMLResponse((web / "index.html").read_text())

    @app.get("/static/{name}", include_in_schema=False)
    def static(name: str):
        if name not in STATIC:
            raise HTTPException(404, f"static/{name}: no such file")
        return Response((web / name).read_text(), media_type=STATIC[name])

    # -- health and the gantry --------------------------------------------------------------------
    # Status reads are cheap (no journal read on most calls: see CampaignQueue.status), so they run on
    # the event loop, without a hop through the thread pool.
    @app.get("/health", response_model=Health)
    async def health():
        current = d.queue.current
        return {"status": "ok", "version": d.version, "gantry": d.cfg.name,
                "running": current.id if current else None, "queued": d.queue.queued(), "auth": bool(d.token)}

    @app.get("/gantry", response_model=GantryStatus)
    def gantry_status():
        q = d.queue
        with q._cond:
            g, rec = q.gantry, q.current
        if g is not None and rec is not None:
            return snapshot(g, rec.id, d.cfg)
        return d.gantry.status()

    def _idle_only() -> None:
        if d.queue.current is not None:
            raise Conflict(f"campaign '{d.queue.current.id}' owns the gantry; pause it first")

    @app.post("/gantry/home", response_model=GantryStatus, dependencies=[Depends(write)])
    def gantry_home():
        _idle_only()
        return d.gantry.move(None)

    @app.post("/gantry/move", response_model=GantryStatus, dependencies=[Depends(write)])
    def gantry_move(body: MoveRequest):
        _idle_only()
        return d.gantry.move(body.model_dump())

    @app.post("/gantry/halt", response_model=Accepted, dependencies=[Depends(write)])
    def gantry_halt():
        cid = d.queue.halt()
        d.gantry.halt()
        return {"id": cid, "state": "halted",
                "message": f"halt: campaign '{cid}' stops mid-move and is held" if cid else
                "halt: every axis stopped"}

    # -- campaigns --------------------------------------------------------------------------------
    @app.post("/campaigns", status_code=201, response_model=CampaignStatus, dependencies=[Depends(write)])
    def submit(body: CampaignRequest):
        rec = d.queue.submit(body.model_dump(exclude_none=True))
        return d.queue.status(rec)

    @app.get("/campaigns", response_model=CampaignList)
    def campaigns():
        q = d.queue
        return {"running": q.current.id if q.current else None,
                "campaigns": [q.status(r) for r in q.records() if (r.folder / "campaign.sqlite").is_file()]}

    @app.get("/campaigns/{cid}", response_model=CampaignStatus)
    async def campaign(cid: CampaignId):
        return d.queue.status(d.queue.get(cid))

    @app.post("/campaigns/{cid}/pause", response_model=Accepted, dependencies=[Depends(write)])
    def pause(cid: CampaignId):
        d.queue.pause(cid)
        return {"id": cid, "state": d.queue.state(d.queue.get(cid)),
                "message": "pausing: the step in flight finishes, then the gantry parks"}

    @app.post("/campaigns/{cid}/resume", response_model=Accepted, dependencies=[Depends(write)])
    def resume(cid: CampaignId, clear_fault: bool = Query(False, description="clear a latched fault")):
        d.queue.resume(cid, clear_fault)
        return {"id": cid, "state": d.queue.state(d.queue.get(cid)), "message": "resumed: runs when its turn "
                "in the queue comes"}

    @app.post("/campaigns/{cid}/abort", response_model=Accepted, dependencies=[Depends(write)])
    def abort(cid: CampaignId):
        d.queue.abort(cid)
        return {"id": cid, "state": d.queue.state(d.queue.get(cid)), "message": "aborting"}

    @app.get("/campaigns/{cid}/log")
    def campaign_log(cid: CampaignId, after: int = Query(0, ge=0, le=2**62),
                     limit: int = Query(1000, ge=1, le=10000)) -> list[dict]:
        """The campaign's journal events (state changes, faults, pauses, halts, parks), oldest first."""
        j = d.queue.journal(d.queue.get(cid))
        try:
            return j.events(after, limit)
        finally:
            j.close()

    @app.get("/campaigns/{cid}/events", response_class=StreamingResponse,
             responses={200: {"content": {"text/event-stream": {}},
                              "description": "server-sent events: measurement, state, fault, log, end"}})
    async def campaign_events(request: Request, cid: CampaignId,
                              last_event_id: str | None = Header(None, max_length=40)):
        rec = d.queue.get(cid)
        try:
            cursor = events.parse_cursor(last_event_id)
        except ValueError as err:
            raise FieldError("Last-Event-ID", str(err).removeprefix("Last-Event-ID: ")) from None
        if not d.streams.acquire():
            raise HTTPException(503, f"too many event streams open (at most {d.streams.limit}); retry later",
                                headers={"Retry-After": "5"})
        gen = events.stream(d.queue, rec, cursor, d.streams, request.is_disconnected)
        return StreamingResponse(gen, media_type="text/event-stream",
                                 headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})

    @app.get("/campaigns/{cid}/brdf", response_class=FileResponse,
             responses={200: {"content": {"application/x-hdf5": {}}, "description": "brdf.h5"}})
    def brdf(cid: CampaignId):
        rec = d.queue.get(cid)
        path = rec.folder / BRDF_NAME
        if not path.is_file():
            raise Conflict(f"campaign '{cid}' is {d.queue.state(rec)}: brdf.h5 is written once every step is "
                           "measured")
        return FileResponse(path, media_type="application/x-hdf5", filename=f"{cid}-brdf.h5")

    return app


def asgi(d: Daemon):
    """The application as served: :func:`create_app` behind the request-body bound."""
    return BodyLimit(create_app(d))
