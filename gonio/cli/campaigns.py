"""Campaign commands: ``plan``, ``config``, ``simulate``, ``run`` and ``status``.

Validation comes before anything is written; SIGINT and SIGTERM during a campaign finish the step in
flight, park, journal the interruption and say how to resume (exit code 130); a second one halts.
"""

from __future__ import annotations

import json
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np

from gonio.cli.common import (
    Eta,
    UsageError,
    creatable_folder,
    grid_arg,
    planning,
    refuse_emulated_placeholders,
)
from gonio.cli.common import Out as _Out
from gonio.cli.common import hms as _hms
from gonio.cli.common import in_main_thread as _in_main_thread
from gonio.cli.common import install_startup_handlers as _install_startup_handlers
from gonio.cli.common import not_empty as _not_empty
from gonio.cli.results import export_formats as _export_formats
from gonio.cli.results import write_exports as _write_exports

#: Seconds between progress lines when stderr is not a terminal (logs, CI, a daemon's journal).
PLAIN_PROGRESS_EVERY_S = 5.0


# -- gonio plan -----------------------------------------------------------------------------------
def cmd_plan(args) -> int:
    from gonio.config import load_config
    from gonio.plan import build_plan, format_plan, plan_summary
    from gonio.plan.grids import grid_kind

    grid = grid_arg(args.grid)
    cfg = load_config(args.config)
    show = sys.stdout.isatty() and not args.json    # a spinner only where a person watches the report
    if grid_kind(grid.kind).campaign == "adaptive":
        return _plan_adaptive(args, cfg, show)
    with planning(_Out(), args.grid, show):
        try:
            plan = build_plan(args.grid, cfg)
        except ValueError as err:   # what the planner refuses is the grid, as a campaign's creation says
            raise UsageError(f"--grid: {err}") from None
        fly = None
        if not plan.grid.startswith("merl:"):  # lattices have lines to sweep: fly side by side
            from gonio.plan.fly import fly_plan

            # A fly campaign sweeps the serpentine's lines (order=fly), whatever order auto chose here.
            lines = plan if plan.order == "serpentine" else build_plan(
                grid.spelled(order="fly"), cfg)
            fly = fly_plan(lines, cfg)
    if args.json:
        print(json.dumps(plan_summary(plan, fly), indent=2))
    else:
        print(format_plan(plan, fly))
    return 0


def _plan_adaptive(args, cfg, show: bool) -> int:
    """``gonio plan`` of an adaptive grid: its pilot's plan (the rounds are placed as it measures) and
    the budget the rounds spend."""
    from gonio.adaptive.plan import budget_text, pilot_text
    from gonio.campaign import plan_campaign
    from gonio.plan import format_plan, plan_summary

    with planning(_Out(), args.grid, show):
        try:
            planned = plan_campaign(args.grid, cfg)
        except ValueError as err:   # what the planner refuses is the grid, as a campaign's creation says
            raise UsageError(f"--grid: {err}") from None
    a = planned.meta["adaptive"]
    if args.json:
        print(json.dumps({"adaptive": a, "pilot": plan_summary(planned.plan)}, indent=2))
        return 0
    print(format_plan(planned.plan))
    print(f"\nadaptive     pilot: {a['pilot_poses']:,} poses ({pilot_text(a)}), estimated "
          f"{_hms(a['pilot_s'])} ({a['pilot_s']:.1f} s) of gantry time\n"
          f"             budget: {budget_text(a)}, pilot included; then rounds of poses placed where the "
          f"samples so far are least trustworthy, each {100 * a['growth']:.0f} % of the samples so far (at "
          f"least {a['min_round']}), planned from the journal as it measures")
    return 0


def _request_error(err, flags: dict[str, str]) -> UsageError:
    """A :class:`gonio.lifecycle.RequestError` as one line naming the command's flag for its field."""
    return UsageError(f"{flags.get(err.field, err.field)}: {err}")


# -- gonio materials -------------------------------------------------------------------------------
def cmd_materials(args) -> int:
    from gonio.sim.materials import MODELS
    from gonio.sim.materials.catalog import catalog, format_catalog

    if args.name is not None and args.name.strip().lower() not in MODELS:
        raise UsageError(f"NAME: {args.name!r} is not a material model; allowed: "
                         f"{', '.join(MODELS)}")
    entries = catalog()
    if args.name is not None:
        entries = [e for e in entries if e.model == args.name.strip().lower()]
    print(format_catalog(entries), end="")
    return 0


