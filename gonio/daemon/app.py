"""The daemon's HTTP API (FastAPI): the gantry, the campaign queue, event streams, the web view.

Campaigns are named by id only; files are produced inside the data folder and served from there, so no
request can name a path (measured materials are names in ``--materials DIR``). Handlers that read
journals are plain functions (FastAPI runs them in its thread pool, off the event loop); every read uses
its own read-only journal connection. Submitting plans in a worker process (:mod:`gonio.daemon.planner`)
while the event loop only waits, and the emergency halt runs on threads of its own, so no number of
slow requests ahead of it can delay it.

Statuses (each route's OpenAPI entry lists the ones it can return): 401 a write without the token (only
when one is set) and 429 after too many wrong ones (:mod:`gonio.daemon.auth`); 403 a Host that is not
the daemon's or a write from another origin, 408 a body too slow, 413 too large, 415 not JSON, 422 NaN
or Infinity in it (:mod:`gonio.daemon.guard`); 422 a field that is wrong (``detail[0].loc`` names it),
404 an unknown campaign, 409 a request the current state refuses, 503 too many event streams or
requests being planned, 507 a full disk (nothing written).
"""

from __future__ import annotations

import asyncio
import logging
import math
import shutil
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from importlib.resources import files
from typing import Annotated, Any

from fastapi import Depends, FastAPI, Header, HTTPException, Path, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse, Response, StreamingResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from pydantic import BaseModel

from gonio.config import GonioConfig
from gonio.daemon import events
from gonio.daemon.auth import FailedTokens, is_loopback, token_ok
from gonio.daemon.gantry import GantryOwner, snapshot
from gonio.daemon.guard import BODY_TIMEOUT_S, Guard, HostNames
from gonio.daemon.models import (
    Accepted,
    CampaignList,
    CampaignRequest,
    CampaignStatus,
    GantryStatus,
    Health,
    MoveRequest,
)
from gonio.daemon.planner import ClientGone, Planner, PlannerBusy, PlannerFailed
from gonio.daemon.queue import CampaignQueue
from gonio.daemon.records import ID_PATTERN, Conflict, FieldError, NotFound, precheck_request
from gonio.dataset import BRDF_NAME
from gonio.protocols import DeviceFault
from gonio.sim.materials.library import MaterialsFolder
from gonio.store import JournalError, is_disk_full

__all__ = ["Daemon", "create_app", "asgi"]

log = logging.getLogger(__name__)

#: The web view's files (package data), served by fixed names only.
STATIC = {"app.js": "text/javascript", "style.css": "text/css"}


@dataclass
class Daemon:
    """Everything the routes use: the queue, the idle gantry, the planner, the token, the names the
    daemon answers to, and the bounds."""

    cfg: GonioConfig
    queue: CampaignQueue
    gantry: GantryOwner
    planner: Planner
    token: str | None = None
    hosts: HostNames = field(default_factory=HostNames)
    materials: MaterialsFolder = field(default_factory=lambda: MaterialsFolder(None))
    halt_needs_token: bool = False
    streams: events.StreamLimit = field(default_factory=lambda: events.StreamLimit(16))
    failures: FailedTokens = field(default_factory=FailedTokens)
    body_timeout_s: float = BODY_TIMEOUT_S
    version: str = "0"
    #: The halt's own threads: a saturated request pool cannot hold it up.
    halt_pool: ThreadPoolExecutor = field(default_factory=lambda: ThreadPoolExecutor(
        max_workers=4, thread_name_prefix="gonio-halt"))


class Problem(BaseModel):
    """Why a request was refused: a line, or (422) a list naming the field in ``loc``."""

    detail: str | list[dict[str, Any]]


_STATUS = {
    401: "the token is missing or wrong (Authorization: Bearer <token>)",
    403: "a Host that is not one of the daemon's names, or a write from another origin",
    404: "no such campaign",
    408: "the request body did not arrive in time",
    409: "the campaign's or the gantry's state does not allow it now",
    413: "the request body is over 16 KiB",
    415: "a body that is not JSON",
    422: "a field is wrong (detail[0].loc names it), or NaN/Infinity in the body",
    429: "too many wrong tokens from this client: writes refused for a while (Retry-After)",
    500: "the planner failed for a reason that is not the request's (one line)",
    503: "too busy: retry later (Retry-After)",
    507: "the data folder's disk is full: nothing was written",
}


def _docs(*codes: int) -> dict:
    return {c: {"model": Problem, "description": _STATUS[c]} for c in sorted(codes)}


_bearer = HTTPBearer(auto_error=False, description="the daemon's token (GONIO_TOKEN), for writes")
Bearer = Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]
CampaignId = Annotated[str, Path(pattern=ID_PATTERN, description="campaign id, e.g. c00001")]


