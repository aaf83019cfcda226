"""Every grid option combination plans on every shipped gantry configuration.

A pose that is reachable alone must stay plannable in any sequence: a plan that exits with "some pose
has no valid branch" on a shipped config is a regression whatever the options. The lattices here are
coarse (so the whole matrix plans in seconds); the one finer grid is the case that once failed.
"""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest

from gonio.config import DEFAULT_CONFIG, load_config
from gonio.geometry import sph_to_vec
from gonio.kinematics import make_kinematics
from gonio.plan import STEP_POSE, build_plan
from gonio.registries import ORDERS

CONFIG_DIR = DEFAULT_CONFIG.parent


def _planning_input(cfg) -> str:
    """What planning reads of a config: the kinematics, the design's axes' limits, speeds and homes, the
    reference schedule, the runner's timing and the exposure. Not the drivers, buses, gear ratios or the
    other axes (a filter changer) of an emulated or hardware twin: it plans as its gantry
    (test_twins_plan_as_their_gantry)."""
    axes = {n: [getattr(cfg.axes[n], f) for f in ("min_deg", "max_deg", "max_velocity_deg_s",
                                                   "max_accel_deg_s2", "home_deg")]
            for n in cfg.axis_names}
    return json.dumps([cfg.kinematics.model_dump(), axes, cfg.reference.model_dump(), cfg.runner.model_dump(),
                       cfg.detector.exposure_s, cfg.detector.frames], sort_keys=True, default=str)


SHIPPED = sorted(CONFIG_DIR.glob("*.toml"), key=lambda p: (p.stem.startswith("emulated-"), p.stem))


def _distinct_configs() -> dict[str, Path]:
    """The shipped configs, one per distinct planning input (the simulated gantry before its twins), by
    that input."""
    out: dict[str, Path] = {}
    for path in SHIPPED:
        out.setdefault(_planning_input(load_config(path)), path)
    return out


DISTINCT = _distinct_configs()
CONFIGS = list(DISTINCT.values())


def _grids(step: int, stride: int) -> list[str]:
    out = []
    for rec, tmax, order in itertools.product(("true", "false"), ("", ",theta_max=60"), ORDERS):
        for mirror in ("false", "true"):
            out.append(f"iso:step={step},reciprocity={rec},mirror={mirror}{tmax},order={order}")
        out.append(f"full:step={step},reciprocity={rec}{tmax},order={order}")
        if order != "fly":
            out.append(f"merl:stride={stride},reciprocity={rec}{tmax},order={order}")
    return out


def test_the_matrix_covers_every_option_of_every_kind():
    grids = _grids(45, 30)
    assert {g.split(":")[0] for g in grids} == {"iso", "full", "merl"}
    assert {g.rsplit("order=", 1)[1] for g in grids} == set(ORDERS)
    # Both designs, and the sample stage also on the slower axes of its emulated Dynamixel twin.
    assert len(CONFIGS) >= 3
    assert {load_config(p).kinematics.design for p in CONFIGS} == {"two-arm", "sample-stage"}


@pytest.mark.parametrize("path", [p for p in SHIPPED if p not in CONFIGS], ids=lambda p: p.stem)
def test_twins_plan_as_their_gantry(path):
    """Each shipped config the matrix leaves out plans exactly as the one it plans for the same planning
    input (a tour, and a serpentine with a theta limit): the matrix covers it."""
    cfg = load_config(path)
    twin = load_config(DISTINCT[_planning_input(cfg)])
    for grid in ("iso:step=30,order=tour", "full:step=45,theta_max=60"):
        a, b = build_plan(grid, cfg), build_plan(grid, twin)
        for name, value in vars(a).items():
            other = getattr(b, name)
            if isinstance(value, np.ndarray):
                np.testing.assert_array_equal(value, other, err_msg=f"{grid}: {name}")
            elif name not in ("via_deg", "timing"):
                assert value == other, f"{grid}: {name}"
        assert a.via_deg.keys() == b.via_deg.keys() and a.timing == b.timing, grid


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.stem)
def test_every_option_combination_plans_on_every_shipped_config(path):
    cfg = load_config(path)
    kin = make_kinematics(cfg)
    failed = []
    for grid in _grids(45, 30):
        try:
            plan = build_plan(grid, cfg, kin)
        except ValueError as e:
            failed.append(f"{grid}: {e}")
            continue
        # Every planned target points the arms along its pose, within the limits.
        wi, wo = kin.directions(plan.axes_deg)
        assert np.allclose(wi, sph_to_vec(plan.theta_i, plan.phi_i), atol=1e-9), grid
        assert np.allclose(wo, sph_to_vec(plan.theta_o, plan.phi_o), atol=1e-9), grid
        assert kin.within_limits(plan.axes_deg).all(), grid
        assert np.count_nonzero(plan.step_kind == STEP_POSE) == plan.theta_i.size, grid
    assert not failed, "\n".join(failed)


@pytest.mark.parametrize("path", [p for p in CONFIGS if load_config(p).kinematics.design == "two-arm"],
                         ids=lambda p: p.stem)
def test_a_light_circling_a_detector_at_the_zenith_plans(path):
    # full:step=20 without reciprocity has runs where the detector sits at the zenith (a free azimuth)
    # while the light circles it at θi = 40°. Re-solving the detector only on the quickest branch from
    # each predecessor pushed its carriage round the ring into its limit: "poses 3950..3999: some pose
    # has no valid branch", though every pose is reachable alone.
    cfg = load_config(path)
    plan = build_plan("full:step=20,reciprocity=false", cfg)
    assert plan.counts["feasible"] == plan.theta_i.size
    zenith = np.count_nonzero(plan.theta_o < 1e-9)
    assert zenith == 72  # θi ≠ 0 on the 4 × 18 lattice, with the detector at the zenith