# -- gonio config ---------------------------------------------------------------------------------
def cmd_config(args) -> int:
    from gonio.config import load_config, packaged_configs, resolve_config

    if args.action == "list":
        shipped = packaged_configs()
        width = max(map(len, shipped), default=0) + 2
        print(f"{'NAME':<{width}}{'DESIGN':<14}GANTRY")
        for name, path in shipped.items():
            cfg = load_config(path)
            print(f"{name:<{width}}{cfg.kinematics.design:<14}{cfg.name}")
        return 0
    if not args.name:
        raise UsageError("show: give NAME, a shipped config (one of: "
                         f"{', '.join(packaged_configs())}) or a path")
    path = resolve_config(args.name)
    load_config(path)  # validated before it is shown
    print(path.read_text(), end="")
    return 0


# -- gonio simulate -------------------------------------------------------------------------------
def _model_check(folder: Path, material) -> str:
    """Simulation only: how far the calibrated samples are from the material they simulate."""
    from gonio.dataset import read_brdf
    from gonio.geometry import sph_to_vec

    b = read_brdf(folder / "brdf.h5")
    wi = sph_to_vec(np.radians(b.theta_i), np.radians(b.phi_i))
    wo = sph_to_vec(np.radians(b.theta_o), np.radians(b.phi_o))
    wavelengths = b.attrs.get("wavelengths_nm")
    if wavelengths is not None and len(wavelengths) == b.value.shape[1]:  # a spectrometer's bands
        from gonio.sim.detector_spectral import spectral_material

        truth = spectral_material(material).eval(wi, wo, np.asarray(wavelengths, float))
    else:
        truth = material.eval(wi, wo)
    ok = truth > 1e-3 * truth.max()
    rel = np.abs(b.value[ok] - truth[ok]) / truth[ok]
    return (f"{len(b.value)} samples; against the simulated material's own eval: median relative error "
            f"{100 * np.median(rel):.2f} %, 95th percentile {100 * np.percentile(rel, 95):.2f} %")


def _created(create, folder: Path, *args, **kw):
    """``create(folder, ...)``, with an OSError that ``_check_out`` could not foresee (root on a read-only
    mount, a full disk) as one line naming --out; nothing is left (creation is atomic)."""
    try:
        return create(folder, *args, **kw)
    except OSError as err:
        raise UsageError(f"--out: {folder} cannot be written ({err.strerror or err}); choose another "
                         "folder") from None


def _check_out(text: str) -> Path:
    """--out must be a folder we can write, or a path where one can be made; checked before writing.
    Empty is refused (it would be the current folder)."""
    out = Path(_not_empty(text, "folder"))
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out: {out} is a file, not a folder; give a folder for the campaign")
    from gonio.dataset import BRDF_NAME
    from gonio.store import JOURNAL_NAME

    if (out / BRDF_NAME).exists() and not (out / JOURNAL_NAME).exists():
        # a new campaign there would replace that file when it ends
        raise UsageError(f"--out: {out} holds a {BRDF_NAME} of no campaign (no {JOURNAL_NAME} beside it); "
                         "choose another folder, or move the file away")
    return creatable_folder(out)


def _progress(out: _Out, total: int, done0: int, gantry, quiet: bool):
    """A live rich progress bar on a terminal, a plain line every few seconds otherwise."""
    t0 = time.perf_counter()
    if quiet:
        return None, (lambda runner, step: None)
    if out.is_terminal:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        progress = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                            TextColumn("gantry {task.fields[sim]}"), TextColumn("wall"), TimeElapsedColumn(),
                            TextColumn("ETA {task.fields[eta]}"), console=out.console, transient=False)
        task = progress.add_task("measuring", total=total, completed=done0, sim="0:00:00", eta="?")
        eta = Eta(total)

        def on_step(runner, step):
            now = time.perf_counter() - t0
            progress.update(task, completed=step + 1, sim=_hms(runner.campaign_s()),
                            eta=Eta.text(eta.update(step + 1, now)))

        return progress, on_step
    last = [-PLAIN_PROGRESS_EVERY_S]
    eta = Eta(total)

    def on_step(runner, step):
        now = time.perf_counter() - t0
        left = eta.update(step + 1, now)
        if now - last[0] < PLAIN_PROGRESS_EVERY_S and step + 1 < total:
            return
        last[0] = now
        out(f"measuring: {step + 1}/{total} steps ({100 * (step + 1) / total:.0f} %), gantry "
            f"{_hms(runner.campaign_s())}, wall {now:.1f} s, ETA {Eta.text(left)}")

    return None, on_step


