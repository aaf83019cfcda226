"""Benchmark: the daemon (``gonio serve``) against the simulated gantry.

1. Status latency: ``GET /campaigns/{id}`` and ``GET /health`` (median and p99 over many requests, one
   keep-alive client) while a simulated campaign runs in the daemon, at pace 0 (the runner computes as
   fast as it can: the worst case for a status request) and at the default pace 0.02. Target: p99 under
   20 ms on 2 cores.
2. Events: how fast the event stream delivers the measurements of a running pace-0 campaign (live,
   against the rate the runner commits them) and of a finished one (catch-up from the journal).
3. Overhead per pose: the same campaign through ``gonio simulate`` and through the daemon (submit, run,
   brdf.h5), both timed from the journal's ``running`` to its ``done`` event.

The daemon runs as a ``gonio serve`` subprocess (pinned to the first ``--cores`` cores when the machine
has more), the client in this process.

Run: .venv/bin/python tools/bench_daemon.py [--grid iso:step=5] [--cores 2] [--requests 1000]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx

from gonio.store import JOURNAL_NAME, Journal

GONIO = [sys.executable, "-m", "gonio.cli"]


def _affinity(cores: int):
    avail = sorted(os.sched_getaffinity(0))
    use = set(avail[:cores])
    return lambda: os.sched_setaffinity(0, use)


class Daemon:
    def __init__(self, data: Path, pace: float, cores: int):
        self.log = data.parent / f"serve-{pace}.log"
        self.f = self.log.open("w")
        self.p = subprocess.Popen([*GONIO, "serve", "--data", str(data), "--port", "0", "--pace", str(pace)],
                                  stdout=self.f, stderr=subprocess.STDOUT, preexec_fn=_affinity(cores),
                                  env={**os.environ, "GONIO_TOKEN": ""})
        deadline = time.monotonic() + 60
        while not (m := re.search(r"listening on (http://\S+)", self.log.read_text())):
            if self.p.poll() is not None or time.monotonic() > deadline:
                raise SystemExit(f"gonio serve did not start: {self.log.read_text()}")
            time.sleep(0.02)
        self.url = m.group(1)
        self.client = httpx.Client(base_url=self.url, timeout=60)

    def submit(self, material: str, grid: str) -> str:
        r = self.client.post("/campaigns", json={"material": material, "grid": grid})
        r.raise_for_status()
        return r.json()["id"]

    def wait(self, cid: str, states=("done",), limit_s: float = 600) -> dict:
        deadline = time.monotonic() + limit_s
        while (st := self.client.get(f"/campaigns/{cid}").json())["state"] not in states:
            if time.monotonic() > deadline:
                raise SystemExit(f"{cid} still {st['state']} after {limit_s} s")
            time.sleep(0.05)
        return st

    def stop(self) -> None:
        self.client.close()
        self.p.send_signal(signal.SIGTERM)
        self.p.wait(120)
        self.f.close()


def _percentiles(xs: list[float]) -> tuple[float, float]:
    xs = sorted(xs)
    return statistics.median(xs), xs[min(len(xs) - 1, int(round(0.99 * (len(xs) - 1))))]


def bench_latency(tmp: Path, grid: str, material: str, pace: float, n: int, cores: int) -> dict:
    d = Daemon(tmp / f"lat-{pace}", pace, cores)
    try:
        cid = d.submit(material, grid)
        d.wait(cid, ("running",))
        out = {}
        for name, path in (("status", f"/campaigns/{cid}"), ("health", "/health")):
            times = []
            for _ in range(n):
                t0 = time.perf_counter()
                r = d.client.get(path)
                times.append(1e3 * (time.perf_counter() - t0))
                r.raise_for_status()
            out[name] = _percentiles(times)
        st = d.client.get(f"/campaigns/{cid}").json()
        out["still_running"] = st["state"] == "running"
        d.client.post(f"/campaigns/{cid}/abort")
        return out
    finally:
        d.stop()


def _stream(url: str, cid: str) -> tuple[int, float, float]:
    """(measurements received, seconds from the first to the end, seconds connected)."""
    n, first = 0, None
    t0 = time.perf_counter()
    with httpx.stream("GET", f"{url}/campaigns/{cid}/events", timeout=httpx.Timeout(60, read=None)) as r:
        for line in r.iter_lines():
            if line.startswith("event: measurement"):
                n += 1
                first = first or time.perf_counter()
            elif line.startswith("event: end"):
                break
    end = time.perf_counter()
    return n, end - (first or end), end - t0


def _run_window(folder: Path) -> tuple[float, int]:
    """Wall seconds from the journal's first 'running' to its 'done', and its step count."""
    j = Journal.open(folder / JOURNAL_NAME, readonly=True)
    try:
        states = [e for e in j.events() if e["kind"] == "state"]
        start = next(e["wall_s"] for e in states if e["state"] == "running")
        done = next(e["wall_s"] for e in states if e["state"] == "done")
        return done - start, j.step_count()
    finally:
        j.close()


