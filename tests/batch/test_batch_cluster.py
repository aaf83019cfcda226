"""Closing a batch's cluster: nothing the workers say about losing the scheduler reaches the user."""

import logging

from gonio.batch import cluster


class _Client:
    def __init__(self, log, fail=False):
        self.log, self.fail = log, fail

    def run(self, fn):
        self.log.append(("run", fn))
        if self.fail:
            raise OSError("a worker is gone")

    def close(self):
        self.log.append("client.close")


class _Cluster:
    def __init__(self, log):
        self.log = log

    def close(self):
        self.log.append("cluster.close")


def test_a_local_clusters_workers_are_quieted_before_the_scheduler_closes_and_a_gone_one_is_no_error():
    for fail in (False, True):
        log = []
        cluster.disconnect(_Client(log, fail), _Cluster(log))
        assert log == [("run", cluster._closing), "client.close", "cluster.close"]
    log = []
    cluster.disconnect(_Client(log), None)      # an existing scheduler's workers are not ours to quiet
    assert log == ["client.close"]


def test_what_the_workers_are_told_silences_the_heartbeat_traceback_of_a_closing_scheduler(caplog):
    worker = logging.getLogger("distributed.worker")
    before = worker.level
    try:
        cluster._closing()
        with caplog.at_level(logging.DEBUG, logger="distributed"):
            worker.error("Failed to communicate with scheduler during heartbeat.")
        assert "heartbeat" not in caplog.text
    finally:
        for name in ("distributed.worker", "distributed.core", "distributed.comm", "distributed.nanny"):
            logging.getLogger(name).setLevel(before if name == "distributed.worker" else logging.NOTSET)


class _Scheduler:
    """What dashboard_link asks of a client: the scheduler's address and its services."""

    def __init__(self, port):
        self.scheduler = type("S", (), {"address": "tcp://127.0.0.1:8786"})()
        self.port = port

    def scheduler_info(self, n_workers):
        return {"services": {} if self.port is None else {"dashboard": self.port}}


def test_the_dashboard_link_says_what_the_schedulers_http_server_answers():
    """A dashboard: its address; Dask's page that says bokeh is missing: a note; an error status or no
    answer at all: nothing (each from a loopback server answering as told)."""
    import http.server
    import socket
    import threading

    answer = {}

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self):
            answer["path"] = self.path
            body = answer["body"].encode()
            self.send_response(answer["status"])
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args):
            pass

    server = http.server.HTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        port = server.server_address[1]
        for status, body, want in (
                (200, "<html>the dashboard</html>", f"http://127.0.0.1:{port}/status"),
                (200, "Dask needs bokeh>=3.1.0 for the dashboard.", "none (the scheduler lacks bokeh >= 3.1, "
                 "which the dashboard needs)"),
                (404, "not found", None), (500, "bokeh", None)):
            answer.update(status=status, body=body)
            assert cluster.dashboard_link(_Scheduler(port)) == want, (status, body)
            assert answer["path"] == "/status"
    finally:
        server.shutdown()
        server.server_close()
    with socket.socket() as s:          # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        closed = s.getsockname()[1]
    assert cluster.dashboard_link(_Scheduler(closed)) is None
    assert cluster.dashboard_link(_Scheduler(None)) is None     # no dashboard service at all


def test_the_dashboard_link_of_a_real_scheduler():
    """A Dask scheduler on loopback TCP (no workers: none are asked) serves its HTTP pages: its dashboard,
    or (bokeh not installed) the page saying it needs bokeh, which the link reports as such."""
    import importlib.util

    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=0, processes=False, protocol="tcp://", host="127.0.0.1",
                      dashboard_address="127.0.0.1:0") as lc, Client(lc) as client:
        link = cluster.dashboard_link(client)
    if importlib.util.find_spec("bokeh") is None:
        assert link == "none (the scheduler lacks bokeh >= 3.1, which the dashboard needs)"
    else:
        assert link.startswith("http://127.0.0.1:") and link.endswith("/status")


def test_local_workers_are_forked_from_a_fork_server_without_dr_jit():
    """A local cluster's workers are forked from a fork server that imported PRELOAD: a thread running
    there (Dr.Jit's pool, which its import starts) would be missing in every forked worker. A worker of
    connect(), asked before any task: its parent is the fork server, and Dr.Jit is not imported."""
    def seen_by_worker():       # sent by value: a local function
        import os
        import sys
        from pathlib import Path

        parent = Path(f"/proc/{os.getppid()}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        return parent, "drjit" in sys.modules

    client, local, threads = cluster.connect(workers=1)
    try:
        assert threads == 1 and local is not None
        seen = client.run(seen_by_worker)
    finally:
        cluster.disconnect(client, local)
    [(parent, drjit)] = seen.values()
    assert "from multiprocessing.forkserver import main" in parent and not drjit, seen


def test_the_fork_servers_environment_defaults_are_dasks():
    """start_fork_server sets the variables Dask sets before it starts a worker process, before
    distributed (which registers Dask's defaults of them) is imported: the same defaults."""
    import dask
    import distributed  # noqa: F401 - registers its configuration's defaults

    assert dask.config.get("distributed.nanny.pre-spawn-environ") == cluster.PRE_SPAWN_DEFAULTS
