"""Benchmark: the daemon (``gonio serve``) against the simulated gantry.

1. Status latency: ``GET /campaigns/{id}`` and ``GET /health`` (median and p99 over many requests, one
   keep-alive client) while a simulated campaign runs in the daemon, at pace 0 (the runner computes as
   fast as it can: the worst case for a status request) and at the default pace 0.02. Target: p99 under
   20 ms on 2 cores.
2. Events: how fast the event stream delivers the measurements of a running pace-0 campaign (live,
   against the rate the runner commits them) and of a finished one (catch-up from the journal).
3. Overhead per pose: the same campaign through ``gonio simulate`` and through the daemon (submit, run,
   brdf.h5), both timed from the journal's ``running`` to its ``done`` event.
4. Pace under a burst: the running campaign's measurements per second (from its journal's commit
   times, at the default pace 0.02) while 20 clients submit small campaigns at once (planned in the
   daemon's worker process), against the quiet windows before and after each burst; three bursts.
   Target: a burst slows it by at most 10 %.
5. Status under 16 event streams: ``GET /campaigns/{id}`` latency (median, p90, p99) with no stream
   open and with 16 clients following the running campaign's event stream, side by side.
6. Bad requests: what the daemon refuses (a foreign Host, a cross-site write, a form body, NaN, a grid
   too large, a material path or FIFO), each timed; target: every one answered 4xx in under 50 ms.

The daemon runs as a ``gonio serve`` subprocess (pinned to the first ``--cores`` cores when the machine
has more), the client in this process.

Run: .venv/bin/python tools/bench_daemon.py [--grid iso:step=5] [--cores 2] [--requests 1000]
     [--only burst,streams,refusals]
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
import threading
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
    def __init__(self, data: Path, pace: float, cores: int, *extra: str):
        self.log = data.parent / f"serve-{data.name}-{pace}.log"
        self.f = self.log.open("w")
        self.p = subprocess.Popen([*GONIO, "serve", "--data", str(data), "--port", "0", "--pace", str(pace),
                                   *extra],
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


def _quantile(xs: list[float], q: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(round(q * (len(xs) - 1))))]


def _rate(folder: Path, t0: float, t1: float) -> float:
    """Measurements per second the journal committed between Unix times t0 and t1."""
    j = Journal.open(folder / JOURNAL_NAME, readonly=True)
    try:
        walls = [m["wall_s"] for m in j.measurement_rows(0, 10**7)]
    finally:
        j.close()
    return sum(t0 <= w < t1 for w in walls) / (t1 - t0)


def bench_burst(tmp: Path, grid: str, material: str, cores: int, burst: int, window_s: float,
                rounds: int) -> dict:
    """The running campaign's pace in quiet windows and during bursts of ``burst`` concurrent submits,
    alternating ``rounds`` times (quiet, burst, quiet, burst, ..., quiet): each burst is compared with the
    quiet windows on either side of it, so that a drift in the machine's other load cancels out."""
    data = tmp / "burst"
    d = Daemon(data, 0.02, cores)
    try:
        cid = d.submit(material, grid)
        d.wait(cid, ("running",))
        folder = data / "campaigns" / cid
        time.sleep(2.0)                                   # past the start (first moves, first reference)
        codes, took, windows = [], [], []

        def one():
            t = time.perf_counter()
            with httpx.Client(base_url=d.url, timeout=120) as c:
                r = c.post("/campaigns", json={"material": "lambert:albedo=0.5", "grid": "iso:step=30"})
            took.append(time.perf_counter() - t)
            codes.append(r.status_code)

        for k in range(2 * rounds + 1):
            t0 = time.time()
            if k % 2 == 0:
                time.sleep(window_s)
            else:
                threads = [threading.Thread(target=one) for _ in range(burst)]
                for t in threads:
                    t.start()
                for t in threads:
                    t.join()
            windows.append((t0, time.time()))
        rates = [_rate(folder, a, b) for a, b in windows]
        quiet, during = rates[0::2], rates[1::2]
        slower = [100 * (1 - during[i] / (0.5 * (quiet[i] + quiet[i + 1]))) for i in range(rounds)]
        st = d.client.get(f"/campaigns/{cid}").json()
        out = {"quiet": quiet, "burst": during, "slower": slower,
               "burst_s": [b - a for a, b in windows[1::2]], "codes": sorted(set(codes)),
               "submit_median_s": statistics.median(took),
               "still_running": st["state"] == "running"}
        d.client.post(f"/campaigns/{cid}/abort")
        return out
    finally:
        d.stop()


