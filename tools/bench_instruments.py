"""Benchmark: what PyVISA costs beside pyserial for the serial instruments (the evidence for the README's
Dependencies section and drivers/README.md).

1. Import time, each in a fresh interpreter that has numpy loaded already (gonio always has): ``import
   serial`` against ``import pyvisa`` + ``ResourceManager('@py')`` (paid only when a port is a VISA
   resource string).
2. One query round trip (``*IDN?``) and one whole PM100 reading (configure, INIT, *OPC?, SYST:ERR?, FETC?)
   through the driver against the PM100 emulator, over a pty and over loopback TCP, through pyserial
   (``/dev/pts/N``, ``socket://``) and through PyVISA (``ASRL...::INSTR``, ``TCPIP0::...::SOCKET``), side
   by side in one run; and the reading as it was before the driver held silent setters for the query
   after them ("setters written alone": each group its own write, which over TCP waits for the
   instrument's delayed acknowledgement, Nagle).

The emulator runs in a Python thread on the same machine: the figures are driver + library + emulator.

Run: .venv/bin/python tools/bench_instruments.py [--n 300]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
from functools import partial

from bench_drivers import timed

from gonio.clock import VirtualClock
from gonio.drivers.serial import SerialPowerMeter
from gonio.sim.emulators.scpi import Pm100Emulator
from gonio.sim.emulators.tcp_link import TcpLink

TRANSPORTS = {
    "pyserial pty": (lambda: None, lambda emu: emu.port),
    "pyvisa ASRL (pty)": (lambda: None, lambda emu: f"ASRL{emu.port}::INSTR"),
    "pyserial socket://": (TcpLink, lambda emu: f"socket://{emu.port}"),
    "pyvisa TCPIP SOCKET": (TcpLink, lambda emu: f"TCPIP0::127.0.0.1::{emu.link.tcp_port}::SOCKET"),
}


def import_ms(code: str, runs: int = 5) -> float:
    prog = ("import numpy, time; t = time.perf_counter(); " + code +
            "; print((time.perf_counter() - t) * 1e3)")
    out = [subprocess.run([sys.executable, "-c", prog], capture_output=True, text=True, check=True).stdout
           for _ in range(runs)]
    return statistics.median(float(x) for x in out)


class _WrittenAlone(SerialPowerMeter):
    """The baseline: each group of silent setters written at once, not with the query after it."""

    def _send(self, lines):
        super()._send(lines)
        held, self._held = self._held, b""
        self._t.write(held)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=300, help="round trips per figure")
    args = ap.parse_args()
    print(f"import serial: {import_ms('import serial'):.1f} ms; import pyvisa + ResourceManager('@py'): "
          f"{import_ms('import pyvisa; pyvisa.ResourceManager(chr(64) + chr(112) + chr(121))'):.1f} ms "
          "(median of 5 fresh interpreters, numpy loaded)")
    for name, (link, port) in TRANSPORTS.items():
        for cls, how in ((SerialPowerMeter, ""), (_WrittenAlone, ", setters written alone")):
            clock = VirtualClock()
            emu = Pm100Emulator(lambda exposure_s: 1e-6, clock=clock, link=link())
            emu.start()
            dev = cls("pm", port(emu), "thorlabs-pm100", wavelength_nm=633.0, clock=clock)
            try:
                dev.connect()
                q = timed(dev.identify, args.n)
                r = timed(partial(dev.measure, 0.003), max(args.n // 5, 10))
            finally:
                dev.close()
                emu.stop()
            print(f"{name + how:<44} *IDN? round trip {q[0]:.3f} ms (p95 {q[1]:.3f}); one PM100 reading "
                  f"{r[0]:.2f} ms (p95 {r[1]:.2f})")


if __name__ == "__main__":
    main()
