"""The assembled gantry asking its Modbus connections at once: each axis gets its own controller's values,
a fault in one controller raises naming that axis once every connection has answered, and axes that
share one connection (an RTU bus) are never asked at the same time."""

from __future__ import annotations

import threading
from types import SimpleNamespace

import numpy as np
import pytest

from gonio.clock import VirtualClock
from gonio.config import load_config, parse_config
from gonio.drivers.modbus import ModbusAlarmError, ModbusExceptionError
from gonio.gantry import CONCURRENT_ABOVE_S, AssembledGantry
from gonio.sim.emulators.gantry import EmulatedGantry
from gonio.sim.emulators.link import SyncedVirtualClock
from gonio.wiring import build_gantry

MATERIAL = "lambert:albedo=0.5"
#: Distinct positions (°) for the sample-stage's four controllers, in kinematics order.
WHERE = {"sample_rotation": -123.45, "sample_tilt": 67.5, "detector_azimuth": 12.0, "detector_tilt": -150.25}


@pytest.fixture
def stage(request):
    """(emulators, connected gantry) of the emulated sample stage (4 AZ controllers on 4 TCP gateways),
    each controller standing at its ``WHERE`` position; all stopped at the end. Indirectly
    parametrized: the AZ axes' ``sync_start`` (default "auto": their moves start together)."""
    data = load_config("emulated-sample-stage-modbus").model_dump(mode="json")
    for name in WHERE:
        data["axes"][name]["sync_start"] = getattr(request, "param", "auto")
    clock = SyncedVirtualClock()
    with EmulatedGantry(parse_config(data), MATERIAL, clock=clock, any_port=True, referenced=True) as emu:
        gantry = build_gantry(emu.config(), clock=clock)
        gantry.connect()
        try:
            for name, deg in WHERE.items():
                emu.motors[name].set_position(gantry.axes[name].steps_for(deg))
            yield emu, gantry
        finally:
            gantry.close()


def _all_at_once(gantry, method: str):
    """Make ``method`` of the four kinematics axes' clients meet at a barrier: a look that does not ask
    the four connections at the same time breaks it (and fails) instead of hanging."""
    barrier = threading.Barrier(len(gantry.axes), timeout=10.0)
    for axis in gantry.axes.values():
        real = getattr(axis.client, method)

        def met(*a, _real=real, **k):
            barrier.wait()
            return _real(*a, **k)

        setattr(axis.client, method, met)
    return barrier


@pytest.mark.parametrize("stage", ["off"], indirect=True)  # moved axis by axis: each move concurrent
def test_a_concurrent_look_returns_each_axiss_own_values(stage):
    emu, gantry = stage
    want = np.array([WHERE[n] for n in gantry.kinematics.axis_names])
    gantry.concurrent = False
    pos_turn, moving = gantry.poll_axes()
    assert not moving and np.allclose(pos_turn, want, atol=0.01)
    gantry.concurrent = True
    _all_at_once(gantry, "read_holding_registers")
    pos, moving = gantry.poll_axes()  # one spanning read per controller, all four in flight together
    assert not moving and np.array_equal(pos, pos_turn)
    assert np.array_equal(gantry.positions(), pos_turn)
    # A move through all four connections at once (function 23 each), then a look while they move.
    _all_at_once(gantry, "readwrite_registers")
    gantry.move_axes({n: 0.0 for n in WHERE})
    assert all(emu.motors[n].moving() for n in WHERE)
    assert gantry.poll_axes() == (None, True)
    gantry.clock.sleep(20.0)
    pos, moving = gantry.poll_axes()
    assert not moving and np.array_equal(pos, np.zeros(4))


def test_a_fault_in_one_controller_during_a_concurrent_look_names_that_axis(stage):
    emu, gantry = stage
    gantry.concurrent = True
    before = {n: len(emu.motors[n].requests) for n in WHERE}
    emu.motors["detector_azimuth"].fail_next(4)  # device failure
    with pytest.raises(ModbusExceptionError) as err:
        gantry.poll_axes()
    assert err.value.device == "detector_azimuth" and err.value.code == 4
    assert {n: len(emu.motors[n].requests) - before[n] for n in WHERE} == dict.fromkeys(WHERE, 1)
    # Two at once: the first in kinematics order is raised, the other is still latched on its axis.
    emu.motors["detector_tilt"].raise_alarm(0x30)
    emu.motors["sample_tilt"].fail_next(6)
    with pytest.raises(ModbusExceptionError) as err:
        gantry.positions()
    assert err.value.device == "sample_tilt" and err.value.transient
    with pytest.raises(ModbusAlarmError) as err:
        gantry.poll_axes()
    assert err.value.device == "detector_tilt" and err.value.alarm_code == 0x30
    assert gantry.axes["detector_tilt"].fault() == "controller alarm 0x0030"
    with pytest.raises(ModbusAlarmError, match="detector_tilt: controller alarm 0x0030 .latched"):
        gantry.move_axes({"sample_rotation": 0.0, "detector_tilt": 0.0})


