"""The ``gonio`` command line.

``gonio plan`` counts and times a plan without moving anything; ``gonio simulate`` runs a whole
campaign on the simulated gantry (resuming one left in the output folder); ``gonio status`` reads a
campaign's journal (read-only, safe while it runs); ``gonio config`` lists and prints the shipped
gantry configs.

A user's mistake (a bad GRID, MATERIAL, config key, path or seed) is one line on stderr naming the field
or path and what is allowed, exit code 2, and nothing written. SIGINT and SIGTERM during a campaign
finish the step in flight, park, journal the interruption and say how to resume (exit code 130); a
second one halts at once. ``--debug`` shows the traceback of an unexpected error.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np

from gonio.config import ConfigError, load_config

__all__ = ["main", "build_parser"]

#: Seconds between progress lines when stderr is not a terminal (logs, CI, a daemon's journal).
PLAIN_PROGRESS_EVERY_S = 5.0


class UsageError(ValueError):
    """A mistake in the command line: printed as one line, exit code 2."""


class Interrupted(BaseException):
    """SIGINT or SIGTERM before a campaign runs (start-up, planning, creating the journal)."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _hms(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


def _seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0, got {value}")
    return value


class _Out:
    """Messages to stderr: rich styles on a terminal, never rich markup (paths may hold ``[...]``)."""

    def __init__(self, quiet: bool = False):
        from rich.console import Console

        self.console = Console(stderr=True, soft_wrap=True, highlight=False)
        self.quiet = quiet

    def __call__(self, message: str, style: str | None = None) -> None:
        self.console.print(message, style=style, markup=False)


# -- gonio plan -----------------------------------------------------------------------------------
def cmd_plan(args) -> int:
    from gonio.plan import build_plan, format_plan, plan_summary

    cfg = load_config(args.config)
    plan = build_plan(args.grid, cfg)
    if args.json:
        print(json.dumps(plan_summary(plan), indent=2))
    else:
        print(format_plan(plan))
    return 0


# -- gonio config ---------------------------------------------------------------------------------
def cmd_config(args) -> int:
    from gonio.config import packaged_configs, resolve_config

    if args.action == "list":
        shipped = packaged_configs()
        width = max(map(len, shipped), default=0) + 2
        print(f"{'NAME':<{width}}{'DESIGN':<14}GANTRY")
        for name, path in shipped.items():
            cfg = load_config(path)
            print(f"{name:<{width}}{cfg.kinematics.design:<14}{cfg.name}")
        return 0
    if not args.name:
        raise UsageError("gonio config show: give NAME (one of: "
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
    truth = material.eval(wi, wo)
    ok = truth > 1e-3 * truth.max()
    rel = np.abs(b.value[ok] - truth[ok]) / truth[ok]
    return (f"{len(b.value)} samples; against the simulated material's own eval: median relative error "
            f"{100 * np.median(rel):.2f} %, 95th percentile {100 * np.percentile(rel, 95):.2f} %")


def _check_out(out: Path) -> None:
    """--out must be a folder we can write, or a path where one can be made; checked before writing."""
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out: {out} is a file, not a folder; give a folder for the campaign")
    probe = out
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise UsageError(f"--out: {probe} is a file, so {out} cannot be a folder")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise UsageError(f"--out: {probe} is not writable (permission denied); choose another folder")


def _progress(out: _Out, total: int, done0: int, gantry, quiet: bool):
    """A live rich progress bar on a terminal, a plain line every few seconds otherwise."""
    t0 = time.perf_counter()
    if quiet:
        return None, (lambda runner, step: None)
    if out.console.is_terminal:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        progress = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                            TextColumn("gantry {task.fields[sim]}"), TextColumn("wall"), TimeElapsedColumn(),
                            TextColumn("ETA {task.fields[eta]}"), console=out.console, transient=False)
        task = progress.add_task("measuring", total=total, completed=done0, sim="0:00:00", eta="?")

        def on_step(runner, step):
            now = time.perf_counter() - t0
            done = step + 1 - done0
            eta = now / done * (total - step - 1) if done > 0 else 0.0
            progress.update(task, completed=step + 1, sim=_hms(runner.campaign_s()), eta=_hms(eta))

        return progress, on_step
    last = [-PLAIN_PROGRESS_EVERY_S]

    def on_step(runner, step):
        now = time.perf_counter() - t0
        if now - last[0] < PLAIN_PROGRESS_EVERY_S and step + 1 < total:
            return
        last[0] = now
        done = step + 1 - done0
        eta = now / done * (total - step - 1) if done > 0 else 0.0
        out(f"measuring: {step + 1}/{total} steps ({100 * (step + 1) / total:.0f} %), gantry "
            f"{_hms(runner.campaign_s())}, wall {now:.1f} s, ETA {_hms(eta)}")

    return None, on_step


