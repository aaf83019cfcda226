"""The accuracy check of fly campaigns through the drivers: per pose against the stop-and-go simulation
of the same material and grid, within 4 σ (both sides' stated uncertainties) + 1 %, rms z about 1."""

from __future__ import annotations

import numpy as np

from gonio.dataset import read_brdf
from gonio.store import JOURNAL_NAME, Journal

__all__ = ["matches_stop_and_go", "measurements", "pose_order", "simulate_stop_and_go", "z_scores"]


def simulate_stop_and_go(folder, config: str, grid: str, material: str):
    """The brdf.h5 (read) of the stop-and-go simulation of ``material`` on ``grid`` with the shipped
    config ``config``, run in ``folder``."""
    from gonio.campaign import create_campaign
    from gonio.config import load_config
    from gonio.lifecycle import run_campaign
    from gonio.runner import State
    from gonio.wiring import build_gantry

    cfg = load_config(config)
    c = create_campaign(folder, cfg, grid=grid, material=material)
    state, _ = run_campaign(c, build_gantry(cfg, material))
    c.close()
    assert state == State.DONE
    return read_brdf(folder / "brdf.h5")


def measurements(folder):
    """(measurements, events) of the journal in ``folder``."""
    j = Journal.open(folder / JOURNAL_NAME, readonly=True)
    try:
        return j.measurements(), j.events()
    finally:
        j.close()


def pose_order(b):
    """Sample order by planned pose (θi, θo, Δφ): the same in every campaign of the grid."""
    ti, pi, to, po = b.planned.T
    keys = np.round(np.stack([ti, to, np.mod(po - pi, 360.0)], axis=1), 6)
    return np.lexsort(keys.T[::-1]), keys


def z_scores(measured, simulated, atol_deg: float = 0.1):
    """Per pose: (fly value, simulated value, z) with z against both stated uncertainties. The emulated
    photodiode renders with the same 256 aperture samples as the simulated gantry, whose stddev states
    that Monte Carlo error: counted once for each side; the fly side adds its motion blur term (the
    serial power meter states no noise of its own)."""
    (m_order, m_keys), (s_order, s_keys) = pose_order(measured), pose_order(simulated)
    np.testing.assert_array_equal(m_keys[m_order], s_keys[s_order])
    # and measured where planned, to within the encoders' resolution (the fly readings: interpolated)
    for b, order in ((measured, m_order), (simulated, s_order)):
        np.testing.assert_allclose(np.stack([b.theta_i, b.theta_o], axis=1)[order],
                                   b.planned[order][:, [0, 2]], atol=atol_deg)
    sim = simulated.value.mean(axis=1)[s_order]
    sd_sim = simulated.stddev.mean(axis=1)[s_order]
    value, sd = measured.value[m_order, 0], measured.stddev[m_order, 0]
    return value, sim, (value - sim) / np.sqrt(2 * sd_sim**2 + sd**2)


def matches_stop_and_go(folder, meta, stop_and_go, rms: float = 1.5, atol_deg: float = 0.1):
    """The fly campaign in ``folder`` against the stop-and-go simulation; its (rows, events, swept).
    ``atol_deg``: how far a reading's (θi, θo) may be from its pose's."""
    measured = read_brdf(folder / "brdf.h5")
    value, sim, z = z_scores(measured, stop_and_go, atol_deg)
    # Within 4 σ each, plus 1 % for the poses, which differ by the encoders' resolution (as the
    # stop-and-go emulated campaign's own check), and honest on the whole: rms z about 1.
    assert np.all(np.abs(value - sim) <= 4 * np.abs((value - sim) / z) + 0.01 * sim), z
    assert np.sqrt(np.mean(z**2)) < rms, z
    rows, events = measurements(folder)
    swept = [m for m in rows if m.frames > 1]
    assert len(swept) == meta["poses"]  # every pose read on the fly, none stop-and-go
    return rows, events, swept