def test_automatic_concurrency_follows_the_links_round_trips(stage):
    _, gantry = stage
    assert gantry.concurrent is None
    singles = gantry._singles
    assert all(a.round_trip_s is not None for a in gantry.axes.values())  # measured from the connect on
    for axis in gantry.axes.values():  # set here: the measured ones are wall times
        axis.round_trip_s = CONCURRENT_ABOVE_S / 10  # in-process emulators: ~0.1 ms
    assert not gantry._threads(singles)
    for axis in gantry.axes.values():
        axis.round_trip_s = CONCURRENT_ABOVE_S / 2  # e.g. an RTU wire behind each gateway
    assert gantry._threads(singles) and not gantry._threads(singles[:1])  # one connection: in turn
    gantry.concurrent = False
    assert not gantry._threads(singles)


class _SharedClient:
    """A stand-in connection that counts the requests in flight on it."""

    def __init__(self):
        self.busy = 0
        self.most = 0
        self.lock = threading.Lock()

    def ask(self, meet: threading.Barrier | None):
        with self.lock:
            self.busy += 1
            self.most = max(self.most, self.busy)
        try:
            if meet is not None:
                meet.wait()
        finally:
            with self.lock:
                self.busy -= 1


class _Axis:
    """Declares :class:`gonio.protocols.ReadsState` (state in one read) and shares its ``client``."""

    state_in_one_read = True

    def __init__(self, name, client, deg, meet=None):
        self.name, self.client, self.deg, self.meet = name, client, deg, meet

    def connect(self):
        pass

    def close(self):
        pass

    def read_state(self):
        self.client.ask(self.meet)
        return self.deg, False

    def position_deg(self):
        return self.read_state()[0]


def test_axes_on_one_connection_are_asked_in_turn_while_other_connections_go_at_once():
    bus, gateway = _SharedClient(), _SharedClient()
    # a and c share an RTU bus, b has its own gateway. a and b meet at a barrier: the two connections
    # are asked at the same time (else the barrier breaks); c is asked after a, never beside it.
    meet = threading.Barrier(2, timeout=10.0)
    axes = {"a": _Axis("a", bus, 1.0, meet), "b": _Axis("b", gateway, 2.0, meet), "c": _Axis("c", bus, 3.0)}
    detector = SimpleNamespace(name="d", set_target=lambda t: None, connect=lambda: None, close=lambda: None)
    light = SimpleNamespace(name="l", connect=lambda: None, close=lambda: None)
    gantry = AssembledGantry("g", SimpleNamespace(axis_names=("a", "b", "c")), axes, light, detector,
                             clock=VirtualClock())
    gantry.connect()
    try:
        assert gantry._links == [[0, 2], [1]]
        gantry.concurrent = True
        pos, moving = gantry.poll_axes()
        assert not moving and list(pos) == [1.0, 2.0, 3.0]
        assert bus.most == 1 and not meet.broken
    finally:
        gantry.close()


def test_a_manual_move_starts_the_az_axes_together(stage):
    """``gonio gantry move`` (:func:`gonio.manual.drive`) on the emulated sample stage: the axes a leg
    moves start on trigger frames (held moves, back_to_back) at one instant of the gantry clock, and
    arrive; the axis it does not move gets nothing."""
    from gonio.manual import drive

    emu, gantry = stage
    counts = {n: len(emu.motors[n].starts) for n in WHERE}
    names = gantry.kinematics.axis_names
    target = np.array([WHERE[n] + (0.0 if n == "sample_tilt" else 5.0) for n in names])
    got = drive(gantry, [target], cfg=emu.config(), clock=gantry.clock)
    np.testing.assert_allclose(got, target, atol=0.01)
    made = {n: emu.motors[n].starts[counts[n]:] for n in WHERE}
    assert not made.pop("sample_tilt") and all(len(m) == 1 for m in made.values())
    for n, ((t, i, _wall),) in made.items():
        assert emu.motors[n].requests[i][7:10] == bytes([0x10, 0x00, 0x66]), n  # the trigger, alone
        assert t == made["sample_rotation"][0][0]
