"""A campaign folder: the journal, the plan it holds, and the sampled BRDF made from it.

``create_campaign`` plans and journals a campaign (no hardware touched), its *kind* recorded in the
journal (``stop-and-go`` or ``fly``: which unit source the engine runs, :mod:`gonio.units`);
``finish_campaign`` writes ``brdf.h5`` from a journal whose every step is measured. Running, resuming
and the rules a request passes are the campaign lifecycle's (:mod:`gonio.lifecycle`), which the CLI and
the daemon both go through.

A folder is run by one process at a time: :class:`CampaignLock` holds an exclusive ``flock`` on
``campaign.lock`` for as long as the campaign is open for writing (the kernel releases it when the
process dies, however it dies).
"""

from __future__ import annotations

import dataclasses
import fcntl
import hashlib
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from gonio import SEED_MAX, software_version
from gonio.plan.grids import grid_kind, parse_grid
from gonio.plan.schedule import step_table
from gonio.store import JOURNAL_NAME, LOCK_NAME, Journal, JournalError, lock_holder
from gonio.units import ADAPTIVE, FLY, KINDS, STOP_AND_GO

# The planner, the config's models, the calibration and HDF5 are imported by the functions that use
# them: reading a campaign's state (gonio status) needs none of them (tools/bench_startup.py).
if TYPE_CHECKING:
    from gonio.config import GonioConfig
    from gonio.plan import Plan
    from gonio.plan.fly import FlyPlan
    from gonio.protocols import Gantry

__all__ = ["Campaign", "CampaignLock", "Planned", "plan_campaign", "create_campaign", "open_campaign",
           "finish_campaign", "software_version", "config_hash", "config_snapshot", "compare_campaign",
           "LOCK_NAME", "journal_devices", "kind_of", "gantry_state"]


def config_snapshot(cfg: GonioConfig) -> dict:
    """The validated config as the journal keeps it: every setting that differs from its default (the
    defaults fill back in when it is parsed again, so the snapshot round-trips whatever the schema adds)."""
    return cfg.model_dump(mode="json", exclude_defaults=True)