def cmd_simulate(args) -> int:
    from gonio.plan import parse_grid
    from gonio.sim.materials import load as load_material

    # Everything the user typed is validated before anything is written.
    material = load_material(args.material)
    parse_grid(args.grid)
    exports = _export_formats(args.export)
    cfg = load_config(args.config)
    return _campaign_command(args, cfg, material=material, sample=None, model_check=True, exports=exports)


def _campaign_command(args, cfg, *, material, sample: str | None, model_check: bool, exports=(),
                      relocate_buses: bool = False) -> int:
    """Create or resume the campaign in ``args.out`` and run it on the gantry ``cfg`` wires (``gonio
    simulate`` and ``gonio run``): progress, signals, latched faults, ``--clear-fault``, brdf.h5.

    ``relocate_buses``: a resumed campaign's devices are reached where ``cfg``'s buses say now (a
    re-plugged adapter, a restarted emulator); every other setting must match the campaign's."""
    from gonio.campaign import compare_campaign, create_campaign, gantry_state, open_campaign, run_campaign
    from gonio.config import relocate
    from gonio.dataset import BRDF_NAME
    from gonio.protocols import DeviceFault
    from gonio.runner import State
    from gonio.store import JOURNAL_NAME
    from gonio.wiring import build_gantry

    out = _Out(args.quiet)
    folder = Path(args.out)
    spec = material.spec if material is not None else None
    _check_out(folder)
    if (folder / JOURNAL_NAME).exists():
        c = open_campaign(folder)
        now = relocate(cfg, c.cfg) if relocate_buses else cfg
        diff = compare_campaign(c.meta, material=spec, grid=args.grid, seed=args.seed, cfg=now, sample=sample)
        if diff is not None:
            c.close()
            raise UsageError(f"--out: {folder} holds another campaign ({diff}); repeat the original "
                             "command to resume it, or choose another --out")
        if c.journal.next_step() == c.journal.step_count() and (folder / BRDF_NAME).exists():
            out(f"the campaign in {folder} is complete: {folder / BRDF_NAME}")
            c.close()
            _write_exports(folder, exports, out)
            return 0
        out(f"resuming the campaign in {folder} at step {c.journal.next_step()}")
    else:
        c = create_campaign(folder, cfg, grid=args.grid, material=spec, seed=args.seed, sample=sample)
    meta = c.meta
    n_steps = c.journal.step_count()
    try:
        gantry = build_gantry(relocate(c.cfg, cfg) if relocate_buses else c.cfg, material, seed=meta["seed"],
                              state=gantry_state(c))
    except BaseException:
        c.close()
        raise
    out(f"{meta['gantry']}: {meta['poses']} poses of {meta['grid']} ({n_steps} steps with dark and "
        f"white-reference readings), estimated {_hms(meta['estimated_s'])} of gantry time (lower bound "
        f"{_hms(meta['lower_bound_s'])})")
    t0 = time.perf_counter()
    progress, on_step = _progress(out, n_steps, c.journal.next_step(), gantry, args.quiet)
    signals: list[str] = []

    def on_runner(runner):
        def handler(signum, frame):
            name = signal.Signals(signum).name
            signals.append(name)
            if len(signals) == 1:
                runner.request_pause(f"{name}: finishing the step in flight, then parking")
                runner.journal.log_event("signal", message=f"{name} received", campaign_s=runner.campaign_s())
            else:
                runner.request_halt(f"{name} again: halt")

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
        c_done = c.journal.done_count()
        c.close()
    wall = time.perf_counter() - t0
    out(f"campaign {state}: {c_done}/{n_steps} steps, gantry time {_hms(runner.campaign_s())}, "
        f"wall time {wall:.1f} s")
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


