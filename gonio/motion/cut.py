"""Where to cut a circular grid loop so that a serpentine sweep of it is cheapest.

An azimuth loop (Δφ in an iso grid, φo − φi in a full grid) is a circle, but a serpentine sweeps it
as a line from one end to the other, and real gantries cannot follow every circle continuously: an
azimuth axis has limits (it has to unwind somewhere) and carriages that share a ring cannot pass
each other (a branch flip somewhere). Where the line starts decides whether those costly moves fall
inside every row or at its ends, where the serpentine joins rows and they are cheap or absent.

The cut is chosen by trial: for each candidate rotation of the loop, a few sample pairs of adjacent
rows are swept (forward, then backward, as the serpentine does), their branches chosen as the plan
chooses them (:func:`gonio.motion.branches.best_branches`), and the total move time compared.

Some gantries need a costly move somewhere inside every full circle wherever it is cut (on the
two-arm gantry the detector's carriage cannot pass the light's: every circle of Δφ needs a branch
flip). Then the circle is split into arcs at the places where sample rows make those moves, and the
arcs become a loop of their own just outside the row loop (:func:`split_arcs`): each arc is swept over
all rows before the next, so the costly move happens once per arc instead of once per row. Whether
that pays is again decided by trial, on sample slabs (:func:`serpentine_loops`).
"""

from __future__ import annotations

import numpy as np

from gonio.motion.branches import best_branches
from gonio.motion.metric import MoveMetric
from gonio.motion.order import serpentine_order

__all__ = ["best_cut", "arc_boundaries", "split_arcs", "serpentine_loops"]

# A move inside a row counts as costly when it takes this many times the row's median move.
_COSTLY = 3.0