def cmd_simulate(args) -> int:
    from gonio.jit import using_backend

    # cuda without a device is refused here, in one line, before anything is written
    with using_backend(args.backend):
        return _simulate(args)


def _simulate(args) -> int:
    from gonio.config import load_config
    from gonio.lifecycle import Request, RequestError, check_request

    # Everything the user typed is validated before anything is written.
    grid_arg(args.grid)
    request = Request(args.grid, material=args.material, seed=args.seed)
    exports = _export_formats(args.export)
    cfg = load_config(args.config)
    if args.detector is not None:
        from gonio.config import with_sim_detector

        cfg = with_sim_detector(cfg, args.detector)
    if cfg.detector.driver != "sim":   # the request's own line speaks of a 'sample' simulate does not take
        raise UsageError(f"--config: gantry '{cfg.name}' has a real detector, which renders no MATERIAL; "
                         "a sample is measured on it with `gonio run ... --sample NAME` (docs/measure.md)")
    try:
        material = check_request(cfg, request)
    except RequestError as err:
        raise _request_error(err, _SIMULATE_FLAGS) from None
    return _campaign_command(args, cfg, request, material=material, model_check=True, exports=exports,
                             flags=_SIMULATE_FLAGS)


#: The flag of each request field, per command (:func:`_request_error`).
_SIMULATE_FLAGS = {"material": "MATERIAL", "grid": "--grid", "gantry": "--config"}
_RUN_FLAGS = {"material": "--material", "sample": "--sample", "grid": "--grid", "gantry": "--config"}