# -- gonio status ---------------------------------------------------------------------------------
def _lock_holder(folder: Path) -> int | None:
    """The pid holding the campaign's lock (running it now), or None."""
    import fcntl

    from gonio.campaign import LOCK_NAME

    path = folder / LOCK_NAME
    if not path.exists():
        return None
    fd = os.open(path, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        text = os.read(fd, 64).decode(errors="replace").strip()
        return int(text) if text.isdigit() else -1
    else:
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


def campaign_status(folder: Path) -> dict:
    """A campaign's state, progress, ETA and last fault, read from its journal (read-only)."""
    from gonio.store import JOURNAL_NAME, Journal

    if not folder.is_dir():
        raise UsageError(f"{folder}: no such folder")
    if not (folder / JOURNAL_NAME).is_file():
        raise UsageError(f"{folder}: not a campaign folder (no {JOURNAL_NAME})")
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
    pid = _lock_holder(folder)
    state = state_event["state"] if state_event else "created"
    if pid is not None and state in ("running", "pausing"):
        state = f"{state} (pid {pid})"
    elif state in ("running", "pausing"):
        state = "interrupted (no process is running it: run the same command to resume)"
    remaining = meta["estimated_s"] * (total - done) / total if total else 0.0
    return {
        "folder": str(folder), "state": state, "steps_done": done, "steps": total, "poses": meta["poses"],
        "grid": meta["grid"], "material": meta.get("material"), "sample": meta.get("sample"),
        "gantry": meta["gantry"], "seed": meta["seed"], "campaign_s": campaign_s,
        "estimated_remaining_s": remaining, "last_update_unix": last_wall,
        "latched_fault": latched["reason"] if latched else None,
        "last_fault": fault_event["message"] if fault_event else None,
    }


def cmd_status(args) -> int:
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
        f"  ETA: about {_hms(st['estimated_remaining_s'])} of gantry time left (the plan's estimate)",
    ]
    if st["latched_fault"]:
        lines.append(f"  latched fault: {st['latched_fault']} (resume with --clear-fault once fixed)")
    elif st["last_fault"]:
        lines.append(f"  last fault: {st['last_fault']}")
    print("\n".join(lines))
    return 0


# -- gonio fit ------------------------------------------------------------------------------------
def _fit_out_path(text: str) -> Path:
    out = Path(text)
    if out.is_dir():
        raise UsageError(f"--out: {out} is a folder; give a file name for the fit's JSON")
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise UsageError(f"--out: folder {parent} does not exist; create it or choose another path")
    probe = out.with_name(out.name + ".partial")
    try:  # before the fit, not after it: a fit may take a while
        probe.open("w").close()
        probe.unlink()
    except OSError as err:
        raise UsageError(f"--out: {out} cannot be written ({err.strerror or err}); choose another path") \
            from None
    return out


def cmd_fit(args) -> int:
    """Fit a model to a finished campaign; the MATERIAL string on stdout, the JSON in --out."""
    from gonio.dataset import BRDF_NAME
    from gonio.fit import fit, parse_channels, parse_model

    source = Path(args.dir)
    if not source.exists():
        raise UsageError(f"{source}: no such campaign folder or {BRDF_NAME} file")
    if source.is_dir() and not (source / BRDF_NAME).is_file():
        raise UsageError(f"{source}: not a finished campaign (no {BRDF_NAME}; it is written once every "
                         "step is measured: finish the campaign with the command that started it)")
    out = _fit_out_path(args.out) if args.out else None
    channels = parse_channels(args.channels)
    parse_model(args.model, channels)  # a bad MODEL is reported before any data is read
    if args.starts < 1:
        raise UsageError(f"--starts: must be an integer >= 1, got {args.starts}")
    result = fit(source, args.model, channels=args.channels, loss=args.loss, starts=args.starts)
    if out is not None:
        tmp = out.with_name(out.name + ".partial")
        tmp.write_text(json.dumps(result.to_json(), indent=2) + "\n")
        tmp.replace(out)
    print(result.material)
    if not args.quiet:
        res = result.residual
        for name, v in result.parameters.items():
            flag = "  (at bound)" if v["at_bound"] else ""
            print(f"  {name} = {v['value']:.6g} ± {v['stddev']:.2g}{flag}", file=sys.stderr)
        print(f"  loss ({result.loss}) {res['loss']:.6g} over {res['residuals']} residuals, "
              f"{res['dof']} degrees of freedom; per dof {res['chi2_reduced']:.3g}; relative "
              f"{res['rms_relative']:.3g}; structure {res['structure']:.2f}"
              f"{'; MISFIT: the model leaves a structured residual' if res['misfit'] else ''}",
              file=sys.stderr)
    return 0


# -- gonio export ---------------------------------------------------------------------------------
def _export_formats(text: str | None) -> list[str]:
    from gonio.export import parse_formats

    return parse_formats(text) if text is not None else []


