"""On-the-fly scanning on a configured gantry whose sweeping axes fly (:class:`gonio.protocols.Flyable`:
Dynamixel servos).

:func:`gonio.fly.units.fly_units` turns a journaled fly campaign into the units the engine
(:class:`~gonio.runner.Runner`) measures and commits whole: one per checkpoint (its dark and white
reference, read stop-and-go by the engine's :class:`~gonio.units.StepReader`), one per line, read here
through the engine's public motion executor (:class:`~gonio.executor.MotionExecutor`). The engine does
the rest as for a stop-and-go campaign: light, target, pause and abort between units, halt within a
wait slice, transient faults retried after the axes are still (the whole sweep again), other faults stop
every axis and latch, the park. A sweep is one journal transaction: a crash or a fault loses at most the
sweep in flight, and a resumed campaign starts from the first sweep with no reading (the sweep in
flight is done again from its start).

A line (:class:`gonio.plan.fly.FlyLine`), by :class:`FlySweeper`:

1. the axes go to the line's start along a collision-free path and settle (the executor's moves: the
   line's travel was checked against the limits and the swept path when planned); a line entered
   through a swept turnaround is there already and does not settle (the plan has no settle there);
2. the sweeping axis gets the line's velocity and acceleration and its goal at the line's far end
   (:meth:`gonio.gantry.AssembledGantry.sweep`: the axis's ``prepare`` and ``kickoff``; the servo
   quantises the profile, so the speed it runs at differs from the plan's a little: the pair it runs at
   is journaled). A line whose first reading is at its start (the plan rests half an exposure there)
   sets the axis going halfway through that reading's sub-reads, so the reading is centred on the
   start as planned;
3. each later reading starts when the axis will pass its pose at the reading's mid-time: the time is
   predicted from the latest timestamped axis read (:meth:`~gonio.gantry.AssembledGantry.stamped_positions`,
   one Sync Read per bus stamped on the gantry clock) on the servo's own trapezoid (its quantised speed
   and acceleration: the readings near the ends are taken while it speeds up or slows down), and axes
   are read every ``read_s`` until the start is nearer than that, so the prediction follows the axis,
   not the plan's clock;
4. a reading is ``subreads`` sub-reads of the detector (exposure / subreads each), with a stamped axis
   read after each (so the exposure is bracketed by reads), their signals summed. A sub-read exposes
   from its request for its exposure (a request-triggered photodiode: its reply, processing and
   transfer, comes after and is not exposure), so its mid-time is half an exposure after the request;
   the reading's mid-time is the mean of its sub-reads' mid-times, and the start of the next reading
   allows for the dead time seen between sub-reads. The axis positions at the mid-time are
   interpolated linearly in time between the reads around it, and their forward kinematics give the
   sample's (θi, φi, θo, φo);
5. after the last reading the axis runs down to the line's end; where the plan enters the next line
   through a swept turnaround, the other axes are sent to that line's start at once (while this axis
   runs out: the planner certified every position between, :meth:`Kinematics.box_clear`); the
   executor's arrival check faults an axis that stopped short; the campaign's profile is written back
   (``complete``; before any later move if it could not be then).

A coordinated line (:class:`gonio.plan.flypath.PathLine`: several axes along a ring) is flown as its
chords (:mod:`gonio.fly.segments`): after the safe move and settle, the first segment starts every moving
axis with one command (:meth:`~gonio.gantry.AssembledGantry.sweep_axes`: one Sync Write per Dynamixel bus
of each servo's goal and profile) halfway through the first reading; each later one is written halfway
through the reading of the pose the axes are passing (:func:`gonio.fly.segments.corner`: from where the
latest stamped read puts them); each reading starts when the lead axis of the segment ending at its pose
will pass it, on that servo's profile from the latest read; the positions of a reading are interpolated
from the stamped reads of every axis as for a one-axis line. A coordinated line starts with its own
safe move and settle (nil where a swept turnaround brought the axes to its start) and ends at rest on
its last pose: its last reading starts once a stamped read puts every moving axis there (the axes brake
in together only as well as their quantised profiles and the host's timing allow; a late one would put
that reading off its pose, on a ring often at its steepest: the specular peak).

A serial photodiode answers one request at a time, so the reads are taken between its sub-reads and
between readings rather than beside them: the dead time of one Sync Read (~1 ms at 1 Mbit/s) per
sub-read is lost to the exposure and the interpolation spans at most one sub-read. The reads between
sub-reads also feed an armed bus watchdog (sub-reads are made shorter than half of it).

A detector that streams (:class:`gonio.protocols.Streams`, declared once: ``Abilities.streams``) is not
asked per sub-read: its stream runs from before the kickoff to after the run-down, a reading's
sub-reads are windows of exposure / subreads back to back from its start, the axes read at each
window's end while the instrument integrates on (no dead time), and after the last reading the
samples, stamped on the gantry clock by the driver's reader, are gathered per window
(:meth:`FlySweeper._stream_subreads`); a sample missing in any window makes the sweep be read again.

Uncertainty. ``stderr`` adds in quadrature the sub-reads' own stated errors (a serial power meter
states none for one frame, as in a stop-and-go reading; a simulated detector its Monte Carlo and sensor
errors) and the motion blur from the quadratic through the sub-reads
(:func:`gonio.fly.blur.motion_blur`, as on the simulated gantry): the bias of the exposure's mean
against the value at its mid-time direction. Where the detector states no noise, the fitted curvature
also carries the sub-reads' noise, so the blur term is then conservative (it counts that noise too).
A reading at rest (a checkpoint, a pose read stop-and-go) is the engine's stop-and-go reading.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from gonio.fly.blur import motion_blur
from gonio.fly.segments import corner, on_limits, path_segments
from gonio.motion.trapezoid import move_time
from gonio.plan.fly import FlyLine
from gonio.plan.flypath import COORDINATED
from gonio.plan.schedule import STEP_POSE
from gonio.protocols import DeviceFault
from gonio.store import Measurement

__all__ = ["FlySweeper", "on_limits", "READ_S", "SUBREADS"]


class _AxisTiming:
    """A one-axis line's motion: started by ``go()`` (its (velocity, acceleration) as the servo runs
    them), each reading's mid-time predicted on the servo's own trapezoid (its quantised profile) from
    rest at the start, from the latest stamped read of the axis."""

    def __init__(self, line: FlyLine, go):
        self.line, self.go = line, go
        self.runs: FlyLine | None = None
        self.due: np.ndarray | None = None

    @property
    def started(self) -> bool:
        return self.runs is not None

    def kickoff(self) -> None:
        v, a = self.go()
        self.runs = replace(self.line, speed_deg_s=v, accel_deg_s2=a)
        self.due = self.runs.time_at(self.line.readings_deg()[:, self.line.axis])

    def at_mid(self, j: int) -> None:
        if self.runs is None:
            self.kickoff()

    def writes(self, j: int) -> bool:
        return False

    def mid_time(self, j: int, t: np.ndarray, x: np.ndarray) -> float:
        ax = self.line.axis
        return float(t[ax] + self.due[j] - self.runs.time_at(x[ax]))


class _PathTiming:
    """A coordinated line's motion (:mod:`gonio.fly.segments`): ``write(k)`` starts segment k (returns
    when, each commanded axis's (velocity, acceleration) as quantised, and how far along its chord the
    lead axis was when written); reading j's mid-time is when the lead axis of the segment ending at
    pose j passes it, on its servo's profile (from rest for the first segment, from the last segment's
    speed after, its ramp from where the segment was written), from the latest stamped read. The last
    reading (the line ends at rest on its pose) starts once a stamped read puts every moving axis on
    that pose (within ``tol``): the axes brake in together only as well as their quantised profiles and
    the host's timing allow, and an axis arriving late would put a reading at a steep peak off its
    pose; an axis still short ``wait_s`` past the lead axis's arrival is left to the arrival check."""

    def __init__(self, segs, write, end_deg: np.ndarray, tol: float, wait_s: float = 1.0):
        self.segs, self.write = segs, write
        self.end_deg, self.tol, self.wait_s = np.asarray(end_deg, dtype=np.float64), tol, wait_s
        self.sent: list[tuple[float, dict[int, tuple[float, float]], float]] = []
        self._due: float | None = None   # the lead axis's arrival on the last pose, first predicted

    @property
    def started(self) -> bool:
        return bool(self.sent)

    def kickoff(self) -> None:
        self.at_mid(0)

    def at_mid(self, j: int) -> None:
        if j == len(self.sent) and j < len(self.segs):
            self.sent.append(self.write(j))

    def writes(self, j: int) -> bool:
        """Whether reading j (a later one; the first is not placed) writes a segment halfway through."""
        return j < len(self.segs)

    def mid_time(self, j: int, t: np.ndarray, x: np.ndarray) -> float:
        seg = self.segs[j - 1]
        ax = seg.lead_axis
        _t_w, given, ramp_at = self.sent[j - 1]
        v, a = given[ax]
        v0 = self.sent[j - 2][1].get(ax, (0.0, 0.0))[0] if j >= 2 else 0.0
        sign = np.sign(seg.goal_deg[ax] - seg.start_deg[ax])
        at = sign * (x[ax] - seg.start_deg[ax])
        to = abs(seg.end_deg[ax] - seg.start_deg[ax])
        lead = float(t[ax] + seg.time_to(to, v0, v, a, ramp_at) - seg.time_to(at, v0, v, a, ramp_at))
        if j < len(self.segs):
            return lead
        if self._due is None:
            self._due = lead
        moving = list(seg.axes)
        there = np.all(np.abs(x[moving] - self.end_deg[moving]) <= self.tol)
        if there or float(np.max(t)) > self._due + self.wait_s:
            return float(np.max(t[moving]))     # there (or given up on): the reading starts now
        return math.inf                         # not there yet: read the axes again

