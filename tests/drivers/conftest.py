"""Fixtures for the driver tests: emulators on a virtual clock, each stopped when its test ends."""

from __future__ import annotations

import pytest

from gonio.clock import VirtualClock
from gonio.sim.emulators.dynamixel import DynamixelBusEmulator, EmulatedServo


@pytest.fixture
def clock():
    return VirtualClock()


@pytest.fixture
def dxl_emu(clock):
    """A bus with two XM430-W350 (IDs 1, 2) and one XL430-W250 (ID 3)."""
    emu = DynamixelBusEmulator([EmulatedServo(1, clock=clock), EmulatedServo(2, clock=clock),
                                EmulatedServo(3, "XL430-W250", clock=clock)])
    emu.start()
    try:
        yield emu
    finally:
        emu.stop()
    # a thread a driver's bytes killed would otherwise show only as the driver's time-outs
    assert emu.error is None, f"the bus emulator's thread died of {emu.error!r}"