def _write_exports(folder: Path, formats: list[str], out: _Out) -> None:
    """``gonio simulate --export``: each format under its unambiguous name in the campaign folder."""
    from gonio.export import EXPORT_NAMES, export

    for fmt in formats:
        out(f"export {export(folder, fmt, folder / EXPORT_NAMES[fmt])}")


def finished_campaign(folder: Path) -> Path:
    """The ``brdf.h5`` of a finished campaign folder; a UsageError for anything else (no folder, not a
    campaign, still running, incomplete, brdf.h5 missing)."""
    from gonio.campaign import LOCK_NAME
    from gonio.dataset import BRDF_NAME
    from gonio.store import JOURNAL_NAME, Journal

    if not folder.is_dir():
        raise UsageError(f"{folder}: no such campaign folder")
    if not (folder / JOURNAL_NAME).is_file():
        raise UsageError(f"{folder}: not a campaign folder (no {JOURNAL_NAME})")
    pid = _lock_holder(folder)
    if pid is not None:
        raise UsageError(f"{folder}: the campaign is still running (pid {pid} holds {LOCK_NAME}); use it "
                         "once it has finished")
    j = Journal.open(folder / JOURNAL_NAME, readonly=True)
    try:
        done, total = j.done_count(), j.step_count()
    finally:
        j.close()
    if done < total:
        raise UsageError(f"{folder}: the campaign is incomplete ({done}/{total} steps measured); finish it "
                         "with the command that started it (it resumes), then use it")
    if not (folder / BRDF_NAME).is_file():
        raise UsageError(f"{folder}: every step is measured but {BRDF_NAME} is missing; run the command that "
                         "started the campaign again to write it")
    return folder / BRDF_NAME


def _writable_out(text: str, *, folder: bool = False) -> Path:
    """--out checked before any work: its folder exists and takes a file; a file (or, with ``folder``,
    a folder) may be replaced, nothing else."""
    out = Path(text)
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise UsageError(f"--out: folder {parent} does not exist; create it or choose another path")
    if out.is_dir() and not folder:
        raise UsageError(f"--out: {out} is a folder; give a file name")
    if out.exists() and folder and not out.is_dir():
        raise UsageError(f"--out: {out} is a file; this format writes a folder of files")
    probe = parent / f".{out.name}.{os.getpid()}.probe"
    try:
        probe.open("w").close()
        probe.unlink()
    except OSError as err:
        raise UsageError(f"--out: {out} cannot be written ({err.strerror or err}); choose another path") \
            from None
    return out


def cmd_export(args) -> int:
    """Export a finished campaign; the report (cells from data, interpolated, empty) on stdout."""
    from gonio.export import export, parse_formats

    fmt = parse_formats(args.format, "--format")
    if len(fmt) != 1:
        raise UsageError(f"--format: one format per export, got {args.format!r}")
    source = finished_campaign(Path(args.dir))
    out = _writable_out(args.out, folder=fmt[0] == "radiance")
    report = export(source, fmt[0], out)
    print(report)
    for note in report.notes:
        print(f"  {note}")
    return 0


# -- gonio run, gonio emulate, gonio gantry (configured hardware) -----------------------------------
def cmd_run(args) -> int:
    from gonio.plan import parse_grid
    from gonio.sim.materials import load as load_material

    material = load_material(args.material) if args.material else None
    parse_grid(args.grid)
    cfg = load_config(args.config)
    if not args.sample.strip():
        raise UsageError("--sample: give the name of the sample measured (not empty)")
    if cfg.detector.driver == "sim" and material is None:
        raise UsageError(f"--material: the detector of config '{cfg.name}' is simulated ('sim'): give the "
                         "MATERIAL it renders, e.g. --material lambert:albedo=0.5")
    return _campaign_command(args, cfg, material=material, sample=args.sample, model_check=False,
                             relocate_buses=True)


def cmd_emulate(args) -> int:
    from gonio.sim.emulators.gantry import EmulatedGantry
    from gonio.sim.materials import load as load_material

    cfg = load_config(args.config)
    material = load_material(args.material)
    target = Path(args.write_config) if args.write_config else None
    if target is not None and (target.is_dir() or not target.parent.is_dir()):
        raise UsageError(f"--write-config: {target} must be a file in an existing folder")
    emu = EmulatedGantry(cfg, material, seed=args.seed, any_port=args.any_port)
    stop = threading.Event()
    if _in_main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda signum, frame: stop.set())
    emu.start()
    try:
        for bus, where in emu.locations().items():
            print(f"{bus}: {where}", flush=True)
        if target is not None:
            tmp = target.with_name(target.name + ".tmp")
            tmp.write_text(emu.config_toml(f"# {cfg.name}, emulated by gonio emulate (pid {os.getpid()}); "
                                           "valid while it runs\n"))
            tmp.replace(target)
            print(f"config: {target}", flush=True)
        print(f"emulating '{cfg.name}' (material {material.spec}); SIGINT or SIGTERM stops", flush=True)
        while not stop.wait(0.5):
            pass
    finally:
        emu.stop()
        if target is not None:
            target.unlink(missing_ok=True)
    return 0


