"""The campaign lifecycle: one way to check a request, open or create, compare, resume, run, finish and
look at a campaign, for the CLI (``gonio simulate``, ``gonio run``), the daemon and scripts alike (the
benchmarks in ``tools/``, ``examples/``; batch runs are to build on it).

Free of CLI and daemon concerns (no flags, no HTTP, no signals): errors are :class:`RequestError`
(naming the request's field) and :class:`CampaignMismatch` (naming the field that differs from the
campaign in the folder); callers say them in their own words. Everything runs in the caller's process.

::

    request ─► check_request ─► plan_request ─► open_or_create ─► run_campaign ─► (done) finish ─► brdf.h5
                (material vs     (the plan and   (compare: the     (the engine, its units
                 sample)          its kind; can   field that        chosen by the campaign's
                                  the gantry      differs)          kind; devices and references
                                  fly it?)                          journaled first)

Request rules, here only: a simulated detector renders a MATERIAL (which the caller's ``load`` reads: the
daemon's refuses paths, ``merl:NAME`` only from its materials folder), a real detector measures a named
sample and takes no material; a spectrometer needs a spectral material; an ``order=fly`` grid needs a
gantry that can fly it (:func:`gonio.fly.units.check_fly_gantry`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from gonio.campaign import (
    Campaign,
    CampaignLock,
    Planned,
    compare_campaign,
    create_campaign,
    finish_campaign,
    gantry_state,
    journal_devices,
    kind_of,
    open_campaign,
    plan_campaign,
)
from gonio.dataset import BRDF_NAME
from gonio.protocols import Gantry, NotReferencedFault
from gonio.runner import Runner, State
from gonio.store import JOURNAL_NAME, Journal
from gonio.units import ADAPTIVE, FLY, unit_source

if TYPE_CHECKING:  # type hints only: the caller holds the config
    from gonio.config import GonioConfig

__all__ = ["Request", "RequestError", "CampaignMismatch", "check_request", "plan_request", "open_or_create",
           "campaign_gantry", "is_complete", "run_campaign", "status"]


class RequestError(ValueError):
    """A request the gantry cannot take: ``field`` names what is wrong (``material``, ``sample``,
    ``grid``, or ``gantry``: the gantry cannot do what the grid asks)."""

    def __init__(self, field: str, message: str):
        super().__init__(message)
        self.field = field


class CampaignMismatch(ValueError):
    """The folder holds another campaign: ``difference`` names the field that differs."""

    def __init__(self, folder: Path, difference: str):
        super().__init__(f"{folder} holds another campaign ({difference})")
        self.folder = folder
        self.difference = difference


@dataclass(frozen=True)
class Request:
    """What a campaign is asked to be: a GRID, the MATERIAL a simulated detector renders or the name of
    the sample a real one measures, and the seed of simulated devices."""

    grid: str
    material: str | None = None
    sample: str | None = None
    seed: int = 0


def check_request(cfg: GonioConfig, request: Request, load: Callable | None = None):
    """The request rules that depend on the detector (see the module docstring); the material, loaded
    with ``load`` (default :func:`gonio.sim.materials.load`), or None for a real detector.

    Raises
    ------
    RequestError
        ``material`` or ``sample``.
    """
    if cfg.detector.driver != "sim":
        if request.material:
            raise RequestError("material", f"gantry '{cfg.name}' has a real detector: name the sample "
                               "('sample'), not a material")
        if not request.sample:
            raise RequestError("sample", f"required on gantry '{cfg.name}' (a real detector): the name of "
                               "the sample measured")
        return None
    if not request.material:
        raise RequestError("material", f"required: the detector of gantry '{cfg.name}' is simulated and "
                           "renders a MATERIAL, e.g. 'lambert:albedo=0.5'")
    if load is None:
        from gonio.sim.materials import load
    try:
        material = load(request.material)
        if cfg.detector.sim.kind == "spectrometer":
            from gonio.sim.detector_spectral import spectral_material

            spectral_material(material)  # a material with no spectrum is refused before anything is written
    except (ValueError, KeyError) as err:
        raise RequestError("material", str(err)) from None
    return material


def plan_request(cfg: GonioConfig, request: Request, material=None, *, plan=None) -> Planned:
    """Plan ``request`` on the gantry ``cfg`` with ``plan`` (default :func:`gonio.campaign.plan_campaign`;
    the daemon's planner passes one that keeps what it planned); a fly campaign only once the gantry's
    devices declare they can fly it (checked on the gantry wired from ``cfg``, not connected: nothing is
    opened). ``material``: what :func:`check_request` gave.

    Raises
    ------
    RequestError
        ``grid`` (the planner refuses it) or ``gantry`` (the gantry cannot fly it).
    """
    try:
        planned = (plan or plan_campaign)(request.grid, cfg)
    except ValueError as err:
        raise RequestError("grid", str(err)) from None
    if planned.kind == FLY:
        from gonio.fly.units import check_fly_gantry
        from gonio.wiring import build_gantry

        try:
            check_fly_gantry(build_gantry(cfg, material, seed=request.seed), cfg, planned.fly)
        except ValueError as err:
            raise RequestError("gantry", str(err)) from None
    return planned


def open_or_create(folder: str | Path, cfg: GonioConfig, request: Request, *, spec: str | None = None,
                   plan: Callable[[], Planned] | None = None, relocate_buses: bool = False,
                   write_hook=None) -> tuple[Campaign, bool]:
    """The campaign of ``request`` in ``folder``: reopened (to resume) when the folder holds it, else
    planned (``plan()``, default :func:`plan_request`) and created. Returns (campaign, created).

    ``spec``: the material's normalized spec (compared, and journaled). ``relocate_buses``: a reopened
    campaign is compared with ``cfg`` as if its buses were where the campaign's are (``gonio run``: a
    re-plugged adapter, a restarted emulator; :func:`campaign_gantry` reaches them where ``cfg`` says).

    Raises
    ------
    CampaignMismatch
        The folder holds another campaign (nothing is changed in it).
    """
    from gonio.config import relocate

    folder = Path(folder)
    if (folder / JOURNAL_NAME).exists():
        c = open_campaign(folder, write_hook=write_hook)
        now = relocate(cfg, c.cfg) if relocate_buses else cfg
        diff = compare_campaign(c.meta, material=spec, grid=request.grid, seed=request.seed, cfg=now,
                                sample=request.sample)
        if diff is not None:
            c.close()
            raise CampaignMismatch(folder, diff)
        return c, False
    planned = plan() if plan is not None else plan_request(cfg, request)
    return create_campaign(folder, cfg, grid=request.grid, material=spec, seed=request.seed,
                           sample=request.sample, planned=planned, write_hook=write_hook), True


def campaign_gantry(c: Campaign, material=None, *, buses_from: GonioConfig | None = None,
                    clock=None) -> Gantry:
    """The gantry ``c`` runs on (not connected): wired from its config snapshot, its buses where
    ``buses_from`` says they are now (default: where they were); simulated devices render ``material``
    with the campaign's seed, from where the journal last saw the axes and at its campaign time
    (:func:`gonio.campaign.gantry_state`). ``clock``: as :func:`gonio.wiring.build_gantry`'s."""
    from gonio.config import relocate
    from gonio.wiring import build_gantry

    cfg = relocate(c.cfg, buses_from) if buses_from is not None else c.cfg
    return build_gantry(cfg, material, seed=int(c.meta["seed"]), state=gantry_state(c), clock=clock)


