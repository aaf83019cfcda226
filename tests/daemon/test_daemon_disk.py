"""A full disk leaves a working daemon: a submit answers 507 in one line and writes nothing, the next
one after space is freed gets the next id, and a running campaign whose journal cannot grow stops with
the reason kept beside it, which the next start journals as ``unclean-stop``.

The data folder is a real 4 MiB tmpfs, mounted in a user and mount namespace of its own (``unshare``;
no root needed where unprivileged user namespaces are allowed, skipped elsewhere); the daemon runs in
that namespace (``nsenter``) and the test reaches the files through ``/proc/PID/root``."""

from __future__ import annotations

import errno
import json
import shutil
import subprocess
from pathlib import Path
from types import SimpleNamespace

import pytest
from daemon_helpers import WAIT_S, Serve, wait_for, wait_state


@pytest.fixture
def small_disk(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    if not (shutil.which("unshare") and shutil.which("nsenter")):
        pytest.skip("unshare/nsenter (util-linux) are not installed")
    mount = f"mount -t tmpfs -o size=4m tmpfs '{data}' && echo mounted && exec sleep 3600"
    holder = subprocess.Popen(["unshare", "--user", "--map-root-user", "--mount", "sh", "-c", mount],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        if holder.stdout.readline() != b"mounted\n":
            pytest.skip(f"cannot mount a tmpfs in a user namespace here: {holder.stderr.read(300)!r}")
        yield SimpleNamespace(data=data, inside=Path(f"/proc/{holder.pid}/root") / data.relative_to("/"),
                              prefix=("nsenter", "-t", str(holder.pid), "--user", "--mount",
                                      "--preserve-credentials", "--"))
    finally:
        holder.kill()
        holder.wait(WAIT_S)


def _fill(folder: Path) -> Path:
    """Fill the disk of ``folder`` to the last byte; the filler's path."""
    path = folder / "filler"
    with open(path, "ab", buffering=0) as fh:
        for chunk in (1 << 16, 1 << 12, 1):
            try:
                while True:
                    fh.write(b"\0" * chunk)
            except OSError as err:
                assert err.errno == errno.ENOSPC
    return path


def _entries(small) -> list[str]:
    root = small.inside / "campaigns"
    return sorted(p.name for p in root.iterdir()) + [f".incoming/{p.name}" for p in
                                                     (root / ".incoming").glob("*")]


@pytest.mark.slow
def test_a_full_disk_answers_507_and_a_runner_fault_is_journaled_at_the_next_start(small_disk):
    # Paced so that the campaign still runs when the disk is filled: 20 ms of wall time per gantry second
    # (~20 ms a step; the journal fails ~60 steps later, when its file must grow, and 250 remain).
    s = Serve(small_disk.data, "--pace", "0.02", prefix=small_disk.prefix)
    body = {"material": "lambert:albedo=0.5", "grid": "iso:step=15"}
    filler = _fill(small_disk.inside)
    before = _entries(small_disk)
    r = s.client.post("/campaigns", json=body)
    assert r.status_code == 507, r.text
    assert r.json() == {"detail": "the data folder's disk is full; nothing was written: free some space"}
    assert _entries(small_disk) == before
    filler.unlink()
    r = s.client.post("/campaigns", json=body)
    assert r.status_code == 201 and r.json()["id"] == "c00001", r.text        # the id was not wedged
    wait_for(lambda: s.client.get("/campaigns/c00001").json()["steps_done"] >= 2, "two committed steps")
    filler = _fill(small_disk.inside)                                           # while it runs
    st = wait_state(s.client, "c00001", "failed")
    assert "the data folder's disk is full" in st["error"] and st["steps_done"] < st["steps"]
    assert s.client.get("/health").json()["status"] == "ok"                      # the daemon runs on
    assert s.client.post("/gantry/halt").status_code == 200
    record = json.loads((small_disk.inside / "campaigns" / "c00001" / "daemon.json").read_text())
    assert "disk is full" in record["unclean_stop"]                    # written with the reserve freed
    filler.unlink()
    assert s.stop() == 0
    s = Serve(small_disk.data, "--pace", "0", prefix=small_disk.prefix)
    log = s.client.get("/campaigns/c00001/log").json()
    unclean = [e for e in log if e["kind"] == "unclean-stop"]
    assert len(unclean) == 1 and "the data folder's disk is full" in unclean[0]["message"], log
    assert s.client.post("/campaigns/c00001/resume").status_code == 200
    st = wait_state(s.client, "c00001", "done")
    assert st["steps_done"] == st["steps"]
    log = s.client.get("/campaigns/c00001/log").json()
    assert sum(e["kind"] == "unclean-stop" for e in log) == 1
    assert s.stop() == 0
