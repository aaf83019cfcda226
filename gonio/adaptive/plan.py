"""An adaptive campaign's plans, from its journal alone: the pilot's, each round's, and the rule that
sizes the rounds.

The pilot is the lattice of :mod:`gonio.adaptive.pilot` planned as any grid is
(:func:`gonio.plan.build.build_plan` with the lattice's poses: reachability with the Helmholtz twin
standing in, a tour, branches, checkpoints): for ``poses=N`` the densest lattice of at most
:data:`~gonio.adaptive.acquire.PILOT_FRACTION` · N reachable poses, for ``budget_s=T`` the densest whose
plan is estimated at most that fraction of T (at least the 2-node lattice either way; a budget below that
pilot is refused). A round is :func:`gonio.adaptive.refine.plan_round` of the samples calibrated from
every committed reading, planned the same way; its steps continue the journal's (the checkpoint that ends
the last phase brackets the round's first run, so the round's own first one is left out).

Round sizes (:func:`round_size`) depend only on the journal's ``adaptive`` meta: with ``poses=N``,
:func:`~gonio.adaptive.acquire.round_sizes` of the pilot and N, at least :data:`MIN_ROUND` poses each
(a round of 10 poses is still worth its tour); with
``budget_s=T`` the same growth, cut to the poses the time left holds at the estimated time per pose so
far (estimates, not the clock: a resumed campaign plans the same round whatever the downtime).

A round may find fewer poses than its size where the gantry's reach, its occlusion cone and theta_max
leave no more new ones (:func:`gonio.adaptive.refine.plan_round`); it is measured as it is. A round
that finds none ends the campaign short of its budget: :func:`next_round` returns no steps and the
meta ``adaptive.ended`` (the round and the reason, in words), appended like a round in one transaction,
so ``gonio status``, the report and a resume see it (:func:`ended_text`); no round is planned after it.

Gantry time: a round's poses are chosen with their motion cost (:data:`MOTION_WEIGHT`,
:mod:`gonio.adaptive.motion`), and its checkpoints are kept only where the drift model needs them
(:data:`CHECKPOINTS_AS_NEEDED`, :func:`_checkpoints`). Both are journaled in the ``adaptive`` meta of a
new campaign (``motion_weight``, ``motion_pool``, ``since_reference_s``), so a journal written before
them replays its rounds as it planned them.

``anisotropic=true``: the pilot is :func:`gonio.adaptive.pilot.pilot_pairs`' ``full:step=S`` grid (the
densest of :data:`~gonio.adaptive.pilot.PAIR_STEPS` within the same share of the budget; the meta keeps
``pilot_step``, and ``pilot_nodes`` is None), the samples keep their φi, and each round is the same
:func:`~gonio.adaptive.refine.plan_round` in the 4D ``pair`` domain; everything else is as above.
"""

from __future__ import annotations

import numpy as np

from gonio.adaptive.acquire import GROWTH, PILOT_FRACTION, round_sizes
from gonio.adaptive.motion import POOL, round_motion
from gonio.adaptive.pilot import PAIR_STEPS, lattice, pair_lattice, pilot_nodes, pilot_pairs
from gonio.adaptive.refine import LOO, PAIR_CELLS, PAIR_LOO, plan_round
from gonio.adaptive.samples import Samples
from gonio.calibrate import calibrate, reference_rho
from gonio.plan.build import Plan, build_plan
from gonio.plan.grids import ADAPTIVE_MAX_BUDGET_S, ADAPTIVE_MAX_POSES, GridPoses, parse_grid
from gonio.plan.schedule import STEP_DARK, STEP_POSE, STEP_REFERENCE, step_table

__all__ = ["pilot_plan", "round_size", "journal_samples", "next_round", "expected_steps", "budget_text",
           "ended_text", "pilot_text", "MIN_ROUND", "SEED", "MOTION_WEIGHT", "LEGACY_POOL",
           "CHECKPOINTS_AS_NEEDED"]

#: Least poses of a round (the last one excepted).
MIN_ROUND = 10
#: Seed of the rounds' random trial points (:func:`gonio.adaptive.refine.plan_round`).
SEED = 0
#: Exponent of a candidate pose's gantry time in its worth (:mod:`gonio.adaptive.motion`; 0: motion
#: ignored), journaled with each new campaign (a journal without it replays its rounds with 0).
MOTION_WEIGHT = 2.0
#: The motion pool (:data:`gonio.adaptive.motion.POOL`) of journals written before it was journaled.
LEGACY_POOL = 3
#: Checkpoints as needed (:func:`_checkpoints`) for new campaigns, journaled as ``since_reference_s`` (a
#: journal without it closes every round with a checkpoint).
CHECKPOINTS_AS_NEEDED = True


