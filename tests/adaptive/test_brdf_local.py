"""gonio.brdf's ``local`` method (:class:`gonio.adaptive.reconstruct.LocalEngine`): taken for adaptive
campaigns, a sample hit exactly is returned as measured, the standard deviation is the fit's response
to the samples' noise (checked against refits of noisy copies), and on adaptive samples it leaves several
times less error than the scattered plane."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.adaptive import acquire, material_measure, random_pairs, weighted_l1
from gonio.adaptive.reconstruct import LocalEngine
from gonio.brdf import MeasuredBRDF
from gonio.config import load_config
from gonio.dataset import SampledBRDF
from gonio.kinematics import make_kinematics
from gonio.sim.materials import load

GGX = "ggx:alpha=0.2,metal=gold"
SYM = {"reciprocity": True, "isotropy": True, "mirror": False}


@pytest.fixture(scope="module")
def adaptive():
    """300 noise-free adaptive samples of GGX (the library's acquisition on the simulated gantry)."""
    cfg = load_config()
    tmax = np.radians(cfg.kinematics.theta_max_deg)
    return acquire(material_measure(load(GGX)), make_kinematics(cfg), tmax, 300).samples, tmax


def _dataset(samples, grid="adaptive:poses=300", stddev=None, sym=SYM):
    deg = [np.degrees(a) for a in (samples.theta_i, np.zeros(len(samples)), samples.theta_o, samples.dphi)]
    sd = np.zeros_like(samples.value) if stddev is None else stddev
    return SampledBRDF(*deg, value=samples.value, stddev=sd, attrs={"symmetries": sym, "grid": grid})


def test_an_adaptive_campaign_is_read_with_the_local_fit_and_beats_the_scattered_plane(adaptive):
    samples, tmax = adaptive
    data = _dataset(samples)
    auto, plane = MeasuredBRDF(data), MeasuredBRDF(data, method="scattered")
    assert (auto.method, auto.domain, plane.method) == ("local", "iso", "scattered")
    wi, wo = random_pairs(4000, tmax, 3)
    truth = load(GGX).eval(wi, wo)
    local_err, answered = weighted_l1(auto.eval(wi, wo).value, truth, wi, wo)
    plane_err, _ = weighted_l1(plane.eval(wi, wo).value, truth, wi, wo)
    assert answered > 0.99 and local_err * 3 < plane_err, (local_err, plane_err)
    # A uniform grid is still read on its lattice.
    assert MeasuredBRDF(_dataset(samples, grid="iso:step=10"), method="auto").method == "scattered"


def test_a_sample_hit_exactly_is_returned_as_measured(adaptive):
    samples, _ = adaptive
    sd = 0.01 * samples.value
    b = MeasuredBRDF(_dataset(samples, stddev=sd))
    pick = np.arange(0, len(samples), 37)
    e = b.eval_deg(np.degrees(samples.theta_i[pick]), 0.0, np.degrees(samples.theta_o[pick]),
                   np.degrees(samples.dphi[pick]))
    assert e.exact.all()
    np.testing.assert_array_equal(e.value, samples.value[pick])
    np.testing.assert_array_equal(e.stddev, sd[pick])


def test_the_standard_deviation_is_the_fits_response_to_sample_noise(adaptive):
    """Refits of copies with Gaussian noise of the stated σ (1 %) scatter as the propagated σ says."""
    samples, tmax = adaptive
    coords = np.stack([samples.theta_i, samples.theta_o, samples.dphi], axis=1)
    sd = 0.01 * samples.value
    wi, wo = random_pairs(60, tmax, 7)
    from gonio.geometry import vec_to_sph
    from gonio.interpolate import domain_coords

    ti, pi_ = vec_to_sph(wi)
    to, po = vec_to_sph(wo)
    q = domain_coords("iso", np.stack([ti, pi_, to, po], axis=1), SYM)
    value, stddev, reason, _ = LocalEngine(coords, samples.value, sd, 1e-9).eval(q)
    rng = np.random.default_rng(11)
    refits = np.stack([LocalEngine(coords, samples.value + sd * rng.standard_normal(sd.shape), sd, 1e-9)
                       .eval(q)[0] for _ in range(200)])
    ok = reason == 0
    ratio = refits.std(axis=0)[ok] / stddev[ok]
    # 200 draws: a standard deviation known to ~5 %; the bound and the log make it a first-order estimate
    spread = np.percentile(ratio, [0, 50, 100])
    assert 0.8 < spread[1] < 1.2 and 0.5 < spread[0] and spread[2] < 1.5, spread
    np.testing.assert_allclose(refits.mean(axis=0)[ok], value[ok], rtol=0.02)


def test_local_refuses_data_it_does_not_fit(adaptive):
    samples, _ = adaptive
    with pytest.raises(ValueError, match="method 'local': fits reciprocal samples without mirror"):
        MeasuredBRDF(_dataset(samples, sym={**SYM, "mirror": True}), method="local")
