"""On-the-fly scanning: the poses of a plan read while one axis sweeps.

A stop-and-go campaign moves, settles and exposes at every pose. Along a line of the grid (a Δφ ring
at fixed θi, θo on the iso grid: on the two-arm gantry the detector carriage turns, nothing else
moves) the poses lie on a straight line in axis space, equally spaced along one axis. A fly campaign
sweeps that axis through the whole line (at its top speed between the ends) and reads the detector,
each reading centred on the time the axis passes a pose.

Lines. :func:`fly_plan` takes the poses of the stop-and-go plan (the serpentine order and its IK
branches, so the same poses are measured) and cuts them into maximal runs where consecutive poses
differ in exactly one axis by the same signed step. A pose that starts no such run is read stop-and-go
(move, settle, expose: a line of one pose, speed 0).

Velocity and exposure. Each line runs rest to rest, from its first reading's pose to its last one's, on
the sweeping axis's trapezoid (its top speed v_max and acceleration a_max; a triangle where the line is
too short to reach v_max), with half an exposure at rest before and after. Each reading exposes for
``FLY_DUTY`` of the time between readings at v_max, so the axis travels at most ``FLY_DUTY`` of a grid
step during one exposure (the motion blur); the readings near the ends are taken while the axis speeds
up or slows down (slower: less blur), and each starts when the axis passes its pose at its mid-time
(:meth:`FlyLine.mid_times`). So no line has a run-up or run-down beyond its end poses: no end pose is
read stop-and-go for want of room before a limit or the other carriage, and no line is slowed for it
(the time-optimal rest-to-rest profile over the line's span: travel beyond it only adds time).

Serpentine passes. Where a line reads the next ring back from the position the line before it ended at
(the same axis, the other direction, only other axes changing: the detector tilt by a grid step), the
turnaround between them is swept (:func:`_turnarounds`): the axis runs on past the last pose (the line's
``tail``) and back (the next line's ``lead``) while the other axes make their change, begun when the last
exposure ends and over before the next line's first begins; the run-out is the one that reads both
lines soonest within the room before a limit or a collision, and every position the turnaround can pass
through lies in a box certified clear (:meth:`Kinematics.box_clear`). Lines so joined form a pass; a
checkpoint between two lines ends a pass (they meet at rest through a safe transit). Coordinated lines
(several axes along a path: :mod:`gonio.plan.flypath`) take the rings that no single axis steps along.

Checks. Each line's whole travel, rest to rest, is one move of one axis between its end poses: its
swept path is the set of positions of the rest-to-rest move between them, so
:meth:`Kinematics.sweep_clearance` certifies it exactly, and both ends are poses of the plan (within
the limits). A line whose sweep between two readings collides is split at the colliding step (a part
of one pose is read stop-and-go). Transits between lines, to and from the white reference and home go
through :func:`gonio.motion.safe.safe_path` like every stop-and-go move.

Checkpoints. A dark and a white-reference reading (stop-and-go, as in every campaign) before the
first line, then between lines once the gantry time since the last reaches the interval (the
config's ``reference.every_s``, or else the stop-and-go plan's own mean gantry time between
references, so the drift correction sees references as often in time), and at the end.

Estimate and bound. The estimate adds the transits (the planner's trapezoid metric,
:class:`~gonio.motion.metric.MoveMetric`, leg by leg along the safe paths), each line's time rest to
rest, settle and exposure of stop-and-go readings, and the checkpoints. The lower bound holds for any
order and direction of these lines, each run rest to rest between its end poses: each line takes at
least the rest-to-rest time of its span at its axis's top speed and acceleration (or its exposures,
(n − 1) · exposure, if longer); before its first reading the gantry must come, at rest, from the end of
another line, a checkpoint or home: at least the rest-to-rest time of the slowest axis's change; each
checkpoint adds its settle and exposures. :func:`physical_floor` is what no fly scan of the poses can
beat: every Δφ step swept once at top speed, no acceleration, no stops.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from gonio.motion.metric import MoveMetric
from gonio.motion.safe import path_time, safe_path
from gonio.motion.trapezoid import move_time
from gonio.plan.flyline import FLY_DUTY, FLY_TOL_DEG, FlyLine
from gonio.plan.flypath import COORDINATED, PathLine, path_line, ring_runs
from gonio.plan.schedule import STEP_REFERENCE, schedule_runs

__all__ = ["FLY_DUTY", "FLY_MOTION", "FLY_TOL_DEG", "FlyLine", "FlyPlan", "fly_plan", "fly_summary",
           "fly_steps", "fly_step_table", "line_lengths", "physical_floor"]

#: The motion model of the lines (journaled in a fly campaign's meta): 2 since lines run rest to rest
#: between their end poses (1, unjournaled: constant velocity with run-ups beyond the ends, slower or
#: trimmed to stop-and-go readings where they had no room). A campaign resumes only under its own model.
FLY_MOTION = 2
#: Above this many lines the entry bound searches a k-d tree instead of every pair (same values).
_PAIRWISE_MAX_LINES = 200
#: Δφ steps per block of the physical floor (memory of the branch-pair temporaries).
_FLOOR_BLOCK = 20000
#: Lines per block of the pairwise bound (memory of the (block, lines, 4, n_axes) temporaries).
_BLOCK = 256


@dataclass
class FlyPlan:
    """A fly campaign over the poses of a stop-and-go :class:`~gonio.plan.build.Plan`.

    Attributes
    ----------
    lines : list of FlyLine
        In campaign order (``line_start_s`` and ``checkpoints`` say when each happens).
    checkpoint_before : ndarray of bool, shape (len(lines) + 1,)
        A dark and a white reference before line k (True), and at the end (the last entry, always True).
    transits : list of ndarray
        Waypoints (k, n_axes) of each move: from home (or the reference) to line 0's start, between
        lines, to and from the reference, home at the end; in order (see :func:`fly_moves`).
    estimated_s, lower_bound_s : float
        The campaign's gantry time and a bound for any order and direction of these lines.
    timing : dict
        Parts of the estimate and of the bound, counts of lines by kind, notes by reason.
    """

    lines: list[FlyLine]
    checkpoint_before: np.ndarray
    reference_deg: np.ndarray
    home_deg: np.ndarray
    settle_s: float
    reading_s: float
    estimated_s: float = 0.0
    lower_bound_s: float = 0.0
    timing: dict = field(default_factory=dict)
    #: Campaign time (s) each line starts, at rest (a stop-and-go reading: its exposure starts).
    line_start_s: np.ndarray | None = None
    #: Per checkpoint, in order: (before line k, dark start s, where the dark is read, reference start s).
    checkpoints: list = field(default_factory=list)
    #: Per line: the rest-to-rest time of the other axes' change when it is entered through a swept
    #: turnaround from the line before (NaN, or None for all: through a transit); a checkpoint between
    #: the two makes it a transit.
    cross: np.ndarray | None = None

    def swept_turn(self, k: int) -> bool:
        """Whether line ``k`` is entered through a swept turnaround from line k − 1."""
        return (k > 0 and self.cross is not None and not np.isnan(self.cross[k])
                and not self.checkpoint_before[k])


def line_lengths(plan: FlyPlan) -> np.ndarray:
    """Readings per line."""
    return np.array([ln.n for ln in plan.lines], dtype=np.int64)


def _runs(axes: np.ndarray) -> list[tuple[int, int, int, float]]:
    """Maximal runs [i, j) of consecutive poses that step along one axis by one signed step:
    (i, j, axis, step); single poses have axis -1."""
    n = axes.shape[0]
    d = np.diff(axes, axis=0)
    moving = np.abs(d) > FLY_TOL_DEG
    one = moving.sum(axis=1) == 1
    ax = np.where(one, np.argmax(moving, axis=1), -1)
    step = np.where(one, d[np.arange(n - 1), np.maximum(ax, 0)], 0.0)
    runs, i = [], 0
    while i < n:
        j = i + 1
        if i < n - 1 and ax[i] >= 0:
            while j < n - 1 and ax[j] == ax[i] and abs(step[j] - step[i]) <= FLY_TOL_DEG:
                j += 1
            j += 1
            runs.append((i, j, int(ax[i]), float(step[i])))
        else:
            runs.append((i, j, -1, 0.0))
        i = j
    return runs


def _lines_of_run(kin, axes, i, j, axis, step, exposure_s) -> list[FlyLine]:
    """The lines a run becomes: split where its sweep collides, each rest to rest between its end
    poses at the axis's top speed and acceleration."""
    pts = axes[i:j]
    clear = kin.sweep_clear(pts[:-1], pts[1:])
    if not clear.all():
        cut = int(np.argmin(clear)) + 1
        head = _lines_of_run(kin, axes, i, i + cut, axis, step, exposure_s) if cut > 1 else \
            [_still(axes, i, "")]
        tail = _lines_of_run(kin, axes, i + cut, j, axis, step, exposure_s) if j - i - cut > 1 else \
            [_still(axes, j - 1, "")]
        note = "split: its sweep collides between two readings"
        for group in (head, tail):
            group[0 if group is tail else -1] = _noted(group[0 if group is tail else -1], note)
        return head + tail
    v_max = float(kin.velocity_deg_s[axis])
    return [FlyLine(np.arange(i, j, dtype=np.int64), axis, pts[0].copy(), step, v_max,
                    float(kin.accel_deg_s2[axis]), exposure_s)]


