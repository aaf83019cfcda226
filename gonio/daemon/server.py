"""What ``gonio serve`` runs: the daemon's parts, uvicorn on a socket, signals, structured logs.

SIGTERM and SIGINT stop the daemon cleanly: the running campaign finishes (or abandons) the step in
flight and parks (the runner's pause), its journal says ``paused``, and since its intent stays ``run``
it resumes when the daemon starts again. SIGKILL loses at most the step in flight (every step is
committed before the next move); the next start resumes from the journal.

One daemon per data folder: ``DATA/daemon.lock`` (``flock``) refuses a second.

Slow clients are bounded: a connection must send a whole request head within ``head_timeout_s`` of
opening (or of its previous reply), heads are at most 16 KiB (h11), bodies arrive within the guard's
time (:mod:`gonio.daemon.guard`), and an idle keep-alive connection closes after 5 s.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import signal
import socket
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import uvicorn
from uvicorn.protocols.http.h11_impl import H11Protocol

from gonio.config import GonioConfig
from gonio.daemon.app import Daemon, asgi
from gonio.daemon.auth import check_bind, check_token
from gonio.daemon.events import StreamLimit
from gonio.daemon.gantry import GantryOwner
from gonio.daemon.guard import BODY_TIMEOUT_S, MAX_BODY_BYTES, HostNames
from gonio.daemon.planner import EXIT_GRACE_S, PLAN_TIMEOUT_S, Planner
from gonio.daemon.queue import CampaignQueue
from gonio.sim.materials.library import MaterialsFolder

__all__ = ["serve", "build_daemon", "Running", "start_in_thread", "setup_logging"]

log = logging.getLogger("gonio.daemon")

#: Seconds a connection may take to send a whole request head.
HEAD_TIMEOUT_S = 10.0
#: Seconds an idle keep-alive connection is kept.
KEEP_ALIVE_S = 5


class _JsonFormatter(logging.Formatter):
    def format(self, record):
        out = {"t": round(record.created, 3), "level": record.levelname.lower(), "logger": record.name,
               "msg": record.getMessage()}
        if record.exc_info:
            out["exc"] = self.formatException(record.exc_info)
        return json.dumps(out)


def setup_logging(json_lines: bool = False, level: int = logging.INFO) -> None:
    """One line per event on stderr: ``time level logger: message``, or one JSON object per line."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_JsonFormatter() if json_lines else logging.Formatter(
        "%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level)


def _lock_data(data: Path) -> int:
    data.mkdir(parents=True, exist_ok=True)
    from gonio.campaign import LockHeld, pid_lock

    try:
        return pid_lock(data / "daemon.lock")
    except LockHeld as held:
        raise ValueError(f"--data: {data} is served by another gonio daemon (pid {held.holder}); stop it or "
                         "choose another folder") from None


def build_daemon(cfg: GonioConfig, data: Path, *, token: str | None = None, pace: float = 0.0,
                 hold: bool = False, max_streams: int = 16, clock=None, materials: str | Path | None = None,
                 allow_hosts=(), halt_needs_token: bool = False, plan_timeout_s: float = PLAN_TIMEOUT_S,
                 body_timeout_s: float = BODY_TIMEOUT_S, plan_idle: bool = True, plans=None) -> Daemon:
    """The daemon's parts (queue and planner not started yet). ``clock``: the time source of a gantry
    with real devices (default the wall clock; tests of emulated devices pass the emulators' clock).
    ``plan_idle``, ``plans``: the planner's worker at idle priority, the plans it starts with
    (:class:`gonio.daemon.planner.Planner`'s ``idle`` and ``plans``).
    ValueError (naming the option) for a token too weak, a materials folder that is not one, or a
    malformed ``allow_hosts`` entry."""
    from gonio.campaign import software_version

    token = check_token(token)
    library = MaterialsFolder(materials)
    library.check()
    hosts = HostNames(tuple(allow_hosts))
    owner = GantryOwner(cfg, pace, clock=clock)
    queue = CampaignQueue(data, cfg, pace=pace, hold=hold, before_run=owner.release, clock=clock,
                          materials=library)
    planner = Planner(cfg, library, timeout_s=plan_timeout_s, idle=plan_idle, plans=plans)
    return Daemon(cfg=cfg, queue=queue, gantry=owner, planner=planner, token=token, hosts=hosts,
                  materials=library, halt_needs_token=halt_needs_token, streams=StreamLimit(max_streams),
                  body_timeout_s=body_timeout_s, version=software_version())


