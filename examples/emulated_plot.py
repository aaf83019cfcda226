"""A campaign on the emulated two-arm gantry, through the real drivers, then its plots.

    python examples/emulated_plot.py [FOLDER]     (default: runs/emulated-plot)

The emulators (Dynamixel servos on a pty, the serial lamp and power meter) start in this process and
share a virtual clock with the gantry, so the campaign takes seconds; `gonio emulate` runs the same
emulators on the wall clock for another process. On a real gantry, build it from your own config:
`build_gantry(load_config("my-gantry.toml"))` talks to the ports the config names, on the wall clock.
Leaves in FOLDER the campaign (campaign.sqlite, brdf.h5), polar.png and albedo.png.
"""

from __future__ import annotations

import sys
from pathlib import Path

from gonio.campaign import create_campaign
from gonio.config import load_config
from gonio.lifecycle import run_campaign
from gonio.plot import plot
from gonio.runner import State
from gonio.sim.emulators.gantry import EmulatedGantry
from gonio.sim.emulators.link import SyncedVirtualClock
from gonio.wiring import build_gantry

CONFIG = "emulated-two-arm-dynamixel"
SAMPLE_SEEN = "ggx:alpha=0.3,metal=gold,rho_d=0.1,rho_s=0.9"   # what the emulated power meter sees
GRID = "iso:step=30"


def measure(folder: Path) -> State:
    clock = SyncedVirtualClock()
    # The emulated servos start referenced here; a real gantry (or `gonio emulate`) powers up with each
    # carriage's ring angle unknown, and `gonio gantry reference --config FILE` comes first.
    with EmulatedGantry(load_config(CONFIG), SAMPLE_SEEN, clock=clock, referenced=True) as emu:
        cfg = emu.config()                    # the config with the ptys the emulators listen on
        c = create_campaign(folder, cfg, grid=GRID, material=None, sample="gold foil")
        try:
            print(f"{c.meta['poses']} poses of {c.meta['grid']}, estimated {c.meta['estimated_s']:.0f} s of "
                  "gantry time")
            state, runner = run_campaign(c, build_gantry(cfg, clock=clock),
                                         on_step=lambda r, step: step % 10 == 0 and print(f"step {step}"))
        finally:
            c.close()
    print(f"campaign {state}" + (f": {runner.fault}" if runner.fault else ""))
    return state


def main(folder: Path) -> int:
    folder.parent.mkdir(parents=True, exist_ok=True)
    if measure(folder) != State.DONE:
        return 1
    for kind in ("polar", "albedo"):
        print(plot(folder, kind, folder / f"{kind}.png"))
    return 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("runs/emulated-plot")))
