"""Where the test suite's time goes: sums the per-test lines that ``GONIO_TEST_CPU=FILE`` makes
tests/conftest.py write (``FILE.<worker>``: wall s, CPU s of the test process, CPU s of the subprocesses
it waited for, test id).

    GONIO_TEST_CPU=/tmp/cpu python -m pytest -q -p no:cacheprovider -n auto --dist load
    python tools/test_cpu.py /tmp/cpu [--top 25]

Prints the totals, the tests with the most CPU, those that wait the most (wall less CPU: sleeps,
wall-clock emulators, time-outs, or a loaded machine) and the files with the most CPU.
"""

from __future__ import annotations

import argparse
import glob
import sys
from collections import defaultdict


def read(prefix: str) -> list[tuple[float, float, float, str]]:
    rows = []
    for path in sorted(glob.glob(glob.escape(prefix) + ".*")):
        with open(path, encoding="utf-8") as f:
            for line in f:
                wall, own, children, nodeid = line.rstrip("\n").split("\t", 3)
                rows.append((float(wall), float(own), float(children), nodeid))
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("prefix", help="the FILE given as GONIO_TEST_CPU")
    ap.add_argument("--top", type=int, default=25, help="rows of each table (default 25)")
    args = ap.parse_args(argv)
    rows = read(args.prefix)
    if not rows:
        print(f"test_cpu: no {args.prefix}.* files", file=sys.stderr)
        return 2
    wall = sum(r[0] for r in rows)
    own = sum(r[1] for r in rows)
    children = sum(r[2] for r in rows)
    print(f"{len(rows)} tests: wall {wall:.1f} s summed over the workers, CPU {own + children:.1f} s "
          f"({own:.1f} s in the test processes, {children:.1f} s in their subprocesses)")
    print(f"\nmost CPU (s)\n{'cpu':>7} {'wall':>7}  test")
    for w, o, c, n in sorted(rows, key=lambda r: -(r[1] + r[2]))[:args.top]:
        print(f"{o + c:7.1f} {w:7.1f}  {n}")
    print(f"\nmost waiting (s: wall less CPU)\n{'wait':>7} {'wall':>7}  test")
    for w, o, c, n in sorted(rows, key=lambda r: -(r[0] - r[1] - r[2]))[:args.top]:
        print(f"{w - o - c:7.1f} {w:7.1f}  {n}")
    files = defaultdict(lambda: [0.0, 0.0, 0])
    for w, o, c, n in rows:
        f = files[n.split("::")[0]]
        f[0] += o + c
        f[1] += w
        f[2] += 1
    print(f"\nfiles by CPU (s)\n{'cpu':>7} {'wall':>7} {'tests':>5}  file")
    for name, (cpu, w, k) in sorted(files.items(), key=lambda kv: -kv[1][0])[:args.top]:
        print(f"{cpu:7.1f} {w:7.1f} {k:5d}  {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