class _TimedH11(H11Protocol):
    """uvicorn's h11 protocol with a deadline on each request head: a connection that has not sent a
    whole request line and headers within ``head_timeout_s`` of opening (or of its previous reply) is
    closed, however slowly it trickles bytes (uvicorn's own keep-alive timer restarts with every byte)."""

    head_timeout_s = HEAD_TIMEOUT_S
    _head_timer = None

    def connection_made(self, transport):
        super().connection_made(transport)
        self._arm_head_deadline()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        self._arm_head_deadline()

    def connection_lost(self, exc):
        if self._head_timer is not None:
            self._head_timer.cancel()
        super().connection_lost(exc)

    def _arm_head_deadline(self) -> None:
        if self._head_timer is not None:
            self._head_timer.cancel()
        self._head_timer = self.loop.call_later(self.head_timeout_s, self._head_late, self.scope)

    def _head_late(self, scope) -> None:
        if self.scope is scope and not self.transport.is_closing():   # no new request since the arming
            self.transport.close()


class _PromptServer(uvicorn.Server):
    """uvicorn, whose main loop notices a stop at once: uvicorn's own looks at ``should_exit`` every
    0.1 s, so every stop waited up to that long before the shutdown began."""

    def __init__(self, config):
        super().__init__(config)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._wake: asyncio.Event | None = None

    async def main_loop(self) -> None:
        self._loop, self._wake = asyncio.get_running_loop(), asyncio.Event()
        counter = 0
        while not await self.on_tick(counter):   # on_tick: the Date header, once a second; should_exit
            counter = (counter + 1) % 864000
            self._wake.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._wake.wait(), 0.1)

    async def shutdown(self, sockets=None) -> None:
        """uvicorn's shutdown without the fixed 0.1 s pause it takes after asking the connections to
        close: stop listening, ask each connection to close once its response is out, wait for the
        connections and their tasks (looked at every 5 ms, at most ``timeout_graceful_shutdown``; the
        tasks left are cancelled, an event stream's among them)."""
        logging.getLogger("uvicorn.error").info("Shutting down")   # as uvicorn's own says it
        for server in self.servers:
            server.close()
        for sock in sockets or []:
            sock.close()
        state = self.server_state
        for connection in list(state.connections):
            connection.shutdown()
        loop = asyncio.get_running_loop()
        grace = self.config.timeout_graceful_shutdown   # None: no limit, as in uvicorn
        deadline = loop.time() + (float("inf") if grace is None else grace)
        while (state.connections or state.tasks) and not self.force_exit and loop.time() < deadline:
            await asyncio.sleep(0.005)
        for task in list(state.tasks):
            task.cancel()
        for server in self.servers:
            await server.wait_closed()
        if not self.force_exit:
            await self.lifespan.shutdown()

    def exit_now(self) -> None:
        """Stop serving (from any thread, or a signal handler): the main loop ends at once."""
        self.should_exit = True
        loop, wake = self._loop, self._wake
        if loop is not None and wake is not None:
            with contextlib.suppress(RuntimeError):   # the loop has closed already
                loop.call_soon_threadsafe(wake.set)


class _Server(_PromptServer):
    """uvicorn, with the daemon's own stop on SIGTERM/SIGINT before the HTTP server closes."""

    def __init__(self, config, daemon: Daemon):
        super().__init__(config)
        self.daemon = daemon
        #: Signals that came before uvicorn's own handlers were in place (see :func:`serve`).
        self.early_signals: list[int] = []

    async def startup(self, sockets=None):
        await super().startup(sockets)
        # uvicorn's handlers are in place by now (its capture_signals wraps the whole serve): a stop asked
        # for while it was starting is acted on here, not lost.
        for sig in self.early_signals:
            self.handle_exit(sig, None)

    def handle_exit(self, sig, frame):
        if not self.daemon.queue.stopping:
            log.info("signal %s: pausing the running campaign, then stopping", sig)
            threading.Thread(target=self.daemon.queue.stop, args=(f"signal {sig}: daemon stopping",),
                             daemon=True).start()
        super().handle_exit(sig, frame)
        self.exit_now()


def _listen(host: str, port: int) -> socket.socket:
    """The listening socket. TCP_NODELAY (inherited by every accepted connection): a reply's header and
    body go out as two writes, and Nagle's algorithm would hold the body until the client's delayed ACK,
    40 ms later."""
    sock = socket.create_server((host, port), family=socket.AF_INET6 if ":" in host else socket.AF_INET)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock


def _config(d: Daemon, access_log: bool, head_timeout_s: float = HEAD_TIMEOUT_S) -> uvicorn.Config:
    protocol = type("TimedH11", (_TimedH11,), {"head_timeout_s": head_timeout_s})
    return uvicorn.Config(asgi(d), log_config=None, access_log=access_log, timeout_graceful_shutdown=2,
                          lifespan="off", ws="none", http=protocol, timeout_keep_alive=KEEP_ALIVE_S,
                          h11_max_incomplete_event_size=MAX_BODY_BYTES)