def _given(theta_i, phi_i, theta_o, phi_o) -> GridPoses:
    n = np.size(theta_i)
    return GridPoses(*(np.asarray(a, np.float64) for a in (theta_i, phi_i, theta_o, phi_o)),
                     np.arange(n, dtype=np.int64)[:, None], {"grid": int(n)})


def _theta_max_deg(spec, cfg) -> float:
    return spec.theta_max_deg if spec.theta_max_deg is not None else cfg.kinematics.theta_max_deg


def pilot_plan(grid: str, cfg, kin=None) -> tuple[Plan, dict]:
    """The pilot's plan of the adaptive ``grid`` on the gantry ``cfg``, and the ``adaptive`` meta the
    journal keeps (the budget, the pilot's size and estimate, the rounds so far: none).

    Raises
    ------
    ValueError
        A budget below the pilot's (naming the option and the least it may be).
    """
    from gonio.kinematics import make_kinematics

    spec = parse_grid(grid)
    kin = make_kinematics(cfg) if kin is None else kin
    tmax_deg = _theta_max_deg(spec, cfg)
    tmax = np.radians(tmax_deg)

    def plan(m):
        ti, to, d = lattice(m, tmax)
        return build_plan(grid, cfg, kin, poses=_given(ti, np.zeros_like(ti), to, d))

    def plan_pairs(step):
        return build_plan(grid, cfg, kin, poses=_given(*pair_lattice(step, tmax)))

    step = None
    if spec.anisotropic and spec.poses is not None:
        m, step = None, pilot_pairs(kin, tmax, max(1, int(PILOT_FRACTION * spec.poses)))[0]
        pilot = plan_pairs(step)
        _check_budget(spec, pilot)
    elif spec.anisotropic:
        m, step = None, PAIR_STEPS[0]
        pilot = plan_pairs(step)
        _check_budget(spec, pilot)
        top = pilot_pairs(kin, tmax, int(PILOT_FRACTION * ADAPTIVE_MAX_POSES))[0]
        for finer in PAIR_STEPS[1:PAIR_STEPS.index(top) + 1]:   # as the isotropic lattices below
            bigger = plan_pairs(finer)
            if bigger.estimated_s > PILOT_FRACTION * spec.budget_s:
                break
            step, pilot = finer, bigger
    elif spec.poses is not None:
        m = pilot_nodes(kin, tmax, max(1, int(PILOT_FRACTION * spec.poses)))
        pilot = plan(m)
        _check_budget(spec, pilot)
    else:
        m, pilot = 2, plan(2)
        _check_budget(spec, pilot)
        # The densest lattice within the pilot's share of the time (estimates grow with m; the smaller
        # ones cost least to plan, so they are tried first), and within the pilot's share of the largest
        # pose budget.
        top = pilot_nodes(kin, tmax, int(PILOT_FRACTION * ADAPTIVE_MAX_POSES))
        while m < top:
            bigger = plan(m + 1)
            if bigger.estimated_s > PILOT_FRACTION * spec.budget_s:
                break
            m, pilot = m + 1, bigger
    n = int(pilot.theta_i.size)
    meta = {"budget_poses": spec.poses, "budget_s": spec.budget_s,
            "pilot_nodes": None if m is None else int(m), "pilot_poses": n,
            "pilot_s": float(pilot.estimated_s), "pilot_lower_bound_s": float(pilot.lower_bound_s),
            "min_round": MIN_ROUND, "growth": GROWTH, "seed": SEED, "motion_weight": MOTION_WEIGHT,
            "motion_pool": POOL,
            "rounds": []}
    if step is not None:
        meta["pilot_step"] = float(step)
    if CHECKPOINTS_AS_NEEDED:
        meta["since_reference_s"] = 0.0
    return pilot, meta


def _check_budget(spec, pilot: Plan) -> None:
    """ValueError when the budget is below the pilot's poses or its estimated gantry time."""
    if spec.poses is not None and pilot.theta_i.size > spec.poses:
        raise ValueError(f"grid '{spec.kind}': option 'poses' must be at least the pilot's "
                         f"{pilot.theta_i.size} poses (and at most {ADAPTIVE_MAX_POSES:,}), got {spec.poses}")
    if spec.budget_s is not None and pilot.estimated_s > spec.budget_s:
        raise ValueError(f"grid '{spec.kind}': option 'budget_s' must be at least the pilot's "
                         f"{pilot.estimated_s:,.0f} s of gantry time (up to {ADAPTIVE_MAX_BUDGET_S:,.0f}), "
                         f"got {spec.budget_s:g}")


