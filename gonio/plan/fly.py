"""On-the-fly scanning: the poses of a plan read while one axis sweeps at constant velocity.

A stop-and-go campaign moves, settles and exposes at every pose. Along a line of the grid (a Δφ ring
at fixed θi, θo on the iso grid: on the two-arm gantry the detector carriage turns, nothing else
moves) the poses lie on a straight line in axis space, equally spaced along one axis. A fly campaign
sweeps that axis through the whole line at a constant velocity and reads the detector continuously,
each reading centred on the time the axis passes a pose.

Lines. :func:`fly_plan` takes the poses of the stop-and-go plan (the serpentine order and its IK
branches, so the same poses are measured) and cuts them into maximal runs where consecutive poses
differ in exactly one axis by the same signed step. A pose that starts no such run is read stop-and-go
(move, settle, expose: a line of one pose, speed 0).

Velocity and exposure. A line sweeps at its axis's top speed v_max unless something nearer forces it
slower. Each reading exposes for ``FLY_DUTY`` of the time between readings at v_max, so the axis
travels ``FLY_DUTY`` of a grid step during one exposure (the motion blur); slower lines keep that
exposure (less blur). Run-up and run-down: from rest the axis accelerates at its a_max to v (over
v²/2a), then travels half an exposure at v before the first reading starts; the same after the last
reading, then it decelerates to rest. Every reading therefore lies wholly in the constant-velocity part.

Checks. Each line's whole travel, rest to rest (run-up, sweep, run-down), is one move of one axis:
its swept path is the same set of axis positions as the rest-to-rest move between its ends, so
:meth:`Kinematics.sweep_clearance` certifies it exactly, and both ends must be within the limits.
Where the run-up or run-down of the top speed leaves the limits or collides, the speed is lowered
(``_SPEED_LADDER``, the run-up shrinks as v²) and the line notes why; when not even half the top speed
fits, the poses at the blocked end that half the top speed's run-up needs are read stop-and-go instead
(a ring that starts right at the other carriage has no room at all); a line whose sweep between its
first and last reading collides is split at the colliding step; a line that no speed in the ladder
clears is read stop-and-go, pose by pose, with the reason. Transits between lines, to and from
the white reference and home go through :func:`gonio.motion.safe.safe_path` like every stop-and-go
move.

Checkpoints. A dark and a white-reference reading (stop-and-go, as in every campaign) before the
first line, then between lines once the gantry time since the last reaches the interval (the
config's ``reference.every_s``, or else the stop-and-go plan's own mean gantry time between
references, so the drift correction sees references as often in time), and at the end.

Estimate and bound. The estimate adds the transits (the planner's trapezoid metric,
:class:`~gonio.motion.metric.MoveMetric`, leg by leg along the safe paths), each line's time rest to
rest, settle and exposure of stop-and-go readings, and the checkpoints. The lower bound holds for any
order and direction of these lines: each line takes at least max(span / v_max, (n − 1) · exposure)
between its first and last reading; before its first reading the gantry must come from the end of
another line, a checkpoint or home, and each axis needs at least the rest-to-rest time of its change
where it is still at both ends, or |change| / v_max where it moves at either end; each checkpoint adds
its settle and exposures.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gonio.motion.metric import MoveMetric
from gonio.motion.safe import path_time, safe_path
from gonio.motion.trapezoid import move_time
from gonio.plan.schedule import STEP_REFERENCE, schedule_runs

__all__ = ["FLY_DUTY", "FLY_TOL_DEG", "FlyLine", "FlyPlan", "fly_plan", "fly_summary", "fly_steps",
           "fly_step_table", "line_lengths"]

#: Exposure / time between readings at the axis's top speed: the axis travels this fraction of a grid
#: step during one exposure.
FLY_DUTY = 0.5
#: Speeds tried (fractions of the axis's top speed) when the run-up or run-down does not fit.
_SPEED_LADDER = (1.0, 0.7, 0.5, 0.35, 0.25, 0.18, 0.12, 0.08, 0.05)
#: The speeds tried before an end pose is given up to a stop-and-go reading.
_FAST = tuple(f for f in _SPEED_LADDER if f >= 0.5)
_TRIMMED = "stop-and-go: the end pose of a line with no room for its run-up or run-down"
#: Degrees: two positions closer than this on an axis count as equal; steps equal within it are equal.
FLY_TOL_DEG = 1e-6
#: Above this many lines the entry bound searches a k-d tree instead of every pair (same values).
_PAIRWISE_MAX_LINES = 200
#: Lines per block of the pairwise bound (memory of the (block, lines, 4, n_axes) temporaries).
_BLOCK = 256


@dataclass(frozen=True)
class FlyLine:
    """One sweep: readings of the plan's poses ``poses`` while ``axis`` moves at ``speed_deg_s``.

    Attributes
    ----------
    poses : ndarray of int64, shape (n,)
        The plan's pose indices, in reading order.
    axis : int
        The sweeping axis (column of the plan's axes); -1 for a stop-and-go reading (n = 1).
    first_deg : ndarray, shape (n_axes,)
        Axis positions at the first reading's mid-time.
    step_deg : float
        Signed travel of ``axis`` from one reading to the next (0 for a stop-and-go reading).
    speed_deg_s : float
        Constant speed during the readings (0 for a stop-and-go reading).
    accel_deg_s2 : float
        The axis's acceleration in the run-up and run-down.
    exposure_s : float
        Exposure of each reading.
    note : str
        Why the line is slower than the top speed, split or read stop-and-go ("" when none of it).
    """

    poses: np.ndarray
    axis: int
    first_deg: np.ndarray
    step_deg: float
    speed_deg_s: float
    accel_deg_s2: float
    exposure_s: float
    note: str = ""

    @property
    def n(self) -> int:
        return int(self.poses.size)

    @property
    def moving(self) -> bool:
        return self.axis >= 0

    @property
    def ramp_deg(self) -> float:
        """Travel from rest to the start of the first exposure (and from the end of the last to rest)."""
        if not self.moving:
            return 0.0
        v = self.speed_deg_s
        return v * v / (2.0 * self.accel_deg_s2) + 0.5 * v * self.exposure_s

    def readings_deg(self) -> np.ndarray:
        """Axis positions (n, n_axes) at each reading's mid-time."""
        out = np.repeat(self.first_deg[None, :], self.n, axis=0)
        if self.moving:
            out[:, self.axis] += self.step_deg * np.arange(self.n)
        return out

    @property
    def start_deg(self) -> np.ndarray:
        """Where the axes rest before the run-up."""
        out = self.first_deg.copy()
        if self.moving:
            out[self.axis] -= np.sign(self.step_deg) * self.ramp_deg
        return out

    @property
    def end_deg(self) -> np.ndarray:
        """Where the axes rest after the run-down."""
        out = self.readings_deg()[-1].copy()
        if self.moving:
            out[self.axis] += np.sign(self.step_deg) * self.ramp_deg
        return out

    @property
    def ramp_s(self) -> float:
        """Time from rest to the first reading's mid-time (and from the last one's to rest)."""
        if not self.moving:
            return 0.0
        v = self.speed_deg_s
        return v / self.accel_deg_s2 + 0.5 * self.exposure_s

    @property
    def duration_s(self) -> float:
        """Rest to rest: run-up, the readings, run-down (a stop-and-go reading: its exposure only)."""
        if not self.moving:
            return self.exposure_s
        return 2.0 * self.ramp_s + (self.n - 1) * abs(self.step_deg) / self.speed_deg_s

    def mid_times(self) -> np.ndarray:
        """Each reading's mid-time, seconds after the line's run-up starts."""
        if not self.moving:
            return np.array([0.5 * self.exposure_s])
        return self.ramp_s + np.arange(self.n) * abs(self.step_deg) / self.speed_deg_s

    def position_at(self, t_s) -> np.ndarray:
        """Axis positions (..., n_axes) at times ``t_s`` (s after the run-up starts): accelerate at
        ``accel_deg_s2``, cruise, decelerate, as :meth:`duration_s` has it; constant outside."""
        t = np.asarray(t_s, dtype=np.float64)
        start = self.start_deg
        out = np.broadcast_to(start, t.shape + start.shape).copy()
        if not self.moving:
            return out
        v, a = self.speed_deg_s, self.accel_deg_s2
        t_acc = v / a
        total = self.duration_s
        tc = np.clip(t, 0.0, total)
        s = (0.5 * a * np.minimum(tc, t_acc) ** 2 + v * np.clip(tc - t_acc, 0.0, total - t_acc)
             - 0.5 * a * np.clip(tc - (total - t_acc), 0.0, t_acc) ** 2)
        out[..., self.axis] += np.sign(self.step_deg) * s
        return out


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
    #: Campaign time (s) each line's run-up starts (a stop-and-go reading: its exposure starts).
    line_start_s: np.ndarray | None = None
    #: Per checkpoint, in order: (before line k, dark start s, where the dark is read, reference start s).
    checkpoints: list = field(default_factory=list)


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
    """The lines a run becomes: split where its sweep collides, each at the fastest speed of the
    ladder whose run-up and run-down fit, or pose by pose where none does."""
    pts = axes[i:j]
    clear, _ = kin.sweep_clearance(pts[:-1], pts[1:])
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
    # Fast lines first, trimming an end pose into a stop-and-go reading where that end has no room
    # (a ring that starts at the other carriage, an arc that ends at a limit); then any speed at all.
    # At most as many poses per end as the run-up of the slowest fast speed covers (plus one).
    v, a = _FAST[-1] * float(kin.velocity_deg_s[axis]), float(kin.accel_deg_s2[axis])
    most = int(np.ceil((v * v / (2 * a) + 0.5 * v * exposure_s) / abs(step))) + 1
    front = back = 0
    tried = []
    for _ in range(2 * most + 2):
        if j - back - (i + front) < 2:
            break
        tried.append((front, back))
        line, blocked = _fit(kin, axes, i + front, j - back, axis, step, exposure_s, _FAST)
        if line is not None:
            return _trimmed(axes, i, j, front, back, line)
        front += blocked[0]
        back += blocked[1]
        if not any(blocked) or front > most or back > most:
            break
    # Then any speed at all: the whole run first, then the most trimmed one tried.
    for front, back in [(0, 0)] + tried[-1:]:
        line, _ = _fit(kin, axes, i + front, j - back, axis, step, exposure_s, _SPEED_LADDER)
        if line is not None:
            return _trimmed(axes, i, j, front, back, line)
    return [_still(axes, k, "stop-and-go: no run-up or run-down fits") for k in range(i, j)]


def _trimmed(axes, i, j, front, back, line) -> list[FlyLine]:
    return ([_still(axes, k, _TRIMMED) for k in range(i, i + front)] + [line]
            + [_still(axes, k, _TRIMMED) for k in range(j - back, j)])


def _fit(kin, axes, i, j, axis, step, exposure_s, ladder):
    """The fastest line over poses [i, j) whose run-up and run-down fit, or None and which ends
    (start, end) were blocked at the slowest speed tried."""
    v_max = float(kin.velocity_deg_s[axis])
    a = float(kin.accel_deg_s2[axis])
    lo, hi = kin.limits_deg[axis]
    pts = axes[i:j]
    line = None
    for frac in ladder:
        line = FlyLine(np.arange(i, j, dtype=np.int64), axis, pts[0].copy(), step, frac * v_max, a,
                       exposure_s)
        s, e = line.start_deg, line.end_deg
        tol = FLY_TOL_DEG
        if not (lo - tol <= s[axis] <= hi + tol and lo - tol <= e[axis] <= hi + tol):
            continue
        if kin.sweep_clear_one(s, e)[0]:
            note = "" if frac == 1.0 else (f"slower ({100 * frac:.0f} % of top speed): the run-up or "
                                           "run-down reaches a limit or collides")
            return _noted(line, note), (False, False)
    s, e = line.start_deg, line.end_deg
    ok_s = lo - FLY_TOL_DEG <= s[axis] <= hi + FLY_TOL_DEG and kin.sweep_clear_one(s, pts[0])[0]
    ok_e = lo - FLY_TOL_DEG <= e[axis] <= hi + FLY_TOL_DEG and kin.sweep_clear_one(pts[-1], e)[0]
    return None, (not ok_s, not ok_e)


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

    lines: list[FlyLine] = []
    for i, j, axis, step in _runs(axes):
        if axis < 0 or abs(abs(step) - spec.step_deg) > FLY_TOL_DEG:   # not a step along a line of the grid
            lines.extend(_still(axes, k, "") for k in range(i, j))
            continue
        exposure = FLY_DUTY * abs(step) / float(kin.velocity_deg_s[axis])
        lines.extend(_lines_of_run(kin, axes, i, j, axis, step, exposure))
    lines = [ln if ln.moving else FlyLine(ln.poses, -1, ln.first_deg, 0.0, 0.0, 1.0, reading_s, ln.note)
             for ln in lines]

    interval = cfg.reference.every_s
    if interval is None:
        n_ref = max(int(np.count_nonzero(plan.step_kind == STEP_REFERENCE)), 1)
        interval = plan.estimated_s / n_ref
    fp = FlyPlan(lines, np.zeros(len(lines) + 1, dtype=bool), ref, home, settle_s, reading_s)
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
    parts = {"transit_s": 0.0, "line_s": 0.0, "settle_s": 0.0, "reading_s": 0.0, "reference_s": 0.0,
             "via_moves": 0}

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
        if ln.moving:
            span = abs(ln.step_deg) * (ln.n - 1)
            inner += max(span / v_max[ln.axis], (ln.n - 1) * ln.exposure_s)
        else:
            fixed += fp.settle_s + ln.exposure_s
    n_cp = int(fp.checkpoint_before.sum())
    fixed += n_cp * (2 * fp.reading_s + fp.settle_s)
    # Entry of every line: from another line's end (either direction), a checkpoint or home.
    n = len(lines)
    ends = np.empty((n, 2, kin.limits_deg.shape[0]))
    axis = np.array([ln.axis for ln in lines])
    for k, ln in enumerate(lines):
        r = ln.readings_deg()
        ends[k, 0], ends[k, 1] = r[0], r[-1]
    rest = np.stack([fp.reference_deg, fp.home_deg])
    if n <= _PAIRWISE_MAX_LINES:
        entry, method = _entries_pairwise(ends, axis, rest, v_max, a_max), "pairwise"
    else:
        entry, method = _entries_nearest(ends, axis, rest, v_max, a_max), "nearest (k-d tree)"
    moves = float(entry.sum())
    total = inner + fixed + moves
    fp.timing["entries_method"] = method
    return total, {"sweeps_s": inner, "fixed_s": fixed, "entries_s": moves, "total_s": total}


def _entry_times(d, still, v_max, a_max):
    """Least time for axis changes ``d`` (..., A): rest to rest where ``still``, else at top speed."""
    return np.where(still, move_time(d, v_max, a_max), d / v_max)


def _entries_pairwise(ends, axis, rest, v_max, a_max) -> np.ndarray:
    """Each line's least entry time over every other line's ends and the rest positions, exactly."""
    n = ends.shape[0]
    entry = np.full(n, np.inf)
    cols = np.arange(v_max.size)
    for b0 in range(0, n, _BLOCK):
        blk = slice(b0, min(b0 + _BLOCK, n))
        to = ends[blk]                                             # (B, 2, A)
        d = np.abs(to[:, None, :, None, :] - ends[None, :, None, :, :])   # (B, n, 2, 2, A)
        still = (cols[None, None, :] != axis[blk, None, None]) & (cols[None, None, :] != axis[None, :, None])
        t = _entry_times(d, still[:, :, None, None, :], v_max, a_max).max(axis=-1).min(axis=(2, 3))
        own = np.arange(blk.start, blk.stop)
        t[own - blk.start, own] = np.inf
        dr_ = np.abs(to[:, :, None, :] - rest[None, None, :, :])   # (B, 2, 2, A)
        tr = _entry_times(dr_, (cols[None, :] != axis[blk, None])[:, None, None, :], v_max, a_max)
        entry[blk] = np.minimum(t.min(axis=1), tr.max(axis=-1).min(axis=(1, 2)))
    return entry


def _entries_nearest(ends, axis, rest, v_max, a_max) -> np.ndarray:
    """:func:`_entries_pairwise` for many lines, the same values: no move is quicker than its largest
    |change| / v_max over axes, a Chebyshev distance in axis space scaled by 1/v_max; so for each line
    the exact times of its nearest candidates in that distance give a time t, and only candidates
    nearer than t (a k-d tree ball query) can do better."""
    from scipy.spatial import cKDTree

    n, _, n_axes = ends.shape
    cand = np.concatenate([ends.reshape(2 * n, n_axes), rest])
    owner = np.concatenate([np.repeat(np.arange(n), 2), np.full(len(rest), -1)])
    moving_axis = np.concatenate([np.repeat(axis, 2), np.full(len(rest), -1)])
    tree = cKDTree(cand / v_max)
    cols = np.arange(n_axes)
    entry = np.full(n, np.inf)

    def exact(j, e, idx):
        idx = idx[owner[idx] != j]
        if idx.size == 0:
            return np.inf
        d = np.abs(cand[idx] - ends[j, e])
        still = (cols[None, :] != axis[j]) & (cols[None, :] != moving_axis[idx, None])
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


def fly_summary(fp: FlyPlan) -> dict:
    """JSON-ready parts of a fly plan (``gonio plan``): estimate and bound with their parts and counts."""
    est = fp.timing["estimate"]
    return {
        "estimated_s": fp.estimated_s, "lower_bound_s": fp.lower_bound_s,
        "lines": fp.timing["lines"], "stop_and_go_readings": fp.timing["stop_and_go_readings"],
        "readings": fp.timing["readings"], "checkpoints": fp.timing["checkpoints"],
        "reference_interval_s": fp.timing["reference_interval_s"],
        "max_blur_deg": fp.timing["max_blur_deg"],
        "exposure_s": sorted({round(ln.exposure_s, 9) for ln in fp.lines if ln.moving}),
        "estimate": {k: float(v) for k, v in est.items()},
        "lower_bound": {k: float(v) for k, v in fp.timing["lower_bound"].items()},
        "notes": dict(fp.timing["notes"]),
    }