def best_cut(kin, angles, loops, level: int, period: int, start_deg, metric: MoveMetric,
             sample_rows: int = 8, max_candidates: int = 72) -> int:
    """The rotation c (0 <= c < period) of loop ``level`` that makes sample row sweeps quickest.

    Parameters
    ----------
    kin : Kinematics
        For choosing branches (``solutions``, ``inverse`` with ``current_deg``).
    angles : tuple of 4 ndarray, shape (P,)
        θi, φi, θo, φo of the poses, radians (all reachable).
    loops : ndarray of int64, shape (P, L)
        Loop indices; ``loops[:, level]`` is circular with the given period and ``level`` is the
        innermost loop (``L - 1``).
    level, period : int
        The circular loop and its number of values.
    start_deg : array_like, shape (n_axes,)
        Where each sample sweep starts (the reference pose), degrees.
    metric : MoveMetric
        The move-time metric.
    sample_rows : int
        Pairs of adjacent rows tried per candidate.
    max_candidates : int
        Rotations tried (evenly spaced over the period).

    Returns
    -------
    int
        The rotation: use ``(loops[:, level] - c) % period`` as the loop index. 0 on ties.
    """
    loops = np.asarray(loops, dtype=np.int64)
    if level != loops.shape[1] - 1:
        raise ValueError(f"level: only the innermost loop ({loops.shape[1] - 1}) can be cut, got {level}")
    if period <= 1 or loops.shape[0] == 0:
        return 0
    row_of, sizes = _rows(loops, level)
    # Rows that hold the whole circle show the cut's effect; pair each with the next row.
    full = np.flatnonzero(sizes[:-1] == sizes.max())
    if full.size == 0:
        return 0
    picks = full[np.linspace(0, full.size - 1, min(sample_rows, full.size)).round().astype(int)]
    picks = np.unique(picks)
    wanted = np.union1d(picks, picks + 1)
    # Long rows are thinned to about max_candidates poses: where the costly moves fall along a row does
    # not depend on how finely it is sampled, and the trial then costs the same for any step.
    thin = -(-period // max_candidates)
    members = {int(r): (lambda m: m[loops[m, level] % thin == 0])(np.flatnonzero(row_of == r))
               for r in wanted}
    candidates = np.arange(0, period, thin)
    sweeps, starts, total = [], [], 0
    for c in candidates:
        for r in picks:
            a, b = members[r], members[r + 1]
            ka = (loops[a, level] - c) % period
            kb = (loops[b, level] - c) % period
            starts.append(total)
            sweeps.append(np.concatenate([a[np.argsort(ka)], b[np.argsort(-kb)]]))
            total += sweeps[-1].size
    seq = np.concatenate(sweeps)
    starts = np.asarray(starts)
    axes = best_branches(kin, *(np.asarray(x)[seq] for x in angles), starts, start_deg)
    moves = metric.time(axes[:-1], axes[1:])
    inside = np.ones(seq.size - 1, dtype=bool)
    inside[starts[1:] - 1] = False  # the step from one sample sweep to the next is not a move
    per_sweep = np.add.reduceat(np.where(inside, moves, 0.0), starts) if seq.size > 1 else np.zeros(1)
    per_candidate = per_sweep[: candidates.size * picks.size].reshape(candidates.size, picks.size).sum(1)
    best = int(np.argmin(per_candidate))
    # Keep the natural cut unless another is really quicker (1 ms over all samples).
    if per_candidate[0] - per_candidate[best] <= 1e-3:
        return 0
    return int(candidates[best])


def arc_boundaries(kin, angles, loops, level: int, period: int, start_deg, metric: MoveMetric,
                   sample_rows: int = 8) -> np.ndarray:
    """Loop values where sample rows, swept in loop order, make a costly move (see the module
    docstring): the first value after each such move, found in at least half of the samples.

    Returns
    -------
    ndarray of int64
        Sorted values in (0, period); empty when rows sweep without costly moves.
    """
    loops = np.asarray(loops, dtype=np.int64)
    row_of, sizes = _rows(loops, level)
    full = np.flatnonzero(sizes == sizes.max())
    picks = np.unique(full[np.linspace(0, full.size - 1, min(sample_rows, full.size)).round().astype(int)])
    sweeps = [np.flatnonzero(row_of == r) for r in picks]
    sweeps = [m[np.argsort(loops[m, level])] for m in sweeps]
    starts = np.cumsum([0] + [m.size for m in sweeps[:-1]])
    seq = np.concatenate(sweeps)
    axes = best_branches(kin, *(np.asarray(x)[seq] for x in angles), starts, start_deg)
    votes = np.zeros(period, dtype=np.int64)
    for first, m in zip(starts, sweeps, strict=True):
        moves = metric.time(axes[first:first + m.size - 1], axes[first + 1:first + m.size])
        costly = moves > _COSTLY * np.median(moves)
        votes[loops[m[1:][costly], level]] += 1
    found = np.flatnonzero(votes * 2 >= len(picks))
    return found[found > 0]


def split_arcs(loops, level: int, boundaries) -> np.ndarray:
    """Loop indices with an arc level inserted just outside loop ``level - 1``: the arc of each pose's
    value of loop ``level`` between consecutive ``boundaries``."""
    loops = np.asarray(loops, dtype=np.int64)
    arc = np.searchsorted(np.asarray(boundaries, dtype=np.int64), loops[:, level], side="right")
    return np.concatenate([loops[:, :level - 1], arc[:, None], loops[:, level - 1:]], axis=1)


def serpentine_loops(kin, angles, loops, period: int, start_deg, metric: MoveMetric, run_length: int = 50,
                     sample_slabs: int = 2) -> np.ndarray:
    """Loop indices for a serpentine whose innermost loop is circular with ``period`` values: the loop
    cut at :func:`best_cut`, and split into arcs (:func:`split_arcs`) when that sweeps sample slabs
    (all rows under one value of the loops outside the row loop) more quickly, with branches chosen
    in runs of ``run_length`` poses from ``start_deg`` as the campaign will.
    """
    loops = np.asarray(loops, dtype=np.int64).copy()
    level = loops.shape[1] - 1
    cut = best_cut(kin, angles, loops, level, period, start_deg, metric)
    loops[:, level] = (loops[:, level] - cut) % period
    if level < 2:
        return loops
    bounds = arc_boundaries(kin, angles, loops, level, period, start_deg, metric)
    if bounds.size == 0:
        return loops
    split = split_arcs(loops, level, bounds)
    # Try both on the largest slabs (poses sharing the loops outside the row loop).
    slab_of, sizes = _rows(loops, level - 1)
    picks = np.argsort(-sizes, kind="stable")[:sample_slabs]
    cost = []
    for candidate in (loops, split):
        total = 0.0
        for slab in picks:
            members = np.flatnonzero(slab_of == slab)
            seq = members[serpentine_order(candidate[members])]
            starts = np.arange(0, seq.size, run_length)
            axes = best_branches(kin, *(np.asarray(x)[seq] for x in angles), starts, start_deg)
            inside = np.ones(seq.size - 1, dtype=bool)
            inside[starts[1:] - 1] = False  # between runs the gantry goes through the reference
            total += float(np.sum(metric.time(axes[:-1], axes[1:])[inside]))
        cost.append(total)
    return split if cost[1] < cost[0] else loops


def _rows(loops: np.ndarray, level: int) -> tuple[np.ndarray, np.ndarray]:
    """Row number (in natural order) of each pose for the loops outside ``level``, and row sizes."""
    prefix = loops[:, :level] - loops[:, :level].min(axis=0) if level else np.zeros((len(loops), 0), int)
    key = np.zeros(loops.shape[0], dtype=np.int64)
    for col in prefix.T:
        key = key * int(col.max() + 1) + col
    _, row_of, sizes = np.unique(key, return_inverse=True, return_counts=True)
    return row_of.reshape(-1), sizes
