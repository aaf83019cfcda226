"""Cutting and splitting a circular serpentine loop."""

from __future__ import annotations

import numpy as np

from gonio.config import load_config
from gonio.kinematics import make_kinematics
from gonio.motion.branches import best_branches
from gonio.motion.cut import arc_boundaries, best_cut, serpentine_loops, split_arcs
from gonio.motion.metric import MoveMetric
from gonio.motion.order import serpentine_order
from gonio.plan.grids import enumerate_grid, parse_grid


def test_split_arcs_inserts_a_level_outside_the_row_loop():
    loops = np.array([[0, 1, 0], [0, 1, 3], [0, 1, 5], [1, 2, 7]])
    got = split_arcs(loops, 2, [3, 6])
    assert got.tolist() == [[0, 0, 1, 0], [0, 1, 1, 3], [0, 1, 1, 5], [1, 2, 2, 7]]


def test_two_arm_rows_need_a_flip_and_arcs_pay_it_once_per_arc():
    # On the two-arm gantry the detector carriage cannot pass the light's (at azimuth 0): a sweep of
    # Δφ over a full circle must make a costly move (a branch flip) somewhere, wherever it is cut.
    cfg = load_config()
    kin = make_kinematics(cfg)
    metric = MoveMetric(kin.velocity_deg_s, kin.accel_deg_s2)
    g = enumerate_grid(parse_grid("iso:step=10,theta_max=60"), 60)
    ok = kin.feasibility(g.theta_i, g.phi_i, g.theta_o, g.phi_o) == 0
    angles = [a[ok] for a in (g.theta_i, g.phi_i, g.theta_o, g.phi_o)]
    loops = g.loops[ok]
    start = kin.inverse(0.0, 0.0, np.radians(45), np.pi)[0]
    for cut in (0, 9, 18, 27):
        rotated = loops.copy()
        rotated[:, 2] = (loops[:, 2] - cut) % 36
        assert arc_boundaries(kin, angles, rotated, 2, 36, start, metric).size >= 1
    cut = best_cut(kin, angles, loops, 2, 36, start, metric)
    assert 0 <= cut < 36
    # So the planner splits the circle into arcs swept over all rows in turn, and that is quicker.
    split = serpentine_loops(kin, angles, loops, 36, start, metric, run_length=50)
    assert split.shape[1] == 4
    rotated = loops.copy()
    rotated[:, 2] = (loops[:, 2] - cut) % 36

    def motion(lp):
        order = serpentine_order(lp)
        axes = best_branches(kin, *(a[order] for a in angles), np.arange(0, len(order), 50), start)
        return float(metric.time(axes[:-1], axes[1:]).sum())

    assert motion(split) < motion(rotated)
