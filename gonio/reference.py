"""Referencing: finding where the axes are after power-up (``gonio gantry reference``).

An axis whose absolute position a power cycle loses (an extended-position Dynamixel behind a gear, whose
count restarts within one turn; an incremental stepper) is *unreferenced* until referenced, and nothing
moves it: :func:`refusal` is the one line that says so, and every mover (``gonio gantry
move|home|jog``, ``gonio run``, the daemon, the runner itself through the drivers) gives it. Each axis's
``[axes.NAME] reference`` method:

``index``
    The axis stands at ``reference_deg`` within half a servo turn (a mark, a pin): the turns are taken
    from there, the fine position from the encoder. Nothing moves.
``hard_stop``
    A Dynamixel XM430 approaches a mechanical stop at ``reference_deg`` slowly, in current-based position
    mode with Goal Current ``reference_current_a``, until it stalls there; the turns come from the
    stall, the fine position from the encoder (a stall more than a quarter turn from where the stop
    should be is refused: something else stopped it). Its position being unknown, its path cannot be
    planned; the axes the kinematics couple to it (the other carriage of a shared ring) move along at
    the same speed in the same direction, so that they keep their distance.
``origin``
    A Modbus controller runs its own return-to-origin operation and reports the origin set.

The reference lives where a power cycle erases it (the servo's RAM, the controller's origin flag), so a
restart of gonio keeps it and a power cycle does not; each campaign journals it when it starts
(:func:`journal_references`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping

from gonio.protocols import DeviceFault, Follows, ReferencesIndex, ReferencesOrigin, Referencing, SeeksStop

__all__ = ["unreferenced", "refusal", "reference_axes", "references", "journal_references", "STALL_S",
           "METHODS"]

#: Seconds an approach that slowed down must then stand still to count as stalled against its stop.
STALL_S = 0.3
#: Times an approach interrupted by a transient fault (no reply, a bus watchdog that fired while the
#: host was held up) starts again before the reference gives up.
RESUMES = 3


#: The ability protocol each reference method needs of its axis.
METHODS = {"index": ReferencesIndex, "hard_stop": SeeksStop, "origin": ReferencesOrigin}


def _referencing(axes: Mapping) -> dict:
    return {n: a for n, a in axes.items() if isinstance(a, Referencing) and a.reference_method != "none"}


def unreferenced(axes: Mapping) -> list[str]:
    """The names of the axes (connected) whose position cannot be trusted until they are referenced."""
    return [n for n, a in _referencing(axes).items() if not a.referenced()]


def refusal(names: list[str]) -> str:
    """The one line that refuses to move while ``names`` are unreferenced."""
    if len(names) == 1:
        what, whose = f"axis '{names[0]}' is", "its"
    else:
        what, whose = f"axes {', '.join(repr(n) for n in names)} are", "their"
    return (f"{what} not referenced ({whose} absolute position is unknown since the controller powered "
            "up): run `gonio gantry reference --config FILE` first")


def references(axes: Mapping) -> list[dict]:
    """What is known of each referencing axis's reference: name, method, referenced, when (Unix s)."""
    out = []
    for name, axis in _referencing(axes).items():
        info = axis.reference_info()
        out.append({"axis": name, "method": axis.reference_method, "referenced": axis.referenced(),
                    "stamp": info.get("stamp")})
    return out


def journal_references(journal, axes: Mapping, campaign_s: float) -> None:
    """One ``reference`` event with every referencing axis's reference (none: no event)."""
    refs = references(axes)
    if not refs:
        return
    parts = []
    for r in refs:
        when = (time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(r["stamp"])) if r["stamp"]
                else "at an unrecorded time")
        parts.append(f"{r['axis']} referenced ({r['method']}) {when}" if r["referenced"]
                     else f"{r['axis']} NOT referenced ({r['method']})")
    journal.log_event("reference", message="; ".join(parts), campaign_s=campaign_s)


def reference_axes(gantry, cfg, names: list[str] | None = None, *,
                   out: Callable[[str], None] = print) -> dict:
    """Reference ``names`` (default: every axis with a method other than ``none``), in config order,
    by their configured methods; the axes must be connected. Returns name -> how far (°) the found
    position lay from where the config put the stop or index (0 for ``origin``).

    Raises
    ------
    DeviceFault
        A method failed (no stall within the time the travel needs, a stall away from the stop, a
        controller that does not report the origin set); the axis stays unreferenced.
    """
    axes = dict(gantry.all_axes)
    todo = _referencing(axes)
    names = list(todo) if names is None else names
    found = {}
    for name in names:
        axis = todo.get(name)
        if axis is None:
            continue
        method, a = axis.reference_method, cfg.axes[name]
        ability = METHODS.get(method)
        if ability is None:  # pragma: no cover - the config allows no other
            raise ValueError(f"axes.{name}.reference: unknown method {method!r}")
        if not isinstance(axis, ability):
            raise DeviceFault(name, f"reference method '{method}': its driver cannot reference that way")
        if method == "index":
            found[name] = axis.reference_index(a.reference_at_deg)
        elif method == "hard_stop":
            found[name] = _hard_stop(gantry, cfg, name, out)
        else:  # origin
            axis.reference_origin(cfg.runner.move_timeout_s, cfg.runner.poll_s)
            found[name] = 0.0
        off = round(found[name], 2) + 0.0   # + 0.0: a found stop 0.001° short reads +0.00, not -0.00
        out(f"{name}: referenced ({method}" + (f", {off:+.2f}° from {a.reference_at_deg:g}°)"
                                               if method != "origin" else ")"))
    return found


