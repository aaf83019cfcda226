"""The ``gonio`` command line.

``gonio plan`` counts and times a plan without moving anything; ``gonio simulate`` runs a whole
campaign on the simulated gantry (resuming one left in the output folder).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from gonio.config import ConfigError, load_config

__all__ = ["main"]


def _hms(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


def cmd_plan(args) -> int:
    from gonio.plan import build_plan, format_plan, plan_summary

    cfg = load_config(args.config)
    plan = build_plan(args.grid, cfg)
    if args.json:
        print(json.dumps(plan_summary(plan), indent=2))
    else:
        print(format_plan(plan))
    return 0


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


def cmd_simulate(args) -> int:
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from gonio.campaign import create_campaign, open_campaign, run_campaign
    from gonio.plan import parse_grid
    from gonio.runner import State
    from gonio.sim.materials import load as load_material
    from gonio.store import JOURNAL_NAME
    from gonio.wiring import build_gantry

    console = Console(stderr=True, soft_wrap=True)
    out = Path(args.out)
    material = load_material(args.material)
    if (out / JOURNAL_NAME).exists():
        c = open_campaign(out)
        meta = c.meta
        if meta["material"] != args.material or meta["grid_requested"] != parse_grid(args.grid).normalized:
            console.print(f"[red]{out} holds another campaign ({meta['material']}, {meta['grid']}); "
                          f"choose another --out[/red]")
            c.close()
            return 2
        console.print(f"resuming the campaign in {out} at step {c.journal.next_step()}")
        seed = meta["seed"]
    else:
        cfg = load_config(args.config)
        c = create_campaign(out, cfg, grid=args.grid, material=args.material, seed=args.seed)
        seed = args.seed
    meta = c.meta
    n_steps = c.journal.step_count()
    gantry = build_gantry(c.cfg, material, seed=seed)
    console.print(f"[bold]{meta['gantry']}[/bold]: {meta['poses']} poses of {meta['grid']} "
                  f"({n_steps} steps with dark and white-reference readings), estimated "
                  f"{_hms(meta['estimated_s'])} of gantry time (lower bound {_hms(meta['lower_bound_s'])})")
    t0 = time.perf_counter()
    with Progress(TextColumn("[progress.description]{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TextColumn("gantry {task.fields[sim]}"), TextColumn("wall"), TimeElapsedColumn(),
                  TextColumn("ETA {task.fields[eta]}"), console=console, transient=False,
                  disable=args.quiet) as progress:
        done0 = c.journal.next_step()
        task = progress.add_task("measuring", total=n_steps, completed=done0, sim="0:00:00", eta="?")

        def on_step(runner, step):
            now = time.perf_counter() - t0
            done = step + 1 - done0
            eta = now / done * (n_steps - step - 1) if done else 0.0
            progress.update(task, completed=step + 1, sim=_hms(gantry.clock.now()), eta=_hms(eta))

        state, runner = run_campaign(c, gantry, on_step=on_step)
    wall = time.perf_counter() - t0
    console.print(f"campaign {state}: {len(c.journal.done_steps())}/{n_steps} steps, gantry time "
                  f"{_hms(gantry.clock.now())}, wall time {wall:.1f} s")
    if state != State.DONE:
        if runner.fault:
            console.print(f"[red]fault: {runner.fault}[/red]")
        console.print(f"the journal keeps every committed step: run the same command to resume ({out})")
        c.close()
        return 1
    console.print(f"wrote {out / 'brdf.h5'} and {out / JOURNAL_NAME}")
    console.print(_model_check(out, material))
    c.close()
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="gonio", description="Control and acquisition for gonio-reflectometers.")
    sub = p.add_subparsers(dest="command", required=True)

    sp = sub.add_parser("plan", help="count and time a plan without moving anything")
    sp.add_argument("--grid", required=True, help="GRID, e.g. iso:step=5, full:step=15, merl:stride=4")
    sp.add_argument("--config", default=None, help="gantry config TOML (default: the simulated gantry)")
    sp.add_argument("--json", action="store_true", help="one JSON object instead of the report")
    sp.set_defaults(func=cmd_plan)

    ss = sub.add_parser("simulate", help="run a whole campaign on the simulated gantry")
    ss.add_argument("material",
                    help="MATERIAL, e.g. lambert:albedo=0.8 or cook-torrance:d=beckmann,m=0.2,metal=gold")
    ss.add_argument("--grid", required=True)
    ss.add_argument("--out", required=True, help="campaign folder (an unfinished campaign there is resumed)")
    ss.add_argument("--config", default=None)
    ss.add_argument("--seed", type=int, default=0)
    ss.add_argument("--quiet", action="store_true", help="no progress bar")
    ss.set_defaults(func=cmd_simulate)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (ConfigError, ValueError) as err:
        print(f"gonio {args.command}: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
