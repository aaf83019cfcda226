"""Building a plan: grid → shortcuts → feasibility → order → branches → schedule → estimate and bound.

A plan is data (numpy arrays and small dicts); building one does no I/O and moves nothing.

Choices worth knowing:

- Reciprocity and mirror keep one pose of each class. When the kept pose cannot be reached but
  another member of its class can (the gantry is not symmetric under swapping light and detector),
  the reachable member is measured instead; a class counts as infeasible only when no member is
  reachable, under the reason of the kept pose.
- Orders: ``serpentine`` and ``raster`` follow the grid's loops; ``tour`` is nearest neighbour then
  2-opt/Or-opt on one branch per pose (those nearest home or a reference branch; the two sets lying
  closest together are each ordered and planned, the quicker kept: :func:`_tour_seeds`), from and
  back to the reference pose, then :data:`TOUR_KICKS_PER_POSE` seeded double-bridge kicks per pose
  (at most :data:`TOUR_KICKS_MAX`), each repaired by the same local search and kept when shorter
  (iterated local search, :func:`gonio.motion.order.perturb_tour`). ``auto`` takes a tour for merl grids up to
  :data:`TOUR_MAX_POSES` poses and the serpentine for full grids (a tour was 0.4-0.8 % slower on
  ``full:step=15``); for iso grids up to :data:`AUTO_TOUR_MAX_POSES` poses it plans both and keeps
  the one estimated quicker (the serpentine's row ends and the sample stage's coupled axes leave it
  3-8 % above the bound on coarse grids, the tour 2-5 %: ``tools/bench_plan.py --orders``), above
  that the serpentine.
- Branches: for the chosen order, each run's inverse-kinematics branches minimize its total move
  time, trips from and back to the reference included (:func:`gonio.motion.branches.best_branches`,
  dynamic programming). That is never slower than chaining each pose to the branch nearest the last
  (:func:`gonio.motion.chain.chain_branches`, used to try serpentine cuts) and avoids its needless
  unwinding and flips. The reference pose takes, of its branches, the one that makes the trips to and
  from the runs shortest.
- Checkpoints: by gantry time between reference readings (``reference.every_s``, the shipped configs'
  way) and/or by count (``reference.every``), each run ended where its detour to the reference is least
  (:mod:`gonio.plan.checkpoints`).
- Tours are not reordered again with branches priced exactly: on the shipped merl grids
  :func:`gonio.motion.refine.refine_windows` saved under 0.01 s of 1,418 s for 10 s of planning.
- The lower bound holds for every order and every branch choice (:mod:`gonio.motion.relaxed`); the
  older bound for the plan's own branches is kept in ``timing["branch_fixed_bound"]``.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from gonio.motion.branches import COLLISION_PENALTY_S, best_branches
from gonio.motion.chain import free_azimuth, nearest_branch
from gonio.motion.cut import serpentine_loops
from gonio.motion.estimate import campaign_estimate, campaign_lower_bound, step_move_times
from gonio.motion.exact import EXACT_MAX_POSES, exact_order
from gonio.motion.metric import MoveMetric
from gonio.motion.order import (
    nearest_neighbour_tour,
    neighbour_lists,
    perturb_tour,
    raster_order,
    serpentine_order,
)
from gonio.motion.refine import refine_order
from gonio.motion.relaxed import pose_branches, relaxed_campaign_bound
from gonio.plan.checkpoints import cut_runs, overdue_runs
from gonio.plan.grids import (
    GridKind,
    GridPoses,
    GridSpec,
    class_members,
    enumerate_grid,
    grid_kind,
    parse_grid,
)
from gonio.plan.schedule import STEP_DARK, STEP_POSE, STEP_REFERENCE, run_starts, schedule_runs
from gonio.plan.transit import colliding_runs, secure_branches, step_targets, via_points
from gonio.registries import ORDERS

if TYPE_CHECKING:  # type hints only: the caller holds the config
    from gonio.config import GonioConfig

__all__ = ["Plan", "build_plan", "OrderInputs", "order_raster", "order_serpentine", "order_tour",
           "TOUR_MAX_POSES", "AUTO_TOUR_MAX_POSES", "REASON_CAUSES"]

#: Largest pose set ordered by a tour (nearest neighbour is O(N) scans in the worst case).
TOUR_MAX_POSES = 50_000
#: Largest iso grid for which ``order=auto`` also plans a tour and keeps the quicker.
AUTO_TOUR_MAX_POSES = 10_000
#: Double-bridge kicks per pose of a tour, and at most (about 0.7 ms each on this project's machine).
TOUR_KICKS_PER_POSE = 2
TOUR_KICKS_MAX = 4_000
#: Seeded branch sets a tour is ordered on and planned through, the best kept (:func:`_tour_seeds`),
#: for plans up to this many poses; above, only the most promising one.
TOUR_SEED_TRIALS = 2
TOUR_SEED_TRIALS_MAX_POSES = 1_500
#: A seeded set is a candidate only when its poses lie at most this much (relative) less close together
#: than the closest set's (on the sample stage's iso:step=10 the best two differ by 0.3 %; on the
#: two-arm gantry the next distinct set is 2.3 % apart and loses).
TOUR_SEED_MARGIN = 0.01
#: Tours of at most this many poses are refined with every move priced after the branch choice, with
#: this many double-bridge restarts and then windows of this many stops solved exactly
#: (:func:`gonio.motion.refine.refine_order`): with the exact shortcut off, 8 restarts and no windows left
#: 8-12-pose subsets of the sample stage up to 5.6 % above the optimum, windows of 9 a 13-pose subset of
#: the two-arm gantry's full:step=15 3.8 % above (``tools/bench_plan.py --subsets``).
TOUR_REFINE_MAX_POSES = 24
TOUR_REFINE_KICKS = 16
TOUR_REFINE_WINDOW = 11
#: Largest plan whose valid bound uses every pose (``iso:step=2``, 142,879 poses, takes ~4 s of it);
#: above it an evenly spread subset of this many (the moves through a subset are no longer than
#: through all: still a bound, a weaker one).
BOUND_MAX_POSES = 250_000
#: Run length the serpentine's cut trials choose branches in (the count between checkpoints when it is
#: smaller): a stand-in for the runs a time-scheduled campaign will have, which are cut later.
CUT_RUN_LENGTH = 50
# Times the runs are cut again when via points push a run past reference.every_s.
_RECUT_TRIES = 3

#: The config field behind each infeasibility reason (what to change when it removes every pose).
REASON_CAUSES = {
    "out_of_reach": "the axis limits (axes.<name>.min_deg / max_deg)",
    "arm_collision": "kinematics.arm_collision_deg",
    "occlusion": "kinematics.clearance_deg",
    "beyond_theta_max": "kinematics.theta_max_deg",
}


@dataclass(frozen=True)
class Plan:
    """A campaign as data: which poses, in which order, on which axis targets, with which readings.

    Attributes
    ----------
    grid : str
        The GRID string with every option spelled out (theta_max and order as used).
    symmetries : dict of str to bool
        ``reciprocity``, ``isotropy`` and ``mirror`` as used.
    counts : dict of str to int
        Poses left after each stage, in order: the grid's stages (:mod:`gonio.plan.grids`) and then
        ``feasible``.
    infeasible : dict of str to int
        Poses (classes) removed as unreachable, by reason (:data:`gonio.kinematics.REASONS`), nonzero
        only.
    theta_i, phi_i, theta_o, phi_o : ndarray, shape (P,)
        Measurement poses in motion order, radians.
    axes_deg : ndarray, shape (P, n_axes)
        Axis targets of the poses, degrees: per run, the branches that make it quickest.
    step_kind : ndarray of int8, shape (S,)
        ``STEP_POSE``, ``STEP_DARK`` or ``STEP_REFERENCE``.
    step_pose : ndarray of int64, shape (S,)
        Index into the poses for pose steps, -1 otherwise.
    reference_axes_deg : ndarray, shape (n_axes,)
        Axis targets of the white-reference pose, degrees.
    estimated_s : float
        Estimated duration of the campaign, seconds.
    lower_bound_s : float
        A lower bound on that duration (same cost model, any order of the poses, each on any of its
        branches, with the least checkpoints the reference schedule allows; :mod:`gonio.motion.relaxed`),
        seconds.
    order : str
        The order used (``serpentine``, ``raster`` or ``tour``).
    axis_names : tuple of str
        Columns of ``axes_deg``.
    timing : dict
        ``{"estimate": {...}, "lower_bound": {...}, "branch_fixed_bound": {...}}``: the parts of the
        estimate, the valid bound and the older bound for the plan's own branches only (not a bound
        on other branch choices; see :mod:`gonio.motion.estimate`) in seconds, plus ``reference_s``
        (what the checkpoints add: readings, settles and detours), ``pose_motion_s``, the estimate's
        pose-to-pose moves,
        ``via_moves`` (moves that need via points, the park included) and ``resolved_runs`` (runs
        whose branches were chosen again because a move collided).
    via_deg : dict of int to ndarray, shape (k, n_axes)
        Step index -> the waypoints (degrees) the gantry passes at rest before that step's target,
        for the moves that would collide in transit if made directly; exactly
        ``gonio.motion.safe.safe_path(kin, previous target, target)[:-1]`` (from home for the first).
    park_deg : ndarray, shape (K, n_axes)
        The path home after the last step (``gonio.motion.safe.park_path``); its last row is home.
    step_end_s : ndarray, shape (S,)
        Estimated gantry time at the end of each step's reading, seconds from the start (the campaign
        clock of a simulated run).
    """

    grid: str
    symmetries: dict[str, bool]
    counts: dict[str, int]
    infeasible: dict[str, int]
    theta_i: np.ndarray
    phi_i: np.ndarray
    theta_o: np.ndarray
    phi_o: np.ndarray
    axes_deg: np.ndarray
    step_kind: np.ndarray
    step_pose: np.ndarray
    reference_axes_deg: np.ndarray
    estimated_s: float
    lower_bound_s: float
    order: str = "serpentine"
    axis_names: tuple[str, ...] = ()
    timing: dict = field(default_factory=dict)
    via_deg: dict[int, np.ndarray] = field(default_factory=dict)
    park_deg: np.ndarray | None = None
    step_end_s: np.ndarray | None = None


def build_plan(grid: str, cfg: GonioConfig, kin=None, *, poses: GridPoses | None = None,
               _tour_seed: int | None = None, _bound: dict | None = None,
               _orders: list | None = None) -> Plan:
    """Plan a campaign over ``grid`` on the gantry ``cfg`` describes.

    Parameters
    ----------
    grid : str
        A GRID string (:func:`gonio.plan.grids.parse_grid`).
    cfg : GonioConfig
        The gantry: kinematics, axis speeds, settle time, exposure, reference schedule.
    kin : Kinematics, optional
        Defaults to ``gonio.kinematics.make_kinematics(cfg)``.
    poses : GridPoses, optional
        The poses to plan instead of the grid's own (an adaptive campaign's pilot and rounds: the grid
        string then gives theta_max, the order and the symmetries).

    Returns
    -------
    Plan

    Raises
    ------
    ValueError
        For a bad GRID string, a grid too large, an unreachable reference pose, or when no pose of
        the grid can be reached (naming the dominant reason and the config field behind it).
    """
    spec = parse_grid(grid)
    if kin is None:
        from gonio.kinematics import make_kinematics

        kin = make_kinematics(cfg)
    kind = grid_kind(spec.kind)
    if spec.order == "auto" and kind.auto == "quicker":
        first = build_plan(spec.spelled(order="serpentine"), cfg, kin, poses=poses)
        if first.theta_i.size > AUTO_TOUR_MAX_POSES:
            return first
        second = build_plan(spec.spelled(order="tour"), cfg, kin, poses=poses,
                            _bound=first.timing["lower_bound"])
        return second if second.estimated_s < first.estimated_s else first
    theta_max = spec.theta_max_deg if spec.theta_max_deg is not None else cfg.kinematics.theta_max_deg
    given = poses
    poses = enumerate_grid(spec, theta_max) if given is None else given
    counts = dict(poses.counts)
    angles, loops, infeasible = _reachable(spec, kin, poses, theta_max)
    counts["feasible"] = int(angles[0].size)
    n = counts["feasible"]

    home = np.asarray(kin.home_deg, dtype=np.float64)
    metric = MoveMetric(kin.velocity_deg_s, kin.accel_deg_s2)
    ref_angles = _reference_angles(cfg)
    ref_options = _reference_branches(kin, ref_angles, home)
    # Where ordering and cut trials start: the reference branch nearest home among those reachable
    # from home (only they share home's part of the collision-free axis space).
    reachable = ref_options[kin.free_component(ref_options) == kin.free_component(home)[0]]
    if reachable.size == 0:
        raise ValueError(f"reference pose: no branch can be reached from home without a collision "
                         f"({kin.collision_rule}); move the reference pose (reference.*) or home "
                         "(axes.<name>.home_deg)")
    ref_first = reachable[int(np.argmin(metric.time(home, reachable)))].copy()

    order = _resolve_order(spec, kind, n)
    inputs = OrderInputs(spec=spec, kin=kin, angles=tuple(angles), loops=loops, start=ref_first, home=home,
                         metric=metric, run_length=min(cfg.reference.poses_per_run(n), CUT_RUN_LENGTH),
                         seeds=np.vstack([home, reachable]))
    # The candidates of the same poses are the same again: a seed's plan takes its caller's.
    candidates = ORDERS[order].load()(inputs) if _orders is None else _orders
    if callable(candidates):
        candidates = [candidates]
    if isinstance(candidates, np.ndarray):
        perm = candidates
    elif _tour_seed is None and len(candidates) > 1:
        # Several candidate orders: each planned through, the quickest kept (the lower bound holds for
        # every order of the same poses, so it is computed once).
        plans = [build_plan(grid, cfg, kin, poses=given, _tour_seed=0, _bound=_bound, _orders=candidates)]
        bound = plans[0].timing["lower_bound"]
        plans += [build_plan(grid, cfg, kin, poses=given, _tour_seed=i, _bound=bound, _orders=candidates)
                  for i in range(1, len(candidates))]
        return min(plans, key=lambda p: p.estimated_s)
    else:
        perm = np.asarray(candidates[_tour_seed or 0](), dtype=np.int64)
    angles = tuple(a[perm] for a in angles)

    every = cfg.reference.poses_per_run(n)
    every_s = cfg.reference.every_s
    reading_s = cfg.detector.exposure_s * cfg.detector.frames
    settle_s = cfg.runner.settle_s
    # With a time limit the runs are cut below, on these first branches: chosen in runs of at most
    # CUT_RUN_LENGTH (one run of the whole campaign would be a DP of as many steps as poses).
    starts = run_starts(n, every if every_s is None else min(every, CUT_RUN_LENGTH))
    ref = _best_reference(kin, ref_options, angles, starts, home, metric)
    axes = best_branches(kin, *angles, starts, ref)
    for attempt in range(_RECUT_TRIES + 1):
        if every_s is not None:
            starts = cut_runs(axes, ref[None], metric, settle_s, reading_s, every, every_s)
            axes = best_branches(kin, *angles, starts, ref)
        step_kind, step_pose = schedule_runs(n, starts)
        # Moves, not only poses, must be clear: runs with a colliding move choose their branches again
        # with every move checked; what still collides goes through via points.
        runs = colliding_runs(kin, step_kind, step_pose, axes, ref, home, starts)
        axes = secure_branches(kin, angles, starts, ref, axes, runs)
        targets = step_targets(step_kind, step_pose, axes, ref)
        via, park, extra = via_points(kin, targets, home)
        step_s = (step_move_times(targets, home, metric) + extra[:-1] + reading_s
                  + np.where(step_kind != STEP_DARK, settle_s, 0.0))
        late = overdue_runs(np.cumsum(step_s), step_kind, step_pose, starts, STEP_REFERENCE, every_s)
        if late.size == 0:
            break
        if attempt == _RECUT_TRIES:
            raise ValueError(f"reference.every_s: {every_s:g} s cannot be kept between references on this "
                             f"grid ({late.size} runs over it after via points); raise it")
    estimate = campaign_estimate(targets, step_kind != STEP_DARK, step_kind.size, home, metric,
                                 settle_s, reading_s, extra)
    n_ref = int(np.count_nonzero(step_kind == STEP_REFERENCE))
    n_dark = int(np.count_nonzero(step_kind == STEP_DARK))
    fixed_bound = campaign_lower_bound(axes, ref, np.diff(np.append(starts, n)), n_ref, n_dark, home,
                                       metric, settle_s, reading_s)
    bound = _bound if _bound is not None else _valid_bound(
        kin, angles, ref_options, home, metric, settle_s, reading_s, every, every_s,
        np.diff(np.append(starts, n)))
    follows_pose = np.zeros(n, dtype=bool)
    follows_pose[1:] = True
    follows_pose[starts] = False
    pose_motion = metric.time(axes[:-1], axes[1:])[follows_pose[1:]].sum() if n > 1 else 0.0
    reference_s = _reference_share(targets, step_kind, home, metric, settle_s, reading_s, extra)
    timing = {"estimate": estimate, "lower_bound": bound, "branch_fixed_bound": fixed_bound,
              "pose_motion_s": float(pose_motion), "reference_s": reference_s,
              "via_moves": len(via) + int(park.shape[0] > 1), "resolved_runs": int(len(runs))}

    return Plan(
        grid=spec.spelled(theta_max, order),
        symmetries={"reciprocity": spec.reciprocity, "isotropy": spec.isotropy, "mirror": spec.mirror},
        counts=counts,
        infeasible=infeasible,
        theta_i=angles[0], phi_i=angles[1], theta_o=angles[2], phi_o=angles[3],
        axes_deg=axes,
        step_kind=step_kind,
        step_pose=step_pose,
        reference_axes_deg=ref,
        estimated_s=float(estimate["total_s"]),
        lower_bound_s=float(bound["total_s"]),
        order=order,
        axis_names=tuple(kin.axis_names),
        timing=timing,
        via_deg=via,
        park_deg=park,
        step_end_s=np.cumsum(step_s),
    )


def _reachable(spec: GridSpec, kin, poses, theta_max: float):
    """The reachable poses (a reachable class member standing in for an unreachable kept pose), their
    loop indices, and the infeasible counts by reason."""
    from gonio.kinematics import REASONS

    angles = [poses.theta_i.copy(), poses.phi_i.copy(), poses.theta_o.copy(), poses.phi_o.copy()]
    codes = np.asarray(kin.feasibility(*angles), dtype=np.int8)
    bad = np.flatnonzero(codes != 0)
    pending = np.ones(bad.size, dtype=bool)
    for member in class_members(spec, *(a[bad] for a in angles)):
        idx = np.flatnonzero(pending)
        if idx.size == 0:
            break
        alt = [np.asarray(x)[idx] for x in member]
        ok = np.asarray(kin.feasibility(*alt)) == 0
        rows = bad[idx[ok]]
        for a, x in zip(angles, alt, strict=True):
            a[rows] = x[ok]
        codes[rows] = 0
        pending[idx[ok]] = False
    reasons = np.bincount(codes, minlength=len(REASONS))
    infeasible = {REASONS[i]: int(c) for i, c in enumerate(reasons) if i and c}
    good = codes == 0
    if not good.any():
        worst = max(infeasible, key=infeasible.get)
        cause = REASON_CAUSES.get(worst, "the gantry configuration")
        total = codes.size
        raise ValueError(
            f"grid '{spec.spelled(theta_max)}': none of the {total:,} poses can be reached "
            f"(mostly {worst}: {infeasible[worst]:,} of {total:,}); the cause is {cause}"
        )
    return [a[good] for a in angles], poses.loops[good], infeasible


def _reference_angles(cfg: GonioConfig) -> tuple[np.ndarray, ...]:
    r = cfg.reference
    return tuple(np.radians(np.array([x])) for x in (r.theta_i_deg, 0.0, r.theta_o_deg, r.dphi_deg))


def _reference_branches(kin, ref_angles, home) -> np.ndarray:
    """The reference pose's valid branches (k, n_axes), or a ValueError naming the cause."""
    from gonio.kinematics import REASONS

    code = int(np.asarray(kin.feasibility(*ref_angles))[0])
    if code != 0:
        reason = REASONS[code]
        raise ValueError(
            f"reference pose (reference.theta_i_deg, theta_o_deg, dphi_deg = "
            f"{', '.join(f'{np.degrees(a[0]):g}' for a in (ref_angles[0], ref_angles[2], ref_angles[3]))}°) "
            f"cannot be reached: {reason} ({REASON_CAUSES.get(reason, 'the gantry configuration')}); "
            "move the reference pose or change that setting")
    sols = np.asarray(kin.solutions(*ref_angles, current_deg=home), dtype=np.float64)[0]
    return sols[~np.isnan(sols).any(axis=1)]