def serve(cfg: GonioConfig, *, data: Path, host: str = "127.0.0.1", port: int = 8765,
          token: str | None = None, pace: float = 0.02, hold: bool = False, access_log: bool = True,
          max_streams: int = 16, materials: str | Path | None = None, allow_hosts=(),
          halt_needs_token: bool = False, plan_idle: bool = True, announce=print) -> int:
    """Run the daemon until SIGTERM/SIGINT. Refuses a non-loopback ``host`` without a token, and a token
    too weak, before anything is written. ``plan_idle``: as :func:`build_daemon`'s."""
    check_bind(host, check_token(token))
    d = build_daemon(cfg, data, token=token, pace=pace, hold=hold, max_streams=max_streams,
                     materials=materials, allow_hosts=allow_hosts, halt_needs_token=halt_needs_token,
                     plan_idle=plan_idle)
    # The port first: a port that is taken leaves nothing behind in the data folder (no daemon.lock).
    try:
        sock = _listen(host, port)
    except OSError as err:
        raise ValueError(f"--port: cannot listen on {host}:{port} ({err.strerror or err})") from None
    try:
        fd = _lock_data(data)
    except BaseException:
        sock.close()
        raise
    # The runner's thread computes (Dr.Jit, numpy) between short waits: hand the GIL over more often than
    # every 5 ms so that a request thread is not kept waiting behind it.
    sys.setswitchinterval(0.0005)
    bound = sock.getsockname()[1]
    d.hosts.listen(host, bound)
    server = _Server(_config(d, access_log), d)
    if threading.current_thread() is threading.main_thread():
        # From here until uvicorn has its own handlers (once it serves), SIGINT/SIGTERM are recorded and
        # acted on as soon as it does: one sent right after "listening on" was lost, and the daemon ran
        # on. After uvicorn has shut down, it re-raises the signal that stopped it: by then the daemon has
        # stopped cleanly, so the signal is only acknowledged (exit status 0).
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda signum, frame: None if server.started
                          else server.early_signals.append(signum))
    try:
        d.queue.start()
        d.planner.start()
        # Listening (the socket is bound: connections wait in its backlog) is said once the planner's
        # worker has started, so that a submission is planned at once and a stop never waits for a start.
        d.planner.wait_started()
        url = f"http://{'[' + host + ']' if ':' in host else host}:{bound}"
        announce(f"gonio serve: listening on {url} (data {data}, gantry '{cfg.name}', "
                 f"{'token required for writes' if d.token else 'no token: loopback only'}, "
                 f"{'materials from ' + str(materials) if materials else 'no measured materials'})")
        if host in ("0.0.0.0", "::") and not allow_hosts:
            log.warning("listening on every interface, but only loopback names are answered: give the "
                        "names clients use (--allow-host gantry-pc.lab) or any other Host is refused")
        server.run(sockets=[sock])
    finally:
        d.queue.stop("daemon stopping")
        d.planner.stop(start_grace_s=EXIT_GRACE_S)    # the process exits next
        sock.close()
        os.close(fd)
    return 0


@dataclass
class Running:
    """A daemon served from a thread of this process (tests, benchmarks): ``url``, then :meth:`stop`."""

    daemon: Daemon
    server: _PromptServer
    thread: threading.Thread
    url: str

    def stop(self, timeout_s: float = 30.0) -> None:
        self.daemon.queue.stop("daemon stopping", timeout_s)
        self.server.exit_now()
        self.thread.join(timeout_s)
        self.daemon.planner.stop()
        self.daemon.gantry.release()


def start_in_thread(d: Daemon, host: str = "127.0.0.1", port: int = 0, timeout_s: float = 30.0,
                    access_log: bool = False, head_timeout_s: float = HEAD_TIMEOUT_S) -> Running:
    """Start the queue and planner and serve ``d`` on ``host:port`` (0: any free port) from a thread;
    waits (bounded) until it accepts connections."""
    sock = _listen(host, port)
    d.hosts.listen(host, sock.getsockname()[1])
    d.queue.start()
    d.planner.start()
    server = _PromptServer(_config(d, access_log, head_timeout_s))
    server.install_signal_handlers = lambda: None   # uvicorn < 0.29
    t = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, name="gonio-http", daemon=True)
    t.start()
    deadline = time.monotonic() + timeout_s
    while not server.started:
        if not t.is_alive() or time.monotonic() > deadline:
            d.queue.stop()
            d.planner.stop()
            raise RuntimeError("the daemon's HTTP server did not start")
        time.sleep(0.005)
    return Running(d, server, t, f"http://{host}:{sock.getsockname()[1]}")