def is_complete(c: Campaign) -> bool:
    """Every step measured and ``brdf.h5`` written."""
    return c.journal.next_step() == c.journal.step_count() and (c.folder / BRDF_NAME).exists()


def _check_references(c: Campaign, gantry: Gantry) -> None:
    """Journal each axis's reference; refuse (a fault event, not latched: nothing moved) to run while an
    axis is not referenced (:mod:`gonio.reference`)."""
    from gonio.reference import journal_references, refusal, unreferenced

    axes = gantry.all_axes
    campaign_s = c.journal.campaign_clock()[0]
    journal_references(c.journal, axes, campaign_s)
    missing = unreferenced(axes)
    if missing:
        c.journal.log_event("fault", message=f"not started: {refusal(missing)}", campaign_s=campaign_s)
        raise NotReferencedFault(missing[0], refusal(missing))


def run_campaign(c: Campaign, gantry: Gantry,
                 on_step: Callable[[Runner, int], None] | None = None,
                 on_runner: Callable[[Runner], None] | None = None,
                 clear_fault: bool = False) -> tuple[State, Runner]:
    """Run (or resume) ``c`` on ``gantry`` with the engine, its units from the source of the campaign's
    kind (:mod:`gonio.units`; a ValueError before anything moves when the gantry cannot run them, e.g.
    fly sweeps on axes that do not fly); writes ``brdf.h5`` when the campaign is done.

    The gantry is connected here (and closed after), what its devices say they are journaled, every
    axis's reference checked (NotReferencedFault, nothing moved, when one is not referenced).
    ``on_runner(runner)`` is called once the engine exists and before it starts (signal handlers, the
    daemon: requests made then act when it starts). ``clear_fault`` is the operator's explicit clearing
    of a latched fault.
    """
    runner = Runner(gantry, c.journal, c.cfg, on_step=on_step)
    # A fly campaign created in this process runs the fly plan it was made from; a reopened one's is
    # rebuilt from its journal and checked against its steps.
    units = unit_source(c.kind)(runner) if c.fly is None else unit_source(c.kind)(runner, c.fly)
    if on_runner is not None:
        on_runner(runner)
    gantry.connect()
    try:
        journal_devices(c.journal, gantry)
        _check_references(c, gantry)
        if clear_fault and runner.state == State.FAULTED:
            runner.clear_fault()
        state = runner.run(units)
    finally:
        gantry.close()
    if state == State.DONE:
        finish_campaign(c)
    return state, runner


