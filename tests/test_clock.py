"""The clocks: a virtual one that only moves when told, the wall clock of hardware; both refuse nonsense."""

import math

import pytest

from gonio.clock import VirtualClock, WallClock


def test_virtual_clock_moves_only_by_sleep_and_starts_where_told():
    c = VirtualClock(start=12.5)
    assert c.now() == 12.5
    c.sleep(0.25)
    c.sleep(0)
    assert c.now() == 12.75
    assert VirtualClock.real_time is False and WallClock.real_time is True


@pytest.mark.parametrize("clock", [VirtualClock(), WallClock()], ids=["virtual", "wall"])
@pytest.mark.parametrize("bad", [-1.0, -1e-12, math.nan, math.inf])
def test_sleep_refuses_negative_nan_and_infinite_durations(clock, bad):
    before = clock.now() if isinstance(clock, VirtualClock) else None
    with pytest.raises(ValueError, match="sleep: seconds must be a finite number >= 0"):
        clock.sleep(bad)
    if before is not None:
        assert clock.now() == before


def test_sleep_until_lands_exactly_and_never_goes_back():
    c = VirtualClock(start=0.1)
    t = 0.1 + 0.2 + 1e-9
    c.sleep_until(t)
    assert c.now() == t  # not 0.1 + (t − 0.1), which can miss t by an ulp
    c.sleep_until(0.0)
    assert c.now() == t
    w = WallClock()
    w.sleep_until(w.now() - 1.0)  # in the past: returns at once


def test_a_virtual_clock_that_watches_its_sleeps_sees_sleep_until_too():
    """sleep_until skips sleep() only where sleep() is VirtualClock's own: a subclass that overrides
    it (a paced clock, a test's hook) sees every advance, and an infinite one is refused either way."""
    seen = []

    class Watched(VirtualClock):
        def sleep(self, seconds):
            seen.append(seconds)
            super().sleep(seconds)

    c = Watched(start=1.0)
    c.sleep_until(1.5)
    c.sleep_until(1.25)   # in the past: no sleep
    assert seen == [0.5] and c.now() == 1.5
    for clock in (VirtualClock(), Watched()):
        with pytest.raises(ValueError, match="finite"):
            clock.sleep_until(float("inf"))
