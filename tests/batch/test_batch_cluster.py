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