def bench_streams(tmp: Path, grid: str, material: str, cores: int, n: int, streams: int) -> dict:
    """Status latency with no event stream open, then with ``streams`` clients following the campaign."""
    data = tmp / "streams"
    d = Daemon(data, 0.02, cores, "--max-streams", str(streams))
    stop = threading.Event()
    received = [0] * streams

    def follow(i: int) -> None:
        timeout = httpx.Timeout(60, read=None)
        with httpx.stream("GET", f"{d.url}/campaigns/{cid}/events", timeout=timeout) as r:
            for line in r.iter_lines():
                received[i] += line.startswith("event: measurement")
                if stop.is_set():
                    return

    try:
        cid = d.submit(material, grid)
        d.wait(cid, ("running",))
        out = {}
        for label, k in (("0 streams", 0), (f"{streams} streams", streams)):
            followers = [threading.Thread(target=follow, args=(i,), daemon=True) for i in range(k)]
            for t in followers:
                t.start()
            deadline = time.monotonic() + 30
            while k and min(received) == 0 and time.monotonic() < deadline:   # every stream is live
                time.sleep(0.05)
            times = []
            for _ in range(n):
                t0 = time.perf_counter()
                d.client.get(f"/campaigns/{cid}").raise_for_status()
                times.append(1e3 * (time.perf_counter() - t0))
            out[label] = (statistics.median(times), _quantile(times, 0.9), _quantile(times, 0.99))
            stop.set()
        out["still_running"] = d.client.get(f"/campaigns/{cid}").json()["state"] == "running"
        d.client.post(f"/campaigns/{cid}/abort")
        return out
    finally:
        stop.set()
        d.stop()


