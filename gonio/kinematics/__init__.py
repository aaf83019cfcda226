"""Kinematics: sample-frame directions (θi, φi, θo, φo) <-> axis positions, for real gantry designs.

``make_kinematics(cfg)`` builds the design the config names (the registry
:data:`gonio.registries.DESIGNS`: a plugin adds one, docs/EXTENDING.md); every design has the interface of
:class:`~gonio.kinematics.base.Kinematics` (solutions, inverse, forward, directions, feasibility) and
reports unreachable poses with the codes of :data:`REASONS`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from gonio.kinematics.base import (
    ARM_COLLISION,
    BEYOND_THETA_MAX,
    OCCLUSION,
    OK,
    OUT_OF_REACH,
    REASONS,
    Kinematics,
)
from gonio.kinematics.sample_stage import SampleStage
from gonio.kinematics.two_arm import TwoArm
from gonio.registries import DESIGNS

if TYPE_CHECKING:  # type hints only: a design plugin is imported while gonio.config is
    from gonio.config import GonioConfig

__all__ = [
    "REASONS",
    "OK",
    "OUT_OF_REACH",
    "ARM_COLLISION",
    "OCCLUSION",
    "BEYOND_THETA_MAX",
    "DESIGNS",
    "Kinematics",
    "TwoArm",
    "SampleStage",
    "make_kinematics",
]



def make_kinematics(cfg: GonioConfig) -> Kinematics:
    """The kinematics of the design that ``cfg.kinematics.design`` names.

    Raises
    ------
    ValueError
        When the design is not one of :data:`DESIGNS` (the config model already rejects that on load).

    Examples
    --------
    >>> from gonio.config import load_config
    >>> make_kinematics(load_config()).axis_names
    ('light_azimuth', 'light_tilt', 'detector_azimuth', 'detector_tilt')
    """
    return DESIGNS.check(cfg.kinematics.design, "kinematics.design").load()(cfg)
