"""A toy gantry design (docs/EXTENDING.md, "A new gantry design"): the lamp and the detector each ride
their own ring about the sample normal (``*_ring``, the azimuth) and tilt on it (``*_polar``, the polar
angle), so an axis reads an angle of ωi or ωo directly and no two parts can meet. Its kinematics is this
file, a config using it is ``toy-spherical.toml`` beside it; ``GONIO_PLUGINS=toy_design`` loads it."""

import numpy as np

from gonio.geometry import sph_to_vec
from gonio.kinematics.base import POLE_EPS, Kinematics, wrap_360
from gonio.registries import DESIGNS


@DESIGNS.register("toy-spherical", "lamp and detector on rings of their own (a toy plugin)")
class ToySpherical(Kinematics):
    #: The axes this design drives, in the order of every axis array (the config's [axes.NAME]).
    axis_names = ("light_ring", "light_polar", "detector_ring", "detector_polar")
    collision_rule = "none: the lamp and the detector ride rings of their own"

    def __init__(self, cfg):
        super().__init__(cfg)
        self.n_branches = 1  # one pose, one set of axis positions

    def _branches(self, theta_i, phi_i, theta_o, phi_o, current):
        def ring(theta, phi, now):  # at the pole the ring is free: it stays where it is
            return np.where(theta < POLE_EPS, now, wrap_360(np.degrees(phi)))

        cands = np.stack([ring(theta_i, phi_i, current[:, 0]), np.degrees(theta_i),
                          ring(theta_o, phi_o, current[:, 2]), np.degrees(theta_o)], axis=-1)
        return cands[:, None, :], np.zeros((len(cands), 1), dtype=bool)

    def _directions(self, axes_deg):
        a = np.radians(axes_deg)
        return sph_to_vec(a[:, 1], a[:, 0]), sph_to_vec(a[:, 3], a[:, 2])

    def _sweep_margin(self, start, end):
        return np.full(len(start), 180.0)  # nothing to collide with: the margin is always positive
