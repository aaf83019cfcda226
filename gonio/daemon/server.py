"""What ``gonio serve`` runs: the daemon's parts, uvicorn on a socket, signals, structured logs.

SIGTERM and SIGINT stop the daemon cleanly: the running campaign finishes (or abandons) the step in
flight and parks (the runner's pause), its journal says ``paused``, and since its intent stays ``run``
it resumes when the daemon starts again. SIGKILL loses at most the step in flight (every step is
committed before the next move); the next start resumes from the journal.

One daemon per data folder: ``DATA/daemon.lock`` (``flock``) refuses a second.
"""

from __future__ import annotations

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

from gonio.config import GonioConfig
from gonio.daemon.app import Daemon, asgi
from gonio.daemon.auth import check_bind
from gonio.daemon.events import StreamLimit
from gonio.daemon.gantry import GantryOwner
from gonio.daemon.queue import CampaignQueue

__all__ = ["serve", "build_daemon", "Running", "start_in_thread", "setup_logging"]

log = logging.getLogger("gonio.daemon")


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
                 hold: bool = False, max_streams: int = 16, clock=None) -> Daemon:
    """The daemon's parts (queue not started yet). ``clock``: the time source of a gantry with real
    devices (default the wall clock; tests of emulated devices pass the emulators' clock)."""
    from gonio.campaign import software_version

    owner = GantryOwner(cfg, pace, clock=clock)
    queue = CampaignQueue(data, cfg, pace=pace, hold=hold, before_run=owner.release, clock=clock)
    return Daemon(cfg=cfg, queue=queue, gantry=owner, token=token or None,
                  streams=StreamLimit(max_streams), version=software_version())


class _Server(uvicorn.Server):
    """uvicorn, with the daemon's own stop on SIGTERM/SIGINT before the HTTP server closes."""

    def __init__(self, config, daemon: Daemon):
        super().__init__(config)
        self.daemon = daemon

    def handle_exit(self, sig, frame):
        if not self.daemon.queue.stopping:
            log.info("signal %s: pausing the running campaign, then stopping", sig)
            threading.Thread(target=self.daemon.queue.stop, args=(f"signal {sig}: daemon stopping",),
                             daemon=True).start()
        super().handle_exit(sig, frame)


def _listen(host: str, port: int) -> socket.socket:
    """The listening socket. TCP_NODELAY (inherited by every accepted connection): a reply's header and
    body go out as two writes, and Nagle's algorithm would hold the body until the client's delayed ACK,
    40 ms later."""
    sock = socket.create_server((host, port), family=socket.AF_INET6 if ":" in host else socket.AF_INET)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock


def _config(d: Daemon, access_log: bool) -> uvicorn.Config:
    return uvicorn.Config(asgi(d), log_config=None, access_log=access_log, timeout_graceful_shutdown=2,
                          lifespan="off", ws="none")


def serve(cfg: GonioConfig, *, data: Path, host: str = "127.0.0.1", port: int = 8765,
          token: str | None = None, pace: float = 0.02, hold: bool = False, access_log: bool = True,
          max_streams: int = 16, announce=print) -> int:
    """Run the daemon until SIGTERM/SIGINT. Refuses a non-loopback ``host`` without a token."""
    check_bind(host, token)
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
    d = build_daemon(cfg, data, token=token, pace=pace, hold=hold, max_streams=max_streams)
    d.queue.start()
    server = _Server(_config(d, access_log), d)
    bound = sock.getsockname()[1]
    url = f"http://{'[' + host + ']' if ':' in host else host}:{bound}"
    announce(f"gonio serve: listening on {url} (data {data}, gantry '{cfg.name}', "
             f"{'token required for writes' if token else 'no token: loopback only'})")
    if threading.current_thread() is threading.main_thread():
        # uvicorn re-raises the signal that stopped it once it has shut down: by then the daemon has
        # stopped cleanly, so the signal is only acknowledged (exit status 0).
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda signum, frame: None)
    try:
        server.run(sockets=[sock])
    finally:
        d.queue.stop("daemon stopping")
        sock.close()
        os.close(fd)
    return 0


@dataclass
class Running:
    """A daemon served from a thread of this process (tests, benchmarks): ``url``, then :meth:`stop`."""

    daemon: Daemon
    server: uvicorn.Server
    thread: threading.Thread
    url: str

    def stop(self, timeout_s: float = 30.0) -> None:
        self.daemon.queue.stop("daemon stopping", timeout_s)
        self.server.should_exit = True
        self.thread.join(timeout_s)
        self.daemon.gantry.release()


def start_in_thread(d: Daemon, host: str = "127.0.0.1", port: int = 0, timeout_s: float = 30.0,
                    access_log: bool = False) -> Running:
    """Start the queue and serve ``d`` on ``host:port`` (0: any free port) from a thread; waits (bounded)
    until it accepts connections."""
    sock = _listen(host, port)
    d.queue.start()
    server = uvicorn.Server(_config(d, access_log))
    server.install_signal_handlers = lambda: None   # uvicorn < 0.29
    t = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, name="gonio-http", daemon=True)
    t.start()
    deadline = time.monotonic() + timeout_s
    while not server.started:
        if not t.is_alive() or time.monotonic() > deadline:
            d.queue.stop()
            raise RuntimeError("the daemon's HTTP server did not start")
        time.sleep(0.005)
    return Running(d, server, t, f"http://{host}:{sock.getsockname()[1]}")