def _best_reference(kin, options: np.ndarray, angles, starts: np.ndarray, home: np.ndarray,
                    metric: MoveMetric) -> np.ndarray:
    """The reference branch with the shortest trips home → ref, ref ↔ runs, ref → home.

    Each run's first and last pose are taken on their branch nearest that reference branch (the chain
    will pick the first pose's branch that way; the last pose's is an estimate).
    """
    ends = np.unique(np.concatenate([starts, np.append(starts[1:], angles[0].size) - 1]))
    sols = np.asarray(kin.solutions(*(a[ends] for a in angles)), dtype=np.float64)
    cost = 2.0 * metric.time(home, options)
    # A branch the gantry cannot reach from home without a collision is no option; one whose move
    # from home collides only as made directly would need via points: the last resort.
    cost[kin.free_component(options) != kin.free_component(home)[0]] = np.inf
    cost[~kin.sweep_clear(np.broadcast_to(home, options.shape), options)] += COLLISION_PENALTY_S
    for k, option in enumerate(options):
        here = np.broadcast_to(option, (ends.size, option.size))
        near = nearest_branch(sols, here, metric)
        cost[k] += np.nansum(metric.time(here, near))
    return options[int(np.argmin(cost))].copy()


def _cut_loops(spec: GridSpec, kin, angles, loops: np.ndarray, start: np.ndarray, metric: MoveMetric,
               every: int) -> np.ndarray:
    """Loop indices for the serpentine: the inner azimuth loop of the grid kind's rows
    (:attr:`~gonio.plan.grids.GridKind.rows`) cut (and maybe split into arcs) where sweeping it is
    cheapest (:func:`gonio.motion.cut.serpentine_loops`)."""
    rows = grid_kind(spec.kind).rows
    if rows is None:  # scattered points: no azimuth row to cut
        return loops
    loops, period = rows(spec, loops.copy())
    return serpentine_loops(kin, angles, loops, period, start, metric, run_length=every)