def bench_refusals(tmp: Path, cores: int) -> list[tuple[str, int, float]]:
    """(what, status, ms) of requests the daemon must refuse, against a token-less daemon with a campaign
    running."""
    mats = tmp / "materials"
    mats.mkdir()
    os.mkfifo(mats / "pipe")
    (mats / "zero").symlink_to("/dev/zero")
    data = tmp / "refusals"
    d = Daemon(data, 0.02, cores, "--materials", str(mats))
    port = d.url.rsplit(":", 1)[1]
    post = {"material": "lambert:albedo=0.5", "grid": "iso:step=30"}
    cases = [
        ("Host evil.test (rebinding)", "GET", "/campaigns", {"headers": {"Host": f"evil.test:{port}"}}),
        ("cross-site halt (Origin)", "POST", "/gantry/halt", {"headers": {"Origin": "http://evil.test"}}),
        ("cross-site pause (Sec-Fetch-Site)", "POST", "/campaigns/c00001/pause",
         {"headers": {"Sec-Fetch-Site": "cross-site"}}),
        ("form body (text/plain)", "POST", "/campaigns", {"content": json.dumps(post),
                                                          "headers": {"Content-Type": "text/plain"}}),
        ("NaN in the body", "POST", "/campaigns", {"content": '{"grid": "iso:step=30", "seed": NaN}',
                                                   "headers": {"Content-Type": "application/json"}}),
        ("Infinity in a move", "POST", "/gantry/move", {
            "content": '{"theta_i_deg": Infinity, "phi_i_deg": 0, "theta_o_deg": 0, "phi_o_deg": 0}',
            "headers": {"Content-Type": "application/json"}}),
        ("grid full:step=0.01", "POST", "/campaigns", {"json": {**post, "grid": "full:step=0.01"}}),
        ("grid merl:stride=1", "POST", "/campaigns", {"json": {**post, "grid": "merl:stride=1"}}),
    ]
    for what, material in (("bsdf:/dev/zero", "bsdf:/dev/zero"),
                           ("merl:../../etc/passwd", "merl:../../etc/passwd"),
                           ("bsdf:pipe (a FIFO in the folder)", "bsdf:pipe"),
                           ("bsdf:zero (a link to /dev/zero)", "bsdf:zero")):
        cases.append((what, "POST", "/campaigns", {"json": {**post, "material": material}}))
    try:
        cid = d.submit("ggx:alpha=0.2,metal=gold", "iso:step=5")
        d.wait(cid, ("running",))
        out = []
        for what, method, path, kw in cases:
            t0 = time.perf_counter()
            r = d.client.request(method, path, **kw)
            out.append((what, r.status_code, 1e3 * (time.perf_counter() - t0)))
        st = d.client.get(f"/campaigns/{cid}").json()
        names = sorted(p.name for p in (data / "campaigns").iterdir() if not p.name.startswith("."))
        out.append((f"after them: campaign {st['state']}, folders {names}", 0, 0.0))
        d.client.post(f"/campaigns/{cid}/abort")
        return out
    finally:
        d.stop()


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
    ap.add_argument("--burst", type=int, default=20, help="concurrent submits of the burst")
    ap.add_argument("--window-s", type=float, default=8.0, help="seconds of each quiet window")
    ap.add_argument("--rounds", type=int, default=3, help="bursts, each between two quiet windows")
    ap.add_argument("--streams", type=int, default=16)
    ap.add_argument("--only", default=None, help="comma-separated parts: latency, events, burst, streams, "
                    "refusals (default: all)")
    args = ap.parse_args()
    only = set(args.only.split(",")) if args.only else {"latency", "events", "burst", "streams", "refusals"}
    print(f"cores: daemon pinned to {min(args.cores, len(os.sched_getaffinity(0)))} of "
          f"{len(os.sched_getaffinity(0))}; python {sys.version.split()[0]}; load average "
          f"{os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if "burst" in only:
            r = bench_burst(tmp, args.latency_grid, args.material, args.cores, args.burst, args.window_s,
                            args.rounds)
            def seq(xs, fmt=".1f", unit=""):
                return " / ".join(f"{x:{fmt}}{unit}" for x in xs)

            print(f"pace (0.02) of a running {args.latency_grid} campaign, measurements/s: quiet "
                  f"{seq(r['quiet'])}; during each burst of {args.burst} concurrent submits of iso:step=30 "
                  f"{seq(r['burst'])} (bursts of {seq(r['burst_s'])} s, median reply "
                  f"{r['submit_median_s']:.2f} s, statuses {r['codes']})"
                  f"{'' if r['still_running'] else '; campaign ended early'}")
            print("  slower during each burst than the quiet windows beside it: "
                  f"{seq(r['slower'], '+.1f', ' %')}; median {statistics.median(r['slower']):+.1f} % "
                  "(target <= 10 %)")
        if "streams" in only:
            r = bench_streams(tmp, args.latency_grid, args.material, args.cores, args.requests, args.streams)
            for label in ("0 streams", f"{args.streams} streams"):
                med, p90, p99 = r[label]
                print(f"GET /campaigns/{{id}} with {label:<10}: median {med:6.2f} ms  p90 {p90:6.2f} ms  "
                      f"p99 {p99:6.2f} ms ({args.requests} requests, pace 0.02"
                      f"{'' if r['still_running'] else '; campaign ended early'})")
        if "refusals" in only:
            for what, status, ms in bench_refusals(tmp, args.cores):
                print(f"refused: {what:<36} {status}  {ms:6.1f} ms" if status else what)
        for pace in (0.0, 0.02) if "latency" in only else ():
            r = bench_latency(tmp, args.latency_grid, args.material, pace, args.requests, args.cores)
            for name in ("status", "health"):
                med, p99 = r[name]
                print(f"latency pace={pace:<4} GET {name:<7} median {med:6.2f} ms  p99 {p99:6.2f} ms "
                      f"({args.requests} requests{'' if r['still_running'] else '; campaign ended early'})")
        if "events" not in only:
            return
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