def round_size(adaptive: dict) -> int:
    """Poses of the next round from the journal's ``adaptive`` meta (module docstring); 0: the budget is
    spent."""
    rounds = adaptive["rounds"]
    if adaptive.get("ended"):
        return 0
    if adaptive["budget_poses"] is not None:
        sizes = _sizes(adaptive)
        return sizes[len(rounds)] if len(rounds) < len(sizes) else 0
    poses = adaptive["pilot_poses"] + sum(r["poses"] for r in rounds)
    spent = adaptive["pilot_s"] + sum(r["estimated_s"] for r in rounds)
    left = min(int((adaptive["budget_s"] - spent) / (spent / poses)), ADAPTIVE_MAX_POSES - poses)
    return max(0, min(max(adaptive["min_round"], int(adaptive["growth"] * poses)), left))


def _sizes(adaptive: dict) -> list[int]:
    """Every round's size under a pose budget."""
    pilot = adaptive["pilot_poses"]
    return round_sizes(pilot, max(pilot, adaptive["budget_poses"]), adaptive["growth"], adaptive["min_round"])


def journal_samples(journal, cfg) -> Samples:
    """The samples of every committed pose reading, calibrated (:func:`gonio.calibrate.calibrate`) at
    their planned poses (θi, θo, Δφ = φo − φi, and φi)."""
    rho, _ = reference_rho(cfg.reference, journal.detector())
    cal = calibrate(journal.measurements(extra=False), rho)
    steps = journal.steps()
    ti, pi_, to, po = (np.radians(steps[f"{a}_deg"][cal.steps])
                       for a in ("theta_i", "phi_i", "theta_o", "phi_o"))
    d = np.where(to > 0, np.mod(po - pi_, 2.0 * np.pi), 0.0)
    return Samples(ti, to, d, cal.value, pi_)


def next_round(journal, cfg, kin=None) -> tuple[dict, dict, str] | None:
    """The next round of the adaptive campaign in ``journal`` (every step of it measured): (steps to
    append, meta to set, a line saying what it is) for :meth:`gonio.store.Journal.append_steps`, or None
    when the budget is spent. A pure function of the journal (its meta, config snapshot and readings)."""
    from gonio.kinematics import make_kinematics

    meta = journal.meta()
    adaptive = meta["adaptive"]
    n = round_size(adaptive)
    if n == 0:
        return None
    kin = make_kinematics(cfg) if kin is None else kin
    spec = parse_grid(meta["grid"])
    tmax = np.radians(_theta_max_deg(spec, cfg))
    samples = journal_samples(journal, cfg)
    weight = adaptive.get("motion_weight", 0.0)
    # A journal from before the pool was journaled replays its rounds with the pool they were placed with.
    motion = round_motion(cfg, kin, weight, adaptive.get("motion_pool", LEGACY_POOL)) if weight else None
    if spec.anisotropic:
        ti, pi_, to, po = plan_round(samples, n, kin, tmax, PAIR_CELLS, adaptive["seed"], PAIR_LOO, motion)
    else:
        ti, to, po = plan_round(samples, n, kin, tmax, seed=adaptive["seed"], loo=LOO, motion=motion)
        pi_ = np.zeros_like(ti)
    if ti.size == 0:
        k = len(adaptive["rounds"]) + 1
        reason = (f"round {k} found no reachable new pose (the gantry's reach, its occlusion cone and "
                  f"theta_max leave none): ended with {int(meta['poses']):,} poses of a budget of "
                  f"{budget_text(adaptive)}")
        # The readings since the last reference still need one after them (checkpoints as needed).
        journaled = journal.steps()
        closing = _closing_checkpoint(journaled) if adaptive.get("since_reference_s") else slice(0, 0)
        steps = {key: v[closing] for key, v in journaled.items()}
        if steps["kind"].size:   # the dark is read where the gantry stands: at the journal's last step
            steps["axes_deg"][0] = journaled["axes_deg"][-1]
        after = {**adaptive, "ended": {"round": k, "reason": reason}}
        if "since_reference_s" in adaptive:
            after["since_reference_s"] = 0.0
        return steps, {"adaptive": after}, reason
    plan = build_plan(meta["grid"], cfg, kin, poses=_given(ti, pi_, to, po))
    steps = step_table(plan, cfg)
    if not (steps["kind"][0] == STEP_DARK and steps["kind"][1] == STEP_REFERENCE):  # pragma: no cover
        raise AssertionError("a plan's steps begin with a checkpoint")
    added = int(plan.theta_i.size)
    estimated = float(plan.estimated_s)
    stub = {"poses": added, "estimated_s": estimated}
    final = round_size({**adaptive, "rounds": [*adaptive["rounds"], stub]}) == 0
    keep, since = _checkpoints(adaptive, steps["kind"], plan.step_end_s, cfg.reference.every_s, final)
    if keep.stop < steps["kind"].size:   # the closing checkpoint left to a later round
        estimated -= float(plan.step_end_s[-1] - plan.step_end_s[keep.stop - 1])
    if "since_reference_s" in adaptive and not final:   # the gantry goes home after the last round only
        estimated -= float(plan.timing["estimate"]["return_s"])
    if keep.start == 0:   # a dark is read where the gantry stands: after the journal's last step
        steps["axes_deg"][0] = journal.steps()["axes_deg"][-1]
    steps = {k: v[keep] for k, v in steps.items()}
    steps["pose"] = np.where(steps["kind"] == STEP_POSE, steps["pose"] + int(meta["poses"]), -1)
    entry = {"poses": added, "estimated_s": estimated,
             "lower_bound_s": float(plan.lower_bound_s), "first_step": journal.step_count(),
             "steps": int(steps["kind"].size)}
    rounds = adaptive["rounds"] + [entry]
    line = (f"round {len(rounds)}: {added} poses placed from {len(samples)} samples, estimated "
            f"{plan.estimated_s:.0f} s")
    after = {**adaptive, "rounds": rounds}
    if "since_reference_s" in adaptive:
        after["since_reference_s"] = since
    return steps, {"adaptive": after, "poses": int(meta["poses"]) + added}, line


