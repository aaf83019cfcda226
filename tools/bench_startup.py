"""Benchmark: CPU time of the ``gonio`` command, from its start to its exit (what a user waits for, and what
each of the test suite's ``gonio`` subprocesses costs).

Each command runs as a fresh subprocess ``--repeat`` times, in turns with the baseline ``python -c pass``
(the interpreter's own start-up on the same Python), so that a load that changes during the run weighs on
all alike. CPU time is user + system of the process and of the children it waited for (``os.wait4``),
which a busy machine inflates far less than wall time; the table gives the median and the least of the
runs, and each command's median over the baseline's.

Targets (issue 21): ``gonio --version`` and ``gonio <command> --help`` at most 0.3 s of CPU; a small
``gonio simulate`` (iso:step=45) at most 0.7 s.

The commands that work on something name it with a placeholder, filled in before the runs start:

- ``{campaign}``: a finished campaign (``gonio simulate lambert:albedo=0.5 --grid iso:step=45``, made once);
- ``{new}``: a path that does not exist yet, a new one for every run (an output, a campaign folder);
- ``{emulated}``: the config of ``gonio emulate --config emulated-sample-stage-modbus`` running beside
  the runs (started and referenced once, stopped at the end; none of it is measured).

``serve`` and ``emulate`` run until they are ready (``serve`` says it listens, ``emulate`` has written its
``--write-config`` file), then get SIGINT: their figure is the CPU of starting and stopping.

``--before DIR`` runs each command also with the gonio of another source tree, in the same turns: a
checkout of an earlier commit (``git archive COMMIT | tar -x -C DIR``), imported from DIR with its
pyproject's package-dir mapping (gonio.sim = sim/, ...) instead of the installed one.

Run: .venv/bin/python tools/bench_startup.py [--repeat 7] [--before DIR]
     [--commands "plan --help" "status {campaign}" ...]
(a command that starts with a dash is written after a space, `" --version"`, so that it is not taken for
an option of this tool).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import shlex
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path

#: Start-up only (the targets), then commands that do their work, as the tests run them.
DEFAULT_COMMANDS = (
    "--version", "--help", "plan --help", "simulate --help", "export --help", "plot --help", "gantry --help",
    "serve --help", "config list", "plan --grid iso:step=30",
    "simulate lambert:albedo=0.5 --grid iso:step=45 --out {new} --quiet",
    "status {campaign}",
    "export {campaign} --format csv --out {new}.csv",
    "export {campaign} --format bsdf --out {new}.bsdf",
    "fit {campaign} --model lambert --quiet",
    "report {campaign} --models lambert --out {new}.html",
    "plot {campaign} --kind polar --out {new}.png",
    "batch lambert:albedo=0.5 --grid iso:step=45 --workers 1 --quiet --out {new}.zarr",
    "run --config {emulated} --grid iso:step=45 --sample felt --quiet --out {new}",
    # order=fly as the kill tests' `gonio run` children start it (a simulated gantry renders the sweeps)
    "run --config sim --material lambert:albedo=0.5 --sample felt --grid iso:step=30,order=fly --quiet "
    "--out {new}",
    "simulate lambert:albedo=0.5 --grid iso:step=30,order=fly --out {new} --quiet",
    "emulate --config emulated-sample-stage-modbus --any-port --write-config {new}.toml",
    "serve --data {new} --port 0",
)
#: ``python -c`` of a gonio from the source tree argv[1] (``--before``): its packages mapped as its
#: pyproject maps them, ahead of the installed gonio.
BEFORE = """
import importlib.machinery, importlib.util, sys, tomllib
from pathlib import Path
root = Path(sys.argv.pop(1))
dirs = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
class Tree:
    def find_spec(self, name, path=None, target=None):
        if name not in dirs:
            return None
        folder = root / dirs[name]
        if (folder / "__init__.py").is_file():
            return importlib.util.spec_from_file_location(name, folder / "__init__.py",
                                                          submodule_search_locations=[str(folder)])
        spec = importlib.machinery.ModuleSpec(name, None, is_package=True)  # a namespace package
        spec.submodule_search_locations = [str(folder)]
        return spec