def status(folder: str | Path) -> dict:
    """A campaign's state, progress, ETA and last fault, read from its journal (read-only, safe while it
    runs). ``state`` is the journal's last; ``running`` or ``pausing`` with nobody holding the folder's
    lock is ``interrupted`` (no process runs it: running it again resumes); ``pid`` the holder's.
    ``ended_short``: why an adaptive campaign ended short of its budget (a round found no reachable new
    pose, :func:`gonio.adaptive.plan.ended_text`), else None.

    Raises
    ------
    FileNotFoundError
        No folder, or no journal in it.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: " + ("a file, not a campaign folder" if folder.exists()
                                                 else "no such folder"))
    if not (folder / JOURNAL_NAME).is_file():
        raise FileNotFoundError(f"{folder}: not a campaign folder (no {JOURNAL_NAME})")
    j = Journal.open(folder / JOURNAL_NAME, readonly=True)
    try:
        meta = j.meta()
        total = j.step_count()
        done = j.done_count()
        state_event = j.last_event("state")
        latched = j.latched_fault()
        fault_event = j.last_event("fault")
        campaign_s, last_wall = j.campaign_clock()
    finally:
        j.close()
    ended = None
    if kind_of(meta) == ADAPTIVE:   # its rounds are appended as it measures: the steps it will hold
        from gonio.adaptive.plan import ended_text, expected_steps

        total = expected_steps(meta, total)
        ended = ended_text(meta["adaptive"])
    pid = CampaignLock.holder(folder)
    state = state_event["state"] if state_event else "created"
    interrupted = pid is None and state in ("running", "pausing")
    remaining = meta["estimated_s"] * (total - done) / total if total else 0.0
    return {
        "folder": str(folder), "state": "interrupted" if interrupted else state, "pid": pid,
        "kind": kind_of(meta), "steps_done": done, "steps": total, "poses": meta["poses"],
        "grid": meta["grid"], "material": meta.get("material"), "sample": meta.get("sample"),
        "gantry": meta["gantry"], "seed": meta["seed"], "campaign_s": campaign_s,
        "estimated_remaining_s": remaining, "last_update_unix": last_wall,
        "latched_fault": latched["reason"] if latched else None,
        "last_fault": fault_event["message"] if fault_event else None,
        "ended_short": ended,
    }
