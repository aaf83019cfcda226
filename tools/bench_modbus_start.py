"""How far apart emulated Modbus axes start: one synchronized start against one move after another.

Every unit is an emulated Oriental Motor AZ (direct data operation) on the wall clock; each records the
wall time (perf_counter) at which a trigger started its move. Per start, the skew is the latest start
less the earliest. Side by side:

- ``sequential``: each axis's ``move_to`` in turn (a block write with trigger 1, answered, and the start
  check), what a gantry does without a synchronized start;
- ``back_to_back``: the AZ units each behind its own Modbus TCP gateway (the shipped
  emulated-sample-stage-modbus config), the moves preloaded, the triggers sent on every connection before
  any reply is read (:class:`gonio.drivers.modbus.ModbusStartGroup`);
- ``group`` and ``broadcast``: the units on one RTU line (a pty), one query that every unit executes.

``--campaign GRID``: instead, a campaign of GRID on the emulated sample stage (each AZ unit behind its
own TCP gateway, on a :class:`SyncedVirtualClock`), its AZ axes' ``sync_start`` "off" (axis by axis)
then "auto" (back_to_back): per pose move that starts two axes or more (the starts at one instant of the
gantry clock), the wall-time skew of their starts.

Usage: ``python tools/bench_modbus_start.py [--axes N] [--starts N] [--campaign GRID]``
"""

from __future__ import annotations

import argparse
import statistics

from gonio.clock import WallClock
from gonio.drivers.modbus import ModbusAxis, ModbusStartGroup, make_client
from gonio.sim.emulators.modbus import ModbusBusEmulator, ModbusMotorEmulator

AZ = "oriental_az_direct"


def _axis(name, client, unit, clock):
    return ModbusAxis(name, client, AZ, device_id=unit, limits_deg=(-180.0, 180.0), gear_ratio=18.0,
                      velocity_deg_s=60.0, accel_deg_s2=120.0, clock=clock)


def _skews(units, axes, start, starts: int) -> list[float]:
    out = []
    for k in range(starts):
        target = 5.0 if k % 2 == 0 else -5.0
        marks = [len(u.starts) for u in units]
        start(axes, target)
        assert all(len(u.starts) == m + 1 for u, m in zip(units, marks, strict=True))
        t = [u.starts[-1][2] for u in units]
        out.append(max(t) - min(t))
        for a in axes:
            a.stop()
    return out


def _sequential(axes, target):
    for a in axes:
        a.move_to(target)


def _synchronized(group):
    return lambda axes, target: group.start({a.name: (target, None, None) for a in axes})


def bench_tcp(n: int, starts: int) -> dict[str, list[float]]:
    clock = WallClock()
    units = [ModbusMotorEmulator(AZ, clock=clock) for _ in range(n)]
    axes = []
    try:
        for i, u in enumerate(units):
            u.assume_referenced()
            host, port = u.start_tcp()
            axes.append(_axis(f"ax{i}", make_client(f"tcp://{host}:{port}", timeout_s=1.0), 1, clock))
            axes[-1].connect()
        group = ModbusStartGroup(axes, "back_to_back")
        spread = []

        def start(axes, target):
            _synchronized(group)(axes, target)
            spread.append(group.send_spread_s)

        out = {"tcp sequential": _skews(units, axes, _sequential, starts),
               "tcp back_to_back": _skews(units, axes, start, starts)}
        out["  its sends alone"] = spread
        return out
    finally:
        for a in axes:
            a.close()
        for u in units:
            u.stop()


def bench_rtu(n: int, starts: int) -> dict[str, list[float]]:
    clock = WallClock()
    units = [ModbusMotorEmulator(AZ, clock=clock, device_id=i + 1) for i in range(n)]
    for u in units:
        u.assume_referenced()
    bus = ModbusBusEmulator(units)
    client = make_client(f"rtu://{bus.start_rtu()}?baudrate=115200", timeout_s=1.0)
    axes = [_axis(f"ax{i}", client, i + 1, clock) for i in range(n)]
    try:
        for a in axes:
            a.connect()
        out = {"rtu sequential": _skews(units, axes, _sequential, starts)}
        group = ModbusStartGroup(axes, "group")
        out["rtu group"] = _skews(units, axes, _synchronized(group), starts)
        out["rtu broadcast"] = _skews(units, axes, _synchronized(ModbusStartGroup(axes, "broadcast")), starts)
        return out
    finally:
        client.close()
        bus.stop()


def bench_campaign(grid: str) -> dict[str, list[float]]:
    """Per pose move starting several AZ axes: the wall skew of their starts, axis by axis and together."""
    import tempfile
    from pathlib import Path

    from gonio.campaign import create_campaign
    from gonio.config import load_config, parse_config
    from gonio.lifecycle import run_campaign
    from gonio.sim.emulators.gantry import EmulatedGantry
    from gonio.sim.emulators.link import SyncedVirtualClock
    from gonio.wiring import build_gantry

    out = {}
    for mode, label in (("off", "campaign, axis by axis"), ("auto", "campaign, back_to_back")):
        data = load_config("emulated-sample-stage-modbus").model_dump(mode="json")
        for axis in data["axes"].values():
            if axis.get("profile") == AZ:
                axis["sync_start"] = mode
        clock = SyncedVirtualClock()
        with tempfile.TemporaryDirectory(prefix="bench-modbus-start-") as tmp, \
                EmulatedGantry(parse_config(data), "lambert:albedo=0.5", clock=clock, any_port=True,
                               referenced=True) as emu:
            cfg = emu.config()
            c = create_campaign(Path(tmp) / "c", cfg, grid=grid, material=None, sample="bench")
            try:
                run_campaign(c, build_gantry(cfg, clock=clock))
            finally:
                c.close()
            moves: dict[float, list[float]] = {}
            for m in emu.motors.values():
                for t, _i, wall in m.starts:
                    moves.setdefault(t, []).append(wall)
            out[label] = [max(w) - min(w) for w in moves.values() if len(w) > 1]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--axes", type=int, default=4)
    ap.add_argument("--starts", type=int, default=20)
    ap.add_argument("--campaign", metavar="GRID", help="a campaign's pose moves instead (e.g. iso:step=30)")
    args = ap.parse_args()
    if args.campaign:
        rows = bench_campaign(args.campaign)
        print(f"{args.campaign} on emulated-sample-stage-modbus, n pose moves starting 2+ AZ axes: "
              "skew = latest start - earliest (ms, wall)")
    else:
        rows = {**bench_tcp(args.axes, args.starts), **bench_rtu(args.axes, args.starts)}
        print(f"{args.axes} emulated AZ units, {args.starts} starts each: "
              "skew = latest start - earliest (ms)")
    print(f"{'how':<24} {'n':>4} {'median':>8} {'max':>8}")
    for name, skews in rows.items():
        print(f"{name:<24} {len(skews):4d} {1e3 * statistics.median(skews):8.3f} {1e3 * max(skews):8.3f}")


if __name__ == "__main__":
    main()
