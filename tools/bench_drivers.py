"""Benchmark: driver round trips against the emulators (real dynamixel-sdk and pymodbus, pty / loopback).

1. Dynamixel: one multi-axis move command (one Sync Write of goal positions) and one Sync Read of
   the state block (watchdog .. present position, 38 bytes per servo), for 2, 4 and 8 servos on one bus.
2. Modbus: one move (the profile's block write, then the status read that sees the moving bit) and one
   position read, TCP on 127.0.0.1 and RTU over a pty; one look at four controllers on four TCP
   gateways, in turn and at once, with replies held back 0, 1 and 3 ms (a wire's latency).

The emulators run in Python threads on the same machine, so the figures are the driver + library +
emulator cost, not a wire's: at 1 Mbit/s a real 4-servo Sync Read adds ~0.5 ms of bytes on the wire.

3. A whole campaign through the drivers on each emulated gantry (``emulated-two-arm-dynamixel``,
   ``emulated-sample-stage-modbus``): the emulators and the gantry share a virtual clock, so every
   physical wait (moves, settling, exposures) costs no wall time and the wall time per pose is the
   overhead beyond the physical motion, split into: driver round trips (time inside the drivers'
   transactions, emulator included, less the render), safe-path planning, the journal (commits and
   events), the runner and the rest, and the emulated detector's Dr.Jit render (the emulator's work, not
   the drivers': reported apart). Each gantry runs in several ways (:data:`WAYS`): per axis (the
   gantry's batched reads hidden, so the runner asks each axis in turn: the "before") and batched (one
   Sync Read per bus per poll); the Modbus gantry also batched with its profiles' ``span_read`` and
   ``write_read`` off (one request per register read and a separate start check: the batched "before"),
   as shipped, and with its connections asked at once. The ways of a gantry take turns, one campaign
   each, ``--repeat`` rounds, so that a load that changes during the run weighs on all alike.

Run: .venv/bin/python tools/bench_drivers.py [--n 300] [--grid iso:step=15] [--repeat 3]
[--only dynamixel|modbus]
"""

from __future__ import annotations

import argparse
import collections
import os
import statistics
import threading
import time

