"""Simulate a campaign, export it for Mitsuba 3 and render a sphere made of it.

    python examples/render_sphere.py [FOLDER]     (default: runs/render-sphere)

Needs the development extras (Mitsuba 3: `make test` installs them, or `pip install mitsuba`). Leaves in
FOLDER the campaign (campaign.sqlite, brdf.h5), its tensor export (gold.bsdf) and the render
(sphere.exr, sphere.png). Start here to render your own measurement: give `export` your campaign folder.
"""

from __future__ import annotations

import sys
from pathlib import Path

from gonio.campaign import create_campaign, open_campaign
from gonio.config import load_config
from gonio.export import export
from gonio.lifecycle import run_campaign
from gonio.store import JOURNAL_NAME
from gonio.wiring import build_gantry

MATERIAL = "ggx:alpha=0.3,metal=gold"
GRID = "iso:step=15"


def simulate(folder: Path) -> None:
    """The campaign on the simulated gantry (resumed, or left as it is, if it is already there)."""
    if (folder / JOURNAL_NAME).exists():
        c = open_campaign(folder)
    else:
        c = create_campaign(folder, load_config(), grid=GRID, material=MATERIAL, seed=1)
    try:
        if not (folder / "brdf.h5").exists():
            state, _ = run_campaign(c, build_gantry(c.cfg, MATERIAL, seed=1))
            print(f"campaign {state}: {folder / 'brdf.h5'}")
    finally:
        c.close()


def render(bsdf_file: Path, out: Path, size: int = 128, spp: int = 64) -> None:
    """A unit sphere of the measured BSDF, lit by a directional light and a dim sky."""
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    look = mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0])
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "direct"},
        "sensor": {"type": "perspective", "fov": 28.0, "to_world": look,
                   "film": {"type": "hdrfilm", "width": size, "height": size},
                   "sampler": {"type": "independent", "sample_count": spp}},
        "sphere": {"type": "sphere", "bsdf": {"type": "measured", "filename": str(bsdf_file)}},
        "sun": {"type": "directional", "direction": [-1.0, -0.6, -1.0], "irradiance": 3.0},
        "sky": {"type": "constant", "radiance": 0.3},
    })
    image = mi.render(scene)
    mi.util.write_bitmap(str(out.with_suffix(".exr")), image)
    mi.util.write_bitmap(str(out.with_suffix(".png")), image)   # sRGB, 8 bits
    print(f"rendered {out.with_suffix('.png')} and {out.with_suffix('.exr')}")


def main(folder: Path) -> int:
    folder.parent.mkdir(parents=True, exist_ok=True)
    simulate(folder)
    report = export(folder, "bsdf", folder / "gold.bsdf")
    print(report)
    render(folder / "gold.bsdf", folder / "sphere")
    return 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("runs/render-sphere")))