def _room(kin, at_deg, axis, direction, most) -> float:
    """The longest travel (up to ``most``) of ``axis`` from ``at_deg`` in ``direction`` (+1 or -1) that
    stays within its limits and whose swept path is clear (a longer one sweeps a shorter one's path,
    so clear travels form an interval from 0, found by bisection to ``FLY_TOL_DEG``)."""
    lo, hi = kin.limits_deg[axis]
    x = float(at_deg[axis])
    room = min(most, max(0.0, (hi - x) if direction > 0 else (x - lo)))

    def clear(r):
        end = np.array(at_deg, dtype=np.float64)
        end[axis] = x + direction * r
        return kin.sweep_clear_one(at_deg, end)[0]

    if clear(room):
        return room
    ok, bad = 0.0, room
    while bad - ok > FLY_TOL_DEG:
        mid = 0.5 * (ok + bad)
        ok, bad = (mid, bad) if clear(mid) else (ok, mid)
    return ok


#: Run-outs tried at a turnaround, as fractions of the one whose out-and-back just covers the cross move.
_RUN_OUTS = (0.25, 0.5, 0.75, 1.0, 1.25, 1.5)


def _turnarounds(lines: list[FlyLine], kin) -> np.ndarray:
    """Sweep the turnarounds of serpentine passes: where line k reverses line k − 1 along the same axis
    from the same position (a ring of the next θo, read back), the axis runs on past line k − 1's last
    pose (its ``tail``) and back (line k's ``lead``) while the other axes make their change, which
    starts when line k − 1's last exposure ends and ends before line k's first one starts. The run-out
    is the one (of ``_RUN_OUTS`` times the out-and-back that just covers the change, within the room
    before a limit or collision) that reads both lines soonest; every position of the turnaround lies
    in the box between the two lines' end poses and the run-out, certified by
    :meth:`Kinematics.box_clear`. Sets the lines' tail and lead in place; returns per line the
    rest-to-rest time of the change entering it through a swept turnaround (NaN: entered by a transit).
    """
    v_max = np.asarray(kin.velocity_deg_s, dtype=np.float64)
    a_max = np.asarray(kin.accel_deg_s2, dtype=np.float64)
    cross = np.full(len(lines), np.nan)
    for k in range(1, len(lines)):
        p, q = lines[k - 1], lines[k]
        if not (p.moving and q.moving and p.axis == q.axis >= 0 and p.step_deg * q.step_deg < 0):
            continue
        ax, last, first = p.axis, p.readings_deg()[-1], q.first_deg
        d = np.abs(first - last)
        if d[ax] > FLY_TOL_DEG:
            continue
        t_cross = float(np.delete(move_time(d, v_max, a_max), ax).max())
        a, e = p.accel_deg_s2, 0.5 * (p.exposure_s + q.exposure_s)
        v_e = min(p.speed_deg_s, 0.5 * a * (t_cross + e))
        sign = float(np.sign(p.step_deg))
        room = min(_room(kin, last, ax, sign, v_e * v_e / a), _room(kin, first, ax, sign, v_e * v_e / a))
        best, best_s = 0.0, _turn_s(p, q, t_cross)
        for f in _RUN_OUTS:
            o = min(f * v_e * v_e / (2.0 * a), room)
            lo, hi = np.minimum(last, first), np.maximum(last, first)
            (hi if sign > 0 else lo)[ax] = last[ax] + sign * o
            if o <= FLY_TOL_DEG or not kin.box_clear(lo, hi):
                continue
            t = _turn_s(replace(p, tail=o), replace(q, lead=o), t_cross)
            if t < best_s:
                best, best_s = o, t
        if best > 0.0:
            lines[k - 1], lines[k] = replace(p, tail=best), replace(q, lead=best)
            cross[k] = t_cross
    return cross


