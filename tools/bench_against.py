"""Benchmark: ``gonio simulate``'s campaign run on this tree and on another checkout of gonio (an older
commit), side by side: process CPU per step of the whole run (the engine, the simulated motion, the
journal, brdf.h5) and of the simulated detector's calls (``measure``, ``take``, ``develop``), and hashes
of the journal's readings, of the whole journal (every row of its steps, measurements and events but the
Unix times of their commits) and of ``brdf.h5`` (every dataset and attribute but the times it was
created and written):
equal hashes: the same campaign bit for bit.

Each tree runs in its own subprocess of this venv, with the editable install's package mapping pointed at
that tree; the two alternate ``--rounds`` times (each subprocess: one warm-up campaign, then
``--repeats`` timed ones, medians).

Run (the tree of an older commit exported first)::

    git archive b9750b6 | (mkdir -p /tmp/base && tar -x -C /tmp/base)
    .venv/bin/python tools/bench_against.py /tmp/base --grid iso:step=10

``--config`` names another gantry's config (``config/sample-stage.toml``); a ``--grid`` with ``order=fly``
runs a fly campaign.
"""

from __future__ import annotations

import argparse
import gc
import hashlib
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]


def _point_at(root: Path) -> None:
    """Make ``import gonio`` (and its mapped sub-packages) load from ``root`` instead of this tree."""
    for finder in sys.meta_path:
        mapping = getattr(sys.modules.get(getattr(finder, "__module__", ""), None), "MAPPING", None)
        if isinstance(mapping, dict) and "gonio" in mapping:
            for name, path in mapping.items():
                mapping[name] = str(root / Path(path).relative_to(HERE))
            return
    raise SystemExit("this venv has no editable install of gonio to point elsewhere")


def _journal_digest(path: Path) -> str:
    """SHA-256 (16 hex digits) of a journal's rows, the Unix times of their commits left out."""
    import sqlite3

    conn = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        h = hashlib.sha256()
        for table in ("meta", "steps", "measurements", "events"):
            cols = [r[1] for r in conn.execute(f"PRAGMA table_info({table})") if r[1] != "wall_s"]
            query = f"SELECT {', '.join(cols)} FROM {table} ORDER BY 1"
            if table == "meta":   # every value but the creation time's
                query = ("SELECT key, CASE WHEN key LIKE 'created%' THEN '' ELSE value END FROM meta "
                         "ORDER BY key")
            for row in conn.execute(query):
                h.update(repr(row).encode())
        return h.hexdigest()[:16]
    finally:
        conn.close()


def _brdf_digest(path: Path) -> str:
    """SHA-256 (16 hex digits) of every dataset and attribute of ``brdf.h5`` but the times it was created
    and written."""
    import h5py
    import numpy as np

    h = hashlib.sha256()
    with h5py.File(path, "r") as f:
        def visit(name, obj):
            h.update(name.encode())
            for k in sorted(obj.attrs):
                if not k.startswith(("created", "written")):
                    h.update(k.encode() + repr(obj.attrs[k]).encode())
            if isinstance(obj, h5py.Dataset):
                value = obj[()]
                h.update(repr(value.tolist()).encode() if value.dtype.kind == "O" else
                         np.ascontiguousarray(value).tobytes())

        visit("/", f)
        f.visititems(visit)
    return h.hexdigest()[:16]


def _child(root: Path, grid: str, repeats: int, config: str | None) -> None:
    _point_at(root)
    import gonio
    from gonio.config import load_config
    from gonio.lifecycle import (
        Request,
        campaign_gantry,
        check_request,
        open_or_create,
        plan_request,
        run_campaign,
    )

    assert Path(gonio.__file__).is_relative_to(root), gonio.__file__
    cfg = load_config(config)
    request = Request(grid, material="ggx:alpha=0.1,metal=gold", seed=3)
    material = check_request(cfg, request)
    planned = plan_request(cfg, request, material)
    runs, digest = [], ""
    with tempfile.TemporaryDirectory() as d:
        for r in range(repeats + 1):
            c, _ = open_or_create(Path(d) / str(r), cfg, request, spec=material.spec, plan=lambda: planned)
            gantry = campaign_gantry(c, material)
            det, spent = gantry.detector, [0.0, 0.0]

            def timed(fn, spent=spent):
                def call(*args, **kw):
                    t, u = time.process_time(), time.thread_time()
                    try:
                        return fn(*args, **kw)
                    finally:
                        spent[0] += time.process_time() - t
                        spent[1] += time.thread_time() - u
                return call

            for name in ("measure", "take", "develop"):
                if hasattr(det, name):
                    setattr(det, name, timed(getattr(det, name)))
            gc.collect()
            t, u = time.process_time(), time.thread_time()
            state, _ = run_campaign(c, gantry)
            cpu, own = time.process_time() - t, time.thread_time() - u
            assert state == "done", state
            n = c.journal.step_count()
            digest = hashlib.sha256(b"".join(m.signal.tobytes() + m.stderr.tobytes()
                                             for m in c.journal.measurements())).hexdigest()[:16]
            c.close()
            digest += f",journal={_journal_digest(c.folder / 'campaign.sqlite')}"
            digest += f",brdf={_brdf_digest(c.folder / 'brdf.h5')}"
            if r:
                runs.append((cpu / n, spent[0] / n, (own - spent[1]) / n))
    print(*(statistics.median(run[k] for run in runs) for k in range(3)), n, digest)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("other", type=Path, help="another gonio tree (e.g. an older commit, exported)")
    ap.add_argument("--grid", default="iso:step=10")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--config", help="a gantry config (default: the simulated two-arm gantry's)")
    ap.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child is not None:
        _child(a.child, a.grid, a.repeats, a.config)
        return
    trees = {"other": a.other.resolve(), "this": HERE}
    got = {k: [] for k in trees}
    print(f"load average at the start: {os.getloadavg()[0]:.2f}")
    for _ in range(a.rounds):
        for k, root in trees.items():
            config = ["--config", str(Path(a.config).resolve())] if a.config else []
            out = subprocess.run([sys.executable, __file__, str(root), "--grid", a.grid, "--repeats",
                                  str(a.repeats), "--child", str(root), *config], capture_output=True,
                                 text=True, check=True).stdout.split()
            got[k].append((float(out[0]), float(out[1]), float(out[2]), int(out[3]), out[4]))
    print(f"gonio simulate ggx:alpha=0.1,metal=gold --grid {a.grid} --seed 3"
          f"{' --config ' + a.config if a.config else ''}, {got['this'][0][3]} steps; "
          f"medians of {a.rounds} x {a.repeats} (load average at the end {os.getloadavg()[0]:.2f}):")
    for k, root in trees.items():
        whole = statistics.median(g[0] for g in got[k])
        det = statistics.median(g[1] for g in got[k])
        rest = statistics.median(g[2] for g in got[k])
        print(f"  {k} ({root}): whole run {1e3 * whole:.3f} ms CPU per step, detector {1e3 * det:.3f} ms, "
              f"outside the detector {1e3 * (whole - det):.3f} ms ({1e3 * rest:.3f} ms in the campaign's "
              f"thread); {got[k][0][4]}")
    print(f"  readings, journal and brdf.h5 identical: {got['other'][0][4] == got['this'][0][4]}")


if __name__ == "__main__":
    main()