def _campaign_command(args, cfg, request, *, material, model_check: bool, exports=(), flags=_RUN_FLAGS,
                      relocate_buses: bool = False, planned=None, gantry=None) -> int:
    """Create or resume the campaign of ``request`` in ``args.out`` and run it on the gantry ``cfg``
    wires (``gonio simulate`` and ``gonio run``) through the campaign lifecycle (:mod:`gonio.lifecycle`):
    progress, signals, latched faults, ``--clear-fault``, brdf.h5. ``planned``: the new campaign's plans
    when the caller made them already (``gonio run`` checks a fly campaign's gantry before connecting).

    ``relocate_buses``: a resumed campaign's devices are reached where ``cfg``'s buses say now (a
    re-plugged adapter, a restarted emulator); every other setting must match the campaign's.
    ``gantry``: a new campaign's gantry, already connected (:func:`_connected_gantry`)."""
    from gonio.dataset import BRDF_NAME
    from gonio.lifecycle import (
        CampaignMismatch,
        RequestError,
        campaign_gantry,
        is_complete,
        open_or_create,
        plan_request,
        run_campaign,
    )
    from gonio.protocols import DeviceFault
    from gonio.runner import State
    from gonio.store import JOURNAL_NAME

    out = _Out(args.quiet)
    folder = _check_out(args.out)
    spec = material.spec if material is not None else None

    def plan():
        if planned is not None:
            return planned
        with planning(out, args.grid, not args.quiet):
            try:
                return plan_request(cfg, request, material)
            except RequestError as err:
                raise _request_error(err, flags) from None

    try:
        c, created = _created(open_or_create, folder, cfg, request, spec=spec, plan=plan,
                              relocate_buses=relocate_buses)
    except CampaignMismatch as err:
        if gantry is not None:
            gantry.close()
        raise UsageError(f"--out: {folder} holds another campaign ({err.difference}); repeat the original "
                         "command to resume it, or choose another --out") from None
    except BaseException:
        if gantry is not None:
            gantry.close()
        raise
    if not created:
        if is_complete(c):
            out(f"the campaign in {folder} is complete: {folder / BRDF_NAME}")
            c.close()
            _write_exports(folder, exports, out)
            return 0
        out(f"resuming the campaign in {folder} at step {c.journal.next_step()}")
    meta = c.meta
    n_steps = c.journal.step_count()
    try:
        if gantry is None:
            gantry = campaign_gantry(c, material, buses_from=cfg if relocate_buses else None)
    except BaseException:
        c.close()
        raise
    sweeps = f" in {meta['fly']['lines']} sweeps" if c.kind == "fly" else ""
    if c.kind == "adaptive":
        from gonio.adaptive.plan import budget_text, expected_steps

        a = meta["adaptive"]
        out(f"{meta['gantry']}: {meta['grid']}: a pilot of {a['pilot_poses']} poses (estimated "
            f"{_hms(a['pilot_s'])} of gantry time), then rounds placed from what is measured until "
            f"{budget_text(a)} are spent; {meta['poses']} poses planned so far")
        n_steps = expected_steps(meta, n_steps)
    else:
        out(f"{meta['gantry']}: {meta['poses']} poses of {meta['grid']}{sweeps} ({n_steps} steps with dark "
            f"and white-reference readings), estimated {_hms(meta['estimated_s'])} of gantry time (lower "
            f"bound {_hms(meta['lower_bound_s'])})")
    t0 = time.perf_counter()
    progress, on_step = _progress(out, n_steps, c.journal.next_step(), gantry, args.quiet)
    signals: list[str] = []
    actors: list[threading.Thread] = []   # the threads acting on signals (joined before the journal closes)

    def on_runner(runner):
        def act(name: str, first: bool) -> None:
            if first:
                runner.journal.log_event("signal", message=f"{name} received", campaign_s=runner.campaign_s())
                runner.request_pause(f"{name}: finishing the step in flight, then parking")
            else:
                runner.request_halt(f"{name} again: halt")

        def handler(signum, frame):
            # The handler interrupts the main thread anywhere, also inside a journal transaction or a
            # device command (their locks are re-entrant): acting from here would nest a transaction in
            # it. Another thread acts as soon as those locks are free, as any other thread's request does.
            name = signal.Signals(signum).name
            signals.append(name)
            t = threading.Thread(target=act, args=(name, len(signals) == 1), name=f"gonio-{name}",
                                 daemon=True)
            actors.append(t)
            t.start()

        if _in_main_thread():
            signal.signal(signal.SIGINT, handler)
            signal.signal(signal.SIGTERM, handler)

    try:
        if progress is not None:
            with progress:
                state, runner = run_campaign(c, gantry, on_step=on_step, on_runner=on_runner,
                                             clear_fault=args.clear_fault)
        else:
            state, runner = run_campaign(c, gantry, on_step=on_step, on_runner=on_runner,
                                         clear_fault=args.clear_fault)
    except DeviceFault as err:  # the gantry could not be connected (or a fault could not be cleared)
        out(f"gantry: {err}", style="red")
        out("nothing was measured this time; every committed step is kept: fix it, then run the same command")
        return 1
    finally:
        _install_startup_handlers()
        for t in actors:
            t.join(timeout=30.0)
        c_done = c.journal.done_count()
        n_steps = c.journal.step_count() if c.kind == "adaptive" else n_steps   # its rounds were appended
        ended = c.journal.meta()["adaptive"].get("ended") if c.kind == "adaptive" else None
        c.close()
    wall = time.perf_counter() - t0
    out(f"campaign {state}: {c_done}/{n_steps} steps, gantry time {_hms(runner.campaign_s())}, "
        f"wall time {wall:.1f} s")
    if ended:
        out(f"ended short of its budget: {ended['reason']}", style="yellow")
    if state == State.DONE:
        out(f"wrote {folder / 'brdf.h5'} and {folder / JOURNAL_NAME}")
        if model_check:
            out(_model_check(folder, material))
        _write_exports(folder, exports, out)
        return 0
    if runner.fault:
        out(f"fault: {runner.fault}", style="red")
        out("the fault is latched: fix its cause, then run the same command with --clear-fault to resume")
        return 1
    if signals:
        out(f"interrupted ({signals[0]}): {state} at step {c_done}; every committed step is kept: run the "
            "same command to resume")
        return 130
    out(f"campaign {state}; the journal keeps every committed step: run the same command to resume")
    return 1


def campaign_status(folder: Path) -> dict:
    """A campaign's state, progress, ETA and last fault, read from its journal (read-only):
    :func:`gonio.lifecycle.status`, its state in words (who runs it; interrupted: how to resume)."""
    from gonio.lifecycle import status

    try:
        st = status(folder)
    except FileNotFoundError as err:
        raise UsageError(str(err)) from None
    pid = st.pop("pid")
    if st["state"] in ("running", "pausing"):
        st["state"] = f"{st['state']} (pid {pid})"
    elif st["state"] == "interrupted":
        st["state"] = "interrupted (no process is running it: run the same command to resume)"
    return st


