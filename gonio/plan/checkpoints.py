"""Where the checkpoints (a dark and a white-reference reading) fall in a campaign, and where the white
standard is read at each.

By count, a checkpoint comes after every ``reference.every`` poses. By time (``reference.every_s``), the
gantry time from one reference reading to the next (the *interval*: the moves, settles and readings of
the run between them, the dark reading and the reference's own move, settle and reading) stays at most
``every_s``, which is what bounds the error of interpolating the lamp's drift between them
(:mod:`gonio.calibrate`). Both limits apply when both are set.

Within those limits a run does not have to end at the last pose that fits: a checkpoint costs the
detour ``d(last, ref) + d(ref, next) − d(last, next)``, which is small where the walk passes near a
reference position and large where it is far from all of them. Each run is therefore ended, among the
poses in the last :data:`SLACK` of its allowed reach, where that detour is least. With several reference
positions allowed (``reference.positions``, each with its branches), each checkpoint reads the standard
at the one that makes its detour least (:func:`reference_choice`).

Balance. Cutting greedily (each run as long as its limit allows) leaves whatever is over for the last
run: a tour of 330 s at every_s = 90 s got intervals of 72, 77, 76, 87 and 14 s, and the drift
interpolation falls back from its cubic where neighbouring intervals differ by more than a factor
(:data:`gonio.calibrate.SPACING_RATIO`). So the limit used is the least one, found by bisection down
to :data:`BALANCE_FLOOR` of ``every_s``, that still gives as many runs as ``every_s`` does: the same
number of checkpoints, spread evenly (and each interval shorter, so the drift between references is
smaller too).

A run's interval is computed on the branches the plan had when the runs were cut; the branches are
then chosen again for the new runs (never slower for a run), and the build checks the final intervals
and cuts any run again that a re-solved collision or via point pushed past ``every_s``
(:func:`overdue_runs`).
"""

from __future__ import annotations

import numpy as np

from gonio.motion.metric import MoveMetric

__all__ = ["cut_runs", "reference_choice", "intervals", "overdue_runs", "SLACK"]

#: A run may end this fraction short of its reach (in poses) when a cheaper checkpoint lies there.
SLACK = 0.25
#: The balanced time limit is searched down to this fraction of ``every_s``.
BALANCE_FLOOR = 0.5
# Bisection steps of that search (the limit to 2^-10 of the range).
_BALANCE_STEPS = 10


def reference_choice(options, before, after, metric: MoveMetric) -> tuple[np.ndarray, np.ndarray]:
    """For checkpoints between ``before`` (C, n) and ``after`` (C, n), the option (K, n) with the least
    ``d(before, option) + d(option, after)``: its index (C,) and that time (C,) in s. NaN rows of
    ``before``/``after`` (no pose on that side) count as 0."""
    opts = np.asarray(options, dtype=np.float64)
    b = np.asarray(before, dtype=np.float64)
    a = np.asarray(after, dtype=np.float64)
    tb = np.nan_to_num(metric.time(b[:, None, :], opts[None]), nan=0.0)
    ta = np.nan_to_num(metric.time(opts[None], a[:, None, :]), nan=0.0)
    total = tb + ta
    pick = np.argmin(total, axis=1)
    return pick, total[np.arange(total.shape[0]), pick]


