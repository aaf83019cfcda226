"""Benchmark: how long a stop takes, for the pieces a campaign, a test or ``gonio serve`` stops often.

1. The daemon's HTTP server served from a thread (:func:`gonio.daemon.server.start_in_thread`), one
   ``GET /health`` on it, then :meth:`Running.stop` (the queue, the server's thread, the planner).
2. Each emulator kind started and stopped: the PM100 on a pty and on loopback TCP, a Dynamixel bus, a
   Modbus unit over TCP and over RTU (a pty and its relay).
3. A line instrument's ``socket://`` port (pyserial) closed.

Medians and maxima of ``--n`` stops each, in milliseconds. To compare two trees, run this file with each
tree's interpreter (its ``gonio`` imported from that tree), one after the other:

Run: .venv/bin/python tools/bench_stops.py [--n 10]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path


def _ms(samples: list[float]) -> str:
    return f"median {1e3 * statistics.median(samples):7.2f} ms, max {1e3 * max(samples):7.2f} ms"


def daemon_stops(n: int) -> list[float]:
    import httpx

    from gonio.config import load_config
    from gonio.daemon.server import build_daemon, start_in_thread

    cfg, out = load_config(), []
    with tempfile.TemporaryDirectory(prefix="bench-stops-") as tmp:
        for i in range(n):
            d = build_daemon(cfg, Path(tmp) / f"data{i}", plan_idle=False)
            r = start_in_thread(d)
            with httpx.Client(base_url=r.url) as c:
                c.get("/health").raise_for_status()
            t0 = time.perf_counter()
            r.stop()
            out.append(time.perf_counter() - t0)
    return out


def emulator_stops(n: int) -> dict[str, list[float]]:
    from gonio.clock import VirtualClock
    from gonio.sim.emulators.dynamixel import DynamixelBusEmulator, EmulatedServo
    from gonio.sim.emulators.modbus import ModbusMotorEmulator
    from gonio.sim.emulators.scpi import Pm100Emulator
    from gonio.sim.emulators.tcp_link import TcpLink

    def pm100_pty():
        e = Pm100Emulator(lambda exposure_s: 1e-6, clock=VirtualClock())
        e.start()
        return e.stop

    def pm100_tcp():
        e = Pm100Emulator(lambda exposure_s: 1e-6, clock=VirtualClock(), link=TcpLink())
        e.start()
        return e.stop

    def dynamixel():
        e = DynamixelBusEmulator([EmulatedServo(1, clock=VirtualClock())])
        e.start()
        return e.stop

    def modbus_tcp():
        e = ModbusMotorEmulator(clock=VirtualClock())
        e.start_tcp()
        return e.stop

    def modbus_rtu():
        e = ModbusMotorEmulator(clock=VirtualClock())
        e.start_rtu()
        return e.stop

    out = {}
    for name, make in [("PM100 emulator, pty", pm100_pty), ("PM100 emulator, TCP", pm100_tcp),
                       ("Dynamixel bus emulator", dynamixel), ("Modbus emulator, TCP", modbus_tcp),
                       ("Modbus emulator, RTU", modbus_rtu)]:
        out[name] = []
        for _ in range(n):
            stop = make()
            time.sleep(0.01)   # serving: its thread waits on the link
            t0 = time.perf_counter()
            stop()
            out[name].append(time.perf_counter() - t0)
    return out


def socket_closes(n: int) -> list[float]:
    import socket

    from gonio.drivers.serial.transport import open_transport

    out = []
    with socket.create_server(("127.0.0.1", 0)) as srv:
        port = srv.getsockname()[1]
        for _ in range(n):
            t = open_transport(f"socket://127.0.0.1:{port}", 115200, b"\n")
            conn, _ = srv.accept()
            t0 = time.perf_counter()
            t.close()
            out.append(time.perf_counter() - t0)
            conn.close()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10, help="stops of each kind (default 10)")
    n = ap.parse_args().n
    import gonio

    print(f"gonio from {Path(gonio.__file__).parent.parent}")
    print(f"{'daemon: Running.stop':28s} {_ms(daemon_stops(n))}")
    for name, samples in emulator_stops(n).items():
        print(f"{name:28s} {_ms(samples)}")
    print(f"{'socket:// port close':28s} {_ms(socket_closes(n))}")


if __name__ == "__main__":
    main()
