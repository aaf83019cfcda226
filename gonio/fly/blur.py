"""The motion blur of a reading taken while the axes move, from its sub-reads.

A fly reading (:mod:`gonio.sim.fly` on the simulated gantry, :mod:`gonio.fly.hardware` on a real one)
is the sum of M sub-reads, each integrating its slice of the exposure. The reading estimates the mean
of the response over the exposure's path but is reported at the direction of its mid-time: for a
response quadratic in time over the exposure, a + b·τ + c·τ² (τ in exposures), the mean over
τ in [−½, ½] is c/12 above the mid-time value. :func:`motion_blur` states that bias from the quadratic
through the sub-reads; :mod:`gonio.sim.fly`'s docstring gives the reasoning and what was measured.
"""

from __future__ import annotations

import numpy as np

__all__ = ["motion_blur"]


def motion_blur(sub, noise_var) -> np.ndarray:
    """The motion blur of each reading (n, C) from its sub-reads (n, M, C), M >= 3: the bias of the
    mean over the exposure against the value at its mid-time. A quadratic y = a + b·τ + c·τ² through
    the sub-reads (τ the slice centres, in exposures) has its exposure mean c/12 above its mid-time
    value. The fitted ĉ carries the noise of the sub-reads (``noise_var``, (n, M, C): their stated
    variances), of variance σ_c², so E[ĉ²] = c² + σ_c²: the bias squared is estimated by ĉ² − σ_c²
    (clipped at 0), not by ĉ², whose excess is noise the sensor term already states. Returned in the
    units of the summed reading (M sub-reads)."""
    sub = np.asarray(sub, dtype=np.float64)
    m = sub.shape[1]
    tau = (np.arange(m) + 0.5) / m - 0.5
    design = np.stack([np.ones(m), tau, tau**2], axis=1)
    pinv = np.linalg.pinv(design)                   # (3, M)
    c = np.einsum("m,nmc->nc", pinv[2], sub)
    c_var = np.einsum("m,nmc->nc", pinv[2] ** 2, np.asarray(noise_var, dtype=np.float64))
    return m * np.sqrt(np.maximum(c * c - c_var, 0.0)) / 12.0