def config_hash(cfg: GonioConfig) -> str:
    """SHA-256 of the config snapshot (canonical JSON): what a campaign was planned with."""
    text = json.dumps(config_snapshot(cfg), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


class LockHeld(Exception):
    """:func:`pid_lock` found the lock held; ``holder`` is the pid its holder wrote ("?" if none)."""

    def __init__(self, holder: str):
        super().__init__(holder)
        self.holder = holder


#: How long :func:`pid_lock` tries before it says the lock is held: a reader that asks whether anyone
#: holds it (:func:`gonio.store.lock_holder`) takes a shared lock for microseconds, and a writer arriving
#: in that instant must not take it for a campaign running elsewhere.
LOCK_PATIENCE_S = 0.25


def pid_lock(path: Path) -> int:
    """Take the exclusive ``flock`` on ``path`` (created if missing) and write this process's pid into
    it; the open descriptor (closing it releases the lock). LockHeld if another process holds it for
    :data:`LOCK_PATIENCE_S` (a reader's probe is over long before). The kernel drops the lock when its
    holder dies, even by SIGKILL."""
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    deadline, pause = time.monotonic() + LOCK_PATIENCE_S, 0.001
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            break
        except BlockingIOError:
            if time.monotonic() >= deadline:
                holder = os.read(fd, 64).decode(errors="replace").strip() or "?"
                os.close(fd)
                raise LockHeld(holder) from None
            time.sleep(pause)
            pause = min(2 * pause, 0.05)
    os.ftruncate(fd, 0)
    os.write(fd, str(os.getpid()).encode())
    return fd


class CampaignLock:
    """An exclusive lock on a campaign folder (``campaign.lock``, ``flock``), held until :meth:`release`."""

    def __init__(self, folder: str | Path):
        self.path = Path(folder) / LOCK_NAME
        self._fd: int | None = None

    def acquire(self) -> CampaignLock:
        try:
            self._fd = pid_lock(self.path)
        except LockHeld as held:
            raise JournalError(f"{self.path.parent}: another gonio process (pid {held.holder}) is running "
                               "this campaign; wait for it, or stop it first") from None
        return self

    def release(self) -> None:
        if self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None

    @staticmethod
    def holder(folder: str | Path) -> int | None:
        """The pid of the process holding ``folder``'s lock (running its campaign now; -1 when it wrote
        none), or None."""
        return lock_holder(Path(folder) / LOCK_NAME)


def kind_of(meta: dict) -> str:
    """A journal's campaign kind: the one recorded at creation; a journal from before kinds were recorded
    is ``fly`` when it holds a fly summary (``create_fly_campaign`` wrote one), else ``stop-and-go``."""
    return meta.get("kind") or (FLY if "fly" in meta else STOP_AND_GO)


@dataclass
class Campaign:
    folder: Path
    journal: Journal
    cfg: GonioConfig
    lock: CampaignLock | None = None
    #: The fly plan its journal's steps were made from, where this process planned it
    #: (:func:`create_campaign`); None: rebuilt from the journal when needed
    #: (:func:`gonio.fly.plans.rebuild_fly_plan`).
    fly: FlyPlan | None = None

    @property
    def meta(self) -> dict:
        return self.journal.meta()

    @property
    def kind(self) -> str:
        """``stop-and-go``, ``fly`` or ``adaptive`` (:func:`kind_of`): which unit source the engine runs."""
        return kind_of(self.meta)

    def close(self) -> None:
        self.journal.close()
        if self.lock is not None:
            self.lock.release()


@dataclass(frozen=True)
class Planned:
    """A campaign planned and not yet journaled: its kind, its stop-and-go plan and, for a fly campaign,
    its fly plan (:func:`plan_campaign`)."""

    kind: str
    plan: Plan
    fly: FlyPlan | None = None
    #: Further meta the journal keeps (an adaptive campaign's ``adaptive``: its budget and rounds).
    meta: dict = dataclasses.field(default_factory=dict)

    @property
    def steps(self) -> int:
        """How many steps its journal will hold (readings with their darks and references)."""
        if self.fly is None:
            return len(self.plan.step_kind)
        from gonio.plan.fly import fly_step_table

        return len(fly_step_table(self.fly)[0])


def plan_campaign(grid: str, cfg: GonioConfig) -> Planned:
    """Plan ``grid`` on the gantry ``cfg``; the kind follows the grid (``order=fly``: a fly campaign; an
    ``adaptive`` grid: an adaptive campaign, planned up to its pilot, :mod:`gonio.adaptive.plan`).
    ValueError (naming the field) for a grid the planner refuses."""
    from gonio.plan import build_plan

    spec = parse_grid(grid)
    if grid_kind(spec.kind).campaign == ADAPTIVE:
        from gonio.adaptive.plan import pilot_plan

        plan, adaptive = pilot_plan(grid, cfg)
        # The whole budget's estimate (at the pilot's pace for a pose budget): what a status's ETA is of.
        pace = plan.estimated_s / max(1, len(plan.theta_i))
        whole = adaptive["budget_s"] or pace * adaptive["budget_poses"]
        return Planned(ADAPTIVE, plan, meta={"adaptive": adaptive, "estimated_s": float(whole)})
    if spec.order == "fly":
        from gonio.fly.plans import fly_plans

        plan, fp = fly_plans(grid, cfg)
        return Planned(FLY, plan, fp)
    return Planned(STOP_AND_GO, build_plan(grid, cfg))


def create_campaign(folder: str | Path, cfg: GonioConfig, *, grid: str, material: str | None, seed: int = 0,
                    plan: Plan | None = None, write_hook=None, sample: str | None = None,
                    planned: Planned | None = None) -> Campaign:
    """Plan the campaign and journal it in ``folder`` (created; must not hold a campaign already).

    Everything is validated and planned before anything is written; the journal then appears whole or
    not at all (:meth:`gonio.store.Journal.create`). ``material`` is the simulated material's spec
    (normalized by the caller), ``sample`` the name of a real sample. ``planned`` (or ``plan``, a
    stop-and-go plan): what :func:`plan_campaign` gave for this grid and config, when the caller has it.

    The journal's meta records the campaign's ``kind``; a fly campaign's has ``estimated_s`` and
    ``lower_bound_s`` those of the fly plan, ``stop_and_go_estimated_s`` beside them and ``fly`` its
    summary, and its steps are the fly plan's readings in order (:func:`gonio.plan.fly.fly_step_table`).
    """
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or not 0 <= seed <= SEED_MAX:
        raise ValueError(f"seed: must be an integer in [0, {SEED_MAX}], got {seed!r}")
    folder = Path(folder)
    if planned is None:
        planned = Planned(STOP_AND_GO, plan) if plan is not None else plan_campaign(grid, cfg)
    if planned.kind not in KINDS:
        raise ValueError(f"kind: {planned.kind!r} is not a campaign kind; known: {', '.join(KINDS)}")
    plan, extra = planned.plan, {}
    if planned.fly is not None:
        from gonio.plan.fly import fly_step_table, fly_summary

        fp = planned.fly
        kind, pose = fly_step_table(fp)
        extra = {"fly": fly_summary(fp), "stop_and_go_estimated_s": float(plan.estimated_s)}
        plan = dataclasses.replace(plan, step_kind=kind, step_pose=pose, estimated_s=fp.estimated_s,
                                   lower_bound_s=fp.lower_bound_s)
    meta = {"kind": planned.kind, **extra,
        "grid": plan.grid, "grid_requested": parse_grid(grid).normalized, "material": material,
        "sample": sample, "seed": int(seed), "symmetries": plan.symmetries,
        "counts": plan.counts, "infeasible": plan.infeasible, "poses": int(len(plan.theta_i)),
        "estimated_s": float(plan.estimated_s), "lower_bound_s": float(plan.lower_bound_s),
        "axis_names": list(cfg.axis_names), "channels": list(cfg.detector.channel_names),
        "detector": cfg.detector.descriptor(),
        "gantry": cfg.name, "config": config_snapshot(cfg), "config_sha256": config_hash(cfg),
        "software_version": software_version(), "created_unix": time.time(),
        **planned.meta,
    }
    steps = step_table(plan, cfg)
    folder.mkdir(parents=True, exist_ok=True)
    lock = CampaignLock(folder).acquire()
    try:
        journal = Journal.create(folder / JOURNAL_NAME, meta, steps, write_hook=write_hook)
    except BaseException:
        lock.release()
        raise
    return Campaign(folder, journal, cfg, lock, fly=planned.fly)


def open_campaign(folder: str | Path, *, write_hook=None, readonly: bool = False) -> Campaign:
    """Reopen a campaign (to resume it, or ``readonly`` to look at it while it runs): the config is the
    snapshot it was planned with. For writing, the folder's lock is taken first."""
    from gonio.config import parse_config

    folder = Path(folder)
    lock = None if readonly else CampaignLock(folder).acquire()
    try:
        journal = Journal.open(folder / JOURNAL_NAME, write_hook=write_hook, readonly=readonly)
        cfg = parse_config(journal.meta()["config"], f"{folder / JOURNAL_NAME} (config snapshot)")
    except BaseException:
        if lock is not None:
            lock.release()
        raise
    return Campaign(folder, journal, cfg, lock)


def _first_difference(a, b, path: str = "") -> str | None:
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            d = _first_difference(a.get(k), b.get(k), f"{path}.{k}" if path else str(k))
            if d is not None:
                return d
        return None
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            d = _first_difference(x, y, f"{path}[{i}]")
            if d is not None:
                return d
        return None
    return None if a == b else f"{path}: {json.dumps(a)} in the campaign, {json.dumps(b)} now"


def compare_campaign(meta: dict, *, material: str | None, grid: str, seed: int, cfg: GonioConfig,
                     sample: str | None = None) -> str | None:
    """Which field of a new request differs from the campaign in ``meta`` (all normalized), or None.

    ``material`` is the normalized spec (compared with the journal's after normalizing it too, so that
    ``albedo=0.50`` and ``albedo=0.5`` are one campaign).
    """
    from gonio.config import parse_config

    if material is not None:
        from gonio.sim.materials import load

        theirs = load(meta["material"]).spec if meta.get("material") else None
        if theirs != material:
            return f"material: '{theirs}' in the campaign, '{material}' now"
    if sample is not None and meta.get("sample") != sample:
        return f"sample: '{meta.get('sample')}' in the campaign, '{sample}' now"
    requested = parse_grid(grid).normalized
    if meta["grid_requested"] != requested:
        return f"grid: '{meta['grid_requested']}' in the campaign, '{requested}' now"
    if int(meta["seed"]) != int(seed):
        return f"seed: {meta['seed']} in the campaign, {seed} now"
    planned = parse_config(meta["config"], "config snapshot")
    diff = _first_difference(planned.model_dump(mode="json"), cfg.model_dump(mode="json"))
    if diff is not None:
        return f"config: {diff}"
    return None


def finish_campaign(c: Campaign) -> Path:
    """Calibrate every measured pose and write ``brdf.h5`` (format version 2: measured and planned
    angles, grid indices, steps, exposures, campaign times; see :mod:`gonio.dataset`)."""
    from gonio.calibrate import calibrate, reference_rho
    from gonio.dataset import BRDF_NAME, CONE_DETECTORS, campaign_dataset, write_brdf

    meta = c.meta
    # The values come from the journal's rows; a frame file lost or altered since is recorded, not hidden.
    for step, problem in c.journal.check_frames():
        c.journal.log_event("fault", step=step, message=f"frame: {problem}")
    measurements = c.journal.measurements(extra=False)   # calibration reads the readings alone
    rho, per_channel = reference_rho(c.cfg.reference, c.journal.detector())
    cal = calibrate(measurements, rho)
    exposure = {m.step: m.exposure_s for m in measurements}
    # the cones a simulated reading averages over (gonio.sim.aperture; a camera's pixels see others)
    sim = c.cfg.detector.sim
    cones = (c.cfg.light.sim.half_angle_deg, sim.half_angle_deg) \
        if meta.get("material") and sim.kind in CONE_DETECTORS else None
    data = campaign_dataset(cal, c.journal.steps(), meta, exposure_s=[exposure[int(s)] for s in cal.steps],
                            reference_albedo=c.cfg.reference.albedo, software_version=software_version(),
                            reference_reflectance=rho if per_channel else None, cones=cones)
    return write_brdf(c.folder / BRDF_NAME, data)


def gantry_state(c: Campaign) -> tuple[np.ndarray, float] | None:
    """Where the journal last saw the gantry: (axis positions in degrees, campaign_s), or None."""
    return c.journal.last_known_axes()


def journal_devices(journal, gantry: Gantry) -> None:
    """What every device says it is (:func:`gonio.gantry.describe_devices`: identity, firmware, units,
    settings), journaled at each run once connected: the meta key ``devices`` holds the latest, a
    ``devices`` event each run's (a servo or a meter swapped between two runs shows there). The
    instruments that speak through a profile (the light and the detector: its name, SHA-256 and the
    identity read at connect) are also under ``instruments``, with an ``instruments`` event."""
    from gonio.gantry import describe_devices

    described = describe_devices(gantry)
    if not described:
        return
    journal.set_meta("devices", described)
    journal.log_event("devices", message="; ".join(
        f"{name}: {d.get('driver')} {d.get('identity')!r}"
        + (f" firmware {d['firmware']}" if d.get("firmware") is not None else "")
        for name, d in described.items()))
    instruments = {name: d for name, d in described.items()
                   if name in (gantry.light.name, gantry.detector.name) and "profile" in d}
    if instruments:
        journal.set_meta("instruments", instruments)
        journal.log_event("instruments", message="; ".join(
            f"{name}: {d.get('profile')} {d.get('identity')!r}" for name, d in instruments.items()))
