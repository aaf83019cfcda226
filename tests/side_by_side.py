"""Independent scenarios of one test (each its own emulators, ports, clock and folder) run at once, each in a
thread of its own, so that what they wait for (reply deadlines, wall-clock motion, a serial client's polls)
is waited for together.

The collector's automatic runs are held off while they run: a full collection stops every thread of the
process (it holds the GIL), and in a worker that keeps the collected suite and its cached plans (up to a
million objects) one lasts 0.2-1 s, longer than the reply deadlines (0.1-0.5 s) the scenarios' drivers
wait with, so a reply the emulator's thread had not been let send counted as late. Their garbage is
collected after them."""

from __future__ import annotations

import gc
import threading
import time
from collections.abc import Callable


def side_by_side(scenarios: dict[str, Callable[[], object]], limit_s: float = 60.0) -> dict[str, object]:
    """Run ``scenarios`` (name -> function) at once; return name -> what each returned. Fails naming every
    scenario that failed (the first one's error chained), or one that did not end within ``limit_s``."""
    errors: dict[str, BaseException] = {}
    results: dict[str, object] = {}

    def run(name, fn):
        try:
            results[name] = fn()
        except BaseException as exc:  # reported below, by name
            errors[name] = exc

    threads = [threading.Thread(target=run, args=item, name=f"scenario {item[0]}", daemon=True)
               for item in scenarios.items()]
    collecting = gc.isenabled()
    gc.disable()
    try:
        for t in threads:
            t.start()
        deadline = time.monotonic() + limit_s
        for t in threads:
            t.join(max(0.0, deadline - time.monotonic()))
    finally:
        if collecting:
            gc.enable()
    assert not [t.name for t in threads if t.is_alive()], f"a scenario did not end within {limit_s} s"
    if errors:
        name = sorted(errors)[0]
        raise AssertionError(f"scenarios {sorted(errors)} of {len(scenarios)} failed; {name}: "
                             f"{type(errors[name]).__name__}: {errors[name]}") from errors[name]
    return results


def each_side_by_side(scenario: Callable[[str], object], names, limit_s: float = 60.0) -> dict[str, object]:
    """``scenario(name)`` for each of ``names``, side by side (:func:`side_by_side`)."""
    return side_by_side({name: (lambda name=name: scenario(name)) for name in names}, limit_s)