from gonio.clock import VirtualClock
from gonio.drivers.dynamixel import DynamixelAxis, DynamixelBus, DynamixelGroup
from gonio.drivers.modbus import ModbusAxis, make_client
from gonio.sim.emulators.dynamixel import DynamixelBusEmulator, EmulatedServo
from gonio.sim.emulators.link import FaultPlan
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
    axes = [DynamixelAxis(f"a{i}", bus, i, limits_deg=(-90.0, 90.0), homing_offset_ticks=2048, watchdog_s=0,
                          clock=clock)
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


def bench_modbus_looks(n, latencies_ms=(0.0, 1.0, 3.0)):
    """One look (``poll_axes``) at the emulated sample stage's four controllers (four TCP gateways), with
    each reply held back ``latency`` ms (what a wire and the unit's turnaround add; 0: the in-process
    emulator alone), asking the connections in turn and at once."""
    from gonio.config import load_config
    from gonio.sim.emulators.gantry import EmulatedGantry
    from gonio.sim.emulators.link import SyncedVirtualClock
    from gonio.wiring import build_gantry

    clock = SyncedVirtualClock()
    with EmulatedGantry(load_config("emulated-sample-stage-modbus"), "lambert:albedo=0.5", clock=clock,
                        any_port=True, referenced=True) as emu:
        gantry = build_gantry(emu.config(), clock=clock)
        gantry.connect()
        try:
            for latency in latencies_ms:
                figures = []
                for concurrent in (False, True):
                    gantry.concurrent = concurrent
                    for name in gantry.axes:
                        emu.motors[name].faults = FaultPlan()
                        if latency:
                            emu.motors[name].faults.add("delay", times=n + 10, delay_s=latency / 1e3)
                    gantry.poll_axes()
                    figures.append(timed(gantry.poll_axes, n))
                (turn, turn95), (once, once95) = figures
                print(f"modbus look at 4 controllers, reply latency {latency:g} ms: in turn {turn:.2f} ms "
                      f"(p95 {turn95:.2f}), at once {once:.2f} ms (p95 {once95:.2f})")
        finally:
            for name in gantry.axes:
                emu.motors[name].faults = FaultPlan()
            gantry.close()


class _Split:
    """Wall time (and the calling thread's CPU time) spent inside chosen functions (wrapped in place;
    :meth:`undo` restores them). A call made inside another wrapped call of the same thread counts for the
    outer one only."""

    def __init__(self):
        self.s = collections.Counter()
        self.cpu = collections.Counter()
        self.n = collections.Counter()
        self._undo = []
        self._depth = threading.local()

    def wrap(self, owner, attr, key):
        fn = getattr(owner, attr)

        def timed(*a, **k):
            depth = getattr(self._depth, "n", 0)
            self._depth.n = depth + 1
            t, c = time.perf_counter(), time.thread_time()
            try:
                return fn(*a, **k)
            finally:
                self._depth.n = depth
                if depth == 0:
                    self.s[key] += time.perf_counter() - t
                    self.cpu[key] += time.thread_time() - c
                    self.n[key] += 1

        setattr(owner, attr, timed)
        self._undo.append((owner, attr, fn))

    def replace(self, owner, attr, fn):
        self._undo.append((owner, attr, getattr(owner, attr)))
        setattr(owner, attr, fn)

    def undo(self):
        for owner, attr, fn in reversed(self._undo):
            setattr(owner, attr, fn)
        self._undo = []


def _emulator_cpu() -> float:
    """CPU seconds used so far by the emulators' threads (named ``emu-*``: the Modbus servers, the serial
    and Dynamixel links): the devices' own work, which a real rig does on the devices' processors. In
    this benchmark they share the interpreter with gonio, so a round trip's wall time holds it too."""
    total = 0.0
    for t in threading.enumerate():
        if t.name.startswith("emu-") and t.ident is not None:
            try:
                total += time.clock_gettime(time.pthread_getcpuclockid(t.ident))
            except OSError:        # the thread ended meanwhile
                pass
    return total


class _PerAxis:
    """The assembled gantry without its batched methods: the runner then moves and reads each axis in
    turn (one transaction per axis per poll), as it did before batching; with the runner reading every
    axis again at the start of each step's path (``_start_positions`` replaced), the "before" figures."""

    _HIDDEN = ("positions", "poll_axes", "move_axes", "keep_alive")

    def __init__(self, gantry):
        self._g = gantry

    def __getattr__(self, name):
        if name in self._HIDDEN:
            raise AttributeError(name)
        return getattr(self._g, name)


#: How each gantry runs: (label, per axis, Dynamixel watchdog on, Modbus way). Modbus way: None (as
#: shipped: spanning reads and function 23 where the profile has them, connections asked at once only
#: above ``CONCURRENT_ABOVE_S``), "plain" (span_read and write_read off, connections in turn: before),
#: "at once" (``AssembledGantry.concurrent = True``).
WAYS = {
    "emulated-two-arm-dynamixel": [("per axis (before), watchdog off", True, False, None),
                                   ("batched, watchdog off", False, False, None),
                                   ("batched, watchdog 0.5 s (shipped)", False, True, None)],
    "emulated-sample-stage-modbus": [("per axis (before)", True, True, "plain"),
                                     ("batched, a request per register, start check apart (before)", False,
                                      True, "plain"),
                                     ("batched (shipped)", False, True, None),
                                     ("batched, connections asked at once", False, True, "at once")],
}


def bench_campaigns(twin, grid, repeat=3):
    """The best of ``repeat`` campaigns on ``twin`` in each of its :data:`WAYS` (taking turns; the
    machine is shared: the least disturbed run is the closest to the cost itself); prints, for each, its
    wall time per pose and where it went. The per-axis path does not feed the Dynamixel watchdogs (a
    move longer than the watchdog would stop short): it runs with them off."""
    runs = {way: [] for way in WAYS[twin]}
    for _ in range(repeat):
        for way in WAYS[twin]:
            runs[way].append(_campaign(twin, grid, *way[1:]))
    for way, done in runs.items():
        bad = [r["state"] for r in done if r["state"] != "done"]
        if bad:
            raise SystemExit(f"campaign {twin}, {way[0]}: ended {bad[0]}, not done")
        _report(twin, grid, way[0], repeat, **min(done, key=lambda r: r["wall"]))


def _campaign(twin, grid, per_axis, watchdog, modbus):
    import dataclasses
    import tempfile

    import gonio.drivers.modbus.axis
    import gonio.runner
    from gonio.campaign import create_campaign
    from gonio.config import GonioConfig, load_config
    from gonio.drivers.serial.line import LineInstrument
    from gonio.gantry import AssembledGantry
    from gonio.lifecycle import run_campaign
    from gonio.sim.emulators.gantry import EmulatedGantry
    from gonio.sim.emulators.link import SyncedVirtualClock
    from gonio.store import Journal
    from gonio.wiring import build_gantry

    split = _Split()
    split.wrap(AssembledGantry, "keep_alive", "feeding")
    split.wrap(DynamixelBus, "_call", "driver")
    split.wrap(ModbusAxis, "_call", "driver")
    split.wrap(LineInstrument, "_exchange", "driver")
    split.wrap(EmulatedGantry, "_render", "render")
    split.wrap(gonio.runner, "safe_path", "planning")
    split.wrap(gonio.runner, "check_targets", "planning")
    split.wrap(Journal, "commit_measurement", "journal")
    split.wrap(Journal, "log_event", "journal")
    if per_axis:
        split.replace(gonio.runner.Runner, "_start_positions", gonio.runner.Runner._positions)
    if modbus == "plain":
        load = gonio.drivers.modbus.axis.load_profile
        split.replace(gonio.drivers.modbus.axis, "load_profile",
                      lambda name: dataclasses.replace(load(name), span_read=False, write_read=False))
    clock = SyncedVirtualClock()
    try:
        cfg = load_config(twin)
        if not watchdog:
            data = cfg.model_dump(mode="json")
            for axis in data["axes"].values():
                axis["watchdog_s"] = 0.0
            cfg = GonioConfig.model_validate(data)
        with EmulatedGantry(cfg, "cook-torrance:d=beckmann,m=0.3,metal=gold", clock=clock,
                            any_port=True, referenced=True) as emu, tempfile.TemporaryDirectory() as d:
            cfg = emu.config()
            c = create_campaign(d, cfg, grid=grid, material=None, sample="bench")
            poses, steps = c.meta["poses"], c.journal.step_count()
            gantry = build_gantry(cfg, clock=clock)
            gantry.concurrent = {"plain": False, "at once": True}.get(modbus)
            split.s.clear()
            split.n.clear()
            sent = {n: len(getattr(e, "received", getattr(e, "requests", [])))
                    for n, e in emu.emulators.items()}
            t, emu_cpu = time.perf_counter(), _emulator_cpu()
            state, _ = run_campaign(c, _PerAxis(gantry) if per_axis else gantry)
            wall = time.perf_counter() - t
            emu_cpu = _emulator_cpu() - emu_cpu
            c.close()
            dxl = sum(len(e.received) - sent[n] for n, e in emu.emulators.items() if hasattr(e, "servos"))
            mb = sum(len(e.requests) - sent[n] for n, e in emu.emulators.items() if hasattr(e, "profile"))
    finally:
        split.undo()
    return dict(wall=wall, state=state, poses=poses, steps=steps, gantry_s=clock.now(), s=split.s, n=split.n,
                dxl=dxl, mb=mb, emu=emu_cpu - split.cpu["render"])


def _report(twin, grid, how, repeat, *, wall, state, poses, steps, gantry_s, s, n, dxl, mb, emu):
    ms = {k: 1e3 * v / poses for k, v in s.items()}
    render = ms.get("render", 0.0)
    parts = {"driver round trips": ms.get("driver", 0.0) - render,
             "watchdog feeding reads (during the motion on a real gantry)": ms.get("feeding", 0.0),
             "safe-path planning": ms.get("planning", 0.0), "journal": ms.get("journal", 0.0)}
    parts["runner and the rest"] = 1e3 * wall / poses - render - sum(parts.values())
    print(f"campaign {twin} {grid}, {how}, best of {repeat}: {state}, {poses} poses / {steps} steps, "
          f"gantry time {gantry_s:.0f} s, wall {wall:.2f} s = {1e3 * wall / poses:.2f} ms per pose, of which "
          f"the emulated detector's Dr.Jit render {render:.2f} ms ({n['render']} renders) and through the "
          f"drivers {1e3 * wall / poses - render:.2f} ms:")
    print("    " + ", ".join(f"{k} {v:.2f} ms" for k, v in parts.items())
          + f"; per pose {dxl / poses:.1f} Dynamixel instruction packets, {mb / poses:.1f} Modbus requests")
    through, own = 1e3 * wall / poses - render, 1e3 * emu / poses
    print(f"    the emulators' own work (their threads' CPU, less the render's) {own:.2f} ms per pose: "
          f"gonio's overhead through the drivers without it {through - own:.2f} ms")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=300, help="repetitions per figure")
    ap.add_argument("--grid", default="iso:step=15", help="GRID of the campaign benchmark")
    ap.add_argument("--repeat", type=int, default=3, help="campaigns per figure (the best is shown)")
    ap.add_argument("--only", choices=("dynamixel", "modbus"), help="benchmark one family only")
    args = ap.parse_args()
    families = (args.only,) if args.only else ("dynamixel", "modbus")
    print("load average (1, 5, 15 min): " + " ".join(f"{x:.2f}" for x in os.getloadavg()))
    for twin in ("emulated-two-arm-dynamixel", "emulated-sample-stage-modbus"):
        if not any(f in twin for f in families):
            continue
        bench_campaigns(twin, args.grid, args.repeat)
    if "dynamixel" in families:
        for k in (2, 4, 8):
            bench_dynamixel(k, args.n)
    if "modbus" in families:
        for t in ("tcp", "rtu"):
            bench_modbus(t, max(20, args.n // 3))
        bench_modbus_looks(max(20, args.n // 3))
    print("load average at the end: " + " ".join(f"{x:.2f}" for x in os.getloadavg()))


if __name__ == "__main__":
    main()