sys.meta_path.insert(0, Tree())
from gonio.cli import main
sys.exit(main())
"""
#: Seconds a command may take (a daemon: to be ready).
TIMEOUT_S = 300.0
#: Byte-code caches written and used (as an installed gonio has them, and as `make test` runs), no token.
_ENV = {**{k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}, "GONIO_TOKEN": ""}


def gonio_command() -> list[str]:
    """The ``gonio`` console script beside this interpreter (what a user runs), else ``-m gonio.cli``."""
    script = Path(sys.executable).with_name("gonio")
    return [str(script)] if script.is_file() else [sys.executable, "-m", "gonio.cli"]


def _answers(log: Path) -> bool:
    """``gonio serve`` said where it listens and answers an HTTP request there (any status)."""
    m = re.search(r"listening on (http://\S+)", log.read_text())
    if m is None:
        return False
    try:
        urllib.request.urlopen(m[1] + "/", timeout=1.0).close()
    except urllib.error.HTTPError:
        return True
    except OSError:
        return False
    return True


def _ready(argv: list[str], log: Path):
    """For a daemon command, the test that it is ready; None for a command that exits by itself."""
    if "serve" in argv:
        return lambda: _answers(log)
    if "emulate" in argv:
        written = Path(argv[argv.index("--write-config") + 1])
        return written.exists
    return None


def _reaped(pid: int, until: float):
    """(exit status, rusage) of child ``pid`` once it has exited, waiting until ``until`` at most (else
    None). ``os.wait4``: the rusage of that one child (and of the children it waited for)."""
    while True:
        done, status, usage = os.wait4(pid, os.WNOHANG)
        if done or time.monotonic() >= until:
            return (status, usage) if done else None
        time.sleep(0.01)  # polling a child process, bounded by ``until``


def cpu_s(argv: list[str], scratch: Path) -> float:
    """User + system CPU seconds of one run of ``argv`` and the children it waited for (it must exit 0, a
    daemon after SIGINT once it is ready)."""
    log = scratch / f"log-{time.monotonic_ns()}"
    with log.open("w") as out:
        proc = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, env=_ENV)
    ready, deadline = _ready(argv, log), time.monotonic() + TIMEOUT_S
    done = _reaped(proc.pid, deadline if ready is None else time.monotonic())
    while done is None and time.monotonic() < deadline and not ready():
        done = _reaped(proc.pid, time.monotonic() + 0.01)
    while done is None and time.monotonic() < deadline:
        proc.send_signal(signal.SIGINT)  # sent again if it came too early to be seen
        done = _reaped(proc.pid, min(time.monotonic() + 10.0, deadline))
    if done is None:
        proc.kill()
        os.wait4(proc.pid, 0)
    proc.returncode = 0  # reaped here: Popen must not wait for it again
    if done is None or os.waitstatus_to_exitcode(done[0]) not in ((0, 130) if ready else (0,)):
        raise SystemExit(f"{shlex.join(argv)} failed or did not stop:\n{log.read_text()[-2000:]}")
    usage = done[1]
    return usage.ru_utime + usage.ru_stime


@contextlib.contextmanager
def emulator(gonio: list[str], scratch: Path):
    """``gonio emulate`` of the shipped Modbus sample stage, referenced: the config path to run on."""
    config = scratch / "emulated.toml"
    log = (scratch / "emulate.log").open("w")
    proc = subprocess.Popen([*gonio, "emulate", "--config", "emulated-sample-stage-modbus", "--any-port",
                             "--write-config", str(config)], stdout=log, stderr=subprocess.STDOUT, env=_ENV)
    try:
        deadline = time.monotonic() + TIMEOUT_S
        while not config.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)  # polling another process's output, bounded by the deadline
        subprocess.run([*gonio, "gantry", "reference", "--config", str(config)], check=True, env=_ENV,
                       stdout=subprocess.DEVNULL, timeout=TIMEOUT_S)
        yield config
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(TIMEOUT_S)
        log.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7, help="runs of each command")
    ap.add_argument("--commands", nargs="+", default=list(DEFAULT_COMMANDS),
                    help="gonio arguments, one string per command ({campaign}, {new}, {emulated}: above)")
    ap.add_argument("--before", type=Path, help="a source tree of another gonio to run side by side")
    args = ap.parse_args()
    gonio = gonio_command()
    before = [sys.executable, "-c", BEFORE, str(args.before.resolve())] if args.before else None
    with tempfile.TemporaryDirectory(prefix="bench-startup-") as tmp, contextlib.ExitStack() as stack:
        scratch = Path(tmp)
        campaign = scratch / "campaign"
        subprocess.run([*gonio, "simulate", "lambert:albedo=0.5", "--grid", "iso:step=45", "--quiet", "--out",
                        str(campaign)], check=True, env=_ENV, stdout=subprocess.DEVNULL,
                       stderr=subprocess.DEVNULL, timeout=TIMEOUT_S)
        emulated = stack.enter_context(emulator(gonio, scratch)) if any(
            "{emulated}" in c for c in args.commands) else None
        runs = {"python -c pass": [sys.executable, "-c", "pass"]}
        for c in args.commands:
            runs[f"gonio {c.strip()}"] = gonio + shlex.split(c)
            if before:
                runs[f"before: gonio {c.strip()}"] = before + shlex.split(c)
        count = iter(range(10**9))

        def filled(argv: list[str]) -> list[str]:
            new = scratch / f"new-{next(count)}"
            return [re.sub(r"\{(campaign|new|emulated)\}", lambda m: str(
                {"campaign": campaign, "new": new, "emulated": emulated}[m[1]]), a) for a in argv]

        for argv in runs.values():  # warm the file cache and write the .pyc files first: not measured
            cpu_s(filled(argv), scratch)
        times: dict[str, list[float]] = {name: [] for name in runs}
        for _ in range(args.repeat):
            for name, argv in runs.items():
                times[name].append(cpu_s(filled(argv), scratch))
    base = statistics.median(times["python -c pass"])
    load = os.getloadavg()[0]
    print(f"Python {sys.version.split()[0]}, {os.cpu_count()} CPUs, load average {load:.2f}; "
          f"{args.repeat} runs each; `python -c pass` {base:.3f} s (median)"
          + (f"; before: {args.before}" if before else ""))
    print("| command | CPU s, median (least) | x `python -c pass` |"
          + (" before: median (least) | now / before |" if before else "") + " target |")
    print("|---|---|---|" + ("---|---|" if before else "") + "---|")
    for name, values in times.items():
        if name.startswith("before: ") or name == "python -c pass":
            continue
        med = statistics.median(values)
        target = 0.3 if name == "gonio --version" or name.endswith("--help") else (
            0.7 if name.startswith("gonio simulate ") and "iso:step=45" in name else None)
        verdict = "" if target is None else f"<= {target} s: " + ("meets" if med <= target else "MISSES")
        row = f"| `{name}` | {med:.3f} ({min(values):.3f}) | {med / base:.1f}x |"
        if before:
            old = times[f"before: {name}"]
            row += f" {statistics.median(old):.3f} ({min(old):.3f}) | {med / statistics.median(old):.2f} |"
        print(f"{row} {verdict} |")


if __name__ == "__main__":
    main()
