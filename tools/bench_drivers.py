"""Benchmark: driver round trips against the emulators (real dynamixel-sdk and pymodbus, pty / loopback).

1. Dynamixel: one multi-axis move command (one Sync Write of goal positions) and one Sync Read of
   the state block (watchdog .. present position, 38 bytes per servo), for 2, 4 and 8 servos on one bus.
2. Modbus: one move (the profile's block write, then the status read that sees the moving bit) and one
   position read, TCP on 127.0.0.1 and RTU over a pty.

The emulators run in Python threads on the same machine, so the figures are the driver + library +
emulator cost, not a wire's: at 1 Mbit/s a real 4-servo Sync Read adds ~0.5 ms of bytes on the wire.

Run: .venv/bin/python tools/bench_drivers.py [--n 300]
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


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=300, help="repetitions per figure")
    args = ap.parse_args()
    for k in (2, 4, 8):
        bench_dynamixel(k, args.n)
    for t in ("tcp", "rtu"):
        bench_modbus(t, max(20, args.n // 3))


if __name__ == "__main__":
    main()