def cmd_status(args) -> int:
    import re

    from gonio.daemon.records import ID_PATTERN

    # A campaign id (or --url): ask the daemon, as `gonio queue ID` does; otherwise read the folder.
    if args.url is not None or (re.match(ID_PATTERN, args.dir) and not Path(args.dir).exists()):
        from gonio.daemon.commands import cmd_queue

        args.id = args.dir
        return cmd_queue(args)
    st = campaign_status(Path(args.dir))
    if args.json:
        print(json.dumps(st, indent=2))
        return 0
    what = st["material"] or st["sample"]
    pct = 100.0 * st["steps_done"] / st["steps"] if st["steps"] else 100.0
    lines = [
        f"{st['folder']}: {st['state']}",
        f"  {what} on {st['gantry']}, grid {st['grid']}, seed {st['seed']}",
        f"  progress: {st['steps_done']}/{st['steps']} steps ({pct:.1f} %), campaign time "
        f"{_hms(st['campaign_s'])}",
    ]
    if st["steps_done"] < st["steps"] and not st["state"].startswith("aborted"):
        lines.append(f"  ETA: about {_hms(st['estimated_remaining_s'])} of gantry time left (the plan's "
                     "estimate)")
    if st["ended_short"]:
        lines.append(f"  ended short of its budget: {st['ended_short']}")
    if st["latched_fault"]:
        lines.append(f"  latched fault: {st['latched_fault']} (resume with --clear-fault once fixed)")
    elif st["last_fault"]:
        lines.append(f"  last fault: {st['last_fault']}")
    print("\n".join(lines))
    return 0


# -- gonio run, gonio emulate, gonio gantry (configured hardware) -----------------------------------
def _connected_gantry(cfg, material, seed: int):
    """A new campaign's gantry, connected before anything is planned or written: a port that cannot be
    opened is one line (exit 1) and leaves no half-made campaign behind."""
    from gonio.protocols import DeviceFault
    from gonio.wiring import build_gantry

    gantry = build_gantry(cfg, material, seed=seed)
    try:
        gantry.connect()
    except DeviceFault as err:
        raise GantryUnreachable(f"gantry: {err}; nothing was written: connect it (or start its "
                                "emulators), then run the same command") from None
    return gantry


class GantryUnreachable(RuntimeError):
    """The devices of a new campaign could not be connected (exit code 1)."""


def cmd_run(args) -> int:
    from gonio.config import load_config
    from gonio.lifecycle import Request, RequestError, check_request, plan_request
    from gonio.store import JOURNAL_NAME

    fly = grid_arg(args.grid).order == "fly"
    cfg = load_config(args.config)
    refuse_emulated_placeholders(cfg, args.config)
    if not args.sample.strip():
        raise UsageError("--sample: give the name of the sample measured (not empty)")
    request = Request(args.grid, material=args.material, sample=args.sample, seed=args.seed)
    try:
        material = check_request(cfg, request)
    except RequestError as err:
        raise _request_error(err, _RUN_FLAGS) from None
    folder = _check_out(args.out)
    planned = None
    if fly and not (folder / JOURNAL_NAME).exists():
        # order=fly: what sweeps is known once the lines are planned; a gantry that cannot fly them is
        # refused before anything is connected or written.
        with planning(_Out(args.quiet), args.grid, not args.quiet):
            try:
                planned = plan_request(cfg, request, material)
            except RequestError as err:
                raise _request_error(err, _RUN_FLAGS) from None
    _check_referenced(cfg, material)
    gantry = None
    if not (folder / JOURNAL_NAME).exists():
        try:
            gantry = _connected_gantry(cfg, material, args.seed)
        except GantryUnreachable as err:
            _Out()(str(err), style="red")
            return 1
    return _campaign_command(args, cfg, request, material=material, model_check=False,
                             relocate_buses=True, planned=planned, gantry=gantry)


def _check_referenced(cfg, material) -> None:
    """Refuse (one line, exit 2, nothing written) while an axis is not referenced: the axes looked at
    read-only before the campaign folder is touched. A gantry that cannot be reached now is left to the
    run itself to report."""
    if cfg.drivers() == {"sim"}:
        return
    from gonio import manual
    from gonio.protocols import DeviceFault
    from gonio.reference import refusal, unreferenced
    from gonio.wiring import build_gantry

    gantry = build_gantry(cfg, material)
    try:
        axes = manual.connect_axes(gantry, keep_faulted=True, readonly=True)
    except DeviceFault:
        return
    missing = unreferenced(axes)
    manual.close_axes(axes)
    if missing:
        raise UsageError(refusal(missing))
