"""Creating a campaign journal (gonio.store.Journal.create, then close): wall and CPU per journal.

Every campaign a command or a test makes starts here, so the syncs of its creation are waited for once
per campaign. Each run creates ``--count`` journals of a ``--steps``-step plan in a fresh folder beside the
others (same file system as the tests' temporary folders), in a process of its own; ``--before DIR`` runs
the gonio of another source tree in the same turns, side by side.

Run: .venv/bin/python tools/bench_journal.py [--count 40] [--steps 60] [--repeat 3] [--before DIR]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: One process: ``count`` creations, the wall and CPU (user + system) of each, as JSON.
RUN = """
import json, os, resource, sys, tempfile, time
import numpy as np
from gonio.store import Journal
count, n = int(sys.argv[1]), int(sys.argv[2])
steps = {"kind": np.zeros(n, int), "pose": np.arange(n), "theta_i_deg": np.linspace(0, 80, n),
         "phi_i_deg": np.zeros(n), "theta_o_deg": np.linspace(0, 80, n), "phi_o_deg": np.full(n, 180.0),
         "axes_deg": np.zeros((n, 4))}
meta = {"grid": "iso:step=15", "seed": 0, "poses": n, "config": {"axes": list(range(40))}}
base = tempfile.mkdtemp(prefix="bench-journal-")
cpu = lambda: sum(getattr(resource.getrusage(resource.RUSAGE_SELF), f) for f in ("ru_utime", "ru_stime"))
w0, c0 = time.perf_counter(), cpu()
for i in range(count):
    folder = os.path.join(base, str(i))
    os.mkdir(folder)
    Journal.create(os.path.join(folder, "campaign.sqlite"), meta, steps).close()
print(json.dumps({"wall": (time.perf_counter() - w0) / count, "cpu": (cpu() - c0) / count}))
"""


def _run(tree: Path, count: int, steps: int) -> dict:
    # The tree's gonio first on the path (``gonio.sim`` and ``gonio.drivers`` are mapped by the install;
    # creating a journal needs neither).
    code = f"import sys; sys.path.insert(0, {str(tree)!r});" + RUN
    out = subprocess.run([sys.executable, "-c", code, str(count), str(steps)], capture_output=True,
                         text=True, check=True, timeout=600)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--count", type=int, default=40)
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--before", type=Path, help="a source tree of another gonio to run side by side")
    args = ap.parse_args()
    trees = {"now": ROOT} | ({"before": args.before} if args.before else {})
    runs: dict[str, list[dict]] = {k: [] for k in trees}
    for _ in range(args.repeat):
        for name, tree in trees.items():
            runs[name].append(_run(tree, args.count, args.steps))
    print(f"{args.count} journals of {args.steps} steps per run, {args.repeat} runs; median (least) per "
          "journal")
    print("| tree | wall ms | CPU ms |")
    print("|---|---|---|")
    for name, rs in runs.items():
        w, c = [r["wall"] * 1e3 for r in rs], [r["cpu"] * 1e3 for r in rs]
        print(f"| {name} | {statistics.median(w):.1f} ({min(w):.1f}) | {statistics.median(c):.2f} "
              f"({min(c):.2f}) |")


if __name__ == "__main__":
    main()