def cut_runs(axes_deg, options, metric: MoveMetric, settle_s: float, reading_s: float, every: int,
             every_s: float | None) -> np.ndarray:
    """Run starts (R,) for poses in motion order on ``axes_deg`` (P, n_axes).

    Parameters
    ----------
    axes_deg : ndarray, shape (P, n_axes)
        The poses' axis targets in motion order, degrees.
    options : ndarray, shape (K, n_axes)
        Axis positions the reference may be read at, degrees.
    metric : MoveMetric
    settle_s, reading_s : float
        Settle after a move, exposure × frames per reading, seconds.
    every : int
        At most this many poses per run.
    every_s : float or None
        At most this many seconds from one reference reading to the next.

    Returns
    -------
    ndarray of int64
        Indices of the poses that start a run (0 first).

    Raises
    ------
    ValueError
        When a single pose between two references takes longer than ``every_s``.
    """
    axes = np.asarray(axes_deg, dtype=np.float64)
    p = axes.shape[0]
    if p == 0:
        return np.zeros(0, dtype=np.int64)
    if every_s is None:
        return np.arange(0, p, int(every), dtype=np.int64)
    cut = _greedy_cuts(axes, options, metric, settle_s, reading_s, every)
    starts = cut(every_s)
    if starts.size < 2:
        return starts
    lo, hi = BALANCE_FLOOR * every_s, float(every_s)
    best = starts
    for _ in range(_BALANCE_STEPS):
        mid = 0.5 * (lo + hi)
        try:
            trial = cut(mid)
        except ValueError:   # a pose alone is longer than that: no lower limit works
            lo = mid
            continue
        if trial.size <= starts.size:
            best, hi = trial, mid
        else:
            lo = mid
    return best


def _greedy_cuts(axes, options, metric: MoveMetric, settle_s: float, reading_s: float, every: int):
    """``cut(limit) -> starts``: runs cut greedily, each ended (within :data:`SLACK`) where its
    checkpoint's detour is least, every interval at most ``limit`` s."""
    p = axes.shape[0]
    opts = np.asarray(options, dtype=np.float64)
    to_ref = metric.time(axes[:, None, :], opts[None]).min(axis=1)  # symmetric metric: from = to
    step = np.zeros(p)
    step[1:] = metric.time(axes[:-1], axes[1:])
    per_pose = settle_s + reading_s
    cum = np.concatenate([[0.0], np.cumsum(step[1:] + per_pose)])  # cum[e] - cum[s]: poses s+1..e
    # Detour of a checkpoint after pose e (before pose e + 1), with the best option for that pair.
    if p > 1:
        _, both = reference_choice(opts, axes[:-1], axes[1:], metric)
        detour = np.append(both - step[1:], 0.0)
    else:
        detour = np.zeros(1)
    fixed = per_pose + reading_s + settle_s + reading_s  # first pose, dark, reference settle + reading
    return lambda limit: _cut(limit, p, every, cum, to_ref, detour, fixed)


def _cut(every_s, p, every, cum, to_ref, detour, fixed) -> np.ndarray:
    starts = [0]
    s = 0
    while True:
        reach = min(s + int(every), p)
        # Poses the time limit can possibly hold (the trips to the reference only add to this).
        reach = min(reach, int(np.searchsorted(cum, cum[s] + every_s, side="right")))
        ends = np.arange(s, max(reach, s + 1))
        interval = to_ref[s] + cum[ends] - cum[s] + fixed + to_ref[ends]
        fits = np.flatnonzero(interval <= every_s)
        if fits.size == 0:
            if interval[0] > every_s:
                raise ValueError(f"reference.every_s: {every_s:g} s is shorter than the pose {s} takes "
                                 f"between two references ({interval[0]:.1f} s); raise it")
            fits = np.array([0])
        last = int(ends[fits[-1]])
        if last >= p - 1:
            break
        lo = s + int(np.floor((1.0 - SLACK) * (last - s)))
        window = np.arange(lo, last + 1)
        window = window[np.isin(window, ends[fits])]
        e = int(window[np.argmin(detour[window])])
        s = e + 1
        starts.append(s)
    return np.asarray(starts, dtype=np.int64)


def intervals(campaign_s, step_kind, reference_kind: int) -> np.ndarray:
    """Gantry time (R,) in s between consecutive reference readings, from each step's end time."""
    t = np.asarray(campaign_s, dtype=np.float64)[np.asarray(step_kind) == reference_kind]
    return np.diff(t)


def overdue_runs(step_end_s, step_kind, step_pose, run_starts, reference_kind: int,
                 every_s: float | None) -> np.ndarray:
    """Indices of the runs whose interval (see :func:`intervals`) exceeds ``every_s`` (1 µs slack)."""
    if every_s is None or len(run_starts) == 0:
        return np.zeros(0, dtype=np.int64)
    gaps = intervals(step_end_s, step_kind, reference_kind)
    return np.flatnonzero(gaps > every_s + 1e-6)