@dataclass(frozen=True)
class OrderInputs:
    """What an order (a :data:`gonio.registries.ORDERS` entry's target) sees of the reachable poses.

    An order is ``order(inputs)`` returning a permutation of the poses (int array of shape (P,)), or a
    list of candidates, each a function of no argument that returns one: :func:`build_plan` plans each
    and keeps the quickest.

    Attributes
    ----------
    spec : GridSpec
    kin : Kinematics
    angles : tuple of 4 ndarray (P,)
        θi, φi, θo, φo of the poses, radians.
    loops : ndarray of int64 (P, L)
        Each pose's indices in the grid's natural loops, outer first (:class:`~gonio.plan.grids.GridPoses`).
    start : ndarray (n_axes,)
        Where the order starts and ends: the reference pose's branch nearest home, degrees.
    home : ndarray (n_axes,)
    metric : MoveMetric
        Move times between axis positions.
    run_length : int
        Poses between checkpoints (a serpentine chooses its cuts for runs this long).
    seeds : ndarray (K, n_axes)
        Home and the reference branches reachable from it: where a tour may seed its branches.
    """

    spec: GridSpec
    kin: object
    angles: tuple
    loops: np.ndarray
    start: np.ndarray
    home: np.ndarray
    metric: MoveMetric
    run_length: int
    seeds: np.ndarray