def _turn_start_s(p: FlyLine, q: FlyLine, t_cross: float) -> float:
    """When line ``q`` starts after line ``p`` starts, through a swept turnaround whose change of the
    other axes takes ``t_cross``: once p has come to rest, and late enough that the change, begun when
    p's last exposure ends, is over when q's first begins."""
    return max(p.duration_s, p.mid_times()[-1] + 0.5 * p.exposure_s + t_cross
               - (q.mid_times()[0] - 0.5 * q.exposure_s))


def _turn_s(p: FlyLine, q: FlyLine, t_cross: float) -> float:
    """From p's start to q's end through a swept turnaround (or, with neither a tail nor a lead, p, the
    change at rest, q)."""
    if p.tail == 0.0 and q.lead == 0.0:
        return p.duration_s + t_cross + q.duration_s
    return _turn_start_s(p, q, t_cross) + q.duration_s


def _still(axes, k, note) -> FlyLine:
    return FlyLine(np.array([k], dtype=np.int64), -1, axes[k].copy(), 0.0, 0.0, 1.0, 0.0, note)


def _noted(line: FlyLine, note: str) -> FlyLine:
    if not note or line.note:
        return line
    return FlyLine(line.poses, line.axis, line.first_deg, line.step_deg, line.speed_deg_s, line.accel_deg_s2,
                   line.exposure_s, note)


