"""Benchmark: driver round trips against the emulators (real dynamixel-sdk and pymodbus, pty / loopback).

1. Dynamixel: one multi-axis move command (one Sync Write of goal positions) and one Sync Read of
   the state block (watchdog .. present position, 38 bytes per servo), for 2, 4 and 8 servos on one bus.
2. Modbus: one move (the profile's block write, then the status read that sees the moving bit) and one
   position read, TCP on 127.0.0.1 and RTU over a pty.

The emulators run in Python threads on the same machine, so the figures are the driver + library +
emulator cost, not a wire's: at 1 Mbit/s a real 4-servo Sync Read adds ~0.5 ms of bytes on the wire.

3. A whole campaign through the drivers on each emulated gantry (``emulated-two-arm-dynamixel``,
   ``emulated-sample-stage-modbus``): the emulators and the gantry share a virtual clock, so every
   physical wait (moves, settling, exposures) costs no wall time and the wall time per pose is the
   overhead beyond the physical motion: driver round trips, planning safe paths, the runner, the journal
   commit, and the emulated detector's Dr.Jit render (the last is the emulator's, not the drivers').

Run: .venv/bin/python tools/bench_drivers.py [--n 300] [--grid iso:step=15]
"""

from __future__ import annotations

import argparse
import statistics
import time

from gonio.clock import VirtualClock
from gonio.drivers.dynamixel import DynamixelAxis, DynamixelBus, DynamixelGroup
from gonio.drivers.modbus import ModbusAxis, make_client
from gonio.sim.emulators.dynamixel import DynamixelBusEmulator, EmulatedServo
from gonio.sim.emulators.modbus import ModbusMotorEmulator


def timed(fn, n):
    out = []
    for _ in range(n):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return statistics.median(out) * 1e3, sorted(out)[int(0.95 * (n - 1))] * 1e3


def bench_dynamixel(n_servos, n):
    clock = VirtualClock()
    emu = DynamixelBusEmulator([EmulatedServo(i, clock=clock) for i in range(1, n_servos + 1)])
    emu.start()
    bus = DynamixelBus(emu.port)
    axes = [DynamixelAxis(f"a{i}", bus, i, limits_deg=(-90.0, 90.0), homing_offset_ticks=2048, watchdog_s=0)
            for i in range(1, n_servos + 1)]
    try:
        for a in axes:
            a.connect()
        group = DynamixelGroup(axes)
        k = [0]

        def move():
            k[0] += 1
            group.move_to({a.name: float(k[0] % 40) for a in axes})

        w = timed(move, n)
        r = timed(group.read, n)
        print(f"dynamixel {n_servos} servos: sync write move {w[0]:.3f} ms (p95 {w[1]:.3f}), "
              f"sync read {r[0]:.3f} ms (p95 {r[1]:.3f})")
    finally:
        for a in axes:
            a.close()
        emu.stop()


def bench_modbus(transport, n):
    clock = VirtualClock()
    emu = ModbusMotorEmulator("generic", clock=clock)
    url = (f"tcp://{':'.join(map(str, emu.start_tcp()))}" if transport == "tcp"
           else f"rtu://{emu.start_rtu()}?baudrate=115200")
    axis = ModbusAxis("m", make_client(url, timeout_s=0.5, retries=0), "generic", limits_deg=(-180.0, 180.0),
                      clock=clock)
    try:
        axis.connect()
        k = [0]

        def move():
            k[0] += 1
            clock.sleep(100.0)  # the previous move is over
            axis.move_to(float(k[0] % 90))

        w = timed(move, n)
        r = timed(axis.position_deg, n)
        print(f"modbus {transport}: move (block write + status) {w[0]:.3f} ms (p95 {w[1]:.3f}), "
              f"position read {r[0]:.3f} ms (p95 {r[1]:.3f})")
    finally:
        axis.close()
        emu.stop()


def bench_campaign(twin, grid):
    import tempfile

    from gonio.campaign import create_campaign, run_campaign
    from gonio.config import load_config
    from gonio.sim.emulators.gantry import EmulatedGantry
    from gonio.wiring import build_gantry

    clock = VirtualClock()
    with EmulatedGantry(load_config(twin), "cook-torrance:d=beckmann,m=0.3,metal=gold", clock=clock,
                        any_port=True) as emu, tempfile.TemporaryDirectory() as d:
        cfg = emu.config()
        c = create_campaign(d, cfg, grid=grid, material=None, sample="bench")
        poses, steps = c.meta["poses"], c.journal.step_count()
        t = time.perf_counter()
        state, _ = run_campaign(c, build_gantry(cfg, clock=clock))
        wall = time.perf_counter() - t
        c.close()
        render = emu._detector._count
    print(f"campaign {twin} {grid}: {state}, {poses} poses / {steps} steps, gantry time {clock.now():.0f} s, "
          f"wall {wall:.2f} s = {1e3 * wall / poses:.2f} ms per pose beyond the physical motion "
          f"({render} emulated readings rendered)")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=300, help="repetitions per figure")
    ap.add_argument("--grid", default="iso:step=15", help="GRID of the campaign benchmark")
    args = ap.parse_args()
    for twin in ("emulated-two-arm-dynamixel", "emulated-sample-stage-modbus"):
        bench_campaign(twin, args.grid)
    for k in (2, 4, 8):
        bench_dynamixel(k, args.n)
    for t in ("tcp", "rtu"):
        bench_modbus(t, max(20, args.n // 3))


if __name__ == "__main__":
    main()