def bench_events_and_overhead(tmp: Path, grid: str, material: str, cores: int) -> dict:
    data = tmp / "ev"
    d = Daemon(data, 0.0, cores)
    try:
        cid = d.submit(material, grid)
        live_n, live_s, _ = _stream(d.url, cid)          # connected from the start: follows the runner
        d.wait(cid)
        run_s, steps = _run_window(data / "campaigns" / cid)
        catch_n, catch_s, _ = _stream(d.url, cid)        # the finished campaign, from the journal
    finally:
        d.stop()
    sim = tmp / "sim"
    t0 = time.perf_counter()
    subprocess.run([*GONIO, "simulate", material, "--grid", grid, "--out", str(sim), "--quiet"], check=True,
                   preexec_fn=_affinity(cores), capture_output=True)
    sim_total = time.perf_counter() - t0
    sim_s, sim_steps = _run_window(sim)
    assert sim_steps == steps
    return {"steps": steps, "live_events": live_n, "live_per_s": live_n / max(live_s, 1e-9),
            "runner_per_s": steps / run_s, "catchup_per_s": catch_n / max(catch_s, 1e-9),
            "daemon_run_s": run_s, "simulate_run_s": sim_s, "simulate_total_s": sim_total,
            "overhead_ms_per_step": 1e3 * (run_s - sim_s) / steps}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grid", default="iso:step=5", help="the campaign's GRID (overhead and events)")
    ap.add_argument("--latency-grid", default="iso:step=2", help="GRID of the campaign running during the "
                    "latency test (large enough to outlast it at pace 0)")
    ap.add_argument("--material", default="ggx:alpha=0.2,metal=gold")
    ap.add_argument("--requests", type=int, default=1000)
    ap.add_argument("--cores", type=int, default=2)
    args = ap.parse_args()
    print(f"cores: daemon pinned to {min(args.cores, len(os.sched_getaffinity(0)))} of "
          f"{len(os.sched_getaffinity(0))}; python {sys.version.split()[0]}")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for pace in (0.0, 0.02):
            r = bench_latency(tmp, args.latency_grid, args.material, pace, args.requests, args.cores)
            for name in ("status", "health"):
                med, p99 = r[name]
                print(f"latency pace={pace:<4} GET {name:<7} median {med:6.2f} ms  p99 {p99:6.2f} ms "
                      f"({args.requests} requests{'' if r['still_running'] else '; campaign ended early'})")
        r = bench_events_and_overhead(tmp, args.grid, args.material, args.cores)
        print(f"events ({args.grid}, {r['steps']} steps): live {r['live_per_s']:.0f} measurements/s "
              f"delivered while the runner commits {r['runner_per_s']:.0f} steps/s "
              f"({r['live_events']} received); "
              f"catch-up {r['catchup_per_s']:.0f} measurements/s")
        print(f"overhead: daemon run {r['daemon_run_s']:.2f} s vs gonio simulate {r['simulate_run_s']:.2f} s "
              f"(running -> done) = {r['overhead_ms_per_step']:+.3f} ms per step "
              f"(gonio simulate end to end {r['simulate_total_s']:.2f} s)")
        print(json.dumps(r))


if __name__ == "__main__":
    main()