def fly_plan(plan, cfg, kin=None) -> FlyPlan:
    """The fly campaign over ``plan``'s poses (a :class:`~gonio.plan.build.Plan` of an iso or full grid)
    on the gantry ``cfg``: lines, checkpoints, safe transits, the estimate and its lower bound.

    Raises
    ------
    ValueError
        When the grid has no step (merl grids are scattered points: no line to sweep).
    """
    from gonio.plan.grids import parse_grid

    spec = parse_grid(plan.grid)
    if spec.step_deg is None:
        raise ValueError(f"grid '{spec.kind}': order=fly needs lines of a lattice (iso or full grids)")
    if kin is None:
        from gonio.kinematics import make_kinematics

        kin = make_kinematics(cfg)
    metric = MoveMetric(kin.velocity_deg_s, kin.accel_deg_s2)
    axes = np.asarray(plan.axes_deg, dtype=np.float64)
    reading_s = cfg.detector.exposure_s * cfg.detector.frames
    settle_s = cfg.runner.settle_s
    home = np.asarray(kin.home_deg, dtype=np.float64)
    ref = np.asarray(plan.reference_axes_deg, dtype=np.float64)

    lines: list = []
    rest = [None]   # the first pose of a run of poses that step along no single axis

    def flush(j):
        # Poses no single axis sweeps: coordinated lines along the rings among them (several axes
        # moving together, :mod:`gonio.plan.flypath`), the others read stop-and-go.
        if rest[0] is not None:
            for a, b in ring_runs(plan, axes, spec.step_deg, rest[0], j):
                lines.extend(path_line(kin, plan, axes, a, b, spec.step_deg) if b - a > 1 else
                             [_still(axes, a, "")])
        rest[0] = None

    for i, j, axis, step in _runs(axes):
        if axis < 0 or abs(abs(step) - spec.step_deg) > FLY_TOL_DEG:   # not a step along a line of the grid
            rest[0] = i if rest[0] is None else rest[0]
            continue
        flush(i)
        exposure = FLY_DUTY * abs(step) / float(kin.velocity_deg_s[axis])
        lines.extend(_lines_of_run(kin, axes, i, j, axis, step, exposure))
    flush(len(axes))
    lines = [ln if ln.moving else FlyLine(ln.poses, -1, ln.first_deg, 0.0, 0.0, 1.0, reading_s, ln.note)
             for ln in lines]

    interval = cfg.reference.every_s
    if interval is None:
        n_ref = max(int(np.count_nonzero(plan.step_kind == STEP_REFERENCE)), 1)
        interval = plan.estimated_s / n_ref
    cross = _turnarounds(lines, kin)
    fp = FlyPlan(lines, np.zeros(len(lines) + 1, dtype=bool), ref, home, settle_s, reading_s, cross=cross)
    _schedule(fp, kin, metric, float(interval))
    fp.lower_bound_s, bound = _bound(fp, kin, metric)
    fp.timing["lower_bound"] = bound
    fp.timing["reference_interval_s"] = float(interval)
    return fp


