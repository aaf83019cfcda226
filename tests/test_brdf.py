"""gonio.brdf: symmetries applied as declared, exact at measured pairs, honest NaN with reasons."""


import numpy as np
import pytest
from brdf_samples import sampled

from gonio.brdf import Reason, open_brdf
from gonio.geometry import sph_to_vec
from gonio.sim.materials import load

SPEC = "ggx:alpha=0.3,metal=gold"


def _random_pairs(n, theta_max_deg, seed=0):
    rng = np.random.default_rng(seed)
    th = np.arccos(1 - rng.random((2, n)) * (1 - np.cos(np.radians(theta_max_deg))))
    ph = rng.random((2, n)) * 2 * np.pi
    return sph_to_vec(th[0], ph[0]), sph_to_vec(th[1], ph[1])


@pytest.mark.parametrize("grid,domain", [("iso:step=5", "iso"), ("iso:step=5,mirror=true", "iso"),
                                         ("merl:stride=3", "merl"), ("full:step=15", "full")])
def test_grid_interpolation_is_exact_at_samples_and_close_between(grid, domain):
    data = sampled(SPEC, grid)
    b = open_brdf(data)
    assert (b.domain, b.method) == (domain, "grid")
    at = b.eval_deg(data.theta_i, data.phi_i, data.theta_o, data.phi_o)
    assert at.exact.all()
    np.testing.assert_array_equal(at.value, data.value)
    np.testing.assert_allclose(at.stddev, data.stddev, rtol=1e-12)
    wi, wo = _random_pairs(5000, b.theta_max_deg - 1)
    ev = b.eval(wi, wo)
    ok = ev.reason == Reason.OK
    assert ok.mean() > (0.85 if domain == "merl" else 0.95)  # merl: bins by the horizon are gaps
    truth = load(SPEC).eval(wi[ok], wo[ok], precision="float64")
    assert np.abs(ev.value[ok] - truth).sum() / truth.sum() < (0.12 if domain == "full" else 0.02)
    # propagated stddev: a convex combination of 1 % errors stays within 1 % of the value
    assert np.all(ev.stddev[ok] <= 0.01 * ev.value[ok] + 1e-12)


def test_symmetries_are_applied_only_when_declared():
    data = sampled(SPEC, "iso:step=10")
    swapped = dict(theta_i=[20.0], phi_i=[0.0], theta_o=[10.0], phi_o=[0.0])  # only (10, 20) was measured
    b = open_brdf(data)
    ev = b.eval_deg(swapped["theta_i"], swapped["phi_i"], swapped["theta_o"], swapped["phi_o"])
    assert ev.exact[0] and ev.reason[0] == Reason.OK
    attrs = dict(data.attrs, symmetries={"reciprocity": False, "isotropy": True, "mirror": False})
    from gonio.dataset import SampledBRDF
    b2 = open_brdf(SampledBRDF(data.theta_i, data.phi_i, data.theta_o, data.phi_o, data.value, data.stddev,
                               attrs))
    ev2 = b2.eval_deg(swapped["theta_i"], swapped["phi_i"], swapped["theta_o"], swapped["phi_o"])
    assert ev2.reason[0] == Reason.NO_DATA and np.isnan(ev2.value).all()
    # isotropy: rotating both directions gives the same answer
    r = b.eval_deg(30.0, 77.0, 40.0, 77.0 + 120.0)
    r0 = b.eval_deg(30.0, 0.0, 40.0, 120.0)
    np.testing.assert_allclose(r.value, r0.value, rtol=1e-12)


def test_reasons_horizon_range_invalid():
    b = open_brdf(sampled(SPEC, "iso:step=10", theta_max_deg=60.0))
    ev = b.eval_deg([95.0, 70.0, np.nan, 30.0], 0.0, [10.0, 10.0, 10.0, 30.0], 180.0)
    assert ev.reason.tolist() == [Reason.BELOW_HORIZON, Reason.OUT_OF_RANGE, Reason.INVALID, Reason.OK]
    assert np.isnan(ev.value[:3]).all() and np.isfinite(ev.value[3]).all()


def test_scattered_data_and_gaps():
    data = sampled(SPEC, "iso:step=5")
    rng = np.random.default_rng(2)
    jitter = lambda a: a + rng.normal(0, 0.05, a.shape) * (a > 0)  # noqa: E731
    from gonio.dataset import SampledBRDF
    ti, to = jitter(data.theta_i), jitter(data.theta_o)
    pi_, po = np.zeros_like(ti), data.phi_o.copy()
    truth = load(SPEC).eval(sph_to_vec(np.radians(ti), 0), sph_to_vec(np.radians(to), np.radians(po)),
                            precision="float64")
    hole = (to > 40) & (to < 60) & (ti > 40) & (ti < 60)
    keep = ~hole
    s = SampledBRDF(ti[keep], pi_[keep], to[keep], po[keep], truth[keep], 0.01 * truth[keep], data.attrs)
    b = open_brdf(s)
    assert b.method == "scattered"
    wi, wo = _random_pairs(4000, 80, seed=5)
    ev = b.eval(wi, wo)
    ok = ev.reason == Reason.OK
    ref = load(SPEC).eval(wi[ok], wo[ok], precision="float64")
    assert ok.mean() > 0.85 and np.abs(ev.value[ok] - ref).sum() / ref.sum() < 0.03
    inside = b.eval_deg(50.0, 0.0, 50.0, 90.0)
    assert inside.reason[0] == Reason.NO_DATA


def test_open_errors_name_the_path(tmp_path):
    with pytest.raises(ValueError, match="no such campaign folder"):
        open_brdf(tmp_path / "nowhere")
    with pytest.raises(ValueError, match="method: must be one of"):
        open_brdf(sampled(SPEC, "iso:step=30"), method="cubic")


def test_scattered_estimate_is_the_weighted_least_squares_plane():
    """The closed-form fit against numpy's lstsq on the same neighbours, weights and embedding."""
    from gonio.interpolate import Scattered, domain_coords

    rng = np.random.default_rng(7)
    n = 400
    ang = np.radians(np.stack([rng.uniform(0, 80, n), np.zeros(n), rng.uniform(0, 80, n),
                               rng.uniform(0, 360, n)], axis=1))
    value = rng.random((n, 2))
    sym = {"reciprocity": False, "isotropy": True, "mirror": False}
    eng = Scattered("iso", domain_coords("iso", ang, sym), value, 0.1 * value, sym, 1e-9)
    q = np.radians(np.array([[30.0, 0.0, 40.0, 180.0], [50.0, 0.0, 20.0, 77.0], [10.0, 0.0, 70.0, 300.0]]))
    got = eng.eval(domain_coords("iso", q, sym))[0]
    p = eng._embed(domain_coords("iso", q, sym))
    samples = eng._embed(domain_coords("iso", ang, sym))  # in the order of `value` (no symmetry copies)
    for row, point in enumerate(p):
        dist = np.linalg.norm(samples - point, axis=1)
        near = np.argsort(dist)[:eng.k]
        h = dist[near].max() * 1.05
        sw = np.sqrt((1 - (dist[near] / h) ** 2) ** 2)
        design = np.concatenate([np.ones((eng.k, 1)), (samples[near] - point) / h], axis=1)
        coef = np.linalg.lstsq(design * sw[:, None], value[near] * sw[:, None], rcond=None)[0]
        np.testing.assert_allclose(got[row], coef[0], rtol=1e-4)  # up to the 1e-6 ridge