def order_raster(x: OrderInputs) -> np.ndarray:
    """The grid's loops in their natural order."""
    return raster_order(x.loops)


def order_serpentine(x: OrderInputs) -> np.ndarray:
    """The innermost loop swept back and forth, cut where sweeping is cheapest."""
    return serpentine_order(_cut_loops(x.spec, x.kin, x.angles, x.loops, x.start, x.metric, x.run_length))


def order_tour(x: OrderInputs) -> list:
    """A tour through the poses for each of the most promising branch sets (:func:`_tour_seeds`), at most
    :data:`TOUR_SEED_TRIALS` of them."""
    from functools import partial

    n = x.angles[0].size
    seeds = _tour_seeds(x.kin, x.angles, x.seeds, x.metric)
    trials = min(len(seeds), TOUR_SEED_TRIALS if n <= TOUR_SEED_TRIALS_MAX_POSES else 1)
    return [partial(_tour_order, x.kin, x.angles, *seeds[i], x.start, x.home, x.metric)
            for i in range(max(trials, 1))]


def _resolve_order(spec: GridSpec, kind: GridKind, n: int) -> str:
    if spec.order == "tour" and n > TOUR_MAX_POSES:
        raise ValueError(f"grid '{spec.kind}': option 'order=tour' handles at most {TOUR_MAX_POSES:,} "
                         f"poses, this grid has {n:,}; use order=serpentine")
    if spec.order != "auto":
        return spec.order
    if kind.auto == "tour" and n <= TOUR_MAX_POSES:
        return "tour"
    return "serpentine"


