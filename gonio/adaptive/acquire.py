"""An adaptive acquisition: the pilot, then rounds until the pose budget is spent.

``measure(theta_i, theta_o, dphi)`` (radians, φi = 0; the poses as the gantry drives them) returns f_r
(n, C). Each round is :func:`gonio.adaptive.refine.plan_round` of the samples measured so far, so a run
can be replayed from its samples alone: the rounds' sizes depend only on the budget and the pilot's
size (:func:`round_sizes`). A round that finds no reachable new pose ends the run short of its budget
(:attr:`Acquisition.ended` says which round).

``anisotropic=True`` measures the 4D domain (θi, φi, θo, φo): the pilot is
:func:`gonio.adaptive.pilot.pilot_pairs`, the rounds the same :func:`~gonio.adaptive.refine.plan_round`
in the ``pair`` domain, and ``measure`` is called with ``phi_i=`` the poses' φi.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gonio.adaptive.pilot import pilot_pairs, pilot_poses
from gonio.adaptive.refine import CELLS, LOO, PAIR_CELLS, PAIR_LOO, plan_round
from gonio.adaptive.samples import Samples

__all__ = ["acquire", "round_sizes", "Acquisition", "PILOT_FRACTION", "GROWTH"]

#: Share of the budget the pilot may take (``tools/bench_adaptive.py --pilots`` compares others).
PILOT_FRACTION = 0.1
#: Each round adds this fraction of the samples so far (at least one pose), until the budget is spent.
GROWTH = 0.2


@dataclass(frozen=True)
class Acquisition:
    """The result: every sample in the order measured, the size of each phase (pilot first), and the
    round that found no reachable new pose (None: the budget was spent)."""

    samples: Samples
    phases: tuple[int, ...]
    ended: int | None = None


def round_sizes(pilot: int, budget: int, growth: float = GROWTH, least: int = 1) -> list[int]:
    """Sizes of the rounds after a pilot of ``pilot`` poses, each at least ``least`` (a remainder
    smaller than that joins the last round; only a budget left below ``least`` makes a smaller one);
    they sum to ``budget - pilot``.

    >>> round_sizes(100, 400, growth=0.5)
    [50, 75, 112, 63]
    >>> round_sizes(5, 40, growth=0.2, least=10)
    [10, 10, 15]
    """
    if not 0 < pilot <= budget:
        raise ValueError(f"budget: must be at least the pilot's {pilot} poses, got {budget}")
    sizes, total = [], pilot
    while total < budget:
        step = min(budget - total, max(least, int(growth * total)))
        if budget - total - step < least:
            step = budget - total
        sizes.append(step)
        total += step
    return sizes


def acquire(measure, kin, theta_max: float, budget: int, *, pilot_fraction: float = PILOT_FRACTION,
            domain: str = CELLS, seed: int = 0, growth: float = GROWTH, loo: tuple = LOO,
            motion=None, anisotropic: bool = False, pilot=None) -> Acquisition:
    """Measure ``budget`` poses adaptively (module docstring); ``motion``: a
    :class:`gonio.adaptive.motion.Motion` to weigh each round's poses by their gantry time; ``pilot``
    (anisotropic only): ``pilot(kin, theta_max, share) -> (θi, φi, θo, φo)`` in place of
    :func:`~gonio.adaptive.pilot.pilot_pairs` (``tools/bench_adaptive.py --aniso --pilots`` compares).

    Raises
    ------
    ValueError
        For a budget below the smallest pilot, or a pilot fraction outside (0, 1].
    """
    if not 0.0 < pilot_fraction <= 1.0:
        raise ValueError(f"pilot_fraction: must be in (0, 1], got {pilot_fraction}")
    share = max(1, int(pilot_fraction * budget))
    if anisotropic:
        domain, loo = PAIR_CELLS, PAIR_LOO
        ti, pi_, to, po = (pilot or (lambda *a: pilot_pairs(*a)[1]))(kin, theta_max, share)
        d = po - pi_
        samples = Samples(ti, to, d, measure(ti, to, d, phi_i=pi_), pi_)
    else:
        ti, to, d = pilot_poses(kin, theta_max, share)
        samples = Samples(ti, to, d, measure(ti, to, d))
    sizes = round_sizes(len(samples), budget, growth)
    phases = [len(samples)]
    for k, size in enumerate(sizes):
        poses = plan_round(samples, size, kin, theta_max, domain, seed, loo, motion)
        if poses[0].size == 0:
            return Acquisition(samples, tuple(phases), k + 1)
        if anisotropic:
            ti, pi_, to, po = poses
            d = po - pi_
            samples = samples.extended(ti, to, d, measure(ti, to, d, phi_i=pi_), pi_)
        else:
            ti, to, d = poses
            samples = samples.extended(ti, to, d, measure(ti, to, d))
        phases.append(int(ti.size))
    return Acquisition(samples, tuple(phases))


def material_measure(material):
    """A noise-free ``measure`` of a :mod:`gonio.sim.materials` material (its ``eval`` at the poses)."""
    from gonio.geometry import sph_to_vec

    def measure(theta_i, theta_o, dphi, phi_i=0.0):
        phi_i = np.broadcast_to(np.asarray(phi_i, dtype=np.float64), np.shape(theta_i))
        return material.eval(sph_to_vec(theta_i, phi_i), sph_to_vec(theta_o, phi_i + dphi))

    return measure
