"""Adaptive acquisition of BRDFs: a pilot grid, then rounds of poses placed where the reconstruction from
the samples so far is least trustworthy, within a pose budget and the gantry's reach. Isotropic samples
are measured over (θi, θo, Δφ); anisotropic ones (``anisotropic=true``) over (θi, φi, θo, φo) by the
same rounds in another embedding (:mod:`~gonio.adaptive.domain`'s ``pair``).

Each module is one idea:

- :mod:`~gonio.adaptive.samples`: the measured samples a round sees, and the pose domain's embedding.
- :mod:`~gonio.adaptive.reach`: which poses the gantry can measure (a reciprocal stand-in where the kept
  pose cannot be reached).
- :mod:`~gonio.adaptive.pilot`: the pilot, a coarse reachable iso lattice (a ``full`` grid in 4D).
- :mod:`~gonio.adaptive.reconstruct`: f_r anywhere from scattered samples, and each sample's
  leave-one-out residual.
- :mod:`~gonio.adaptive.refine`: one round: a pure function of the samples so far.
- :mod:`~gonio.adaptive.motion`: what a round's poses cost in gantry time, and the choice that trades
  error against it.
- :mod:`~gonio.adaptive.acquire`: pilot + rounds until the budget is spent, around a measure callback.
- :mod:`~gonio.adaptive.error`: the benchmark's error: cosine-weighted relative L1 at random pairs.
"""

from gonio.adaptive.acquire import acquire, material_measure, round_sizes
from gonio.adaptive.error import random_pairs, weighted_l1
from gonio.adaptive.pilot import pilot_poses
from gonio.adaptive.reach import reachable_iso, reachable_pair
from gonio.adaptive.reconstruct import LocalFit, reconstruct
from gonio.adaptive.refine import plan_round
from gonio.adaptive.samples import Samples

__all__ = ["Samples", "reachable_iso", "reachable_pair", "pilot_poses", "LocalFit", "reconstruct",
           "plan_round", "acquire", "material_measure", "round_sizes", "random_pairs", "weighted_l1"]