def _tour_seeds(kin, angles, seeds, metric: MoveMetric) -> list[tuple[np.ndarray, np.ndarray]]:
    """Candidate branches per pose for a tour to be ordered on, with their neighbour lists, most
    promising first.

    A tour is searched over one fixed position per pose; its branches are chosen again afterwards, for
    the order found. Taking each pose's branch nearest home mixes branch families where they are about
    as near (the sample stage's two tilt signs: 194 of 304 poses one way and 105 the other on
    ``iso:step=15``), and the order then pays for flips the branch choice can only partly undo. So each
    seed (home and every reference branch reachable from it) picks the branches nearest itself, and
    the sets are ranked by how close together their poses lie (the sum of each pose's two nearest
    moves, twice the degree bound of a tour through them); sets lying exactly as close together count
    once, and sets more than :data:`TOUR_SEED_MARGIN` less close together than the closest are dropped.
    The ranking is a good guide, not a sure one: the swept-path check may re-choose branches after
    ordering, so :func:`build_plan` orders the first :data:`TOUR_SEED_TRIALS` of them and keeps the
    quickest plan.
    """
    ranked = []
    for seed in np.unique(np.asarray(seeds, dtype=np.float64), axis=0):
        points = kin.inverse(*angles, current_deg=seed)
        neigh, times = neighbour_lists(points, metric)
        spread = float(times[:, :2].sum())
        # The same spread as a set before: the same branches but at the poles, where a free azimuth
        # stands wherever the seed has it (the two-arm gantry's home and reference seeds).
        if any(abs(spread - r[0]) <= 1e-9 * spread for r in ranked):
            continue
        ranked.append((spread, len(ranked), points, neigh))
    ranked.sort(key=lambda r: (r[0], r[1]))
    # Only sets about as close together as the closest are worth planning.
    return [(points, neigh) for spread, _, points, neigh in ranked
            if spread <= ranked[0][0] * (1.0 + TOUR_SEED_MARGIN)]