def fly_steps(fp: FlyPlan) -> list[tuple[str, int, int]]:
    """The campaign's sweeps and checkpoints in order, each (kind, index, first step): kind
    ``"checkpoint"`` (2 steps: dark, reference) with the line it comes before, or ``"line"`` (one
    step per reading) with the line's index."""
    out, step = [], 0
    c = 0
    for k in range(len(fp.lines) + 1):
        if fp.checkpoint_before[k]:
            out.append(("checkpoint", c, step))
            step += 2
            c += 1
        if k < len(fp.lines):
            out.append(("line", k, step))
            step += fp.lines[k].n
    return out


def fly_step_table(fp: FlyPlan) -> tuple[np.ndarray, np.ndarray]:
    """Kind (STEP_POSE, STEP_DARK, STEP_REFERENCE) and plan pose (-1 for checkpoints) of every step, in
    the order of :func:`fly_steps`: the lines read the plan's poses in its order, so this is the
    stop-and-go schedule with runs starting at the lines that follow a checkpoint."""
    n = int(sum(ln.n for ln in fp.lines))
    starts = [int(ln.poses[0]) for ln, cp in zip(fp.lines, fp.checkpoint_before[:-1], strict=True) if cp]
    return schedule_runs(n, starts)


def _schedule(fp: FlyPlan, kin, metric: MoveMetric, interval: float) -> None:
    """Place the checkpoints (every ``interval`` s of gantry time, between lines) and estimate."""
    here = fp.home_deg
    t = since = 0.0
    parts = {"transit_s": 0.0, "turn_s": 0.0, "line_s": 0.0, "settle_s": 0.0, "reading_s": 0.0,
             "reference_s": 0.0, "via_moves": 0, "turnarounds": 0}

    def go(target):
        nonlocal here
        path = safe_path(kin, here, target)
        dt = path_time(kin, here, path)
        parts["via_moves"] += int(path.shape[0] > 1)
        here = np.asarray(target, dtype=np.float64)
        return dt

    def checkpoint(k):
        # Dark where the gantry stands (shutter closed), then the white reference.
        dark_deg = here.copy()
        dt = fp.reading_s + go(fp.reference_deg) + fp.settle_s
        fp.checkpoints.append((k, t, dark_deg, t + dt))
        dt += fp.reading_s
        parts["reference_s"] += dt
        return dt

    fp.checkpoints = []
    fp.line_start_s = np.zeros(len(fp.lines))
    t += checkpoint(0)
    fp.checkpoint_before[0] = True
    for k, line in enumerate(fp.lines):
        if k > 0 and since >= interval:
            fp.checkpoint_before[k] = True
            t += checkpoint(k)
            since = 0.0
        if fp.swept_turn(k):
            prev = fp.lines[k - 1]
            dt = max(fp.line_start_s[k - 1] + _turn_start_s(prev, line, float(fp.cross[k])) - t, 0.0)
            parts["turn_s"] += dt
            parts["turnarounds"] += 1
            here = line.start_deg
        else:
            dt = go(line.start_deg)
            parts["transit_s"] += dt
        fp.line_start_s[k] = t + dt + (0.0 if line.moving else fp.settle_s)
        if line.moving:
            dt += line.duration_s
            parts["line_s"] += line.duration_s
            here = line.end_deg
        else:
            dt += fp.settle_s + line.exposure_s
            parts["settle_s"] += fp.settle_s
            parts["reading_s"] += line.exposure_s
        t += dt
        since += dt
    fp.checkpoint_before[-1] = True
    t += checkpoint(len(fp.lines))
    back = go(fp.home_deg)
    parts["transit_s"] += back
    t += back
    moving = [ln for ln in fp.lines if ln.moving]
    notes: dict[str, int] = {}
    for ln in fp.lines:
        if ln.note:
            notes[ln.note] = notes.get(ln.note, 0) + 1
    fp.estimated_s = float(t)
    fp.timing.update({
        "estimate": {**parts, "total_s": float(t)},
        "lines": len(moving), "stop_and_go_readings": len(fp.lines) - len(moving),
        "coordinated_lines": sum(1 for ln in moving if ln.axis == COORDINATED),
        "readings": int(sum(ln.n for ln in fp.lines)),
        "checkpoints": int(fp.checkpoint_before.sum()),
        "max_blur_deg": max((ln.speed_deg_s * ln.exposure_s for ln in moving), default=0.0),
        "notes": notes,
    })


