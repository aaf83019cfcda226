"""A costly fixture built once per test run, not once per pytest-xdist worker.

``--dist load`` hands a module's tests to both workers, so a module-scoped fixture (a simulated campaign,
the report built from it) is built twice, once in each. :func:`built_once` builds it in a folder shared by
the run's workers (the parent of each worker's base temporary folder, which pytest keeps per run): the
first worker to ask holds an exclusive ``flock`` while it builds and then writes the value, pickled; a
worker that asks meanwhile waits on the lock (no polling) and loads the value. A build that raised leaves
no value: the next worker to ask builds again (and fails the same way, in its own tests). Without xdist it
is an ordinary build in a fresh temporary folder.

The tests that share a value must not write into its folder (they copy it first), as for any
module-scoped fixture.
"""

from __future__ import annotations

import fcntl
import os
import pickle
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

T = TypeVar("T")


def built_once(tmp_path_factory, name: str, build: Callable[[Path], T]) -> T:
    """``build(folder)`` (``folder`` an empty folder of its own) once per run, its value to every worker."""
    worker, base = os.environ.get("PYTEST_XDIST_WORKER"), tmp_path_factory.getbasetemp()
    if not worker or base.name != f"popen-{worker}":  # not a worker's folder inside the run's own
        return build(tmp_path_factory.mktemp(name))
    shared = base.parent / "built-once"
    shared.mkdir(exist_ok=True)
    folder, value = shared / name, shared / f"{name}.pickle"
    with open(shared / f"{name}.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)         # waits while another worker builds it
        if value.exists():
            return pickle.loads(value.read_bytes())
        shutil.rmtree(folder, ignore_errors=True)  # what a build that raised left
        folder.mkdir()
        out = build(folder)
        tmp = value.with_suffix(".tmp")
        tmp.write_bytes(pickle.dumps(out))
        os.replace(tmp, value)
        return out