def cmd_gantry(args) -> int:
    from gonio import manual
    from gonio.protocols import DeviceFault
    from gonio.wiring import build_gantry

    cfg = load_config(args.config)
    gantry = build_gantry(cfg, "lambert:albedo=0.5" if cfg.detector.driver == "sim" else None)
    kin = gantry.kinematics
    angles = [args.theta_i, args.phi_i, args.theta_o, args.phi_o] if args.action == "move" else []
    axes_arg = None
    if args.action == "move":
        if args.axes is not None and any(a is not None for a in angles):
            raise UsageError("gonio gantry move: give either --axes or the four angles, not both")
        if args.axes is not None:
            try:
                axes_arg = [float(x) for x in args.axes.split(",")]
            except ValueError:
                raise UsageError(f"--axes: {args.axes!r} is not a comma-separated list of degrees") from None
            if len(axes_arg) != len(kin.axis_names):
                raise UsageError(f"--axes: {len(axes_arg)} values for the {len(kin.axis_names)} axes "
                                 f"{', '.join(kin.axis_names)}")
        elif any(a is None for a in angles):
            raise UsageError("gonio gantry move: give --theta-i, --phi-i, --theta-o and --phi-o (degrees), "
                             "or --axes")
    if args.action == "jog" and (args.axis not in kin.axis_names or args.by is None):
        raise UsageError(f"gonio gantry jog: give --axis (one of {', '.join(kin.axis_names)}) and --by DEG")
    try:
        axes = manual.connect_axes(gantry, keep_faulted=args.action in ("status", "reboot", "stop"))
    except DeviceFault as err:
        print(f"gonio gantry {args.action}: {err}", file=sys.stderr)
        return 1
    try:
        if args.action == "status":
            reports = [manual.axis_report(a) for a in axes.values()]
            if args.json:
                print(json.dumps({"gantry": cfg.name, "axes": reports}, indent=2))
            else:
                for r in reports:
                    units = (f" ({r['position_units']} {r['units']}, target {r['target_units']})"
                             if r["units"] else "")
                    target = f"{r['target_deg']:.3f}°" if r["target_deg"] is not None else "-"
                    fault = f"  FAULT: {r['fault']}" if r["fault"] else ""
                    print(f"{r['axis']:<18} {r['position_deg']:9.3f}°  target {target}{units}"
                          f"{'  moving' if r['moving'] else ''}{fault}")
            return 0
        if args.action == "stop":
            gantry.stop()
            print(f"stopped {len(axes)} axes: {', '.join(axes)}")
            return 0
        if args.action == "reboot":
            names = [args.axis] if args.axis else list(axes)
            unknown = [n for n in names if n not in axes]
            if unknown:
                raise UsageError(f"--axis: {unknown[0]!r} is not one of {', '.join(axes)}")
            cleared = [n for n in names if axes[n].fault() is not None]
            for n in cleared:
                axes[n].clear_fault()
            print(f"cleared: {', '.join(cleared)}" if cleared else "no axis had a fault")
            return 0
        current = np.array([gantry.axes[n].position_deg() for n in kin.axis_names])
        if args.action == "home":
            target = np.asarray(kin.home_deg, float)
        elif args.action == "jog":
            target = current.copy()
            target[kin.axis_names.index(args.axis)] += args.by
        elif axes_arg is not None:
            target = np.asarray(axes_arg)
        else:
            target = manual.pose_targets(kin, current, *angles)
        legs = manual.plan_move(kin, current, target)  # refused here, before anything moves
        final = manual.drive(gantry, legs, cfg=cfg, clock=gantry.clock)
        print("  ".join(f"{n}={v:.3f}°" for n, v in zip(kin.axis_names, final, strict=True))
              + (f"  ({len(legs)} legs)" if len(legs) > 1 else ""))
        return 0
    except DeviceFault as err:
        print(f"gonio gantry {args.action}: {err}", file=sys.stderr)
        return 1
    finally:
        manual.close_axes(axes)


