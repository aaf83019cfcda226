"""Sampled BRDFs built from a material's own eval on a plan's grid (a campaign without the gantry)."""

import numpy as np

from gonio.dataset import SampledBRDF
from gonio.geometry import sph_to_vec
from gonio.plan.grids import enumerate_grid, parse_grid
from gonio.sim.materials import load


def sampled(spec: str, grid: str, theta_max_deg: float = 85.0, rel_sd: float = 0.01) -> SampledBRDF:
    g = enumerate_grid(parse_grid(grid), theta_max_deg)
    gs = parse_grid(grid)
    v = load(spec).eval(sph_to_vec(g.theta_i, g.phi_i), sph_to_vec(g.theta_o, g.phi_o), precision="float64")
    return SampledBRDF(*(np.degrees(a) for a in (g.theta_i, g.phi_i, g.theta_o, g.phi_o)), v, rel_sd * v,
                       attrs={"grid": gs.normalized, "material": spec, "channels": ["R", "G", "B"],
                              "symmetries": {"reciprocity": gs.reciprocity, "isotropy": gs.isotropy,
                                             "mirror": gs.mirror}})