def _tour_order(kin, angles, points, neighbours, depot, home, metric: MoveMetric) -> np.ndarray:
    """A tour from and back to ``depot`` through the poses at ``points`` (one branch each: see
    :func:`_tour_seeds`).

    At most :data:`~gonio.motion.exact.EXACT_MAX_POSES` poses: the optimum over every order and branch
    choice (:func:`gonio.motion.exact.exact_order`; the search below ended up to 13 % above it on
    8-12-pose sets of the sample stage). More: nearest neighbour, 2-opt/Or-opt with kicks; then, for at
    most :data:`TOUR_REFINE_MAX_POSES` poses, the same moves priced after choosing every pose's branch
    again (:func:`gonio.motion.refine.refine_order`, :data:`TOUR_REFINE_KICKS` restarts, then windows of
    :data:`TOUR_REFINE_WINDOW` stops solved exactly), which finds what a search on fixed branches
    cannot."""
    n = points.shape[0]
    if 2 <= n <= EXACT_MAX_POSES:
        return exact_order(_branch_table(kin, angles, home, depot), depot, depot, metric)[0]
    perm = nearest_neighbour_tour(points, metric, depot, neighbours)
    perm = perturb_tour(points, perm, metric, depot, neighbours,
                        kicks=min(TOUR_KICKS_PER_POSE * n, TOUR_KICKS_MAX))
    if 2 <= n <= TOUR_REFINE_MAX_POSES:
        perm, _ = refine_order(_branch_table(kin, angles, home, depot), perm, depot, depot, metric,
                               kicks=TOUR_REFINE_KICKS, window=TOUR_REFINE_WINDOW)
    return perm