# -- gonio plot -----------------------------------------------------------------------------------
def cmd_plot(args) -> int:
    """Draw a finished campaign; the file written (and any caveat) on stdout."""
    from gonio.plot import KINDS, SUFFIXES, plot

    if args.kind not in KINDS:
        raise UsageError(f"--kind: {args.kind!r} is unknown; allowed: {', '.join(KINDS)}")
    if Path(args.out).suffix.lower() not in SUFFIXES:
        raise UsageError(f"--out: {args.out} must end in {', '.join(SUFFIXES)} (the suffix picks the format)")
    if not (np.isfinite(args.theta_i) and 0.0 <= args.theta_i < 90.0):
        raise UsageError(f"--theta-i: must be in [0, 90) degrees, got {args.theta_i}")
    if not np.isfinite(args.phi_i):
        raise UsageError(f"--phi-i: must be a finite number of degrees, got {args.phi_i}")
    source = finished_campaign(Path(args.dir))
    out = _writable_out(args.out)
    print(plot(source.parent, args.kind, out, theta_i_deg=args.theta_i, phi_i_deg=args.phi_i))
    return 0


# -- gonio report ---------------------------------------------------------------------------------
def cmd_report(args) -> int:
    """Write the HTML report of a finished campaign; the page's path and its verdict lines on stdout."""
    from gonio.report import SUFFIXES, parse_models, report
    from gonio.report.html import LEVELS

    out = Path(args.out)
    if out.is_dir():
        raise UsageError(f"--out: {out} is a folder; give a file name ending in .html")
    if out.suffix.lower() not in SUFFIXES:
        raise UsageError(f"--out: {out} must end in .html (the report is one self-contained HTML page)")
    models = parse_models(args.models)  # a bad MODEL is reported before any data is read
    source = finished_campaign(Path(args.dir))
    out = _writable_out(args.out)
    rep = report(source.parent, out, models)
    print(f"report: {out}")
    for level, topic, text in rep.verdicts:
        print(f"  {LEVELS[level]:<4}  {topic}: {text}")
    return 0