def _bound(fp: FlyPlan, kin, metric: MoveMetric) -> tuple[float, dict]:
    """The lower bound of the module docstring: (total, parts)."""
    v_max = np.asarray(kin.velocity_deg_s, dtype=np.float64)
    a_max = np.asarray(kin.accel_deg_s2, dtype=np.float64)
    lines = fp.lines
    inner = 0.0
    fixed = 0.0
    for ln in lines:
        if isinstance(ln, PathLine):
            # No path through its poses in order is quicker than its slowest axis's travel at top speed.
            inner += max(float(np.max(ln.travel_deg() / v_max)), (ln.n - 1) * ln.exposure_s)
        elif ln.moving:
            v, a = float(v_max[ln.axis]), float(a_max[ln.axis])
            r = ln.readings_deg()
            sign = float(np.sign(ln.step_deg))
            reach = v * v / (2.0 * a)
            caps = [min(v, float(np.sqrt(2.0 * a * _room(kin, at, ln.axis, d, reach))))
                    for at, d in ((r[0], -sign), (r[-1], sign))]
            inner += max(_least_traverse_s(ln.span_deg, v, a, *caps), (ln.n - 1) * ln.exposure_s)
        else:
            fixed += fp.settle_s + ln.exposure_s
    n_cp = int(fp.checkpoint_before.sum())
    fixed += n_cp * (2 * fp.reading_s + fp.settle_s)
    # Entry of every line: from another line's end (either direction), a checkpoint or home.
    n = len(lines)
    ends = np.empty((n, 2, kin.limits_deg.shape[0]))
    moves = np.zeros((n, ends.shape[2]), dtype=bool)   # the axes that move at a line's ends
    for k, ln in enumerate(lines):
        r = ln.readings_deg()
        ends[k, 0], ends[k, 1] = r[0], r[-1]
        if isinstance(ln, PathLine):
            moves[k] = ln.moving_axes
        elif ln.moving:
            moves[k, ln.axis] = True
    rest = np.stack([fp.reference_deg, fp.home_deg])
    if n <= _PAIRWISE_MAX_LINES:
        entry, method = _entries_pairwise(ends, moves, rest, v_max, a_max), "pairwise"
    else:
        entry, method = _entries_nearest(ends, moves, rest, v_max, a_max), "nearest (k-d tree)"
    entries = float(entry.sum())
    total = inner + fixed + entries
    fp.timing["entries_method"] = method
    return total, {"sweeps_s": inner, "fixed_s": fixed, "entries_s": entries, "total_s": total}


def _least_traverse_s(d: float, v: float, a: float, v0: float, v1: float) -> float:
    """The least time to travel ``d`` ≥ 0 at speeds ≤ ``v``, accelerations ≤ ``a``, starting at a speed
    ≤ ``v0`` and ending at one ≤ ``v1``: start at v0, speed up, slow down to v1 (each end's cap lowered
    to what the other end can reach over d)."""
    v0 = min(v0, float(np.sqrt(v1 * v1 + 2.0 * a * d)))
    v1 = min(v1, float(np.sqrt(v0 * v0 + 2.0 * a * d)))
    peak = min(v, float(np.sqrt(a * d + 0.5 * (v0 * v0 + v1 * v1))))
    if peak <= 0.0:
        return 0.0
    ramps = (peak * peak - v0 * v0 + peak * peak - v1 * v1) / (2.0 * a)
    return (2.0 * peak - v0 - v1) / a + max(d - ramps, 0.0) / peak


