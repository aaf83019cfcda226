"""Emulators of real devices, for running the real driver libraries without hardware.

Each emulator speaks a device's wire protocol over a pty or a loopback socket, runs in its own thread with
bounded waits and a clean ``stop()``, and applies injectable faults (dropped, corrupt or truncated replies,
delays, hardware error bits, alarms, exception responses, disconnects).

- :mod:`gonio.sim.emulators.dynamixel`: a Dynamixel Protocol 2.0 bus of X-series servos (pty).
- :mod:`gonio.sim.emulators.modbus`: a Modbus motor controller (pymodbus server; TCP or RTU over a pty).
- :mod:`gonio.sim.emulators.instruments`: line-based serial light source, power meter and spectrometer.
"""