def _branch_table(kin, angles, home, ref) -> np.ndarray:
    """Every valid branch (P, W, n_axes) of the poses reachable from the reference without a collision,
    invalid ones replaced by a valid one of the same pose (:func:`gonio.motion.relaxed.pose_branches`)."""
    sols = np.asarray(kin.solutions(*angles, current_deg=home), dtype=np.float64)
    valid = ~np.isnan(sols[..., 0])
    part = kin.free_component(np.asarray(ref, float)[None])[0]
    valid &= kin.free_component(np.where(valid[..., None], sols, 0.0)).reshape(valid.shape) == part
    sols[~valid] = np.nan
    return pose_branches(sols)


def _valid_bound(kin, angles, ref_options, home, metric, settle_s, reading_s, every, every_s,
                 run_lengths) -> dict:
    """The lower bound over every order and branch choice (:mod:`gonio.motion.relaxed`).

    It depends on the pose set, not on its order (``run_lengths`` only through their number, on
    count-only schedules, which is the same for every order): the poses are taken in a canonical order
    so that every order of the same grid gets the same figure, to the last digit. The last
    :data:`_BOUNDS_KEPT` bounds of each kinematics are remembered by their inputs (the Lagrangian's
    hundred spanning trees are most of a small plan's time), so that planning the same poses in another
    order (``order=auto`` after ``serpentine``, or a daemon's next plan) computes it once (with the
    tuning of :mod:`gonio.motion.relaxed` as it was then)."""
    angles = tuple(a[np.lexsort(angles[::-1])] for a in angles)
    key = (b"".join(np.ascontiguousarray(x, dtype=np.float64).tobytes()
                    for x in (*angles, ref_options, home, metric.velocity_deg_s, metric.accel_deg_s2)),
           np.asarray(run_lengths, dtype=np.int64).tobytes(), float(settle_s), float(reading_s), every,
           every_s)
    known = _BOUNDS.setdefault(kin, {})
    if key not in known:
        known[key] = _relaxed_bound(kin, angles, ref_options, home, metric, settle_s, reading_s, every,
                                    every_s, run_lengths)
        while len(known) > _BOUNDS_KEPT:
            known.pop(next(iter(known)))
    return dict(known[key])