def _field_error(err: FieldError) -> JSONResponse:
    loc = ["body", *err.field.split(".")]
    return JSONResponse(status_code=422, content={"detail": [
        {"loc": loc, "msg": f"{err.field}: {err}", "type": "value_error"}]})


def _plain(error: dict) -> dict:
    """A validation error without the input it echoes (NaN or Infinity there made the 422 a 500)."""
    return {"loc": [x if isinstance(x, (str, int)) else str(x) for x in error.get("loc", ())],
            "msg": str(error.get("msg", "")), "type": str(error.get("type", "value_error"))}


def create_app(d: Daemon) -> FastAPI:
    """The FastAPI application serving daemon ``d`` (:func:`asgi` puts the guard in front)."""
    app = FastAPI(title="gonio daemon", version=d.version,
                  description="Control and acquisition for a gonio-reflectometer: one gantry, a queue of "
                              "campaigns, live event streams. " + (
                                  "Writes need the bearer token (the halt from loopback excepted)."
                                  if d.token else "This daemon has no token: it listens on loopback only.")
                              + " Writes from another origin, and bodies that are not JSON, are refused.")

    async def write(request: Request, cred: Bearer) -> None:
        client = request.client.host if request.client else "?"
        wait = d.failures.blocked(client)
        if wait:
            raise HTTPException(429, f"too many wrong tokens from {client}: its writes are refused for "
                                f"{math.ceil(wait)} s", headers={"Retry-After": str(math.ceil(wait))})
        if not token_ok(d.token, request.headers.get("authorization")):
            d.failures.failed(client)
            raise HTTPException(401, "this daemon needs its token for every write: send 'Authorization: "
                                "Bearer <token>' (GONIO_TOKEN)", headers={"WWW-Authenticate": "Bearer"})

    async def halt_auth(request: Request) -> None:   # its security is said in halt_security
        if d.halt_needs_token or not (request.client and is_loopback(request.client.host)):
            await write(request, None)

    auth = [Depends(write)] if d.token else []
    auth_codes = (401, 429) if d.token else ()
    reads = (403, 408, 413)                   # the guard's, on every route
    writes = (*reads, 415, 422, *auth_codes)

    @app.exception_handler(RequestValidationError)
    async def _on_invalid(request, err: RequestValidationError):
        return JSONResponse(status_code=422, content={"detail": [_plain(e) for e in err.errors()]})

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

    @app.exception_handler(PlannerBusy)
    async def _on_busy(request, err: PlannerBusy):
        return JSONResponse(status_code=503, content={"detail": str(err)}, headers={"Retry-After": "5"})

    @app.exception_handler(OSError)
    async def _on_os(request, err: OSError):
        if is_disk_full(err):
            return JSONResponse(status_code=507, content={"detail": "the data folder's disk is full; "
                                                          "nothing was written: free some space"})
        log.error("%s %s: %s", request.method, request.url.path, err)
        return JSONResponse(status_code=500, content={"detail": f"{type(err).__name__}: {err}"})

    @app.exception_handler(PlannerFailed)
    async def _on_planner(request, err: PlannerFailed):
        return JSONResponse(status_code=500, content={"detail": f"could not plan the campaign: {err}"})

    @app.exception_handler(ClientGone)
    async def _on_gone(request, err: ClientGone):   # nobody reads it
        return JSONResponse(status_code=400, content={"detail": str(err)})

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
    # Every route that takes the queue's lock is a plain function (run on FastAPI's request threads): the
    # event loop never waits for a lock, so it always takes the next request, the halt among them.
    @app.get("/health", response_model=Health, responses=_docs(*reads))
    def health():
        current = d.queue.current
        return {"status": "ok", "version": d.version, "gantry": d.cfg.name,
                "running": current.id if current else None, "queued": d.queue.queued(), "auth": bool(d.token)}

    @app.get("/gantry", response_model=GantryStatus, responses=_docs(*reads, 409))
    def gantry_status():
        q = d.queue
        g, rec = q.running_gantry()
        if g is not None and rec is not None:
            return snapshot(g, rec.id, d.cfg)
        return d.gantry.status()

    def _idle_only() -> None:
        if d.queue.current is not None:
            raise Conflict(f"campaign '{d.queue.current.id}' owns the gantry; pause it first")

    @app.post("/gantry/home", response_model=GantryStatus, dependencies=auth, responses=_docs(*writes, 409))
    def gantry_home():
        _idle_only()
        return d.gantry.move(None)

    @app.post("/gantry/move", response_model=GantryStatus, dependencies=auth, responses=_docs(*writes, 409))
    def gantry_move(body: MoveRequest):
        _idle_only()
        return d.gantry.move(body.model_dump())

    halt_security = [{"HTTPBearer": []}] + ([{}] if not d.halt_needs_token else [])

    @app.post("/gantry/halt", response_model=Accepted, dependencies=[Depends(halt_auth)] if d.token else [],
              responses=_docs(*writes), openapi_extra={"security": halt_security} if d.token else None,
              description="Emergency stop: every axis stops now, mid-move too; the running campaign is "
              "held. Served on threads of its own. " + ("A loopback client needs no token." if d.token
                                                        and not d.halt_needs_token else ""))
    async def gantry_halt():
        def stop():
            cid = d.queue.halt()
            d.gantry.halt()
            return cid

        cid = await asyncio.get_running_loop().run_in_executor(d.halt_pool, stop)
        return {"id": cid, "state": "halted",
                "message": f"halt: campaign '{cid}' stops mid-move and is held" if cid else
                "halt: every axis stopped"}

    # -- campaigns --------------------------------------------------------------------------------
    def refuse_unreferenced():
        if d.queue.current is None:  # an idle gantry: refused now, nothing written, while not referenced
            from gonio.reference import refusal

            try:
                missing = d.gantry.unreferenced()
            except DeviceFault:
                missing = []  # not reachable now: the run reports it when its turn comes
            if missing:
                raise Conflict(refusal(missing))

    @app.post("/campaigns", status_code=201, response_model=CampaignStatus, dependencies=auth,
              responses=_docs(*writes, 409, 500, 503, 507))
    async def submit(request: Request, body: CampaignRequest):
        req = body.model_dump(exclude_none=True)
        precheck_request(d.cfg, req, d.materials)      # milliseconds: the grid's size, a material's name
        staging = d.queue.staging()

        def admit():
            try:
                refuse_unreferenced()   # reads the axes: on a request thread, not the event loop
                return d.queue.status(d.queue.admit(staging, req))
            finally:
                shutil.rmtree(staging, ignore_errors=True)   # gone when admitted

        try:
            await d.planner.prepare(req, staging, request.is_disconnected)
            if await request.is_disconnected():      # nobody would learn the campaign's id
                raise ClientGone("the client went away")
        except BaseException:
            await run_in_threadpool(shutil.rmtree, staging, True)
            raise
        return await run_in_threadpool(admit)

    @app.get("/campaigns", response_model=CampaignList, responses=_docs(*reads, 409))
    def campaigns():
        q = d.queue
        return {"running": q.current.id if q.current else None,
                "campaigns": [q.status(r) for r in q.records() if (r.folder / "campaign.sqlite").is_file()]}

    @app.get("/campaigns/{cid}", response_model=CampaignStatus, responses=_docs(*reads, 404, 409, 422))
    def campaign(cid: CampaignId):
        return d.queue.status(d.queue.get(cid))

    @app.post("/campaigns/{cid}/pause", response_model=Accepted, dependencies=auth,
              responses=_docs(*writes, 404, 409))
    def pause(cid: CampaignId):
        d.queue.pause(cid)
        return {"id": cid, "state": d.queue.state(d.queue.get(cid)),
                "message": "pausing: the step in flight finishes, then the gantry parks"}

    @app.post("/campaigns/{cid}/resume", response_model=Accepted, dependencies=auth,
              responses=_docs(*writes, 404, 409))
    def resume(cid: CampaignId, clear_fault: bool = Query(False, description="clear a latched fault")):
        d.queue.resume(cid, clear_fault)
        return {"id": cid, "state": d.queue.state(d.queue.get(cid)), "message": "resumed: runs when its turn "
                "in the queue comes"}

    @app.post("/campaigns/{cid}/abort", response_model=Accepted, dependencies=auth,
              responses=_docs(*writes, 404, 409))
    def abort(cid: CampaignId):
        d.queue.abort(cid)
        return {"id": cid, "state": d.queue.state(d.queue.get(cid)), "message": "aborting"}

    @app.get("/campaigns/{cid}/log", responses=_docs(*reads, 404, 409, 422))
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
                              "description": "server-sent events: measurement, state, fault, log, end"},
                        **_docs(*reads, 404, 409, 422, 503)})
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
             responses={200: {"content": {"application/x-hdf5": {}}, "description": "brdf.h5"},
                        **_docs(*reads, 404, 409, 422)})
    def brdf(cid: CampaignId):
        rec = d.queue.get(cid)
        path = rec.folder / BRDF_NAME
        if not path.is_file():
            raise Conflict(f"campaign '{cid}' is {d.queue.state(rec)}: brdf.h5 is written once every step is "
                           "measured")
        return FileResponse(path, media_type="application/x-hdf5", filename=f"{cid}-brdf.h5")

    return app


def asgi(d: Daemon):
    """The application as served: :func:`create_app` behind the guard (:mod:`gonio.daemon.guard`)."""
    return Guard(create_app(d), d.hosts, body_timeout_s=d.body_timeout_s)