#: Seconds between timestamped axis reads while waiting for a reading's start.
READ_S = 0.005
#: Sub-reads per reading (at least; more where an exposure is longer than half the bus watchdog).
SUBREADS = 4


class FlySweeper:
    """Reads the lines of a fly campaign on the engine's gantry (see the module docstring).

    Parameters
    ----------
    engine : Runner
        Its gantry (one that flies its axes: :class:`gonio.protocols.FliesAxes`, an
        :class:`~gonio.gantry.AssembledGantry`), motion executor, stop-and-go reader and campaign clock.
    read_s : float
        Seconds between stamped axis reads while waiting for a reading to start.
    subreads : int
        Sub-reads per reading, >= 3 (the blur's quadratic).
    """

    def __init__(self, engine, *, read_s: float = READ_S, subreads: int = SUBREADS):
        if not (math.isfinite(read_s) and read_s > 0):
            raise ValueError(f"read_s: must be > 0 s, got {read_s!r}")
        if not isinstance(subreads, int) or subreads < 3:
            raise ValueError(f"subreads: must be an integer >= 3, got {subreads!r}")
        self.engine = engine
        self.executor = engine.executor
        self.flies = self.executor.abilities.flies
        if self.flies is None:
            raise ValueError("the gantry cannot sweep its axes (on-the-fly scanning needs Dynamixel servos)")
        #: The detector where it streams (its samples stamped on the gantry clock): sub-reads are taken
        #: from the stream, back to back, not requested (:meth:`_stream_subreads`).
        self.streams = self.executor.abilities.streams
        keep = self.executor.abilities.keep_alive
        self.feed_s = keep.feed_s if keep is not None else None
        self.read_s = float(read_s)
        self.subreads = subreads
        self._gaps: list[float] = []   # the latest dead times between sub-reads, over sweeps
        self._writes: list[float] = []   # the latest durations of writes within a reading, over sweeps
        self._turned: FlyLine | None = None   # the line a swept turnaround just brought the axes to

    def sweep(self, line: FlyLine, step: int, attempt: int, then: FlyLine | None = None) -> list[Measurement]:
        """The readings of ``line`` (steps from ``step``), attempt ``attempt`` (from 1); ``then``: the
        next line, where the plan enters it through a swept turnaround (the other axes make their change
        while this line's axis runs out)."""
        ex, flies = self.executor, self.flies
        turned, self._turned = self._turned is line, None
        if not line.moving:  # a pose read stop-and-go
            return [self.engine.reader.read(step, attempt)]
        if line.axis == COORDINATED:
            return self._sweep_path(line, step, attempt)
        kin, clock = ex.kinematics, ex.gantry.clock
        name = kin.axis_names[line.axis]
        start, end = on_limits(kin, line.start_deg), on_limits(kin, line.end_deg)
        # Entered through a swept turnaround the axes arrived at the start already (unless something
        # moved them since: a pause parks the gantry).
        tol = ex.rc.position_tolerance_deg
        if not (turned and np.all(np.abs(ex.positions() - start) <= tol)):
            ex.goto(start)
            ex.settle()
        reads: list[tuple[np.ndarray, np.ndarray]] = []
        went: list[tuple[float, float, float]] = []    # (v, a, t) of the kickoff, once made

        def go() -> tuple[float, float]:
            v, a = ex.command(lambda: flies.sweep(name, float(end[line.axis]), line.speed_deg_s,
                                                  line.accel_deg_s2))
            went.append((v, a, clock.now()))
            return v, a

        if self.streams is not None:
            self.streams.start_stream()
        try:
            out = self._readings(line, step, attempt, _AxisTiming(line, go), reads)
            # The run-down: the axis arrives at the line's end (the executor faults one that stopped short).
            v, a, t_go = went[0]
            left = t_go + line.duration_s - sum(line.pads()) - clock.now()
            if then is not None:
                # The turnaround: the other axes go to the next line's start now (the last exposure
                # is over) while this axis runs out; the planner certified every position between.
                target = on_limits(kin, then.start_deg)
                target[line.axis] = end[line.axis]
                ex.send_move(end, target)
                cross = np.delete(np.abs(target - end), line.axis)
                left = max(left, float(np.max(move_time(cross, *(np.delete(x, line.axis) for x in (
                    kin.velocity_deg_s, kin.accel_deg_s2))))))
                end = target
            ex.arrive(start, end, max(left, 0.0))
            if then is not None:
                self._turned = then
        except BaseException:
            self._stop_stream()
            if went:
                try:
                    flies.end_sweep(name)
                except Exception:  # noqa: S110 - the first failure is the one to report; the next move restores
                    pass
            raise
        flies.end_sweep(name)
        if self.streams is not None:
            self.streams.stop_stream()
        for m in out:
            m.extra.update({"speed_deg_s": v, "accel_deg_s2": a, "planned_speed_deg_s": line.speed_deg_s})
        return out

    def _sweep_path(self, line, step: int, attempt: int) -> list[Measurement]:
        """The readings of a coordinated line (:class:`~gonio.plan.flypath.PathLine`): its straight
        segments (:func:`gonio.fly.segments.path_segments`), each started by one command to every moving
        axis (:meth:`~gonio.gantry.AssembledGantry.sweep_axes`: one Sync Write per bus), the next written
        as the axes pass the pose between, halfway through that pose's reading; the line's readings
        timed and placed as a one-axis line's, from the stamped reads of every axis."""
        ex, flies = self.executor, self.flies
        kin, clock = ex.kinematics, ex.gantry.clock
        poses = on_limits(kin, line.readings_deg())
        segs = path_segments(kin, line, poses)
        names = [kin.axis_names[i] for i in segs[0].axes]
        start, end = poses[0], poses[-1]
        ex.goto(start)
        ex.settle()

        reads: list[tuple[np.ndarray, np.ndarray]] = []

        def write(k: int) -> tuple[float, dict[int, tuple[float, float]]]:
            seg = segs[k]
            speed, accel = seg.speed_deg_s.copy(), seg.accel_deg_s2.copy()
            if k:
                # Where the axes are now: the latest read, carried on at the speeds they were given.
                prev, given = segs[k - 1], timing.sent[-1][1]
                t, x = reads[-1]
                was = np.array([np.sign(prev.goal_deg[i] - prev.start_deg[i]) * given[i][0] if i in given
                                else 0.0 for i in range(x.size)])
                now = x + was * (clock.now() - t)
                speed, accel = corner(kin, seg, now, was)
            sweeps = {kin.axis_names[i]: (float(seg.goal_deg[i]), float(speed[i]), float(accel[i]))
                      for i in seg.axes}
            got = ex.command(lambda: flies.sweep_axes(sweeps))
            sent = clock.now()
            ramp_at = 0.0
            if k:   # how far along its chord the lead axis was when the write went out (however late)
                i = seg.lead_axis
                ramp_at = float(np.sign(seg.goal_deg[i] - seg.start_deg[i])
                                * (x[i] + was[i] * (sent - t[i]) - seg.start_deg[i]))
            return sent, {kin.axis_names.index(n): va for n, va in got.items()}, ramp_at

        timing = _PathTiming(segs, write, end, ex.rc.position_tolerance_deg)
        if self.streams is not None:
            self.streams.start_stream()
        try:
            out = self._readings(line, step, attempt, timing, reads)
            t, x = self._look(reads)
            ex.arrive(start, end, max(timing.mid_time(line.n - 1, t, x) - clock.now(), 0.0))
        except BaseException:
            self._stop_stream()
            if timing.started:
                for n in names:
                    try:
                        flies.end_sweep(n)
                    except Exception:  # noqa: S110 - the first failure is the one to report
                        pass
            raise
        for n in names:
            flies.end_sweep(n)
        if self.streams is not None:
            self.streams.stop_stream()
        for m in out:
            m.extra.update({"segments": len(segs), "segment_rate_hz": segs[0].rate,
                            "planned_speed_deg_s": line.speed_deg_s})
        return out

    def _stop_stream(self) -> None:
        """Stop the stream after a failure (the failure is the one to report)."""
        if self.streams is not None:
            try:
                self.streams.stop_stream()
            except Exception:  # noqa: S110 - a stream that cannot stop now is started afresh next time
                pass

    def _look(self, reads) -> tuple[float, float]:
        t, x = self.flies.stamped_positions()
        reads.append((t, x))
        return t, x

    def _readings(self, line, step: int, attempt: int, motion, reads) -> list[Measurement]:
        """The readings of a line whose motion ``motion`` (:class:`_AxisTiming`, :class:`_PathTiming`)
        starts and times."""
        ex = self.executor
        g, kin, clock = ex.gantry, ex.kinematics, ex.gantry.clock
        e = line.exposure_s
        feed = self.feed_s
        m = max(self.subreads, math.ceil(e / feed) if feed else 0)
        planned = line.readings_deg()
        self._look(reads)
        spans, signals, variances, ends, windows = [], [], [], [], []
        gaps = self._gaps   # dead time between sub-reads seen so far (their reads and replies)
        writes = self._writes   # how long the writes halfway through readings took
        # A line whose first reading is at its start (no run-up: the plan rests half an exposure before
        # the motion) starts that reading at rest and sets the axes going halfway through it (at its
        # mid-time); one with a run-up sets them going now. A coordinated line's next segment is
        # written halfway through each reading (as the axes pass its pose).
        at_start = line.pads()[0] > 0.0
        if not at_start:
            motion.kickoff()
        for j in range(line.n):
            # Each reading (but a first one at the start) starts when the axis, on its profile from the
            # last read, passes the pose at the mid-time of the sub-reads (their exposures and the dead
            # time between them, as seen so far; none when they come from a stream).
            dead = float(np.median(gaps)) if gaps and self.streams is None else 0.0
            span = e + (m - 1) * dead
            # A write halfway through (a coordinated line's next segment) holds up the sub-reads after
            # it by as long as the writes seen so far took: the reading starts earlier by their share.
            held = float(np.median(writes)) * (m - m // 2) / m if writes and motion.writes(j) else 0.0
            while j or not at_start:
                start = motion.mid_time(j, *reads[-1]) - 0.5 * span - held
                wait = start - clock.now()
                if wait <= self.read_s:
                    if wait > 0:
                        ex.wait(wait)
                    break
                ex.wait(self.read_s)
                self._look(reads)
            if self.streams is not None:
                # Sub-reads from the stream: windows back to back, the axes read at each window's end
                # while the instrument integrates on; their samples are gathered after the last reading.
                t0 = clock.now()
                for k in range(m):
                    if k == m // 2:
                        motion.at_mid(j)
                    ex.wait(max(t0 + (k + 1) * e / m - clock.now(), 0.0))
                    self._look(reads)
                windows.append(t0)
                t1 = t0 + e
                ends.append((t1, self.engine.campaign_s() - (clock.now() - t1)))
                continue
            subs, var, mids = [], [], []
            for k in range(m):
                if k == m // 2:
                    before = clock.now()
                    motion.at_mid(j)
                    if j and motion.writes(j):
                        writes.append(clock.now() - before)
                        del writes[:-64]
                t0 = clock.now()
                if k:
                    gaps.append(t0 - mids[-1] - 0.5 * e / m)
                    del gaps[:-64]
                reading = g.detector.read_on_the_fly(e / m, key=(step + j, (attempt - 1) * m + k))
                t1 = clock.now()
                self._look(reads)
                subs.append(reading.signal)
                var.append(np.asarray(reading.stderr, dtype=np.float64) ** 2)
                # The photodiode integrates from the request for its exposure; its reply comes after.
                mids.append(t0 + 0.5 * reading.exposure_s)
            spans.append((float(np.mean(mids)), e))
            signals.append(np.asarray(subs, dtype=np.float64))
            variances.append(np.asarray(var))
            ends.append((t1, self.engine.campaign_s() - (clock.now() - t1)))
        if self.streams is not None:
            spans, signals, variances, counts = self._stream_subreads(windows, e, m, step)
        subs = np.stack(signals)                                        # (n, M, C)
        noise_var = np.stack(variances)
        blur = motion_blur(subs, noise_var)                             # (n, C)
        sensor = np.sqrt(noise_var.sum(axis=1))
        stderr = np.sqrt(sensor**2 + blur**2)
        times = np.array([t for t, _ in reads])                         # (R, n_axes): each axis's stamps
        pos = np.array([x for _, x in reads])
        mid = np.array([s for s, _ in spans])
        actual = np.stack([np.interp(mid, times[:, i], pos[:, i]) for i in range(pos.shape[1])], axis=1)
        angles = np.degrees(np.stack(kin.forward(actual), axis=1))
        return [Measurement(step=step + j, kind=STEP_POSE, pose=int(line.poses[j]), commanded_deg=planned[j],
                            actual_deg=actual[j], angles_deg=angles[j], clock_s=float(ends[j][0]),
                            campaign_s=float(ends[j][1]), exposure_s=e, frames=m, signal=subs[j].sum(axis=0),
                            stderr=stderr[j], attempts=attempt,
                            extra={"mid_s": float(mid[j]), "stderr_blur": blur[j].tolist(),
                                   "stderr_sensor": sensor[j].tolist(), "axis_reads": len(reads),
                                   **({} if self.streams is None else {"stream_samples": counts[j]})})
                for j in range(line.n)]

    def _stream_subreads(self, windows: list[float], e: float, m: int, step: int):
        """The sub-reads of readings starting at ``windows`` (gantry clock), each ``m`` windows of ``e / m``
        s back to back, from the stream: a sample belongs to the window holding its mid-time (each
        sample counted once, the exposure continuous). A summing stream's sub-read is its samples' sum
        scaled from their exposure (whole samples) to the window's; a rate's is their mean. Waits (in
        slices, the axes read as in any wait) until the stream holds a sample past the last window;
        a sample lost in any window (a gap in the counter) is a transient fault: the sweep is read
        again, never interpolated across the gap."""
        ex, clock = self.executor, self.executor.gantry.clock
        last = windows[-1] + e
        deadline = last + max(1.0, 10 * e)
        while True:
            s = self.streams.read_stream()
            if len(s.index) and s.t_end_s[-1] - 0.5 * s.period_s >= last:
                break
            if clock.now() > deadline:
                raise DeviceFault(self.engine.gantry.detector.name, f"stream: no sample past {last:.4f} s "
                                  f"by {clock.now():.4f} s (step {step}): the stream stalled", transient=True)
            ex.wait(self.read_s)
        period = s.period_s
        mids = s.t_end_s - 0.5 * period
        origin = float(s.t_end_s[0] - (s.index[0] + 1) * period)   # where sample 0 started
        spans, signals, variances, counts = [], [], [], []
        sub = e / m
        for t0 in windows:
            edges = t0 + sub * np.arange(m + 1)
            # the counters the windows need: every sample whose mid-time falls in them
            k_lo = math.ceil((edges[0] - origin) / period - 0.5 - 1e-9)
            k_hi = math.ceil((edges[-1] - origin) / period - 0.5 - 1e-9)
            lost = [(a, b) for a, b in s.missing if a < k_hi and b > k_lo]
            if lost:
                a, b = lost[0]
                raise DeviceFault(self.engine.gantry.detector.name, f"stream: samples {a}..{b - 1} lost "
                                  f"during step {step} (reading from {t0:.4f} s): the sweep is read again",
                                  transient=True)
            which = np.searchsorted(edges, mids, side="right") - 1
            subs, sub_mids, n_used = [], [], 0
            for k in range(m):
                take = which == k
                q = int(take.sum())
                if q == 0:
                    raise DeviceFault(self.engine.gantry.detector.name, f"stream: no sample in a sub-read of "
                                      f"step {step} ({sub:g} s at {period:g} s a sample)", transient=True)
                vals = s.values[take]
                summed = s.combine == "sum"
                subs.append(vals.sum(axis=0) * sub / (q * period) if summed else vals.mean(axis=0))
                sub_mids.append(float(mids[take].mean()))
                n_used += q
            spans.append((float(np.mean(sub_mids)), e))
            signals.append(np.asarray(subs, dtype=np.float64))
            variances.append(np.zeros_like(signals[-1]))   # a stream states no noise of its own
            counts.append(n_used)
        return spans, signals, variances, counts
