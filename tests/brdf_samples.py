"""Sampled BRDFs built from a material's own eval on a plan's grid (a campaign without the gantry), and a
small measured-BSDF tensor file."""

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


def tiny_tensor_file(path):
    """A small valid measured-BSDF tensor file at ``path`` (two θi slices, 4 × 4 tables): what a
    ``bsdf:`` material reads, without an export's cost."""
    from gonio.formats.tensor import write_tensor

    rgb = np.linspace(0.1, 0.9, 2 * 3 * 16, dtype=np.float32).reshape(1, 2, 3, 4, 4)
    write_tensor(path, {"theta_i": np.array([0.0, 0.5], np.float32), "phi_i": np.zeros(1, np.float32),
                        "ndf": np.ones((4, 4), np.float32), "sigma": np.ones((4, 4), np.float32),
                        "vndf": np.ones((1, 2, 4, 4), np.float32), "jacobian": np.ones(1, np.uint8),
                        "rgb": rgb})
    return path
