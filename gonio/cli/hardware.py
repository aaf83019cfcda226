"""Hardware commands: ``emulate`` (the emulated devices of a config) and ``gantry`` (manual control)."""

from __future__ import annotations

import json
import math
import os
import re
import signal
import sys
import threading
from pathlib import Path

import numpy as np

from gonio.cli.common import UsageError, refuse_emulated_placeholders
from gonio.cli.common import in_main_thread as _in_main_thread
from gonio.config import load_config

#: The first line of the config ``gonio emulate --write-config`` writes: the emulator's name and pid.
_CONFIG_HEAD = "# {name}, emulated by gonio emulate (pid {pid}); valid while it runs\n"


def _emulator_of(path: Path) -> int | None:
    """The pid of the running ``gonio emulate`` whose config ``path`` is (its first line says so and that
    process lives), or None."""
    try:
        with path.open(encoding="utf-8", errors="replace") as fh:
            head = fh.readline(200)
    except OSError:
        return None
    m = re.search(r"emulated by gonio emulate \(pid (\d+)\)", head)
    if m is None or int(m.group(1)) == os.getpid():
        return None
    try:
        os.kill(int(m.group(1)), 0)
    except ProcessLookupError:
        return None          # a config left by an emulator that is gone: replaced
    except PermissionError:
        pass                 # alive, another user's
    return int(m.group(1))


def cmd_emulate(args) -> int:
    """Serve the emulated devices of a config until SIGINT or SIGTERM (exit 0, as ``gonio serve``: stopping
    is how a server ends). If an emulator's serving thread dies (a bug: nothing a driver sends kills one),
    one line on stderr names the device and the exception, every other emulator is stopped (ptys and
    sockets closed), the ``--write-config`` file is removed (a config naming ports nothing serves would
    only time out), and the exit code is 1. An emulator still busy when the stop's wait runs out is one
    line too (exit 1): the process ends it."""
    from gonio.sim.emulators.gantry import EmulatedGantry
    from gonio.sim.materials import load as load_material

    cfg = load_config(args.config)
    try:
        material = load_material(args.material)
    except ValueError as err:
        raise UsageError(f"--material: {err}") from None
    target = Path(args.write_config) if args.write_config else None
    if target is not None and (target.is_dir() or not target.parent.is_dir()):
        raise UsageError(f"--write-config: {target} must be a file in an existing folder")
    if target is not None and (owner := _emulator_of(target)) is not None:
        raise UsageError(f"--write-config: {target} is the config of the gonio emulate that runs as pid "
                         f"{owner}; its devices would lose their config when this one stops: give another "
                         "file, or stop that one first")
    emu = EmulatedGantry(cfg, material, seed=args.seed, any_port=args.any_port)
    stop = threading.Event()
    dead: list[tuple[str, BaseException]] = []
    written = False

    def died(bus: str, exc: BaseException) -> None:  # in the dying thread: record, wake the main one
        dead.append((bus, exc))
        stop.set()

    emu.watch(died)
    if _in_main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda signum, frame: stop.set())
    emu.start()
    try:
        for bus, where in emu.locations().items():
            print(f"{bus}: {where}", flush=True)
        if target is not None and not stop.is_set():
            tmp = target.with_name(target.name + ".tmp")
            tmp.write_text(emu.config_toml(_CONFIG_HEAD.format(name=cfg.name, pid=os.getpid())))
            tmp.replace(target)
            written = True
            print(f"config: {target}", flush=True)
        print(f"emulating '{cfg.name}' (material {material.spec}); SIGINT or SIGTERM stops", flush=True)
        fresh = [n for n, a in cfg.axes.items() if not a.simulated and a.reference_method != "none"]
        if fresh:  # powered up as hardware is: the positions of these are unknown until referenced
            print(f"powered up unreferenced: {', '.join(fresh)}; run `gonio gantry reference --config "
                  f"{target or 'FILE'}` before moving them", flush=True)
        while not stop.wait(0.5):
            pass
    finally:
        if target is not None:  # first: no client may read ports that are about to close
            target.unlink(missing_ok=True)
        try:
            emu.stop()
        except RuntimeError as err:  # a thread busy past the stop's wait (a PM100 averaging for minutes)
            stuck = err
        else:
            stuck = None
    if stuck is not None and not dead:
        print(f"gonio emulate: {stuck}; the others stopped, and it ends with this process", file=sys.stderr,
              flush=True)
        return 1
    if dead:
        bus, exc = dead[0]
        what = " ".join(f"{type(exc).__name__}: {exc}".split())  # one line, whatever the message holds
        gone = "" if target is None else f"; {target} {'removed' if written else 'not written'}"
        print(f"gonio emulate: {emu.devices[bus]} (bus '{bus}') stopped answering: its emulator died of "
              f"{what}; every other emulator stopped{gone}", file=sys.stderr, flush=True)
        return 1
    return 0