def _hard_stop(gantry, cfg, name: str, out) -> float:
    """Seek the stop of ``name``, its coupled axes along (see the module docstring)."""
    axes = gantry.all_axes
    a, axis, rc = cfg.axes[name], axes[name], cfg.runner
    partners = [axes[p] for p in gantry.kinematics.coupled_axes(name)]
    for p in partners:
        if not isinstance(p, Follows):
            raise DeviceFault(name, f"a hard-stop reference moves it without a planned path, so '{p.name}' "
                              "must follow it, which its driver cannot")
    toward, speed, accel = a.reference_toward, a.reference_speed_deg_s, a.max_accel_deg_s2
    travel = (a.max_deg - a.min_deg) + 360.0 / a.gear_ratio  # from anywhere in its range, and a turn
    clock = gantry.clock
    out(f"{name}: seeking its stop at {a.reference_at_deg:g}° ({'+' if toward > 0 else '-'} direction, "
        f"{speed:g}°/s, at most {a.reference_current_a:g} A)"
        + (f", {', '.join(p.name for p in partners)} along" if partners else ""))
    limit = travel / speed + 2.0 * speed / accel + 5.0
    for resumed in range(RESUMES + 1):
        try:
            partners_stopped = _approach(axis, partners, clock, rc, name, toward, speed, accel,
                                         a.reference_current_a, travel, limit)
            break
        except DeviceFault as exc:
            for p in partners:
                _quietly(p.follow_stop)
            _quietly(axis.seek_abort)
            if not exc.transient or resumed == RESUMES:
                raise
            # A reply lost or late, a watchdog that fired while this host was held up: nothing is known
            # of the stop yet, so the approach starts again from where the axes stand.
            out(f"{exc}; the approach starts again ({resumed + 1} of {RESUMES})")
        except BaseException:
            for p in partners:
                _quietly(p.follow_stop)
            _quietly(axis.seek_abort)
            raise
    if not partners_stopped:
        for p in partners:
            p.follow_stop()
    try:
        return axis.seek_end(a.reference_at_deg)
    except BaseException:
        _quietly(axis.seek_abort)
        raise


def _approach(axis, partners, clock, rc, name: str, toward: int, speed: float, accel: float,
              current_a: float, travel: float, limit: float) -> bool:
    """One approach of ``axis`` to its stop, ``partners`` along, until it stalls there; returns whether
    the partners were stopped on the way. A fault leaves the axes moving (the caller stops them)."""
    axis.seek_start(toward, speed, accel, current_a, travel)
    partners_stopped = False
    for p in partners:
        p.follow_start(toward, speed, accel, travel)
    start = clock.now()
    slowed: tuple[float, float] | None = None  # (clock, position) when the approach slowed down
    last: tuple[float, float, float] | None = None     # (clock, position, half the read's duration)
    v_seen = False
    while True:
        clock.sleep(rc.poll_s)
        asked = clock.now()
        state = axis.seek_state()
        answered = clock.now()
        # The position was read somewhere between the request and the reply: a slow round trip (a
        # loaded host) must not make the travel between two looks seem shorter than it was.
        now, half = 0.5 * (asked + answered), 0.5 * (answered - asked)
        for p in partners:
            p.seek_state()  # also feeds its watchdog
        # Slowed, once past the acceleration: less than a quarter of the approach's travel since the
        # last look (over the least time that can have passed between the two reads), or (where the
        # servo reports its velocity: it was seen at speed) its velocity under a quarter of the
        # approach's, which shows the stop a look earlier.
        v_seen = v_seen or abs(state.velocity_deg_s) >= 0.5 * speed
        moved = None if last is None else abs(state.position_deg - last[1])
        crept = (moved is not None and last[0] - start >= speed / accel
                 and moved < 0.25 * speed * (now - last[0] - half - last[2]))
        braked = v_seen and now - start >= speed / accel and abs(state.velocity_deg_s) < 0.25 * speed
        if slowed is None and (crept or braked):
            # At the first sign of the stop the followers stop: the carriages' distance changes
            # by no more than one look of travel.
            for p in partners:
                p.follow_stop()
            partners_stopped = True
            slowed = (now, state.position_deg)
        last = (now, state.position_deg, half)
        if slowed is not None:
            if abs(state.position_deg - slowed[1]) > max(0.5, 0.25 * speed * STALL_S):
                raise DeviceFault(name, f"the approach slowed at {slowed[1]:.2f}° (unreferenced) and "
                                  "then moved on: no stop there (a tight spot?); nothing is referenced: "
                                  "check the mechanics and run it again")
            if now - slowed[0] >= STALL_S:
                break
        if now - start > limit:
            raise DeviceFault(name, f"found no stop within {limit:.0f} s ({travel:.0f}° at "
                              f"{speed:g}°/s): is reference_deg/reference_direction right?")
    return partners_stopped


def _quietly(fn) -> None:
    try:
        fn()
    except Exception:  # the first failure is the one reported
        pass