def _entry_times(d, still, v_max, a_max):
    """Least time for axis changes ``d`` (..., A): rest to rest where ``still``, else at top speed."""
    return np.where(still, move_time(d, v_max, a_max), d / v_max)


def _entries_pairwise(ends, moves, rest, v_max, a_max) -> np.ndarray:
    """Each line's least entry time over every other line's ends and the rest positions, exactly;
    ``moves`` (n, A): the axes that move at each line's ends (at top speed there, not from rest)."""
    n = ends.shape[0]
    entry = np.full(n, np.inf)
    for b0 in range(0, n, _BLOCK):
        blk = slice(b0, min(b0 + _BLOCK, n))
        to = ends[blk]                                             # (B, 2, A)
        d = np.abs(to[:, None, :, None, :] - ends[None, :, None, :, :])   # (B, n, 2, 2, A)
        still = ~moves[blk, None, :] & ~moves[None, :, :]          # (B, n, A)
        t = _entry_times(d, still[:, :, None, None, :], v_max, a_max).max(axis=-1).min(axis=(2, 3))
        own = np.arange(blk.start, blk.stop)
        t[own - blk.start, own] = np.inf
        dr_ = np.abs(to[:, :, None, :] - rest[None, None, :, :])   # (B, 2, 2, A)
        tr = _entry_times(dr_, ~moves[blk, None, None, :], v_max, a_max)
        entry[blk] = np.minimum(t.min(axis=1), tr.max(axis=-1).min(axis=(1, 2)))
    return entry


def _entries_nearest(ends, moves, rest, v_max, a_max) -> np.ndarray:
    """:func:`_entries_pairwise` for many lines, the same values: no move is quicker than its largest
    |change| / v_max over axes, a Chebyshev distance in axis space scaled by 1/v_max; so for each line
    the exact times of its nearest candidates in that distance give a time t, and only candidates
    nearer than t (a k-d tree ball query) can do better."""
    from scipy.spatial import cKDTree

    n, _, n_axes = ends.shape
    cand = np.concatenate([ends.reshape(2 * n, n_axes), rest])
    owner = np.concatenate([np.repeat(np.arange(n), 2), np.full(len(rest), -1)])
    cand_moves = np.concatenate([np.repeat(moves, 2, axis=0), np.zeros((len(rest), n_axes), dtype=bool)])
    tree = cKDTree(cand / v_max)
    entry = np.full(n, np.inf)

    def exact(j, e, idx):
        idx = idx[owner[idx] != j]
        if idx.size == 0:
            return np.inf
        d = np.abs(cand[idx] - ends[j, e])
        still = ~moves[j][None, :] & ~cand_moves[idx]
        return float(_entry_times(d, still, v_max, a_max).max(axis=-1).min())

    k = min(8, cand.shape[0])
    _, near = tree.query((ends / v_max).reshape(2 * n, n_axes), k=k, p=np.inf)
    near = np.asarray(near).reshape(n, 2, k)
    for j in range(n):
        for e in (0, 1):
            best = exact(j, e, near[j, e])
            if np.isfinite(best):
                ball = tree.query_ball_point(ends[j, e] / v_max, r=best, p=np.inf)
                best = min(best, exact(j, e, np.asarray(ball, dtype=np.int64)))
            entry[j] = min(entry[j], best)
    return entry


