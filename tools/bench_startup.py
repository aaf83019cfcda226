"""Benchmark: CPU time of starting the ``gonio`` command (what a user waits for before anything happens).

Each command runs as a fresh subprocess ``--repeat`` times, in turns with the baseline ``python -c pass``
(the interpreter's own start-up on the same Python), so that a load that changes during the run weighs on
all alike. CPU time is user + system of the children (``resource.getrusage(RUSAGE_CHILDREN)`` before and
after each run), which a busy machine inflates far less than wall time; the table gives the median and the
least of the runs, and each command's median over the baseline's.

Target (issue 21): ``gonio --version`` and ``gonio <command> --help`` at most 0.3 s of CPU.

Run: .venv/bin/python tools/bench_startup.py [--repeat 7] [--commands "plan --help" "config list" ...]
(a command that starts with a dash is written after a space, `" --version"`, so that it is not taken for
an option of this tool). ``config list`` and ``plan --grid ...`` do their work: what a command that loads a
config, and one that plans, costs beyond its start.
"""

from __future__ import annotations

import argparse
import os
import resource
import shlex
import statistics
import subprocess
import sys
from pathlib import Path

DEFAULT_COMMANDS = ("--version", "--help", "plan --help", "simulate --help", "export --help", "plot --help",
                    "gantry --help", "serve --help", "config list", "plan --grid iso:step=30")


def gonio_command() -> list[str]:
    """The ``gonio`` console script beside this interpreter (what a user runs), else ``-m gonio.cli``."""
    script = Path(sys.executable).with_name("gonio")
    return [str(script)] if script.is_file() else [sys.executable, "-m", "gonio.cli"]


def cpu_s(argv: list[str]) -> float:
    """User + system CPU seconds of one run of ``argv`` (its output discarded; it must exit 0)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True,
                   env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"})
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7, help="runs of each command")
    ap.add_argument("--commands", nargs="+", default=list(DEFAULT_COMMANDS),
                    help="gonio arguments, one string per command")
    args = ap.parse_args()
    gonio = gonio_command()
    runs = {"python -c pass": [sys.executable, "-c", "pass"]}
    runs |= {f"gonio {c}": gonio + shlex.split(c) for c in args.commands}
    for argv in runs.values():  # warm the file cache (and .pyc files) first: not measured
        cpu_s(argv)
    times: dict[str, list[float]] = {name: [] for name in runs}
    for _ in range(args.repeat):
        for name, argv in runs.items():
            times[name].append(cpu_s(argv))
    base = statistics.median(times["python -c pass"])
    load = os.getloadavg()[0]
    print(f"Python {sys.version.split()[0]}, {os.cpu_count()} CPUs, load average {load:.2f}; "
          f"{args.repeat} runs each")
    print("| command | CPU s, median (least) | x `python -c pass` | --version, --help: target <= 0.3 s |")
    print("|---|---|---|---|")
    for name, values in times.items():
        med = statistics.median(values)
        targeted = name == "gonio --version" or name.endswith("--help")  # the others do their work
        verdict = "" if not targeted else ("meets" if med <= 0.3 else "MISSES")
        print(f"| `{name}` | {med:.3f} ({min(values):.3f}) | {med / base:.1f}x | {verdict} |")


if __name__ == "__main__":
    main()
