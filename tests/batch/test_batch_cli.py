"""``gonio batch`` as a user runs it: a local cluster of two worker processes, killed midway and rerun;
an existing Dask scheduler and a worker process on loopback; bad input refused in one line with nothing
written. The three stores agree bit for bit."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zarr
from cli_helpers import one_clear_line

from gonio.batch import DONE, open_store
from gonio.cli import main

GONIO = [sys.executable, "-m", "gonio.cli"]
MATERIALS = "ggx:alpha=0.1..0.4x3,metal=gold|copper"          # 6 materials
ARGS = ["--grid", "iso:step=45", "--seed", "2", "--quiet"]
WAIT_S = 120.0


def _start(cmd, **kw) -> subprocess.Popen:
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, **kw)


def _stop(p: subprocess.Popen, sig=signal.SIGTERM) -> None:
    """Signal the process group (a local cluster's worker processes too) and reap the leader."""
    try:
        os.killpg(p.pid, sig)
    except ProcessLookupError:
        pass
    try:
        p.wait(timeout=30)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        p.wait(timeout=30)


def _done(store: Path) -> int:
    """Rows done in ``store``. A row's status is written as one chunk file of ``status`` (a missing row has
    none: Zarr leaves a chunk that holds only the fill value unwritten), so until a chunk file is there no
    row is done and the store is not opened: polled every 10 ms, this costs a directory listing."""
    try:
        if not any(name[:1].isdigit() for name in os.listdir(store / "status")):
            return 0
        return int((zarr.open_group(str(store), mode="r")["status"][:] == DONE).sum())
    except Exception:        # not created yet
        return 0


def _rows(store: Path) -> dict:
    """Every array of the store as stored, and its attributes (zarr alone: 0.02 s where an xarray open
    costs 0.1-0.15 s; the ``whole`` fixture reads its store through xarray)."""
    group = zarr.open_group(str(store), mode="r", zarr_format=2)
    arrays = {name: a[...] for name, a in group.arrays()}
    return arrays | {"attrs": json.dumps(dict(group.attrs), sort_keys=True),
                     "array attrs": json.dumps({name: dict(a.attrs) for name, a in group.arrays()},
                                               sort_keys=True)}


@pytest.fixture(scope="module")
def whole(tmp_path_factory, client):
    """The batch run whole, in this process (one Dask worker thread): what the command must write."""
    from gonio.batch import read_materials, run_batch
    from gonio.config import load_config

    out = tmp_path_factory.mktemp("whole") / "b.zarr"
    run_batch(read_materials(MATERIALS), grid="iso:step=45", seed=2, cfg=load_config(), out=out,
              client=client, threads=1)
    ds = open_store(out)
    assert ds.sizes["material"] == 6 and (ds.status.values == DONE).all()
    assert np.isfinite(ds.value.values).all() and (ds.value.values > 0).any()
    return out


def test_two_local_workers_killed_midway_then_rerun_agree_bit_for_bit(whole, tmp_path, capsys):
    out = tmp_path / "b.zarr"
    args = ["batch", MATERIALS, "--out", str(out), "--workers", "2", *ARGS]
    p = _start([*GONIO, *args])
    try:
        deadline = time.monotonic() + WAIT_S
        while _done(out) < 1 and p.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        _stop(p, signal.SIGKILL)
    done = _done(out)
    assert 1 <= done < 6, f"the kill landed with {done} rows done"
    # The rerun through main() in this process (the killed batch was the process, killed with its workers):
    # a local cluster of two worker processes again, not quiet: the summary.
    capsys.readouterr()
    assert main(args[:-1]) == 0
    assert f"({6 - done} written now, {done} before, 0 failed)" in capsys.readouterr().err
    a, b = _rows(whole), _rows(out)
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_an_existing_scheduler_and_worker_on_loopback(whole, tmp_path):
    """gonio batch --scheduler sends its tasks to a worker process of a scheduler it did not start. The
    scheduler runs in this process (on loopback TCP, as a lab server's would; docs/batch.md starts it as
    ``python -m dask scheduler``), the worker is a process of its own."""
    from distributed import LocalCluster

    with LocalCluster(n_workers=0, processes=False, protocol="tcp://", host="127.0.0.1",
                      dashboard_address=None) as scheduler:
        address = scheduler.scheduler_address
        assert address.startswith("tcp://127.0.0.1:")
        # One worker process (no nanny process to watch over it: not what gonio sees of a cluster).
        worker = _start([sys.executable, "-m", "dask", "worker", address, "--nthreads", "1", "--nworkers",
                         "1", "--no-dashboard", "--no-nanny", "--host", "127.0.0.1"])
        try:
            out = tmp_path / "b.zarr"
            # gonio batch in this process (its own process is the test above's): what is tested is its
            # client on the scheduler's address and the worker process that runs its tasks.
            assert main(["batch", MATERIALS, "--out", str(out), "--scheduler", address, *ARGS]) == 0
        finally:
            _stop(worker)
    a, b = _rows(whole), _rows(out)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


@pytest.mark.parametrize("args, message", [
    (["lambert:albedo=2", "--grid", "iso:step=45"], "albedo"),
    (["lambert:albedo=0.5", "--grid", "iso:step=0"], "--grid"),
    (["lambert:albedo=0.5", "--grid", "iso:step=45,order=fly"], "order=fly is not for a batch"),
    (["lambert:albedo=0.5", "--grid", "adaptive:budget_s=600"], "give poses=N instead"),
    (["lambert:albedo=0.5", "--grid", "iso:step=45", "--scheduler", "http://x/y"], "--scheduler"),
    (["lambert:albedo=0.5", "--grid", "iso:step=45", "--config", "emulated-two-arm-dynamixel"], "--config"),
])
def test_bad_input_is_one_line_exit_2_nothing_written(tmp_path, capsys, args, message):
    out = tmp_path / "b.zarr"
    assert main(["batch", *args, "--out", str(out)]) == 2
    one_clear_line(capsys, "gonio batch: ", message)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args, message", [
    (["--workers", "0"], "argument --workers: must be an integer from 1 to 256, got '0'"),
    (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "not allowed with argument --workers"),
])
def test_bad_arguments_are_refused_by_the_parser_nothing_written(tmp_path, capsys, args, message):
    with pytest.raises(SystemExit) as e:
        main(["batch", "lambert:albedo=0.5", "--grid", "iso:step=45", "--out", str(tmp_path / "b"), *args])
    assert e.value.code == 2
    one_clear_line(capsys, "gonio batch: ", f"{message}; `gonio batch --help` shows every argument")
    assert list(tmp_path.iterdir()) == []