def physical_floor(plan, kin) -> tuple[float, int]:
    """The physical floor of a lattice grid's campaign: every Δφ arc the grid needs, swept once at the
    axes' top speeds, no stops (no acceleration, no exposure, no transit, no reference): the least
    campaign any fly scan of these poses can take. Returns (seconds, Δφ steps counted).

    Defined for iso grids (ValueError for others). A ring is the plan's poses at one (θi, φi, θo); its
    arcs join the poses whose Δφ differ by one grid step
    (around the circle). One step costs the least time at top speed, max over axes of |change| / v_max,
    between any valid branches of its two poses (on the two-arm gantry one azimuth turns by the step; on
    the sample stage a Δφ step moves both detector axes together).
    """
    from gonio.plan.grids import parse_grid

    spec = parse_grid(plan.grid)
    step = spec.step_deg
    if spec.kind != "iso" or step is None:
        # A full grid's poses can be swept along Δφ or along φ at fixed Δφ (the sample stage's rotation,
        # faster): its Δφ arcs bound nothing.
        raise ValueError(f"grid '{spec.kind}': the physical floor is defined for iso grids (Δφ rings)")
    ti, to = (np.round(np.degrees(np.asarray(x, dtype=np.float64)), 6) for x in (plan.theta_i, plan.theta_o))
    pi = np.round(np.mod(np.degrees(np.asarray(plan.phi_i, dtype=np.float64)), 360.0), 6) % 360.0
    dphi = np.round(np.mod(np.degrees(np.asarray(plan.phi_o) - np.asarray(plan.phi_i)), 360.0), 6) % 360.0
    # Poses at a pole have no Δφ (a point, not an arc); the rest, grouped by ring (θi, φi, θo: an iso
    # grid has one φi, a full grid many) and sorted by Δφ.
    arc = (ti > 1e-6) & (to > 1e-6)
    idx = np.flatnonzero(arc)
    order = idx[np.lexsort((dphi[idx], to[idx], pi[idx], ti[idx]))]
    ring = np.stack([ti[order], pi[order], to[order]], axis=1)
    starts = np.sort(np.unique(ring, axis=0, return_index=True)[1])
    ends = np.append(starts[1:], order.size)
    pairs = []
    for s0, s1 in zip(starts, ends, strict=True):
        members = order[s0:s1]
        d = dphi[members]
        gap = np.mod(np.roll(d, -1) - d, 360.0)
        near = np.abs(gap - step) <= 1e-6
        if members.size < 2:
            continue
        if members.size == 2:           # two poses one step apart: one arc step, not two around
            near[1] = False
        pairs += list(zip(members[near], np.roll(members, -1)[near], strict=True))
    if not pairs:
        return 0.0, 0
    pa, pb = np.array(pairs).T
    rad = [np.asarray(x, dtype=np.float64) for x in (plan.theta_i, plan.phi_i, plan.theta_o, plan.phi_o)]
    v = np.asarray(kin.velocity_deg_s, dtype=np.float64)
    total, counted = 0.0, 0
    for b0 in range(0, pa.size, _FLOOR_BLOCK):
        a, b = pa[b0:b0 + _FLOOR_BLOCK], pb[b0:b0 + _FLOOR_BLOCK]
        sa = kin.solutions(*(x[a] for x in rad))                        # (P, S, A)
        sb = kin.solutions(*(x[b] for x in rad))
        t = (np.abs(sa[:, :, None, :] - sb[:, None, :, :]) / v).max(axis=-1)
        t = np.where(np.isnan(t), np.inf, t).min(axis=(1, 2))
        total += float(t[np.isfinite(t)].sum())
        counted += int(np.isfinite(t).sum())
    return total, counted


def fly_summary(fp: FlyPlan) -> dict:
    """JSON-ready parts of a fly plan (``gonio plan``): estimate and bound with their parts and counts."""
    est = fp.timing["estimate"]
    return {
        "motion": FLY_MOTION, "estimated_s": fp.estimated_s, "lower_bound_s": fp.lower_bound_s,
        "lines": fp.timing["lines"], "coordinated_lines": fp.timing["coordinated_lines"],
        "stop_and_go_readings": fp.timing["stop_and_go_readings"],
        "readings": fp.timing["readings"], "checkpoints": fp.timing["checkpoints"],
        "reference_interval_s": fp.timing["reference_interval_s"],
        "max_blur_deg": fp.timing["max_blur_deg"],
        "exposure_s": sorted({round(ln.exposure_s, 9) for ln in fp.lines if ln.moving}),
        "estimate": {k: float(v) for k, v in est.items()},
        "lower_bound": {k: float(v) for k, v in fp.timing["lower_bound"].items()},
        "notes": dict(fp.timing["notes"]),
    }