def cmd_gantry(args) -> int:
    from gonio import manual
    from gonio.protocols import DeviceFault
    from gonio.reference import refusal, unreferenced
    from gonio.wiring import build_gantry

    cfg = load_config(args.config)
    refuse_emulated_placeholders(cfg, args.config)
    gantry = build_gantry(cfg, "lambert:albedo=0.5" if cfg.detector.simulated else None)
    kin = gantry.kinematics
    angles = [args.theta_i, args.phi_i, args.theta_o, args.phi_o] if args.action == "move" else []
    axes_arg = None
    if args.action == "move":
        if args.axes is not None and any(a is not None for a in angles):
            raise UsageError("move: give either --axes or the four angles, not both")
        if args.axes is not None:
            try:
                axes_arg = [float(x) for x in args.axes.split(",")]
            except ValueError:
                raise UsageError(f"--axes: {args.axes!r} is not a comma-separated list of degrees") from None
            if len(axes_arg) != len(kin.axis_names):
                raise UsageError(f"--axes: {len(axes_arg)} values for the {len(kin.axis_names)} axes "
                                 f"{', '.join(kin.axis_names)}")
        elif any(a is None for a in angles):
            raise UsageError("move: give --theta-i, --phi-i, --theta-o and --phi-o (degrees), "
                             "or --axes")
        given = zip(kin.axis_names, axes_arg, strict=True) if axes_arg is not None else \
            zip(("--theta-i", "--phi-i", "--theta-o", "--phi-o"), angles, strict=True)
        for name, value in given:   # NaN and inf: said here in degrees, as given
            if not math.isfinite(value):
                raise UsageError(f"{'--axes: axis ' if axes_arg is not None else ''}{name}: must be a finite "
                                 f"number of degrees, got {value}")
    if args.action == "jog" and (args.axis not in kin.axis_names or args.by is None):
        raise UsageError(f"jog: give --axis (one of {', '.join(kin.axis_names)}) and --by DEG")
    if args.action == "jog" and not math.isfinite(args.by):
        raise UsageError(f"--by: must be a finite number of degrees, got {args.by}")
    if args.action == "reference" and args.axis is not None:
        from gonio.protocols import Referencing

        methods = {n: a.reference_method if isinstance(a, Referencing) else "none"
                   for n, a in gantry.all_axes.items()}
        if args.axis not in methods:
            raise UsageError(f"--axis: {args.axis!r} is not one of {', '.join(methods)}")
        if methods[args.axis] == "none":
            have = ", ".join(n for n, m in methods.items() if m != "none")
            raise UsageError(f"--axis: {args.axis!r} needs no reference (axes.{args.axis}.reference is "
                             f"'none'); axes that have one: {have}")
    try:
        if args.action in ("home", "move", "jog"):  # refused, nothing written, while one is unreferenced
            axes = manual.connect_axes(gantry, readonly=True)
            missing = unreferenced(axes)
            manual.close_axes(axes)
            if missing:
                raise UsageError(refusal(missing))
        axes = manual.connect_axes(gantry, keep_faulted=args.action in ("status", "reboot", "stop"),
                                   readonly=args.action == "status")
    except DeviceFault as err:
        print(f"gonio gantry {args.action}: {err}", file=sys.stderr)
        return 1
    try:
        if args.action == "reference":
            from gonio.reference import reference_axes

            reference_axes(gantry, cfg, None if args.axis is None else [args.axis])
            for r in (manual.axis_report(a) for a in axes.values()):
                print(f"{r['axis']:<18} {r['position_deg']:9.3f}°"
                      + ("" if r["referenced"] is None else "  referenced" if r["referenced"]
                         else "  NOT referenced"))
            return 0
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
                    ref = ("  NOT referenced (run `gonio gantry reference`)" if r["referenced"] is False
                           else "")
                    print(f"{r['axis']:<18} {r['position_deg']:9.3f}°  target {target}{units}"
                          f"{'  moving' if r['moving'] else ''}{ref}{fault}")
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
        # refused here, before anything moves
        legs = manual.plan_move(kin, current, target, cfg.runner.position_tolerance_deg)
        final = manual.drive(gantry, legs, cfg=cfg, clock=gantry.clock)
        print("  ".join(f"{n}={v:.3f}°" for n, v in zip(kin.axis_names, final, strict=True))
              + (f"  ({len(legs)} legs)" if len(legs) > 1 else ""))
        return 0
    except DeviceFault as err:
        print(f"gonio gantry {args.action}: {err}", file=sys.stderr)
        return 1
    finally:
        manual.close_axes(axes)