# -- the parser -----------------------------------------------------------------------------------
class _DefaultsFormatter(argparse.HelpFormatter):
    """Help that shows each option's default where it has a meaningful one (not for flags, required
    options, or where the text already says it)."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if (default is None or default is False or default == argparse.SUPPRESS or "default" in text
                or action.required or not action.option_strings):
            return text
        return f"{text} (default: {default})"


def build_parser() -> argparse.ArgumentParser:
    from gonio.campaign import software_version

    fmt = _DefaultsFormatter
    p = argparse.ArgumentParser(prog="gonio", formatter_class=fmt,
                                description="Control and acquisition for gonio-reflectometers.")
    p.add_argument("--version", action="version", version=f"gonio {software_version()}")
    p.add_argument("--debug", action="store_true", help="show the traceback of an unexpected error")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    sp = sub.add_parser("plan", formatter_class=fmt, help="count and time a plan without moving anything")
    sp.add_argument("--grid", required=True, help="GRID, e.g. iso:step=5, full:step=15, merl:stride=4")
    sp.add_argument("--config", default=None,
                    help="gantry config: a TOML file or a shipped config's name (default: sim)")
    sp.add_argument("--json", action="store_true", help="one JSON object instead of the report")
    sp.set_defaults(func=cmd_plan)

    ss = sub.add_parser("simulate", formatter_class=fmt, help="run a whole campaign on the simulated gantry")
    ss.add_argument("material",
                    help="MATERIAL, e.g. lambert:albedo=0.8 or cook-torrance:d=beckmann,m=0.2,metal=gold")
    ss.add_argument("--grid", required=True, help="GRID, e.g. iso:step=10")
    ss.add_argument("--out", required=True, help="campaign folder (an unfinished campaign there is resumed)")
    ss.add_argument("--config", default=None,
                    help="gantry config: a TOML file or a shipped config's name (default: sim)")
    ss.add_argument("--seed", type=_seed, default=0, help="seed of the simulated detector's random numbers")
    ss.add_argument("--clear-fault", action="store_true",
                    help="clear the campaign's latched fault (after fixing its cause) and resume")
    ss.add_argument("--quiet", action="store_true", help="no progress output")
    ss.add_argument("--export", default=None, metavar="FORMATS",
                    help="exports written into the campaign folder once it is finished, comma-separated: "
                         "merl, bsdf, bsdf-spectral, radiance, csv, h5")
    ss.set_defaults(func=cmd_simulate)

    st = sub.add_parser("status", formatter_class=fmt,
                        help="a campaign's state, progress, ETA and last fault (read-only, safe while it "
                             "runs)")
    st.add_argument("dir", metavar="DIR", help="campaign folder")
    st.add_argument("--json", action="store_true", help="one JSON object")
    st.set_defaults(func=cmd_status)

    sc = sub.add_parser("config", formatter_class=fmt, help="list or print the shipped gantry configs")
    sc.add_argument("action", choices=["list", "show"])
    sc.add_argument("name", nargs="?", help="config name (for show) or a path")
    sc.set_defaults(func=cmd_config)

    sf = sub.add_parser("fit", formatter_class=fmt,
                        help="fit a reflectance model to a finished campaign's measured samples")
    sf.add_argument("dir", metavar="CAMPAIGN_DIR", help="finished campaign folder (or its brdf.h5)")
    sf.add_argument("--model", required=True,
                    help="lambert, phong, modified-phong, blinn-phong, normalized-blinn-phong, ward, "
                         "cook-torrance, ggx, or lambert+NAME; ':key=value,...' holds keys fixed or picks "
                         "the form (d=blinn, fresnel=dielectric, metal=gold), ':anisotropic' for ward/ggx")
    sf.add_argument("--channels", default=None, help="channels to fit, e.g. R,G,B or G (default: all)")
    sf.add_argument("--loss", default="auto", choices=["auto", "chi2", "cos"],
                    help="chi2: weighted by the measured stddev; cos: cos θi cos θo (f_model − f); auto: "
                         "chi2 when the data have stddevs")
    sf.add_argument("--starts", type=int, default=4, help="number of starts; the best fit wins")
    sf.add_argument("--out", metavar="FIT.json", default=None,
                    help="write parameters, uncertainties, loss and residual statistics as JSON")
    sf.add_argument("--quiet", action="store_true", help="only the MATERIAL string")
    sf.set_defaults(func=cmd_fit)

    se = sub.add_parser("export", formatter_class=fmt,
                        help="export a finished campaign's BRDF to a renderer's or a tool's file format")
    se.add_argument("dir", metavar="CAMPAIGN_DIR", help="finished campaign folder")
    se.add_argument("--format", required=True, metavar="FORMAT",
                    help="merl, bsdf (Mitsuba 3 / pbrt-v4 tensor, RGB), bsdf-spectral, radiance (a folder of "
                         "PAB-Opto files), csv, h5")
    se.add_argument("--out", required=True, metavar="FILE", help="output file (a folder for radiance)")
    se.set_defaults(func=cmd_export)

    sg = sub.add_parser("plot", formatter_class=fmt,
                        help="draw a finished campaign's BRDF (a PNG/PDF figure, or the slice's float "
                             "values as EXR)")
    sg.add_argument("dir", metavar="CAMPAIGN_DIR", help="finished campaign folder")
    sg.add_argument("--kind", required=True, metavar="KIND",
                    help="polar (in-plane f_r for several θi), hemisphere (f_r over ωo for one ωi), merl "
                         "((θh, θd) image), reciprocity (residual map; campaigns measured with "
                         "reciprocity=false), albedo (directional albedo against θi)")
    sg.add_argument("--out", required=True, metavar="FILE", help="FILE.png, FILE.pdf or FILE.exr")
    sg.add_argument("--theta-i", type=float, default=30.0, help="θi of the hemisphere plot, degrees")
    sg.add_argument("--phi-i", type=float, default=0.0, help="φi (plane of incidence), degrees")
    sg.set_defaults(func=cmd_plot)

    sq = sub.add_parser("report", formatter_class=fmt,
                        help="a finished campaign's report as one self-contained HTML page: the campaign, "
                             "its calibration, data checks, and several models fitted side by side")
    sq.add_argument("dir", metavar="CAMPAIGN_DIR", help="finished campaign folder")
    sq.add_argument("--out", required=True, metavar="REPORT.html", help="the page to write")
    sq.add_argument("--models", default=None, metavar="MODELS",
                    help="comma-separated fit MODELs as for gonio fit (default: lambert, ward, "
                         "cook-torrance, ggx, lambert+ggx)")
    sq.set_defaults(func=cmd_report)

    sr = sub.add_parser("run", formatter_class=fmt,
                        help="run a whole campaign on the configured (real, emulated or mixed) gantry")
    sr.add_argument("--config", required=True, help="gantry config: a TOML file or a shipped config's name")
    sr.add_argument("--grid", required=True, help="GRID, e.g. iso:step=10")
    sr.add_argument("--out", required=True, help="campaign folder (an unfinished campaign there is resumed)")
    sr.add_argument("--sample", required=True, help="name of the sample measured")
    sr.add_argument("--material", default=None,
                    help="MATERIAL a simulated detector renders (dry runs: config detector driver 'sim')")
    sr.add_argument("--seed", type=_seed, default=0, help="seed of simulated devices' random numbers")
    sr.add_argument("--clear-fault", action="store_true",
                    help="clear the campaign's latched fault (after fixing its cause) and resume")
    sr.add_argument("--quiet", action="store_true", help="no progress output")
    sr.set_defaults(func=cmd_run)

    se = sub.add_parser("emulate", formatter_class=fmt,
                        help="run the emulated devices of a config until SIGINT/SIGTERM")
    se.add_argument("--config", required=True, help="gantry config: a TOML file or a shipped config's name")
    se.add_argument("--material", default="lambert:albedo=0.5", help="MATERIAL the emulated detector sees")
    se.add_argument("--seed", type=_seed, default=0, help="seed of the emulated detector's readings")
    se.add_argument("--write-config", default=None, metavar="PATH",
                    help="write the config with the emulators' ptys and urls to PATH (removed at exit)")
    se.add_argument("--any-port", action="store_true",
                    help="serve Modbus TCP on free loopback ports, not the ports the config names")
    se.set_defaults(func=cmd_emulate)

    sg = sub.add_parser("gantry", formatter_class=fmt, help="manual control of the configured gantry")
    sg.add_argument("action", choices=["status", "home", "move", "jog", "stop", "reboot"])
    sg.add_argument("--config", required=True, help="gantry config: a TOML file or a shipped config's name")
    sg.add_argument("--theta-i", type=float, default=None, help="move: θi (°)")
    sg.add_argument("--phi-i", type=float, default=None, help="move: φi (°)")
    sg.add_argument("--theta-o", type=float, default=None, help="move: θo (°)")
    sg.add_argument("--phi-o", type=float, default=None, help="move: φo (°)")
    sg.add_argument("--axes", default=None, help="move: axis positions a,b,c,d (°) in the design's order")
    sg.add_argument("--axis", default=None, help="jog: the axis; reboot: only this axis")
    sg.add_argument("--by", type=float, default=None, help="jog: degrees to move by (signed)")
    sg.add_argument("--json", action="store_true", help="status: one JSON object")
    sg.set_defaults(func=cmd_gantry)

    # The daemon and its clients: gonio serve, submit, queue, watch, pause, resume, abort, halt, fetch
    # (their cmd_* functions live in gonio.daemon.commands).
    from gonio.daemon.commands import add_parsers as add_daemon_parsers

    add_daemon_parsers(sub, fmt, _seed)
    return p


def _user_error(err: BaseException) -> str:
    if isinstance(err, OSError) and err.filename is not None:
        return f"{err.filename}: {err.strerror or err}"
    return str(err)


def _raise_interrupted(signum, frame):
    raise Interrupted(signum)


def _in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def _install_startup_handlers() -> None:
    """Before and after a campaign runs, SIGINT and SIGTERM end the command cleanly (no traceback).
    Signal handlers belong to the main thread; called from another (a test, an embedding), nothing."""
    if _in_main_thread():
        signal.signal(signal.SIGINT, _raise_interrupted)
        signal.signal(signal.SIGTERM, _raise_interrupted)


def main(argv: list[str] | None = None) -> int:
    from gonio.calibrate import CalibrationError
    from gonio.store import JournalError

    parser = build_parser()
    args = parser.parse_args(argv)
    main_thread = _in_main_thread()
    previous = (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) if main_thread else None
    _install_startup_handlers()
    try:
        return args.func(args)
    except (ConfigError, UsageError, JournalError, CalibrationError, ValueError, OSError) as err:
        if args.debug:
            raise
        print(f"gonio {args.command}: {_user_error(err)}", file=sys.stderr)
        return 2
    except Interrupted as err:
        out = getattr(args, "out", None)
        where = f"; the journal in {out} keeps every committed step: run the same command to resume" \
            if out and Path(out, "campaign.sqlite").exists() else "; nothing was written"
        print(f"gonio {args.command}: interrupted ({err}){where}", file=sys.stderr)
        return 130
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous[0])
            signal.signal(signal.SIGTERM, previous[1])


if __name__ == "__main__":
    sys.exit(main())