#: Bounds remembered per kinematics (:func:`_valid_bound`), the oldest forgotten first.
_BOUNDS_KEPT = 8
_BOUNDS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _relaxed_bound(kin, angles, ref_options, home, metric, settle_s, reading_s, every, every_s,
                   run_lengths) -> dict:
    """:func:`_valid_bound` computed, the poses in canonical order."""
    n = angles[0].size
    keep = np.arange(n)
    if n > BOUND_MAX_POSES:
        keep = np.unique(np.linspace(0, n - 1, BOUND_MAX_POSES).round().astype(np.int64))
    sub = tuple(a[keep] for a in angles)
    free = np.zeros(n, dtype=bool)
    free[keep] = free_azimuth(*sub)
    free[np.setdiff1d(np.arange(n), keep)] = True  # left out of the moves like a free pose
    table = _branch_table(kin, tuple(a[~free] for a in angles), home, home) if (~free).any() \
        else np.empty((0, 1, home.size))
    branches = np.full((n, table.shape[1], home.size), np.nan)
    branches[~free] = table
    part = kin.free_component(home)[0]
    options = ref_options[kin.free_component(ref_options) == part]
    return relaxed_campaign_bound(branches, free, options, home, metric, settle_s, reading_s, every, every_s,
                                  run_lengths=run_lengths)


def _reference_share(targets, step_kind, home, metric, settle_s, reading_s, extra) -> float:
    """Seconds the checkpoints add to the campaign: their readings and settle, and the moves into
    and out of each reference beyond the direct move between the poses on either side (s)."""
    moving = ~np.isnan(targets).any(axis=1)
    pts = np.vstack([home, targets[moving], home])
    kinds = np.concatenate([[STEP_POSE], step_kind[moving], [STEP_POSE]])
    legs = metric.time(pts[:-1], pts[1:])
    legs[:-1] += extra[:-1][moving]
    legs[-1] += extra[-1]
    is_ref = np.flatnonzero(kinds == STEP_REFERENCE)
    detour = legs[is_ref - 1] + legs[is_ref] - metric.time(pts[is_ref - 1], pts[is_ref + 1])
    readings = np.count_nonzero(step_kind != STEP_POSE) * reading_s
    return float(detour.sum() + is_ref.size * settle_s + readings)
