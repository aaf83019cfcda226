"""Benchmark: dead time per sub-read of a fly sweep, a photodiode read on request against the same
photodiode streaming (real pyserial and dynamixel-sdk over ptys to the emulators, on the wall clock).

A fly reading is sub-reads of ``--exposure-ms`` each with a stamped Sync Read of the servos after each
(what :class:`gonio.fly.hardware.FlySweeper` does). Both ways run ``--n`` sub-reads back to back:

- on request (``acknowledging``-dialect photodiode: ``MEAS?``, which the emulator answers once its
  exposure has passed): a sub-read's wall time is its exposure plus the dead time (the request and
  reply on the wire and through the drivers, and the Sync Read), in which nothing is integrated;
- from the stream (``streaming-photodiode`` at ``--rate`` Hz): the instrument integrates without a
  pause; the sweeper waits for each window's end and does its Sync Read while the next window
  integrates. Its dead time per sub-read is the time in the span of the windows covered by no sample
  that reached the host (lost, garbled or overflowed lines), over the sub-reads; the lateness of the
  samples (the window's end to the last sample in hand: the line's delay and transfer, the reader)
  delays the data, not the exposure, and is printed beside.

The emulators are threads of this process, so the on-request figure is the drivers' and the
emulator's Python cost on this machine (a USB adapter's latency timer adds up to 16 ms on hardware).

Run: .venv/bin/python tools/bench_stream.py [--n 200] [--exposure-ms 25] [--rate 400]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np

from gonio.clock import WallClock
from gonio.drivers.dynamixel import DynamixelAxis, DynamixelBus
from gonio.drivers.serial import SerialPowerMeter, StreamingPowerMeter
from gonio.sim.emulators.dynamixel import DynamixelBusEmulator, EmulatedServo
from gonio.sim.emulators.instruments import PowerMeterEmulator, StreamingPhotodiodeEmulator


def _exposed(exposure_s: float) -> float:
    """The on-request photodiode integrates for its exposure before it answers."""
    time.sleep(exposure_s)
    return 1e4 * exposure_s


def _servos(clock):
    emu = DynamixelBusEmulator([EmulatedServo(i, clock=clock) for i in (1, 2, 3, 4)])
    emu.start()
    bus = DynamixelBus(emu.port)
    axes = [DynamixelAxis(f"a{i}", bus, i, limits_deg=(-90.0, 90.0), homing_offset_ticks=2048, watchdog_s=0,
                          clock=clock) for i in (1, 2, 3, 4)]
    for a in axes:
        a.connect()
    return emu, bus, axes[0].make_group(axes)


def on_request(n: int, e: float, group, clock) -> dict:
    emu = PowerMeterEmulator(_exposed, clock=clock)
    emu.start()
    dev = SerialPowerMeter("pd", emu.port, timeout_s=1.0, clock=clock)
    dev.connect()
    try:
        dev.read_on_the_fly(e)   # configured once, as after the first reading of a sweep
        cycles = []
        for _ in range(n):
            t = time.perf_counter()
            dev.read_on_the_fly(e)
            group.read_stamped(clock)
            cycles.append(time.perf_counter() - t)
    finally:
        dev.close()
        emu.stop()
    dead = np.array(cycles) - e
    return {"dead_ms": statistics.median(dead) * 1e3, "p95_ms": float(np.percentile(dead, 95)) * 1e3,
            "late_ms": float("nan"), "covered": e / statistics.median(cycles)}


def from_stream(n: int, e: float, rate: float, group, clock) -> dict:
    emu = StreamingPhotodiodeEmulator(lambda p: 1e4 * p, clock=clock)
    emu.start()
    dev = StreamingPowerMeter("pd", emu.port, "streaming-photodiode", rate_hz=rate, timeout_s=1.0,
                              clock=clock)
    dev.connect()
    try:
        dev.start_stream()
        t0 = clock.now() + 0.05
        clock.sleep_until(t0)
        late = []
        for k in range(n):
            end = t0 + (k + 1) * e
            clock.sleep_until(end)
            group.read_stamped(clock)
            while True:   # the window's samples in hand (measured, not needed before the sweep ends)
                s = dev.read_stream()
                if len(s.index) and s.t_end_s[-1] - 0.5 * s.period_s >= end - 0.5 / rate:
                    break
                time.sleep(0.0002)
            late.append(clock.now() - end)
        s = dev.read_stream()
        dev.stop_stream()
    finally:
        dev.close()
        emu.stop()
    mids = s.t_end_s - 0.5 * s.period_s
    inside = (mids >= t0) & (mids < t0 + n * e)
    covered = inside.sum() * s.period_s
    span = n * e
    return {"dead_ms": max(span - covered, 0.0) / n * 1e3, "p95_ms": float("nan"),
            "late_ms": statistics.median(late) * 1e3, "covered": covered / span}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=200)
    ap.add_argument("--exposure-ms", type=float, default=25.0)
    ap.add_argument("--rate", type=float, default=400.0)
    args = ap.parse_args()
    if not 1 <= args.n <= 100_000 or not 1 <= args.exposure_ms <= 1000 or not 1 <= args.rate <= 2000:
        ap.error("--n in [1, 100000], --exposure-ms in [1, 1000], --rate in [1, 2000]")
    clock = WallClock()
    e = args.exposure_ms / 1e3
    emu, bus, group = _servos(clock)
    try:
        rows = [("on request (MEAS? per sub-read)", on_request(args.n, e, group, clock)),
                (f"from the stream ({args.rate:g} Hz)", from_stream(args.n, e, args.rate, group, clock))]
    finally:
        emu.stop()
    print(f"load {os.getloadavg()[0]:.2f}; {args.n} sub-reads of {args.exposure_ms:g} ms, a stamped Sync "
          "Read of 4 servos after each")
    print(f"{'way':38s} {'dead/sub-read':>14s} {'p95':>8s} {'exposed':>8s} {'samples late':>13s}")
    for name, r in rows:
        p95 = "" if np.isnan(r["p95_ms"]) else f"{r['p95_ms']:.2f} ms"
        late = "" if np.isnan(r["late_ms"]) else f"{r['late_ms']:.2f} ms"
        print(f"{name:38s} {r['dead_ms']:11.3f} ms {p95:>8s} {r['covered'] * 100:7.1f} % {late:>13s}")


if __name__ == "__main__":
    main()