def _other_zarr(path: Path) -> None:
    group = zarr.open_group(str(path), mode="w", zarr_format=2)
    group.attrs["format"] = "someone-else"
    group.create_array("x", shape=(3,), dtype="f8")


def test_a_store_of_another_batch_is_refused_before_any_worker_starts(whole, tmp_path, capsys, monkeypatch):
    """The store was compared with the batch only once the local cluster ran (1.7 s, and a line saying the
    batch started on its workers)."""
    import gonio.batch.cluster
    import gonio.cli.batch

    def no_workers(*a, **kw):
        raise AssertionError("a worker was started")
    monkeypatch.setattr(gonio.cli.batch, "connected", no_workers)
    monkeypatch.setattr(gonio.batch.cluster, "start_fork_server", no_workers)
    before = _rows(whole)
    assert main(["batch", "lambert:albedo=0.5", *ARGS, "--out", str(whole)]) == 2
    one_clear_line(capsys, f"gonio batch: --out: {whole} holds another batch (its materials differ")
    after = _rows(whole)
    assert before.keys() == after.keys() and all(np.array_equal(before[k], after[k]) for k in before)


def test_a_file_or_a_folder_that_is_no_store_is_refused_as_out(tmp_path, capsys):
    """A file, a folder, and a Zarr store of something else: one line, exit 2, left as they were (the
    Zarr store was read for its materials and ended in a KeyError traceback, after a cluster started)."""
    for name, make, says in (("f.zarr", lambda p: p.write_text("x"), "is a file"),
                             ("d.zarr", lambda p: p.mkdir(), "no batch store"),
                             ("z.zarr", _other_zarr, "not a gonio batch store (format 'someone-else')")):
        out = tmp_path / name
        make(out)
        before = sorted(out.rglob("*")) if out.is_dir() else out.read_bytes()
        assert main(["batch", "lambert:albedo=0.5", "--grid", "iso:step=45", "--out", str(out)]) == 2
        one_clear_line(capsys, "gonio batch: --out:", says)
        assert before == (sorted(out.rglob("*")) if out.is_dir() else out.read_bytes())   # left alone