def _checkpoints(adaptive: dict, kind, end_s, every_s, final: bool) -> tuple[slice, float]:
    """Which of a round's planned steps to journal, and the estimated gantry time from its last reference
    reading to its end (0 when it closes with a checkpoint).

    A round's plan is [checkpoint, run, checkpoint, ..., run, checkpoint]. A campaign journaled before
    checkpoints were placed as needed (no ``since_reference_s`` in its meta) drops the first (the one
    closing the phase before brackets the first run) and keeps the rest. Otherwise the first is kept only
    when the readings since the last reference and the round's first run would span more than
    ``every_s`` between references (``reference.every_s``), and the last only in the ``final`` round
    (the one that spends the budget): every reading is still bracketed by references at most about
    ``every_s`` apart (estimates), as a uniform grid's are, without a detour to the reference after every
    round. With no ``every_s`` (a count of poses between references instead) every round closes with its
    checkpoint."""
    size = len(kind)
    since = adaptive.get("since_reference_s")
    if since is None or every_s is None:
        return slice(2, size), 0.0
    refs = np.flatnonzero(np.asarray(kind) == STEP_REFERENCE)
    first = 0 if since + float(end_s[refs[1]] - end_s[refs[0]]) > every_s else 2
    if final:
        return slice(first, size), 0.0
    last = size - 2   # the closing checkpoint's dark: left out with its reference
    kept = [r for r in refs[:-1] if r >= first]
    start = end_s[kept[-1]] if kept else end_s[refs[0]] - since
    return slice(first, last), float(end_s[last - 1] - start)


def _closing_checkpoint(steps: dict) -> np.ndarray:
    """Step indices of a checkpoint to close the journal with: a dark where the gantry stands (its last
    step's axes) and the white reference as the journal's first checkpoint read it."""
    dark = int(np.flatnonzero(steps["kind"] == STEP_DARK)[0])
    return np.array([dark, int(np.flatnonzero(steps["kind"] == STEP_REFERENCE)[0])])


def expected_steps(meta: dict, steps: int) -> int:
    """The steps an adaptive campaign will hold when done, estimated from its meta and the ``steps`` its
    journal holds now (a progress bar's total): each round to come adds its poses and one checkpoint
    (with checkpoints as needed, :func:`_checkpoints`: the last round's only, a lower estimate)."""
    adaptive = meta["adaptive"]
    poses = int(meta["poses"])
    if adaptive.get("ended"):
        return steps
    if adaptive["budget_poses"] is not None:
        left = max(0, len(_sizes(adaptive)) - len(adaptive["rounds"]))
        checkpoints = min(left, 1) if "since_reference_s" in adaptive else left
        return steps + max(0, adaptive["budget_poses"] - poses) + 2 * checkpoints
    spent = adaptive["pilot_s"] + sum(r["estimated_s"] for r in adaptive["rounds"])
    return max(steps, int(steps * adaptive["budget_s"] / spent))


def pilot_text(adaptive: dict) -> str:
    """What the pilot is, in words: ``a 5-node lattice`` or, anisotropic, ``the full:step=45 grid``."""
    if adaptive.get("pilot_step") is not None:
        return f"the full:step={adaptive['pilot_step']:g} grid"
    return f"a {adaptive['pilot_nodes']}-node lattice"


def ended_text(adaptive: dict) -> str | None:
    """Why the campaign ended short of its budget (a round found no reachable new pose), or None."""
    ended = adaptive.get("ended")
    return ended["reason"] if ended else None


def budget_text(adaptive: dict) -> str:
    """The budget in words: ``1,000 poses`` or ``3,600 s of gantry time``."""
    if adaptive["budget_poses"] is not None:
        return f"{adaptive['budget_poses']:,} poses"
    return f"{adaptive['budget_s']:,.0f} s of gantry time"
