"""Fixtures shared across the test folders."""

import pytest
from brdf_samples import sampled


@pytest.fixture
def make_sampled():
    """``sampled(spec, grid, theta_max_deg=85, rel_sd=0.01)``: a SampledBRDF from a material's own eval."""
    return sampled
